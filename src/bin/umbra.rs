//! The `umbra` command line: `umbra render [SCENE] -o OUT [options]`.

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};
use umbra::geometry::SceneGeometry;
use umbra::scene::Visibility;
use umbra::scene::{Model, Scene};
use umbra::transport::{Progress, RenderOptions, Renderer};

/// `umbra grad`, `umbra gradcheck` and `umbra bench grad`.
#[path = "umbra_cli/grad.rs"]
mod grad_cli;
use grad_cli::{bench_grad, grad, gradcheck, GradArgs, GradcheckArgs};

/// `umbra fit`.
#[path = "umbra_cli/fit.rs"]
mod fit_cli;

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
    /// Built-in benchmarks: `tri3` (speed on the 10k-triangle reference case and the
    /// error-vs-subdivision table); `grad` (adjoint against forward time, and the
    /// adjoint's peak memory against spp).
    Bench(BenchArgs),
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
struct BenchArgs {
    /// Which benchmark: tri3, grad, ablation, accuracy, scaling.
    which: String,
    /// Timed repetitions (median reported).
    #[arg(long, default_value_t = 5)]
    reps: usize,
    /// Samples per seed of the mc3 reference of the error table (0: speed only, no table).
    #[arg(long, default_value_t = 1 << 19)]
    reference_spp: u32,
    /// Worker threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// grad-pass: the model.
    #[arg(long)]
    model: Option<String>,
    /// grad-pass / ablation: samples per measurement (ablation: 32768, reference 128x).
    #[arg(long)]
    spp: Option<u32>,
    /// ablation / accuracy: directory for the PNG and CSV (and accuracy's cached
    /// references).
    #[arg(long, default_value = "docs")]
    out: PathBuf,
    /// accuracy: stop a method's curve after a render longer than this (s).
    #[arg(long, default_value_t = 4.0)]
    budget: f64,
    /// scaling-point: the axis (index into bench::scaling::AXES) and its value.
    #[arg(long)]
    axis: Option<usize>,
    #[arg(long)]
    value: Option<u32>,
    /// accuracy: scenes (letter, sphere, bunny, corner), comma-separated.
    #[arg(long, default_value = "letter,sphere,bunny,corner")]
    scenes: String,
}

#[derive(clap::Args)]
struct RenderArgs {
    /// Scene file: Umbra TOML (.toml) or mitransient-style Mitsuba XML (.xml).
    scene: Option<PathBuf>,
    /// Output file: .npy (mitransient's layout, default), .exr or .hdf5 / .h5 (y-tal's
    /// capture format). PNG previews are written next to it.
    #[arg(short, long, default_value = "transient.npy")]
    output: PathBuf,
    /// Light-transport model: tri3 (deterministic per-triangle three-bounce), mc3 (Monte
    /// Carlo three-bounce), path (multi-bounce) or auto (the cheapest accurate enough).
    #[arg(long)]
    model: Option<String>,
    /// tri3: shadow rays: none, centroid or subtriangle.
    #[arg(long)]
    visibility: Option<String>,
    /// tri3: subdivision threshold: largest h²/(r·w) of a sub-triangle (edge h, height
    /// above the wall r, bin width w), i.e. the OPL curvature across it in bins.
    #[arg(long)]
    subdivision: Option<f32>,
    /// auto: the relative error the chosen model may leave (e.g. 0.01).
    #[arg(long)]
    max_error: Option<f32>,
    /// Samples per measurement (overrides the scene).
    #[arg(long)]
    spp: Option<u32>,
    /// Random seed (overrides the scene).
    #[arg(long)]
    seed: Option<u64>,
    /// Worker threads (default: all cores). The output does not depend on it.
    #[arg(long)]
    threads: Option<usize>,
    /// Longest path in bounces, laser spot and sensor point included (3 = one hidden
    /// bounce); -1 for unbounded. Overrides the scene.
    #[arg(long, allow_negative_numbers = true)]
    max_depth: Option<i64>,
    /// Override the scene's laser sampling (NEE to the laser spot): true or false.
    #[arg(long)]
    laser_sampling: Option<bool>,
    /// Override hidden-geometry (area) sampling: true or false.
    #[arg(long)]
    hidden_geometry_sampling: Option<bool>,
    /// Override BSDF (cosine) sampling: true or false. With hidden-geometry sampling
    /// also on, the two are combined by multiple importance sampling.
    #[arg(long)]
    bsdf_sampling: Option<bool>,
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
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => render(args),
        Command::Bench(args) => bench(args),
        Command::Grad(args) => grad(args),
        Command::Gradcheck(args) => gradcheck(args),
        Command::Fit(args) => load_scene(args.scene.as_deref(), &args.define)
            .and_then(|scene| fit_cli::fit(args.fit, scene)),
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
    let mut scene = load_scene(args.scene.as_deref(), &args.define)?;
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(d) = args.max_depth {
        scene.render.max_bounces = match d {
            -1 => u32::MAX,
            d if d >= 3 => d as u32,
            d => {
                return Err(umbra::Error::Invalid(format!(
                    "--max-depth: must be -1 or >= 3 bounces, got {d}"
                )))
            }
        };
    }
    let t = &mut scene.render.techniques;
    t.laser_sampling = args.laser_sampling.unwrap_or(t.laser_sampling);
    t.hidden_geometry_sampling = args
        .hidden_geometry_sampling
        .unwrap_or(t.hidden_geometry_sampling);
    t.bsdf_sampling = args.bsdf_sampling.unwrap_or(t.bsdf_sampling);
    let mut opts = RenderOptions::from_scene(&scene);
    if let Some(m) = &args.model {
        opts.model = Model::parse(m).ok_or_else(|| {
            umbra::Error::Invalid(format!(
                "--model: '{m}' is not one of tri3, mc3, path, auto"
            ))
        })?;
    }
    if let Some(s) = args.spp {
        if s == 0 {
            return Err(umbra::Error::Invalid("--spp: must be at least 1".into()));
        }
        opts.spp = s;
    }
    if let Some(s) = args.seed {
        opts.seed = s;
    }
    if let Some(v) = &args.visibility {
        opts.visibility = Visibility::parse(v).ok_or_else(|| {
            umbra::Error::Invalid(format!(
                "--visibility: '{v}' is not one of none, centroid, subtriangle"
            ))
        })?;
    }
    if let Some(s) = args.subdivision {
        if !(s.is_finite() && s > 0.0) {
            return Err(umbra::Error::Invalid(format!(
                "--subdivision: must be > 0, got {s}"
            )));
        }
        opts.subdivision = s;
    }
    if let Some(e) = args.max_error {
        if !(e.is_finite() && e > 0.0) {
            return Err(umbra::Error::Invalid(format!(
                "--max-error: must be > 0, got {e}"
            )));
        }
        opts.max_error = e;
    }
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(t) = args.threads {
            b = b.num_threads(t.max(1));
        }
        b.build()
            .map_err(|e| umbra::Error::Invalid(format!("thread pool: {e}")))?
    };

    let start = Instant::now();
    let geom = SceneGeometry::build(&scene);
    let progress = Arc::new(Progress::default());
    {
        let p = progress.clone();
        // A second Ctrl-C kills the process the usual way.
        let _ = ctrlc::set_handler(move || {
            if p.cancel.swap(true, Ordering::Relaxed) {
                std::process::exit(130);
            }
        });
    }
    let renderer = pool.install(|| Renderer::new(&scene, &geom, &opts))?;
    if let Some(choice) = &renderer.auto_choice {
        eprintln!("auto: chose {}", choice.reason);
    }
    let total = renderer.total_work();
    let unit = renderer.work_unit();
    let bar = if args.quiet {
        ProgressBar::hidden()
    } else {
        let b = ProgressBar::new(total);
        b.set_style(
            ProgressStyle::with_template(&format!(
                "{{spinner}} [{{elapsed_precise}}] {{bar:40}} {{percent:>3}}% {{human_pos}}/{{human_len}} {unit} ({{per_sec}}, ETA {{eta}})"
            ))
            .expect("template"),
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
    umbra::io::write_capture(&args.output, &transient, &scene)?;
    let mut previews = Vec::new();
    if !args.no_preview {
        previews = umbra::io::preview::write_previews(&args.output, &transient)?;
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

fn bench(args: BenchArgs) -> umbra::Result<()> {
    use umbra::bench;
    if !matches!(
        args.which.as_str(),
        "tri3" | "grad" | "grad-pass" | "ablation" | "accuracy" | "scaling" | "scaling-point"
    ) {
        return Err(umbra::Error::Invalid(format!(
            "bench: unknown benchmark '{}' (available: tri3, grad, ablation, accuracy, scaling)",
            args.which
        )));
    }
    let mut b = rayon::ThreadPoolBuilder::new();
    if let Some(t) = args.threads {
        b = b.num_threads(t.max(1));
    }
    let pool = b
        .build()
        .map_err(|e| umbra::Error::Invalid(format!("thread pool: {e}")))?;
    if args.which == "grad-pass" {
        // Child of `bench grad`: one adjoint pass, then its peak memory.
        let model = Model::parse(args.model.as_deref().unwrap_or("mc3"))
            .ok_or_else(|| umbra::Error::Invalid("--model: tri3 or mc3".into()))?;
        pool.install(|| bench::grad_pass(model, args.spp.unwrap_or(1)))?;
        println!("{}", bench::peak_rss_kb().unwrap_or(0));
        return Ok(());
    }
    if args.which == "grad" {
        return pool.install(|| bench_grad(&args));
    }
    if args.which == "ablation" {
        return pool.install(|| bench_ablation(&args));
    }
    if args.which == "accuracy" {
        return pool.install(|| bench_accuracy(&args));
    }
    if args.which == "scaling-point" {
        // Child of `bench scaling`: one render, then its time, peak memory and work.
        let (s, kb, work) = pool.install(|| {
            umbra::bench::scaling::point(args.axis.unwrap_or(0), args.value.unwrap_or(8))
        })?;
        println!("{s} {kb} {work}");
        return Ok(());
    }
    if args.which == "scaling" {
        return bench_scaling(&args);
    }
    pool.install(|| {
        let threads = rayon::current_num_threads();
        let scene = bench::tri3_speed_scene()?;
        println!("## tri3 forward pass ({threads} threads)\n");
        println!("Confocal 64 x 64 scan, 512 bins of 4 mm, wavy sheet of {} triangles at 0.8 m, visibility none, box bins.\n", scene.total_hidden_triangles());
        println!("| subdivision | sub-triangles | setup s | render s (median of {}) | M pairs/s |", args.reps);
        println!("|---|---|---|---|---|");
        let s = umbra::scene::DEFAULT_SUBDIVISION;
        let t = bench::tri3_speed(&scene, args.reps, s)?;
        println!(
            "| {s} | {} | {:.3} | {:.3} | {:.1} |",
            t.subtriangles,
            t.setup_seconds,
            t.median(),
            t.mpairs_per_second()
        );
        if args.reference_spp == 0 {
            return Ok(());
        }
        println!("\n## tri3 error against mc3 as the subdivision threshold falls\n");
        let thresholds = [4.0, 1.0, 0.5, 0.3, 0.15, 0.08, 0.04];
        for (name, scene) in bench::error_table_scenes()? {
            let (noise, rows) = bench::tri3_error_table(&scene, args.reference_spp, &thresholds)?;
            println!(
                "{name}, confocal {}x{} scan, {} bins of {} mm; mc3 reference 2 x {} spp, its own noise {:.3} %:\n",
                scene.scan.nx,
                scene.scan.ny,
                scene.film.temporal_bins,
                scene.film.bin_width_opl * 1000.0,
                args.reference_spp,
                100.0 * noise
            );
            println!("| subdivision | sub-triangles | render s | rel. L2 vs mc3 | same, reference noise removed |");
            println!("|---|---|---|---|---|");
            for r in rows {
                println!(
                    "| {}{} | {} | {:.4} | {:.3} % | {:.3} % |",
                    r.subdivision,
                    if r.subdivision == umbra::scene::DEFAULT_SUBDIVISION { " (default)" } else { "" },
                    r.subtriangles,
                    r.seconds,
                    100.0 * r.error,
                    100.0 * r.error_without_noise(noise)
                );
            }
            println!();
        }
        Ok(())
    })
}

/// `umbra bench ablation`: the seed paper's sampling-technique comparison (bench::ablation).
fn bench_ablation(args: &BenchArgs) -> umbra::Result<()> {
    use umbra::bench::ablation;
    let spp = args.spp.unwrap_or(32768).max(1);
    let factor = 128; // the reference's noise: 1/sqrt(128) of the best variant's
    let scene = ablation::ablation_scene()?;
    let a = ablation::run(&scene, spp, factor)?;
    std::fs::create_dir_all(&args.out).map_err(|e| umbra::Error::io(&args.out, e))?;
    let csv = args.out.join("ablation.csv");
    std::fs::write(&csv, a.csv()).map_err(|e| umbra::Error::io(&csv, e))?;
    let png = args.out.join("ablation.png");
    a.write_png(&png)?;
    println!(
        "## Sampling techniques at equal samples ({spp} spp; reference {} spp, all techniques)\n",
        a.reference_spp
    );
    println!("Concave corner 0.8 m from the wall, one confocal scan point, laser spot of 5 cm radius, up to 6 bounces; BSDF sampling on in every variant (MIS).\n");
    println!(
        "| variant | laser sampling | hidden-geometry sampling | rel. L2 vs reference | time s |"
    );
    println!("|---|---|---|---|---|");
    for v in &a.variants {
        println!(
            "| {} | {} | {} | {:.2} % | {:.3} |",
            v.label,
            if v.laser_sampling { "on" } else { "off" },
            if v.hidden_geometry_sampling {
                "on"
            } else {
                "off"
            },
            100.0 * v.error,
            v.seconds
        );
    }
    println!("\n{} and {} written", png.display(), csv.display());
    Ok(())
}

/// `umbra bench accuracy`: error against time for every method (bench::accuracy).
fn bench_accuracy(args: &BenchArgs) -> umbra::Result<()> {
    use umbra::bench::accuracy;
    let wanted: Vec<&str> = args.scenes.split(',').map(str::trim).collect();
    let all = accuracy::scenes()?;
    if let Some(bad) = wanted.iter().find(|w| !all.iter().any(|(n, _)| n == *w)) {
        return Err(umbra::Error::Invalid(format!(
            "--scenes: '{bad}' is not one of letter, sphere, bunny, corner"
        )));
    }
    let reference_spp = args.reference_spp.max(2);
    let cache = args.out.join("accuracy_cache");
    let mut points = Vec::new();
    let mut names = Vec::new();
    for (name, scene) in all.iter().filter(|(n, _)| wanted.contains(n)) {
        eprintln!(
            "bench accuracy: {name}: reference ({reference_spp} spp, cached in {})",
            cache.display()
        );
        let r = accuracy::reference(name, scene, reference_spp, &cache)?;
        eprintln!(
            "bench accuracy: {name}: reference error {:.3} %; curves",
            100.0 * r.error
        );
        points.extend(accuracy::curves(name, scene, &r, args.budget)?);
        names.push(*name);
        println!(
            "{name}: reference {reference_spp} spp, its own error {:.3} %",
            100.0 * r.error
        );
    }
    std::fs::create_dir_all(&args.out).map_err(|e| umbra::Error::io(&args.out, e))?;
    let csv = args.out.join("accuracy.csv");
    std::fs::write(&csv, accuracy::csv(&points)).map_err(|e| umbra::Error::io(&csv, e))?;
    let png = args.out.join("accuracy.png");
    accuracy::write_png(&png, &points, &names)?;
    let mut methods: Vec<String> = Vec::new();
    for p in &points {
        if !methods.contains(&p.method) {
            methods.push(p.method.clone());
        }
    }
    println!("\n| scene | method | time to 5 % | time to 1 % | lowest error (its time) |");
    println!("|---|---|---|---|---|");
    for scene in &names {
        for m in &methods {
            let fmt = |t: Option<f64>| t.map_or("not reached".to_string(), |t| format!("{t:.3} s"));
            let best = points
                .iter()
                .filter(|p| p.scene == *scene && &p.method == m)
                .min_by(|a, b| a.error.total_cmp(&b.error));
            if let Some(b) = best {
                println!(
                    "| {scene} | {m} | {} | {} | {:.2} % ({:.3} s) |",
                    fmt(accuracy::time_to(&points, scene, m, 0.05)),
                    fmt(accuracy::time_to(&points, scene, m, 0.01)),
                    100.0 * b.error,
                    b.seconds
                );
            }
        }
    }
    println!("\n{} and {} written", png.display(), csv.display());
    Ok(())
}

/// `umbra bench scaling`: each point in a fresh process (bench::scaling).
fn bench_scaling(args: &BenchArgs) -> umbra::Result<()> {
    use umbra::bench::scaling::{exponent, AXES};
    use umbra::io::plot::Series;
    let exe = std::env::current_exe().map_err(|e| umbra::Error::Invalid(e.to_string()))?;
    let mut panels = Vec::new();
    let mut table = Vec::new();
    for (axis, (name, values)) in AXES.iter().enumerate() {
        let mut time = Vec::new();
        let mut memory = Vec::new();
        let mut per_work = Vec::new();
        for &v in values.iter() {
            let mut cmd = std::process::Command::new(&exe);
            cmd.args([
                "bench",
                "scaling-point",
                "--axis",
                &axis.to_string(),
                "--value",
                &v.to_string(),
            ]);
            if let Some(t) = args.threads {
                cmd.args(["--threads", &t.to_string()]);
            }
            let out = cmd
                .output()
                .map_err(|e| umbra::Error::Invalid(format!("bench scaling: {e}")))?;
            let text = String::from_utf8_lossy(&out.stdout);
            let f: Vec<f64> = text
                .split_whitespace()
                .filter_map(|w| w.parse().ok())
                .collect();
            if !out.status.success() || f.len() != 3 {
                return Err(umbra::Error::Invalid(format!(
                    "bench scaling: point {name} = {v} failed: {}",
                    String::from_utf8_lossy(&out.stderr)
                )));
            }
            // The natural size: measurements for the scan axis, else the value itself.
            let size = if axis == 0 { (v * v) as f64 } else { v as f64 };
            eprintln!(
                "bench scaling: {name} = {v}: {:.3} s, {:.0} MB",
                f[0],
                f[1] / 1024.0
            );
            time.push((size, f[0]));
            per_work.push((f[2], f[0]));
            memory.push((size, f[1] / 1024.0));
            table.push(format!(
                "| {name} | {v} | {:.0} | {:.4} | {:.1} |",
                f[2],
                f[0],
                f[1] / 1024.0
            ));
        }
        let (kt, km) = (exponent(&time), exponent(&memory));
        let size_name = if axis == 0 {
            "measurements (side²)"
        } else {
            name
        };
        println!(
            "{name}: time ∝ {size_name}^{kt:.2} (∝ work^{:.2}, work = {}), peak memory ∝ {size_name}^{km:.2}",
            exponent(&per_work),
            if axis == 3 { "samples" } else { "(measurement, sub-triangle) pairs" }
        );
        panels.push((
            format!("time vs {size_name} (fitted exponent {kt:.2})"),
            vec![Series {
                label: "render s",
                points: time,
            }],
        ));
        panels.push((
            format!("peak memory (MB) vs {size_name} (exponent {km:.2})"),
            vec![Series {
                label: "peak RSS MB",
                points: memory,
            }],
        ));
    }
    println!("\n| axis | value | work (pairs or samples) | render s | peak RSS MB |");
    println!("|---|---|---|---|---|");
    for row in &table {
        println!("{row}");
    }
    std::fs::create_dir_all(&args.out).map_err(|e| umbra::Error::io(&args.out, e))?;
    let png = args.out.join("scaling.png");
    umbra::io::plot::loglog_panel_chart(
        &png,
        "Scaling: one axis at a time from the base case (tri3; path for spp)",
        "size",
        "",
        2,
        &panels,
    )?;
    let csv = args.out.join("scaling.csv");
    let mut text = String::from("axis,value,work,seconds,peak_rss_mb\n");
    for row in &table {
        let cells: Vec<&str> = row.trim_matches('|').split('|').map(str::trim).collect();
        text += &cells.join(",");
        text.push('\n');
    }
    std::fs::write(&csv, text).map_err(|e| umbra::Error::io(&csv, e))?;
    println!("\n{} and {} written", png.display(), csv.display());
    Ok(())
}
