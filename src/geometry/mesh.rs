//! Triangle meshes: world-space positions, triangles, optional per-vertex albedo.
//! Loaded from OBJ (own reader, vertices in file order); placed by an affine transform; degenerate triangles
//! (zero area, non-finite) are dropped with a warning, since they cannot be sampled
//! by area and only add work to the BVH.

use crate::error::{Error, Result};
use glam::{Affine3A, Vec3};
use std::path::Path;

#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    pub positions: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex albedo in [0, 1], interpolated barycentrically; `None` = object albedo.
    pub vertex_albedo: Option<Vec<f32>>,
}

/// The vertex index (0-based) of one `f` entry `v`, `v/vt`, `v//vn` or `v/vt/vn`, given
/// `n` vertices so far. The `vt` and `vn` parts are not used, but must be integers when
/// present, so a malformed line (`f 1/2/3/4 2// 3/x`) is refused rather than half read.
fn face_vertex(entry: &str, n: i64) -> std::result::Result<u32, String> {
    let parts: Vec<&str> = entry.split('/').collect();
    if parts.len() > 3 {
        return Err("has more than v/vt/vn".into());
    }
    let v = parts[0];
    let k = match v.parse::<i64>() {
        Ok(k) if k > 0 && k <= n => k - 1,
        Ok(k) if k < 0 && -k <= n => n + k,
        _ => return Err("does not name an earlier vertex".into()),
    };
    if let Some(bad) = parts[1..]
        .iter()
        .find(|p| !p.is_empty() && p.parse::<i64>().map_or(true, |i| i == 0))
    {
        return Err(format!(
            "has a texture or normal index '{bad}' that is not a non-zero integer"
        ));
    }
    if parts.len() > 1 && parts[parts.len() - 1].is_empty() {
        return Err("ends with '/' (write v, v/vt, v//vn or v/vt/vn)".into());
    }
    Ok(k as u32)
}

impl TriMesh {
    /// Reads every object and group of an OBJ file into one mesh (polygons triangulated).
    pub fn load_obj(path: &Path) -> Result<TriMesh> {
        let text = crate::io::read_text(path, "an OBJ mesh")?;
        Self::parse_obj(&text, path)
    }

    /// Parses OBJ text; `origin` names the source in error messages.
    ///
    /// Vertices keep the order of the file's `v` lines (unused ones too), so vertex `i`
    /// of the mesh, and row `i` of a vertex gradient, is the file's `i`-th `v` line.
    /// Faces are fanned into triangles `(a, b, c), (a, c, d), …`; negative indices count
    /// back from the last vertex; `vt`/`vn` indices and every other statement are ignored.
    /// (Own reader rather than tobj: tobj renumbers vertices by first use and drops unused
    /// ones, which breaks that correspondence.)
    pub fn parse_obj(text: &str, origin: &Path) -> Result<TriMesh> {
        let mut mesh = TriMesh::default();
        // Vertex colours (`v x y z r g b`), if every vertex has them, become per-vertex
        // albedo: the mean of r, g, b (Umbra is monochrome).
        let mut colours = Vec::new();
        let mut all_coloured = true;
        // Lines of the first vertex with a colour and the first without one.
        let (mut first_coloured, mut first_plain) = (None, None);
        let mut face = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let at = |msg: String| Error::line(origin, i + 1, msg);
            let mut it = line.split_whitespace();
            match it.next() {
                Some("v") => {
                    let fields: Vec<&str> = it.collect();
                    if fields.len() < 3 {
                        return Err(at("vertex needs 3 coordinates".into()));
                    }
                    let mut xyz = [0.0f32; 3];
                    for (x, c) in xyz.iter_mut().zip(&fields) {
                        *x = match c.parse::<f32>() {
                            Ok(v) if v.is_finite() => v,
                            _ => {
                                return Err(at(format!(
                                    "vertex coordinate '{c}' is not a finite number"
                                )))
                            }
                        };
                    }
                    mesh.positions.push(Vec3::from_array(xyz));
                    let rgb: Option<Vec<f32>> = (fields.len() >= 6)
                        .then(|| fields[3..6].iter().map(|c| c.parse().ok()).collect())
                        .flatten();
                    match rgb {
                        Some(rgb) => {
                            first_coloured.get_or_insert(i + 1);
                            colours.push(rgb.iter().sum::<f32>() / 3.0);
                        }
                        None => {
                            first_plain.get_or_insert(i + 1);
                            all_coloured = false;
                        }
                    }
                }
                Some("f") => {
                    face.clear();
                    let n = mesh.positions.len() as i64;
                    for v in it {
                        face.push(
                            face_vertex(v, n).map_err(|m| at(format!("face vertex '{v}' {m}")))?,
                        );
                    }
                    if face.len() < 3 {
                        return Err(at("face needs at least 3 vertices".into()));
                    }
                    for k in 1..face.len() - 1 {
                        mesh.triangles.push([face[0], face[k], face[k + 1]]);
                    }
                }
                _ => {}
            }
        }
        if mesh.triangles.is_empty() {
            return Err(Error::scene(origin, "OBJ has no faces"));
        }
        // Colours on some vertices only have no albedo meaning for the rest: refused
        // rather than dropped.
        if let (Some(c), Some(p)) = (first_coloured, first_plain) {
            return Err(Error::scene(
                origin,
                format!(
                    "{} of {} vertices have colours (v x y z r g b, read as albedo; first at line {c}), the rest not (first at line {p}): give every vertex a colour, or none",
                    colours.len(),
                    mesh.positions.len()
                ),
            ));
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
    fn keeps_the_files_vertex_order() {
        let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nv 0 0 1\nf 5 2 3\nf 1/1 2/2/2 -1//3\n";
        let m = TriMesh::parse_obj(obj, Path::new("o.obj")).unwrap();
        assert_eq!(m.positions.len(), 5);
        assert_eq!(m.positions[3], Vec3::splat(5.0));
        assert_eq!(m.triangles, vec![[4, 1, 2], [0, 1, 4]]);
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
        let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        for (face, why) in [
            ("f 1/2/3/4 2 3", "'1/2/3/4' has more than v/vt/vn"),
            ("f 1 2// 3", "'2//' ends with '/'"),
            ("f 1 2 3/x", "'3/x' has a texture or normal index 'x'"),
            ("f 1 2 3/", "'3/' ends with '/'"),
            ("f 1 2 3/0", "'3/0' has a texture or normal index '0'"),
        ] {
            let e = TriMesh::parse_obj(&format!("{tri}{face}\n"), Path::new("x.obj"))
                .unwrap_err()
                .to_string();
            assert!(
                e.starts_with("x.obj:4: face vertex ") && e.contains(why),
                "{face}: {e}"
            );
        }
        for ok in ["f 1/1 2/2/2 3//3", "f -3 -2 -1"] {
            TriMesh::parse_obj(&format!("{tri}{ok}\n"), Path::new("x.obj")).unwrap();
        }
    }
}
