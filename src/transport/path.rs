//! Multi-bounce NLOS path tracing (DESIGN §3, rung 3), with the seed paper's sampling
//! techniques (Royo et al., "Non-line-of-sight transient rendering"):
//!
//! - **relay-wall sensor sampling**: every path starts at the sensor point `x_s`
//!   (deterministic, no pdf), with the wall's BRDF `ρ_w/π`;
//! - **continuation** from a vertex `x` to the next vertex `y` by one-sample multiple
//!   importance sampling (balance heuristic) between *BSDF sampling* (cosine-weighted
//!   direction, then a ray cast) and *hidden-geometry sampling* (a point on the hidden
//!   meshes by area, then a shadow ray). Each is picked with probability `c_i`; the
//!   throughput is divided by the mixture's area density
//!   `q(y) = c_bsdf (cos θ_x/π) cos θ_y / |x - y|² + c_hg [y hidden] / A`,
//!   which is unbiased whenever either technique can produce `y`. The shares `c_i`
//!   depend on where `x` is ([`BSDF_SHARE_AT_WALL`], [`BSDF_SHARE_AT_HIDDEN`]);
//! - **laser sampling**: next-event estimation from every hidden vertex to the laser
//!   spot `x_l`. A point spot (`spot_radius = 0`) is a delta light: NEE is the only way
//!   to reach it, with "intensity" `P (ρ_w/π) cos θ_l`. A finite spot is a lit disk of
//!   radiance `L_e = (ρ_w/π) P / (π r²)`; then BSDF-sampled paths that land on it count
//!   too, and the two are combined by the balance heuristic (NEE area pdf `1/(π r²)`
//!   against the BSDF technique's area density at the spot point);
//! - **Russian roulette** once a path has `rr_bounces` bounces, survival probability the
//!   local albedo (at most 0.95); before that, from the first hidden vertex on, of
//!   constant survival `rr_early_survival` (by default `auto`: a pilot picks it per
//!   render, `transport::roulette`) after the vertex's own contribution is recorded; `max_bounces` caps the length, `filter_bounces` keeps
//!   only paths of one length (mitransient's `filter_bounces`, in our count), and
//!   `discard_direct_paths` drops paths that never leave the wall. A hidden vertex in
//!   front of whose plane no hidden triangle rises (a planar or convex object) continues
//!   only to the wall: BSDF samples are traced against the wall alone, hidden-geometry
//!   samples of hidden triangles end the path (their `cos θ_x ≤ 0`), and where the
//!   techniques cannot reach the wall either, the path ends before the step is drawn
//!   (`path_step::Onward`: those continuations have zero weight).
//!   A walk also ends where all it could still record lands past the film's end
//!   (`MeasurementCtx::past_film`, a lower bound on the rest of the path): the film is
//!   the same bits, the steps after are not drawn.
//!
//! The measurement contribution of a path `x_s = y_0, y_1, …, y_k, x_l` is
//! `f(y_0) G(y_0,y_1) f(y_1) … f(y_k) G(y_k, x_l) · P (ρ_w/π)` (point spot), each
//! `G(a, b) = |cos θ_a| |cos θ_b| / |a-b|²` with visibility, `f = ρ/π`; it lands at OPL
//! `Σ|y_i - y_{i+1}| + |y_k - x_l|` (plus the laser and detector legs if requested).
//! The wall scatters like any surface (paths may bounce off it mid-way); hidden-geometry
//! sampling samples it only with `hidden_geometry_includes_wall`, so with BSDF sampling
//! off and that flag off, paths through the wall (5+ bounces) are missing, as in
//! mitransient.
//!
//! Supports: all capture types, one- and two-sided Lambertian surfaces, per-vertex
//! albedo, each technique switched off alone (not BSDF and hidden-geometry sampling
//! together; not laser sampling with a point spot). Does not: non-Lambertian BRDFs,
//! participating media, a non-planar wall.
//!
//! Renders and gradients draw each path's first step eight paths at a time
//! ([`super::path_lanes`], the same steps bit for bit) and go on with `trace`.
//!
//! **Adjoint (path replay).** The weights are written once over [`Real`]
//! (`continuation` with its mixture density, `Spot`'s NEE and emission weights,
//! `survival`); an adjoint sink makes the same loop carry, next to the `f32` state, a
//! state in dual numbers with respect to the corners and albedos of up to
//! [`PATH_TRIANGLES`] hidden triangles met on the path. The dual state lags behind:
//! each step (and Russian roulette's division) is recorded and applied only when a
//! contribution needs the state, so the steps after a path's last contribution cost no
//! dual arithmetic (the same operations in the same order: the same bits). A point
//! drawn by area sampling keeps its barycentrics; a point found by a ray keeps the
//! ray's sampled numbers, so it moves along the ray, whose direction follows the
//! previous vertex's normal; the area densities use the current triangle areas over the
//! (fixed) triangle probabilities, and the discrete choices (technique, triangle,
//! Russian roulette) stay put: the derivative of the estimator at fixed random numbers,
//! which finite differences with common random numbers check. Paths meeting more hidden
//! triangles lose the further ones' derivatives (counted; see `adjoint`). A finite
//! spot's NEE point is drawn on the disk and stays put; the spot rim's boundary term (a
//! BSDF-sampled landing point crossing the rim) is not included, so gradients need
//! laser sampling on (then those paths carry the small MIS share `q/(q + 1/(π r²))`),
//! or BSDF sampling off (the gate says so).

use super::path_replay::{Deferred, NeeTarget, PathReplay, TriCache};
use super::path_step::{
    bsdf_share, onward, p_hg_at, step, survival, technique_probabilities, Onward, Step, Surf,
    WalkVertex,
};
pub use super::path_step::{BSDF_SHARE_AT_HIDDEN, BSDF_SHARE_AT_WALL};
use super::{sample_spot, Contribution, HiddenGrad, MeasurementCtx, Sink};
use crate::adjoint::dual::{self, Dual, Real};
use crate::rng::Sampler;
use glam::Vec3;
use std::f32::consts::{FRAC_1_PI, PI};

/// Hidden triangles whose derivatives one path can carry (12 parameters each).
pub const PATH_TRIANGLES: usize = 4;

/// Dual numbers over [`PATH_TRIANGLES`] triangles' corners and albedos.
pub type PathDual = Dual<f32, 48>;

/// Per-thread counters and storage of the adjoint pass (the forward pass keeps no
/// per-path storage).
#[derive(Default)]
pub struct PathScratch {
    /// Adjoint pass: contributions whose path met more than [`PATH_TRIANGLES`] hidden
    /// triangles (their further derivatives are lost), and all contributions.
    pub truncated: u64,
    pub emitted: u64,
    /// Continuations drawn from the second vertex on: from `y_1`, and from `y_2` or
    /// later (the roulette's pilot counts their cost).
    pub later_steps: [u64; 2],
    /// The replay's actions not yet applied ([`Deferred`]; one path's, reused).
    deferred: Vec<Deferred>,
    /// The replay's triangles in dual numbers ([`TriCache`]).
    tri_cache: TriCache,
}

/// `w_bsdf` of the continuation from the sensor point to hidden point `y` (on hidden
/// triangle `flat`): the visibility boundary terms (`adjoint::boundary`) weight their two
/// forms by it.
pub(crate) fn bsdf_share_from_sensor(ctx: &MeasurementCtx, y: Vec3, flat: u32) -> f32 {
    let x_s = WalkVertex::wall(ctx, ctx.x_s);
    let y = WalkVertex::hidden(ctx.geom, flat, [0.0; 2], y, ctx.x_s);
    bsdf_share(ctx, &x_s.s, true, &y)
}

/// The lit spot as the path's light (DESIGN §2). A point spot (`radius = 0`) is a delta
/// light of intensity `P ρ_w/π`, reached by next-event estimation only. A finite spot is a
/// disk of radiance `L_e = (ρ_w/π) P / (π r²)`, reached by NEE (area density
/// `p_nee = 1/(π r²)`) and by continuations that land on it (density `q`), combined by the
/// balance heuristic. Both weights are written once over [`Real`]: the forward pass runs
/// them in `f32`, the replay in dual numbers.
pub(super) struct Spot {
    radius: f32,
    /// `1/(π r²)`; 0 for a point spot.
    p_nee: f32,
    /// `L_e` (finite spot) or the intensity `P ρ_w/π` (point spot).
    emitted: f32,
    laser_sampling: bool,
}

impl Spot {
    pub(super) fn new(ctx: &MeasurementCtx) -> Spot {
        let radius = ctx.scene.laser.spot_radius;
        let lit = ctx.f_wall * ctx.power;
        let (p_nee, emitted) = if radius > 0.0 {
            let area = PI * radius * radius;
            (1.0 / area, lit / area)
        } else {
            (0.0, lit)
        };
        Spot {
            radius,
            p_nee,
            emitted,
            laser_sampling: ctx.scene.render.techniques.laser_sampling,
        }
    }

    pub(super) fn is_point(&self) -> bool {
        self.radius <= 0.0
    }

    /// Next-event estimation from hidden vertex `y` (throughput `beta` up to `y`, `f(y)`
    /// not included) to spot point `x_l`: the contribution's weight and `|y − x_l|`, or
    /// `None` if `x_l` is behind either surface. With `G = cos θ_y cos θ_wall / r²`:
    /// point spot `β f(y) G P ρ_w/π`; finite spot `β f(y) G L_e / p_nee · w_nee` with the
    /// balance weight `w_nee = p_nee / (p_nee + q_l)`, `q_l = c_bsdf G/π + c_hg p_hg(x_l)`
    /// the continuation's area density at `x_l` (`c` at a hidden vertex; `p_hg_l`, area
    /// sampling's density at the wall point, does not move with the hidden geometry).
    pub(super) fn nee<R: Real>(
        &self,
        y: &Surf<R>,
        beta: R,
        x_l: Vec3,
        n_w: Vec3,
        (c_bsdf, c_hg): (f32, f32),
        p_hg_l: f32,
    ) -> Option<(R, R)> {
        let to_l = dual::sub(dual::constant(x_l), y.p);
        let r2 = dual::dot(to_l, to_l);
        let r = r2.sqrt();
        let cos_y = dual::dot(y.n_side, to_l) / r;
        let cos_wall = -dual::dot(dual::constant(n_w), to_l) / r;
        if cos_y.v() <= 0.0 || cos_wall.v() <= 0.0 {
            return None;
        }
        let g = cos_y * cos_wall / r2;
        let light = if self.is_point() {
            R::c(self.emitted as f64)
        } else {
            let q_l = g.s(c_bsdf * FRAC_1_PI) + R::c((c_hg * p_hg_l) as f64);
            R::c(self.emitted as f64) / (q_l + R::c(self.p_nee as f64))
        };
        Some((beta * y.f * g * light, r))
    }

    /// A continuation that lands on the finite spot with mixture density `q`:
    /// `β L_e w_emit`, `w_emit = q / (q + p_nee)` when laser sampling competes, else 1.
    pub(super) fn emission<R: Real>(&self, beta: R, q: R) -> R {
        let w = if self.laser_sampling {
            q / (q + R::c(self.p_nee as f64))
        } else {
            R::c(1.0)
        };
        beta * w.s(self.emitted)
    }
}

/// Traces one path from the sensor point and emits its contributions to `sink`.
pub fn sample<S: Sink>(
    ctx: &MeasurementCtx,
    sampler: &mut Sampler,
    scratch: &mut PathScratch,
    sink: &mut S,
) {
    trace(ctx, sampler, scratch, sink, FirstStep::Draw);
}

/// How [`trace`] has its first continuation, from the sensor point.
pub(crate) enum FirstStep {
    /// Drawn here by [`step`] from the sample's first pair.
    Draw,
    /// Drawn already from the sample's first pair, as [`step`] would (`path_lanes` draws
    /// eight at a time): `None` where the path ends there. With it, where the spot is a
    /// point, next-event estimation from the drawn vertex worked out as [`Spot::nee`]
    /// would (`None` where `x_l` is behind either surface; the shadow ray is `trace`'s).
    Drawn(Option<Step>, Option<NeeValue>),
}

/// [`Spot::nee`]'s value in `f32`: the contribution's weight and `|y − x_l|`.
pub(crate) type NeeValue = Option<(f32, f32)>;

/// [`sample`], the first step given or not.
pub(crate) fn trace<S: Sink>(
    ctx: &MeasurementCtx,
    sampler: &mut Sampler,
    scratch: &mut PathScratch,
    sink: &mut S,
    first: FirstStep,
) {
    let geom = ctx.geom;
    let r = &ctx.scene.render;
    let tech = &r.techniques;
    if !tech.bsdf_sampling && !tech.hidden_geometry_sampling {
        return;
    }
    let max_bounces = r.longest_bounces();
    let keep = |bounces: u32, hidden_seen: bool| {
        r.keeps_bounces(bounces) && (hidden_seen || !r.discard_direct_paths)
    };
    let spot = Spot::new(ctx);
    let n_w = ctx.n_w;

    let mut x = WalkVertex::wall(ctx, ctx.x_s);
    let mut beta = 1.0f32; // throughput up to x, without f(x)
    let mut opl = ctx.opl_sensor_leg; // OPL from the detector (or x_s) to x
    let mut hidden_seen = false;
    let mut replay = S::ADJOINT.then(|| PathReplay::new(ctx));
    scratch.deferred.clear();

    // The shortest path y_j can close: j + 1 bounces by landing on a finite spot; a point
    // spot is reached only by next-event estimation from y_j, j + 2 bounces. A vertex
    // that can close no kept path is not traced (a three-bounce render stops at y_1).
    let closing = if spot.is_point() { 2 } else { 1 };
    let mut first = Some(first);
    let mut given_nee = None;
    for j in 1u32.. {
        let to = onward(ctx, &x);
        if j + closing > max_bounces
            || to == Onward::Nowhere
            || ctx.past_film(opl, x.p(), x.on_wall(), to == Onward::WallOnly)
        {
            break;
        }
        // --- continuation: sample y_j by one of the two techniques -----------------
        // One stratified pair picks the technique and, rescaled, drives it.
        let st = match first.take() {
            Some(FirstStep::Drawn(st, nee)) => {
                sampler.reserve_2d();
                given_nee = nee;
                st
            }
            _ => {
                if j >= 2 {
                    scratch.later_steps[usize::from(j >= 3)] += 1;
                }
                step(ctx, &x.s, x.on_wall(), to, sampler.next_2d())
            }
        };
        // Set aside, read only where needed (a finite spot; Russian roulette).
        let u_spot = sampler.reserve_2d();
        let u_rr = sampler.reserve_2d();
        let techniques = technique_probabilities(tech, x.on_wall());
        let Some(st) = st else {
            break;
        };
        beta *= st.factor;
        opl += st.dist;
        let y = st.y;
        // The first vertex's NEE value if `path_lanes` worked it out (only ever for y_1).
        let lane_nee = given_nee.take();
        if replay.is_some() {
            scratch.deferred.push(Deferred::Step(st, techniques));
        }

        if y.on_wall() {
            // A continuation landing on a finite lit spot: emission, MIS-weighted against
            // laser sampling (NEE) of the same point.
            if !spot.is_point()
                && (y.p() - ctx.x_l).length_squared() <= spot.radius * spot.radius
                && keep(j + 1, hidden_seen)
            {
                let total_opl = opl + ctx.opl_laser_leg(y.p());
                if total_opl >= ctx.opl_min && total_opl < ctx.opl_max {
                    let grad = replay.as_mut().map(|rp| {
                        rp.catch_up(ctx, &mut scratch.deferred, &mut scratch.tri_cache);
                        rp.emission(ctx, &spot)
                    });
                    emit(
                        scratch,
                        sink,
                        total_opl,
                        spot.emission(beta, st.q),
                        j + 1,
                        grad.as_ref().map(|(g, n, t)| (&g[..*n], *t)),
                    );
                }
            }
        } else {
            hidden_seen = true;
            if tech.laser_sampling && keep(j + 2, hidden_seen) {
                let x_l = sample_spot(ctx, sampler, u_spot);
                // The continuation from y (a hidden vertex) could land on x_l too: by
                // BSDF sampling, or by area sampling of the wall.
                let from_y = technique_probabilities(tech, false);
                let p_hg_l = if spot.is_point() || !tech.hidden_geometry_includes_wall {
                    0.0
                } else {
                    p_hg_at(ctx, u32::MAX, || geom.wall_tri_of(x_l))
                };
                let nee = match lane_nee {
                    Some(v) => v,
                    None => spot.nee(&y.s, beta, x_l, n_w, from_y, p_hg_l),
                };
                if let Some((weight, r_l)) = nee {
                    let total_opl = opl + r_l + ctx.opl_laser_leg(x_l);
                    let in_film = total_opl >= ctx.opl_min && total_opl < ctx.opl_max;
                    if in_film && weight > 0.0 && !ctx.occluded_touching(y.p(), x_l, y.flat) {
                        let grad = replay.as_mut().and_then(|rp| {
                            rp.catch_up(ctx, &mut scratch.deferred, &mut scratch.tri_cache);
                            let at = NeeTarget {
                                x_l,
                                from_y,
                                p_hg_l,
                            };
                            rp.nee(ctx, &spot, &at)
                        });
                        emit(
                            scratch,
                            sink,
                            total_opl,
                            weight,
                            j + 2,
                            grad.as_ref().map(|(g, n, t)| (&g[..*n], *t)),
                        );
                    }
                }
            }
        }

        // --- Russian roulette before extending: by albedo from rr_bounces on, of
        // constant survival before (the recorded terms above keep every sample) ------
        if j + 2 >= r.rr_bounces {
            let survive = survival(y.albedo);
            if sampler.get_1d(u_rr) >= survive {
                break;
            }
            beta /= survive;
            if replay.is_some() {
                let wall_albedo = y.on_wall().then_some(y.albedo);
                scratch.deferred.push(Deferred::Survive(wall_albedo));
            }
        } else if ctx.rr_early_survival < 1.0 {
            let survive = ctx.rr_early_survival;
            if sampler.get_1d(u_rr) >= survive {
                break;
            }
            beta /= survive;
            if replay.is_some() {
                scratch.deferred.push(Deferred::SurviveConstant(survive));
            }
        }
        x = y;
    }
}

/// Emits a contribution; in the adjoint pass with its derivatives (`None` for paths
/// whose derivatives are not followed).
#[inline]
fn emit<S: Sink>(
    scratch: &mut PathScratch,
    sink: &mut S,
    opl: f32,
    weight: f32,
    bounces: u32,
    grads: Option<(&[HiddenGrad], bool)>,
) {
    let c = Contribution {
        opl,
        weight,
        bounces,
    };
    if S::ADJOINT {
        scratch.emitted += 1;
        if let Some((g, truncated)) = grads {
            scratch.truncated += truncated as u64;
            sink.add_grad(&c, g);
        }
    } else {
        sink.add(&c);
    }
}
