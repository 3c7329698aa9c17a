//! The mesh being fitted: `f64` vertex positions (m), triangles as vertex indices, and an
//! optional scalar per vertex (albedo) that remeshing carries along.

use serde::{Deserialize, Serialize};

/// A triangle mesh with an optional per-vertex scalar.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Mesh {
    /// Vertex positions (m).
    pub vertices: Vec<[f64; 3]>,
    /// Triangles, counter-clockwise seen from the side the normal points to.
    pub faces: Vec<[u32; 3]>,
    /// One value per vertex (e.g. albedo), or empty.
    pub vertex_values: Vec<f64>,
}

impl Mesh {
    pub fn new(vertices: Vec<[f64; 3]>, faces: Vec<[u32; 3]>) -> Self {
        Mesh {
            vertices,
            faces,
            vertex_values: Vec::new(),
        }
    }
}
