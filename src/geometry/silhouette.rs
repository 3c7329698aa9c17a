//! Mesh edges and their silhouettes as seen from a point: the support of the visibility
//! boundary terms (issue 18; `notes/boundary-methods.md` §3.1 and §4).
//!
//! [`EdgeMesh`] welds a hidden mesh's vertices by position (an OBJ seam or a mesh made
//! of separate triangles must not look like an open boundary) and lists each undirected
//! edge once with the faces that share it. [`EdgeMesh::silhouettes`] keeps, for a
//! viewpoint `o` (a laser spot `x_l` or a sensor point `x_s` on the relay wall), the edges
//! across which what `o` sees can change:
//!
//! - a **boundary edge** (one face): always;
//! - an edge whose faces all lie on one side of the plane through `o` and the edge (for
//!   two faces: one faces `o` and one faces away, whatever their winding): a contour;
//! - not an edge of two coplanar faces, nor one with faces on both sides of that plane
//!   (a crease with no contour: both faces face `o` or both face away);
//! - a **non-manifold** edge (three faces or more): by the same one-side rule.
//!
//! Occlusion is geometric: a one-sided face hides what is behind it from both sides, so
//! the classification ignores sidedness.

use glam::Vec3;
use std::collections::HashMap;

/// One undirected edge of the welded mesh.
#[derive(Clone, Debug, PartialEq)]
pub struct Edge {
    /// Welded vertex indices, `v[0] < v[1]`.
    pub v: [u32; 2],
    /// Faces (triangle indices of the mesh) sharing the edge: one for a boundary edge.
    pub faces: Vec<u32>,
}

/// A triangle mesh's edges over welded vertices.
#[derive(Clone, Debug, Default)]
pub struct EdgeMesh {
    /// Welded positions (m).
    pub positions: Vec<Vec3>,
    /// For each vertex of the input mesh, its welded vertex.
    pub weld: Vec<u32>,
    pub edges: Vec<Edge>,
    /// Per face: unit normal (zero for a degenerate face) and the welded corners.
    pub normals: Vec<Vec3>,
    pub corners: Vec<[u32; 3]>,
}

/// Faces whose normals differ by less than this (|n₀·n₁| above `1 − COPLANAR`) are one
/// plane: the edge between them is never a silhouette.
const COPLANAR: f32 = 1e-6;

impl EdgeMesh {
    /// Welds `positions` (exactly equal coordinates become one vertex) and collects the
    /// edges of `triangles`, in a deterministic order (by welded vertex pair).
    pub fn new(positions: &[Vec3], triangles: &[[u32; 3]]) -> EdgeMesh {
        let mut index: HashMap<[u32; 3], u32> = HashMap::new();
        let mut welded = Vec::new();
        let weld: Vec<u32> = positions
            .iter()
            .map(|p| {
                let key = p.to_array().map(f32::to_bits);
                *index.entry(key).or_insert_with(|| {
                    welded.push(*p);
                    (welded.len() - 1) as u32
                })
            })
            .collect();
        let corners: Vec<[u32; 3]> = triangles
            .iter()
            .map(|t| t.map(|i| weld[i as usize]))
            .collect();
        let normals = corners
            .iter()
            .map(|&[a, b, c]| {
                let (a, b, c) = (welded[a as usize], welded[b as usize], welded[c as usize]);
                (b - a).cross(c - a).normalize_or_zero()
            })
            .collect();
        let mut by_pair: HashMap<[u32; 2], Vec<u32>> = HashMap::new();
        for (f, c) in corners.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (c[k], c[(k + 1) % 3]);
                if a != b {
                    by_pair
                        .entry([a.min(b), a.max(b)])
                        .or_default()
                        .push(f as u32);
                }
            }
        }
        let mut edges: Vec<Edge> = by_pair
            .into_iter()
            .map(|(v, faces)| Edge { v, faces })
            .collect();
        edges.sort_by_key(|e| e.v);
        EdgeMesh {
            positions: welded,
            weld,
            edges,
            normals,
            corners,
        }
    }

    /// Indices into [`EdgeMesh::edges`] of the silhouettes seen from `o` (module docs).
    pub fn silhouettes(&self, o: Vec3) -> Vec<u32> {
        (0..self.edges.len() as u32)
            .filter(|&e| self.is_silhouette(e as usize, o))
            .collect()
    }

    fn is_silhouette(&self, e: usize, o: Vec3) -> bool {
        let edge = &self.edges[e];
        if edge.faces.len() == 1 {
            return true;
        }
        if let [f0, f1] = edge.faces[..] {
            let (n0, n1) = (self.normals[f0 as usize], self.normals[f1 as usize]);
            if n0.dot(n1).abs() > 1.0 - COPLANAR {
                return false;
            }
        }
        // Which side of the plane through `o` and the edge each face lies on (the sign of
        // its third vertex): all on one side leaves the other side open, a contour seen
        // from `o`; faces on both sides close it. Independent of the faces' winding.
        let mut sides = edge.faces.iter().map(|&f| self.side_of_view_plane(e, f, o));
        let first = sides.next().unwrap_or(0.0);
        first != 0.0 && sides.all(|s| s * first > 0.0)
    }

    /// The third vertex of face `f` (the corner not on edge `e`).
    pub fn third_vertex(&self, e: usize, f: u32) -> Vec3 {
        let v = self.edges[e].v;
        let c = self.corners[f as usize];
        let k = c.iter().position(|i| !v.contains(i)).unwrap_or(0);
        self.positions[c[k] as usize]
    }

    /// Signed distance-like side of face `f`'s third vertex with respect to the plane
    /// through `o` and edge `e`.
    fn side_of_view_plane(&self, e: usize, f: u32, o: Vec3) -> f32 {
        let [a, b] = self.edges[e].v.map(|i| self.positions[i as usize]);
        (b - a).cross(a - o).dot(self.third_vertex(e, f) - a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit square in z = 1 as two triangles with their own copies of the diagonal's
    /// vertices (an unwelded seam), and a tent: two faces meeting at a ridge.
    fn square() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let p = [
            [0., 0., 1.],
            [1., 0., 1.],
            [1., 1., 1.],
            [0., 0., 1.],
            [1., 1., 1.],
            [0., 1., 1.],
        ];
        (p.map(Vec3::from_array).to_vec(), vec![[0, 1, 2], [3, 4, 5]])
    }

    #[test]
    fn welding_makes_the_seam_an_inner_edge() {
        let (p, t) = square();
        let m = EdgeMesh::new(&p, &t);
        assert_eq!(m.positions.len(), 4);
        assert_eq!(m.edges.len(), 5);
        let inner: Vec<_> = m.edges.iter().filter(|e| e.faces.len() == 2).collect();
        assert_eq!(inner.len(), 1);
        // From the wall (z = 0) the four boundary edges are silhouettes, the coplanar
        // diagonal is not.
        let s = m.silhouettes(Vec3::new(0.3, 0.2, 0.0));
        assert_eq!(s.len(), 4);
        assert!(s.iter().all(|&e| m.edges[e as usize].faces.len() == 1));
    }

    #[test]
    fn a_ridge_is_a_silhouette_only_where_one_face_turns_away() {
        // Tent along y: faces x in [0, 1] rising to the ridge at x = 0.5, z = 0.5 (nearer
        // the wall at z = 0), so each face looks at one side.
        let p = [
            [0., 0., 1.],
            [0.5, 0., 0.5],
            [0.5, 1., 0.5],
            [0., 1., 1.],
            [1., 0., 1.],
            [1., 1., 1.],
        ]
        .map(Vec3::from_array)
        .to_vec();
        let t = vec![[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]];
        let m = EdgeMesh::new(&p, &t);
        let ridge = m.edges.iter().position(|e| e.v == [1, 2]).unwrap() as u32;
        // Straight in front of the ridge, both faces face the viewpoint: no contour.
        assert!(!m.silhouettes(Vec3::new(0.5, 0.5, 0.0)).contains(&ridge));
        // Far to the side, beyond the plane of one face, that face turns away.
        assert!(m.silhouettes(Vec3::new(5.0, 0.5, 0.0)).contains(&ridge));
        // Silhouettes do not depend on the faces' winding, even when it is inconsistent
        // (one face flipped: a sign test on the two normals would get every ridge wrong).
        let flipped: Vec<[u32; 3]> = t.iter().map(|&[a, b, c]| [a, c, b]).collect();
        let mut one_flipped = t.clone();
        one_flipped[3] = [1, 2, 5];
        for other in [flipped, one_flipped] {
            let mf = EdgeMesh::new(&p, &other);
            for o in [Vec3::new(0.5, 0.5, 0.0), Vec3::new(5.0, 0.5, 0.0)] {
                assert_eq!(m.silhouettes(o), mf.silhouettes(o));
            }
        }
    }
}
