//! Where the boundary terms are evaluated (issue 18, [`super::boundary`]): points on the
//! silhouette edges seen from a wall point `o`, each with the edge length it stands for,
//! its view-ray frame ([`EdgePoint`]) and the hidden receiver point behind it.
//!
//! Two placements, both deterministic for a seed:
//!
//! - [`Placement::Quadrature`] (`tri3`, a noise-free model): a midpoint rule with nodes
//!   a fixed distance apart along every edge (half the kernel's width), at most
//!   [`MAX_NODES_PER_EDGE`] per edge, refined by bisection where what lies behind the
//!   edge changes between two nodes (`quadrature`);
//! - [`Placement::Sampled`] (`mc3`, `path`): `count` points per wall point, spread over
//!   the silhouettes by systematic sampling of the edges' subtended angles (Mitsuba 3's
//!   primary-silhouette weight), uniform in length within an edge, one random offset
//!   per wall point (hashed from the seed and the point's coordinates, so the same point
//!   gets the same nodes on any thread count). Unbiased; its cost follows the spp like
//!   the interior term's.
//!
//! A node is kept if `y` is seen from `o` and in front of the wall; its receiver is the
//! first hit beyond `y`. One ray answers both: from `o` through a point just on the lit
//! side of `y`, where the edge's own faces are not.

use super::edge::EdgePoint;
use crate::geometry::silhouette::EdgeMesh;
use crate::geometry::{SceneGeometry, SurfaceKind};
use crate::rng::Sampler;
use crate::scene::Scene;
use glam::Vec3;

/// Upper bound on the quadrature nodes of one edge seen from one wall point.
pub const MAX_NODES_PER_EDGE: usize = 512;

/// Sampled nodes per batch at most: the nodes of one wall point are made and used a
/// batch at a time, so memory does not grow with the spp.
pub const SAMPLED_BATCH: u32 = 1024;

/// A receiver closer behind its edge than this many ray epsilons (plus 1e-4 of the
/// edge's distance) touches it ([`node`]).
const COINCIDENT: f32 = 16.0;

/// Bisection steps locating a change of what lies behind an edge between two
/// quadrature nodes ([`quadrature`]).
const REFINE: u32 = 5;

/// How nodes are placed along the silhouettes (module docs).
#[derive(Clone, Copy, Debug)]
pub enum Placement {
    /// Midpoint rule, nodes `spacing` apart (m).
    Quadrature { spacing: f32 },
    /// `count` stratified points per wall point.
    Sampled { count: u32, seed: u64 },
}

impl Placement {
    /// How many batches the nodes of one wall point come in.
    pub fn batches(&self) -> u32 {
        match *self {
            Placement::Quadrature { .. } => 1,
            Placement::Sampled { count, .. } => count.div_ceil(SAMPLED_BATCH).max(1),
        }
    }
}

/// A hidden point: its triangle, barycentrics and position.
#[derive(Clone, Copy, Debug)]
pub struct Point {
    pub flat: u32,
    pub bary: [f32; 2],
    pub x: Vec3,
}

/// A point of a silhouette edge seen from `o`, visible from `o`, and the hidden receiver
/// point behind it.
#[derive(Clone, Copy, Debug)]
pub struct Node {
    pub object: u32,
    /// The edge's end vertices, as the object's own vertex indices.
    pub ends: [u32; 2],
    /// Position along the edge, `y = (1 − s) p0 + s p1`.
    pub s: f32,
    /// Edge length the node stands for (m): the quadrature weight, or length over
    /// count times the inverse selection probability.
    pub length: f32,
    pub frame: EdgePoint,
    /// The hidden receiver point behind the edge: `None` where the ray misses the hidden
    /// objects (kept only when asked, for `path`'s foreground term).
    pub receiver: Option<Point>,
    /// `cos` at the wall point `o` toward the edge (`n_w · d`).
    pub cos_o: f32,
}

/// The hidden meshes' edges, built once per gradient.
pub struct EdgeSet {
    objects: Vec<(EdgeMesh, Vec<[u32; 3]>)>,
}

/// One silhouette edge seen from a wall point.
struct Silhouette {
    object: u32,
    ends: [u32; 2],
    p: [Vec3; 2],
    /// Third vertex of the edge's first face (the normal points away from it).
    q: Vec3,
    /// Angle subtended at the wall point (rad).
    angle: f32,
}

impl EdgeSet {
    pub fn new(scene: &Scene) -> EdgeSet {
        EdgeSet {
            objects: scene
                .objects
                .iter()
                .map(|o| {
                    let e = EdgeMesh::new(&o.mesh.positions, &o.mesh.triangles);
                    (e, o.mesh.triangles.clone())
                })
                .collect(),
        }
    }

    fn silhouettes(&self, o: Vec3) -> Vec<Silhouette> {
        let mut out = Vec::new();
        for (oi, (mesh, triangles)) in self.objects.iter().enumerate() {
            for e in mesh.silhouettes(o) {
                let edge = &mesh.edges[e as usize];
                let p = edge.v.map(|i| mesh.positions[i as usize]);
                let face = edge.faces[0];
                let Some(ends) = original_ends(&triangles[face as usize], mesh, edge.v) else {
                    continue;
                };
                out.push(Silhouette {
                    object: oi as u32,
                    ends,
                    p,
                    q: mesh.third_vertex(e as usize, face),
                    angle: (p[0] - o).angle_between(p[1] - o),
                });
            }
        }
        out
    }

    /// Batch `batch` of the nodes seen from the wall point `o` ([`Placement::batches`]);
    /// `keep_missing` keeps those whose ray misses the hidden objects behind the edge.
    pub fn nodes(
        &self,
        geom: &SceneGeometry,
        o: Vec3,
        placement: Placement,
        batch: u32,
        keep_missing: bool,
    ) -> Vec<Node> {
        let sil = self.silhouettes(o);
        let mut nodes = Vec::new();
        let mut place = |e: &Silhouette, s: f32, length: f32| {
            if let (Some(n), _) = node(geom, (o, geom.wall_normal), e, s, keep_missing) {
                nodes.push(Node { length, ..n });
            }
        };
        match placement {
            Placement::Quadrature { spacing } => {
                for e in &sil {
                    let len = (e.p[1] - e.p[0]).length();
                    let count = ((len / spacing).ceil() as usize).clamp(1, MAX_NODES_PER_EDGE);
                    quadrature(
                        geom,
                        (o, geom.wall_normal),
                        e,
                        count,
                        keep_missing,
                        &mut nodes,
                    );
                }
            }
            Placement::Sampled { count, seed } => {
                let total: f64 = sil.iter().map(|e| e.angle as f64).sum();
                if total.is_nan() || total <= 0.0 || count == 0 {
                    return nodes;
                }
                // Points k = batch + B j of the systematic sample (k + ξ) / count: batch b
                // is itself systematic, `count / B` points with offset (b + ξ) / B.
                let batches = placement.batches();
                let xi = Sampler::new(seed, viewpoint_stream(o), 0).next_1d() as f64;
                let points = (count - batch).div_ceil(batches);
                let step = total * batches as f64 / count as f64;
                let offset = (batch as f64 + xi) / batches as f64;
                let (mut k, mut start) = (0u32, 0.0f64);
                for e in &sil {
                    let angle = e.angle as f64;
                    let end = start + angle;
                    // Points (k + offset) step that fall on this edge's share.
                    while k < points && (k as f64 + offset) * step < end {
                        let s = (((k as f64 + offset) * step - start) / angle) as f32;
                        let len = (e.p[1] - e.p[0]).length() as f64;
                        // Each point stands for 1/count of the total angle.
                        let share = total / count as f64;
                        place(e, s.clamp(0.0, 1.0), (len * share / angle) as f32);
                        k += 1;
                    }
                    start = end;
                }
            }
        }
        nodes
    }
}

impl EdgeSet {
    /// One node seen from the hidden point `o` (its side's normal `n_o`): a silhouette
    /// edge picked with probability proportional to the angle it subtends at `o` (from
    /// `u[0]`), a point uniform along it (`u[1]`); its `length` is the edge's length over
    /// that probability. `None` where the point is not seen from `o`, or has no hidden
    /// receiver and `keep_missing` is off.
    pub fn sample_node(
        &self,
        geom: &SceneGeometry,
        (o, n_o): (Vec3, Vec3),
        u: [f32; 2],
        keep_missing: bool,
    ) -> Option<Node> {
        let eps = 8.0 * geom.eps;
        // Edges wholly in or behind o's tangent plane (its own face's) cannot be seen.
        let sil: Vec<Silhouette> = self
            .silhouettes(o)
            .into_iter()
            .filter(|e| e.p.iter().any(|&p| n_o.dot(p - o) > eps))
            .collect();
        let total: f32 = sil.iter().map(|e| e.angle).sum();
        if total.is_nan() || total <= 0.0 {
            return None;
        }
        let mut pick = u[0] * total;
        let e = sil
            .iter()
            .find(|e| {
                pick -= e.angle;
                pick < 0.0
            })
            .unwrap_or(&sil[sil.len() - 1]);
        if e.angle.is_nan() || e.angle <= 0.0 {
            return None;
        }
        let len = (e.p[1] - e.p[0]).length();
        let (n, _) = node(geom, (o, n_o), e, u[1], keep_missing);
        // From a hidden point, an edge grazing its own plane is seen edge-on: nothing.
        n.filter(|n| n.cos_o > 1e-5).map(|n| Node {
            length: len * total / e.angle,
            ..n
        })
    }
}

/// The occluder's own point at the edge point of `frame`, seen from `viewpoint`: the
/// first hidden hit of the ray through a point just on the occluding side of the edge
/// (the foreground of a silhouette, for the boundary terms of BSDF-sampled points).
pub fn occluder_at(geom: &SceneGeometry, viewpoint: Vec3, frame: &EdgePoint) -> Option<Point> {
    let inside = frame.y - 4.0 * geom.eps * frame.n;
    let hit = geom.intersect(viewpoint, (inside - viewpoint).normalize())?;
    matches!(hit.kind, SurfaceKind::Hidden { .. }).then_some(Point {
        flat: hit.flat,
        bary: hit.bary,
        x: hit.p,
    })
}

/// What lies behind an edge point, as far as the quadrature's refinement cares: a change
/// along the edge is a discontinuity of the integrand.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Class {
    /// Hidden from `o`, behind the wall, or touching its receiver: no node.
    Hidden,
    /// Seen, nothing hidden behind.
    Missing,
    /// Seen, a hidden receiver of this object at this distance from `o` (m).
    Receiver(u32, f32),
}

impl Class {
    /// Whether the integrand jumps between two neighbouring points of an edge seen at
    /// distance `r` (a receiver's depth jumping by 2 % of `r` is another surface).
    fn differs(self, other: Class, r: f32) -> bool {
        match (self, other) {
            (Class::Receiver(a, ra), Class::Receiver(b, rb)) => {
                a != b || (ra - rb).abs() > 0.02 * r
            }
            (a, b) => a != b,
        }
    }
}

/// The node at `s` on silhouette `e` seen from `o` (its `length` to be set), if `y` is
/// seen from `o`, and what lies behind `y`.
fn node(
    geom: &SceneGeometry,
    (o, n_o): (Vec3, Vec3),
    e: &Silhouette,
    s: f32,
    keep_missing: bool,
) -> (Option<Node>, Class) {
    let y = e.p[0].lerp(e.p[1], s);
    let Some(frame) = EdgePoint::new(o, y, e.p[1] - e.p[0], e.q) else {
        return (None, Class::Hidden);
    };
    let cos_o = n_o.dot(frame.d);
    if cos_o <= 0.0 {
        return (None, Class::Hidden);
    }
    // One ray from o through a point just on the lit side of y: it never meets the edge's
    // own faces (they lie on the other side of the plane through o and the edge). A hit
    // before y means y is hidden from o; the first hit beyond is the receiver.
    let lit = y + 4.0 * geom.eps * frame.n;
    let to_lit = lit - o;
    let r_lit = to_lit.length();
    let hit = geom.intersect(o, to_lit / r_lit);
    if hit.is_some_and(|h| h.t < r_lit - geom.eps) {
        return (None, Class::Hidden);
    }
    // A surface touching the edge (a coplanar piece meeting it, a T-junction) is not in
    // its shadow: a shadow ray to it ends on the edge, within the rays' tolerance, so
    // moving the edge changes nothing there.
    if hit.is_some_and(|h| h.t - r_lit < COINCIDENT * geom.eps + 1e-4 * frame.r_y) {
        return (None, Class::Hidden);
    }
    let hidden = hit.filter(|h| matches!(h.kind, SurfaceKind::Hidden { .. }));
    let class = match hidden {
        Some(h) => Class::Receiver(geom.flat_to_local[h.flat as usize].0, h.t),
        None => Class::Missing,
    };
    let receiver = hidden.map(|h| Point {
        flat: h.flat,
        bary: h.bary,
        x: h.p,
    });
    if receiver.is_none() && !keep_missing {
        return (None, class);
    }
    let node = Node {
        object: e.object,
        ends: e.ends,
        s,
        length: 0.0,
        frame,
        receiver,
        cos_o,
    };
    (Some(node), class)
}

/// `tri3`'s midpoint rule on one edge, `count` nodes, each standing for the stretch of
/// edge nearer to it than to its neighbours, except where what lies behind changes
/// between two neighbours ([`Class`]): there the change is located by bisection
/// ([`REFINE`] probes) and each node stands for its own side of it.
fn quadrature(
    geom: &SceneGeometry,
    (o, n_o): (Vec3, Vec3),
    e: &Silhouette,
    count: usize,
    keep_missing: bool,
    nodes: &mut Vec<Node>,
) {
    let len = (e.p[1] - e.p[0]).length();
    let r = (e.p[0] - o).length();
    let s_of = |j: usize| (j as f32 + 0.5) / count as f32;
    let probes: Vec<(Option<Node>, Class)> = (0..count)
        .map(|j| node(geom, (o, n_o), e, s_of(j), keep_missing))
        .collect();
    // bounds[j]: where node j's stretch starts.
    let mut bounds: Vec<f32> = (0..=count).map(|j| j as f32 / count as f32).collect();
    for j in 1..count {
        let (left, right) = (probes[j - 1].1, probes[j].1);
        if !left.differs(right, r) {
            continue;
        }
        let (mut lo, mut hi) = (s_of(j - 1), s_of(j));
        for _ in 0..REFINE {
            let mid = 0.5 * (lo + hi);
            if node(geom, (o, n_o), e, mid, keep_missing)
                .1
                .differs(left, r)
            {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        bounds[j] = 0.5 * (lo + hi);
    }
    for (j, (n, _)) in probes.into_iter().enumerate() {
        if let Some(mut n) = n {
            n.length = (bounds[j + 1] - bounds[j]) * len;
            nodes.push(n);
        }
    }
}

/// A random stream per wall point, from its coordinates' bits.
fn viewpoint_stream(o: Vec3) -> u64 {
    let [x, y, z] = o.to_array().map(|c| c.to_bits() as u64);
    (x << 42) ^ (y << 21) ^ z ^ 0xB0DA_5EED_0000_0000
}

/// The corners of `tri` (own vertex indices) that weld to the edge's ends `v`.
fn original_ends(tri: &[u32; 3], mesh: &EdgeMesh, v: [u32; 2]) -> Option<[u32; 2]> {
    let find = |w: u32| tri.iter().copied().find(|&c| mesh.weld[c as usize] == w);
    Some([find(v[0])?, find(v[1])?])
}

/// The nodes seen from the last laser spot (slot 0) and the last sensor point (slot 1),
/// reused while consecutive measurements share them (a `single` capture's laser spot; an
/// exhaustive capture's sensor point), when they come in one batch.
#[derive(Default)]
pub struct ViewCache {
    slots: [Option<(Vec3, Vec<Node>)>; 2],
    /// Nodes evaluated, summed over measurements.
    pub nodes_used: u64,
}

impl ViewCache {
    /// Batch `batch` of `batches` of the nodes seen from `o` in `slot`: the cached ones
    /// if `o` is the slot's last point and there is one batch, else `make()`'s.
    pub fn nodes(
        &mut self,
        slot: usize,
        o: Vec3,
        batches: u32,
        make: impl FnOnce() -> Vec<Node>,
    ) -> std::borrow::Cow<'_, [Node]> {
        let nodes = if batches > 1 {
            std::borrow::Cow::Owned(make())
        } else {
            if self.slots[slot].as_ref().is_none_or(|(p, _)| *p != o) {
                self.slots[slot] = Some((o, make()));
            }
            std::borrow::Cow::Borrowed(&self.slots[slot].as_ref().expect("just filled").1[..])
        };
        self.nodes_used += nodes.len() as u64;
        nodes
    }
}
