//! Monte Carlo three-bounce estimator with hidden-geometry area sampling (DESIGN §3,
//! rung 2).
//!
//! For laser spot `x_l` and sensor point `x_s`, the three-bounce measurement is
//!
//! `H(x_s) = P(x_l) (ρ_w/π) ∫_A (ρ(x)/π) G(x_l, x) V(x_l, x) G(x, x_s) V(x, x_s) dA(x) (ρ_w/π)`
//!
//! with `G(a, b) = cos θ_a cos θ_b / |a - b|²`. One sample picks a hidden point `x` with
//! `pdf_area = p_t / A_t` (triangle `t` with probability `p_t ∝ A_t`, uniform
//! barycentrics; `1/A` in total) and contributes the
//! integrand over the pdf at OPL `|x_l - x| + |x - x_s|`. Exact visibility: two shadow
//! rays. A finite laser spot is sampled uniformly (its power `P` spread over the disk).
//!
//! Supports: all capture types, one- and two-sided surfaces, per-vertex albedo.
//! Does not: interreflections (see `path`), or paths through the wall.
//!
//! Renders and gradients run it eight samples at a time ([`super::mc3_lanes`], the same
//! contributions and derivatives bit for bit); [`sample`] is the one-sample reference.

use super::{sample_spot, Contribution, HiddenGrad, MeasurementCtx, Sink};
use crate::adjoint::dual::{self, Dual, Float, Real, V3};
use crate::geometry::sampling::TriangleSample;
use crate::geometry::HiddenTri;
use crate::rng::Sampler;
use glam::Vec3;
use std::f32::consts::FRAC_1_PI;

/// Local parameters of a hidden triangle in the adjoint pass: its 9 corner coordinates
/// (`v0.x, v0.y, v0.z, v1.x, …`), then its 3 corner albedos.
pub const TRI_PARAMS: usize = 12;

/// Derivatives with respect to a triangle's [`TRI_PARAMS`].
pub type TriDual = Dual<f32, TRI_PARAMS>;

/// A hidden triangle as the formulas see it: corners and corner albedos, constants in
/// the primal pass and [`TriDual`] variables in the adjoint pass.
#[derive(Clone, Copy, Debug)]
pub struct TriParams<R> {
    pub v: [V3<R>; 3],
    pub albedo: [R; 3],
    pub two_sided: bool,
    /// Retroreflective (`tri3` only; [`crate::scene::Reflectance`]).
    pub retro: bool,
    /// Its angular falloff exponent (`tri3` only).
    pub retro_falloff: f32,
}

impl TriParams<f32> {
    pub fn constant(t: &HiddenTri) -> Self {
        TriParams {
            v: t.v.map(|v| v.to_array()),
            albedo: t.albedo,
            two_sided: t.two_sided,
            retro: t.retro,
            retro_falloff: t.retro_falloff,
        }
    }
}

impl<T: Float, const N: usize> TriParams<Dual<T, N>> {
    /// Every corner coordinate and albedo a variable: slots `0..12`.
    pub fn variables(t: &HiddenTri) -> Self {
        Self::variables_at(t, 0)
    }

    /// Every corner coordinate and albedo a variable: slots `offset..offset + 12`.
    pub fn variables_at(t: &HiddenTri, offset: usize) -> Self {
        let var = |v: f32, i: usize| Dual::var(T::c(v as f64), offset + i);
        TriParams {
            v: std::array::from_fn(|i| std::array::from_fn(|k| var(t.v[i][k], 3 * i + k))),
            albedo: std::array::from_fn(|i| var(t.albedo[i], 9 + i)),
            two_sided: t.two_sided,
            retro: t.retro,
            retro_falloff: t.retro_falloff,
        }
    }
}

impl<R: Real> TriParams<R> {
    /// The point at barycentrics `(b1, b2)`: `(1 − b1 − b2) v0 + b1 v1 + b2 v2`.
    pub fn point(&self, [b1, b2]: [f32; 2]) -> V3<R> {
        let b0 = 1.0 - b1 - b2;
        std::array::from_fn(|k| self.v[0][k].s(b0) + self.v[1][k].s(b1) + self.v[2][k].s(b2))
    }

    /// Barycentrics `(b1, b2)` of a point `y` of the triangle's plane.
    pub fn barycentric_of(&self, y: V3<R>) -> [R; 2] {
        let (e1, e2) = (
            dual::sub(self.v[1], self.v[0]),
            dual::sub(self.v[2], self.v[0]),
        );
        let w = dual::sub(y, self.v[0]);
        let (d00, d01, d11) = (dual::dot(e1, e1), dual::dot(e1, e2), dual::dot(e2, e2));
        let (d20, d21) = (dual::dot(w, e1), dual::dot(w, e2));
        let inv = R::c(1.0) / (d00 * d11 - d01 * d01);
        [(d11 * d20 - d01 * d21) * inv, (d00 * d21 - d01 * d20) * inv]
    }

    /// Albedo at barycentrics that are themselves [`Real`]s.
    pub fn albedo_at_r(&self, [b1, b2]: [R; 2]) -> R {
        self.albedo[0] * (R::c(1.0) - b1 - b2) + self.albedo[1] * b1 + self.albedo[2] * b2
    }

    pub fn albedo_at(&self, [b1, b2]: [f32; 2]) -> R {
        self.albedo[0].s(1.0 - b1 - b2) + self.albedo[1].s(b1) + self.albedo[2].s(b2)
    }

    /// Unit normal `(v1 − v0) × (v2 − v0)` normalised, and area (m²).
    pub fn normal_area(&self) -> (V3<R>, R) {
        let c = dual::cross(
            dual::sub(self.v[1], self.v[0]),
            dual::sub(self.v[2], self.v[0]),
        );
        let len = dual::length(c);
        (dual::scale(c, R::c(1.0) / len), len.s(0.5))
    }
}

/// The three-bounce contribution of the hidden point at `bary` on `t`, a triangle that
/// the area sampler picks with probability `prob`: `(weight, OPL)`, or `None` where the
/// point cannot scatter from `x_l` to `x_s` (back-facing, behind the wall, outside the
/// film). Visibility is the caller's. The weight is the integrand over
/// `pdf_area = prob / A_t`: the area of the *current* triangle, so that moving its
/// vertices scales the weight (the area factor of an attached sample, DESIGN §5) while
/// the discrete choice stays put.
#[inline]
pub fn evaluate<R: Real>(
    ctx: &MeasurementCtx,
    t: &TriParams<R>,
    bary: [f32; 2],
    prob: f32,
    x_l: Vec3,
) -> Option<(R, R)> {
    evaluate_on(ctx, t, t.normal_area(), bary, prob, x_l)
}

/// [`evaluate`] with the triangle's unit normal and area given (the primal pass reads
/// them from [`HiddenTri`]: the same numbers, computed once per triangle).
#[inline]
fn evaluate_on<R: Real>(
    ctx: &MeasurementCtx,
    t: &TriParams<R>,
    (n, area): (V3<R>, R),
    bary: [f32; 2],
    prob: f32,
    x_l: Vec3,
) -> Option<(R, R)> {
    let x = t.point(bary);
    let d_l = dual::sub(dual::constant(x_l), x);
    let d_s = dual::sub(dual::constant(ctx.x_s), x);
    let (r_l, r_s) = (dual::length(d_l), dual::length(d_s));
    // r cos θ at x toward each wall point, and at each wall point toward x.
    let (c_l, c_s) = (dual::dot(n, d_l), dual::dot(n, d_s));
    let facing = if t.two_sided {
        c_l.v() * c_s.v() > 0.0
    } else {
        c_l.v() > 0.0 && c_s.v() > 0.0
    };
    let n_w = dual::constant(ctx.n_w);
    let (cw_l, cw_s) = (-dual::dot(n_w, d_l), -dual::dot(n_w, d_s));
    // The wall is one-sided: x must be in front of both wall points.
    if !facing || cw_l.v() <= 0.0 || cw_s.v() <= 0.0 {
        return None;
    }
    let opl = r_l + r_s + R::c((ctx.opl_laser_leg(x_l) + ctx.opl_sensor_leg) as f64);
    if opl.v() < ctx.opl_min as f64 || opl.v() >= ctx.opl_max as f64 {
        return None;
    }
    // G(x_l, x) G(x, x_s) = (c_l cw_l / r_l⁴)(c_s cw_s / r_s⁴), one leg at a time: the
    // product r_l⁴ r_s⁴ overflows f32 beyond ~66 km (the render was silently zero there).
    let (r2_l, r2_s) = (r_l * r_l, r_s * r_s);
    let geometry = (c_l * cw_l / (r2_l * r2_l) * (c_s * cw_s / (r2_s * r2_s))).abs();
    let f_x = t.albedo_at(bary).s(FRAC_1_PI);
    let constant = ctx.three_bounce_constant() / prob;
    Some(((f_x * geometry * area).s(constant), opl))
}

/// The random choices of one sample: a hidden triangle and barycentrics (area sampling),
/// then a point of the laser spot. Exported as is (`umbra.mc3_samples`) so that an
/// independent implementation can evaluate exactly this estimator.
#[inline]
pub fn draw(ctx: &MeasurementCtx, sampler: &mut Sampler) -> (TriangleSample, Vec3) {
    let ts = ctx.geom.hidden_area.sample(sampler.next_2d());
    let u_spot = sampler.reserve_2d();
    let x_l = sample_spot(ctx, sampler, u_spot);
    (ts, x_l)
}

/// Draws one three-bounce sample and emits its contribution (if any) to `sink`; an
/// adjoint sink also gets the derivatives of its weight and OPL with respect to the
/// sampled triangle's corners and albedos (the sample keeps its barycentrics).
#[inline]
pub fn sample<S: Sink>(ctx: &MeasurementCtx, sampler: &mut Sampler, sink: &mut S) {
    let geom = ctx.geom;
    let (ts, x_l) = draw(ctx, sampler);
    let tri = &geom.hidden[ts.tri as usize];
    let n_area = (tri.n.to_array(), tri.area);
    let constant = TriParams::constant(tri);
    let Some((weight, opl)) = evaluate_on(ctx, &constant, n_area, ts.bary, ts.prob, x_l) else {
        return;
    };
    let x = tri.point(ts.bary);
    let blocked = |b: Vec3| ctx.occluded_touching(x, b, ts.tri);
    if weight <= 0.0 || blocked(x_l) || blocked(ctx.x_s) {
        return;
    }
    emit(ctx, &ts, x_l, opl, weight, sink);
}

/// Emits the visible contribution `(opl, weight)` of sample `ts` (spot point `x_l`); an
/// adjoint sink also gets its derivatives, by [`evaluate`] in dual numbers.
#[inline]
pub(crate) fn emit<S: Sink>(
    ctx: &MeasurementCtx,
    ts: &TriangleSample,
    x_l: Vec3,
    opl: f32,
    weight: f32,
    sink: &mut S,
) {
    let c = Contribution {
        opl,
        weight,
        bounces: 3,
    };
    if S::ADJOINT {
        let vars = TriParams::variables(&ctx.geom.hidden[ts.tri as usize]);
        if let Some((w, o)) = evaluate(ctx, &vars, ts.bary, ts.prob, x_l) {
            sink.add_grad(
                &c,
                &[HiddenGrad {
                    flat: ts.tri,
                    weight: w.d,
                    opl: o.d,
                }],
            );
        }
    } else {
        sink.add(&c);
    }
}
