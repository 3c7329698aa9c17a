//! Visibility boundary terms of the vertex gradients (issue 18; `notes/boundary-methods.md`,
//! docs/GRADIENTS.md "Boundary terms").
//!
//! The three-bounce measurement integrates over the hidden surfaces,
//! `I_b = ∫_A F_b(x) V(x_l, x) V(x, x_s) dA(x)`. The interior derivative (path replay,
//! barycentrics held fixed) differentiates `F_b` on material points; where a shadow
//! curve of `V` crosses a surface it misses the motion of that curve. By the transport
//! theorem on the receiving surfaces, the missing part is, for each wall point `o` that
//! casts shadows (`x_l`, and `x_s` unless it is the same point) and `o'` the other,
//!
//! `∂I_b/∂θ|_bd = − Σ_E ∫_E V(o, y) F_b(x) V(x, o') J (∂y/∂θ − (r_y/r_x) ∂x_R/∂θ)·n dℓ(y)`
//!
//! over the silhouette edges `E` seen from `o` (`EdgeMesh::silhouettes`), with `x` the
//! receiver point behind the edge point `y` (first hit of the ray from `o` through `y`,
//! just on the lit side), `n` the edge's normal across the view ray toward the lit side,
//! `J = sin φ r_x² / (r_y² cos θ_x)` the receiver area per edge length and normal
//! displacement, and `∂x_R/∂θ` the receiver's material-point velocity
//! ([`super::edge::EdgePoint`]). `F_b J = C (ρ(x)/π) cos_o sin φ / r_y² · G(x, o') k_b(opl(x))`
//! with `C = P (ρ_w/π)²`: the receiver's own `r_x`, `cos θ_x` cancel, so grazing
//! receivers stay finite. The foreground (the occluder's own reflection) needs no term:
//! its domain moves with its barycentrics, which the interior term already follows. The
//! time of flight is the receiver's full OPL, through the film's kernel like the interior
//! term. With `x_l = x_s` (confocal) the two shadows coincide: one integral, `V(x, o') = 1`.
//!
//! `path` reaches its first hidden point from the sensor point by a one-sample mixture of
//! area sampling (the form above) and BSDF sampling, whose point is found by a ray and
//! slides along it when the surface moves. For the BSDF share `w_bsdf` (the balance
//! heuristic's weight) the domain is the sphere of directions at `x_s`: a silhouette seen
//! from `x_s` separates the occluder (foreground) from the receiver (background), and the
//! term is `+ w_bsdf (F J)_fg (∂y/∂θ)·n − w_bsdf (F J)_bg (∂y/∂θ)·n` (Li et al. 2018's
//! primary edges, Mitsuba 3's `ΔL`); a shadow cast from `x_l` keeps the area form with the
//! receiver's velocity along its ray from `x_s`.
//!
//! Nodes ([`super::edge_nodes`]): a deterministic midpoint rule for `tri3`; for the Monte
//! Carlo models `spp` points per wall point by systematic sampling of the silhouettes'
//! subtended angles, seeded from the seed and the wall point (same bits on any thread
//! count, unbiased). The nodes seen from one wall point (visibility `V(o, y)` and the
//! receiver hit) are computed once and shared by consecutive measurements with that
//! point (the laser spot of a `single` capture).
//!
//! The weights are detached (their derivatives are second order), so the adjoint is a
//! scatter of `a = Σ_b δH_b F_b J dℓ` along `−n`: `(1 − s)` of it to the edge's first
//! vertex, `s` to its second, and `+(r_y/r_x) β_i` to the receiver's corners.
//!
//! Supports: one- and two-sided surfaces, open and closed meshes (boundary edges, contours,
//! non-manifold edges), per-vertex albedo, all capture types, box and Gaussian kernels.
//! `path`'s paths of 4 or more bounces (shadows between hidden points, and the wall legs'
//! shadows on longer paths) are `boundary_paths`'s.
//! Does not: a finite laser spot's penumbra (the spot is taken at its centre), the laser and detector legs
//! (`visible_legs` is a step in θ: no derivative), retroreflective receivers. A mesh seam
//! (two copies of a vertex) sends an edge's share to the copies of the edge's first face.

use super::boundary_paths::LongerPaths;
use super::edge_nodes::{EdgeSet, Node, Placement, Point, ViewCache};
use crate::film::Film;
use crate::rng::Sampler;
use crate::scene::{KernelSpec, Model, Scene};
use crate::transport::{MeasurementCtx, RenderOptions};
use glam::Vec3;
use std::f32::consts::FRAC_1_PI;

/// Node spacing of `tri3`'s quadrature along an edge, in units of the kernel's width
/// (σ, or a bin for the box kernel). Half a width keeps the boundary terms within 2x the
/// interior gradient's cost on the bunny-like fit (2.2x at a quarter); the quadrature's
/// error, against the exact reference of `tests/gradient_bias.rs`, is 0.1–0.6 % of the
/// gradient (0.06–0.2 % at a quarter).
const NODE_SPACING: f32 = 0.5;

/// The boundary estimator of one gradient: the hidden meshes' edges and where to
/// evaluate along them.
pub struct Boundary {
    edges: EdgeSet,
    placement: Placement,
    /// `path` with BSDF sampling: its continuation from the sensor point mixes area and
    /// BSDF sampling, whose points move differently ([`Boundary::measurement`]).
    path_mixture: bool,
    /// `path` with paths of 4 bounces or more ([`super::boundary_paths`]).
    longer: Option<LongerPaths>,
}

/// Per-object vertex gradients (the scatter's target).
pub type VertexGrad = Vec<Vec<[f64; 3]>>;

/// Triangle-vertex pairs [`Boundary::occlusion_possible`] tests at most (a few ms).
const CONVEXITY_TEST_LIMIT: u64 = 20_000_000;

impl Boundary {
    /// For a gradient of `opts.model`: a deterministic quadrature for `tri3`, `opts.spp`
    /// sampled nodes per wall point for the Monte Carlo models ([`Placement`]).
    pub fn new(scene: &Scene, film: &Film, opts: &RenderOptions) -> Boundary {
        let width = match film.kernel {
            KernelSpec::Box => film.width,
            KernelSpec::Gaussian { sigma_opl } => sigma_opl as f64,
        } as f32;
        let placement = match opts.model {
            Model::Tri3 => Placement::Quadrature {
                spacing: NODE_SPACING * width,
            },
            _ => Placement::Sampled {
                count: opts.spp.max(1),
                seed: opts.seed,
            },
        };
        Boundary {
            edges: EdgeSet::new(scene),
            placement,
            path_mixture: opts.model == Model::Path && scene.render.techniques.bsdf_sampling,
            longer: LongerPaths::new(scene, opts),
        }
    }

    /// Whether the scene's measurements can have a boundary term at all: `false` when
    /// the path-length filter keeps only paths `model` does not have.
    pub fn applies(scene: &Scene, model: Model) -> bool {
        let r = &scene.render;
        r.filter_bounces
            .is_none_or(|f| f == 3 || (model == Model::Path && f > 3 && f <= r.max_bounces))
    }

    /// Whether a hidden triangle can hide another from the relay wall (its points, and
    /// the hidden points in between for `path`). Not when the hidden geometry lies on the
    /// boundary of its convex hull `K` (every triangle's plane has all hidden vertices on
    /// one side, its inner side) and every triangle that the wall sees from the inner side
    /// is culled (one-sided, its front outward): a point seen from the outer side of its
    /// plane is seen along a segment that stays on that side, where no other triangle is;
    /// a segment between two hidden points runs inside `K`, where none is either. That
    /// covers geometry on one plane (a ray meets a plane once) and the faces of one convex
    /// body (not a two-sided open one seen from within, nor two objects seen through the
    /// gap between them). Every boundary term is then zero, and the edge quadrature would
    /// only spend rays finding nothing behind the silhouettes (the built-in default scene,
    /// a flat letter, spent 5x its render on them; the accuracy benchmark's sphere 1.7x, for
    /// no node: measured). The wall's points are the wall rectangle, the scan grid and the
    /// laser target (all on one plane: their corners decide). Tolerance: 1e-6 of the
    /// geometry's extent. Meshes with more than `CONVEXITY_TEST_LIMIT` triangle-vertex
    /// pairs are not tested (taken as possible).
    pub fn occlusion_possible(scene: &Scene, geom: &crate::geometry::SceneGeometry) -> bool {
        use glam::DVec3;
        let Some(first) = geom.hidden.first() else {
            return false;
        };
        let mut keys: Vec<[u32; 3]> = geom
            .hidden
            .iter()
            .flat_map(|t| t.v.iter().map(|v| v.to_array().map(f32::to_bits)))
            .collect();
        keys.sort_unstable();
        keys.dedup();
        if keys.len() as u64 * geom.hidden.len() as u64 > CONVEXITY_TEST_LIMIT {
            return true;
        }
        let points: Vec<DVec3> = keys
            .iter()
            .map(|k| glam::Vec3::from_array(k.map(f32::from_bits)).as_dvec3())
            .collect();
        let scan = &scene.scan;
        let last = scan.len().saturating_sub(1);
        let corners = [
            0,
            scan.nx.saturating_sub(1) as usize,
            last + 1 - scan.nx as usize,
            last,
        ];
        let wall: Vec<DVec3> = geom
            .wall_tris
            .iter()
            .flatten()
            .copied()
            .chain(corners.map(|i| scan.point(i.min(last))))
            .chain([scene.laser.target])
            .map(|v| v.as_dvec3())
            .collect();
        let p0 = first.v[0].as_dvec3();
        let extent = points
            .iter()
            .map(|p| (*p - p0).length())
            .fold(0.0, f64::max);
        let tol = 1e-6 * extent;
        geom.hidden.iter().any(|t| {
            let (n, o) = (t.n.as_dvec3(), t.v[0].as_dvec3());
            // Signed distances' range over `ps` (along the triangle's front normal).
            let range = |ps: &[DVec3]| {
                ps.iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                        let d = n.dot(*p - o);
                        (lo.min(d), hi.max(d))
                    })
            };
            let (lo, hi) = range(&points);
            if lo >= -tol && hi <= tol {
                return false; // all on this plane: a ray meets it once
            }
            if lo < -tol && hi > tol {
                return true; // not on the hull's boundary
            }
            // The hull is behind the triangle's front (`hi <= tol`) or in front of it.
            let inner_is_back = hi <= tol;
            if inner_is_back && !t.two_sided {
                return false; // seen from within only by its culled back
            }
            let (wall_lo, wall_hi) = range(&wall);
            // Seen from the outer side only, or occlusion is possible.
            if inner_is_back {
                wall_lo <= tol
            } else {
                wall_hi >= -tol
            }
        })
    }

    /// Adds the boundary term of measurement `m` (`ctx`, adjoint histogram `adjoint`) to
    /// `grad`: the shadows cast from the laser spot and, unless the capture is confocal,
    /// from the sensor point; for `path`, also those of its longer paths.
    #[allow(clippy::too_many_arguments)]
    pub fn measurement(
        &self,
        scene: &Scene,
        ctx: &MeasurementCtx,
        m: usize,
        film: &Film,
        adjoint: &[f32],
        views: &mut ViewCache,
        grad: &mut VertexGrad,
    ) {
        let confocal = ctx.x_l == ctx.x_s;
        let keep_missing = self.path_mixture;
        let batches = self.placement.batches();
        for (slot, o, other) in [(0, ctx.x_l, ctx.x_s), (1, ctx.x_s, ctx.x_l)] {
            if slot == 1 && confocal {
                break;
            }
            for batch in 0..batches {
                let nodes = views.nodes(slot, o, batches, || {
                    self.edges
                        .nodes(ctx.geom, o, self.placement, batch, keep_missing)
                });
                let view = View {
                    o,
                    other,
                    m,
                    first: batch * super::edge_nodes::SAMPLED_BATCH,
                };
                self.evaluate(scene, ctx, film, adjoint, &nodes, view, grad);
            }
        }
        if let Some(longer) = &self.longer {
            longer.hidden_legs(scene, ctx, film, adjoint, &self.edges, m, grad);
        }
    }

    /// The terms of `nodes`, seen from `view.o`.
    #[allow(clippy::too_many_arguments)]
    fn evaluate(
        &self,
        scene: &Scene,
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        nodes: &[Node],
        view: View,
        grad: &mut VertexGrad,
    ) {
        let (o, other) = (view.o, view.other);
        // Whether a `path` continuation from the sensor point that BSDF-samples the
        // receiver sees this shadow: a shadow cast from x_s is then a change of the
        // first surface hit (foreground minus background, below); one cast from x_l
        // falls on a point that slides along its ray from x_s.
        let seen_from_sensor = o == ctx.x_s;
        for (j, node) in nodes.iter().enumerate() {
            // The longer paths' walks from this node (module `boundary_paths`).
            let mut walks = self.longer.as_ref().and_then(|l| {
                let slot = if o == ctx.x_l { 0 } else { 1 };
                Some((l, l.node_sampler(view.m, slot, view.first + j as u32)?))
            });
            if let Some(receiver) = &node.receiver {
                self.background(
                    scene, ctx, film, adjoint, node, receiver, other, &mut walks, grad,
                );
                if let (Some((l, sampler)), true) = (&mut walks, o == ctx.x_l) {
                    l.last_leg(scene, ctx, film, adjoint, receiver, node, sampler, grad);
                }
            }
            if self.path_mixture && seen_from_sensor {
                self.foreground(scene, ctx, film, adjoint, node, other, &mut walks, grad);
            }
        }
    }

    /// The receiver's part: `− F_b J (∂y/∂θ − (r_y/r_x) ∂x/∂θ)·n`, `∂x/∂θ` the velocity of
    /// the receiver point as the interior term moves it: with its material (area
    /// sampling), or along its ray from the sensor point (`path`'s BSDF-sampled share, for
    /// a shadow cast from the laser spot; for one cast from the sensor point that motion
    /// is along the view ray, normal to `n`).
    #[allow(clippy::too_many_arguments)]
    fn background(
        &self,
        scene: &Scene,
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        node: &Node,
        receiver: &Point,
        other: Vec3,
        walks: &mut Walks,
        grad: &mut VertexGrad,
    ) {
        let Some(w) = weight(ctx, film, adjoint, receiver, node, other, walks) else {
            return;
        };
        let o = node.frame.o;
        let share = self.bsdf_share(ctx, receiver) as f64;
        let motion = Motion {
            edge: -w,
            material: w * (1.0 - share),
            along_sensor_ray: if o == ctx.x_s { 0.0 } else { w * share },
        };
        scatter(scene, ctx, node, Some(receiver), motion, grad);
    }

    /// `w_bsdf` of `path`'s continuation from the sensor point at `p` (0 for the other
    /// models).
    fn bsdf_share(&self, ctx: &MeasurementCtx, p: &Point) -> f32 {
        if self.path_mixture {
            crate::transport::path::bsdf_share_from_sensor(ctx, p.x, p.flat)
        } else {
            0.0
        }
    }

    /// `path`'s BSDF-sampled continuation from the sensor point parameterises the first
    /// hidden point by direction: across a silhouette seen from `x_s`, the hit jumps from
    /// the occluder (foreground, at the edge) to the receiver. The background's part is
    /// the area term above; this adds the foreground's, `+ w_bsdf F(y) J(y) (∂y/∂θ)·n`,
    /// at the occluder's point just inside the edge.
    #[allow(clippy::too_many_arguments)]
    fn foreground(
        &self,
        scene: &Scene,
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        node: &Node,
        other: Vec3,
        walks: &mut Walks,
        grad: &mut VertexGrad,
    ) {
        let Some(fg) = super::edge_nodes::occluder_at(ctx.geom, node.frame.o, &node.frame) else {
            return;
        };
        let Some(w) = weight(ctx, film, adjoint, &fg, node, other, walks) else {
            return;
        };
        let motion = Motion {
            edge: w * self.bsdf_share(ctx, &fg) as f64,
            material: 0.0,
            along_sensor_ray: 0.0,
        };
        scatter(scene, ctx, node, None, motion, grad);
    }
}

/// How a node's weight moves the vertices: along the edge's motion (`edge` times
/// `(∂y/∂θ)·n`), with the receiver's material point (`material` times
/// `−(r_y/r_x)(∂x_R/∂θ)·n`), and with the receiver's point on its ray from the sensor
/// point (`along_sensor_ray`, the same with that point's velocity).
pub(super) struct Motion {
    edge: f64,
    material: f64,
    along_sensor_ray: f64,
}

impl Motion {
    /// The edge's motion alone.
    pub(super) fn edge(edge: f64) -> Motion {
        Motion {
            edge,
            material: 0.0,
            along_sensor_ray: 0.0,
        }
    }
}

/// A view's wall point `o`, the other wall point of the measurement, the measurement, and
/// the index of the view's first node (for the longer paths' random streams).
#[derive(Clone, Copy)]
struct View {
    o: Vec3,
    other: Vec3,
    m: usize,
    first: u32,
}

/// `path`'s longer paths, and the random numbers of one node's walks.
type Walks<'a> = Option<(&'a LongerPaths, Sampler<'a>)>;

/// `Σ_b δH_b F_b J dℓ` of the node for the hidden point `p` (its receiver, or the
/// occluder at the edge), seen from the node's wall point `o` and lit from `other`
/// (traced unless the two coincide); seen from the sensor point, `path`'s longer paths
/// through `p` too (`walks`). `None` where it adds nothing.
fn weight(
    ctx: &MeasurementCtx,
    film: &Film,
    adjoint: &[f32],
    p: &Point,
    node: &Node,
    other: Vec3,
    walks: &mut Walks,
) -> Option<f64> {
    let direct = integrand(ctx, p, node, other).map_or(0.0, |(value, opl)| {
        let a = film.adjoint_value(opl, adjoint);
        if a == 0.0 || (other != node.frame.o && ctx.geom.occluded(p.x, other)) {
            return 0.0;
        }
        a * value as f64 * node.length as f64
    });
    let longer = match walks {
        Some((l, sampler)) if node.frame.o == ctx.x_s => {
            l.first_leg(ctx, film, adjoint, p, node, sampler)
        }
        _ => 0.0,
    };
    let w = direct + longer;
    (w != 0.0 && w.is_finite()).then_some(w)
}

/// `F_b J / k_b` at the hidden point `p` behind (or at) the node, for the node's wall
/// point `o` (the shadow's) and `other`, and `p`'s OPL; `None` where `p` cannot scatter
/// between them.
fn integrand(ctx: &MeasurementCtx, p: &Point, node: &Node, other: Vec3) -> Option<(f32, f32)> {
    let o = node.frame.o;
    let tri = &ctx.geom.hidden[p.flat as usize];
    if tri.retro || ctx.scene.render.filter_bounces.is_some_and(|f| f != 3) {
        return None;
    }
    let (to_o, to_other) = (o - p.x, other - p.x);
    let (c_o, c_other) = (tri.n.dot(to_o), tri.n.dot(to_other));
    let facing = if tri.two_sided {
        c_o * c_other > 0.0
    } else {
        c_o > 0.0 && c_other > 0.0
    };
    let cw_other = -ctx.n_w.dot(to_other);
    if !facing || cw_other <= 0.0 {
        return None;
    }
    let (r_o, r_other) = (to_o.length(), to_other.length());
    let opl = r_o + r_other + ctx.opl_laser_leg(ctx.x_l) + ctx.opl_sensor_leg;
    if opl < ctx.opl_min || opl >= ctx.opl_max {
        return None;
    }
    let r2 = r_other * r_other;
    let g_other = (c_other * cw_other).abs() / (r2 * r2);
    let f_x = tri.albedo_at(p.bary) * FRAC_1_PI;
    let c = ctx.three_bounce_constant();
    Some((
        c * f_x * node.cos_o * node.frame.area_per_length() * g_other,
        opl,
    ))
}

/// Adds a node's weights to the vertices it moves ([`Motion`]): `edge (∂y/∂θ)·n` to the
/// edge's ends, `+ (r_y/r_x) β_i (material n + along_sensor_ray (d_s·n)/(n_x·d_s) n_x)` to
/// the receiver's corners (`d_s` the ray from the sensor point, `n_x` the receiver's
/// normal: a point on a fixed ray moves by `d_s (n_x·v)/(n_x·d_s)` when its plane moves
/// by `v`).
pub(super) fn scatter(
    scene: &Scene,
    ctx: &MeasurementCtx,
    node: &Node,
    receiver: Option<&Point>,
    m: Motion,
    grad: &mut VertexGrad,
) {
    let n = node.frame.n.as_dvec3();
    let mut add = |object: usize, v: u32, dir: glam::DVec3| {
        let g = &mut grad[object][v as usize];
        for (g, d) in g.iter_mut().zip(dir.to_array()) {
            *g += d;
        }
    };
    let o = node.object as usize;
    add(o, node.ends[0], m.edge * (1.0 - node.s as f64) * n);
    add(o, node.ends[1], m.edge * node.s as f64 * n);
    let Some(r) = receiver else {
        return;
    };
    let ratio = node.frame.r_y as f64 / (r.x - node.frame.o).length() as f64;
    let mut dir = m.material * n;
    if m.along_sensor_ray != 0.0 {
        let n_x = ctx.geom.hidden[r.flat as usize].n.as_dvec3();
        let d_s = (r.x - ctx.x_s).normalize().as_dvec3();
        let cos = n_x.dot(d_s);
        if cos.abs() > 1e-6 {
            dir += m.along_sensor_ray * d_s.dot(n) / cos * n_x;
        }
    }
    let (ro, rt) = ctx.geom.flat_to_local[r.flat as usize];
    let corners = scene.objects[ro as usize].mesh.triangles[rt as usize];
    let [b1, b2] = r.bary.map(|b| b as f64);
    for (v, beta) in corners.into_iter().zip([1.0 - b1 - b2, b1, b2]) {
        add(ro as usize, v, ratio * beta * dir);
    }
}
