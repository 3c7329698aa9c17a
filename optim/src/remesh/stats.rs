//! Mesh quality and topology helpers.

use super::geom::dist2;
use super::halfedge::HeMesh;
use crate::mesh::Mesh;

/// Faces whose indices are all in range and distinct.
fn valid_faces(mesh: &Mesh) -> impl Iterator<Item = [u32; 3]> + '_ {
    let n = mesh.vertices.len();
    mesh.faces.iter().copied().filter(move |f| {
        f.iter().all(|&v| (v as usize) < n) && f[0] != f[1] && f[1] != f[2] && f[2] != f[0]
    })
}

/// Undirected edges `(min, max)` of the valid faces, sorted, one entry per face side.
fn edge_keys(mesh: &Mesh) -> Vec<(u32, u32)> {
    let mut keys: Vec<(u32, u32)> = valid_faces(mesh)
        .flat_map(|f| (0..3).map(move |k| (f[k].min(f[(k + 1) % 3]), f[k].max(f[(k + 1) % 3]))))
        .collect();
    keys.sort_unstable();
    keys
}

/// (min, mean, max) length of the mesh's edges, each edge counted once. Faces with
/// out-of-range or repeated indices are ignored; `(0, 0, 0)` when there is no edge.
/// Non-finite coordinates propagate into the mean.
pub fn edge_length_stats(mesh: &Mesh) -> (f64, f64, f64) {
    let mut keys = edge_keys(mesh);
    keys.dedup();
    if keys.is_empty() {
        return (0.0, 0.0, 0.0);
    }
    let (mut min, mut max, mut sum) = (f64::INFINITY, 0.0f64, 0.0);
    for &(a, b) in &keys {
        let l = dist2(mesh.vertices[a as usize], mesh.vertices[b as usize]).sqrt();
        min = min.min(l);
        max = max.max(l);
        sum += l;
    }
    (min, sum / keys.len() as f64, max)
}

/// Whether the faces form an oriented 2-manifold (with or without boundary): indices in
/// range and distinct in each face, every edge shared by one or two faces, the two faces
/// at an edge oriented consistently, and the faces around each vertex a single fan.
/// Topological only (coordinates are not looked at); a mesh without faces is manifold.
pub fn is_manifold(mesh: &Mesh) -> bool {
    if valid_faces(mesh).count() != mesh.faces.len() {
        return false;
    }
    HeMesh::build(vec![[0.0; 3]; mesh.vertices.len()], Vec::new(), &mesh.faces).is_ok()
}

/// Number of boundary loops: connected components of the boundary edges (edges with
/// exactly one face); for a manifold mesh these are its boundary loops, 0 if it is closed.
/// Faces with out-of-range or repeated indices are ignored.
pub fn boundary_loops(mesh: &Mesh) -> usize {
    let keys = edge_keys(mesh);
    let mut parent: Vec<u32> = (0..mesh.vertices.len() as u32).collect();
    fn root(parent: &mut [u32], mut v: u32) -> u32 {
        while parent[v as usize] != v {
            let up = parent[parent[v as usize] as usize];
            parent[v as usize] = up;
            v = up;
        }
        v
    }
    let mut on_boundary = vec![false; mesh.vertices.len()];
    let mut i = 0;
    while i < keys.len() {
        let mut j = i + 1;
        while j < keys.len() && keys[j] == keys[i] {
            j += 1;
        }
        if j - i == 1 {
            let (a, b) = keys[i];
            on_boundary[a as usize] = true;
            on_boundary[b as usize] = true;
            let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
            if ra != rb {
                parent[ra.max(rb) as usize] = ra.min(rb);
            }
        }
        i = j;
    }
    (0..mesh.vertices.len() as u32)
        .filter(|&v| on_boundary[v as usize] && root(&mut parent, v) == v)
        .count()
}
