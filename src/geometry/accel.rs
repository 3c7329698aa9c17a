//! Ray queries against the whole scene: the hidden triangles (in an obvhs CWBVH, or,
//! when there are few, in SIMD packets of eight: [`super::packet`]) and the relay wall, a
//! parallelogram intersected analytically ([`super::wall_plane`]). Closest hit for
//! continuing paths, occlusion for visibility `V(a, b)` between two surface points.
//!
//! Rays that start or end on a surface are shortened by `eps` (a fraction of the scene
//! size) at both ends, so a surface does not shadow itself.

use super::blockers::{BlockerSets, Blockers, Reach, Side};
use super::packet::{self, TriPacket};
use super::point_shadow::PointShadow;
use super::wall_plane::WallPlane;
use crate::geometry::sampling::AreaDistribution;
use crate::scene::Scene;
use glam::{Vec3, Vec3A};
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray, RayHit};
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;
use std::time::Duration;

/// Scenes with at most this many hidden triangles test them all, eight at a time
/// ([`packet`]), instead of traversing a BVH: below it a packet loop costs less than a
/// CWBVH traversal's fixed cost (~450 instructions per shadow ray, callgrind). Measured
/// crossover with packets of four (`path`, MIS, 2 threads): packets 1.33x faster on the
/// 24-triangle arc and 1.29x on it split into 48; the BVH 1.6x faster on the 72-triangle
/// letter of the default scene. So the threshold lies in [48, 72). With packets of eight
/// the BVH still wins on that letter: 0.24–0.25 s against 0.28–0.29 s with a threshold of
/// 80 (2048 spp, 2 threads, alternated, 2026-12-06).
pub const PACKET_TRIANGLES: usize = 64;

/// What a primitive belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SurfaceKind {
    /// Triangle `tri` of hidden object `object` (index into `Scene::objects`).
    Hidden {
        object: u32,
        tri: u32,
    },
    Wall,
}

/// The hidden triangles' acceleration structure.
enum HiddenAccel {
    /// Every triangle, in flat order, four to a packet.
    Packets(Vec<TriPacket>),
    /// A CWBVH, with the triangles and their flat indices in BVH order.
    Bvh {
        bvh: CwBvh,
        tris: Vec<Triangle>,
        flat: Vec<u32>,
    },
}

/// A ray's closest hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Distance along the (unit) ray direction (m).
    pub t: f32,
    pub p: Vec3,
    /// Unit geometric normal (orientation as the triangle's winding).
    pub n: Vec3,
    pub kind: SurfaceKind,
    /// Flat hidden-triangle index, `u32::MAX` for the wall.
    pub flat: u32,
    /// Barycentrics (b1, b2) of `p` on the triangle (vertex 1 and 2 weights).
    pub bary: [f32; 2],
}

/// A hidden triangle's shading data, by flat index.
#[derive(Clone, Copy, Debug)]
pub struct HiddenTri {
    pub v: [Vec3; 3],
    /// Unit geometric normal, `(v1 - v0) × (v2 - v0)` normalised.
    pub n: Vec3,
    /// Area (m²), `|(v1 - v0) × (v2 - v0)| / 2`.
    pub area: f32,
    /// Albedo at the three vertices (the object's albedo three times if it has no
    /// per-vertex albedo).
    pub albedo: [f32; 3],
    pub two_sided: bool,
    /// Retroreflective ([`crate::scene::Reflectance`]); Lambertian otherwise.
    pub retro: bool,
    /// A retroreflector's angular falloff exponent `m` (`cos^m θ`; 0 otherwise).
    pub retro_falloff: f32,
}

impl HiddenTri {
    pub fn point(&self, bary: [f32; 2]) -> Vec3 {
        let [b1, b2] = bary;
        (1.0 - b1 - b2) * self.v[0] + b1 * self.v[1] + b2 * self.v[2]
    }
    pub fn albedo_at(&self, bary: [f32; 2]) -> f32 {
        let [b1, b2] = bary;
        (1.0 - b1 - b2) * self.albedo[0] + b1 * self.albedo[1] + b2 * self.albedo[2]
    }
}

/// The scene's surfaces ready for queries and sampling.
pub struct SceneGeometry {
    accel: HiddenAccel,
    wall: WallPlane,
    /// Per hidden triangle and side, what a segment touching it can be blocked by.
    blockers: BlockerSets,
    /// Hidden triangles by flat index: (object, local triangle).
    pub flat_to_local: Vec<(u32, u32)>,
    /// Hidden triangles by flat index.
    pub hidden: Vec<HiddenTri>,
    /// Area sampling of all hidden triangles (hidden-geometry sampling).
    pub hidden_area: AreaDistribution,
    /// Area sampling of the hidden triangles followed by the wall's two triangles
    /// (flat indices `hidden.len()` and `hidden.len() + 1`).
    pub hidden_and_wall_area: AreaDistribution,
    /// The wall's two triangles.
    pub wall_tris: [[Vec3; 3]; 2],
    /// Self-intersection offset (m).
    pub eps: f32,
    pub wall_normal: Vec3,
    /// Distance (m) from the wall's plane to the nearest hidden corner in front of it; 0
    /// where a hidden triangle touches the plane or lies behind it. A path leaving a wall
    /// point must next meet hidden geometry at least this far out (the wall is planar).
    pub wall_gap: f32,
    /// Which hidden triangles nothing shadows toward a point, by point asked for
    /// ([`SceneGeometry::clear_toward`]); `None` where the blocker sets are all empty
    /// (then nothing needs clearing).
    point_shadow: Option<PointShadow>,
}

impl SceneGeometry {
    pub fn build(scene: &Scene) -> SceneGeometry {
        let mut tris = Vec::new();
        let mut flat_to_local = Vec::new();
        let mut areas = Vec::new();
        let mut hidden = Vec::new();
        let mut extent = scene.wall.axis_u.length() + scene.wall.axis_v.length();
        for (oi, o) in scene.objects.iter().enumerate() {
            for t in 0..o.mesh.triangles.len() {
                let [a, b, c] = o.mesh.triangle(t);
                extent = extent.max(a.length()).max(b.length()).max(c.length());
                flat_to_local.push((oi as u32, t as u32));
                areas.push(o.mesh.area(t));
                let idx = o.mesh.triangles[t];
                hidden.push(HiddenTri {
                    v: [a, b, c],
                    n: (b - a).cross(c - a).normalize(),
                    area: 0.5 * (b - a).cross(c - a).length(),
                    albedo: match &o.mesh.vertex_albedo {
                        Some(va) => idx.map(|i| va[i as usize]),
                        None => [o.albedo; 3],
                    },
                    two_sided: o.two_sided,
                    retro: o.reflectance.is_retro(),
                    retro_falloff: o.reflectance.falloff(),
                });
                tris.push([a, b, c]);
            }
        }
        let w = &scene.wall;
        let c00 = w.center - 0.5 * w.axis_u - 0.5 * w.axis_v;
        let c10 = c00 + w.axis_u;
        let c11 = c10 + w.axis_v;
        let c01 = c00 + w.axis_v;
        let wall_tris = [[c00, c10, c11], [c00, c11, c01]];
        let centroids: Vec<Vec3> = hidden
            .iter()
            .map(|t| (t.v[0] + t.v[1] + t.v[2]) / 3.0)
            .collect();
        let mut areas_with_wall = areas.clone();
        let mut centroids_with_wall = centroids.clone();
        for [a, b, c] in wall_tris {
            areas_with_wall.push(0.5 * (b - a).cross(c - a).length());
            centroids_with_wall.push((a + b + c) / 3.0);
        }
        let eps = 2e-6 * extent.max(1e-3) + 1e-6;
        let normals: Vec<Vec3> = hidden.iter().map(|t| t.n).collect();
        let as_packets = tris.len() <= PACKET_TRIANGLES;
        let blockers = BlockerSets::build(&tris, &normals, &wall_tris, 0.25 * eps, as_packets);
        let accel = if as_packets {
            HiddenAccel::Packets(packet::pack(&tris))
        } else {
            let tris: Vec<Triangle> = tris.iter().map(|&[a, b, c]| tri(a, b, c)).collect();
            let mut build_time = Duration::ZERO;
            let bvh = obvhs::cwbvh::builder::build_cwbvh_from_tris(
                &tris,
                BvhBuildParams::medium_build(),
                &mut build_time,
            );
            let order = &bvh.primitive_indices;
            HiddenAccel::Bvh {
                tris: order.iter().map(|&i| tris[i as usize]).collect(),
                flat: order.clone(),
                bvh,
            }
        };
        let wall_normal = w.normal();
        let wall_gap = hidden
            .iter()
            .flat_map(|t| t.v)
            .map(|v| wall_normal.dot(v - w.center))
            .fold(f32::INFINITY, f32::min)
            .max(0.0);
        let point_shadow = (!blockers.everywhere_empty()).then(|| {
            let tris: Vec<[Vec3; 3]> = hidden.iter().map(|t| t.v).collect();
            PointShadow::new(&tris, 0.25 * eps)
        });
        SceneGeometry {
            accel,
            wall: WallPlane::new(w.center, w.axis_u, w.axis_v),
            blockers,
            flat_to_local,
            hidden,
            hidden_area: AreaDistribution::spatial(&areas, &centroids),
            hidden_and_wall_area: AreaDistribution::spatial(&areas_with_wall, &centroids_with_wall),
            wall_tris,
            eps,
            wall_normal,
            wall_gap,
            point_shadow,
        }
    }

    /// Every triangle a ray can hit, hidden ones then the wall's two, as obvhs triangles
    /// (the ray-throughput benchmark's bare BVH).
    pub fn all_triangles(&self) -> Vec<Triangle> {
        let hidden = self.hidden.iter().map(|t| t.v);
        hidden
            .chain(self.wall_tris)
            .map(|[a, b, c]| tri(a, b, c))
            .collect()
    }

    /// Area of hidden triangle `flat` (m²).
    pub fn hidden_area_of(&self, flat: u32) -> f32 {
        self.hidden[flat as usize].area
    }

    /// Which of the two relay-wall triangles ([`SceneGeometry::wall_tris`]) holds the wall
    /// point `p`.
    pub fn wall_tri_of(&self, p: Vec3) -> u32 {
        let [a, b, c] = self.wall_tris[0];
        // p is in the first triangle iff it is on b's side of the diagonal a–c.
        let (n, diag) = ((b - a).cross(c - a), c - a);
        let side = |q: Vec3| diag.cross(q - a).dot(n);
        if side(p) * side(b) >= 0.0 {
            0
        } else {
            1
        }
    }

    /// The same geometry sampled with `base`'s discrete distributions over triangles
    /// (same triangle count): the estimators' weights then use this geometry's areas with
    /// `base`'s probabilities, so renders at perturbed vertices keep every sample's
    /// triangle. That is the estimator that finite differences with common random
    /// numbers differentiate, and whose derivative the adjoint pass computes.
    pub fn with_sampling_of(mut self, base: &SceneGeometry) -> SceneGeometry {
        assert_eq!(self.hidden.len(), base.hidden.len(), "same triangles");
        self.hidden_area = base.hidden_area.clone();
        self.hidden_and_wall_area = base.hidden_and_wall_area.clone();
        self
    }

    /// Closest hidden triangle hit by the ray within `[tmin, tmax]`: `(t, flat index)`.
    #[inline]
    fn hidden_hit(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<(f32, u32)> {
        match &self.accel {
            HiddenAccel::Packets(p) => packet::closest(p, o, d, tmin, tmax),
            HiddenAccel::Bvh { bvh, tris, flat } => {
                let ray = Ray::new(o.into(), d.into(), tmin, tmax);
                let mut hit = RayHit::none();
                bvh.ray_traverse(ray, &mut hit, |r, id| tris[id].intersect(r))
                    .then(|| (hit.t, flat[hit.primitive_id as usize]))
            }
        }
    }

    /// Closest surface hit by the ray `origin + t * dir` (`dir` unit), `t > eps`. A wall
    /// hit has barycentrics `[0, 0]` (the wall is not differentiated).
    #[inline]
    pub fn intersect(&self, origin: Vec3, dir: Vec3) -> Option<Hit> {
        super::ray_log::log(origin, dir, f32::INFINITY, false);
        let hidden = self.hidden_hit(origin, dir, self.eps, f32::INFINITY);
        let t_max = hidden.map_or(f32::INFINITY, |(t, _)| t);
        if let Some(hit) = self.wall_hit(origin, dir, t_max) {
            if hidden.is_none_or(|(th, _)| hit.t < th) {
                return Some(hit);
            }
        }
        let (t, flat) = hidden?;
        let tri = &self.hidden[flat as usize];
        let (object, local) = self.flat_to_local[flat as usize];
        let p = origin + t * dir;
        Some(Hit {
            t,
            p,
            n: tri.n,
            kind: SurfaceKind::Hidden { object, tri: local },
            flat,
            bary: barycentric(&tri.v, p),
        })
    }

    /// [`SceneGeometry::intersect`] against the wall alone: the continuation from a hidden
    /// vertex in front of which no hidden triangle rises (`path_step::Onward::WallOnly`).
    /// Analytic, so not in the ray log.
    #[inline]
    pub fn intersect_wall(&self, origin: Vec3, dir: Vec3) -> Option<Hit> {
        self.wall_hit(origin, dir, f32::INFINITY)
    }

    #[inline]
    fn wall_hit(&self, origin: Vec3, dir: Vec3, t_max: f32) -> Option<Hit> {
        let t = self.wall.intersect(origin, dir, self.eps, t_max)?;
        Some(Hit {
            t,
            p: origin + t * dir,
            n: self.wall_normal,
            kind: SurfaceKind::Wall,
            flat: u32::MAX,
            bary: [0.0; 2],
        })
    }

    /// True if the open segment between surface points `a` and `b` is blocked.
    #[inline]
    pub fn occluded(&self, a: Vec3, b: Vec3) -> bool {
        self.occluded_by(a, b, &Blockers::All)
    }

    /// [`SceneGeometry::occluded`] for a segment one of whose ends lies on hidden
    /// triangle `flat`: only the triangles that can block it from that triangle's side
    /// are tested ([`super::blockers`]; none for a convex or planar object).
    #[inline]
    pub fn occluded_touching(&self, a: Vec3, b: Vec3, flat: u32) -> bool {
        self.occluded_by(a, b, self.blockers.of_segment(flat, a, b))
    }

    /// For `L` segments `a[k] → b[k]` touching hidden triangles `flat[k]`, in lanes: the
    /// blocker set each is tested against
    /// ([`super::blockers::BlockerSets::side_lanes`]), and whether it is clear without a
    /// ray (nothing can block on its side, and the wall does not separate its ends).
    /// [`SceneGeometry::occluded_on_side`] of a lane's side is
    /// [`SceneGeometry::occluded_touching`]'s answer, and `false` where it is clear.
    #[inline(always)]
    pub fn segment_sides<const L: usize>(
        &self,
        flat: [u32; L],
        a: &[[f32; L]; 3],
        b: &[[f32; L]; 3],
    ) -> ([Side; L], [bool; L]) {
        let sides = self.blockers.side_lanes(flat, a, b);
        let separates = self.wall.separates_lanes(a, b);
        let clear = std::array::from_fn(|k| sides[k] == Side::CLEAR && !separates[k]);
        (sides, clear)
    }

    /// [`SceneGeometry::occluded_touching`] with the side known
    /// ([`SceneGeometry::segment_sides`]).
    #[inline]
    pub fn occluded_on_side(&self, a: Vec3, b: Vec3, flat: u32, side: Side) -> bool {
        self.occluded_by(a, b, self.blockers.on_side(flat, side))
    }

    /// What hidden-geometry sampling can reach from hidden triangle `flat` on the side of
    /// `n_side` ([`super::blockers`]: nothing, from a planar or convex object).
    #[inline]
    pub fn reach_from(&self, flat: u32, n_side: Vec3) -> Reach {
        self.blockers
            .reach(flat, n_side.dot(self.hidden[flat as usize].n) >= 0.0)
    }

    /// Whether a continuation from some hidden triangle can meet another
    /// ([`super::blockers::Reach`]); not for a planar or convex object, whose every
    /// continuation meets the wall or nothing (`path_step::Onward`).
    #[inline]
    pub fn hidden_reaches_hidden(&self) -> bool {
        self.blockers.some_side_reaches_hidden()
    }

    /// Whether no hidden triangle can shadow a segment touching another, on either side
    /// (a planar or convex object): every blocker set is empty.
    #[inline]
    pub fn blockers_everywhere_empty(&self) -> bool {
        self.blockers.everywhere_empty()
    }

    /// How many hidden-triangle sides need no hidden-geometry shadow test (of `2 N`).
    pub fn unblockable_sides(&self) -> usize {
        self.blockers.empty_sides()
    }

    /// Bit `t` set: no hidden triangle can shadow a segment from hidden triangle `t` to
    /// the point `l` ([`super::point_shadow`]; empty for scenes whose blocker sets
    /// already are, or with more than 64 hidden triangles).
    pub fn clear_toward(&self, l: Vec3) -> u64 {
        self.point_shadow
            .as_ref()
            .map_or(0, |ps| ps.clear_toward(l))
    }

    /// [`SceneGeometry::occluded_touching`] for a segment that no hidden triangle can
    /// shadow ([`SceneGeometry::clear_toward`]): the wall only.
    #[inline]
    pub fn occluded_by_wall(&self, a: Vec3, b: Vec3) -> bool {
        self.occluded_by(a, b, &Blockers::Nothing)
    }

    #[inline]
    fn occluded_by(&self, a: Vec3, b: Vec3, blockers: &Blockers) -> bool {
        // Nothing to trace: no hidden triangle can block, and the wall does not separate
        // the ends (two dot products; the usual case for a planar or convex object).
        if matches!(blockers, Blockers::Nothing) && !self.wall.separates(a, b) {
            return false;
        }
        let d = b - a;
        let dist = d.length();
        if dist <= 2.0 * self.eps {
            return false;
        }
        let dir = d / dist;
        let (tmin, tmax) = (self.eps, dist - self.eps);
        super::ray_log::log(a, dir, tmax, true);
        if self.wall.blocks(a, b, dir, tmin, tmax) {
            return true;
        }
        match (blockers, &self.accel) {
            (Blockers::Nothing, _) => false,
            (Blockers::Packets(p), _) | (Blockers::All, HiddenAccel::Packets(p)) => {
                packet::any_hit(p, a, dir, tmin, tmax)
            }
            (Blockers::All, HiddenAccel::Bvh { bvh, tris, .. }) => {
                let ray = Ray::new(a.into(), dir.into(), tmin, tmax);
                !bvh.ray_traverse_miss(ray, |r, id| tris[id].intersect(r))
            }
        }
    }
}

fn tri(a: Vec3, b: Vec3, c: Vec3) -> Triangle {
    Triangle {
        v0: a.into(),
        v1: b.into(),
        v2: c.into(),
    }
}

/// Barycentrics (b1, b2) of a point on the triangle's plane.
fn barycentric(v: &[Vec3; 3], p: Vec3) -> [f32; 2] {
    let e1 = Vec3A::from(v[1] - v[0]);
    let e2 = Vec3A::from(v[2] - v[0]);
    let q = Vec3A::from(p - v[0]);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (q1, q2) = (q.dot(e1), q.dot(e2));
    let det = d11 * d22 - d12 * d12;
    let b1 = (d22 * q1 - d12 * q2) / det;
    let b2 = (d11 * q2 - d12 * q1) / det;
    [b1, b2]
}
