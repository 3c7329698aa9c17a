//! A whole fit: the initial mesh, the schedule's stages through `optim::fit` with
//! Umbra's renderer as the objective, and the outputs in the output directory:
//!
//! - `mesh.obj`: the fitted surface (world space, m; faces fitted dark, faces no
//!   measurement lights and sees, and faces whose signal is within the noise, dropped),
//!   and
//!   `mesh_all.obj` with every face and its albedo as vertex colour;
//! - `loss.csv` and `loss.png`: the loss per iteration (data term and total), stage
//!   boundaries marked;
//! - `albedo.npy`, `depth.npy`: the fitted surface seen from the wall ([`super::seen`]):
//!   per scan point (float32 `(ny, nx)`, `[iy, ix]` in the measurement's scan order) the
//!   albedo and depth (m) of the first face along the wall normal, NaN where none;
//!   `albedo.png` that albedo seen from the wall; `reconstruction.png` the fitted albedo
//!   and depth next to Umbra's LCT of the measurement (a filtered backprojection if not
//!   confocal; `reconstruction` module doc); a failure to draw a picture is a warning;
//! - `transients.png`: measured and fitted transients side by side (streak images of
//!   the middle scan row, the fitted one times the fitted scale), and their difference;
//! - `checkpoint/`: the resumable state (see `optim::fit`), stamped with the fit's
//!   identity ([`identity`]): a resume with another scene, measurement, model or option
//!   is refused, naming what differs.

use super::capture_options::CaptureOptions;
use super::determined::face_determination;
use super::init::{depth_from_data, plane, sphere};
use super::intensity::{Intensity, IntensityModel};
use super::objective::{first_fitted_bin, hidden_object, zero_leading_bins, UmbraObjective};
use super::outputs::{relative_l2, write_loss, write_transients};
use super::reconstruction::{backprojection_mesh, write_reconstruction_png};
use super::resolution::{at_resolution, ScanReduce};
use super::seen::{seen_surface, write_seen, SeenSurface};
use super::support::supported_faces;
use crate::error::{Error, Result};
use crate::geometry::accel::SceneGeometry;
use crate::scene::{Model, Scene};
use crate::transport::RenderOptions;
use optim::checkpoint::{write_atomic, Fnv64, Identity, LossRecord};
use optim::fit::{FitError, Progress};
use optim::{Mesh, MeshObjective, ObjectiveFactory, Schedule, SolverKind, Stage};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Faces darker than this fraction of the brightest vertex are dropped from `mesh.obj`.
pub const DARK: f64 = 0.25;

/// Where the fit starts.
#[derive(Clone, Debug)]
pub enum Init {
    /// A square grid parallel to the wall at the data's depth.
    Plane,
    /// An icosphere in front of the scan centre at the data's depth.
    Sphere,
    /// A given mesh (e.g. the scene's hidden object).
    Mesh(Mesh),
    /// The height field of a filtered backprojection's depth map (`crate::recon`).
    Backprojection,
    /// The height field of the light-cone transform's depth map (confocal captures).
    Lct,
}

/// Settings of a fit besides the schedule.
#[derive(Clone, Debug)]
pub struct FitConfig {
    pub schedule: Schedule,
    pub init: Init,
    /// The model stages use unless they name their own (`auto` means `tri3`).
    pub model: Model,
    pub spp: u32,
    /// Fit the intensity scale (real data; false when the measurement's absolute scale
    /// matches Umbra's radiometry) and a constant background (dark counts, ambient
    /// light), both in closed form (`objective` module doc).
    pub intensity: IntensityModel,
    pub two_sided: bool,
    /// Albedo of the fitted surface (absorbed by the scale when that is fitted).
    pub albedo: f32,
    pub resume: bool,
    /// Leave OPLs below this (m) out of the fit (residual direct light in real captures;
    /// the LCT code zeroes its first 600 bins, 0.72 m).
    pub ignore_before_opl: Option<f32>,
    /// Detector timing jitter `σ` (OPL, m) blurred into the render (0: none).
    pub jitter_opl: f64,
    /// The detector's measured impulse response (replaces the jitter Gaussian).
    pub irf: Option<crate::film::irf::Irf>,
    /// Fit an unknown time offset `|δ| ≤` this (OPL, m; needs `jitter_opl > 0`).
    pub time_offset_max_opl: f64,
    /// How the fitted surface reflects.
    pub reflectance: crate::scene::Reflectance,
    /// The measurement is photon counts whose `n x n` scan blocks were averaged:
    /// `Some(n)` (Poisson noise, `Var M = M / n²`). Faces whose signal is within that
    /// noise are left out of `mesh.obj` ([`super::determined`]); `None` (a render, data of
    /// unknown noise): no face is left out for it.
    pub photon_counts: Option<u32>,
    /// A real capture's calibrated model ([`super::capture`]): response, gain field,
    /// floor, direct tails, likelihood; replaces `intensity`, `jitter_opl`, `irf` and
    /// `time_offset_max_opl` when present.
    pub capture: Option<CaptureOptions>,
}

/// What a fit produced.
#[derive(Clone, Debug)]
pub struct FitReport {
    /// The fitted surface: [`FitReport::full_mesh`] without faces whose fitted albedo
    /// is below [`DARK`] of the brightest, without faces no measurement lights and
    /// sees ([`super::support`]) and without faces whose signal is within the noise
    /// ([`super::determined`]).
    pub mesh: Mesh,
    pub full_mesh: Mesh,
    pub history: Vec<LossRecord>,
    pub seconds: f64,
    /// The loss `‖s H + b − M‖² / ‖M‖²` over the fitted bins of the final mesh at full
    /// resolution (its square root is the relative L2 error).
    pub final_loss: f64,
    /// `‖μ − M‖ / ‖M‖` of the final fitted transient `μ` over the fitted bins (the
    /// square root of `final_loss` when the loss is L2).
    pub relative_l2: f64,
    /// The Poisson deviance per fitted bin, when that is the loss (a perfect model of
    /// counts scores about 1).
    pub deviance: Option<f64>,
    /// The final mesh's intensity scale and background.
    pub intensity: Intensity,
    /// The fitted time offset (OPL, m; 0 unless searched).
    pub time_offset_opl: f64,
    /// The detector response calibrated on the final mesh (with a capture model).
    pub response: Option<crate::film::response::Response>,
    /// The capture model's gain, floor and tail coefficients on the final mesh, by name
    /// (empty without one; `PointBackground::coefficients`).
    pub nuisance: Vec<(String, f64)>,
    /// The capture model's floor per scan point on the final mesh (counts per bin of the
    /// fitted measurement, in the measurement's scan order; `floor.npy`; empty without
    /// one).
    pub floors: Vec<f64>,
    /// The loss at the held-out scan points of the final mesh (NaN: none held out).
    pub held_out_loss: f64,
    pub rejected_steps: u64,
    /// Faces left out of `mesh` because no measurement lights and sees them
    /// ([`super::support`]), besides the dark ones.
    pub unsupported_faces: usize,
    /// Faces left out of `mesh` because their signal is within the noise
    /// ([`super::determined`]), besides the dark and unsupported ones.
    pub undetermined_faces: usize,
    /// Per face of [`FitReport::full_mesh`]: its cluster's signal-to-noise over the
    /// noise its parameters could absorb (below 1: undetermined, left out of `mesh`; 0:
    /// not tested, left out as dark or unsupported). See [`super::determined`]. Empty
    /// when the measurement is not photon counts (no noise model: nothing left out).
    pub face_determination: Vec<f64>,
    /// The final mesh's fitted transient at full resolution, `s K H + b` (scale,
    /// detector response and background applied; bins left out of the fit are zero), in
    /// the measurement's layout.
    pub render: Vec<f32>,
    /// The fitted surface seen from the wall (`albedo.npy`, `depth.npy`; [`super::seen`]).
    pub seen: SeenSurface,
    pub files: Vec<PathBuf>,
}

/// The default coarse-to-fine schedule: Adam on a coarse grid (time bins x4, scan
/// points x2) with a soft large-steps parameterisation (λ = 2) and a large step
/// (0.03), which lets the mesh bend to the data; remeshing to 0.4 of the mean edge, then
/// Adam with albedo at half the time resolution; L-BFGS at full time resolution on the
/// coarse scan; L-BFGS at full resolution. λ and the step sizes come from the sweep in
/// docs/FITTING.md ("Choosing the schedule").
pub fn default_schedule() -> Schedule {
    let stage = |iters, solver, lr, time, scan, fit_albedo, remesh_factor| Stage {
        large_steps: 2.0,
        fit_albedo,
        remesh_factor,
        time_downsample: time,
        scan_downsample: scan,
        ..Stage::new(iters, solver, lr)
    };
    Schedule {
        stages: vec![
            stage(100, SolverKind::Adam, 0.03, 4, 2, false, None),
            stage(60, SolverKind::Adam, 0.01, 2, 2, true, Some(0.4)),
            stage(20, SolverKind::Lbfgs, 0.0, 1, 2, true, None),
            stage(10, SolverKind::Lbfgs, 0.0, 1, 1, true, None),
        ],
        checkpoint_every: 5,
    }
}

struct Factory<'a> {
    scene: &'a Scene,
    /// The measurement with its leading bins still in: the capture model's `D_p` sums
    /// the direct return there; each stage zeroes them for its objective.
    measured: &'a [f32],
    cfg: &'a FitConfig,
    /// `calibration.csv`'s rows: every response model tried, per stage built.
    calibrations: std::cell::RefCell<Vec<String>>,
}

impl Factory<'_> {
    /// The objective of `stage`; with a capture model, its response is calibrated on
    /// `start` rendered (where the stage's bins resolve it, [`super::capture`]).
    fn build(&self, stage: &Stage, start: &Mesh) -> Result<UmbraObjective> {
        let (scene, measured) = at_resolution(
            self.scene,
            self.measured,
            stage.time_downsample,
            stage.scan_downsample,
            ScanReduce::Subsample,
        )?;
        let model = match &stage.model {
            Some(name) => Model::parse(name).ok_or_else(|| {
                Error::Invalid(format!("stage model '{name}': expected tri3, mc3 or path"))
            })?,
            None => self.cfg.model,
        };
        let options = RenderOptions {
            model,
            spp: stage.spp.unwrap_or(self.cfg.spp),
            ..RenderOptions::from_scene(&scene)
        };
        let first_bin = first_fitted_bin(&scene, self.cfg.ignore_before_opl);
        let grid = (self.scene.scan.nx as usize, self.scene.scan.ny as usize);
        let capture = self.cfg.capture.as_ref().map(|o| {
            o.at_stage(
                &scene,
                &measured,
                first_bin,
                stage.scan_downsample as usize,
                grid,
            )
        });
        let mut measured = measured;
        zero_leading_bins(&mut measured, scene.film.temporal_bins as usize, first_bin);
        let mut objective = UmbraObjective {
            first_bin,
            scene,
            measured,
            options,
            intensity: self.cfg.intensity,
            albedo: self.cfg.albedo,
            two_sided: self.cfg.two_sided,
            reflectance: self.cfg.reflectance,
            jitter_opl: self.cfg.jitter_opl,
            irf: self.cfg.irf.clone(),
            time_offset_max_opl: self.cfg.time_offset_max_opl,
            capture,
        };
        if let (Some(options), Some(mut capture)) = (&self.cfg.capture, objective.capture.take()) {
            if options.calibrates_at(capture.bin_width) {
                let (_, _, _, raw) = objective.raw(start)?;
                let label = format!(
                    "{},{},{}",
                    stage.time_downsample, stage.scan_downsample, capture.bin_width
                );
                let tried = capture.calibrate(&raw, &objective.measured, &options.prior);
                self.calibrations
                    .borrow_mut()
                    .extend(tried.iter().map(|c| format!("{label},{}", c.csv_row())));
            }
            objective.capture = Some(capture);
        }
        Ok(objective)
    }
}

impl ObjectiveFactory for Factory<'_> {
    fn objective(
        &mut self,
        stage: &Stage,
        _index: usize,
        start: &Mesh,
    ) -> std::result::Result<Box<dyn MeshObjective>, String> {
        self.build(stage, start)
            .map(|o| Box::new(o) as Box<dyn MeshObjective>)
            .map_err(|e| e.to_string())
    }
}

/// The hash of a measurement as the checkpoints record it (FNV-1a 64 of its `f32` bits,
/// length first).
pub fn measurement_hash(measured: &[f32]) -> u64 {
    Fnv64::new().f32s(measured).finish()
}

/// What a fit's checkpoints depend on besides the schedule and the initial mesh (which
/// `optim::fit` adds): the scene (its canonical content after defaults: the `Debug`
/// text of the loaded [`Scene`], whose floats print exactly, warnings left out), the
/// measurement as fitted (its `f32` bits), the model with its samples per measurement,
/// and every other option of `cfg` that changes the result (intensity model, albedo,
/// sidedness, ignored bins, jitter, detector response, time offset, reflectance). Each
/// is a separate FNV-1a 64 hash, so a refusal names what differs.
pub fn identity(scene: &Scene, measured: &[f32], cfg: &FitConfig) -> Identity {
    let canonical = Scene {
        warnings: Vec::new(),
        ..scene.clone()
    };
    let scene_text = format!("{canonical:?}");
    let total: f64 = measured.iter().map(|&v| v as f64).sum();
    let model = format!("{}, {} spp", cfg.model.name(), cfg.spp);
    let options = format!(
        "intensity {:?}, albedo {}, two-sided {}, ignore before {:?} m, jitter {} m, time offset {} m, reflectance {:?}, capture model {:?}",
        cfg.intensity,
        cfg.albedo,
        cfg.two_sided,
        cfg.ignore_before_opl,
        cfg.jitter_opl,
        cfg.time_offset_max_opl,
        cfg.reflectance,
        cfg.capture
    );
    let irf = format!("{:?}", cfg.irf);
    let options_hash = Fnv64::new()
        .field(options.as_bytes())
        .field(irf.as_bytes())
        .finish();
    let options_summary = match &cfg.irf {
        Some(k) => format!("{options}, detector response of {} taps", k.taps.len()),
        None => options,
    };
    Identity::default()
        .with(
            "scene",
            Fnv64::new().field(scene_text.as_bytes()).finish(),
            format!(
                "{} x {} scan points, {} bins of {} m, {} hidden objects",
                scene.scan.nx,
                scene.scan.ny,
                scene.film.temporal_bins,
                scene.film.bin_width_opl,
                scene.objects.len()
            ),
        )
        .with(
            "measurement",
            measurement_hash(measured),
            format!("{} values summing to {total:.6e}", measured.len()),
        )
        .with(
            "model",
            Fnv64::new().field(model.as_bytes()).finish(),
            model,
        )
        .with("options", options_hash, options_summary)
}

/// The initial mesh of `cfg.init` for this measurement, whose bins before `first_bin`
/// are left out of the fit.
pub fn initial_mesh(
    scene: &Scene,
    measured: &[f32],
    first_bin: usize,
    init: &Init,
) -> Result<Mesh> {
    let depth = || {
        depth_from_data(scene, measured).ok_or_else(|| {
            Error::Invalid("the measurement has no signal to place the initial mesh".into())
        })
    };
    Ok(match init {
        Init::Plane => plane(scene, depth()?, 0.5, 8),
        Init::Sphere => {
            let r = 0.15 * scene.scan.axis_u.length().min(scene.scan.axis_v.length());
            sphere(scene, depth()?, r, 2)
        }
        Init::Mesh(m) => m.clone(),
        Init::Backprojection => backprojection_mesh(scene, measured, first_bin)?,
        Init::Lct => super::reconstruction::lct_mesh(scene, measured, first_bin)?,
    })
}

/// The spacing of `scene`'s scan points (m): the smaller of its two axes'.
pub fn scan_pitch(scene: &Scene) -> f64 {
    let s = &scene.scan;
    let u = f64::from(s.axis_u.length()) / f64::from(s.nx.max(1));
    let v = f64::from(s.axis_v.length()) / f64::from(s.ny.max(1));
    match (s.nx > 1, s.ny > 1) {
        (true, true) => u.min(v),
        (true, false) => u,
        (false, true) => v,
        (false, false) => u.max(v),
    }
}

/// `schedule` with every stage's `remesh_pitch` turned into `remesh`: that many
/// [`scan_pitch`]es of `scene` (the scan as fitted, after `--bin`).
pub fn with_scan_pitch(schedule: &Schedule, scene: &Scene) -> Schedule {
    let pitch = scan_pitch(scene);
    let mut out = schedule.clone();
    for stage in &mut out.stages {
        if let Some(k) = stage.remesh_pitch.take() {
            stage.remesh = Some(k * pitch);
        }
    }
    out
}

/// Isotropic remeshing between stages (`optim::remesh`): splits, collapses, flips and
/// tangential relaxation to the target edge, boundary kept, per-vertex albedo carried.
fn remesh(mesh: &Mesh, edge: f64) -> std::result::Result<Mesh, String> {
    optim::remesh::remesh(mesh, &optim::remesh::RemeshOptions::new(edge)).map_err(|e| e.to_string())
}

/// Runs the fit of `cfg` against `measured` (the scene's output layout) and writes the
/// outputs into `out`.
pub fn fit(
    scene: &Scene,
    measured: &[f32],
    cfg: &FitConfig,
    out: &Path,
    progress: Progress,
) -> Result<FitReport> {
    let start = Instant::now();
    let base = Scene {
        objects: Vec::new(),
        ..scene.clone()
    };
    if base.num_measurements() * base.film.temporal_bins as usize != measured.len() {
        return Err(Error::Invalid(format!(
            "the measurement has {} values; the scene's capture has {} measurements x {} bins",
            measured.len(),
            base.num_measurements(),
            base.film.temporal_bins
        )));
    }
    if (cfg.intensity.background == super::Background::PerPoint) != cfg.capture.is_some() {
        return Err(Error::Invalid(
            "the per-point background is the capture model's: FitConfig needs `capture` (fit::capture_options) with `Background::PerPoint`, and only with it".into(),
        ));
    }
    if let Some(i) = measured.iter().position(|v| !v.is_finite()) {
        return Err(Error::Invalid(format!(
            "the measurement has a non-finite value at flat index {i}"
        )));
    }
    let identity = identity(scene, measured, cfg);
    let unzeroed = measured;
    let mut measured = measured.to_vec();
    let first = first_fitted_bin(&base, cfg.ignore_before_opl);
    zero_leading_bins(&mut measured, base.film.temporal_bins as usize, first);
    if measured.iter().all(|&v| v == 0.0) {
        return Err(Error::Invalid(format!(
            "the measurement is zero in every bin the fit uses (from OPL {:.3} m): nothing to fit (a demonstration target is zero when the scene's hidden objects are beyond the film's last bin, OPL {:.3} m)",
            base.film.start_opl + first as f32 * base.film.bin_width_opl,
            base.film.start_opl + base.film.temporal_bins as f32 * base.film.bin_width_opl
        )));
    }
    let measured = &measured[..];
    let schedule = with_scan_pitch(&cfg.schedule, &base);
    let last_stage = schedule
        .stages
        .last()
        .ok_or_else(|| Error::Invalid("the fit schedule has no stage".into()))?;
    let initial = initial_mesh(&base, measured, first, &cfg.init)?;
    let mut factory = Factory {
        scene: &base,
        measured: unzeroed,
        cfg,
        calibrations: Default::default(),
    };
    let dir = out.join("checkpoint");
    let outcome = optim::fit(
        &initial,
        &schedule,
        &mut factory,
        &remesh,
        &dir,
        cfg.resume,
        &identity,
        progress,
    )
    .map_err(|e| match e {
        FitError::Interrupted { .. } => Error::Cancelled,
        other => Error::Invalid(format!("fit: {other}")),
    })?;
    let mut files = Vec::new();
    // The final mesh at full resolution.
    let full = Stage {
        time_downsample: 1,
        scan_downsample: 1,
        ..last_stage.clone()
    };
    let objective = factory.build(&full, &outcome.mesh)?;
    let rendered = objective.render(&outcome.mesh)?;
    let (render, final_loss, intensity, time_offset_opl) = (
        rendered.compared,
        rendered.loss,
        rendered.intensity,
        rendered.time_offset_opl,
    );
    // Faces the data drove dark, faces no measurement lights and sees (`support`), and
    // faces whose signal the data cannot tell from noise (`determined`) are not surface
    // the data support: mesh.obj drops them, mesh_all.obj keeps all.
    let mut fitted = base.clone();
    fitted.objects = vec![hidden_object(
        &outcome.mesh,
        cfg.albedo,
        cfg.two_sided,
        cfg.reflectance,
    )];
    let supported = supported_faces(&fitted, &SceneGeometry::build(&fitted));
    let bright = outcome.mesh.bright_faces(DARK);
    let unsupported_faces = supported
        .iter()
        .zip(&bright)
        .filter(|(s, b)| **b && !**s)
        .count();
    let candidates: Vec<bool> = supported
        .iter()
        .zip(&bright)
        .map(|(s, b)| *s && *b)
        .collect();
    let face_determination = match cfg.photon_counts {
        Some(n) => face_determination(
            &objective,
            &outcome.mesh,
            &candidates,
            &render,
            &intensity,
            time_offset_opl,
            n,
        )?,
        None => Vec::new(),
    };
    let keep: Vec<bool> = candidates
        .iter()
        .enumerate()
        .map(|(f, c)| *c && face_determination.get(f).is_none_or(|d| *d >= 1.0))
        .collect();
    let undetermined_faces = candidates
        .iter()
        .zip(&keep)
        .filter(|(c, k)| **c && !**k)
        .count();
    let surface = outcome.mesh.with_faces(&keep);
    for (name, mesh) in [("mesh.obj", &surface), ("mesh_all.obj", &outcome.mesh)] {
        let path = out.join(name);
        write_atomic(&path, mesh.to_obj().as_bytes()).map_err(|e| Error::io(&path, e))?;
        files.push(path);
    }
    // The fitted surface seen from the wall: albedo.npy, depth.npy, albedo.png.
    let seen = seen_surface(&base, &outcome.mesh, cfg.albedo);
    files.extend(write_seen(out, &base, &seen)?);
    files.extend(write_loss(out, &outcome.history)?);
    let (nx, ny) = (base.scan.nx as usize, base.scan.ny as usize);
    if rendered.floors.len() == nx * ny {
        let path = out.join("floor.npy");
        let values: Vec<f32> = rendered.floors.iter().map(|&f| f as f32).collect();
        let bytes = super::seen::npy(&values, ny, nx, &path)?;
        write_atomic(&path, &bytes).map_err(|e| Error::io(&path, e))?;
        files.push(path);
    }
    if cfg.capture.is_some() {
        let path = out.join("calibration.csv");
        let mut csv = format!(
            "time_downsample,scan_downsample,bin_width_m,{}\n",
            super::capture::Candidate::CSV_HEADER
        );
        factory
            .calibrations
            .borrow()
            .iter()
            .for_each(|r| csv.push_str(&format!("{r}\n")));
        write_atomic(&path, csv.as_bytes()).map_err(|e| Error::io(&path, e))?;
        files.push(path);
    }
    files.push(write_transients(out, &base, measured, &rendered.model)?);
    // The picture is a by-product: the fit's results must not be lost over it.
    let picture = out.join("reconstruction.png");
    match write_reconstruction_png(&picture, &base, measured, first, &seen) {
        Ok(()) => files.push(picture),
        Err(e) => eprintln!("umbra fit: warning: {} not written: {e}", picture.display()),
    }
    let bins = base.film.temporal_bins as usize;
    let relative_l2 = relative_l2(&rendered.model, measured, bins, first);
    let deviance = cfg
        .capture
        .as_ref()
        .filter(|c| matches!(c.likelihood, super::linear_fit::Likelihood::Poisson { .. }))
        .map(|_| final_loss);
    Ok(FitReport {
        relative_l2,
        deviance,
        render: rendered.model,
        response: objective.capture.as_ref().map(|c| c.response.clone()),
        nuisance: rendered.nuisance,
        floors: rendered.floors,
        held_out_loss: rendered.held_out,
        mesh: surface,
        full_mesh: outcome.mesh,
        history: outcome.history,
        seconds: start.elapsed().as_secs_f64(),
        final_loss,
        intensity,
        time_offset_opl,
        rejected_steps: outcome.rejected_steps,
        unsupported_faces,
        undetermined_faces,
        face_determination,
        seen,
        files,
    })
}
