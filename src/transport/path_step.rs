//! One step of `path`'s random walk (DESIGN §3, rung 3; [`super::path`] has the whole
//! estimator): from a vertex `x`, the next vertex `y` by one-sample multiple importance
//! sampling between BSDF sampling (cosine-weighted direction, then a ray) and
//! hidden-geometry sampling (a point by area, then a shadow ray), with the throughput
//! factor `f(x) cos θ_x cos θ_y / (|x − y|² q(y))`, `q` the mixture's area density
//! `q(y) = c_bsdf (cos θ_x/π) cos θ_y / |x − y|² + c_hg [y reachable] p_hg(y)`.
//!
//! [`step`] is the one sampling routine of the forward pass, its adjoint replay and the
//! boundary terms' walks (`adjoint::boundary_paths`), so they cannot drift; [`walk`]
//! strings steps together from any start (a hidden point toward a wall point, for the
//! boundary terms of longer paths).

use super::MeasurementCtx;
use crate::adjoint::dual::{self, Real, V3};
use crate::geometry::sampling::AreaDistribution;
use crate::geometry::sampling::{cosine_hemisphere, ONE_MINUS_EPS};
use crate::geometry::{SceneGeometry, SurfaceKind};
use crate::rng::Sampler;
use crate::scene::Techniques;
use glam::Vec3;
use std::f32::consts::FRAC_1_PI;

/// Probability of continuing by BSDF sampling at a relay-wall vertex when both
/// techniques are on. From the wall, every direction that hits anything hits hidden
/// geometry (the wall is planar), which hidden-geometry sampling reaches with far less
/// variance; BSDF sampling keeps a small share for large, close surfaces where area
/// sampling's `1/d²` is a poor match.
pub const BSDF_SHARE_AT_WALL: f32 = 0.1;
/// The same at a hidden vertex, where interreflections need both.
pub const BSDF_SHARE_AT_HIDDEN: f32 = 0.5;

/// A path vertex as the weight formulas see it.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Surf<R> {
    pub p: V3<R>,
    /// Normal on the side the path arrived from (the side light leaves from).
    pub n_side: V3<R>,
    /// BRDF `ρ/π` at the vertex.
    pub f: R,
}

/// A vertex of a walk (primal): where it is, which surface, which side.
#[derive(Clone, Copy, Debug)]
pub(crate) struct WalkVertex {
    pub s: Surf<f32>,
    pub albedo: f32,
    /// Flat hidden-triangle index; `u32::MAX` on the wall.
    pub flat: u32,
    pub bary: [f32; 2],
}

impl WalkVertex {
    pub fn on_wall(&self) -> bool {
        self.flat == u32::MAX
    }
    pub fn p(&self) -> Vec3 {
        Vec3::from_array(self.s.p)
    }
    pub fn n_side(&self) -> Vec3 {
        Vec3::from_array(self.s.n_side)
    }
    /// A point of the relay wall (normal toward the hidden scene).
    pub fn wall(ctx: &MeasurementCtx, p: Vec3) -> WalkVertex {
        WalkVertex {
            s: Surf {
                p: p.to_array(),
                n_side: ctx.n_w.to_array(),
                f: ctx.f_wall,
            },
            albedo: ctx.scene.wall.albedo,
            flat: u32::MAX,
            bary: [0.0; 2],
        }
    }
    /// Hidden point `(flat, bary)` at `p`, on the side of its triangle facing `toward`.
    pub fn hidden(geom: &SceneGeometry, flat: u32, bary: [f32; 2], p: Vec3, toward: Vec3) -> Self {
        let tri = &geom.hidden[flat as usize];
        let n = if tri.n.dot(toward - p) >= 0.0 {
            tri.n
        } else {
            -tri.n
        };
        let albedo = tri.albedo_at(bary);
        WalkVertex {
            s: Surf {
                p: p.to_array(),
                n_side: n.to_array(),
                f: albedo * FRAC_1_PI,
            },
            albedo,
            flat,
            bary,
        }
    }
}

/// `(c_bsdf, c_hg)`: one-sample MIS probabilities of the two continuation techniques.
pub(crate) fn technique_probabilities(tech: &Techniques, on_wall: bool) -> (f32, f32) {
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
pub(crate) fn hidden_geometry_distribution<'a>(
    geom: &'a SceneGeometry,
    tech: &Techniques,
) -> &'a AreaDistribution {
    if tech.hidden_geometry_includes_wall {
        &geom.hidden_and_wall_area
    } else {
        &geom.hidden_area
    }
}

/// The continuation `x → y`: the throughput factor `f(x) cos θ_x cos θ_y / (d² q(y))`,
/// the segment's length, and `q` itself (the one-sample MIS mixture's area density;
/// `p_hg` is hidden-geometry sampling's area density at `y`).
pub(crate) fn continuation<R: Real>(
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

/// Hidden-geometry sampling's area density at `y` (hidden triangle `flat`, or the wall
/// triangle `wall_tri` when `flat` is `u32::MAX`); 0 where it cannot reach `y`.
pub(crate) fn p_hg_at(ctx: &MeasurementCtx, flat: u32, wall_tri: impl FnOnce() -> u32) -> f32 {
    let (geom, tech) = (ctx.geom, &ctx.scene.render.techniques);
    let hg_dist = hidden_geometry_distribution(geom, tech);
    let n_hidden = geom.hidden.len() as u32;
    if flat != u32::MAX {
        hg_dist.prob(flat) / geom.hidden_area_of(flat)
    } else if tech.hidden_geometry_includes_wall {
        let k = wall_tri();
        let [a, b, c] = geom.wall_tris[k as usize];
        hg_dist.prob(n_hidden + k) / (0.5 * (b - a).cross(c - a).length())
    } else {
        0.0
    }
}

/// `w_bsdf`: the balance-heuristic share of the continuation `x → y` that BSDF sampling
/// makes: how much of the estimator moves `y` along its ray from `x` rather than with its
/// material. 0 when BSDF sampling is off.
pub(crate) fn bsdf_share(
    ctx: &MeasurementCtx,
    x: &Surf<f32>,
    x_on_wall: bool,
    y: &WalkVertex,
) -> f32 {
    let techniques = technique_probabilities(&ctx.scene.render.techniques, x_on_wall);
    if techniques.0 == 0.0 {
        return 0.0;
    }
    let p_hg = p_hg_at(ctx, y.flat, || ctx.geom.wall_tri_of(y.p()));
    let (_, _, q) = continuation(x, y.s.p, y.s.n_side, techniques, p_hg);
    let from_bsdf = q - techniques.1 * p_hg;
    if q > 0.0 && from_bsdf > 0.0 {
        from_bsdf / q
    } else {
        0.0
    }
}

/// Where a continuation from a vertex can have a nonzero weight (`geometry::blockers`'s
/// [`Reach`]: what rises more than `τ` in front of a hidden vertex's plane on the side the
/// path leaves).
///
/// [`Reach`]: crate::geometry::blockers::Reach
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Onward {
    /// Hidden geometry or the wall: the full step.
    Anywhere,
    /// The wall only: no hidden triangle rises in front of the vertex's plane (a planar
    /// or convex object facing the wall), so every hidden `y` has `cos θ_x ≤ 0` (up to
    /// the rounding `τ` stands for, `0/0` in the plane). [`step`] then traces BSDF
    /// samples against the wall alone and ends hidden-geometry samples of a hidden
    /// triangle; [`MeasurementCtx::past_film`] knows the next vertex is a wall point.
    WallOnly,
    /// Nothing the techniques can reach (hidden-geometry sampling alone, with nothing in
    /// front; or nothing at all in front, not even the wall): the path ends before the
    /// step is drawn.
    Nowhere,
}

/// [`Onward`] from `x`. The forward pass, its replay and the boundary terms' walks all
/// ask here before each step, and draw it with the answer.
#[inline]
pub(crate) fn onward(ctx: &MeasurementCtx, x: &WalkVertex) -> Onward {
    if x.on_wall() {
        return Onward::Anywhere;
    }
    let tech = &ctx.scene.render.techniques;
    let reach = ctx.geom.reach_from(x.flat, x.n_side());
    if reach.hidden {
        Onward::Anywhere
    } else if reach.wall && (tech.bsdf_sampling || tech.hidden_geometry_includes_wall) {
        Onward::WallOnly
    } else {
        Onward::Nowhere
    }
}

/// One sampled continuation.
#[derive(Clone, Copy)]
pub(crate) struct Step {
    pub y: WalkVertex,
    /// The surface's kind at `y`.
    pub kind: SurfaceKind,
    /// Drawn by BSDF sampling (then `u_dir` drove the direction).
    pub by_bsdf: bool,
    pub u_dir: [f32; 2],
    /// `y` is seen from the back of its surface.
    pub back: bool,
    /// Throughput factor, segment length (m), mixture area density `q` and `p_hg`.
    pub factor: f32,
    pub dist: f32,
    pub q: f32,
    pub p_hg: f32,
}

/// Samples the vertex after `x` (on the wall if `x_on_wall`; [`onward`] of it `to`) from
/// the pair `u_pick, u_2` (the pick rescaled drives the technique). `None` where the path
/// ends: nothing hit, a blocked or backward sample, a grazing hit, the back of a
/// one-sided surface or of the wall, or a hidden target from a vertex that reaches only
/// the wall.
pub(crate) fn step(
    ctx: &MeasurementCtx,
    x: &Surf<f32>,
    x_on_wall: bool,
    to: Onward,
    [u_pick, u_2]: [f32; 2],
) -> Option<Step> {
    let wall_only = to == Onward::WallOnly;
    let (geom, tech, n_w) = (ctx.geom, &ctx.scene.render.techniques, ctx.n_w);
    let hg_dist = hidden_geometry_distribution(geom, tech);
    let n_hidden = geom.hidden.len() as u32;
    let techniques = technique_probabilities(tech, x_on_wall);
    let (c_bsdf, c_hg) = techniques;
    let x_p = Vec3::from_array(x.p);
    let x_n = Vec3::from_array(x.n_side);
    let by_bsdf = u_pick < c_bsdf;
    let u_dir = [u_pick / c_bsdf.max(f32::MIN_POSITIVE), u_2];
    let (y_p, y_n, kind, flat, bary, sampled_tri) = if by_bsdf {
        let ds = cosine_hemisphere(x_n, u_dir);
        let hit = if wall_only {
            geom.intersect_wall(x_p, ds.dir)?
        } else {
            geom.intersect(x_p, ds.dir)?
        };
        (hit.p, hit.n, hit.kind, hit.flat, hit.bary, None)
    } else {
        let u_hg = ((u_pick - c_bsdf) / c_hg).min(ONE_MINUS_EPS);
        let ts = hg_dist.sample([u_hg, u_2]);
        if wall_only && ts.tri < n_hidden {
            return None;
        }
        let (y, n, kind, flat) = if ts.tri < n_hidden {
            let tri = &geom.hidden[ts.tri as usize];
            let (object, t) = geom.flat_to_local[ts.tri as usize];
            let kind = SurfaceKind::Hidden { object, tri: t };
            (tri.point(ts.bary), tri.n, kind, ts.tri)
        } else {
            let [a, b, c] = geom.wall_tris[(ts.tri - n_hidden) as usize];
            let [b1, b2] = ts.bary;
            let y = (1.0 - b1 - b2) * a + b1 * b + b2 * c;
            (y, n_w, SurfaceKind::Wall, u32::MAX)
        };
        // The cheap rejections below first: a backward or grazing sample (a point in the
        // plane of a planar x) needs no shadow ray.
        let dir = (y - x_p).normalize();
        if x_n.dot(dir) <= 0.0 || n.dot(dir).abs() <= 1e-7 {
            return None;
        }
        let blocked = if flat == u32::MAX {
            geom.occluded(x_p, y)
        } else {
            ctx.occluded_touching(x_p, y, flat)
        };
        if blocked {
            return None;
        }
        (y, n, kind, flat, ts.bary, Some(ts.tri))
    };
    let dir = (y_p - x_p).normalize();
    if x_n.dot(dir) <= 0.0 || y_n.dot(dir).abs() <= 1e-7 {
        return None;
    }
    let on_wall = kind == SurfaceKind::Wall;
    // Hidden-geometry sampling's area density at y (0 where it cannot reach y).
    let p_hg = p_hg_at(ctx, flat, || match sampled_tri {
        Some(t) => t - n_hidden,
        None => geom.wall_tri_of(y_p),
    });
    let (factor, dist, q) = continuation(x, y_p.to_array(), y_n.to_array(), techniques, p_hg);
    // Which side of y light arrives on; a one-sided surface hit from behind is black.
    let back = y_n.dot(dir) >= 0.0;
    if back && (on_wall || !geom.hidden[flat as usize].two_sided) {
        return None;
    }
    // The wall's side is its normal toward the hidden scene (as `path` keeps it).
    let n_side = if on_wall {
        n_w
    } else if back {
        -y_n
    } else {
        y_n
    };
    let (albedo, f) = if on_wall {
        (ctx.scene.wall.albedo, ctx.f_wall)
    } else {
        let a = geom.hidden[flat as usize].albedo_at(bary);
        (a, a * FRAC_1_PI)
    };
    let y = WalkVertex {
        s: Surf {
            p: y_p.to_array(),
            n_side: n_side.to_array(),
            f,
        },
        albedo,
        flat,
        bary,
    };
    Some(Step {
        y,
        kind,
        by_bsdf,
        u_dir,
        back,
        factor,
        dist,
        q,
        p_hg,
    })
}

/// Russian roulette's survival probability at a vertex of this albedo.
/// Written over [`Real`]: the replay differentiates it where the albedo is not clamped.
pub(crate) fn survival<R: Real>(albedo: R) -> R {
    if albedo.v() < 0.05 {
        R::c(0.05)
    } else if albedo.v() > 0.95 {
        R::c(0.95)
    } else {
        albedo
    }
}

/// A walk from `start` by [`step`]s, as `path` extends its paths: `visit(vertices, beta,
/// opl)` after each new vertex, `beta` the throughput from `start` to it (the factors of
/// the steps, `f` of the last vertex not included) and `opl` the length walked (m).
/// `first_bounce` is the bounce count of a path closed at `start`: the walk stops before
/// paths would pass `last_bounce`, and plays Russian roulette once they have
/// `rr_bounces`, like `path` (not its roulette before `rr_bounces`, `rr_early_survival`).
pub(crate) fn walk(
    ctx: &MeasurementCtx,
    start: WalkVertex,
    sampler: &mut Sampler,
    first_bounce: u32,
    last_bounce: u32,
    vertices: &mut Vec<WalkVertex>,
    mut visit: impl FnMut(&[WalkVertex], f32, f32),
) {
    let rr_bounces = ctx.scene.render.rr_bounces;
    vertices.clear();
    vertices.push(start);
    let (mut beta, mut opl) = (1.0f32, 0.0f32);
    for k in 1u32.. {
        let x = vertices[vertices.len() - 1];
        let to = onward(ctx, &x);
        if first_bounce + k > last_bounce || to == Onward::Nowhere {
            break;
        }
        let u = sampler.next_2d();
        let u_rr = sampler.reserve_2d();
        let Some(s) = step(ctx, &x.s, x.on_wall(), to, u) else {
            break;
        };
        beta *= s.factor;
        opl += s.dist;
        vertices.push(s.y);
        visit(vertices, beta, opl);
        if first_bounce + k >= rr_bounces {
            let survive = survival(s.y.albedo);
            if sampler.get_1d(u_rr) >= survive {
                break;
            }
            beta /= survive;
        }
    }
}
