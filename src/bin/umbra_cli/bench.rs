//! `umbra bench`: the built-in benchmarks (`umbra::bench`) behind the command line:
//! `tri3` (speed and error against subdivision), `grad` (adjoint against forward time and
//! memory), `ablation`, `accuracy` (error against time), `scaling` (time and memory
//! against size, a fresh process per point).

use super::grad_cli::{bench_grad, tri3_ratios};
use std::path::PathBuf;
use umbra::scene::Model;

#[derive(clap::Args)]
pub struct BenchArgs {
    /// Which benchmark: tri3, grad, tri3-grad (tri3 gradient vs render), ablation, accuracy,
    /// grad-accuracy, scaling, rays (the path tracer's rays/s against obvhs's).
    pub which: String,
    /// Timed repetitions (median reported).
    #[arg(long, default_value_t = 5)]
    pub reps: usize,
    /// Samples per seed of the mc3 reference of the error table (0: speed only, no table).
    #[arg(long, default_value_t = 1 << 19)]
    pub reference_spp: u32,
    /// Worker threads (default or 0: all cores; at most 4 per core, `umbra::threads`).
    #[arg(long)]
    pub threads: Option<usize>,
    /// grad-pass: the model.
    #[arg(long)]
    pub model: Option<String>,
    /// grad-pass / ablation: samples per measurement (ablation: 32768, reference 128x).
    #[arg(long)]
    pub spp: Option<u32>,
    /// ablation / accuracy: directory for the PNG and CSV (and accuracy's cached
    /// references).
    #[arg(long, default_value = "docs")]
    pub out: PathBuf,
    /// accuracy: stop a method's curve after a render longer than this (s).
    #[arg(long, default_value_t = 4.0)]
    pub budget: f64,
    /// scaling-point: the axis (index into bench::scaling::AXES) and its value.
    #[arg(long)]
    pub axis: Option<usize>,
    #[arg(long)]
    pub value: Option<u32>,
    /// accuracy: scenes (letter, sphere, bunny, corner), comma-separated.
    #[arg(long, default_value = "letter,sphere,bunny,corner")]
    pub scenes: String,
    /// accuracy: write the references and each scene as mitransient renders it (Mitsuba
    /// XML with box bins 8x finer, plus a TOML manifest) to this folder, then stop
    /// (python/bench/bench_accuracy_mitransient.py runs it).
    #[arg(long)]
    pub export_mitsuba: Option<PathBuf>,
    /// accuracy: more curves to chart with Umbra's (a CSV in accuracy.csv's columns: the
    /// mitransient curves of python/bench/bench_accuracy_mitransient.py).
    #[arg(long)]
    pub extra_curves: Option<PathBuf>,
    /// rays: the scene (TOML or Mitsuba XML; default: the built-in default scene) and its
    /// defines, NAME=VALUE.
    #[arg(long)]
    pub scene: Option<PathBuf>,
    #[arg(short = 'D', long = "define")]
    pub define: Vec<String>,
    /// accuracy / grad-accuracy: redraw the chart and table from the CSV in --out
    /// instead of measuring.
    #[arg(long)]
    pub replot: bool,
}

pub fn bench(args: BenchArgs) -> umbra::Result<()> {
    use umbra::bench;
    if !matches!(
        args.which.as_str(),
        "tri3"
            | "grad"
            | "tri3-grad"
            | "grad-pass"
            | "ablation"
            | "accuracy"
            | "grad-accuracy"
            | "scaling"
            | "scaling-point"
            | "rays"
    ) {
        return Err(umbra::Error::Invalid(format!(
            "bench: unknown benchmark '{}' (available: tri3, grad, tri3-grad, ablation, accuracy, grad-accuracy, scaling, rays)",
            args.which
        )));
    }
    let pool = umbra::threads::pool(args.threads, "--threads")?;
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
    if args.which == "tri3-grad" {
        return pool.install(|| tri3_ratios(&args));
    }
    if args.which == "ablation" {
        return pool.install(|| bench_ablation(&args));
    }
    if args.which == "accuracy" {
        return pool.install(|| bench_accuracy(&args));
    }
    if args.which == "grad-accuracy" {
        return pool.install(|| bench_grad_accuracy(&args));
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
    if args.which == "rays" {
        return pool.install(|| bench_rays(&args));
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

/// `umbra bench rays`: the scene's render against a replay of its rays (bench::rays).
fn bench_rays(args: &BenchArgs) -> umbra::Result<()> {
    let scene = crate::load_scene(args.scene.as_deref(), &args.define)?;
    let mut opts = umbra::transport::RenderOptions::from_scene(&scene);
    if let Some(spp) = args.spp {
        opts.spp = spp;
    }
    let f = umbra::bench::rays::rays(&scene, &opts, args.reps)?;
    let threads = rayon::current_num_threads();
    println!(
        "## Ray throughput: {:?}, {} measurements x {} spp, {} hidden triangles, {threads} threads\n",
        opts.model,
        scene.num_measurements(),
        opts.spp,
        scene.total_hidden_triangles()
    );
    println!(
        "{:.3} rays per sample ({} closest-hit, {} shadow); medians of {} runs.\n",
        f.rays_per_sample(),
        f.closest_rays,
        f.shadow_rays,
        args.reps.max(1)
    );
    println!("| what | seconds | M rays/s | M samples/s |");
    println!("|---|---|---|---|");
    let m = 1e-6;
    println!(
        "| render (effective: samples/s x rays/sample) | {:.4} | {:.2} | {:.2} |",
        f.render_seconds,
        m * f.effective_rays_per_second(),
        m * f.samples_per_second()
    );
    println!(
        "| its rays alone, Umbra's ray functions | {:.4} | {:.2} | |",
        f.umbra_replay_seconds,
        m * f.umbra_rays_per_second()
    );
    println!(
        "| its rays alone, bare obvhs CWBVH (wall as 2 triangles) | {:.4} | {:.2} | |",
        f.obvhs_replay_seconds,
        m * f.obvhs_rays_per_second()
    );
    println!(
        "\nRay queries at Umbra's rate would be {:.0} % of the render's time ({:.0} % at obvhs's). Hits: {} (Umbra), {} (obvhs), {} (every triangle tested).",
        100.0 * f.umbra_replay_seconds / f.render_seconds,
        100.0 * f.obvhs_replay_seconds / f.render_seconds,
        f.umbra_hits,
        f.obvhs_hits,
        f.brute_force_hits
            .map_or("not counted".to_string(), |h| h.to_string())
    );
    Ok(())
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
        if args.replot {
            names.push(*name);
            continue;
        }
        eprintln!(
            "bench accuracy: {name}: reference ({reference_spp} spp, cached in {})",
            cache.display()
        );
        let r = accuracy::reference(name, scene, reference_spp, &cache)?;
        names.push(*name);
        if let Some(dir) = &args.export_mitsuba {
            accuracy::export_mitsuba(name, scene, &r, dir, 8)?;
            println!(
                "{name}: reference {} ({:.3} %), mitransient scenes in {}",
                r.path.display(),
                100.0 * r.error,
                dir.display()
            );
            continue;
        }
        eprintln!(
            "bench accuracy: {name}: reference error {:.3} %; curves",
            100.0 * r.error
        );
        points.extend(accuracy::curves(name, scene, &r, args.budget)?);
        println!(
            "{name}: reference {reference_spp} spp, its own error {:.3} %",
            100.0 * r.error
        );
    }
    if args.export_mitsuba.is_some() {
        return Ok(());
    }
    std::fs::create_dir_all(&args.out).map_err(|e| umbra::Error::io(&args.out, e))?;
    let csv = args.out.join("accuracy.csv");
    if args.replot {
        points = accuracy::read_points(&csv, &names)?;
    } else {
        std::fs::write(&csv, accuracy::csv(&points)).map_err(|e| umbra::Error::io(&csv, e))?;
    }
    if let Some(extra) = &args.extra_curves {
        let more = accuracy::read_points(extra, &names)?;
        eprintln!(
            "bench accuracy: {} points from {}",
            more.len(),
            extra.display()
        );
        points.extend(more);
    }
    let png = args.out.join("accuracy.png");
    let title = "Relative L2 error against a converged multi-bounce reference, vs wall-clock time";
    accuracy::write_png(&png, title, &points, &names)?;
    print_time_to_table(&points, &names);
    println!("\n{} and {} written", png.display(), csv.display());
    Ok(())
}

/// The table of time to 5 % and 1 % error and each method's lowest error.
fn print_time_to_table(points: &[umbra::bench::accuracy::Point], names: &[&str]) {
    use umbra::bench::accuracy::time_to;
    let mut methods: Vec<&str> = Vec::new();
    for p in points {
        if !methods.contains(&p.method.as_str()) {
            methods.push(&p.method);
        }
    }
    println!("\n| scene | method | time to 5 % | time to 1 % | lowest error (its time) |");
    println!("|---|---|---|---|---|");
    let fmt = |t: Option<f64>| t.map_or("not reached".to_string(), |t| format!("{t:.3} s"));
    for scene in names {
        for m in &methods {
            let best = points
                .iter()
                .filter(|p| p.scene == *scene && p.method == *m)
                .min_by(|a, b| a.error.total_cmp(&b.error));
            if let Some(b) = best {
                println!(
                    "| {scene} | {m} | {} | {} | {:.2} % ({:.3} s) |",
                    fmt(time_to(points, scene, m, 0.05)),
                    fmt(time_to(points, scene, m, 0.01)),
                    100.0 * b.error,
                    b.seconds
                );
            }
        }
    }
}

/// `umbra bench grad-accuracy`: gradient error against time (bench::grad_accuracy).
fn bench_grad_accuracy(args: &BenchArgs) -> umbra::Result<()> {
    use umbra::bench::{accuracy, grad_accuracy as ga};
    let reference_spp = args.reference_spp.max(2);
    let cache = args.out.join("accuracy_cache");
    let csv = args.out.join("grad_accuracy.csv");
    let scenes = ga::scenes()?;
    let names: Vec<&'static str> = scenes.iter().map(|(n, _)| *n).collect();
    let mut points = if args.replot {
        accuracy::read_points(&csv, &names)?
    } else {
        Vec::new()
    };
    for (name, scene) in scenes.iter().filter(|_| !args.replot) {
        let adj = ga::adjoint_histogram(scene)?;
        eprintln!(
            "bench grad-accuracy: {name}: reference ({reference_spp} spp, cached in {})",
            cache.display()
        );
        let r = ga::reference(name, scene, &adj, reference_spp, &cache)?;
        println!(
            "{name}: reference gradient {reference_spp} spp, its own error {:.3} %",
            100.0 * r.error
        );
        points.extend(ga::curves(name, scene, &adj, &r, args.budget)?);
    }
    std::fs::create_dir_all(&args.out).map_err(|e| umbra::Error::io(&args.out, e))?;
    if !args.replot {
        std::fs::write(&csv, accuracy::csv(&points)).map_err(|e| umbra::Error::io(&csv, e))?;
    }
    let png = args.out.join("grad_accuracy.png");
    let title =
        "Vertex-gradient error against a converged multi-bounce reference, vs wall-clock time";
    accuracy::write_png(&png, title, &points, &names)?;
    print_time_to_table(&points, &names);
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
            table.push((*name, v, f[2], f[0], f[1] / 1024.0));
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
            if axis >= 3 { "samples" } else { "(measurement, sub-triangle) pairs" }
        );
        panels.push((
            format!("time vs {size_name} (fitted exponent {kt:.2})"),
            vec![Series {
                label: "seconds",
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
    println!("\n| axis | value | work (pairs or samples) | seconds (render or adjoint pass) | peak RSS MB |");
    println!("|---|---|---|---|---|");
    for (name, v, work, seconds, mb) in &table {
        println!("| {name} | {v} | {work:.0} | {seconds:.4} | {mb:.1} |");
    }
    std::fs::create_dir_all(&args.out).map_err(|e| umbra::Error::io(&args.out, e))?;
    let png = args.out.join("scaling.png");
    umbra::io::plot::loglog_panel_chart(
        &png,
        "Scaling: one axis at a time from the base case (tri3; path, mc3 and their adjoints for spp)",
        "size",
        "",
        2,
        &panels,
    )?;
    let csv = args.out.join("scaling.csv");
    let mut text = String::from("axis,value,work,seconds,peak_rss_mb\n");
    for (name, v, work, seconds, mb) in &table {
        text += &format!("{name},{v},{work:.0},{seconds:.6},{mb:.1}\n");
    }
    std::fs::write(&csv, text).map_err(|e| umbra::Error::io(&csv, e))?;
    println!("\n{} and {} written", png.display(), csv.display());
    Ok(())
}
