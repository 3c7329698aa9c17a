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

use super::{sample_spot, scatter_cosines, Contribution, MeasurementCtx, PathVertex, Sink};
use crate::geometry::sampling::{cosine_hemisphere, ONE_MINUS_EPS};
use crate::geometry::SurfaceKind;
use crate::rng::Sampler;
use crate::scene::Techniques;
use glam::Vec3;
use std::f32::consts::{FRAC_1_PI, PI};

/// Reusable per-thread storage for a path's vertices (no allocation per sample).
#[derive(Default)]
pub struct PathScratch {
    /// `x_s, y_1, …, y_j` while tracing; the laser spot is pushed for each emission.
    vertices: Vec<PathVertex>,
}

/// The vertex the path stands on.
struct Vertex {
    p: Vec3,
    /// Normal on the side the path arrived from (the side light leaves from).
    n_side: Vec3,
    /// BRDF `ρ/π` at the vertex.
    f: f32,
    albedo: f32,
    on_wall: bool,
}

/// Probability of continuing by BSDF sampling at a relay-wall vertex when both
/// techniques are on. From the wall, every direction that hits anything hits hidden
/// geometry (the wall is planar), which hidden-geometry sampling reaches with far less
/// variance; BSDF sampling keeps a small share for large, close surfaces where area
/// sampling's `1/d²` is a poor match.
pub const BSDF_SHARE_AT_WALL: f32 = 0.1;
/// The same at a hidden vertex, where interreflections need both.
pub const BSDF_SHARE_AT_HIDDEN: f32 = 0.5;

/// `(c_bsdf, c_hg)`: one-sample MIS probabilities of the two continuation techniques.
fn technique_probabilities(tech: &Techniques, on_wall: bool) -> (f32, f32) {
    match (tech.bsdf_sampling, tech.hidden_geometry_sampling) {
        (true, true) => {
            let c = if on_wall {
                BSDF_SHARE_AT_WALL
            } else {
                BSDF_SHARE_AT_HIDDEN
            };
            (c, 1.0 - c)
        }
        (true, false) => (1.0, 0.0),
        _ => (0.0, 1.0),
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
    let max_bounces = r.max_bounces.min(r.filter_bounces.unwrap_or(u32::MAX));
    let keep = |bounces: u32, hidden_seen: bool| {
        bounces <= r.max_bounces
            && r.filter_bounces.is_none_or(|f| f == bounces)
            && (hidden_seen || !r.discard_direct_paths)
    };
    let spot_r = ctx.scene.laser.spot_radius;
    let spot_area = PI * spot_r * spot_r;
    let spot_radiance = if spot_r > 0.0 {
        ctx.f_wall * ctx.power / spot_area
    } else {
        0.0
    };
    let hg_dist = if tech.hidden_geometry_includes_wall {
        &geom.hidden_and_wall_area
    } else {
        &geom.hidden_area
    };
    let pdf_hg = hg_dist.pdf_area();
    let n_hidden = geom.hidden.len() as u32;

    scratch.vertices.clear();
    scratch.vertices.push(ctx.wall_vertex(ctx.x_s));
    let mut x = Vertex {
        p: ctx.x_s,
        n_side: ctx.n_w,
        f: ctx.f_wall,
        albedo: ctx.scene.wall.albedo,
        on_wall: true,
    };
    let mut beta = 1.0f32; // throughput up to x, without f(x)
    let mut opl = ctx.opl_sensor_leg; // OPL from the detector (or x_s) to x
    let mut hidden_seen = false;

    for j in 1u32.. {
        // y_j can at best close a path of j + 1 bounces (landing on the spot).
        if j + 1 > max_bounces {
            break;
        }
        // One stratified pair picks the technique and, rescaled, drives it.
        let [u_pick, u_2] = sampler.next_2d();
        let u_spot = sampler.next_2d();
        let u_rr = sampler.next_1d();
        let (c_bsdf, c_hg) = technique_probabilities(tech, x.on_wall);

        // --- continuation: sample y_j by one of the two techniques -----------------
        let (dir, dist, y_p, y_n, kind, flat, bary) = if u_pick < c_bsdf {
            let ds = cosine_hemisphere(x.n_side, [u_pick / c_bsdf, u_2]);
            let Some(hit) = geom.intersect(x.p, ds.dir) else {
                break;
            };
            (ds.dir, hit.t, hit.p, hit.n, hit.kind, hit.flat, hit.bary)
        } else {
            let u_hg = ((u_pick - c_bsdf) / c_hg).min(ONE_MINUS_EPS);
            let ts = hg_dist.sample([u_hg, u_2]);
            let (y, n, kind, flat) = if ts.tri < n_hidden {
                let tri = &geom.hidden[ts.tri as usize];
                let (object, t) = geom.flat_to_local[ts.tri as usize];
                (
                    tri.point(ts.bary),
                    tri.n,
                    SurfaceKind::Hidden { object, tri: t },
                    ts.tri,
                )
            } else {
                let [a, b, c] = geom.wall_tris[(ts.tri - n_hidden) as usize];
                let [b1, b2] = ts.bary;
                let y = (1.0 - b1 - b2) * a + b1 * b + b2 * c;
                (y, ctx.n_w, SurfaceKind::Wall, u32::MAX)
            };
            let d = y - x.p;
            let dist = d.length();
            let dir = d / dist;
            if x.n_side.dot(dir) <= 0.0 || geom.occluded(x.p, y) {
                break;
            }
            (dir, dist, y, n, kind, flat, ts.bary)
        };
        let cos_x = x.n_side.dot(dir);
        let cos_y = y_n.dot(dir).abs();
        if cos_x <= 0.0 || cos_y <= 1e-7 {
            break;
        }
        let inv_d2 = 1.0 / (dist * dist);
        let p_bsdf_area = cos_x * FRAC_1_PI * cos_y * inv_d2;
        let p_hg_area = if kind != SurfaceKind::Wall || tech.hidden_geometry_includes_wall {
            pdf_hg
        } else {
            0.0
        };
        let q = c_bsdf * p_bsdf_area + c_hg * p_hg_area;
        beta *= x.f * cos_x * cos_y * inv_d2 / q;
        opl += dist;
        let y_vertex = PathVertex {
            p: y_p,
            kind,
            flat,
            bary,
        };

        let y = match kind {
            SurfaceKind::Wall => {
                // The wall scatters only on its front.
                if y_n.dot(dir) >= 0.0 {
                    break;
                }
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
                        );
                    }
                }
                Vertex {
                    p: y_p,
                    n_side: ctx.n_w,
                    f: ctx.f_wall,
                    albedo: ctx.scene.wall.albedo,
                    on_wall: true,
                }
            }
            SurfaceKind::Hidden { .. } => {
                hidden_seen = true;
                let tri = &geom.hidden[flat as usize];
                // The side of y light arrives on; a one-sided surface hit from behind is black.
                let n_side = if y_n.dot(dir) < 0.0 { y_n } else { -y_n };
                if !tri.two_sided && n_side != y_n {
                    break;
                }
                let albedo = tri.albedo_at(bary);
                let f_y = albedo * FRAC_1_PI;
                if tech.laser_sampling && keep(j + 2, hidden_seen) {
                    let x_l = sample_spot(ctx, u_spot);
                    let to_l = x_l - y_p;
                    let r_l = to_l.length();
                    let w_l = to_l / r_l;
                    let cos_wall_l = -ctx.n_w.dot(w_l);
                    let total_opl = opl + r_l + ctx.opl_laser_leg(x_l);
                    if let (Some((_, cos_y_l)), true, true) = (
                        scatter_cosines(y_n, tri.two_sided, -dir, w_l),
                        cos_wall_l > 0.0,
                        total_opl >= ctx.opl_min && total_opl < ctx.opl_max,
                    ) {
                        let g = cos_y_l * cos_wall_l / (r_l * r_l);
                        let weight = if spot_r > 0.0 {
                            let p_nee = 1.0 / spot_area;
                            // The continuation from y (a hidden vertex) could have landed
                            // on x_l too: by BSDF sampling, or by area sampling of the wall.
                            let (c_b, c_h) = technique_probabilities(tech, false);
                            let q_l = c_b * cos_y_l * FRAC_1_PI * cos_wall_l / (r_l * r_l)
                                + if tech.hidden_geometry_includes_wall {
                                    c_h * pdf_hg
                                } else {
                                    0.0
                                };
                            let w_mis = p_nee / (p_nee + q_l);
                            beta * f_y * g * spot_radiance / p_nee * w_mis
                        } else {
                            beta * f_y * g * ctx.power * ctx.f_wall
                        };
                        if weight > 0.0 && !geom.occluded(y_p, x_l) {
                            scratch.vertices.push(y_vertex);
                            emit(
                                scratch,
                                sink,
                                ctx.wall_vertex(x_l),
                                total_opl,
                                weight,
                                j + 2,
                            );
                            scratch.vertices.pop();
                        }
                    }
                }
                Vertex {
                    p: y_p,
                    n_side,
                    f: f_y,
                    albedo,
                    on_wall: false,
                }
            }
        };

        // --- Russian roulette before extending past rr_bounces -----------------------
        if j + 2 >= r.rr_bounces {
            let survive = y.albedo.clamp(0.05, 0.95);
            if u_rr >= survive {
                break;
            }
            beta /= survive;
        }
        scratch.vertices.push(y_vertex);
        x = y;
    }
}

/// Emits a contribution whose last vertex (the laser spot) is `spot`.
#[inline]
fn emit<S: Sink>(
    scratch: &mut PathScratch,
    sink: &mut S,
    spot: PathVertex,
    opl: f32,
    weight: f32,
    bounces: u32,
) {
    scratch.vertices.push(spot);
    sink.add(&Contribution {
        opl,
        weight,
        bounces,
        vertices: &scratch.vertices,
    });
    scratch.vertices.pop();
}
