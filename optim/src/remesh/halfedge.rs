//! Vec-based half-edge mesh for the remesher.
//!
//! Half-edges come in pairs: `h ^ 1` is the twin of `h`, and edge `e` owns half-edges
//! `2e` and `2e + 1`. Each half-edge stores the vertex it points to, its successor and
//! predecessor and its face; a boundary half-edge has no face ([`NONE`]) and is linked to
//! the next boundary half-edge of its loop. A boundary vertex's outgoing half-edge
//! (`vhe`) is always its boundary half-edge. Deleted elements are marked with [`NONE`]
//! (`vhe` for vertices, `to` for half-edges, `fhe` for faces) and dropped by
//! [`HeMesh::to_mesh`]. All iteration is by index, so results are deterministic.

use super::geom::V3;
use super::RemeshError;
use crate::mesh::Mesh;

/// Marker for "no element" / "deleted".
pub(super) const NONE: u32 = u32::MAX;

pub(super) struct HeMesh {
    pub pos: Vec<V3>,
    /// One value per vertex, or empty.
    pub val: Vec<f64>,
    /// Protected boundary vertex (a corner of the input's boundary): never moved or removed.
    pub corner: Vec<bool>,
    /// An outgoing half-edge per vertex (the boundary one on the boundary); `NONE`: deleted.
    pub vhe: Vec<u32>,
    pub to: Vec<u32>,
    pub next: Vec<u32>,
    pub prev: Vec<u32>,
    pub face: Vec<u32>,
    /// A half-edge per face; `NONE`: deleted.
    pub fhe: Vec<u32>,
    pub live_faces: usize,
}

#[inline]
fn ix(i: u32) -> usize {
    i as usize
}

impl HeMesh {
    /// Builds the half-edge structure. Preconditions (checked by the caller): indices in
    /// range and the three indices of each face distinct. Fails on edges with more than
    /// two faces, inconsistently oriented neighbours and non-manifold vertices.
    pub fn build(pos: Vec<V3>, val: Vec<f64>, faces: &[[u32; 3]]) -> Result<Self, RemeshError> {
        let nv = pos.len();
        let nf = faces.len();
        let directed = |c: usize| -> (u32, u32) {
            let f = faces[c / 3];
            (f[c % 3], f[(c + 1) % 3])
        };
        let key = |c: usize| -> (u32, u32) {
            let (u, v) = directed(c);
            (u.min(v), u.max(v))
        };
        // Corners sorted by (undirected edge, corner index), packed in one u128 each.
        let mut packed: Vec<u128> = (0..3 * nf)
            .map(|c| {
                let (a, b) = key(c);
                (u128::from(a) << 96) | (u128::from(b) << 64) | c as u128
            })
            .collect();
        packed.sort_unstable();
        let order: Vec<usize> = packed.iter().map(|&x| x as u64 as usize).collect();
        drop(packed);

        let mut to = Vec::with_capacity(6 * nf);
        let mut face = Vec::with_capacity(6 * nf);
        let mut he_of_corner = vec![NONE; 3 * nf];
        let mut i = 0;
        while i < order.len() {
            let k = key(order[i]);
            let mut j = i + 1;
            while j < order.len() && key(order[j]) == k {
                j += 1;
            }
            let c0 = order[i];
            let (u, v) = directed(c0);
            let h = to.len() as u32;
            match j - i {
                1 => {
                    to.extend([v, u]);
                    face.extend([(c0 / 3) as u32, NONE]);
                    he_of_corner[c0] = h;
                }
                2 => {
                    let c1 = order[i + 1];
                    if directed(c1) != (v, u) {
                        return Err(RemeshError::InconsistentOrientation { a: k.0, b: k.1 });
                    }
                    to.extend([v, u]);
                    face.extend([(c0 / 3) as u32, (c1 / 3) as u32]);
                    he_of_corner[c0] = h;
                    he_of_corner[c1] = h + 1;
                }
                _ => return Err(RemeshError::NonManifoldEdge { a: k.0, b: k.1 }),
            }
            i = j;
        }
        if to.len() >= NONE as usize {
            return Err(RemeshError::TooLarge);
        }

        let nh = to.len();
        let mut next = vec![NONE; nh];
        let mut prev = vec![NONE; nh];
        let mut vhe = vec![NONE; nv];
        let mut degree = vec![0usize; nv];
        for f in 0..nf {
            for k in 0..3 {
                let h = he_of_corner[3 * f + k];
                let n = he_of_corner[3 * f + (k + 1) % 3];
                next[ix(h)] = n;
                prev[ix(n)] = h;
                vhe[ix(faces[f][k])] = h;
                degree[ix(faces[f][k])] += 1;
            }
        }
        // Boundary half-edges: at most one leaves (and one enters) each vertex.
        let mut bout = vec![NONE; nv];
        for h in (0..nh).filter(|&h| face[h] == NONE) {
            let origin = to[h ^ 1];
            if bout[ix(origin)] != NONE {
                return Err(RemeshError::NonManifoldVertex { vertex: origin });
            }
            bout[ix(origin)] = h as u32;
        }
        for h in (0..nh).filter(|&h| face[h] == NONE) {
            let n = bout[ix(to[h])];
            if n == NONE || prev[ix(n)] != NONE {
                return Err(RemeshError::NonManifoldVertex { vertex: to[h] });
            }
            next[h] = n;
            prev[ix(n)] = h as u32;
        }
        for v in 0..nv {
            if bout[v] != NONE {
                vhe[v] = bout[v];
            }
        }
        let m = HeMesh {
            corner: vec![false; nv],
            pos,
            val,
            vhe,
            to,
            next,
            prev,
            face,
            fhe: faces
                .iter()
                .enumerate()
                .map(|(f, _)| he_of_corner[3 * f])
                .collect(),
            live_faces: nf,
        };
        // One fan per vertex: walking around it must meet all of its faces.
        let mut ring = Vec::new();
        for v in 0..nv as u32 {
            if m.vhe[ix(v)] == NONE {
                continue;
            }
            m.outgoing(v, &mut ring);
            let faces_met = ring.iter().filter(|&&h| m.face[ix(h)] != NONE).count();
            if faces_met != degree[ix(v)] {
                return Err(RemeshError::NonManifoldVertex { vertex: v });
            }
        }
        Ok(m)
    }

    #[inline]
    pub fn from(&self, h: u32) -> u32 {
        self.to[ix(h ^ 1)]
    }

    #[inline]
    pub fn n_edges(&self) -> usize {
        self.to.len() / 2
    }

    #[inline]
    pub fn edge_alive(&self, e: usize) -> bool {
        self.to[2 * e] != NONE
    }

    #[inline]
    pub fn vertex_alive(&self, v: usize) -> bool {
        self.vhe[v] != NONE
    }

    #[inline]
    pub fn is_boundary_vertex(&self, v: u32) -> bool {
        self.face[ix(self.vhe[ix(v)])] == NONE
    }

    #[inline]
    pub fn is_boundary_edge(&self, h: u32) -> bool {
        self.face[ix(h)] == NONE || self.face[ix(h ^ 1)] == NONE
    }

    #[inline]
    pub fn p(&self, v: u32) -> V3 {
        self.pos[ix(v)]
    }

    /// Value of vertex `v` (0 when the mesh carries no values).
    #[inline]
    pub fn value(&self, v: u32) -> f64 {
        self.val.get(ix(v)).copied().unwrap_or(0.0)
    }

    #[inline]
    pub fn link(&mut self, a: u32, b: u32) {
        self.next[ix(a)] = b;
        self.prev[ix(b)] = a;
    }

    /// The half-edges leaving `v`, counter-clockwise, starting with `vhe[v]`.
    pub fn outgoing(&self, v: u32, out: &mut Vec<u32>) {
        out.clear();
        let start = self.vhe[ix(v)];
        if start == NONE {
            return;
        }
        let mut h = start;
        // The cap only guards against a corrupted structure; a valid one closes the loop.
        for _ in 0..self.to.len() {
            out.push(h);
            h = self.prev[ix(h)] ^ 1;
            if h == start {
                return;
            }
        }
        debug_assert!(false, "unclosed vertex ring");
    }

    /// Number of edges at `v`.
    pub fn valence(&self, v: u32) -> usize {
        let start = self.vhe[ix(v)];
        if start == NONE {
            return 0;
        }
        let mut h = start;
        let mut n = 0;
        while n < self.to.len() {
            n += 1;
            h = self.prev[ix(h)] ^ 1;
            if h == start {
                break;
            }
        }
        n
    }

    /// Points `vhe[v]` at a live outgoing half-edge `h`, or at `v`'s boundary half-edge if
    /// it has one.
    pub fn reset_outgoing(&mut self, v: u32, h: u32, ring: &mut Vec<u32>) {
        self.vhe[ix(v)] = h;
        self.outgoing(v, ring);
        if let Some(&b) = ring.iter().find(|&&g| self.face[ix(g)] == NONE) {
            self.vhe[ix(v)] = b;
        }
    }

    /// The three vertices of face `f`, in order.
    pub fn face_verts(&self, f: u32) -> [u32; 3] {
        let h = self.fhe[ix(f)];
        let n = self.next[ix(h)];
        [self.from(h), self.to[ix(h)], self.to[ix(n)]]
    }

    pub fn new_vertex(&mut self, p: V3, value: f64) -> u32 {
        let v = self.pos.len() as u32;
        self.pos.push(p);
        if !self.val.is_empty() {
            self.val.push(value);
        }
        self.corner.push(false);
        self.vhe.push(NONE);
        v
    }

    /// Appends an edge; returns its first half-edge (the second is `h ^ 1`).
    pub fn new_edge(&mut self, from: u32, to: u32) -> u32 {
        let h = self.to.len() as u32;
        self.to.extend([to, from]);
        self.next.extend([NONE, NONE]);
        self.prev.extend([NONE, NONE]);
        self.face.extend([NONE, NONE]);
        h
    }

    /// Appends a face made of the loop `h0 -> h1 -> h2`.
    pub fn new_face(&mut self, hs: [u32; 3]) -> u32 {
        let f = self.fhe.len() as u32;
        self.fhe.push(hs[0]);
        self.set_face(f, hs);
        self.live_faces += 1;
        f
    }

    /// Makes `hs` the loop of face `f`.
    pub fn set_face(&mut self, f: u32, hs: [u32; 3]) {
        for k in 0..3 {
            self.link(hs[k], hs[(k + 1) % 3]);
            self.face[ix(hs[k])] = f;
        }
        self.fhe[ix(f)] = hs[0];
    }

    pub fn kill_edge(&mut self, h: u32) {
        self.to[ix(h)] = NONE;
        self.to[ix(h ^ 1)] = NONE;
    }

    pub fn kill_face(&mut self, f: u32) {
        self.fhe[ix(f)] = NONE;
        self.live_faces -= 1;
    }

    /// Rebuilds the structure without its deleted elements (same vertex and face order).
    pub fn compact(&mut self) -> Result<(), RemeshError> {
        let (mesh, map) = self.compacted();
        let mut corner = vec![false; mesh.vertices.len()];
        for (v, &w) in map.iter().enumerate() {
            if w != NONE {
                corner[ix(w)] = self.corner[v];
            }
        }
        *self = HeMesh::build(mesh.vertices, mesh.vertex_values, &mesh.faces)?;
        self.corner = corner;
        Ok(())
    }

    /// Compacts the live elements into a [`Mesh`] (vertices and faces in index order).
    pub fn to_mesh(&self) -> Mesh {
        self.compacted().0
    }

    /// The compacted mesh and the new index of each vertex (`NONE`: deleted).
    fn compacted(&self) -> (Mesh, Vec<u32>) {
        let mut map = vec![NONE; self.pos.len()];
        let mut vertices = Vec::new();
        let mut values = Vec::new();
        for (v, slot) in map.iter_mut().enumerate() {
            if self.vertex_alive(v) {
                *slot = vertices.len() as u32;
                vertices.push(self.pos[v]);
                if !self.val.is_empty() {
                    values.push(self.val[v]);
                }
            }
        }
        let faces = (0..self.fhe.len() as u32)
            .filter(|&f| self.fhe[ix(f)] != NONE)
            .map(|f| self.face_verts(f).map(|v| map[ix(v)]))
            .collect();
        let mesh = Mesh {
            vertices,
            faces,
            vertex_values: values,
        };
        (mesh, map)
    }
}
