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
    /// Whether each face's mean vertex value is at least `threshold` times the bright
    /// reference, the 95th percentile of the vertex values (every face when the mesh has
    /// no vertex values). A fitted albedo near zero marks surface the data do not
    /// support; a percentile rather than the largest value, so that a few outlier
    /// vertices (a fit whose albedo is free in scale puts some at a rim) do not make the
    /// rest dark.
    pub fn bright_faces(&self, threshold: f64) -> Vec<bool> {
        if self.vertex_values.len() != self.vertices.len() {
            return vec![true; self.faces.len()];
        }
        let mut sorted = self.vertex_values.clone();
        sorted.sort_by(f64::total_cmp);
        let max = sorted
            .get(((sorted.len() as f64 - 1.0) * 0.95).round() as usize)
            .copied()
            .unwrap_or(0.0);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Dark faces are judged against the 95th percentile of the vertex values: one
    /// outlier vertex does not make the rest of the surface dark.
    #[test]
    fn one_outlier_vertex_does_not_darken_the_rest() {
        // A strip of 40 vertices, 38 faces; values 0.2, one vertex 5.0, the last three 0.01.
        let vertices: Vec<[f64; 3]> = (0..40)
            .map(|i| [(i / 2) as f64, (i % 2) as f64, 0.0])
            .collect();
        let faces: Vec<[u32; 3]> = (0..38u32).map(|i| [i, i + 1, i + 2]).collect();
        let mut values = vec![0.2; 40];
        values[10] = 5.0;
        values[37..].iter_mut().for_each(|v| *v = 0.01);
        let mesh = Mesh {
            vertices,
            faces,
            vertex_values: values,
        };
        let bright = mesh.bright_faces(0.25);
        assert!(bright[..35].iter().all(|&b| b), "{bright:?}");
        assert!(!bright[37], "{bright:?}");
    }
}
