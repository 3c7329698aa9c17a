//! Triangle meshes: world-space positions, triangles, optional per-vertex albedo.
//! Loaded from OBJ with tobj; placed by an affine transform; degenerate triangles
//! (zero area, non-finite) are dropped with a warning, since they cannot be sampled
//! by area and only add work to the BVH.

use crate::error::{Error, Result};
use glam::{Affine3A, Vec3};
use std::path::Path;

#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex albedo in [0, 1], interpolated barycentrically; `None` = object albedo.
    pub vertex_albedo: Option<Vec<f32>>,
}

impl TriMesh {
    /// Reads every object and group of an OBJ file into one mesh (polygons triangulated).
    pub fn load_obj(path: &Path) -> Result<TriMesh> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        Self::parse_obj(&text, path)
    }

    /// Parses OBJ text; `origin` names the source in error messages.
    pub fn parse_obj(text: &str, origin: &Path) -> Result<TriMesh> {
        check_obj_lines(text, origin)?;
        let opts = tobj::LoadOptions {
            triangulate: true,
            ignore_points: true,
            ignore_lines: true,
            ..Default::default()
        };
        let mut reader = std::io::BufReader::new(text.as_bytes());
        let (models, _) =
            tobj::load_obj_buf(&mut reader, &opts, |_| Err(tobj::LoadError::OpenFileFailed))
                .map_err(|e| Error::scene(origin, format!("malformed OBJ: {e}")))?;
        let mut mesh = TriMesh::default();
        // Vertex colours (`v x y z r g b`), if every vertex has them, become per-vertex
        // albedo: the mean of r, g, b (Umbra is monochrome).
        let all_coloured = models
            .iter()
            .all(|m| m.mesh.vertex_color.len() == m.mesh.positions.len());
        let mut colours = Vec::new();
        for m in &models {
            let base = mesh.positions.len() as u32;
            let p = &m.mesh.positions;
            mesh.positions
                .extend(p.chunks_exact(3).map(|c| Vec3::new(c[0], c[1], c[2])));
            if all_coloured {
                colours.extend(
                    m.mesh
                        .vertex_color
                        .chunks_exact(3)
                        .map(|c| (c[0] + c[1] + c[2]) / 3.0),
                );
            }
            let n = (p.len() / 3) as u32;
            for t in m.mesh.indices.chunks_exact(3) {
                if t.iter().any(|&i| i >= n) {
                    return Err(Error::scene(
                        origin,
                        "malformed OBJ: face index out of range",
                    ));
                }
                mesh.triangles.push([base + t[0], base + t[1], base + t[2]]);
            }
        }
        if mesh.triangles.is_empty() {
            return Err(Error::scene(origin, "OBJ has no faces"));
        }
        if all_coloured && !colours.is_empty() {
            if let Some(bad) = colours.iter().position(|a| !(0.0..=1.0).contains(a)) {
                return Err(Error::scene(
                    origin,
                    format!(
                        "vertex colour of vertex {} is outside [0, 1]: it is used as albedo",
                        bad + 1
                    ),
                ));
            }
            mesh.vertex_albedo = Some(colours);
        }
        Ok(mesh)
    }

    pub fn transform(&mut self, m: &Affine3A) {
        for p in &mut self.positions {
            *p = m.transform_point3(*p);
        }
    }

    pub fn triangle(&self, t: usize) -> [Vec3; 3] {
        let [a, b, c] = self.triangles[t];
        [
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        ]
    }

    /// Triangle area (m²).
    pub fn area(&self, t: usize) -> f32 {
        let [a, b, c] = self.triangle(t);
        0.5 * (b - a).cross(c - a).length()
    }

    /// Drops zero-area and non-finite triangles; returns how many went.
    pub fn drop_degenerate(&mut self) -> usize {
        let before = self.triangles.len();
        let pos = &self.positions;
        self.triangles.retain(|&[a, b, c]| {
            let (a, b, c) = (pos[a as usize], pos[b as usize], pos[c as usize]);
            let n = (b - a).cross(c - a);
            let scale = (b - a).length_squared().max((c - a).length_squared());
            n.is_finite() && n.length_squared() > 1e-14 * scale * scale && scale > 0.0
        });
        before - self.triangles.len()
    }
}

/// tobj reports malformed numbers without a line; find the line ourselves so the user
/// sees `file.obj:12: ...`.
fn check_obj_lines(text: &str, origin: &Path) -> Result<()> {
    let mut n_vertices = 0usize;
    for (i, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                n_vertices += 1;
                let coords: Vec<&str> = it.collect();
                if coords.len() < 3 {
                    return Err(Error::line(origin, i + 1, "vertex needs 3 coordinates"));
                }
                for c in &coords[..3] {
                    match c.parse::<f32>() {
                        Ok(v) if v.is_finite() => {}
                        _ => {
                            return Err(Error::line(
                                origin,
                                i + 1,
                                format!("vertex coordinate '{c}' is not a finite number"),
                            ))
                        }
                    }
                }
            }
            Some("f") => {
                let idx: Vec<&str> = it.collect();
                if idx.len() < 3 {
                    return Err(Error::line(origin, i + 1, "face needs at least 3 vertices"));
                }
                for v in idx {
                    let first = v.split('/').next().unwrap_or("");
                    match first.parse::<i64>() {
                        Ok(k) if k > 0 && (k as usize) <= n_vertices => {}
                        Ok(k) if k < 0 && ((-k) as usize) <= n_vertices => {}
                        _ => {
                            return Err(Error::line(
                                origin,
                                i + 1,
                                format!("face vertex '{v}' does not name an earlier vertex"),
                            ))
                        }
                    }
                }
            }
            _ => {}
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_quads_and_drops_degenerate() {
        let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nf 1 2 3 4\nf 1 2 5\n";
        let mut m = TriMesh::parse_obj(obj, Path::new("t.obj")).unwrap();
        assert_eq!(m.triangles.len(), 3);
        assert_eq!(m.drop_degenerate(), 1);
        assert!((m.area(0) + m.area(1) - 1.0).abs() < 1e-6);
    }

    #[test]
    fn vertex_colours_are_albedo() {
        let obj = "v 0 0 0 0.2 0.2 0.2\nv 1 0 0 0.4 0.5 0.6\nv 0 1 0 1 1 1\nf 1 2 3\n";
        let m = TriMesh::parse_obj(obj, Path::new("c.obj")).unwrap();
        let a = m.vertex_albedo.unwrap();
        for (got, want) in a.iter().zip([0.2, 0.5, 1.0]) {
            assert!((got - want).abs() < 1e-6, "{a:?}");
        }
        let plain =
            TriMesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", Path::new("p.obj")).unwrap();
        assert_eq!(plain.vertex_albedo, None);
    }

    #[test]
    fn bad_obj_names_line() {
        let e = TriMesh::parse_obj("v 0 0 0\nv 1 nan 0\n", Path::new("x.obj")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "x.obj:2: vertex coordinate 'nan' is not a finite number"
        );
        let e = TriMesh::parse_obj("v 0 0 0\nf 1 2 3\n", Path::new("x.obj")).unwrap_err();
        assert!(e.to_string().starts_with("x.obj:2:"), "{e}");
    }
}
