//! The render options of `umbra.render`, `umbra.grad` and `umbra.torch`: keyword
//! arguments that override the scene's render settings, the same set as the CLI's
//! `umbra render` flags. [`resolve`] is the one place they are read: one more option is
//! one more arm of its `match` (and a line in `_umbra.pyi`).
//!
//! Only conversions are checked here (a name that is not a model, a value of the wrong
//! type); whether a setting suits the scene is the core's to say (`Renderer::new`,
//! `adjoint::gradient`), and its error reaches Python as `UmbraError`.

use crate::UmbraError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::borrow::Cow;
use umbra::scene::{Model, Scene, Visibility};
use umbra::transport::RenderOptions;

/// The option names, in the order `umbra render --help` lists them.
pub const NAMES: &[&str] = &[
    "model",
    "visibility",
    "subdivision",
    "max_error",
    "spp",
    "seed",
    "threads",
    "max_depth",
    "laser_sampling",
    "hidden_geometry_sampling",
    "bsdf_sampling",
];

/// A scene with the options applied, the options as the renderer takes them, and the
/// worker thread count (None: all cores).
pub struct Resolved<'a> {
    /// The caller's scene, or a copy when an option lives in the scene itself
    /// (`max_depth` and the sampling techniques); the copy shares nothing with Python.
    pub scene: Cow<'a, Scene>,
    pub opts: RenderOptions,
    pub threads: Option<usize>,
}

fn value<'py, T>(name: &str, v: &Bound<'py, PyAny>) -> PyResult<T>
where
    T: for<'a> FromPyObject<'a, 'py, Error = PyErr>,
{
    v.extract::<T>().map_err(|e| {
        UmbraError::new_err(format!(
            "{name}: {e} (got {})",
            v.repr().map_or_else(|_| "?".into(), |r| r.to_string())
        ))
    })
}

/// Applies the keyword arguments `options` (None values mean "the scene's") to the
/// scene's render settings.
pub fn resolve<'a>(
    scene: &'a Scene,
    options: Option<&Bound<'_, PyDict>>,
) -> PyResult<Resolved<'a>> {
    let mut r = scene.render.clone();
    let mut threads = None;
    let mut scene_level = false;
    for (key, v) in options.into_iter().flat_map(|d| d.iter()) {
        let key: String = key.extract()?;
        if v.is_none() {
            continue;
        }
        let k = key.as_str();
        match k {
            "model" => {
                let m: String = value(k, &v)?;
                r.model = Model::parse(&m).ok_or_else(|| {
                    UmbraError::new_err(format!("model: '{m}' is not one of tri3, mc3, path, auto"))
                })?;
            }
            "visibility" => {
                let name: String = value(k, &v)?;
                r.visibility = Visibility::parse(&name).ok_or_else(|| {
                    UmbraError::new_err(format!(
                        "visibility: '{name}' is not one of none, centroid, subtriangle"
                    ))
                })?;
            }
            "subdivision" => r.subdivision = value(k, &v)?,
            "max_error" => r.max_error = value(k, &v)?,
            "spp" => r.spp = value(k, &v)?,
            "seed" => r.seed = value(k, &v)?,
            "threads" => threads = Some(value::<usize>(k, &v)?),
            "max_depth" => {
                r.max_bounces = match value::<i64>(k, &v)? {
                    -1 => u32::MAX,
                    d if (3..=u32::MAX as i64 - 1).contains(&d) => d as u32,
                    d => {
                        return Err(UmbraError::new_err(format!(
                            "max_depth: {d} is not -1 (unbounded) or a number of bounces >= 3"
                        )))
                    }
                };
                scene_level = true;
            }
            "laser_sampling" => {
                r.techniques.laser_sampling = value(k, &v)?;
                scene_level = true;
            }
            "hidden_geometry_sampling" => {
                r.techniques.hidden_geometry_sampling = value(k, &v)?;
                scene_level = true;
            }
            "bsdf_sampling" => {
                r.techniques.bsdf_sampling = value(k, &v)?;
                scene_level = true;
            }
            other => {
                return Err(UmbraError::new_err(format!(
                    "unknown option '{other}': the options are {}",
                    NAMES.join(", ")
                )))
            }
        }
    }
    if scene_level {
        let mut s = scene.clone();
        s.render = r;
        let opts = RenderOptions::from_scene(&s);
        return Ok(Resolved {
            scene: Cow::Owned(s),
            opts,
            threads,
        });
    }
    // Only settings `RenderOptions` carries were overridden: no copy of the scene.
    let opts = RenderOptions {
        model: r.model,
        spp: r.spp,
        seed: r.seed,
        visibility: r.visibility,
        subdivision: r.subdivision,
        max_error: r.max_error,
    };
    Ok(Resolved {
        scene: Cow::Borrowed(scene),
        opts,
        threads,
    })
}
