//! What a fit needs besides its options, made ready for [`super::request::run`]: the
//! initial and true meshes, the demonstration target (rendered, or read back on a
//! resume), the detector response, the photon-noise floor of a counted measurement, and
//! the warning for fits with a Monte Carlo model.

use super::objective::first_fitted_bin;
use crate::error::{Error, Result};
use crate::film::irf::Irf;
use crate::geometry::SceneGeometry;
use crate::scene::{Model, Scene};
use crate::transport::{RenderOptions, Renderer};
use optim::{Mesh, Schedule};
use std::path::Path;

/// The hidden objects of `scene` as one mesh (`what` names it in the error if there are
/// none).
pub fn to_mesh(scene: &Scene, what: &str) -> Result<Mesh> {
    let mut m = Mesh::default();
    for o in &scene.objects {
        let part = super::fit_mesh(&o.mesh);
        let base = m.vertices.len() as u32;
        m.vertices.extend(part.vertices);
        m.faces
            .extend(part.faces.iter().map(|t| t.map(|i| i + base)));
    }
    if m.faces.is_empty() {
        return Err(Error::Invalid(format!(
            "{what}: the scene has no hidden mesh"
        )));
    }
    Ok(m)
}

/// The demonstration target: the scene's hidden objects through the `path` model.
pub(super) fn render_target(scene: &Scene, spp: u32, out: &Path) -> Result<Vec<f32>> {
    let geom = SceneGeometry::build(scene);
    let opts = RenderOptions {
        model: Model::Path,
        spp,
        ..RenderOptions::from_scene(scene)
    };
    let t = Renderer::new(scene, &geom, &opts)?.render(None)?;
    crate::io::write_npy(&out.join("target.npy"), &t)?;
    Ok(t.data)
}

/// A warning when a stage fits with a Monte Carlo model (`mc3`, `path`): their
/// gradients carry the render's noise, and on the default demonstration the default
/// schedule does not converge with them at any affordable sample count
/// (docs/FITTING.md, "Monte Carlo models"), where the noise-free `tri3` does.
pub(super) fn monte_carlo_warning(
    n: &dyn Fn(&str) -> String,
    model: Model,
    spp: u32,
    schedule: &Schedule,
) -> Option<String> {
    let stage_models = schedule.stages.iter().map(|s| {
        let m = s.model.as_deref().and_then(Model::parse).unwrap_or(model);
        (m, s.spp.unwrap_or(spp))
    });
    let (worst, spp) = stage_models
        .filter(|(m, _)| matches!(m, Model::Mc3 | Model::Path))
        .min_by_key(|(_, spp)| *spp)?;
    Some(format!(
        "warning: {} {} fits with Monte Carlo gradients ({spp} spp): they are noisy, and the \
         fit may not converge (measured on the default demonstration: seen Chamfer 67 mm \
         with mc3 at 16 spp, 24 mm at 1024 spp, 14 mm at 4096 spp in 5 minutes, against \
         1.6 mm with tri3 in 95 s; docs/FITTING.md); fit with {} tri3 (noise-free, the \
         default) unless you need {}'s light transport",
        n("model"),
        worst.name(),
        n("model"),
        worst.name()
    ))
}

/// On a resume of the demonstration: the target written by the run that made the
/// checkpoint (`target.npy`), if it is there, has the scene's shape and is the
/// measurement the checkpoint records (same hash); else `None` with a note, and the
/// target is rendered again.
pub(super) fn saved_target(
    scene: &Scene,
    out: &Path,
    identity: &optim::checkpoint::Identity,
    log: &mut dyn FnMut(&str),
) -> Option<Vec<f32>> {
    let path = out.join("target.npy");
    if !path.exists() {
        log(&format!(
            "{} is missing: rendering the target again",
            path.display()
        ));
        return None;
    }
    let why = match crate::io::read_npy(&path) {
        Err(e) => format!("unreadable ({e})"),
        Ok(t) if t.shape != scene.output_shape() => format!(
            "of shape {:?}, the scene renders {:?}",
            t.shape,
            scene.output_shape()
        ),
        Ok(t) => {
            let want = identity.get("measurement").map(|c| c.hash);
            if want == Some(super::run::measurement_hash(&t.data)) {
                log(&format!("target read back from {}", path.display()));
                return Some(t.data);
            }
            "not the measurement the checkpoint was fitted to".into()
        }
    };
    log(&format!(
        "{} is {why}: rendering the target again",
        path.display()
    ));
    None
}

/// The detector response of `choice` (none, direct, or a `.npy` of taps).
pub(super) fn detector_response(
    n: &dyn Fn(&str) -> String,
    choice: &str,
    scene: &Scene,
    measured: &[f32],
    ignore_before_opl: Option<f32>,
    log: &mut dyn FnMut(&str),
) -> Result<Option<Irf>> {
    let width = scene.film.bin_width_opl as f64;
    Ok(match choice {
        "none" => None,
        "direct" => {
            let first = first_fitted_bin(scene, ignore_before_opl);
            if first == 0 {
                return Err(Error::Invalid(format!(
                    "{} direct: the direct return is the bins before {} OPL, and none are left out",
                    n("irf"),
                    n("ignore_before")
                )));
            }
            let bins = scene.film.temporal_bins as usize;
            let irf = Irf::from_direct_return(measured, bins, first, width).ok_or_else(|| {
                Error::Invalid(format!(
                    "{} direct: the measurement's leading bins hold nothing above its floor",
                    n("irf")
                ))
            })?;
            log(&format!(
                "detector response from the direct return: {} bins of {:.2} mm, {:.0} % of it beyond 24 mm",
                irf.taps.len(),
                1e3 * width,
                100.0 * irf.taps_at(0.024).iter().skip(1).sum::<f64>()
            ));
            Some(irf)
        }
        file => {
            let t = crate::io::read_npy(Path::new(file))?;
            let total: f64 = t.data.iter().map(|&v| v as f64).sum();
            if t.shape.len() != 1
                || t.data.iter().any(|v| !v.is_finite() || *v < 0.0)
                || total <= 0.0
            {
                return Err(Error::Invalid(format!(
                    "{} {file}: expected a 1-D array of non-negative taps (shape {:?})",
                    n("irf"),
                    t.shape
                )));
            }
            Some(Irf {
                bin_width: width,
                taps: t.data.iter().map(|&v| v as f64 / total).collect(),
            })
        }
    })
}

/// The relative L2 error that Poisson noise alone gives, `√(Σ Var M / Σ M²)` over the
/// fitted bins (OPL from `ignore_before_opl` on), for a measurement of photon counts
/// whose `scan x scan` blocks were averaged (`Var M = M / scan²`).
pub(super) fn photon_noise_floor(
    scene: &Scene,
    measured: &[f32],
    scan: u32,
    ignore_before_opl: Option<f32>,
) -> f64 {
    let bins = scene.film.temporal_bins as usize;
    let first = first_fitted_bin(scene, ignore_before_opl);
    let (mut var, mut energy) = (0.0f64, 0.0f64);
    for (i, &m) in measured.iter().enumerate() {
        if i % bins.max(1) >= first {
            var += m as f64 / (scan as f64).powi(2);
            energy += (m as f64).powi(2);
        }
    }
    if energy > 0.0 {
        (var / energy).sqrt()
    } else {
        f64::NAN
    }
}
