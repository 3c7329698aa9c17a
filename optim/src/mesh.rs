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

impl Mesh {
    /// The mesh as Wavefront OBJ text (`v` lines in vertex order, 1-based `f` lines);
    /// vertex values, when present, follow each `v` as a grey vertex colour.
    pub fn to_obj(&self) -> String {
        let mut s = String::with_capacity(40 * (self.vertices.len() + self.faces.len()));
        s.push_str("# written by umbra fit\n");
        for (i, p) in self.vertices.iter().enumerate() {
            match self.vertex_values.get(i) {
                Some(a) => s.push_str(&format!("v {} {} {} {a} {a} {a}\n", p[0], p[1], p[2])),
                None => s.push_str(&format!("v {} {} {}\n", p[0], p[1], p[2])),
            }
        }
        for f in &self.faces {
            s.push_str(&format!("f {} {} {}\n", f[0] + 1, f[1] + 1, f[2] + 1));
        }
        s
    }
}

impl Mesh {
    /// Whether each face's mean vertex value is at least `threshold` times the largest
    /// vertex value (every face when the mesh has no vertex values). A fitted albedo near
    /// zero marks surface the data do not support.
    pub fn bright_faces(&self, threshold: f64) -> Vec<bool> {
        if self.vertex_values.len() != self.vertices.len() {
            return vec![true; self.faces.len()];
        }
        let max = self.vertex_values.iter().cloned().fold(0.0, f64::max);
        self.faces
            .iter()
            .map(|f| {
                f.iter()
                    .map(|&i| self.vertex_values[i as usize])
                    .sum::<f64>()
                    / 3.0
                    >= threshold * max
            })
            .collect()
    }

    /// The faces [`Mesh::bright_faces`] keeps, unreferenced vertices removed.
    pub fn without_dark_faces(&self, threshold: f64) -> Mesh {
        self.with_faces(&self.bright_faces(threshold))
    }

    /// The faces `keep` marks (one flag per face), with unreferenced vertices removed and
    /// vertex values carried along.
    pub fn with_faces(&self, keep: &[bool]) -> Mesh {
        let values = self.vertex_values.len() == self.vertices.len();
        let mut remap = vec![u32::MAX; self.vertices.len()];
        let mut out = Mesh::default();
        for (f, _) in self.faces.iter().zip(keep).filter(|(_, &k)| k) {
            let g = f.map(|i| {
                let r = &mut remap[i as usize];
                if *r == u32::MAX {
                    *r = out.vertices.len() as u32;
                    out.vertices.push(self.vertices[i as usize]);
                    if values {
                        out.vertex_values.push(self.vertex_values[i as usize]);
                    }
                }
                *r
            });
            out.faces.push(g);
        }
        out
    }
}
