//! Mitsuba XML importer (placeholder until implemented).
use super::Scene;
use crate::error::{Error, Result};
use std::path::Path;

pub fn load(path: &Path) -> Result<Scene> {
    Err(Error::scene(path, "Mitsuba XML import is not implemented yet"))
}
