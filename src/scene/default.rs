//! The built-in default scene, embedded in the binary so `umbra render` with no scene
//! shows a result at once: `scenes/default.toml` and the mesh it names.

use super::{toml_format, Scene};
use crate::error::{Error, Result};
use crate::geometry::mesh::TriMesh;
use std::path::Path;

pub const DEFAULT_TOML: &str = include_str!("../../scenes/default.toml");
const LETTER_T_OBJ: &str = include_str!("../../scenes/meshes/letter_t.obj");

/// The default scene, parsed from the embedded files (never read from disk).
pub fn default_scene() -> Result<Scene> {
    let origin = Path::new("<built-in default scene>");
    toml_format::parse(DEFAULT_TOML, origin, &|file| match file {
        "meshes/letter_t.obj" => TriMesh::parse_obj(LETTER_T_OBJ, Path::new(file)),
        other => Err(Error::scene(Path::new(other), "not embedded in the binary")),
    })
}
