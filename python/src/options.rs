//! The render options of `umbra.render`, `umbra.grad` and `umbra.torch`: keyword
//! arguments that override the scene's render settings, the same set as the CLI's
//! `umbra render` flags. [`resolve`] reads them into the core's
//! [`umbra::transport::gate::Overrides`], the one place the CLI's flags are checked too,
//! so Python and the CLI accept and refuse the same values with the same messages; one
//! more option is one more arm of its `match` (and a line in `_umbra.pyi`).
//!
//! Only conversions are checked here (a value of the wrong type); whether a setting
//! suits the scene is the core's gate to say (`Renderer::new`, `adjoint::gradient`), and
//! its error reaches Python as `UmbraError`.

use crate::UmbraError;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::borrow::Cow;
use umbra::scene::Scene;
use umbra::transport::gate::Overrides;
use umbra::transport::RenderOptions;

/// The option names (the stubs' keyword order).
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
    "visible_legs",
    "boundary_terms",
    "rr_early_survival",
];

/// A scene with the options applied, the options as the renderer takes them, and the
/// worker thread count (None: all cores).
pub struct Resolved<'a> {
    /// The caller's scene, or a copy when an option lives in the scene itself
    /// (`max_depth`, the sampling techniques, `visible_legs`, `boundary_terms`); the copy
    /// shares nothing
    /// with Python.
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
    let mut o = Overrides::default();
    let mut threads = None;
    for (key, v) in options.into_iter().flat_map(|d| d.iter()) {
        let key: String = key.extract()?;
        if v.is_none() {
            continue;
        }
        let k = key.as_str();
        match k {
            "model" => o.model = Some(value(k, &v)?),
            "spp" => o.spp = Some(value(k, &v)?),
            "seed" => o.seed = Some(value(k, &v)?),
            "max_depth" => o.max_depth = Some(value(k, &v)?),
            "laser_sampling" => o.laser_sampling = Some(value(k, &v)?),
            "hidden_geometry_sampling" => o.hidden_geometry_sampling = Some(value(k, &v)?),
            "bsdf_sampling" => o.bsdf_sampling = Some(value(k, &v)?),
            "visibility" => o.visibility = Some(value(k, &v)?),
            "subdivision" => o.subdivision = Some(value(k, &v)?),
            "max_error" => o.max_error = Some(value(k, &v)?),
            "visible_legs" => o.visible_legs = Some(value(k, &v)?),
            "boundary_terms" => o.boundary_terms = Some(value(k, &v)?),
            "rr_early_survival" => {
                o.rr_early_survival = Some(match v.extract::<f64>() {
                    Ok(q) => q.to_string(),
                    Err(_) => value::<String>(k, &v)?,
                })
            }
            "threads" => threads = Some(value::<usize>(k, &v)?),
            other => {
                return Err(UmbraError::new_err(format!(
                    "unknown option '{other}': the options are {}",
                    NAMES.join(", ")
                )))
            }
        }
    }
    let mut r = scene.render.clone();
    let opts = o.apply_to(&mut r).map_err(crate::to_py)?;
    let same_scene = r.max_bounces == scene.render.max_bounces
        && r.techniques == scene.render.techniques
        && r.visible_legs == scene.render.visible_legs
        && r.boundary_terms == scene.render.boundary_terms
        && r.rr_early_survival == scene.render.rr_early_survival;
    let scene = if same_scene {
        // Only settings `RenderOptions` carries changed: no copy of the scene.
        Cow::Borrowed(scene)
    } else {
        let mut s = scene.clone();
        s.render = r;
        Cow::Owned(s)
    };
    Ok(Resolved {
        scene,
        opts,
        threads,
    })
}
