//! A fit as `umbra fit` and Python's `umbra.fit` ask for it: the measurement (a file, an
//! array, or a demonstration target rendered from the scene), the choices a user makes
//! (initial mesh, schedule, model, detector response, intensity model, binning) with
//! their defaults, resolved into a [`FitConfig`] and run through [`super::fit`], then
//! measured against the truth when there is one. Both front ends call [`run`]: there is
//! one fitting path.

use super::metrics::{chamfer, chamfer_seen};
use super::objective::first_fitted_bin;
use super::prepare::{
    monte_carlo_warning, photon_noise_floor, render_target, saved_target, to_mesh,
};
use super::request_options::DetectorResponse;
use super::resolution::{at_resolution, ScanReduce};
use super::run::{default_schedule, FitConfig, FitReport, Init};
use super::starts::{fit_starts, start_dir, AutoFit, StartSummary, StartsRun};
use super::{Background, IntensityModel};
use crate::error::{Error, Result};
use crate::scene::{CaptureType, Model, Scene};
use optim::checkpoint::write_atomic;
use optim::fit::Progress;
use optim::{Mesh, Schedule};
use std::path::{Path, PathBuf};

/// What the fit is against.
#[derive(Clone, Debug)]
pub enum Measurement {
    /// No measurement: a target rendered from the scene's hidden objects with the `path`
    /// model at this many samples per measurement (written as `target.npy`), fitted from
    /// the initial mesh and compared with the truth.
    Demo { target_spp: u32 },
    /// A file: `.npy` (the scene's output layout), y-tal `.hdf5`, or a Stanford LCT
    /// `.mat` (whose capture geometry replaces the scene's).
    File(PathBuf),
    /// An array in the scene's output layout (row-major).
    Array(Vec<f32>),
}

/// Who asks: error messages name the options as that front end spells them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Front {
    /// `--time-offset`.
    #[default]
    Cli,
    /// `time_offset`.
    Python,
}

impl Front {
    /// Option `name` (snake case) as this front end spells it.
    pub fn name(self, name: &str) -> String {
        match self {
            Front::Cli => format!("--{}", name.replace('_', "-")),
            Front::Python => name.to_string(),
        }
    }
}

/// A fit's choices; `None` means the default for the measurement (see each field).
#[derive(Clone, Debug)]
pub struct FitRequest {
    /// How errors name the options.
    pub front: Front,
    pub measurement: Measurement,
    /// Output directory: mesh.obj, mesh_all.obj, albedo.npy, depth.npy, albedo.png,
    /// loss.csv, loss.png, calibration.csv (with the capture model), transients.png,
    /// reconstruction.png, summary.toml, checkpoint/.
    pub output: PathBuf,
    /// plane, sphere, scene (the scene's hidden objects), backprojection, lct, or auto
    /// (fits from a plane, a sphere and the LCT, confocal, or the backprojection,
    /// otherwise; keeps the lowest loss, a later start within [`super::starts::AUTO_LOSS_MARGIN`]).
    /// `None`: lct for a Stanford `.mat` capture, plane otherwise ([`super::init::default_init`]).
    pub init: Option<String>,
    /// The stages (default [`default_schedule`]).
    pub schedule: Option<Schedule>,
    /// Total iterations, shared among the stages in the schedule's proportions.
    pub iters: Option<u64>,
    pub resume: bool,
    /// tri3, mc3 or path: the stages' model unless they name one.
    pub model: String,
    pub spp: u32,
    /// The measurement has Umbra's absolute scale: no intensity scale is fitted.
    pub known_scale: bool,
    /// Default: none for the demonstration, per-point for LCT captures (with the
    /// calibrated capture model, `fit::capture`), else constant.
    pub background: Option<Background>,
    /// poisson or l2; default poisson for photon counts with the per-point background,
    /// else l2.
    pub likelihood: Option<String>,
    /// Detector jitter σ (OPL, m); default 0.
    pub jitter: Option<f64>,
    /// none, direct, calibrate (with the per-point background: a core and tails calibrated
    /// from the capture, `fit::capture`), or a `.npy` file of taps; default calibrate with
    /// the per-point background, else none.
    pub irf: Option<String>,
    /// Search an unknown time offset within ± this (OPL, m).
    pub time_offset: Option<f64>,
    /// lambertian or retroreflective; default the scene's first hidden object's.
    pub reflectance: Option<String>,
    /// A retroreflective surface's angular falloff exponent `m` (`cos^m θ`); default the
    /// scene's first hidden object's, or 0 with `reflectance`.
    pub retro_falloff: Option<f32>,
    /// Leave OPLs below this (m) out; default 0.72 m for LCT captures.
    pub ignore_before: Option<f32>,
    /// With a measurement: the scene's hidden objects are the truth (Chamfer reported).
    pub truth: bool,
    /// `(time, scan)` binning of the measurement; default (8, 2) for LCT, else (1, 1).
    pub bin: Option<(u32, u32)>,
    /// Visibility boundary terms in the fit's gradients; default the scene's
    /// `render.boundary_terms` (on).
    pub boundary_terms: Option<bool>,
}

impl FitRequest {
    /// The defaults of `umbra fit` for `measurement`, writing into `output`.
    pub fn new(measurement: Measurement, output: PathBuf) -> FitRequest {
        FitRequest {
            front: Front::Cli,
            measurement,
            output,
            init: None,
            schedule: None,
            iters: None,
            resume: false,
            model: "tri3".into(),
            spp: 16,
            known_scale: false,
            background: None,
            likelihood: None,
            jitter: None,
            irf: None,
            time_offset: None,
            reflectance: None,
            retro_falloff: None,
            ignore_before: None,
            truth: false,
            bin: None,
            boundary_terms: None,
        }
    }
}

/// A schedule from TOML text (`[[stage]]` tables); `origin` names it in errors, which
/// name the stage (from 0) and the field: `schedule.toml: stage 2: lr = -0.01 must be
/// positive and finite (…)`.
pub fn parse_schedule(text: &str, origin: &Path) -> Result<Schedule> {
    let s: Schedule = toml::from_str(text)
        .map_err(|e| Error::scene(origin, format!("not a fit schedule: {e}")))?;
    check_schedule(&s).map_err(|e| Error::scene(origin, e))?;
    Ok(s)
}

/// [`Schedule::check`] and the stages' model names.
pub fn check_schedule(s: &Schedule) -> std::result::Result<(), String> {
    s.check()?;
    for (i, stage) in s.stages.iter().enumerate() {
        if let Some(name) = &stage.model {
            if Model::parse(name).is_none_or(|m| m == Model::Auto) {
                return Err(format!(
                    "stage {i}: model = '{name}' is not one of tri3, mc3, path"
                ));
            }
        }
    }
    Ok(())
}

/// Chamfer distances to the truth (mm); "seen" = the truth's surface seen from the
/// scan ([`chamfer_seen`]).
#[derive(Clone, Debug, serde::Serialize)]
pub struct ChamferSummary {
    pub seen_mm: f64,
    pub seen_fit_to_truth_mm: f64,
    pub seen_truth_to_fit_mm: f64,
    pub seen_fit_to_truth_p90_mm: f64,
    pub seen_truth_to_fit_p90_mm: f64,
    pub fit_seen_area_fraction: f64,
    pub truth_seen_area_fraction: f64,
    pub whole_mm: f64,
}

/// `OUTDIR/summary.toml`: the fit's figures, for scripts (the recovery studies).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    pub iterations: usize,
    pub seconds: f64,
    /// The loss the fit minimised: relative squared error (L2), or the Poisson deviance
    /// per fitted bin.
    pub final_loss: f64,
    /// `‖μ − M‖ / ‖M‖` of the fitted transient over the fitted bins, whatever the loss.
    pub relative_l2: f64,
    /// The Poisson deviance per fitted bin (a perfect model of the counts: about 1).
    pub deviance_per_bin: Option<f64>,
    /// The loss at the scan points held out of the fit (`--background per-point`).
    pub held_out_loss: Option<f64>,
    /// The detector response calibrated from the capture (`--background per-point`).
    pub response: Option<super::capture_options::ResponseSummary>,
    /// The capture model's gain, floor and tail coefficients by name (`--background
    /// per-point`; `PointBackground::coefficients`).
    pub nuisance: Option<std::collections::BTreeMap<String, f64>>,
    pub scale: f64,
    pub background: f64,
    /// Fitted time offset (OPL, m; 0 unless searched).
    pub time_offset: f64,
    pub vertices: usize,
    pub faces: usize,
    pub rejected_steps: u64,
    /// Faces left out of mesh.obj because no measurement lights and sees them
    /// (`fit::support`; the dark ones are not counted).
    pub unsupported_faces: usize,
    /// Faces left out of mesh.obj because their signal is within the noise
    /// (`fit::determined`; the dark and unsupported ones are not counted).
    pub undetermined_faces: usize,
    /// The start used (`auto: NAME` when `--init auto` chose).
    pub init: String,
    /// `--init auto`: every start's final loss and time (each fit is in `start-NAME/`).
    pub starts: Vec<StartSummary>,
    /// `--init auto`: the starts that failed, each with its error (left out of the choice).
    pub failed_starts: Vec<String>,
    /// For photon-count data: the relative L2 Poisson noise alone gives (the best a
    /// fit can reach at this resolution).
    pub photon_noise_floor: Option<f64>,
    pub chamfer: Option<ChamferSummary>,
    /// With a known truth: the baselines study's score (`fit::score`), the same numbers
    /// `umbra recon --truth` gives a reconstruction's surface.
    pub score: Option<super::score::SurfaceScore>,
}

/// What [`run`] returns.
pub struct FitOutcome {
    pub report: FitReport,
    pub summary: Summary,
    /// The measurement as fitted (after binning, leading bins zeroed) and the shape of it
    /// and of `report.render`.
    pub measured: Vec<f32>,
    pub shape: Vec<usize>,
}

/// Runs the fit `req` asks for on `scene`: prepares the measurement, resolves the
/// defaults, fits ([`super::fit`], which writes the outputs), compares with the truth
/// when there is one, and writes `summary.toml`. `log` receives one-line notes on the
/// choices made; `progress` is called after every iteration (false stops the fit with
/// [`Error::Cancelled`], the checkpoint kept).
pub fn run(
    mut scene: Scene,
    req: &FitRequest,
    progress: Progress,
    log: &mut dyn FnMut(&str),
) -> Result<FitOutcome> {
    let n = |name: &str| req.front.name(name);
    if let Some(b) = req.boundary_terms {
        scene.render.boundary_terms = b;
    }
    // Counts that would silently run as something else (spp 0 ran as 1, iters 0 as 4,
    // a 0-spp target was all NaN).
    let target_spp = match req.measurement {
        Measurement::Demo { target_spp } => Some(target_spp),
        _ => None,
    };
    for (name, value) in [
        ("spp", Some(req.spp as u64)),
        ("iters", req.iters),
        ("target_spp", target_spp.map(u64::from)),
    ] {
        if value == Some(0) {
            return Err(Error::Invalid(format!("{}: must be at least 1", n(name))));
        }
    }
    if let Some(v) = req.ignore_before.filter(|v| !v.is_finite()) {
        return Err(Error::Invalid(format!(
            "{}: {v} is not an optical path length (m, finite)",
            n("ignore_before")
        )));
    }
    let mut schedule = req.schedule.clone().unwrap_or_else(default_schedule);
    let schedule_name = match req.front {
        Front::Cli => "--config",
        Front::Python => "schedule",
    };
    check_schedule(&schedule).map_err(|e| Error::Invalid(format!("{schedule_name}: {e}")))?;
    if let Some(total) = req.iters {
        // Fewer iterations than stages: the first `total` stages, one iteration each.
        let stages = schedule.stages.len();
        if (total as usize) < stages {
            log(&format!(
                "{} {total}: fewer than the schedule's {stages} stages; running its first {total}, one iteration each",
                n("iters")
            ));
            schedule.stages.truncate(total as usize);
        }
        let weights: Vec<u64> = schedule.stages.iter().map(|s| s.iters).collect();
        let split = super::iters::split_iters(&weights, total)
            .ok_or_else(|| Error::Invalid(format!("{}: must be at least 1", n("iters"))))?;
        for (s, k) in schedule.stages.iter_mut().zip(split) {
            s.iters = k;
        }
    }
    let model = Model::parse(&req.model)
        .filter(|m| *m != Model::Auto)
        .ok_or_else(|| {
            Error::Invalid(format!(
                "{}: '{}' is not one of tri3, mc3, path",
                n("model"),
                req.model
            ))
        })?;
    // `--init auto` fits from each start in its own folder (`fit::starts`); the first
    // one's (the plane's) checkpoint is the one a resume needs.
    let init = req
        .init
        .clone()
        .unwrap_or_else(|| super::init::default_init(&req.measurement).to_string());
    let auto = init == "auto";
    let checkpoint_dir = if auto {
        start_dir(&req.output, "plane").join("checkpoint")
    } else {
        req.output.join("checkpoint")
    };
    // A resume fails early on a checkpoint that is not there or damaged (before any
    // target is rendered); what it was written for is compared in the fit.
    let resumed = if req.resume {
        let stage = checkpoint_dir.join("stage.bin");
        if !stage.exists() {
            return Err(Error::Invalid(format!(
                "{}: cannot resume: no checkpoint here (run without {})",
                stage.display(),
                n("resume")
            )));
        }
        Some(optim::fit::checkpoint_identity(&checkpoint_dir).map_err(Error::Invalid)?)
    } else {
        None
    };
    std::fs::create_dir_all(&req.output).map_err(|e| Error::io(&req.output, e))?;
    // One fit per folder, held until the fit returns; before anything there is touched.
    let _lock =
        optim::lock::FolderLock::acquire(&req.output, "umbra fit").map_err(Error::Invalid)?;
    // Temporaries of outputs a killed run was writing (target.npy, mesh.obj, ...).
    optim::checkpoint::remove_stale_temporaries_of(&req.output, |_| true);
    let file = match &req.measurement {
        Measurement::File(p) => Some(p.as_path()),
        _ => None,
    };
    let truth_of = |s: &Scene| -> Result<Option<(Mesh, Scene)>> {
        Ok(Some((to_mesh(s, "truth")?, s.clone())))
    };
    let (scene, measured, truth) = match &req.measurement {
        Measurement::File(path) => {
            let m = crate::io::measured::read_measured(path)?;
            let truth = if req.truth { truth_of(&scene)? } else { None };
            let fitted = m.scene_for(&scene)?;
            m.check_against(&fitted)?;
            (fitted, m.transient.data, truth)
        }
        Measurement::Array(data) => {
            let truth = if req.truth { truth_of(&scene)? } else { None };
            (scene, data.clone(), truth)
        }
        Measurement::Demo { target_spp } => {
            let truth = truth_of(&scene)?;
            let saved = resumed
                .as_ref()
                .and_then(|id| saved_target(&scene, &req.output, id, log));
            let data = match saved {
                Some(data) => data,
                None => {
                    log(&format!(
                        "no measurement: rendering the scene's hidden objects ({} triangles) with the path model at {target_spp} spp as the target",
                        truth.as_ref().map_or(0, |t| t.0.faces.len()),
                    ));
                    render_target(&scene, *target_spp, &req.output)?
                }
            };
            (scene, data, truth)
        }
    };
    let demo = matches!(req.measurement, Measurement::Demo { .. });
    let is_lct = file.is_some_and(super::init::is_lct_capture);
    let lct_default = is_lct.then_some(600.0 * crate::io::lct::LCT_BIN_OPL);
    let bin = req.bin.unwrap_or(if is_lct { (8, 2) } else { (1, 1) });
    if bin.0 == 0 || bin.1 == 0 {
        return Err(Error::Invalid(format!(
            "{}: {},{} is not TIME,SCAN (two integers >= 1)",
            n("bin"),
            bin.0,
            bin.1
        )));
    }
    let counts = !demo && measured.iter().all(|&v| v >= 0.0 && v.fract() == 0.0);
    let (scene, measured) = if bin == (1, 1) {
        (scene, measured)
    } else {
        let (mut binned, data) =
            at_resolution(&scene, &measured, bin.0, bin.1, ScanReduce::Average)
                .map_err(|e| Error::Invalid(format!("{} {},{}: {e}", n("bin"), bin.0, bin.1)))?;
        binned.objects = scene.objects.clone();
        log(&format!(
            "measurement binned {},{}: {} x {} scan points, {} bins of {:.2} mm",
            bin.0,
            bin.1,
            binned.scan.nx,
            binned.scan.ny,
            binned.film.temporal_bins,
            1e3 * binned.film.bin_width_opl
        ));
        (binned, data)
    };
    let ignore_before_opl = req.ignore_before.or(lct_default);
    super::objective::check_ignore_before(&scene.film, req.ignore_before, &n("ignore_before"))?;
    let noise_floor =
        counts.then(|| photon_noise_floor(&scene, &measured, bin.1, ignore_before_opl));
    let starts: Vec<(&str, Init)> = match init.as_str() {
        "plane" => vec![("plane", Init::Plane)],
        "sphere" => vec![("sphere", Init::Sphere)],
        "scene" => vec![(
            "scene",
            Init::Mesh(to_mesh(&scene, &format!("{} scene", n("init")))?),
        )],
        "backprojection" => vec![("backprojection", Init::Backprojection)],
        "lct" => vec![("lct", Init::Lct)],
        "auto" if scene.capture == CaptureType::Confocal => vec![
            ("plane", Init::Plane),
            ("sphere", Init::Sphere),
            ("lct", Init::Lct),
        ],
        "auto" => vec![
            ("plane", Init::Plane),
            ("sphere", Init::Sphere),
            ("backprojection", Init::Backprojection),
        ],
        other => {
            return Err(Error::Invalid(format!(
                "{}: '{other}' is not one of plane, sphere, scene, backprojection, lct, auto",
                n("init")
            )))
        }
    };
    let reflectance = super::request_options::reflectance(req, &scene, model, &schedule)?;
    if let Some(note) = monte_carlo_warning(&n, model, req.spp, &schedule) {
        log(&note);
    }
    let background = req.background.unwrap_or(if demo {
        Background::None
    } else if is_lct {
        Background::PerPoint
    } else {
        Background::Constant
    });
    let per_point = background == Background::PerPoint;
    let capture = super::capture_options::from_request(&n, req, &scene, per_point, counts, bin.1)?;
    let DetectorResponse {
        irf,
        jitter_opl,
        time_offset_max_opl,
    } = super::request_options::detector_response(
        req,
        &scene,
        &measured,
        ignore_before_opl,
        per_point,
        log,
    )?;
    let mut cfg = FitConfig {
        schedule,
        init: Init::Plane,
        model,
        spp: req.spp.max(1),
        intensity: IntensityModel {
            scale: !req.known_scale,
            background,
        },
        two_sided: true,
        albedo: scene.objects.first().map_or(0.8, |o| o.albedo),
        resume: req.resume,
        ignore_before_opl,
        jitter_opl,
        irf,
        time_offset_max_opl,
        reflectance,
        photon_counts: counts.then_some(bin.1),
        capture,
    };
    let AutoFit {
        name: chosen_name,
        report,
        starts: starts_summary,
        failed: failed_starts,
    } = fit_starts(
        &scene,
        &measured,
        &mut cfg,
        starts,
        &StartsRun {
            output: &req.output,
            auto,
            resume: req.resume,
            flag: &n("init"),
        },
        progress,
        log,
    )?;
    // A fit that ends where the surface returns nothing it can use has failed, whatever
    // its exit status: say so rather than report a mesh as if it were one.
    let no_signal =
        report.relative_l2 >= 0.999 || (!req.known_scale && report.intensity.scale <= 0.0);
    if no_signal {
        log(&format!(
            "warning: the fitted surface returns no light the fit can use (relative L2 {:.3}, scale {:.3e}): the fit failed; a step size (lr) too large for the scene throws the mesh out of view (see loss.csv)",
            report.relative_l2,
            report.intensity.scale
        ));
    }
    if report.unsupported_faces > 0 {
        log(&format!(
            "{} faces left out of mesh.obj: no measurement lights and sees them (in the fitted surface's own shadow), so the data say nothing about them (mesh_all.obj keeps them)",
            report.unsupported_faces
        ));
    }
    if report.undetermined_faces > 0 {
        log(&format!(
            "{} faces left out of mesh.obj: their signal is within the noise of the bins it lands in, so the data do not determine them (fit::determined; mesh_all.obj keeps them)",
            report.undetermined_faces
        ));
    }
    let mut summary = Summary {
        iterations: report.history.len(),
        seconds: report.seconds,
        final_loss: report.final_loss,
        relative_l2: report.relative_l2,
        deviance_per_bin: report.deviance,
        held_out_loss: report
            .held_out_loss
            .is_finite()
            .then_some(report.held_out_loss),
        response: report
            .response
            .as_ref()
            .map(super::capture_options::ResponseSummary::of),
        nuisance: (!report.nuisance.is_empty()).then(|| report.nuisance.iter().cloned().collect()),
        scale: report.intensity.scale,
        background: report.intensity.background,
        time_offset: report.time_offset_opl,
        vertices: report.mesh.vertices.len(),
        faces: report.mesh.faces.len(),
        rejected_steps: report.rejected_steps,
        unsupported_faces: report.unsupported_faces,
        undetermined_faces: report.undetermined_faces,
        init: if auto {
            format!("auto: {chosen_name}")
        } else {
            init.clone()
        },
        starts: starts_summary,
        failed_starts,
        photon_noise_floor: noise_floor,
        chamfer: None,
        score: None,
    };
    if let Some((truth, truth_scene)) = truth {
        let (c, seen) = chamfer_seen(&report.mesh, &truth, &truth_scene, 4000);
        let all = chamfer(&report.mesh, &truth, 4000);
        summary.chamfer = Some(ChamferSummary {
            seen_mm: 1e3 * c.symmetric,
            seen_fit_to_truth_mm: 1e3 * c.fit_to_truth,
            seen_truth_to_fit_mm: 1e3 * c.truth_to_fit,
            seen_fit_to_truth_p90_mm: 1e3 * c.fit_to_truth_p90,
            seen_truth_to_fit_p90_mm: 1e3 * c.truth_to_fit_p90,
            fit_seen_area_fraction: seen[0],
            truth_seen_area_fraction: seen[1],
            whole_mm: 1e3 * all.symmetric,
        });
        summary.score = Some(super::score::score_surface(
            &report.mesh,
            &truth,
            &truth_scene,
        )?);
    }
    let path = req.output.join("summary.toml");
    let text = toml::to_string(&summary).map_err(|e| Error::Invalid(format!("summary: {e}")))?;
    write_atomic(&path, text.as_bytes()).map_err(|e| Error::io(&path, e))?;
    let mut measured = measured;
    let first = first_fitted_bin(&scene, ignore_before_opl);
    super::objective::zero_leading_bins(&mut measured, scene.film.temporal_bins as usize, first);
    Ok(FitOutcome {
        report,
        summary,
        measured,
        shape: scene.output_shape(),
    })
}
