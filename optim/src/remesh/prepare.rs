//! Input validation and the documented repairs done before remeshing.

use super::halfedge::{HeMesh, NONE};
use super::RemeshError;
use crate::mesh::Mesh;

/// The validated, repaired input: its half-edge structure and the faces it was built from.
pub(super) struct Prepared {
    pub he: HeMesh,
    pub faces: Vec<[u32; 3]>,
}

/// Checks `mesh` and repairs what can be repaired:
/// - errors: values count neither 0 nor the vertex count, non-finite coordinates, face
///   indices out of range, no usable face, and (after the repairs) edges with more than
///   two faces, inconsistent orientation, non-manifold vertices;
/// - repairs: vertices with bit-identical coordinates are welded (unless welding makes the
///   mesh non-manifold while the unwelded one is fine), faces repeating a vertex are
///   dropped, repeated faces (same three vertices) are kept once, unreferenced vertices
///   are dropped.
pub(super) fn prepare(mesh: &Mesh) -> Result<Prepared, RemeshError> {
    let nv = mesh.vertices.len();
    if !mesh.vertex_values.is_empty() && mesh.vertex_values.len() != nv {
        return Err(RemeshError::ValueCount {
            values: mesh.vertex_values.len(),
            vertices: nv,
        });
    }
    if nv >= NONE as usize {
        return Err(RemeshError::TooLarge);
    }
    if let Some(v) = mesh
        .vertices
        .iter()
        .position(|p| p.iter().any(|x| !x.is_finite()))
    {
        return Err(RemeshError::NonFiniteVertex { vertex: v });
    }
    if let Some(v) = mesh.vertex_values.iter().position(|x| !x.is_finite()) {
        return Err(RemeshError::NonFiniteValue { vertex: v });
    }
    for (f, face) in mesh.faces.iter().enumerate() {
        if let Some(&index) = face.iter().find(|&&i| i as usize >= nv) {
            return Err(RemeshError::IndexOutOfRange {
                face: f,
                index,
                vertex_count: nv,
            });
        }
    }
    let weld = weld_map(&mesh.vertices);
    let welded: Vec<[u32; 3]> = mesh
        .faces
        .iter()
        .map(|f| f.map(|v| weld[v as usize]))
        .collect();
    let welded = clean_faces(&welded);
    let plain = clean_faces(&mesh.faces);
    if plain.is_empty() && welded.is_empty() {
        return Err(RemeshError::NoFaces);
    }
    let build = |faces: Vec<[u32; 3]>| -> Result<Prepared, RemeshError> {
        if faces.is_empty() {
            return Err(RemeshError::NoFaces);
        }
        let he = HeMesh::build(mesh.vertices.clone(), mesh.vertex_values.clone(), &faces)?;
        Ok(Prepared { he, faces })
    };
    if welded == plain {
        return build(plain);
    }
    build(welded).or_else(|_| build(plain))
}

/// For each vertex, the lowest-indexed vertex with bit-identical coordinates (-0 = +0).
fn weld_map(vertices: &[[f64; 3]]) -> Vec<u32> {
    let key = |v: usize| vertices[v].map(|x| (x + 0.0).to_bits());
    let mut order: Vec<usize> = (0..vertices.len()).collect();
    order.sort_by_key(|&v| (key(v), v));
    let mut map: Vec<u32> = (0..vertices.len() as u32).collect();
    for w in 1..order.len() {
        if key(order[w]) == key(order[w - 1]) {
            map[order[w]] = map[order[w - 1]];
        }
    }
    map
}

/// Drops faces that repeat a vertex and later copies of a face with the same vertex set.
fn clean_faces(faces: &[[u32; 3]]) -> Vec<[u32; 3]> {
    let sorted = |f: &[u32; 3]| {
        let mut s = *f;
        s.sort_unstable();
        s
    };
    let mut order: Vec<usize> = (0..faces.len()).collect();
    order.sort_by_key(|&f| (sorted(&faces[f]), f));
    let mut keep = vec![true; faces.len()];
    for w in 0..order.len() {
        let s = sorted(&faces[order[w]]);
        if s[0] == s[1] || s[1] == s[2] || (w > 0 && sorted(&faces[order[w - 1]]) == s) {
            keep[order[w]] = false;
        }
    }
    faces
        .iter()
        .zip(keep)
        .filter(|(_, k)| *k)
        .map(|(f, _)| *f)
        .collect()
}
