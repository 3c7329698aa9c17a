//! The primal pass of [`super::path`] with each path's first step drawn eight at a time
//! (DESIGN §3, rung 3).
//!
//! A path's first continuation leaves the sensor point `x_s`, the same vertex for every
//! sample of a measurement. Where hidden-geometry sampling draws it (the pick
//! `u ≥ c_bsdf` and a hidden triangle, not the wall), it is `mc3`'s kind of work: the
//! pick and the point on the triangle, the direction and its two cosines, the shadow
//! ray, the throughput factor `f(x_s) cos θ_x cos θ_y / (d² q(y))`. For eight consecutive
//! samples this module does it in lanes, operation for operation as
//! `path_step::step` does it, and hands each path, in sample order, to
//! `path::trace` with its first step already drawn; `trace` goes on from there
//! (next-event estimation to the laser spot, Russian roulette, the further bounces) with
//! the scalar code. A lane that BSDF sampling draws, or that picks a wall triangle, is
//! drawn by `trace` itself.
//!
//! So the contributions are the scalar pass's, bit for bit and in the same order
//! (`tests/lanes.rs`). The adjoint pass runs this pass too: its replay starts from the
//! drawn `Step` (an area-sampled point keeps its barycentrics), as it starts from the
//! step `trace` draws, so the derivatives are the scalar [`super::path::sample`]'s.

use super::lanes::{
    albedos, at, dot, from_const, gather3, lanes, minus_const, points, splat, F, LANES,
};
use super::path::{self, FirstStep, NeeValue, PathScratch};
use super::path_step::{
    hidden_geometry_distribution, technique_probabilities, Step, Surf, WalkVertex,
};
use super::{MeasurementCtx, Sink};
use crate::geometry::sampling::ONE_MINUS_EPS;
use crate::geometry::{HiddenTri, SurfaceKind};
use crate::rng::StreamSeeds;
use std::f32::consts::FRAC_1_PI;

/// Runs samples `range` of the measurement with stream seeds `seeds` into `sink`: what
/// a loop of [`path::sample`] over the range gives, in the same order (derivatives too,
/// for an adjoint sink).
pub fn run<S: Sink>(
    ctx: &MeasurementCtx,
    seeds: &StreamSeeds,
    range: std::ops::Range<u32>,
    scratch: &mut PathScratch,
    sink: &mut S,
) {
    let mut first = range.start;
    if first_steps_in_lanes(ctx) {
        while range.end - first >= LANES as u32 {
            let steps = first_steps(ctx, seeds, first);
            for (k, st) in steps.into_iter().enumerate() {
                let mut sampler = seeds.sampler(first + k as u32);
                path::trace(ctx, &mut sampler, scratch, sink, st);
            }
            first += LANES as u32;
        }
    }
    for i in first..range.end {
        path::sample(ctx, &mut seeds.sampler(i), scratch, sink);
    }
}

/// Whether `trace` draws a first step at all, by hidden-geometry sampling some of the
/// time, from a distribution with hidden triangles in it.
fn first_steps_in_lanes(ctx: &MeasurementCtx) -> bool {
    let r = &ctx.scene.render;
    let tech = &r.techniques;
    // The shortest path the first vertex can close, `trace`'s `closing`: `trace` draws
    // the vertex only if `1 + closing` bounces are kept.
    let closing = if ctx.scene.laser.spot_radius > 0.0 {
        1
    } else {
        2
    };
    tech.hidden_geometry_sampling
        && closing < r.longest_bounces()
        && !ctx.geom.hidden.is_empty()
        && !hidden_geometry_distribution(ctx.geom, tech).is_empty()
}

/// The first steps of samples `first..first + LANES`: [`path_step::step`] from the
/// sensor point with each sample's first pair, for the lanes that hidden-geometry
/// sampling draws on a hidden triangle; `FirstStep::Draw` for the others.
///
/// [`path_step::step`]: super::path_step::step
#[inline(always)]
fn first_steps(ctx: &MeasurementCtx, seeds: &StreamSeeds, first: u32) -> [FirstStep; LANES] {
    let (geom, tech) = (ctx.geom, &ctx.scene.render.techniques);
    let hg_dist = hidden_geometry_distribution(geom, tech);
    let n_hidden = geom.hidden.len() as u32;
    let techniques = technique_probabilities(tech, true);
    let (c_bsdf, c_hg) = techniques;
    let x = WalkVertex::wall(ctx, ctx.x_s);
    let (x_p, x_n) = (ctx.x_s, ctx.n_w);
    let point_spot = ctx.scene.laser.spot_radius <= 0.0;

    let [u_pick, u_2] = seeds.pair_lanes::<LANES>(0, first);
    let u_hg = lanes(|k| {
        let u = (u_pick[k] - c_bsdf) / c_hg;
        if u < ONE_MINUS_EPS {
            u
        } else {
            ONE_MINUS_EPS
        }
    });
    let ts = hg_dist.sample_lanes(u_hg, u_2);
    let drawn: [bool; LANES] = std::array::from_fn(|k| u_pick[k] >= c_bsdf && ts.tri[k] < n_hidden);
    // Lanes drawn elsewhere compute on triangle 0 and are dropped.
    let flat: [u32; LANES] = std::array::from_fn(|k| if drawn[k] { ts.tri[k] } else { 0 });
    let tris: [&HiddenTri; LANES] = flat.map(|t| &geom.hidden[t as usize]);
    let (y, b0) = points(&tris, [ts.b1, ts.b2]);
    let n = gather3(&tris, |t| t.n);

    // `(y − x).normalize()`: times `1 / |y − x|`.
    let d = minus_const(&y, x_p);
    let d2 = dot(&d, &d);
    let dist = d2.map(f32::sqrt);
    let inv = dist.map(|l| 1.0 / l);
    let dir: [F; 3] = std::array::from_fn(|i| lanes(|k| d[i][k] * inv[k]));
    let x_nl = splat(x_n);
    let (x_dot, n_dot) = (dot(&x_nl, &dir), dot(&n, &dir));
    let forward: [bool; LANES] =
        std::array::from_fn(|k| !(x_dot[k] <= 0.0 || n_dot[k].abs() <= 1e-7));

    // The shadow ray `x_s → y`, in lanes where no hidden triangle shadows another.
    let x_pl = splat(x_p);
    let sides = geom
        .blockers_everywhere_empty()
        .then(|| geom.segment_sides(flat, &x_pl, &y));

    // `continuation(x, y, n, techniques, p_hg)`, `d` and `d²` as above.
    let cos_x = lanes(|k| dot(&x_nl, &d)[k] / dist[k]);
    let dn = dot(&n, &d);
    let cos_y = lanes(|k| {
        let c = dn[k] / dist[k];
        // `Real::abs`: a zero keeps its sign.
        if c < 0.0 {
            -c
        } else {
            c
        }
    });
    let p_hg = lanes(|k| hg_dist.prob(flat[k]) / geom.hidden_area_of(flat[k]));
    let q = lanes(|k| {
        let p_bsdf = cos_x[k] * FRAC_1_PI * cos_y[k] / d2[k];
        p_bsdf * c_bsdf + p_hg[k] * c_hg
    });
    let factor = lanes(|k| x.s.f * cos_x[k] * cos_y[k] / (d2[k] * q[k]));
    let albedo = albedos(&tris, [ts.b1, ts.b2], b0);
    let back: [bool; LANES] = std::array::from_fn(|k| n_dot[k] >= 0.0);
    let n_side: [F; 3] =
        std::array::from_fn(|i| lanes(|k| if back[k] { -n[i][k] } else { n[i][k] }));
    let nee = point_spot.then(|| nee_lanes(ctx, &y, &n_side, factor, albedo));

    std::array::from_fn(|k| {
        if !drawn[k] {
            return FirstStep::Draw;
        }
        if !forward[k] {
            return FirstStep::Drawn(None, None);
        }
        let blocked = match &sides {
            Some((side, clear)) => {
                !clear[k] && geom.occluded_on_side(x_p, at(&y, k), flat[k], side[k])
            }
            None => ctx.occluded_touching(x_p, at(&y, k), flat[k]),
        };
        if blocked {
            return FirstStep::Drawn(None, None);
        }
        // Which side of y light arrives on; a one-sided surface hit from behind is black.
        if back[k] && !tris[k].two_sided {
            return FirstStep::Drawn(None, None);
        }
        let (object, tri) = geom.flat_to_local[flat[k] as usize];
        FirstStep::Drawn(
            Some(Step {
                y: WalkVertex {
                    s: Surf {
                        p: at(&y, k).to_array(),
                        n_side: at(&n_side, k).to_array(),
                        f: albedo[k] * FRAC_1_PI,
                    },
                    albedo: albedo[k],
                    flat: flat[k],
                    bary: [ts.b1[k], ts.b2[k]],
                },
                kind: SurfaceKind::Hidden { object, tri },
                by_bsdf: false,
                u_dir: [u_pick[k] / c_bsdf.max(f32::MIN_POSITIVE), u_2[k]],
                back: back[k],
                factor: factor[k],
                dist: dist[k],
                q: q[k],
                p_hg: p_hg[k],
            }),
            nee.map(|v| v[k]),
        )
    })
}

/// `Spot::nee` from the drawn points `y` (sides `n_side`, BRDF `albedo/π`, throughput
/// `1 · factor`) to a point spot, in lanes, operation for operation: `to_l = x_l − y`,
/// `r = √(to_l · to_l)`, `cos θ_y = n_side · to_l / r`, `cos θ_l = −(n_w · to_l) / r`, and
/// where both are positive `β f G P ρ_w/π` with `G = cos θ_y cos θ_l / r²`.
#[inline(always)]
fn nee_lanes(
    ctx: &MeasurementCtx,
    y: &[F; 3],
    n_side: &[F; 3],
    factor: F,
    albedo: F,
) -> [NeeValue; LANES] {
    let to_l = from_const(ctx.x_l, y);
    let r2 = dot(&to_l, &to_l);
    let r = r2.map(f32::sqrt);
    let n_side_dot = dot(n_side, &to_l);
    let wall_dot = dot(&splat(ctx.n_w), &to_l);
    let cos_y = lanes(|k| n_side_dot[k] / r[k]);
    let cos_wall = lanes(|k| -wall_dot[k] / r[k]);
    // `Spot::emitted` of a point spot.
    let emitted = ctx.f_wall * ctx.power;
    let weight = lanes(|k| {
        let beta = 1.0f32 * factor[k];
        let g = cos_y[k] * cos_wall[k] / r2[k];
        beta * (albedo[k] * FRAC_1_PI) * g * emitted
    });
    std::array::from_fn(|k| (!(cos_y[k] <= 0.0 || cos_wall[k] <= 0.0)).then_some((weight[k], r[k])))
}
