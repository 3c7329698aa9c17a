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
//! over the silhouette edges `E` seen from `o` ([`EdgeMesh::silhouettes`]), with `x` the
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
//! The edge integral is a deterministic midpoint rule: nodes spaced a quarter of the
//! kernel's width (`σ`, or a bin for the box kernel) along each edge, at most
//! [`MAX_NODES_PER_EDGE`]. No random numbers: same bits on any thread count, and the same
//! term whether the interior estimator is `tri3`, `mc3` or `path`. The nodes seen from one
//! wall point (visibility `V(o, y)` and the receiver hit) are computed once and shared by
//! consecutive measurements with that point (the laser spot of a `single` capture).
//!
//! The weights are detached (their derivatives are second order), so the adjoint is a
//! scatter of `a = Σ_b δH_b F_b J dℓ` along `−n`: `(1 − s)` of it to the edge's first
//! vertex, `s` to its second, and `+(r_y/r_x) β_i` to the receiver's corners.
//!
//! Supports: one- and two-sided surfaces, open and closed meshes (boundary edges, contours,
//! non-manifold edges), per-vertex albedo, all capture types, box and Gaussian kernels.
//! Does not: shadows between hidden points (paths of 5 or more bounces in `path`), a finite
//! laser spot's penumbra (the spot is taken at its centre), the laser and detector legs
//! (`visible_legs` is a step in θ: no derivative), retroreflective receivers. A mesh seam
//! (two copies of a vertex) sends an edge's share to the copies of the edge's first face.

use super::edge::EdgePoint;
use crate::film::Film;
use crate::geometry::silhouette::EdgeMesh;
use crate::geometry::{SceneGeometry, SurfaceKind};
use crate::scene::{KernelSpec, Model, Scene};
use crate::transport::MeasurementCtx;
use glam::Vec3;
use std::f32::consts::FRAC_1_PI;

/// Upper bound on the quadrature nodes of one edge seen from one wall point.
pub const MAX_NODES_PER_EDGE: usize = 512;

/// Node spacing along an edge, in units of the kernel's width.
const NODE_SPACING: f32 = 0.25;

/// The hidden meshes' edges, built once per gradient.
pub struct Boundary {
    objects: Vec<ObjectEdges>,
    /// Node spacing along edges (m).
    spacing: f32,
    /// `path`: the continuation from the sensor point mixes area and BSDF sampling
    /// (`(c_bsdf, c_hg)`), whose points move differently ([`Boundary::measurement`]).
    mixture: Option<(f32, f32)>,
}

struct ObjectEdges {
    edges: EdgeMesh,
    /// The object's triangles over its own (unwelded) vertex indices.
    triangles: Vec<[u32; 3]>,
}

/// One quadrature node: a point of a silhouette edge seen from `o`, visible from `o`,
/// and the hidden receiver point behind it.
#[derive(Clone, Copy, Debug)]
pub struct Node {
    pub object: u32,
    /// The edge's end vertices, as the object's own vertex indices.
    pub ends: [u32; 2],
    /// Position along the edge, `y = (1 − s) p0 + s p1`.
    pub s: f32,
    /// Edge length the node stands for (m).
    pub length: f32,
    pub frame: EdgePoint,
    /// The hidden receiver point behind the edge: `None` where the ray misses the hidden
    /// objects (kept only for `path`'s foreground term).
    pub receiver: Option<Point>,
    /// `cos` at the wall point `o` toward the edge (`n_w · d`).
    pub cos_o: f32,
}

/// Per-object vertex gradients (the scatter's target).
pub type VertexGrad = Vec<Vec<[f64; 3]>>;

impl Boundary {
    pub fn new(scene: &Scene, film: &Film, model: Model) -> Boundary {
        let objects = scene
            .objects
            .iter()
            .map(|o| ObjectEdges {
                edges: EdgeMesh::new(&o.mesh.positions, &o.mesh.triangles),
                triangles: o.mesh.triangles.clone(),
            })
            .collect();
        let width = match film.kernel {
            KernelSpec::Box => film.width,
            KernelSpec::Gaussian { sigma_opl } => sigma_opl as f64,
        } as f32;
        let tech = &scene.render.techniques;
        let mixture = (model == Model::Path)
            .then(|| crate::transport::path::technique_probabilities(tech, true))
            .filter(|&(c_bsdf, _)| c_bsdf > 0.0);
        Boundary {
            objects,
            spacing: NODE_SPACING * width,
            mixture,
        }
    }

    /// Whether the scene's measurements can have a three-bounce boundary term at all:
    /// `false` when the path-length filter excludes three-bounce paths.
    pub fn applies(scene: &Scene) -> bool {
        scene.render.filter_bounces.is_none_or(|f| f == 3)
    }

    /// The nodes of every silhouette edge seen from the wall point `o`.
    pub fn nodes(&self, geom: &SceneGeometry, o: Vec3) -> Vec<Node> {
        let mut nodes = Vec::new();
        let offset = 4.0 * geom.eps;
        for (oi, obj) in self.objects.iter().enumerate() {
            let mesh = &obj.edges;
            for e in mesh.silhouettes(o) {
                let edge = &mesh.edges[e as usize];
                let [p0, p1] = edge.v.map(|i| mesh.positions[i as usize]);
                let face = edge.faces[0];
                let q = mesh.third_vertex(e as usize, face);
                let Some(ends) = original_ends(&obj.triangles[face as usize], mesh, edge.v) else {
                    continue;
                };
                let len = (p1 - p0).length();
                let count = ((len / self.spacing).ceil() as usize).clamp(1, MAX_NODES_PER_EDGE);
                let length = len / count as f32;
                for j in 0..count {
                    let s = (j as f32 + 0.5) / count as f32;
                    let y = p0.lerp(p1, s);
                    let Some(frame) = EdgePoint::new(o, y, p1 - p0, q) else {
                        continue;
                    };
                    let cos_o = geom.wall_normal.dot(frame.d);
                    if cos_o <= 0.0 {
                        continue;
                    }
                    // Just on the lit side: the edge's own faces lie on the other.
                    let lit = y + offset * frame.n;
                    if geom.occluded(o, lit) {
                        continue;
                    }
                    let receiver = geom
                        .intersect(lit, frame.d)
                        .filter(|h| matches!(h.kind, SurfaceKind::Hidden { .. }))
                        .map(|h| Point {
                            flat: h.flat,
                            bary: h.bary,
                            x: h.p,
                        });
                    if receiver.is_none() && self.mixture.is_none() {
                        continue;
                    }
                    nodes.push(Node {
                        object: oi as u32,
                        ends,
                        s,
                        length,
                        frame,
                        receiver,
                        cos_o,
                    });
                }
            }
        }
        nodes
    }

    /// Adds the boundary term of measurement `ctx` (adjoint histogram `adjoint`) to
    /// `grad`: the shadows cast from the laser spot and, unless the capture is confocal,
    /// from the sensor point.
    pub fn measurement(
        &self,
        scene: &Scene,
        ctx: &MeasurementCtx,
        film: &Film,
        adjoint: &[f32],
        views: &mut ViewCache,
        grad: &mut VertexGrad,
    ) {
        let confocal = ctx.x_l == ctx.x_s;
        views.update(self, ctx, confocal);
        let from_l = (&views.laser.1[..], ctx.x_l, ctx.x_s);
        let from_s = (!confocal).then(|| (&views.sensor.1[..], ctx.x_s, ctx.x_l));
        for (nodes, o, other) in std::iter::once(from_l).chain(from_s) {
            views.nodes_used += nodes.len() as u64;
            // Whether a `path` continuation from the sensor point that BSDF-samples the
            // receiver sees this shadow: a shadow cast from x_s is then a change of the
            // first surface hit (foreground minus background, below); one cast from x_l
            // falls on a point that slides along its ray from x_s.
            let seen_from_sensor = o == ctx.x_s;
            for node in nodes {
                if let Some(receiver) = &node.receiver {
                    self.background(scene, ctx, film, adjoint, node, receiver, other, grad);
                }
                if self.mixture.is_some() && seen_from_sensor {
                    self.foreground(scene, ctx, film, adjoint, node, other, grad);
                }
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
        grad: &mut VertexGrad,
    ) {
        let o = node.frame.o;
        let Some((value, opl)) = integrand(ctx, receiver, node, o, other) else {
            return;
        };
        let (a, _) = film.adjoint(opl, adjoint);
        if a == 0.0 || (other != o && ctx.geom.occluded(receiver.x, other)) {
            return;
        }
        let w = a * value as f64 * node.length as f64;
        let share = self.bsdf_share(ctx, receiver) as f64;
        let motion = Motion {
            edge: -w,
            material: w * (1.0 - share),
            along_sensor_ray: if o == ctx.x_s { 0.0 } else { w * share },
        };
        scatter(scene, ctx, node, Some(receiver), motion, grad);
    }

    /// `w_bsdf`: the share of `path`'s continuation from the sensor point that reaches
    /// `p` by BSDF sampling (balance heuristic; 0 for the other models).
    fn bsdf_share(&self, ctx: &MeasurementCtx, p: &Point) -> f32 {
        let Some((c_bsdf, c_hg)) = self.mixture else {
            return 0.0;
        };
        let geom = ctx.geom;
        let to = p.x - ctx.x_s;
        let d2 = to.length_squared();
        let d = to / d2.sqrt();
        let cos_y = geom.hidden[p.flat as usize].n.dot(d).abs();
        let p_bsdf = ctx.n_w.dot(d).max(0.0) * FRAC_1_PI * cos_y / d2;
        let dist = if ctx.scene.render.techniques.hidden_geometry_includes_wall {
            &geom.hidden_and_wall_area
        } else {
            &geom.hidden_area
        };
        let p_hg = dist.prob(p.flat) / geom.hidden_area_of(p.flat);
        let q = c_bsdf * p_bsdf + c_hg * p_hg;
        if q > 0.0 {
            c_bsdf * p_bsdf / q
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
        grad: &mut VertexGrad,
    ) {
        let f = &node.frame;
        let inside = f.y - 4.0 * ctx.geom.eps * f.n;
        let Some(hit) = ctx.geom.intersect(f.o, (inside - f.o).normalize()) else {
            return;
        };
        if !matches!(hit.kind, SurfaceKind::Hidden { .. }) {
            return;
        }
        let fg = Point {
            flat: hit.flat,
            bary: hit.bary,
            x: hit.p,
        };
        let Some((value, opl)) = integrand(ctx, &fg, node, f.o, other) else {
            return;
        };
        let (a, _) = film.adjoint(opl, adjoint);
        if a == 0.0 || (other != f.o && ctx.geom.occluded(fg.x, other)) {
            return;
        }
        let w = a * value as f64 * node.length as f64 * self.bsdf_share(ctx, &fg) as f64;
        let motion = Motion {
            edge: w,
            material: 0.0,
            along_sensor_ray: 0.0,
        };
        scatter(scene, ctx, node, None, motion, grad);
    }
}

/// A hidden point: its triangle, barycentrics and position.
#[derive(Clone, Copy, Debug)]
pub struct Point {
    pub flat: u32,
    pub bary: [f32; 2],
    pub x: Vec3,
}

/// How a node's weight moves the vertices: along the edge's motion (`edge` times
/// `(∂y/∂θ)·n`), with the receiver's material point (`material` times
/// `−(r_y/r_x)(∂x_R/∂θ)·n`), and with the receiver's point on its ray from the sensor
/// point (`along_sensor_ray`, the same with that point's velocity).
struct Motion {
    edge: f64,
    material: f64,
    along_sensor_ray: f64,
}

/// The nodes seen from the last laser spot and the last sensor point, reused while
/// consecutive measurements share them (a `single` capture's laser spot; an exhaustive
/// capture's sensor point).
#[derive(Default)]
pub struct ViewCache {
    laser: (Option<Vec3>, Vec<Node>),
    sensor: (Option<Vec3>, Vec<Node>),
    /// Nodes evaluated, summed over measurements.
    pub nodes_used: u64,
}

impl ViewCache {
    fn update(&mut self, b: &Boundary, ctx: &MeasurementCtx, confocal: bool) {
        for (view, o, needed) in [
            (&mut self.laser, ctx.x_l, true),
            (&mut self.sensor, ctx.x_s, !confocal),
        ] {
            if needed && view.0 != Some(o) {
                *view = (Some(o), b.nodes(ctx.geom, o));
            }
        }
    }
}

/// `F_b J / k_b` at the hidden point `p` behind (or at) the node, for the wall points `o`
/// (the shadow's) and `other`, and `p`'s OPL; `None` where `p` cannot scatter between
/// them.
fn integrand(
    ctx: &MeasurementCtx,
    p: &Point,
    node: &Node,
    o: Vec3,
    other: Vec3,
) -> Option<(f32, f32)> {
    let tri = &ctx.geom.hidden[p.flat as usize];
    if tri.retro {
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
    let c = ctx.power * ctx.f_wall * ctx.f_wall;
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
fn scatter(
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

/// The corners of `tri` (own vertex indices) that weld to the edge's ends `v`.
fn original_ends(tri: &[u32; 3], mesh: &EdgeMesh, v: [u32; 2]) -> Option<[u32; 2]> {
    let find = |w: u32| tri.iter().copied().find(|&c| mesh.weld[c as usize] == w);
    Some([find(v[0])?, find(v[1])?])
}
