//! Monte Carlo three-bounce estimator with hidden-geometry area sampling (DESIGN §3,
//! rung 2).
//!
//! For laser spot `x_l` and sensor point `x_s`, the three-bounce measurement is
//!
//! `H(x_s) = P(x_l) (ρ_w/π) ∫_A (ρ(x)/π) G(x_l, x) V(x_l, x) G(x, x_s) V(x, x_s) dA(x) (ρ_w/π)`
//!
//! with `G(a, b) = cos θ_a cos θ_b / |a - b|²`. One sample picks a hidden point `x` with
//! `pdf_area = 1/A` (a triangle by area, uniform barycentrics) and contributes the
//! integrand over the pdf at OPL `|x_l - x| + |x - x_s|`. Exact visibility: two shadow
//! rays. A finite laser spot is sampled uniformly (its power `P` spread over the disk).
//!
//! Supports: all capture types, one- and two-sided surfaces, per-vertex albedo.
//! Does not: interreflections (see `path`), or paths through the wall.

use super::{sample_spot, scatter_cosines, Contribution, MeasurementCtx, PathVertex, Sink};
use crate::geometry::SurfaceKind;
use crate::rng::Sampler;
use std::f32::consts::FRAC_1_PI;

/// Draws one three-bounce sample and emits its contribution (if any) to `sink`.
#[inline]
pub fn sample<S: Sink>(ctx: &MeasurementCtx, sampler: &mut Sampler, sink: &mut S) {
    let geom = ctx.geom;
    let ts = geom.hidden_area.sample(sampler.next_2d());
    let u_spot = sampler.next_2d();
    let tri = &geom.hidden[ts.tri as usize];
    let x = tri.point(ts.bary);
    let x_l = sample_spot(ctx, u_spot);

    let d_l = x_l - x;
    let r_l = d_l.length();
    let d_s = ctx.x_s - x;
    let r_s = d_s.length();
    let (w_l, w_s) = (d_l / r_l, d_s / r_s);
    let Some((cos_x_l, cos_x_s)) = scatter_cosines(tri.n, tri.two_sided, w_l, w_s) else {
        return;
    };
    // The wall is one-sided: x must be in front of both wall points.
    let cos_wall_l = -ctx.n_w.dot(w_l);
    let cos_wall_s = -ctx.n_w.dot(w_s);
    if cos_wall_l <= 0.0 || cos_wall_s <= 0.0 {
        return;
    }
    let opl = r_l + r_s + ctx.opl_laser_leg(x_l) + ctx.opl_sensor_leg;
    if opl < ctx.opl_min || opl >= ctx.opl_max {
        return;
    }
    let g_l = cos_wall_l * cos_x_l / (r_l * r_l);
    let g_s = cos_x_s * cos_wall_s / (r_s * r_s);
    let f_x = tri.albedo_at(ts.bary) * FRAC_1_PI;
    let weight = ctx.power * ctx.f_wall * f_x * g_l * g_s * ctx.f_wall / ts.pdf_area;
    if weight <= 0.0 || geom.occluded(x, x_l) || geom.occluded(x, ctx.x_s) {
        return;
    }
    let vertices = [
        ctx.wall_vertex(ctx.x_s),
        PathVertex {
            p: x,
            kind: SurfaceKind::Hidden {
                object: geom.flat_to_local[ts.tri as usize].0,
                tri: geom.flat_to_local[ts.tri as usize].1,
            },
            flat: ts.tri,
            bary: ts.bary,
        },
        ctx.wall_vertex(x_l),
    ];
    sink.add(&Contribution {
        opl,
        weight,
        bounces: 3,
        vertices: &vertices,
    });
}
