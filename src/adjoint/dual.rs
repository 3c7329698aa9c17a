//! Scalars that an estimator's weight and OPL are written over once ([`Real`]), so the
//! primal pass (`f32`) and the adjoint pass ([`Dual`], forward-mode derivatives with
//! respect to a handful of local parameters) run the same formula and cannot drift.

use std::ops::{Add, Div, Mul, Neg, Sub};

/// A real number the estimators' formulas accept: `f32`, `f64`, or a [`Dual`] of either.
pub trait Real:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    /// A constant (zero derivative).
    fn c(v: f64) -> Self;
    /// The value (what comparisons, bin indices and ray casts use).
    fn v(self) -> f64;
    fn sqrt(self) -> Self;
    fn exp(self) -> Self;
    /// `self^m` for a constant `m` (`self > 0`).
    fn powc(self, m: f64) -> Self;
    fn erf(self) -> Self;
    /// `1 − erf`, precise in the tail.
    fn erfc(self) -> Self;

    /// The standard normal distribution and density, `(Φ(u), φ(u))`. `f64` reads them
    /// from a table (`film::normal`, error < 1.3e-13); derivatives carry them exactly.
    #[inline(always)]
    fn normal(self) -> (Self, Self) {
        const INV_SQRT_2PI: f64 = 0.398_942_280_401_432_7;
        (
            self.s(-std::f64::consts::FRAC_1_SQRT_2).erfc().s(0.5),
            (self * self).s(-0.5).exp().s(INV_SQRT_2PI),
        )
    }

    /// `self · k` for a constant `k`.
    #[inline(always)]
    fn s<K: Into<f64>>(self, k: K) -> Self {
        self * Self::c(k.into())
    }

    fn abs(self) -> Self {
        if self.v() < 0.0 {
            -self
        } else {
            self
        }
    }

    fn min(self, o: Self) -> Self {
        if o.v() < self.v() {
            o
        } else {
            self
        }
    }

    fn max(self, o: Self) -> Self {
        if o.v() > self.v() {
            o
        } else {
            self
        }
    }
}

/// The float types a [`Dual`] holds.
pub trait Float: Real + Default + std::ops::AddAssign + std::ops::SubAssign {}
impl Float for f32 {}
impl Float for f64 {}

impl Real for f32 {
    #[inline(always)]
    fn c(v: f64) -> Self {
        v as f32
    }
    #[inline(always)]
    fn v(self) -> f64 {
        self as f64
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn exp(self) -> Self {
        f32::exp(self)
    }
    #[inline(always)]
    fn powc(self, m: f64) -> Self {
        f32::powf(self, m as f32)
    }
    #[inline(always)]
    fn erf(self) -> Self {
        libm::erff(self)
    }
    #[inline(always)]
    fn erfc(self) -> Self {
        libm::erfcf(self)
    }
}

impl Real for f64 {
    #[inline(always)]
    fn c(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn v(self) -> f64 {
        self
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn exp(self) -> Self {
        f64::exp(self)
    }
    #[inline(always)]
    fn powc(self, m: f64) -> Self {
        f64::powf(self, m)
    }
    #[inline(always)]
    fn erf(self) -> Self {
        libm::erf(self)
    }
    #[inline(always)]
    fn erfc(self) -> Self {
        libm::erfc(self)
    }
    #[inline(always)]
    fn normal(self) -> (Self, Self) {
        crate::film::normal::normal(self)
    }
}

/// `v + Σ d_i ε_i`: a value and its partial derivatives with respect to `N` parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual<T, const N: usize> {
    pub v: T,
    pub d: [T; N],
}

impl<T: Float, const N: usize> Dual<T, N> {
    /// Parameter `i` with value `v` (derivative 1 in slot `i`).
    pub fn var(v: T, i: usize) -> Self {
        let mut d = [T::default(); N];
        d[i] = T::c(1.0);
        Dual { v, d }
    }

    #[inline(always)]
    fn chain(self, v: T, f: T) -> Self {
        // g(self) with value v and g' = f: derivatives f d.
        Dual {
            v,
            d: self.d.map(|d| f * d),
        }
    }
}

impl<T: Float, const N: usize> Real for Dual<T, N> {
    #[inline(always)]
    fn c(v: f64) -> Self {
        Dual {
            v: T::c(v),
            d: [T::default(); N],
        }
    }
    #[inline(always)]
    fn v(self) -> f64 {
        self.v.v()
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        let s = self.v.sqrt();
        self.chain(s, T::c(0.5) / s)
    }
    #[inline(always)]
    fn powc(self, m: f64) -> Self {
        let p = self.v.powc(m);
        self.chain(p, T::c(m) * p / self.v)
    }
    #[inline(always)]
    fn exp(self) -> Self {
        let e = self.v.exp();
        self.chain(e, e)
    }
    #[inline(always)]
    fn erf(self) -> Self {
        let slope = T::c(std::f64::consts::FRAC_2_SQRT_PI) * (-(self.v * self.v)).exp();
        self.chain(self.v.erf(), slope)
    }
    #[inline(always)]
    fn erfc(self) -> Self {
        let slope = T::c(-std::f64::consts::FRAC_2_SQRT_PI) * (-(self.v * self.v)).exp();
        self.chain(self.v.erfc(), slope)
    }
    #[inline(always)]
    fn normal(self) -> (Self, Self) {
        // Φ' = φ, φ' = −uφ.
        let (c, p) = self.v.normal();
        (self.chain(c, p), self.chain(p, -(self.v * p)))
    }
    #[inline(always)]
    fn s<K: Into<f64>>(self, k: K) -> Self {
        let k = T::c(k.into());
        self.chain(self.v * k, k)
    }
}

impl<T: Float, const N: usize> Add for Dual<T, N> {
    type Output = Self;
    #[inline(always)]
    fn add(self, o: Self) -> Self {
        let mut d = self.d;
        d.iter_mut().zip(o.d).for_each(|(a, b)| *a += b);
        Dual { v: self.v + o.v, d }
    }
}

impl<T: Float, const N: usize> Sub for Dual<T, N> {
    type Output = Self;
    #[inline(always)]
    fn sub(self, o: Self) -> Self {
        let mut d = self.d;
        d.iter_mut().zip(o.d).for_each(|(a, b)| *a -= b);
        Dual { v: self.v - o.v, d }
    }
}

impl<T: Float, const N: usize> Mul for Dual<T, N> {
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

impl<T: Float, const N: usize> Div for Dual<T, N> {
    type Output = Self;
    #[allow(clippy::suspicious_arithmetic_impl)]
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        let inv = T::c(1.0) / o.v;
        let v = self.v * inv;
        let mut d = self.d;
        d.iter_mut()
            .zip(o.d)
            .for_each(|(a, b)| *a = (*a - v * b) * inv);
        Dual { v, d }
    }
}

impl<T: Float, const N: usize> Neg for Dual<T, N> {
    type Output = Self;
    #[inline(always)]
    fn neg(self) -> Self {
        self.chain(-self.v, T::c(-1.0))
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
    [R::c(a.x as f64), R::c(a.y as f64), R::c(a.z as f64)]
}

/// The value of a vector.
#[inline(always)]
pub fn value<R: Real>(a: V3<R>) -> glam::Vec3 {
    glam::Vec3::new(a[0].v() as f32, a[1].v() as f32, a[2].v() as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// d/dx of a formula using every operation, against a central difference in f64.
    #[test]
    fn derivatives_match_finite_differences() {
        fn f<R: Real>(x: R, y: R) -> R {
            let a = [x, y, R::c(0.3)];
            let b = [y.s(2.0), -x, x * y];
            let n = cross(a, b);
            (dot(n, a) + length(n)) / (x * x + R::c(1.0)).sqrt() - (x - y).abs()
                + x.s(0.5).erf() * (-y).exp()
                + (x + y).erfc()
        }
        let (x, y) = (0.7f64, -0.4f64);
        let d = f(Dual::<f64, 2>::var(x, 0), Dual::<f64, 2>::var(y, 1));
        let d32 = f(
            Dual::<f32, 2>::var(x as f32, 0),
            Dual::<f32, 2>::var(y as f32, 1),
        );
        let h = 1e-5;
        let fd_x = (f(x + h, y) - f(x - h, y)) / (2.0 * h);
        let fd_y = (f(x, y + h) - f(x, y - h)) / (2.0 * h);
        assert!((d.v - f(x, y)).abs() < 1e-12);
        assert!(
            (d.d[0] - fd_x).abs() < 1e-8 * fd_x.abs().max(1.0),
            "{d:?} {fd_x}"
        );
        assert!(
            (d.d[1] - fd_y).abs() < 1e-8 * fd_y.abs().max(1.0),
            "{d:?} {fd_y}"
        );
        assert!(
            (d32.d[0] as f64 - fd_x).abs() < 1e-5 * fd_x.abs().max(1.0),
            "{d32:?}"
        );
    }
}
