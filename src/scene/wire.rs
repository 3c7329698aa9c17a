//! A scene as bytes for another process (the workers of `umbra.distributed`, Python's
//! pickle): every field, meshes included, in JSON with exact float round trips, so a
//! worker renders the very scene the caller holds, bit for bit. Read back through
//! [`Scene::validate`], the loaders' own check: bytes from elsewhere are input like a
//! scene file.

use super::Scene;
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
        scene.validate(Path::new(ORIGIN))?;
        Ok(scene)
    }
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
}
