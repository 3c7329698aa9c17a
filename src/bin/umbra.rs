//! The `umbra` command line: `umbra render [SCENE] -o OUT [options]`.

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};
use umbra::geometry::SceneGeometry;
use umbra::scene::{Model, Scene};
use umbra::transport::{Progress, Renderer};

/// The render options shared by render, grad and gradcheck.
#[path = "umbra_cli/flags.rs"]
mod flags;
/// `umbra grad`, `umbra gradcheck` and `umbra bench grad`.
#[path = "umbra_cli/grad.rs"]
mod grad_cli;
use grad_cli::{grad, gradcheck, GradArgs, GradcheckArgs};

/// `umbra fit`.
#[path = "umbra_cli/fit.rs"]
mod fit_cli;

/// `umbra recon`.
#[path = "umbra_cli/recon.rs"]
mod recon_cli;

/// `umbra bench`.
#[path = "umbra_cli/bench.rs"]
mod bench_cli;
use bench_cli::{bench, BenchArgs};

#[derive(Parser)]
#[command(
    name = "umbra",
    version,
    about = "Differentiable transient renderer for NLOS imaging"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render a transient. With no SCENE, renders the built-in default scene.
    Render(RenderArgs),
    /// Gradient of a loss between the render and a measured transient with respect to the
    /// hidden meshes' vertex positions and albedos (path replay).
    Grad(GradArgs),
    /// Check the adjoint gradient against central finite differences with common random
    /// numbers on a few random parameters; exits non-zero above the tolerance.
    Gradcheck(GradcheckArgs),
    /// Fit the hidden mesh to a measured transient (with no --measured: render a target
    /// from the scene's hidden objects with the path model and fit that, a
    /// demonstration with a known answer).
    Fit(FitCliArgs),
    /// A classical reconstruction (bp, fbp, lct, pf) of a measurement, its per-column
    /// depth surface, and with --truth that surface's score against the scene's hidden
    /// objects (seen Chamfer, completeness, depth error).
    Recon(ReconCliArgs),
    /// Write a measurement in another format with the scene's capture geometry: .npy,
    /// .exr or y-tal .hdf5 (e.g. a mitransient .npy for y-tal's reconstructions).
    Convert(ConvertArgs),
    /// Built-in benchmarks: tri3 (speed and error against subdivision), grad (adjoint
    /// against forward time and memory), tri3-grad, ablation (the sampling techniques),
    /// accuracy (error against time per model), grad-accuracy, scaling, rays (the path
    /// tracer's rays/s against obvhs's).
    Bench(BenchArgs),
    /// Write the scene for mitransient 1.3.1: Mitsuba XML plus one world-space OBJ per
    /// hidden object (what mitransient cannot express is refused, naming the field).
    ExportMitsuba(ExportArgs),
}

#[derive(clap::Args)]
struct ExportArgs {
    /// Scene (TOML or Mitsuba XML); default: the built-in default scene.
    scene: Option<PathBuf>,
    /// Output .xml (the OBJ files go next to it).
    #[arg(short, long, default_value = "scene.xml")]
    output: PathBuf,
    /// Mitsuba-style defines for XML scenes, NAME=VALUE.
    #[arg(short = 'D', long = "define")]
    define: Vec<String>,
}

#[derive(clap::Args)]
struct FitCliArgs {
    /// Scene (TOML or Mitsuba XML); default: the built-in default scene.
    scene: Option<PathBuf>,
    /// Mitsuba-style defines for XML scenes, NAME=VALUE.
    #[arg(short = 'D', long = "define")]
    define: Vec<String>,
    #[command(flatten)]
    fit: fit_cli::FitArgs,
}

#[derive(clap::Args)]
struct ConvertArgs {
    /// Scene (TOML or Mitsuba XML) whose capture the measurement is.
    scene: Option<PathBuf>,
    /// Mitsuba-style defines for XML scenes, NAME=VALUE.
    #[arg(short = 'D', long = "define")]
    define: Vec<String>,
    /// The measurement (.npy in the scene's layout, y-tal .hdf5 or an LCT .mat).
    #[arg(long)]
    measured: PathBuf,
    /// Output file: .npy, .exr or .hdf5 / .h5.
    #[arg(short, long)]
    output: PathBuf,
    /// Zero the bins before this OPL (m): residual direct light in measured data.
    #[arg(long)]
    ignore_before: Option<f32>,
    /// Sum every K consecutive bins (the film's bin width grows K times).
    #[arg(long, default_value_t = 1, value_parser = flags::at_least_one)]
    time_bin: usize,
}

/// `umbra convert`.
fn convert(args: ConvertArgs) -> umbra::Result<()> {
    let scene = load_scene(args.scene.as_deref(), &args.define)?;
    umbra::io::check_output(&args.output)?;
    let m = umbra::io::measured::read_measured(&args.measured)?;
    let mut scene = m.scene_for(&scene)?;
    m.check_against(&scene)?;
    let mut t = m.transient;
    let bins = scene.film.temporal_bins as usize;
    umbra::fit::objective::check_ignore_before(&scene.film, args.ignore_before, "--ignore-before")?;
    if let Some(opl) = args.ignore_before {
        let film = &scene.film;
        let first = ((opl - film.start_opl) / film.bin_width_opl)
            .ceil()
            .max(0.0) as usize;
        umbra::recon::zero_bins_before(&mut t.data, bins, first.min(bins));
    }
    if args.time_bin > 1 {
        let (film, data) = umbra::recon::downsample_time(&scene.film, &t.data, args.time_bin)?;
        scene.film = film;
        t.data = data;
        if let Some(last) = t.shape.last_mut() {
            *last = scene.film.temporal_bins as usize;
        }
    }
    umbra::io::write_capture(&args.output, &t, &scene)?;
    println!(
        "umbra convert: {} {:?} -> {}",
        args.measured.display(),
        t.shape,
        args.output.display()
    );
    Ok(())
}

#[derive(clap::Args)]
struct ReconCliArgs {
    /// Scene (TOML or Mitsuba XML); default: the built-in default scene.
    scene: Option<PathBuf>,
    /// Mitsuba-style defines for XML scenes, NAME=VALUE.
    #[arg(short = 'D', long = "define")]
    define: Vec<String>,
    #[command(flatten)]
    recon: recon_cli::ReconArgs,
}

#[derive(clap::Args)]
struct RenderArgs {
    /// Scene file: Umbra TOML (.toml) or mitransient-style Mitsuba XML (.xml).
    scene: Option<PathBuf>,
    /// Output file: .npy (mitransient's layout, default), .exr or .hdf5 / .h5 (y-tal's
    /// capture format). PNG previews are written next to it.
    #[arg(short, long, default_value = "transient.npy")]
    output: PathBuf,
    #[command(flatten)]
    flags: flags::RenderFlags,
    /// Worker threads (default or 0: all cores; at most 4 per core, `umbra::threads`). The output does not depend on it.
    #[arg(long)]
    threads: Option<usize>,
    /// Set a Mitsuba XML `$name` parameter (overrides its <default>), e.g. -D spp=64.
    #[arg(short = 'D', value_name = "NAME=VALUE")]
    define: Vec<String>,
    /// Do not write the PNG previews.
    #[arg(long)]
    no_preview: bool,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
}

fn main() {
    // Past a file-size limit (`ulimit -f`) a write fails with EFBIG instead of the signal
    // killing the process mid-write, so the temporary is removed and the error named.
    // SAFETY: setting a signal's disposition to SIG_IGN has no preconditions.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => render(args),
        Command::Bench(args) => bench(args),
        Command::Grad(args) => grad(args),
        Command::Gradcheck(args) => gradcheck(args),
        Command::Fit(args) => load_scene(args.scene.as_deref(), &args.define)
            .and_then(|scene| fit_cli::fit(args.fit, scene)),
        Command::Convert(args) => convert(args),
        Command::Recon(args) => load_scene(args.scene.as_deref(), &args.define)
            .and_then(|scene| recon_cli::recon(args.recon, scene)),
        Command::ExportMitsuba(args) => {
            load_scene(args.scene.as_deref(), &args.define).and_then(|scene| {
                let out = umbra::scene::mitsuba_xml::write::write(&scene, &args.output)?;
                for w in &out.warnings {
                    eprintln!("warning: {w}");
                }
                println!(
                    "{} written ({} OBJ file(s))",
                    out.xml.display(),
                    out.objs.len()
                );
                Ok(())
            })
        }
    };
    if let Err(e) = result {
        eprintln!("error: {e}");
        std::process::exit(if matches!(e, umbra::Error::Cancelled) {
            130
        } else {
            1
        });
    }
}

fn load_scene(path: Option<&Path>, defines: &[String]) -> umbra::Result<Scene> {
    let defines = defines
        .iter()
        .map(|d| match d.split_once('=') {
            Some((k, v)) if !k.is_empty() => Ok((k.to_string(), v.to_string())),
            _ => Err(umbra::Error::Invalid(format!(
                "-D {d}: expected NAME=VALUE"
            ))),
        })
        .collect::<umbra::Result<Vec<_>>>()?;
    match path {
        Some(p) => Scene::load_with_defines(p, &defines),
        None if defines.is_empty() => umbra::scene::default::default_scene(),
        None => Err(umbra::Error::Invalid("-D needs a Mitsuba XML scene".into())),
    }
}

fn render(args: RenderArgs) -> umbra::Result<()> {
    // The output's format and folder first: a typo must not cost a render.
    umbra::io::check_output(&args.output)?;
    let mut scene = load_scene(args.scene.as_deref(), &args.define)?;
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
    let opts = args.flags.overrides().apply(&mut scene)?;
    let pool = umbra::threads::pool(args.threads, "--threads")?;

    let start = Instant::now();
    let geom = SceneGeometry::build(&scene);
    let progress = Arc::new(Progress::default());
    {
        let p = progress.clone();
        // A second Ctrl-C kills the process the usual way.
        let _ = ctrlc::set_handler(move || {
            if p.cancel.swap(true, Ordering::Relaxed) {
                optim::atomic::remove_live_temporaries();
                std::process::exit(130);
            }
        });
    }
    let renderer = pool.install(|| Renderer::new(&scene, &geom, &opts))?;
    if let Some(choice) = &renderer.auto_choice {
        eprintln!("auto: chose {}", choice.reason);
    }
    let capped = renderer.subdivision_capped();
    if capped > 0 {
        eprintln!(
            "warning: tri3: {capped} triangle(s) need more than {} subdivision levels for \
             --subdivision {}; they stay coarser than asked (split them in the mesh; \
             BENCHMARKS.md, where methods fail)",
            umbra::transport::tri3::MAX_LEVEL,
            opts.subdivision
        );
    }
    let total = renderer.total_work();
    let unit = renderer.work_unit();
    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(total);
        b.set_style(
            ProgressStyle::with_template(&format!(
                "{{spinner}} [{{elapsed_precise}}] {{bar:40}} {{percent:>3}}% {{human_pos}}/{{human_len}} {unit} ({{rate}}, ETA {{eta}})"
            ))
            .expect("template")
            // indicatif's own {per_sec} prints "3,015,942.4269/s".
            .with_key("rate", |s: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
                let _ = write!(w, "{}/s", umbra::io::plot::si(s.per_sec()));
            }),
        );
        b
    };
    let done = std::sync::atomic::AtomicBool::new(false);
    let result = std::thread::scope(|s| {
        // The bar is refreshed every 100 ms; the render's end wakes the watcher at once,
        // so it never delays the command.
        let watcher = s.spawn(|| {
            while !done.load(Ordering::Acquire) {
                bar.set_position(progress.work_done.load(Ordering::Relaxed));
                std::thread::park_timeout(Duration::from_millis(100));
            }
        });
        let r = pool.install(|| renderer.render(Some(&progress)));
        done.store(true, Ordering::Release);
        watcher.thread().unpark();
        let _ = watcher.join();
        r
    });
    bar.finish_and_clear();
    let transient = result?;
    let secs = start.elapsed().as_secs_f64();
    if umbra::transport::silence::all_zero(&transient.data) {
        eprintln!(
            "warning: the render is zero everywhere: {}",
            umbra::transport::silence::zero_reason(&scene)
        );
    }
    umbra::io::write_capture(&args.output, &transient, &scene)?;
    let mut previews = Vec::new();
    // No previews beside a device or a pipe (`-o /dev/null` must not make /dev/null_*.png).
    if !args.no_preview && !optim::atomic::is_special(&args.output) {
        let axes = umbra::io::preview::PreviewAxes::of(&scene);
        previews = umbra::io::preview::write_previews(&args.output, &transient, &axes)?;
    }
    let detail = match renderer.model {
        Model::Tri3 => format!(
            "{} sub-triangles, visibility {}",
            renderer.subtriangles(),
            opts.visibility.name()
        ),
        _ => format!("{} spp, seed {}", opts.spp, opts.seed),
    };
    println!(
        "umbra: {} {:?} ({}, {} triangles, {detail}) in {secs:.2} s: {:.3} M {unit}/s -> {}{}",
        scene.capture.name(),
        transient.shape,
        renderer.model.name(),
        scene.total_hidden_triangles(),
        total as f64 / secs / 1e6,
        args.output.display(),
        if previews.is_empty() {
            String::new()
        } else {
            format!(" (+ {} previews)", previews.len())
        }
    );
    Ok(())
}
