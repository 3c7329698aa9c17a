//! Which hidden triangles can block a segment that touches hidden triangle `t` (DESIGN §3,
//! visibility `V(a, b)`): shadow-ray culling, exact up to the self-intersection offset.
//!
//! A segment from a point `a` of `t`'s plane `P` to a point `b` strictly in front of `P`
//! (`n_t · (b − a) > 0`) has every other point strictly in front of `P`. A triangle `u`
//! whose corners all lie on or behind `P` therefore cannot meet it beyond `a`, and `t`
//! itself meets it only at `a`. So the shadow ray need test only
//!
//! `B(t, +) = { u ≠ t : max_k n_t · (u_k − t_0) > τ }`,
//!
//! and `B(t, −)` likewise for `b` behind `P`. For a convex object every `B` is empty (a
//! convex surface does not shadow itself); for a planar one (a letter, a plate) too. With
//! `τ = eps / 4` (`eps` the scene's self-intersection offset), a triangle that rises at
//! most `τ` above `P`, from rounding of its corners (a planar mesh rotated in `f32` is
//! coplanar to ~1e-8 m), counts as coplanar: it could block only a ray that stays within
//! `τ` of `P`, a ray at a grazing angle `sin θ ≤ (τ + δ)/s` at distance `s ≥ eps`, where
//! `δ` is the rounding of `a`'s own position. The full test decides those rays by
//! rounding too (`0/0` in the plane); their weight carries the factor `cos θ_a = sin θ`.
//!
//! The sets are computed exactly (all pairs) for scenes of up to [`EXACT_TRIANGLES`]
//! hidden triangles, and kept as packets where the scene's hidden triangles are packets;
//! a BVH scene uses the full BVH whenever its set is not empty.
//!
//! The same heights say where a path can go next ([`Reach`]): a continuation from a point
//! `x` of `t`, leaving on side `+`, to a point `y` with `n_t · (y − x) ≤ 0` has
//! `cos θ_x ≤ 0`, so its weight is zero. Hidden-geometry sampling from `t` can thus reach
//! only the triangles of `B(t, +)`, with the same `τ`: a triangle rising at most `τ`
//! above `P` (rounding of a planar mesh) counts as in the plane, where both cosines of a
//! continuation are rounding of `0/0` (dropping those moves T.xml's multi-bounce render
//! by 5e-10 relative L2). A side that reaches no hidden triangle continues to the wall
//! only (`path_step::Onward::WallOnly`: BSDF rays traced against the wall alone).

use super::packet::{self, TriPacket};
use glam::Vec3;

/// Scenes with more hidden triangles test every segment against everything (computing
/// the sets costs `O(N²)`: at this size a few milliseconds).
pub const EXACT_TRIANGLES: usize = 2048;

/// What a segment touching a triangle, on one side of its plane, must be tested against.
#[derive(Clone, Debug)]
pub enum Blockers {
    /// Nothing can block it (the hidden geometry is skipped; the wall is still tested).
    Nothing,
    /// These triangles only, as packets (scenes whose hidden triangles are packets).
    Packets(Vec<TriPacket>),
    /// Every hidden triangle (the scene's own acceleration structure).
    All,
}

/// What hidden-geometry sampling can reach from one side of a hidden triangle: some
/// other hidden triangle, or some wall triangle, with a corner more than `τ` in front of
/// its plane.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reach {
    pub hidden: bool,
    pub wall: bool,
}

/// Where a segment touching a hidden triangle lies ([`BlockerSets::side_lanes`]): in
/// front of its plane, behind it, within `τ` of it (every triangle can block), or on a
/// side where nothing can (either side with an empty set). A byte, so that lanes of it
/// are selects.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Side(u8);

impl Side {
    pub const FRONT: Side = Side(0);
    pub const BACK: Side = Side(1);
    pub const IN_PLANE: Side = Side(2);
    pub const CLEAR: Side = Side(3);
}

/// The sets `B(t, +)` and `B(t, −)` of every hidden triangle `t`, by flat index.
#[derive(Clone, Debug)]
pub struct BlockerSets {
    sides: Vec<[Blockers; 2]>,
    /// What each side can reach ([`Reach`]).
    reach: Vec<[Reach; 2]>,
    /// Unit normal and a corner of each triangle's plane (as [`super::HiddenTri`] has them).
    planes: Vec<(Vec3, Vec3)>,
    /// Heights above a plane below which a segment's far end counts as in the plane.
    tau: f32,
    /// Per triangle and side, whether its set is [`Blockers::Nothing`] (for the lanes).
    nothing: Vec<[bool; 2]>,
    /// Whether every set is [`Blockers::Nothing`].
    everywhere_empty: bool,
}

impl BlockerSets {
    /// The sets of `tris` (`[v0, v1, v2]`, unit normals `normals`), `tau` the coplanarity
    /// tolerance (m); `as_packets` keeps non-empty sets as packets, else as [`Blockers::All`].
    /// `wall_tris` are the relay wall's triangles (for [`Reach`]).
    pub fn build(
        tris: &[[Vec3; 3]],
        normals: &[Vec3],
        wall_tris: &[[Vec3; 3]],
        tau: f32,
        as_packets: bool,
    ) -> Self {
        let planes: Vec<(Vec3, Vec3)> = normals.iter().zip(tris).map(|(&n, t)| (n, t[0])).collect();
        let everywhere = Reach {
            hidden: true,
            wall: true,
        };
        if tris.len() > EXACT_TRIANGLES {
            return BlockerSets {
                sides: vec![[Blockers::All, Blockers::All]; tris.len()],
                reach: vec![[everywhere; 2]; tris.len()],
                planes,
                tau,
                nothing: vec![[false; 2]; tris.len()],
                everywhere_empty: false,
            };
        }
        let mut reach = Vec::with_capacity(tris.len());
        let sides = (0..tris.len())
            .map(|t| {
                // Heights in f64 from the f32 corners, so the sets themselves do not round.
                let (n, o) = (planes[t].0.as_dvec3(), tris[t][0].as_dvec3());
                let rises = |u: &[Vec3; 3], side: f64| {
                    u.iter()
                        .any(|&c| side * n.dot(c.as_dvec3() - o) > tau as f64)
                };
                let sets = [1.0, -1.0].map(|side: f64| {
                    let set: Vec<[Vec3; 3]> = tris
                        .iter()
                        .enumerate()
                        .filter(|&(u, tri)| u != t && rises(tri, side))
                        .map(|(_, tri)| *tri)
                        .collect();
                    let r = Reach {
                        hidden: !set.is_empty(),
                        wall: wall_tris.iter().any(|u| rises(u, side)),
                    };
                    let blockers = match (set.is_empty(), as_packets) {
                        (true, _) => Blockers::Nothing,
                        (false, true) => Blockers::Packets(packet::pack(&set)),
                        (false, false) => Blockers::All,
                    };
                    (blockers, r)
                });
                reach.push(sets.each_ref().map(|(_, r)| *r));
                sets.map(|(b, _)| b)
            })
            .collect::<Vec<[Blockers; 2]>>();
        let nothing = sides
            .iter()
            .map(|s| s.each_ref().map(|b| matches!(b, Blockers::Nothing)))
            .collect::<Vec<[bool; 2]>>();
        let everywhere_empty = nothing.iter().flatten().all(|&b| b);
        BlockerSets {
            sides,
            reach,
            planes,
            tau,
            nothing,
            everywhere_empty,
        }
    }

    /// What hidden-geometry sampling can reach from hidden triangle `flat`, leaving on the
    /// side of its normal (`front`) or the other.
    #[inline]
    pub fn reach(&self, flat: u32, front: bool) -> Reach {
        self.reach[flat as usize][usize::from(!front)]
    }

    /// What the segment `a → b` must be tested against, given that one of its ends lies
    /// on hidden triangle `flat`: the set of the side the other end is on, or
    /// [`Blockers::All`] when both ends are within `τ` of the plane.
    #[inline]
    pub fn of_segment(&self, flat: u32, a: Vec3, b: Vec3) -> &Blockers {
        let (n, o) = self.planes[flat as usize];
        // One end is (up to rounding) in the plane; the sum is the other end's height.
        let h = n.dot(a - o) + n.dot(b - o);
        let sides = &self.sides[flat as usize];
        if h > self.tau {
            &sides[0]
        } else if h < -self.tau {
            &sides[1]
        } else {
            &Blockers::All
        }
    }

    /// [`BlockerSets::of_segment`] for `L` segments `a[k] → b[k]` touching triangles
    /// `flat[k]`, as lanes of which set it picks ([`Side`]): the same height, the same
    /// operations in the same order (`n · (a − o) + n · (b − o)`, each dot product
    /// `x + y + z`), so that [`BlockerSets::on_side`] of a lane's answer is `of_segment`'s.
    #[inline(always)]
    pub fn side_lanes<const L: usize>(
        &self,
        flat: [u32; L],
        a: &[[f32; L]; 3],
        b: &[[f32; L]; 3],
    ) -> [Side; L] {
        let planes = flat.map(|t| self.planes[t as usize]);
        let h: [f32; L] = std::array::from_fn(|k| {
            let (n, o) = planes[k];
            let up = |p: &[[f32; L]; 3]| {
                n.x * (p[0][k] - o.x) + n.y * (p[1][k] - o.y) + n.z * (p[2][k] - o.z)
            };
            up(a) + up(b)
        });
        std::array::from_fn(|k| {
            let [front_empty, back_empty] = self.nothing[flat[k] as usize];
            let (front, back) = (h[k] > self.tau, h[k] < -self.tau);
            let clear = (front && front_empty) || (!front && back && back_empty);
            let code = if front {
                0
            } else if back {
                1
            } else {
                2
            };
            Side(if clear { 3 } else { code })
        })
    }

    /// The set [`BlockerSets::side_lanes`] picked for a segment touching `flat`.
    #[inline]
    pub fn on_side(&self, flat: u32, side: Side) -> &Blockers {
        match side.0 {
            0 | 1 => &self.sides[flat as usize][side.0 as usize],
            2 => &Blockers::All,
            _ => &Blockers::Nothing,
        }
    }

    /// Whether some side of some hidden triangle reaches another hidden triangle
    /// ([`Reach::hidden`]); not for a planar or convex object.
    pub fn some_side_reaches_hidden(&self) -> bool {
        self.reach.iter().flatten().any(|r| r.hidden)
    }

    /// Whether every set is [`Blockers::Nothing`] (no hidden triangle shadows another).
    pub fn everywhere_empty(&self) -> bool {
        self.everywhere_empty
    }

    /// How many triangle sides need no hidden-geometry test at all (for the docs' figures).
    pub fn empty_sides(&self) -> usize {
        self.sides
            .iter()
            .flatten()
            .filter(|b| matches!(b, Blockers::Nothing))
            .count()
    }
}
