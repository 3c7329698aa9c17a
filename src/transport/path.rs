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
use super::{sample_spot, Contribution, HiddenGrad, MeasurementCtx, PathVertex, Sink};
use crate::adjoint::dual::{self, Dual, Real, V3};
use crate::geometry::sampling::AreaDistribution;
use crate::geometry::sampling::{cosine_dir, cosine_hemisphere, ONE_MINUS_EPS};
use crate::geometry::{SceneGeometry, SurfaceKind};
use crate::rng::Sampler;
use crate::scene::Techniques;
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

/// A path vertex as the weight formulas see it.
#[derive(Clone, Copy, Debug)]
struct Surf<R> {
    p: V3<R>,
    /// Normal on the side the path arrived from (the side light leaves from).
    n_side: V3<R>,
    /// BRDF `ρ/π` at the vertex.
    f: R,
}

/// The vertex the path stands on (primal).
struct Vertex {
    s: Surf<f32>,
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

/// What hidden-geometry sampling draws from: the hidden surfaces, and the wall with
/// `hidden_geometry_includes_wall`.
fn hidden_geometry_distribution<'a>(
    geom: &'a SceneGeometry,
    tech: &Techniques,
) -> &'a AreaDistribution {
    if tech.hidden_geometry_includes_wall {
        &geom.hidden_and_wall_area
    } else {
        &geom.hidden_area
    }
}

/// `w_bsdf`: the balance-heuristic share of the continuation from the sensor point that
/// reaches hidden point `y` (on hidden triangle `flat`) by BSDF sampling: the same
/// mixture density [`continuation`] divides by. 0 when BSDF sampling is off. The
/// visibility boundary terms (`adjoint::boundary`) weight their two forms by it.
pub(crate) fn bsdf_share_from_sensor(ctx: &MeasurementCtx, y: Vec3, flat: u32) -> f32 {
    let (geom, tech) = (ctx.geom, &ctx.scene.render.techniques);
    let techniques = technique_probabilities(tech, true);
    if techniques.0 == 0.0 {
        return 0.0;
    }
    let p_hg = hidden_geometry_distribution(geom, tech).prob(flat) / geom.hidden_area_of(flat);
    let x_s = Surf {
        p: ctx.x_s.to_array(),
        n_side: ctx.n_w.to_array(),
        f: ctx.f_wall,
    };
    let n_y = geom.hidden[flat as usize].n.to_array();
    let (_, _, q) = continuation(&x_s, y.to_array(), n_y, techniques, p_hg);
    let from_bsdf = q - techniques.1 * p_hg;
    if q > 0.0 && from_bsdf > 0.0 {
        from_bsdf / q
    } else {
        0.0
    }
}

/// The continuation `x → y`: the throughput factor `f(x) cos θ_x cos θ_y / (d² q(y))`,
/// the segment's length, and `q` itself (the one-sample MIS mixture's area density;
/// `p_hg` is hidden-geometry sampling's area density at `y`).
fn continuation<R: Real>(
    x: &Surf<R>,
    y_p: V3<R>,
    y_n: V3<R>,
    (c_bsdf, c_hg): (f32, f32),
    p_hg: R,
) -> (R, R, R) {
    let d = dual::sub(y_p, x.p);
    let d2 = dual::dot(d, d);
    let dist = d2.sqrt();
    let cos_x = dual::dot(x.n_side, d) / dist;
    let cos_y = (dual::dot(y_n, d) / dist).abs();
    let p_bsdf = cos_x.s(FRAC_1_PI) * cos_y / d2;
    let q = p_bsdf.s(c_bsdf) + p_hg.s(c_hg);
    (x.f * cos_x * cos_y / (d2 * q), dist, q)
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
    let hg_dist = hidden_geometry_distribution(geom, tech);
    let n_hidden = geom.hidden.len() as u32;
    // Hidden-geometry sampling's area density at a point of a wall triangle.
    let wall_pdf = |k: u32| {
        let [a, b, c] = geom.wall_tris[k as usize];
        hg_dist.prob(n_hidden + k) / (0.5 * (b - a).cross(c - a).length())
    };
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
        let (c_bsdf, c_hg) = techniques;
        let x_p = Vec3::from_array(x.s.p);
        let x_n = Vec3::from_array(x.s.n_side);

        // --- continuation: sample y_j by one of the two techniques -----------------
        let by_bsdf = u_pick < c_bsdf;
        let u_dir = [u_pick / c_bsdf.max(f32::MIN_POSITIVE), u_2];
        let (y_p, y_n, kind, flat, bary, sampled_tri) = if by_bsdf {
            let ds = cosine_hemisphere(x_n, u_dir);
            let Some(hit) = geom.intersect(x_p, ds.dir) else {
                break;
            };
            (hit.p, hit.n, hit.kind, hit.flat, hit.bary, None)
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
                (y, n_w, SurfaceKind::Wall, u32::MAX)
            };
            let dir = (y - x_p).normalize();
            if x_n.dot(dir) <= 0.0 || geom.occluded(x_p, y) {
                break;
            }
            (y, n, kind, flat, ts.bary, Some(ts.tri))
        };
        let dir = (y_p - x_p).normalize();
        if x_n.dot(dir) <= 0.0 || y_n.dot(dir).abs() <= 1e-7 {
            break;
        }
        let on_wall = kind == SurfaceKind::Wall;
        // Hidden-geometry sampling's area density at y (0 where it cannot reach y).
        let p_hg = if !on_wall {
            hg_dist.prob(flat) / geom.hidden_area_of(flat)
        } else if tech.hidden_geometry_includes_wall {
            let k = match sampled_tri {
                Some(t) => t - n_hidden,
                None => geom.wall_tri_of(y_p),
            };
            wall_pdf(k)
        } else {
            0.0
        };
        let (factor, dist, q) =
            continuation(&x.s, y_p.to_array(), y_n.to_array(), techniques, p_hg);
        beta *= factor;
        opl += dist;
        let y_vertex = PathVertex {
            p: y_p,
            kind,
            flat,
            bary,
        };
        // Which side of y light arrives on; a one-sided surface hit from behind is black.
        let back = y_n.dot(dir) >= 0.0;
        if on_wall && back {
            break;
        }
        if !on_wall && back && !geom.hidden[flat as usize].two_sided {
            break;
        }

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
            let tri = &geom.hidden[flat as usize];
            let albedo = tri.albedo_at(bary);
            let f_y = albedo * FRAC_1_PI;
            let n_side = if back { -y_n } else { y_n };
            let y_surf = Surf {
                p: y_p.to_array(),
                n_side: n_side.to_array(),
                f: f_y,
            };
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
                                c_h * wall_pdf(geom.wall_tri_of(x_l))
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
            let survive = y.albedo.clamp(0.05, 0.95);
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
