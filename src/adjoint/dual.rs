//! Scalars that an estimator's weight and OPL are written over once ([`Real`]), so the
//! primal pass (`f32`) and the adjoint pass ([`Dual`], forward-mode derivatives with
//! respect to a handful of local parameters) run the same formula and cannot drift.

use std::ops::{Add, Div, Mul, Neg, Sub};

/// A real number the estimators' formulas accept: `f32` or a [`Dual`].
pub trait Real:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + Mul<f32, Output = Self>
{
    /// A constant (zero derivative).
    fn c(v: f32) -> Self;
    /// The value (what comparisons and ray casts use).
    fn v(self) -> f32;
    fn sqrt(self) -> Self;

    fn abs(self) -> Self {
        if self.v() < 0.0 {
            -self
        } else {
            self
        }
    }
}

impl Real for f32 {
    #[inline(always)]
    fn c(v: f32) -> Self {
        v
    }
    #[inline(always)]
    fn v(self) -> f32 {
        self
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
}

/// `v + Σ d_i ε_i`: a value and its partial derivatives with respect to `N` parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual<const N: usize> {
    pub v: f32,
    pub d: [f32; N],
}

impl<const N: usize> Dual<N> {
    /// Parameter `i` with value `v` (derivative 1 in slot `i`).
    pub fn var(v: f32, i: usize) -> Self {
        let mut d = [0.0; N];
        d[i] = 1.0;
        Dual { v, d }
    }

    #[inline(always)]
    fn map(self, v: f32, f: f32) -> Self {
        // f(x) with f'(x) = f: value v, derivatives f d.
        Dual {
            v,
            d: self.d.map(|d| f * d),
        }
    }
}

impl<const N: usize> Real for Dual<N> {
    #[inline(always)]
    fn c(v: f32) -> Self {
        Dual { v, d: [0.0; N] }
    }
    #[inline(always)]
    fn v(self) -> f32 {
        self.v
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        self.map(s, 0.5 / s)
    }
}

impl<const N: usize> Add for Dual<N> {
    type Output = Self;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        let mut d = self.d;
        d.iter_mut().zip(o.d).for_each(|(a, b)| *a += b);
        Dual { v: self.v + o.v, d }
    }
}

impl<const N: usize> Sub for Dual<N> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        let mut d = self.d;
        d.iter_mut().zip(o.d).for_each(|(a, b)| *a -= b);
        Dual { v: self.v - o.v, d }
    }
}

impl<const N: usize> Mul for Dual<N> {
    type Output = Self;
    // The product rule adds.
    #[allow(clippy::suspicious_arithmetic_impl)]
    #[inline(always)]
    fn mul(self, o: Self) -> Self {
        let mut d = self.d;
        d.iter_mut()
            .zip(o.d)
            .for_each(|(a, b)| *a = *a * o.v + self.v * b);
        Dual { v: self.v * o.v, d }
    }
}

impl<const N: usize> Div for Dual<N> {
    type Output = Self;
    #[allow(clippy::suspicious_arithmetic_impl)]
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        let inv = 1.0 / o.v;
        let v = self.v * inv;
        let mut d = self.d;
        d.iter_mut()
            .zip(o.d)
            .for_each(|(a, b)| *a = (*a - v * b) * inv);
        Dual { v, d }
    }
}

impl<const N: usize> Neg for Dual<N> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.map(-self.v, -1.0)
    }
}

impl<const N: usize> Mul<f32> for Dual<N> {
    type Output = Self;
    #[inline(always)]
    fn mul(self, k: f32) -> Self {
        self.map(self.v * k, k)
    }
}

/// 3-vectors over a [`Real`].
pub type V3<R> = [R; 3];

#[inline(always)]
pub fn sub<R: Real>(a: V3<R>, b: V3<R>) -> V3<R> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

#[inline(always)]
pub fn dot<R: Real>(a: V3<R>, b: V3<R>) -> R {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline(always)]
pub fn cross<R: Real>(a: V3<R>, b: V3<R>) -> V3<R> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

#[inline(always)]
pub fn scale<R: Real>(a: V3<R>, k: R) -> V3<R> {
    [a[0] * k, a[1] * k, a[2] * k]
}

#[inline(always)]
pub fn length<R: Real>(a: V3<R>) -> R {
    dot(a, a).sqrt()
}

/// A constant vector.
#[inline(always)]
pub fn constant<R: Real>(a: glam::Vec3) -> V3<R> {
    [R::c(a.x), R::c(a.y), R::c(a.z)]
}

/// The value of a vector.
#[inline(always)]
pub fn value<R: Real>(a: V3<R>) -> glam::Vec3 {
    glam::Vec3::new(a[0].v(), a[1].v(), a[2].v())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// d/dx of a formula using every operation, against a central difference in f64.
    #[test]
    fn derivatives_match_finite_differences() {
        fn f<R: Real>(x: R, y: R) -> R {
            let a = [x, y, R::c(0.3)];
            let b = [y * 2.0, -x, x * y];
            let n = cross(a, b);
            (dot(n, a) + length(n)) / (x * x + R::c(1.0)).sqrt() - (x - y).abs()
        }
        let (x, y) = (0.7f32, -0.4f32);
        let d = f(Dual::<2>::var(x, 0), Dual::<2>::var(y, 1));
        let h = 1e-3f32;
        let fd_x = (f(x + h, y) - f(x - h, y)) / (2.0 * h);
        let fd_y = (f(x, y + h) - f(x, y - h)) / (2.0 * h);
        assert!((d.v - f(x, y)).abs() < 1e-6);
        assert!(
            (d.d[0] - fd_x).abs() < 1e-3 * fd_x.abs().max(1.0),
            "{d:?} {fd_x}"
        );
        assert!(
            (d.d[1] - fd_y).abs() < 1e-3 * fd_y.abs().max(1.0),
            "{d:?} {fd_y}"
        );
    }
}
