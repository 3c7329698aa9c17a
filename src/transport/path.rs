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
//!   local albedo (at most 0.95); `max_bounces` caps the length, `filter_bounces` keeps
//!   only paths of one length (mitransient's `filter_bounces`, in our count), and
//!   `discard_direct_paths` drops paths that never leave the wall.
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
//! **Adjoint (path replay).** The weights are written once over [`Real`]
//! ([`continuation`], [`nee`]); an adjoint sink makes the same loop carry, next to the
//! `f32` state, a state in dual numbers with respect to the corners and albedos of up to
//! [`PATH_TRIANGLES`] hidden triangles met on the path. A point drawn by area sampling
//! keeps its barycentrics; a point found by a ray keeps the ray's sampled numbers, so it
//! moves along the ray, whose direction follows the previous vertex's normal; the area
//! densities use the current triangle areas over the (fixed) triangle probabilities, and
//! the discrete choices (technique, triangle, Russian roulette) stay put: the derivative of
//! the estimator at fixed random numbers, which finite differences with common random
//! numbers check. Paths meeting more hidden triangles lose the further ones'
//! derivatives (counted; see `adjoint`). Laser sampling with a point spot only.

use super::mc3::TriParams;
use super::path_step::{
    bsdf_share, continuation, hidden_geometry_distribution, p_hg_at, step, survival,
    technique_probabilities, Surf, WalkVertex,
};
pub use super::path_step::{BSDF_SHARE_AT_HIDDEN, BSDF_SHARE_AT_WALL};
use super::{sample_spot, Contribution, HiddenGrad, MeasurementCtx, PathVertex, Sink};
use crate::adjoint::dual::{self, Dual, Real, V3};
use crate::geometry::sampling::cosine_dir;
use crate::geometry::SurfaceKind;
use crate::rng::Sampler;
use glam::Vec3;
use std::f32::consts::{FRAC_1_PI, PI};

/// Hidden triangles whose derivatives one path can carry (12 parameters each).
pub const PATH_TRIANGLES: usize = 4;

/// Dual numbers over [`PATH_TRIANGLES`] triangles' corners and albedos.
pub type PathDual = Dual<f32, 48>;

/// Reusable per-thread storage for a path's vertices (no allocation per sample).
#[derive(Default)]
pub struct PathScratch {
    /// `x_s, y_1, …, y_j` while tracing; the laser spot is pushed for each emission.
    vertices: Vec<PathVertex>,
    /// Adjoint pass: contributions whose path met more than [`PATH_TRIANGLES`] hidden
    /// triangles (their further derivatives are lost), and all contributions.
    pub truncated: u64,
    pub emitted: u64,
}

/// The vertex the path stands on (primal).
struct Vertex {
    s: Surf<f32>,
    albedo: f32,
    on_wall: bool,
}

/// `w_bsdf` of the continuation from the sensor point to hidden point `y` (on hidden
/// triangle `flat`): the visibility boundary terms (`adjoint::boundary`) weight their two
/// forms by it.
pub(crate) fn bsdf_share_from_sensor(ctx: &MeasurementCtx, y: Vec3, flat: u32) -> f32 {
    let x_s = WalkVertex::wall(ctx, ctx.x_s);
    let y = WalkVertex::hidden(ctx.geom, flat, [0.0; 2], y, ctx.x_s);
    bsdf_share(ctx, &x_s.s, true, &y)
}

/// Next-event estimation from `y` to the laser spot `x_l`:
/// `(cos θ_y cos θ_wall / r², r)`, or `None` if `x_l` is behind either surface.
fn nee<R: Real>(y: &Surf<R>, x_l: Vec3, n_w: Vec3) -> Option<(R, R)> {
    let to_l = dual::sub(dual::constant(x_l), y.p);
    let r2 = dual::dot(to_l, to_l);
    let r = r2.sqrt();
    let cos_y = dual::dot(y.n_side, to_l) / r;
    let cos_wall = -dual::dot(dual::constant(n_w), to_l) / r;
    (cos_y.v() > 0.0 && cos_wall.v() > 0.0).then(|| (cos_y * cos_wall / r2, r))
}

/// The adjoint pass's state: the path's vertex, throughput and OPL in dual numbers, and
/// which hidden triangle owns each slot group.
struct Replay {
    groups: [u32; PATH_TRIANGLES],
    used: usize,
    truncated: bool,
    x: Surf<PathDual>,
    beta: PathDual,
    opl: PathDual,
}

impl Replay {
    /// Triangle `flat` in dual numbers (its own slots; constants once the slots are full).
    fn triangle(&mut self, ctx: &MeasurementCtx, flat: u32) -> TriParams<PathDual> {
        let tri = &ctx.geom.hidden[flat as usize];
        let g = match self.groups[..self.used].iter().position(|&f| f == flat) {
            Some(g) => g,
            None if self.used < PATH_TRIANGLES => {
                self.groups[self.used] = flat;
                self.used += 1;
                self.used - 1
            }
            None => {
                self.truncated = true;
                let c = TriParams::constant(tri);
                return TriParams {
                    v: c.v.map(|v| v.map(|x| PathDual::c(x as f64))),
                    albedo: c.albedo.map(|a| PathDual::c(a as f64)),
                    two_sided: c.two_sided,
                    retro: c.retro,
                };
            }
        };
        TriParams::variables_at(tri, 12 * g)
    }

    fn grads(&self, weight: &PathDual, opl: &PathDual) -> [HiddenGrad; PATH_TRIANGLES] {
        std::array::from_fn(|g| HiddenGrad {
            flat: self.groups[g],
            weight: std::array::from_fn(|k| weight.d[12 * g + k]),
            opl: std::array::from_fn(|k| opl.d[12 * g + k]),
        })
    }
}

/// Traces one path from the sensor point and emits its contributions to `sink`.
pub fn sample<S: Sink>(
    ctx: &MeasurementCtx,
    sampler: &mut Sampler,
    scratch: &mut PathScratch,
    sink: &mut S,
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
    let spot_r = ctx.scene.laser.spot_radius;
    let spot_area = PI * spot_r * spot_r;
    let spot_radiance = if spot_r > 0.0 {
        ctx.f_wall * ctx.power / spot_area
    } else {
        0.0
    };
    let hg_dist = hidden_geometry_distribution(geom, tech);
    let n_w = ctx.n_w;
    let wall_surf = |p: Vec3| Surf {
        p: p.to_array(),
        n_side: n_w.to_array(),
        f: ctx.f_wall,
    };

    scratch.vertices.clear();
    scratch.vertices.push(ctx.wall_vertex(ctx.x_s));
    let mut x = Vertex {
        s: wall_surf(ctx.x_s),
        albedo: ctx.scene.wall.albedo,
        on_wall: true,
    };
    let mut beta = 1.0f32; // throughput up to x, without f(x)
    let mut opl = ctx.opl_sensor_leg; // OPL from the detector (or x_s) to x
    let mut hidden_seen = false;
    let mut replay = S::ADJOINT.then(|| Replay {
        groups: [0; PATH_TRIANGLES],
        used: 0,
        truncated: false,
        x: Surf {
            p: dual::constant(ctx.x_s),
            n_side: dual::constant(n_w),
            f: PathDual::c(ctx.f_wall as f64),
        },
        beta: PathDual::c(1.0),
        opl: PathDual::c(ctx.opl_sensor_leg as f64),
    });

    for j in 1u32.. {
        // y_j can at best close a path of j + 1 bounces (landing on the spot).
        if j + 1 > max_bounces {
            break;
        }
        // One stratified pair picks the technique and, rescaled, drives it.
        let [u_pick, u_2] = sampler.next_2d();
        let u_spot = sampler.next_2d();
        let u_rr = sampler.next_1d();
        let techniques = technique_probabilities(tech, x.on_wall);

        // --- continuation: sample y_j by one of the two techniques -----------------
        let Some(st) = step(ctx, &x.s, x.on_wall, [u_pick, u_2]) else {
            break;
        };
        let (by_bsdf, u_dir, back, q, p_hg) = (st.by_bsdf, st.u_dir, st.back, st.q, st.p_hg);
        let (y_p, kind, flat, bary) = (st.y.p(), st.kind, st.y.flat, st.y.bary);
        let on_wall = kind == SurfaceKind::Wall;
        beta *= st.factor;
        opl += st.dist;
        let y_vertex = PathVertex {
            p: y_p,
            kind,
            flat,
            bary,
        };

        // --- the same step in dual numbers (adjoint pass) ---------------------------
        if let Some(rp) = replay.as_mut() {
            let (y_d, n_d, f_d) = if on_wall {
                let y = if by_bsdf {
                    let (d, _) = cosine_dir(rp.x.n_side, u_dir);
                    let n = dual::constant(n_w);
                    let c = dual::constant(ctx.scene.wall.center);
                    let t = dual::dot(n, dual::sub(c, rp.x.p)) / dual::dot(n, d);
                    std::array::from_fn(|k| rp.x.p[k] + d[k] * t)
                } else {
                    dual::constant(y_p)
                };
                (y, dual::constant(n_w), PathDual::c(ctx.f_wall as f64))
            } else {
                let tri = rp.triangle(ctx, flat);
                let (n, area) = tri.normal_area();
                let (y, b) = if by_bsdf {
                    let (d, _) = cosine_dir(rp.x.n_side, u_dir);
                    let t = dual::dot(n, dual::sub(tri.v[0], rp.x.p)) / dual::dot(n, d);
                    let y: V3<PathDual> = std::array::from_fn(|k| rp.x.p[k] + d[k] * t);
                    (y, tri.barycentric_of(y))
                } else {
                    (tri.point(bary), bary.map(|b| PathDual::c(b as f64)))
                };
                let p_hg_d = PathDual::c(hg_dist.prob(flat) as f64) / area;
                let (fac, dist, _) = continuation(&rp.x, y, n, techniques, p_hg_d);
                rp.beta = rp.beta * fac;
                rp.opl = rp.opl + dist;
                let n_side = if back { n.map(|c| -c) } else { n };
                rp.x = Surf {
                    p: y,
                    n_side,
                    f: tri.albedo_at_r(b).s(FRAC_1_PI),
                };
                (y, n, rp.x.f)
            };
            if on_wall {
                let p_hg_d = PathDual::c(p_hg as f64);
                let (fac, dist, _) = continuation(&rp.x, y_d, n_d, techniques, p_hg_d);
                rp.beta = rp.beta * fac;
                rp.opl = rp.opl + dist;
                rp.x = Surf {
                    p: y_d,
                    n_side: n_d,
                    f: f_d,
                };
            }
        }

        let y = if on_wall {
            // A BSDF-sampled path landing on a finite lit spot: emission, MIS-weighted
            // against laser sampling (NEE) of the same point.
            if spot_r > 0.0
                && (y_p - ctx.x_l).length_squared() <= spot_r * spot_r
                && keep(j + 1, hidden_seen)
            {
                // Balance heuristic between the continuation (density q, whichever
                // technique drew y) and NEE (density 1/(π r²)) for this spot point.
                let w_mis = if tech.laser_sampling {
                    q / (q + 1.0 / spot_area)
                } else {
                    1.0
                };
                let total_opl = opl + ctx.opl_laser_leg(y_p);
                if total_opl >= ctx.opl_min && total_opl < ctx.opl_max {
                    emit(
                        scratch,
                        sink,
                        y_vertex,
                        total_opl,
                        beta * spot_radiance * w_mis,
                        j + 1,
                        None,
                    );
                }
            }
            Vertex {
                s: wall_surf(y_p),
                albedo: ctx.scene.wall.albedo,
                on_wall: true,
            }
        } else {
            hidden_seen = true;
            let (y_surf, albedo) = (st.y.s, st.y.albedo);
            let (f_y, n_side) = (y_surf.f, st.y.n_side());
            if tech.laser_sampling && keep(j + 2, hidden_seen) {
                let x_l = sample_spot(ctx, u_spot);
                if let Some((g, r_l)) = nee(&y_surf, x_l, n_w) {
                    let total_opl = opl + r_l + ctx.opl_laser_leg(x_l);
                    let weight = if spot_r > 0.0 {
                        let p_nee = 1.0 / spot_area;
                        // The continuation from y (a hidden vertex) could have landed
                        // on x_l too: by BSDF sampling, or by area sampling of the wall.
                        let (c_b, c_h) = technique_probabilities(tech, false);
                        let w_l = (x_l - y_p) / r_l;
                        let (cos_y_l, cos_wall_l) = (n_side.dot(w_l), -n_w.dot(w_l));
                        let q_l = c_b * cos_y_l * FRAC_1_PI * cos_wall_l / (r_l * r_l)
                            + if tech.hidden_geometry_includes_wall {
                                c_h * p_hg_at(ctx, u32::MAX, || geom.wall_tri_of(x_l))
                            } else {
                                0.0
                            };
                        let w_mis = p_nee / (p_nee + q_l);
                        beta * f_y * g * spot_radiance / p_nee * w_mis
                    } else {
                        beta * f_y * g * ctx.power * ctx.f_wall
                    };
                    let in_film = total_opl >= ctx.opl_min && total_opl < ctx.opl_max;
                    if in_film && weight > 0.0 && !geom.occluded(y_p, x_l) {
                        let grad = replay.as_ref().and_then(|rp| {
                            let (g_d, r_d) = nee(&rp.x, x_l, n_w)?;
                            let w = rp.beta * rp.x.f * g_d.s(ctx.power * ctx.f_wall);
                            let o = rp.opl + r_d + PathDual::c(ctx.opl_laser_leg(x_l) as f64);
                            Some((rp.grads(&w, &o), rp.used, rp.truncated))
                        });
                        scratch.vertices.push(y_vertex);
                        emit(
                            scratch,
                            sink,
                            ctx.wall_vertex(x_l),
                            total_opl,
                            weight,
                            j + 2,
                            grad.as_ref().map(|(g, n, t)| (&g[..*n], *t)),
                        );
                        scratch.vertices.pop();
                    }
                }
            }
            Vertex {
                s: y_surf,
                albedo,
                on_wall: false,
            }
        };

        // --- Russian roulette before extending past rr_bounces -----------------------
        if j + 2 >= r.rr_bounces {
            let survive = survival(y.albedo);
            if u_rr >= survive {
                break;
            }
            beta /= survive;
            if let Some(rp) = replay.as_mut() {
                // d survive / dθ: the albedo's where it is not clamped.
                let s = if y.albedo > 0.05 && y.albedo < 0.95 && !y.on_wall {
                    rp.x.f.s(PI)
                } else {
                    PathDual::c(survive as f64)
                };
                rp.beta = rp.beta / s;
            }
        }
        scratch.vertices.push(y_vertex);
        x = y;
    }
}

/// Emits a contribution whose last vertex (the laser spot) is `spot`; in the adjoint
/// pass with its derivatives (`None` for paths whose derivatives are not followed).
#[inline]
fn emit<S: Sink>(
    scratch: &mut PathScratch,
    sink: &mut S,
    spot: PathVertex,
    opl: f32,
    weight: f32,
    bounces: u32,
    grads: Option<(&[HiddenGrad], bool)>,
) {
    scratch.vertices.push(spot);
    let c = Contribution {
        opl,
        weight,
        bounces,
        vertices: &scratch.vertices,
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
    scratch.vertices.pop();
}
