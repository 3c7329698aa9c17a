//! The one gate between a scene with its options and the renderers.
//!
//! Every entry point (`umbra render`, `grad`, `gradcheck`, `fit`, Python's `render`,
//! `grad`, `fit` and `umbra.torch`) reaches the estimators through
//! [`super::Renderer::prepare`] (the render's [`super::Renderer::new`] and
//! [`crate::adjoint::gradient`] both start there), which calls [`check`] first: a
//! combination refused by one entry point is refused by all, with the same message. Option overrides from the command line or from Python keyword arguments go
//! through [`Overrides::apply`], which checks each value and names the option.
//!
//! What is refused, and why:
//!
//! | combination | pass | reason |
//! | --- | --- | --- |
//! | a retroreflective object, capture not confocal | both | retroreflection is modelled for a co-located laser and sensor only |
//! | a retroreflective object, model not `tri3` | both | only `tri3` models it |
//! | `tri3` with `laser.spot_radius > 0` | both | `tri3` integrates from a point spot |
//! | `path` with BSDF and hidden-geometry sampling both off | both | no path can leave the wall |
//! | `path` with laser sampling off and a point spot | both | no path can hit a point |
//! | `path` with `laser.spot_radius > 0`, laser sampling off and BSDF sampling on | gradient | paths then reach the spot only by landing on it, and a ray-found landing point crossing the spot's rim needs a boundary term replay does not have (with laser sampling on, those paths carry the small MIS share `q/(q + 1/(π r²))`) |
//! | `tri3` or `mc3` with `filter_bounces` other than 3 | both | they make three-bounce light only |
//! | `auto` | gradient | resolve it first ([`super::Renderer::new`] does) |
//! | `spp = 0`, `subdivision` or `max_error` not > 0, `max_depth` < 3 | both | |
//! | no hidden triangles | gradient | nothing to differentiate (a render is zero, with a warning: [`super::silence`]) |
//! | a vertex not finite or beyond `scene::checks::MAX_COORD` | both | the BVH and `f32` OPLs cannot take it |
//! | more memory than the machine has ([`super::budget`]) | both | the size in bytes and the fields that make it |

use super::RenderOptions;
use crate::error::{Error, Result};
use crate::scene::{CaptureType, Model, RenderSettings, Scene, Visibility};

/// Which pass the scene is checked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pass {
    /// The forward render.
    Render,
    /// Gradients (path replay or `tri3`'s exact adjoint).
    Gradient,
}

/// Checks that `opts` can run `scene` in `pass`: the one place such combinations are
/// refused (see the module docs for the table).
pub fn check(scene: &Scene, opts: &RenderOptions, pass: Pass) -> Result<()> {
    check_values(scene.render.max_bounces, opts)?;
    check_reflectance(scene, opts.model)?;
    check_vertices(scene)?;
    if pass == Pass::Gradient && scene.total_hidden_triangles() == 0 {
        return Err(Error::Invalid(
            "gradients: the scene has no hidden objects (objects), so there is no vertex or albedo to differentiate".into(),
        ));
    }
    // `auto` is checked as `tri3`, the smallest footprint it can pick, before its pilot
    // runs; `Renderer::new` checks the model it picks.
    let model = match opts.model {
        Model::Auto => Model::Tri3,
        m => m,
    };
    super::budget::check(scene, &RenderOptions { model, ..*opts }, pass)?;
    let t = &scene.render.techniques;
    let point_spot = scene.laser.spot_radius <= 0.0;
    let problem = match (opts.model, pass) {
        (Model::Tri3, _) if !point_spot => {
            "tri3 model: the laser spot must be a point (laser.spot_radius = 0); use mc3 or path"
        }
        (Model::Path, _) if !t.bsdf_sampling && !t.hidden_geometry_sampling => {
            "path model: bsdf_sampling and hidden_geometry_sampling are both off, so no path can leave the wall"
        }
        (Model::Path, _) if !t.laser_sampling && point_spot => {
            "path model: with laser sampling off, paths must hit the lit spot, which needs laser.spot_radius > 0"
        }
        (Model::Path, Pass::Gradient) if !point_spot && !t.laser_sampling && t.bsdf_sampling => {
            "gradients of the path model with a finite laser spot need laser_sampling (or bsdf_sampling off): paths that reach the spot only by a BSDF-sampled ray would need the spot rim's boundary term"
        }
        (Model::Tri3 | Model::Mc3, _) if scene.render.filter_bounces.is_some_and(|f| f != 3) => {
            "render.filter_bounces: tri3 and mc3 make three-bounce light only, and the filter keeps none of it (their renders ignored the filter); use model path"
        }
        (Model::Auto, Pass::Gradient) => {
            "gradients: model auto must be resolved to tri3, mc3 or path first"
        }
        _ => return Ok(()),
    };
    Err(Error::Invalid(problem.into()))
}

/// The option values every model relies on (also [`Overrides::apply`]'s check, so a bad
/// flag is refused before any work).
fn check_values(max_bounces: u32, opts: &RenderOptions) -> Result<()> {
    let bad = |msg: String| Err(Error::Invalid(msg));
    if opts.spp == 0 {
        return bad("spp: must be at least 1".into());
    }
    if !(opts.subdivision.is_finite() && opts.subdivision > 0.0) {
        return bad(format!(
            "subdivision: must be > 0, got {}",
            opts.subdivision
        ));
    }
    if !(opts.max_error.is_finite() && opts.max_error > 0.0) {
        return bad(format!("max_error: must be > 0, got {}", opts.max_error));
    }
    if max_bounces < 3 {
        return bad(format!(
            "max_depth: NLOS paths need at least 3 bounces, got {max_bounces}"
        ));
    }
    Ok(())
}

/// Vertices the BVH and `f32` OPLs can take: finite and within
/// [`checks::MAX_COORD`](crate::scene::checks::MAX_COORD) (a scene from a file was
/// checked on loading; this catches positions set by a program or a fit step).
fn check_vertices(scene: &Scene) -> Result<()> {
    use crate::scene::checks::{bad_vertex, bad_vertex_message};
    for (i, o) in scene.objects.iter().enumerate() {
        if let Some(bad) = bad_vertex(&o.mesh.positions) {
            let what = format!("objects[{i}] ({})", o.name);
            return Err(Error::Invalid(bad_vertex_message(&what, bad)));
        }
    }
    Ok(())
}

/// Retroreflective objects exist only in the confocal `tri3` model.
fn check_reflectance(scene: &Scene, model: Model) -> Result<()> {
    let Some((i, o)) = scene
        .objects
        .iter()
        .enumerate()
        .find(|(_, o)| o.reflectance.is_retro())
    else {
        return Ok(());
    };
    match retroreflective_problem(scene.capture, model) {
        Some(problem) => Err(Error::Invalid(format!(
            "objects[{i}] ({}): {problem}",
            o.name
        ))),
        None => Ok(()),
    }
}

/// Why a retroreflective surface cannot be rendered with `capture` and `model`, if it
/// cannot (the gate's words, which the fit repeats before it starts).
pub fn retroreflective_problem(capture: CaptureType, model: Model) -> Option<String> {
    if capture != CaptureType::Confocal {
        Some(format!(
            "retroreflective reflectance needs confocal capture (the capture is {})",
            capture.name()
        ))
    } else if model != Model::Tri3 {
        Some(format!(
            "retroreflective reflectance is modelled by tri3 only (the model is {})",
            model.name()
        ))
    } else {
        None
    }
}

/// Render options set from the command line or Python keyword arguments; `None` keeps
/// the scene's value. Names are the CLI's flags without dashes and the Python keywords.
#[derive(Clone, Debug, Default)]
pub struct Overrides {
    /// `tri3`, `mc3`, `path` or `auto`.
    pub model: Option<String>,
    pub spp: Option<i64>,
    pub seed: Option<u64>,
    /// Bounces counting the laser spot and the sensor point; -1 = unbounded.
    pub max_depth: Option<i64>,
    pub laser_sampling: Option<bool>,
    pub hidden_geometry_sampling: Option<bool>,
    pub bsdf_sampling: Option<bool>,
    /// `none`, `centroid` or `subtriangle`.
    pub visibility: Option<String>,
    pub subdivision: Option<f32>,
    pub max_error: Option<f32>,
    /// Test the laser -> `x_l` and `x_s` -> detector lines for occlusion.
    pub visible_legs: Option<bool>,
    /// Gradients: add the visibility boundary terms.
    pub boundary_terms: Option<bool>,
    /// `path`: survival of the Russian roulette before `rr_bounces`: `auto` or a
    /// number in (0, 1].
    pub rr_early_survival: Option<String>,
}

impl Overrides {
    /// Writes the overrides into `scene.render` and returns the render options that
    /// follow, checked by the gate's own value checks (the message naming the option).
    pub fn apply(&self, scene: &mut Scene) -> Result<RenderOptions> {
        self.apply_to(&mut scene.render)
    }

    /// [`Overrides::apply`] on render settings alone (a caller that copies the scene only
    /// when a setting outside [`RenderOptions`] changed).
    pub fn apply_to(&self, r: &mut RenderSettings) -> Result<RenderOptions> {
        let bad = |msg: String| Err(Error::Invalid(msg));
        if let Some(m) = &self.model {
            r.model = match Model::parse(m) {
                Some(m) => m,
                None => return bad(format!("model: '{m}' is not one of tri3, mc3, path, auto")),
            };
        }
        if let Some(s) = self.spp {
            r.spp = match u32::try_from(s) {
                Ok(s) => s,
                Err(_) => {
                    return bad(format!(
                        "spp: must be an integer in [1, {}], got {s}",
                        u32::MAX
                    ))
                }
            };
        }
        r.seed = self.seed.unwrap_or(r.seed);
        if let Some(d) = self.max_depth {
            r.max_bounces = match d {
                -1 => u32::MAX,
                d if (3..=u32::MAX as i64).contains(&d) => d as u32,
                d => return bad(format!("max_depth: must be -1 or >= 3 bounces, got {d}")),
            };
        }
        let t = &mut r.techniques;
        t.laser_sampling = self.laser_sampling.unwrap_or(t.laser_sampling);
        t.hidden_geometry_sampling = self
            .hidden_geometry_sampling
            .unwrap_or(t.hidden_geometry_sampling);
        t.bsdf_sampling = self.bsdf_sampling.unwrap_or(t.bsdf_sampling);
        if let Some(v) = &self.visibility {
            r.visibility = match Visibility::parse(v) {
                Some(v) => v,
                None => {
                    return bad(format!(
                        "visibility: '{v}' is not one of none, centroid, subtriangle"
                    ))
                }
            };
        }
        r.subdivision = self.subdivision.unwrap_or(r.subdivision);
        r.max_error = self.max_error.unwrap_or(r.max_error);
        r.visible_legs = self.visible_legs.unwrap_or(r.visible_legs);
        r.boundary_terms = self.boundary_terms.unwrap_or(r.boundary_terms);
        if let Some(q) = &self.rr_early_survival {
            r.rr_early_survival = match crate::scene::EarlySurvival::parse(q) {
                Ok(q) => q,
                Err(e) => return bad(format!("rr_early_survival: {e}")),
            };
        }
        let opts = RenderOptions::from_settings(r);
        check_values(r.max_bounces, &opts)?;
        Ok(opts)
    }
}
