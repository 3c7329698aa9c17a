//! The primal pass of [`super::mc3`] eight samples at a time (DESIGN §3, rung 2).
//!
//! The estimator is `mc3`'s, contribution for contribution: the same numbers, the same
//! triangle, the same weight and OPL, bit for bit, handed to the sink in sample order.
//! Only the evaluation order changes. For `L` consecutive samples of one measurement:
//!
//! 1. their first Sobol' pair ([`StreamSeeds::pair_lanes`]) and triangle picks
//!    ([`crate::geometry::sampling::AreaDistribution::sample_lanes`]) in lanes;
//! 2. the picked triangles' corners, normals, areas and albedos gathered into lanes;
//! 3. [`super::mc3::evaluate`]'s formula in lanes, operation for operation (`x`, both legs'
//!    lengths and cosines, the facing, wall and film tests as masks, the geometry term);
//! 4. for a planar or convex object, which shadow rays need tracing at all, in lanes
//!    ([`crate::geometry::SceneGeometry::segment_sides`]); then per live lane, in order,
//!    the shadow tests left and the sink.
//!
//! Lane arithmetic is written as loops over `[f32; L]`, each `if` a select, so that the
//! compiler turns it into vector instructions with the scalar code's rounding (IEEE
//! `+ − × ÷ √` are exactly rounded either way; no fused multiply-adds). Both passes run
//! it: an adjoint sink gets each live lane's derivatives from [`super::mc3::evaluate`] in
//! dual numbers (`mc3::emit`, as the scalar [`super::mc3::sample`] gives them).
//! The scalar routine stays the reference: the two give the same contributions and
//! derivatives, bit for bit (`tests/lanes.rs`).

use super::lanes::{albedos, at, dot, from_const, gather3, lanes, points, splat, F, LANES};
use super::{mc3, spot_point, MeasurementCtx, Sink};
use crate::geometry::sampling::TriangleSample;
use crate::geometry::HiddenTri;
use crate::rng::StreamSeeds;
use glam::Vec3;
use std::f32::consts::FRAC_1_PI;

/// Runs samples `range` of the measurement with stream seeds `seeds` into `sink`: what
/// a loop of [`mc3::sample`] over the range gives, in the same order; an adjoint sink
/// gets each contribution's derivatives as `mc3::sample` gives them (`mc3::emit`).
pub fn run<S: Sink>(
    ctx: &MeasurementCtx,
    seeds: &StreamSeeds,
    range: std::ops::Range<u32>,
    sink: &mut S,
) {
    let mut first = range.start;
    while range.end - first >= LANES as u32 {
        run_lanes(ctx, seeds, first, sink);
        first += LANES as u32;
    }
    for i in first..range.end {
        mc3::sample(ctx, &mut seeds.sampler(i), sink);
    }
}

/// Samples `first..first + LANES`.
#[inline]
fn run_lanes<S: Sink>(ctx: &MeasurementCtx, seeds: &StreamSeeds, first: u32, sink: &mut S) {
    let geom = ctx.geom;
    // `mc3::draw`: pair 0 picks the triangle and the point, pair 1 the spot's point.
    let [u0, u1] = seeds.pair_lanes::<LANES>(0, first);
    let ts = geom.hidden_area.sample_lanes(u0, u1);
    let spot: [Vec3; LANES] = if ctx.scene.laser.spot_radius > 0.0 {
        let [s0, s1] = seeds.pair_lanes::<LANES>(1, first);
        std::array::from_fn(|k| spot_point(ctx, [s0[k], s1[k]]))
    } else {
        [ctx.x_l; LANES]
    };
    let tris: [&HiddenTri; LANES] = ts.tri.map(|t| &geom.hidden[t as usize]);
    let ev = evaluate(ctx, &tris, [ts.b1, ts.b2], ts.prob, &spot);
    // Where no hidden triangle can shadow another (a planar or convex object), a shadow
    // ray is needed only where the wall separates the ends: two dot products per segment
    // in lanes. Elsewhere the lane test rarely clears and costs more than it saves
    // (measured on the arc), so each live lane runs the scalar test.
    let clear = if geom.blockers_everywhere_empty() {
        let x_l: [F; 3] = std::array::from_fn(|i| lanes(|k| spot[k][i]));
        let x_s = splat(ctx.x_s);
        Some((
            geom.segment_sides(ts.tri, &ev.x, &x_l),
            geom.segment_sides(ts.tri, &ev.x, &x_s),
        ))
    } else {
        None
    };
    for k in (0..LANES).filter(|&k| ev.live[k]) {
        let x = at(&ev.x, k);
        let blocked = match &clear {
            Some(((side_l, clear_l), (side_s, clear_s))) => {
                let on_side = |b: Vec3, side| geom.occluded_on_side(x, b, ts.tri[k], side);
                (!clear_l[k] && on_side(spot[k], side_l[k]))
                    || (!clear_s[k] && on_side(ctx.x_s, side_s[k]))
            }
            None => {
                let touching = |b: Vec3| ctx.occluded_touching(x, b, ts.tri[k]);
                touching(spot[k]) || touching(ctx.x_s)
            }
        };
        if blocked {
            continue;
        }
        let ts = TriangleSample {
            tri: ts.tri[k],
            bary: [ts.b1[k], ts.b2[k]],
            prob: ts.prob[k],
        };
        mc3::emit(ctx, &ts, spot[k], ev.opl[k], ev.weight[k], sink);
    }
}

/// `mc3::evaluate` of eight samples: the hidden points, and per lane whether the sample
/// contributes before visibility (`Some` there, with a positive weight) and its weight
/// and OPL.
struct Evaluated {
    x: [F; 3],
    live: [bool; LANES],
    weight: F,
    opl: F,
}

/// [`mc3::evaluate`] (through its `evaluate_on`, the normal and area read from the
/// triangle) in lanes, the same operations in the same order; the spot point per lane.
/// The tests are the scalar code's negations, so that a NaN passes where it passes there.
#[inline(always)]
#[allow(clippy::neg_cmp_op_on_partial_ord)]
fn evaluate(
    ctx: &MeasurementCtx,
    tris: &[&HiddenTri; LANES],
    [b1, b2]: [F; 2],
    prob: F,
    spot: &[Vec3; LANES],
) -> Evaluated {
    // `TriParams::point` and `albedo_at`.
    let (x, b0) = points(tris, [b1, b2]);
    let albedo = albedos(tris, [b1, b2], b0);
    let n = gather3(tris, |t| t.n);
    let x_l: [F; 3] = std::array::from_fn(|i| lanes(|k| spot[k][i]));
    let d_l: [F; 3] = std::array::from_fn(|i| lanes(|k| x_l[i][k] - x[i][k]));
    let d_s = from_const(ctx.x_s, &x);
    let (ll, ss) = (dot(&d_l, &d_l), dot(&d_s, &d_s));
    let (r_l, r_s) = (ll.map(f32::sqrt), ss.map(f32::sqrt));
    let (c_l, c_s) = (dot(&n, &d_l), dot(&n, &d_s));
    let n_w = splat(ctx.n_w);
    let (cw_l, cw_s) = (dot(&n_w, &d_l).map(|c| -c), dot(&n_w, &d_s).map(|c| -c));
    // The scalar code's constant OPL of the wall legs, per lane only for a finite spot.
    let legs: F = lanes(|k| ctx.opl_laser_leg(spot[k]) + ctx.opl_sensor_leg);
    let opl = lanes(|k| r_l[k] + r_s[k] + legs[k]);
    let geometry = lanes(|k| {
        let (r2_l, r2_s) = (r_l[k] * r_l[k], r_s[k] * r_s[k]);
        let g = c_l[k] * cw_l[k] / (r2_l * r2_l) * (c_s[k] * cw_s[k] / (r2_s * r2_s));
        // `Real::abs`: `-g` below zero, `g` otherwise (a zero keeps its sign).
        if g < 0.0 {
            -g
        } else {
            g
        }
    });
    let f_x = lanes(|k| albedo[k] * FRAC_1_PI);
    let area = lanes(|k| tris[k].area);
    let three_bounce = ctx.three_bounce_constant();
    let weight = lanes(|k| f_x[k] * geometry[k] * area[k] * (three_bounce / prob[k]));
    let live = std::array::from_fn(|k| {
        // The facing test on the signs: the scalar code multiplies the cosines in f64,
        // where the product of two f32s cannot underflow.
        let facing = if tris[k].two_sided {
            (c_l[k] > 0.0 && c_s[k] > 0.0) || (c_l[k] < 0.0 && c_s[k] < 0.0)
        } else {
            c_l[k] > 0.0 && c_s[k] > 0.0
        };
        let front = !(cw_l[k] <= 0.0 || cw_s[k] <= 0.0);
        let in_film = !(opl[k] < ctx.opl_min || opl[k] >= ctx.opl_max);
        facing && front && in_film && !(weight[k] <= 0.0)
    });
    Evaluated {
        x,
        live,
        weight,
        opl,
    }
}
