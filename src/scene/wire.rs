//! A scene as bytes for another process (the workers of `umbra.distributed`, Python's
//! pickle): every field, meshes included, in JSON with exact float round trips, so a
//! worker renders the very scene the caller holds, bit for bit. Read back through
//! [`Scene::validate`], the loaders' own check, after [`check_meshes`], what the OBJ and
//! scene readers check of each mesh as they build it: bytes from elsewhere are input
//! like a scene file.

use super::checks::{bad_vertex, bad_vertex_message};
use super::{HiddenObject, Scene};
use crate::error::{Error, Result};
use std::path::Path;

/// What the bytes are called in messages.
const ORIGIN: &str = "<scene bytes>";

impl Scene {
    /// The scene as bytes ([`Scene::from_wire`] reads them back).
    pub fn to_wire(&self) -> Vec<u8> {
        // Serialising plain data with string keys cannot fail.
        serde_json::to_vec(self).expect("a scene serialises")
    }

    /// A scene from [`Scene::to_wire`]'s bytes, checked like a scene file.
    pub fn from_wire(bytes: &[u8]) -> Result<Scene> {
        let scene: Scene = serde_json::from_slice(bytes).map_err(|e| {
            Error::Invalid(format!(
                "{ORIGIN}: not a scene written by this version of Umbra ({e})"
            ))
        })?;
        check_meshes(&scene)?;
        scene.validate(Path::new(ORIGIN))?;
        Ok(scene)
    }
}

/// What the file readers check of a hidden object as they build it, and the renderers
/// index by without a check: triangles, each naming a vertex; a vertex albedo per vertex;
/// finite vertices; at least one non-degenerate triangle; a falloff in range.
fn check_meshes(scene: &Scene) -> Result<()> {
    for (i, o) in scene.objects.iter().enumerate() {
        check_object(o).map_err(|(field, msg)| {
            Error::field(Path::new(ORIGIN), &format!("objects[{i}].{field}"), msg)
        })?;
    }
    Ok(())
}

/// [`check_meshes`] for object `i`: the failing field (under `objects[i]`) and why.
fn check_object(o: &HiddenObject) -> std::result::Result<(), (&'static str, String)> {
    let (m, name) = (&o.mesh, &o.name);
    let n = m.positions.len();
    if m.triangles.is_empty() {
        return Err(("mesh.triangles", format!("{name} has no triangles")));
    }
    let past = |t: &[u32; 3]| t.iter().copied().find(|&k| k as usize >= n);
    if let Some((t, k)) =
        (m.triangles.iter().enumerate()).find_map(|(t, v)| past(v).map(|k| (t, k)))
    {
        return Err((
            "mesh.triangles",
            format!(
                "triangle {t} of {name} names vertex {k}, and the mesh has {n} vertices (0 to {})",
                n.saturating_sub(1)
            ),
        ));
    }
    if let Some(a) = m.vertex_albedo.as_ref().filter(|a| a.len() != n) {
        return Err((
            "mesh.vertex_albedo",
            format!(
                "{} values for the {n} vertices of {name}: one per vertex",
                a.len()
            ),
        ));
    }
    if let Some(bad) = bad_vertex(&m.positions) {
        return Err(("mesh.positions", bad_vertex_message(name, bad)));
    }
    let mut probe = m.clone();
    if probe.drop_degenerate() == m.triangles.len() {
        return Err((
            "mesh.triangles",
            format!("{name} has no non-degenerate triangles"),
        ));
    }
    o.reflectance
        .with_falloff(o.reflectance.falloff(), "falloff")
        .map(|_| ())
        .map_err(|e| ("reflectance", e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_scene_round_trips_exactly() {
        let mut s = crate::scene::default::default_scene().unwrap();
        s.objects[0].mesh.positions[0].x = 0.1 + f32::EPSILON; // not a short decimal
        s.objects[0].mesh.vertex_albedo = Some(
            (0..s.objects[0].mesh.positions.len())
                .map(|i| 1.0 / (i as f32 + 3.0))
                .collect(),
        );
        let back = Scene::from_wire(&s.to_wire()).unwrap();
        assert_eq!(back.to_wire(), s.to_wire());
        assert_eq!(back.objects[0].mesh, s.objects[0].mesh);
        assert_eq!(back.render, s.render);
        assert_eq!(back.film, s.film);
    }

    #[test]
    fn bad_bytes_are_refused_with_a_reason() {
        let e = Scene::from_wire(b"{\"wall\": 3}").unwrap_err().to_string();
        assert!(
            e.contains("<scene bytes>") && e.contains("not a scene"),
            "{e}"
        );
        let mut s = crate::scene::default::default_scene().unwrap();
        s.film.bin_width_opl = -1.0;
        let e = Scene::from_wire(&s.to_wire()).unwrap_err().to_string();
        assert!(e.contains("bin_width"), "{e}");
    }

    #[test]
    fn meshes_are_checked_like_a_file() {
        let s = crate::scene::default::default_scene().unwrap();
        let bad = |f: &dyn Fn(&mut Scene)| {
            let mut t = s.clone();
            f(&mut t);
            Scene::from_wire(&t.to_wire()).unwrap_err().to_string()
        };
        let n = s.objects[0].mesh.positions.len() as u32;
        let e = bad(&|t| t.objects[0].mesh.triangles[1][2] = n);
        let want = format!("triangle 1 of {} names vertex {n}", s.objects[0].name);
        assert!(
            e.contains("objects[0].mesh.triangles") && e.contains(&want),
            "{e}"
        );
        let e = bad(&|t| t.objects[0].mesh.vertex_albedo = Some(vec![0.5; 2]));
        assert!(
            e.contains("objects[0].mesh.vertex_albedo") && e.contains("2 values"),
            "{e}"
        );
        let e = bad(&|t| t.objects[0].mesh.triangles.clear());
        assert!(e.contains("has no triangles"), "{e}");
        let one = |t: &mut Scene| t.objects[0].mesh.positions.fill(glam::Vec3::ONE);
        assert!(bad(&one).contains("no non-degenerate triangles"));
    }
}
