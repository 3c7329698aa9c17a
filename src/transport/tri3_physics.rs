//! `tri3`'s per-pair physics (the equations of [`super::tri3_kernel`]'s module doc: corner
//! OPL, corner weight, plane factor, centroid) written once over [`Lane`]: one `f32` (the
//! forward kernel's per-lane loop, which the compiler vectorises) or eight (`f32x8`, the
//! adjoint kernel's reverse, [`super::tri3_adjoint`]), so the render and its gradient
//! evaluate the same expressions. The `f64` dual-number model ([`super::tri3_exact`]) is
//! the oracle both are tested against.

use super::tri3_kernel::{BlockFrame, Frame};
use crate::film::Arith;
use std::ops::BitAnd;
use wide::{f32x8, CmpGt};

/// A number in one lane or eight: what the physics needs of it, on top of the arithmetic
/// the pulse's reverse needs ([`Arith`]).
pub trait Lane: Arith {
    type Mask: Copy + BitAnd<Output = Self::Mask>;
    #[inline(always)]
    fn splat(v: f32) -> Self {
        Self::k(f64::from(v))
    }
    /// `self · a + b`, fused.
    fn mul_add(self, a: Self, b: Self) -> Self;
    fn sqrt(self) -> Self;
    fn abs(self) -> Self;
    fn gt(self, o: Self) -> Self::Mask;
    /// `a` where `m`, else `b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
}

impl Lane for f32 {
    type Mask = bool;
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self {
        f32::mul_add(self, a, b)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f32::abs(self)
    }
    #[inline(always)]
    fn gt(self, o: Self) -> bool {
        self > o
    }
    #[inline(always)]
    fn select(m: bool, a: Self, b: Self) -> Self {
        if m {
            a
        } else {
            b
        }
    }
}

impl Lane for f32x8 {
    type Mask = f32x8;
    #[inline(always)]
    fn mul_add(self, a: Self, b: Self) -> Self {
        f32x8::mul_add(self, a, b)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32x8::sqrt(self)
    }
    #[inline(always)]
    fn abs(self) -> Self {
        f32x8::abs(self)
    }
    #[inline(always)]
    fn gt(self, o: Self) -> f32x8 {
        self.cmp_gt(o)
    }
    #[inline(always)]
    fn select(m: f32x8, a: Self, b: Self) -> Self {
        m.blend(a, b)
    }
}

pub type V3<N> = [N; 3];

#[inline(always)]
pub fn dot<N: Lane>(a: V3<N>, b: V3<N>) -> N {
    a[0].mul_add(b[0], a[1].mul_add(b[1], a[2] * b[2]))
}

#[inline(always)]
pub fn sub<N: Lane>(a: V3<N>, b: V3<N>) -> V3<N> {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The measurement's wall points and time scale for one block, in lanes: points of the
/// block are given from its origin `o` ([`BlockFrame`]).
#[derive(Clone, Copy)]
pub struct Wall<N> {
    /// The wall points and normal (m; absolute, for the plane terms).
    pub x_l: V3<N>,
    pub x_s: V3<N>,
    pub n_w: V3<N>,
    /// The laser spot and the sensor point seen from the block's origin.
    from_l: FromOrigin<N>,
    from_s: FromOrigin<N>,
    /// The origin's OPL in bins from the block's base.
    tau: N,
    pub inv_width: N,
}

/// A wall point `x` from the block's origin `o`: `a = x − o` and `|a|` (rounded from
/// `f64`, [`BlockFrame`]), `2a`, `|a|²` and the wall cosine term `−n_w·a`.
#[derive(Clone, Copy)]
struct FromOrigin<N> {
    a: V3<N>,
    a2: V3<N>,
    r: N,
    r2: N,
    c: N,
}

impl<N: Lane> FromOrigin<N> {
    /// `a` and its length `r`.
    #[inline(always)]
    fn new(a: glam::Vec3, r: f32, n_w: glam::Vec3) -> Self {
        let v = |x: glam::Vec3| x.to_array().map(N::splat);
        FromOrigin {
            a: v(a),
            a2: v(a + a),
            r: N::splat(r),
            r2: N::splat(r * r),
            c: N::splat(-n_w.dot(a)),
        }
    }

    /// `|x − v|² − |x − o|² = q·(q − 2a)` for `v = o + q`: small where `q` is, and exact
    /// to its own size (no difference of two lengths).
    #[inline(always)]
    fn excess(&self, q: V3<N>) -> N {
        dot(q, sub(q, self.a2))
    }

    /// The leg from `v = o + q` to `x`: `d = x − v`, `r²`, `r`, `c = −n_w·d`, and the
    /// excess `e` with `|x − v| + |x − o|`, whose ratio is `|x − v| − |x − o|` (m).
    #[inline(always)]
    fn leg(&self, n_w: V3<N>, q: V3<N>) -> (V3<N>, N, N, N, [N; 2]) {
        let e = self.excess(q);
        let r2 = self.r2 + e;
        let r = r2.sqrt();
        (sub(self.a, q), r2, r, self.c + dot(n_w, q), [e, r + self.r])
    }
}

impl<N: Lane> Wall<N> {
    #[inline(always)]
    pub fn new(f: &Frame, b: &BlockFrame) -> Self {
        let v = |x: glam::Vec3| x.to_array().map(N::splat);
        let from_l = FromOrigin::new(b.o_l, b.r_l, f.n_w);
        let from_s = if f.confocal() {
            from_l
        } else {
            FromOrigin::new(b.o_s, b.r_s, f.n_w)
        };
        Wall {
            x_l: v(f.x_l),
            x_s: v(f.x_s),
            n_w: v(f.n_w),
            from_l,
            from_s,
            tau: N::splat(b.tau),
            inv_width: N::splat(f.inv_width as f32),
        }
    }

    /// OPL in bins from the block's base of the point `q` (from the origin) with legs
    /// `legs`: the origin's, plus each leg's difference to the origin's leg (the module
    /// doc of `tri3_kernel`).
    #[inline(always)]
    pub fn bins<const CONFOCAL: bool>(&self, legs: &Legs<N>) -> N {
        let ([e_l, s_l], [e_s, s_s]) = (legs.dr_l, legs.dr_s);
        // e_l/s_l + e_s/s_s with one division (s ~ 2 r: no overflow).
        let dr = if CONFOCAL {
            (e_l + e_l) / s_l
        } else {
            e_l.mul_add(s_s, e_s * s_l) / (s_l * s_s)
        };
        self.tau + dr * self.inv_width
    }
}

/// A point's legs to the wall points: `d = x − v`, `r²`, `r`, the wall cosine term
/// `c = −n_w·d`, and `dr = [e, s]`, the leg's length less the block origin's as the ratio
/// `e / s` (`FromOrigin::leg`), for the laser spot and the sensor point.
#[derive(Clone, Copy)]
pub struct Legs<N> {
    pub d_l: V3<N>,
    pub r2_l: N,
    pub r_l: N,
    pub c_l: N,
    pub dr_l: [N; 2],
    pub d_s: V3<N>,
    pub r2_s: N,
    pub r_s: N,
    pub c_s: N,
    pub dr_s: [N; 2],
}

impl<N: Lane> Legs<N> {
    /// The legs of the point `q` (from the block's origin). `CONFOCAL` (`x_l == x_s`)
    /// skips the second distance.
    #[inline(always)]
    pub fn new<const CONFOCAL: bool>(w: &Wall<N>, q: V3<N>) -> Legs<N> {
        let (d_l, r2_l, r_l, c_l, dr_l) = w.from_l.leg(w.n_w, q);
        let (d_s, r2_s, r_s, c_s, dr_s) = if CONFOCAL {
            (d_l, r2_l, r_l, c_l, dr_l)
        } else {
            w.from_s.leg(w.n_w, q)
        };
        Legs {
            d_l,
            r2_l,
            r_l,
            c_l,
            dr_l,
            d_s,
            r2_s,
            r_s,
            c_s,
            dr_s,
        }
    }

    /// In front of the wall at both wall points.
    #[inline(always)]
    pub fn front(&self) -> N::Mask {
        let zero = N::splat(0.0);
        self.c_l.gt(zero) & self.c_s.gt(zero)
    }

    /// The corner weight without `ρ/π` and the plane factor:
    /// `c_l c_s / (r_l² r_s²)²`, or `c_l / r_l⁴` for a retroreflective triangle (the return
    /// leg's `c_s / r_s⁴` is 1, and its `p_s` in [`Plane`]); 0 behind the wall.
    /// (Confocal, the two legs' factors are one `c / r⁴`: one division, not two.)
    #[inline(always)]
    pub fn weight<const CONFOCAL: bool>(&self, retro: N::Mask) -> N {
        let w = if CONFOCAL {
            let leg = self.c_l / (self.r2_l * self.r2_l);
            N::select(retro, leg, leg * leg)
        } else {
            let back_leg = N::select(retro, N::splat(1.0), self.c_s / (self.r2_s * self.r2_s));
            self.c_l * back_leg / (self.r2_l * self.r2_l)
        };
        N::select(self.front(), w, N::splat(0.0))
    }
}

impl Legs<f32> {
    /// A retroreflector's angular falloff at this corner, `cos^m θ_l = (|p_l| / r_l)^m`
    /// (`p_l` the plane term of [`Plane`], `m = falloff`, 0 to
    /// [`crate::scene::MAX_RETRO_FALLOFF`]; 1 where `m = 0`). Its derivative, for the
    /// adjoint: `∂ ln/∂v = m d_l / r_l²` and `∂ ln/∂p_l = m / p_l`. (One lane: the
    /// forward's; the adjoint's reverse reads the weight it kept.)
    #[inline(always)]
    pub fn falloff(&self, p_l: f32, falloff: f32) -> f32 {
        if falloff > 0.0 {
            (p_l.abs() / self.r_l).powf(falloff)
        } else {
            1.0
        }
    }
}

/// A triangle's plane terms: `p_l = n·x_l − d`, `p_s`, and the factor `|p_l p_s|`
/// (`|p_l|` retroreflective), 0 unless the triangle faces both wall points (either side
/// for a two-sided one).
pub struct Plane<N: Lane> {
    pub p_l: N,
    pub p_s: N,
    pub facing: N::Mask,
    pub factor: N,
}

impl<N: Lane> Plane<N> {
    #[inline(always)]
    pub fn new<const CONFOCAL: bool>(
        w: &Wall<N>,
        n: V3<N>,
        offset: N,
        two_sided: N::Mask,
        retro: N::Mask,
    ) -> Plane<N> {
        let p_l = dot(n, w.x_l) - offset;
        let p_s = if CONFOCAL {
            p_l
        } else {
            dot(n, w.x_s) - offset
        };
        let (prod, zero) = (p_l * p_s, N::splat(0.0));
        // Masks as numbers, to select between them.
        let (one, no) = (N::splat(1.0), N::splat(0.0));
        let one_sided = N::select(p_l.gt(zero) & p_s.gt(zero), one, no);
        let facing = N::select(two_sided, N::select(prod.gt(zero), one, no), one_sided).gt(zero);
        let factor = N::select(retro, p_l.abs(), prod.abs());
        Plane {
            p_l,
            p_s,
            facing,
            factor: N::select(facing, factor, zero),
        }
    }
}

/// The centroid of three corners.
#[inline(always)]
pub fn centroid<N: Lane>([a, b, c]: [V3<N>; 3]) -> V3<N> {
    let third = N::splat(1.0 / 3.0);
    [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) * third)
}

/// [`Legs`] of eight lanes kept by the forward's per-lane loop (`TriBlock::pulses_keeping`)
/// for the adjoint's reverse, which reads them as `f32x8` instead of computing them again.
#[derive(Clone, Copy, Debug, Default)]
pub struct LegLanes {
    d_l: [[f32; 8]; 3],
    r2_l: [f32; 8],
    r_l: [f32; 8],
    c_l: [f32; 8],
    d_s: [[f32; 8]; 3],
    r2_s: [f32; 8],
    r_s: [f32; 8],
    c_s: [f32; 8],
}

impl LegLanes {
    /// Stores lane `j` (confocal, `CONFOCAL`: the laser leg only, the sensor's is the
    /// same).
    #[inline(always)]
    pub fn put<const CONFOCAL: bool>(&mut self, j: usize, l: &Legs<f32>) {
        for k in 0..3 {
            self.d_l[k][j] = l.d_l[k];
        }
        (self.r2_l[j], self.r_l[j], self.c_l[j]) = (l.r2_l, l.r_l, l.c_l);
        if !CONFOCAL {
            for k in 0..3 {
                self.d_s[k][j] = l.d_s[k];
            }
            (self.r2_s[j], self.r_s[j], self.c_s[j]) = (l.r2_s, l.r_s, l.c_s);
        }
    }

    /// All eight lanes, as [`LegLanes::put`] stored them. (`dr`, the time's part, is not
    /// kept: the reverse differentiates `r` itself.)
    #[inline(always)]
    pub fn lanes<const CONFOCAL: bool>(&self) -> Legs<f32x8> {
        let v = |a: &[f32; 8]| f32x8::new(*a);
        let (d_l, r2_l, r_l, c_l) = (
            self.d_l.each_ref().map(v),
            v(&self.r2_l),
            v(&self.r_l),
            v(&self.c_l),
        );
        let (d_s, r2_s, r_s, c_s) = if CONFOCAL {
            (d_l, r2_l, r_l, c_l)
        } else {
            (
                self.d_s.each_ref().map(v),
                v(&self.r2_s),
                v(&self.r_s),
                v(&self.c_s),
            )
        };
        Legs {
            d_l,
            r2_l,
            r_l,
            c_l,
            dr_l: [f32x8::ZERO; 2],
            d_s,
            r2_s,
            r_s,
            c_s,
            dr_s: [f32x8::ZERO; 2],
        }
    }
}

/// What the forward's per-lane loop keeps for the reverse: the legs of the three corners
/// and of the centroid (`legs[3]`), and each corner's weight `k_i` ([`Legs::weight`]).
#[derive(Clone, Copy, Debug, Default)]
pub struct KeptLegs {
    pub legs: [LegLanes; 4],
    pub weight: [[f32; 8]; 3],
}
