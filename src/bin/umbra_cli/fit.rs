//! `umbra fit`: fits the hidden mesh to a measured transient (or, with no `--measured`,
//! to a target rendered from the scene's own hidden objects, as a demonstration with a
//! known answer).

use indicatif::{ProgressBar, ProgressStyle};
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use umbra::fit::{default_schedule, FitConfig, Init};
use umbra::geometry::SceneGeometry;
use umbra::scene::{Model, Scene};
use umbra::transport::{RenderOptions, Renderer};
use umbra::{Error, Result};

#[derive(clap::Args)]
pub struct FitArgs {
    /// The measurement: `.npy` (the scene's output layout), y-tal `.hdf5`, or a Stanford
    /// LCT `.mat` (their capture geometry replaces the scene's). Without it, a target is
    /// rendered from the scene's hidden objects with the `path` model and fitted from
    /// the initial mesh, and the result is compared with the truth.
    #[arg(long)]
    pub measured: Option<PathBuf>,
    /// Output directory: mesh.obj, mesh_all.obj, loss.csv, loss.png, transients.png,
    /// checkpoint/.
    #[arg(short, long, default_value = "out/fit")]
    pub output: PathBuf,
    /// Initial mesh: plane, sphere, scene (the scene's hidden objects), or
    /// backprojection (the height field of a filtered backprojection's depth map).
    #[arg(long, default_value = "plane")]
    pub init: String,
    /// Schedule TOML ([[stage]] tables: iters, solver, lr, large_steps, laplacian,
    /// fit_albedo, albedo_step, remesh, time_downsample, scan_downsample, model, spp).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Total iterations, shared among the stages in the schedule's proportions.
    #[arg(long)]
    pub iters: Option<u64>,
    /// Continue the fit whose checkpoint is in the output directory.
    #[arg(long)]
    pub resume: bool,
    /// Model the stages use unless they name one: tri3 (default), mc3, path.
    #[arg(long, default_value = "tri3")]
    pub model: String,
    /// Samples per measurement for Monte Carlo stages.
    #[arg(long, default_value_t = 16)]
    pub spp: u32,
    /// The measurement has Umbra's absolute scale: do not fit an intensity scale.
    #[arg(long)]
    pub known_scale: bool,
    /// Background fitted with the scale: `none` (default for the demonstration target,
    /// which has none), `constant` (dark counts, ambient light; default with
    /// `--measured`) or `per-bin` (one value per time bin shared by all scan points:
    /// also the direct light's tail; default for LCT `.mat` captures). `true` and
    /// `false` mean `constant` and `none`.
    #[arg(long)]
    pub background: Option<umbra::fit::Background>,
    /// Detector timing jitter: blur the render along time with a Gaussian of this
    /// standard deviation (OPL, m) before comparing it with the measurement. Default 0
    /// (the scene's film kernel only). Needs `--irf none` where an IRF is the default.
    #[arg(long)]
    pub jitter: Option<f64>,
    /// The detector's impulse response the render is convolved with, instead of the
    /// `--jitter` Gaussian: `none`, `direct` (estimated from the measurement's own
    /// direct return, the bins before `--ignore-before`; default for LCT `.mat`
    /// captures) or a `.npy` file of taps at the measurement's bin width, lag 0 first.
    #[arg(long)]
    pub irf: Option<String>,
    /// Fit an unknown time offset of the measurement, searched within +- this (OPL, m):
    /// the render is shifted through the jitter kernel, so it needs `--jitter`.
    #[arg(long)]
    pub time_offset: Option<f64>,
    /// Reflectance of the fitted surface: `lambertian` or `retroreflective` (the LCT
    /// paper's confocal model, signal falling as 1/r^2; `tri3`, confocal only). Default:
    /// the scene's first hidden object's, else lambertian.
    #[arg(long)]
    pub reflectance: Option<String>,
    /// Samples per measurement of the demonstration target (no `--measured`).
    #[arg(long, default_value_t = 4096)]
    pub target_spp: u32,
    /// Leave OPLs below this (m) out of the fit: residual direct light in real captures
    /// (default for LCT `.mat` captures: 0.72 m, the original code's first 600 bins).
    #[arg(long)]
    pub ignore_before: Option<f32>,
    /// With `--measured`: the scene's hidden objects are the true answer (synthetic data
    /// from another renderer); report the Chamfer distance to them, as without
    /// `--measured`.
    #[arg(long)]
    pub truth: bool,
    /// Bin the measurement before fitting: `TIME,SCAN` sums TIME consecutive time bins
    /// and averages SCAN x SCAN blocks of scan points (the schedule's downsampling then
    /// applies on top). Default `8,2` for LCT `.mat` captures (64 x 64 x 2048 bins of
    /// 1.2 mm become 32 x 32 x 256 bins of 9.6 mm, where photon noise is 0.16 of the
    /// signal instead of 0.68), `1,1` otherwise.
    #[arg(long, value_parser = parse_bin)]
    pub bin: Option<(u32, u32)>,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
}
fn parse_bin(text: &str) -> std::result::Result<(u32, u32), String> {
    let parse = |t: &str| {
        t.trim()
            .parse::<u32>()
            .ok()
            .filter(|&v| v >= 1)
            .ok_or_else(|| format!("'{text}' is not TIME,SCAN (two integers >= 1, e.g. 8,2)"))
    };
    match text.split_once(',') {
        Some((t, q)) => Ok((parse(t)?, parse(q)?)),
        None => Err(format!("'{text}' is not TIME,SCAN (e.g. 8,2)")),
    }
}

fn load_schedule(args: &FitArgs) -> Result<optim::Schedule> {
    let mut schedule = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
            toml::from_str(&text)
                .map_err(|e| Error::scene(path, format!("not a fit schedule: {e}")))?
        }
        None => default_schedule(),
    };
    if schedule.stages.is_empty() {
        return Err(Error::Invalid("the schedule has no [[stage]]".into()));
    }
    if let Some(total) = args.iters {
        let old: u64 = schedule.stages.iter().map(|s| s.iters).sum::<u64>().max(1);
        for s in &mut schedule.stages {
            s.iters = (s.iters * total).div_ceil(old).max(1);
        }
    }
    Ok(schedule)
}

fn to_mesh(scene: &Scene) -> Result<optim::Mesh> {
    let mut m = optim::Mesh::default();
    for o in &scene.objects {
        let part = umbra::fit::fit_mesh(&o.mesh);
        let base = m.vertices.len() as u32;
        m.vertices.extend(part.vertices);
        m.faces
            .extend(part.faces.iter().map(|t| t.map(|i| i + base)));
    }
    if m.faces.is_empty() {
        return Err(Error::Invalid(
            "--init scene: the scene has no hidden mesh".into(),
        ));
    }
    Ok(m)
}

/// The demonstration target: the scene's hidden objects through the `path` model.
fn render_target(scene: &Scene, spp: u32, out: &Path) -> Result<Vec<f32>> {
    let geom = SceneGeometry::build(scene);
    let opts = RenderOptions {
        model: Model::Path,
        spp,
        ..RenderOptions::from_scene(scene)
    };
    let t = Renderer::new(scene, &geom, &opts)?.render(None)?;
    umbra::io::write_npy(&out.join("target.npy"), &t)?;
    Ok(t.data)
}

pub fn fit(args: FitArgs, scene: Scene) -> Result<()> {
    let schedule = load_schedule(&args)?;
    let model = Model::parse(&args.model)
        .filter(|m| *m != Model::Auto)
        .ok_or_else(|| {
            Error::Invalid(format!(
                "--model: '{}' is not one of tri3, mc3, path",
                args.model
            ))
        })?;
    std::fs::create_dir_all(&args.output).map_err(|e| Error::io(&args.output, e))?;
    if let Some(t) = args.threads {
        // The fit drives the renderer from this thread (its progress callback is not
        // Send), so the thread count goes to rayon's global pool.
        rayon::ThreadPoolBuilder::new()
            .num_threads(t.max(1))
            .build_global()
            .map_err(|e| Error::Invalid(format!("thread pool: {e}")))?;
    }
    let (scene, measured, truth) = match &args.measured {
        Some(path) => {
            let m = umbra::io::measured::read_measured(path)?;
            let truth = if args.truth {
                Some((to_mesh(&scene)?, scene.clone()))
            } else {
                None
            };
            let scene = m.scene_for(&scene)?;
            m.check_against(&scene)?;
            (scene, m.transient.data, truth)
        }
        None => {
            let truth = to_mesh(&scene)?;
            eprintln!(
                "umbra fit: no --measured: rendering the scene's hidden objects ({} triangles) with the path model at {} spp as the target",
                truth.faces.len(),
                args.target_spp
            );
            let data = render_target(&scene, args.target_spp, &args.output)?;
            (scene.clone(), data, Some((truth, scene)))
        }
    };
    let is_lct = args
        .measured
        .as_ref()
        .is_some_and(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("mat")));
    let lct_default = is_lct.then_some(600.0 * umbra::io::lct::LCT_BIN_OPL);
    let bin = args.bin.unwrap_or(if is_lct { (8, 2) } else { (1, 1) });
    let counts = args.measured.is_some() && measured.iter().all(|&v| v >= 0.0 && v.fract() == 0.0);
    let (scene, measured) = if bin == (1, 1) {
        (scene, measured)
    } else {
        let (mut binned, data) = umbra::fit::resolution::at_resolution(
            &scene,
            &measured,
            bin.0,
            bin.1,
            umbra::fit::resolution::ScanReduce::Average,
        )
        .map_err(|e| Error::Invalid(format!("--bin {},{}: {e}", bin.0, bin.1)))?;
        binned.objects = scene.objects.clone();
        eprintln!(
            "umbra fit: measurement binned {},{}: {} x {} scan points, {} bins of {:.2} mm",
            bin.0,
            bin.1,
            binned.scan.nx,
            binned.scan.ny,
            binned.film.temporal_bins,
            1e3 * binned.film.bin_width_opl
        );
        (binned, data)
    };
    let ignore_before_opl = args.ignore_before.or(lct_default);
    let noise_floor =
        counts.then(|| photon_noise_floor(&scene, &measured, bin.1, ignore_before_opl));
    let init = match args.init.as_str() {
        "plane" => Init::Plane,
        "sphere" => Init::Sphere,
        "scene" => Init::Mesh(to_mesh(&scene)?),
        "backprojection" => Init::Backprojection,
        other => {
            return Err(Error::Invalid(format!(
                "--init: '{other}' is not one of plane, sphere, scene, backprojection"
            )))
        }
    };
    let reflectance = match &args.reflectance {
        None => scene
            .objects
            .first()
            .map_or(Default::default(), |o| o.reflectance),
        Some(r) => umbra::scene::Reflectance::parse(r).ok_or_else(|| {
            Error::Invalid(format!(
                "--reflectance: '{r}' is not one of lambertian, retroreflective"
            ))
        })?,
    };
    let irf_choice = args.irf.clone().unwrap_or_else(|| {
        if is_lct {
            "direct".into()
        } else {
            "none".into()
        }
    });
    if irf_choice != "none" && args.jitter.is_some() {
        return Err(Error::Invalid(if args.irf.is_some() {
            "--jitter and --irf both give the detector's response: give one".into()
        } else {
            "--jitter and --irf both give the detector's response: LCT captures use --irf direct by default, add --irf none for the Gaussian".into()
        }));
    }
    let width = scene.film.bin_width_opl as f64;
    let irf = match irf_choice.as_str() {
        "none" => None,
        "direct" => {
            let first = umbra::fit::objective::first_fitted_bin(&scene, ignore_before_opl);
            if first == 0 {
                return Err(Error::Invalid(
                    "--irf direct: the direct return is the bins before --ignore-before OPL, and none are left out".into(),
                ));
            }
            let bins = scene.film.temporal_bins as usize;
            let irf = umbra::film::irf::Irf::from_direct_return(&measured, bins, first, width)
                .ok_or_else(|| {
                    Error::Invalid(
                        "--irf direct: the measurement's leading bins hold nothing above its floor"
                            .into(),
                    )
                })?;
            eprintln!(
                "umbra fit: detector response from the direct return: {} bins of {:.2} mm, {:.0} % of it beyond 24 mm",
                irf.taps.len(),
                1e3 * width,
                100.0 * irf.taps_at(0.024).iter().skip(1).sum::<f64>()
            );
            Some(irf)
        }
        file => {
            let path = Path::new(file);
            let t = umbra::io::read_npy(path)?;
            let total: f64 = t.data.iter().map(|&v| v as f64).sum();
            if t.shape.len() != 1
                || t.data.iter().any(|v| !v.is_finite() || *v < 0.0)
                || total <= 0.0
            {
                return Err(Error::Invalid(format!(
                    "--irf {file}: expected a 1-D array of non-negative taps (shape {:?})",
                    t.shape
                )));
            }
            Some(umbra::film::irf::Irf {
                bin_width: width,
                taps: t.data.iter().map(|&v| v as f64 / total).collect(),
            })
        }
    };
    let jitter_opl = args.jitter.unwrap_or(0.0);
    if irf.is_some() && args.time_offset.is_some() {
        return Err(Error::Invalid(
            "--time-offset shifts the --jitter Gaussian: use it with --irf none".into(),
        ));
    }
    if !(jitter_opl.is_finite() && jitter_opl >= 0.0) {
        return Err(Error::Invalid(format!(
            "--jitter: {jitter_opl} is not a standard deviation (OPL, m, >= 0)"
        )));
    }
    let time_offset_max_opl = args.time_offset.unwrap_or(0.0);
    if !(time_offset_max_opl.is_finite() && time_offset_max_opl >= 0.0) {
        return Err(Error::Invalid(format!(
            "--time-offset: {time_offset_max_opl} is not a search range (OPL, m, >= 0)"
        )));
    }
    if time_offset_max_opl > 0.0 && jitter_opl <= 0.0 {
        return Err(Error::Invalid(
            "--time-offset needs --jitter SIGMA > 0: with box bins the loss is piecewise constant in the offset (no gradient to find it by)".into(),
        ));
    }
    let cfg = FitConfig {
        schedule,
        init,
        model,
        spp: args.spp.max(1),
        intensity: umbra::fit::IntensityModel {
            scale: !args.known_scale,
            background: args.background.unwrap_or(if args.measured.is_none() {
                umbra::fit::Background::None
            } else if is_lct {
                umbra::fit::Background::PerBin
            } else {
                umbra::fit::Background::Constant
            }),
        },
        two_sided: true,
        albedo: scene.objects.first().map_or(0.8, |o| o.albedo),
        resume: args.resume,
        ignore_before_opl,
        jitter_opl,
        irf,
        time_offset_max_opl,
        reflectance,
    };
    let total: u64 = cfg.schedule.stages.iter().map(|s| s.iters).sum();
    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(total);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} it  {msg}",
            )
            .expect("template"),
        );
        b
    };
    let cancel = Arc::new(AtomicBool::new(false));
    {
        let c = cancel.clone();
        let _ = ctrlc::set_handler(move || {
            if c.swap(true, Ordering::Relaxed) {
                std::process::exit(130);
            }
        });
    }
    let (b, c) = (bar.clone(), cancel.clone());
    let progress: optim::fit::Progress =
        Rc::new(RefCell::new(move |r: &optim::checkpoint::LossRecord| {
            b.set_position(r.iteration);
            b.set_message(format!("stage {} loss {:.4e}", r.stage, r.data_loss));
            !c.load(Ordering::Relaxed)
        }));
    let report = umbra::fit::fit(&scene, &measured, &cfg, &args.output, progress);
    bar.finish_and_clear();
    let report = match report {
        Err(Error::Cancelled) => {
            eprintln!(
                "umbra fit: interrupted; the checkpoint in {} resumes with --resume",
                args.output.join("checkpoint").display()
            );
            std::process::exit(130);
        }
        r => r?,
    };
    if let Some(floor) = noise_floor {
        println!(
            "umbra fit: the measurement is photon counts: Poisson noise alone gives a relative L2 of {floor:.3} at this resolution"
        );
    }
    println!(
        "umbra fit: {} iterations in {:.1} s (this run), final loss {:.4e} (relative L2 {:.3}, scale {:.4e}, background {:.4e}), {} vertices / {} faces{} -> {}",
        report.history.len(),
        report.seconds,
        report.final_loss,
        report.final_loss.sqrt(),
        report.intensity.scale,
        report.intensity.background,
        report.mesh.vertices.len(),
        report.mesh.faces.len(),
        if report.rejected_steps > 0 {
            format!(", {} steps rejected", report.rejected_steps)
        } else {
            String::new()
        },
        report.files.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
    );
    if args.time_offset.is_some() {
        println!(
            "umbra fit: fitted time offset {:+.2} mm of OPL (the render is delayed by it)",
            1e3 * report.time_offset_opl
        );
    }
    let mut summary = Summary {
        iterations: report.history.len(),
        seconds: report.seconds,
        final_loss: report.final_loss,
        relative_l2: report.final_loss.sqrt(),
        scale: report.intensity.scale,
        background: report.intensity.background,
        time_offset: report.time_offset_opl,
        vertices: report.mesh.vertices.len(),
        faces: report.mesh.faces.len(),
        rejected_steps: report.rejected_steps,
        init: args.init.clone(),
        photon_noise_floor: noise_floor,
        chamfer: None,
    };
    if let Some((truth, truth_scene)) = truth {
        let (c, seen) = umbra::fit::metrics::chamfer_seen(&report.mesh, &truth, &truth_scene, 4000);
        let all = umbra::fit::metrics::chamfer(&report.mesh, &truth, 4000);
        println!(
            "umbra fit: Chamfer distance between the surfaces seen from the wall ({:.0} % of the fit's area, {:.0} % of the truth's) {:.2} mm (fit->truth {:.2} mm, truth->fit {:.2} mm); between the whole surfaces {:.2} mm",
            100.0 * seen[0],
            100.0 * seen[1],
            1e3 * c.symmetric,
            1e3 * c.fit_to_truth,
            1e3 * c.truth_to_fit,
            1e3 * all.symmetric,
        );
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
    }
    let path = args.output.join("summary.toml");
    let text = toml::to_string(&summary).map_err(|e| Error::Invalid(format!("summary: {e}")))?;
    optim::checkpoint::write_atomic(&path, text.as_bytes()).map_err(|e| Error::io(&path, e))?;
    Ok(())
}

/// The relative L2 error that Poisson noise alone gives, `√(Σ Var M / Σ M²)` over the
/// fitted bins (OPL from `ignore_before_opl` on), for a measurement of photon counts
/// whose `scan x scan` blocks were averaged (`Var M = M / scan²`).
fn photon_noise_floor(
    scene: &Scene,
    measured: &[f32],
    scan: u32,
    ignore_before_opl: Option<f32>,
) -> f64 {
    let bins = scene.film.temporal_bins as usize;
    let first = umbra::fit::objective::first_fitted_bin(scene, ignore_before_opl);
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

/// `OUTDIR/summary.toml`: the fit's figures, for scripts (the recovery studies).
#[derive(serde::Serialize)]
struct Summary {
    iterations: usize,
    seconds: f64,
    final_loss: f64,
    relative_l2: f64,
    scale: f64,
    background: f64,
    /// Fitted time offset (OPL, m; 0 unless --time-offset).
    time_offset: f64,
    vertices: usize,
    faces: usize,
    rejected_steps: u64,
    init: String,
    /// For photon-count data: the relative L2 Poisson noise alone gives (the best a
    /// fit can reach at this resolution).
    photon_noise_floor: Option<f64>,
    chamfer: Option<ChamferSummary>,
}

/// Chamfer distances to the truth (mm); "seen" = the truth's surface seen from the scan
/// (`umbra::fit::metrics::chamfer_seen`).
#[derive(serde::Serialize)]
struct ChamferSummary {
    seen_mm: f64,
    seen_fit_to_truth_mm: f64,
    seen_truth_to_fit_mm: f64,
    seen_fit_to_truth_p90_mm: f64,
    seen_truth_to_fit_p90_mm: f64,
    fit_seen_area_fraction: f64,
    truth_seen_area_fraction: f64,
    whole_mm: f64,
}
