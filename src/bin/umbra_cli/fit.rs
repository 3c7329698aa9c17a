//! `umbra fit`: fits the hidden mesh to a measured transient (or, with no `--measured`,
//! to a target rendered from the scene's own hidden objects, as a demonstration with a
//! known answer).

use indicatif::{ProgressBar, ProgressStyle};
use std::cell::RefCell;
use std::path::PathBuf;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use umbra::fit::request::parse_schedule;
use umbra::fit::{default_schedule, FitRequest, Measurement};
use umbra::scene::Scene;
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
    /// albedo.npy and depth.npy (the fitted surface seen from the wall, (ny, nx) per scan
    /// point), albedo.png, reconstruction.png (next to the LCT), floor.npy (a capture
    /// model's floor per scan point, (ny, nx)), summary.toml, checkpoint/.
    #[arg(short, long, default_value = "out/fit")]
    pub output: PathBuf,
    /// Initial mesh: plane, sphere, scene (the scene's hidden objects), or
    /// backprojection (the height field of a filtered backprojection's depth map), or lct
    /// (the same of the light-cone transform's; confocal captures), or auto: fits from a
    /// plane, a sphere and a reconstruction (the LCT, confocal; the backprojection,
    /// otherwise), each in OUTDIR/start-NAME, the lowest loss kept (a later start within
    /// 1 % of it wins). Default: lct for a Stanford `.mat` capture, plane otherwise.
    #[arg(long)]
    pub init: Option<String>,
    /// Schedule TOML ([[stage]] tables: iters, solver, lr, large_steps, laplacian,
    /// fit_albedo, albedo_step, albedo_tv, remesh, remesh_factor, remesh_pitch, time_downsample,
    /// scan_downsample, model, spp).
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
    /// `--measured`), `per-bin` (one value per time bin shared by all scan points) or
    /// `per-point` (default for LCT `.mat` captures: the capture model calibrated from
    /// the data, a floor per scan point plus the direct return's tail scaled by
    /// each point's direct counts, a gain field, and the detector response calibrated as
    /// a core with tails; docs/FITTING.md). `true` and `false` mean `constant` and `none`.
    #[arg(long)]
    pub background: Option<umbra::fit::Background>,
    /// The loss: `poisson` (the deviance of photon counts; default for counts with
    /// `--background per-point`) or `l2` (relative squared error; default otherwise).
    #[arg(long)]
    pub likelihood: Option<String>,
    /// Detector timing jitter: blur the render along time with a Gaussian of this
    /// standard deviation (OPL, m) before comparing it with the measurement. Default 0
    /// (the scene's film kernel only). Needs `--irf none` where an IRF is the default.
    #[arg(long)]
    pub jitter: Option<f64>,
    /// The detector's impulse response the render is convolved with, instead of the
    /// `--jitter` Gaussian: `none`, `calibrate` (a Gaussian core with exponential tails,
    /// calibrated from the capture at each stage; default with `--background
    /// per-point`, and only with it), `direct` (estimated from the measurement's own
    /// direct return, the bins before `--ignore-before`) or a `.npy` file of taps at the
    /// measurement's bin width, lag 0 first.
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
    /// A retroreflective surface's angular falloff exponent m: its return scaled by
    /// cos^m of the entrance angle (0 to 16; default the scene object's
    /// `retro_falloff`, else 0, the ideal retroreflector).
    #[arg(long)]
    pub retro_falloff: Option<f32>,
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
    /// Add the visibility boundary terms to the fit's vertex gradients (shadows moving
    /// across hidden surfaces; default: the scene's `render.boundary_terms`, true).
    #[arg(long)]
    pub boundary_terms: Option<bool>,
    /// Worker threads (default or 0: all cores; at most 4 per core, `umbra::threads`).
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

fn load_schedule(args: &FitArgs) -> Result<Option<optim::Schedule>> {
    match &args.config {
        Some(path) => {
            let text = umbra::io::read_text(path, "a fit schedule")?;
            Ok(Some(parse_schedule(&text, path)?))
        }
        None => Ok(None),
    }
}

/// `umbra fit`: the arguments as a [`FitRequest`], run by the library's
/// [`umbra::fit::request::run`] (the function Python's `umbra.fit` calls too), with a
/// progress bar, Ctrl-C and the results printed.
pub fn fit(args: FitArgs, scene: Scene) -> Result<()> {
    if let Some(t) = args.threads {
        // The fit drives the renderer from this thread (its progress callback is not
        // Send), so the thread count goes to rayon's global pool.
        rayon::ThreadPoolBuilder::new()
            .num_threads(umbra::threads::check(Some(t), "--threads")?)
            .build_global()
            .map_err(|e| Error::Invalid(format!("thread pool: {e}")))?;
    }
    let measurement = match &args.measured {
        Some(p) => Measurement::File(p.clone()),
        None => Measurement::Demo {
            target_spp: args.target_spp,
        },
    };
    let req = FitRequest {
        schedule: load_schedule(&args)?,
        iters: args.iters,
        resume: args.resume,
        init: args.init.clone(),
        model: args.model.clone(),
        spp: args.spp,
        known_scale: args.known_scale,
        background: args.background,
        likelihood: args.likelihood.clone(),
        jitter: args.jitter,
        irf: args.irf.clone(),
        time_offset: args.time_offset,
        reflectance: args.reflectance.clone(),
        retro_falloff: args.retro_falloff,
        ignore_before: args.ignore_before,
        truth: args.truth,
        bin: args.bin,
        boundary_terms: args.boundary_terms,
        ..FitRequest::new(measurement, args.output.clone())
    };
    let total: u64 = req
        .schedule
        .as_ref()
        .map_or_else(default_schedule, |s| s.clone())
        .stages
        .iter()
        .map(|s| s.iters)
        .sum();
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
                optim::atomic::remove_live_temporaries();
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
    let b = bar.clone();
    let mut log = move |note: &str| b.suspend(|| eprintln!("umbra fit: {note}"));
    let outcome = umbra::fit::request::run(scene, &req, progress, &mut log);
    bar.finish_and_clear();
    let outcome = match outcome {
        Err(Error::Cancelled) => {
            eprintln!(
                "umbra fit: interrupted; the checkpoint in {} resumes with --resume",
                args.output.join("checkpoint").display()
            );
            optim::atomic::remove_live_temporaries();
            std::process::exit(130);
        }
        r => r?,
    };
    let (report, summary) = (&outcome.report, &outcome.summary);
    if let Some(floor) = summary.photon_noise_floor {
        println!(
            "umbra fit: the measurement is photon counts: Poisson noise alone gives a relative L2 of {floor:.3} at this resolution"
        );
    }
    if let Some(d) = summary.deviance_per_bin {
        let held = summary.held_out_loss.map_or(String::new(), |h| {
            format!(", {h:.3} at the held-out scan points")
        });
        println!("umbra fit: Poisson deviance {d:.3} per fitted bin (a perfect model of the counts: about 1){held}");
    }
    if let Some(r) = &summary.response {
        let tails: Vec<String> = r
            .tail_weights
            .iter()
            .zip(&r.tail_tau_ps)
            .map(|(w, t)| format!("{:.0} % at {t:.0} ps", 100.0 * w))
            .collect();
        println!(
            "umbra fit: detector response calibrated from the capture: core σ {:.1} ps, t0 {:.1} ps, tails [{}]",
            r.sigma_ps,
            r.t0_ps,
            tails.join(", ")
        );
    }
    println!(
        "umbra fit: {} iterations in {:.1} s (this run), final loss {:.4e} (relative L2 {:.3}, scale {:.4e}, background {:.4e}), {} vertices / {} faces{} -> {}",
        report.history.len(),
        report.seconds,
        report.final_loss,
        report.relative_l2,
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
    if let Some(c) = &summary.chamfer {
        println!(
            "umbra fit: Chamfer distance between the surfaces seen from the wall ({:.0} % of the fit's area, {:.0} % of the truth's) {:.2} mm (fit->truth {:.2} mm, truth->fit {:.2} mm); between the whole surfaces {:.2} mm",
            100.0 * c.fit_seen_area_fraction,
            100.0 * c.truth_seen_area_fraction,
            c.seen_mm,
            c.seen_fit_to_truth_mm,
            c.seen_truth_to_fit_mm,
            c.whole_mm,
        );
    }
    Ok(())
}
