//! The gradient commands of the `umbra` CLI: `grad`, `gradcheck` and `bench grad`.

use super::flags::RenderFlags;
use super::{load_scene, BenchArgs};
use std::path::PathBuf;
use umbra::scene::Model;
use umbra::transport::{silence, RenderOptions};

#[derive(clap::Args)]
pub struct GradArgs {
    /// Scene file: Umbra TOML (.toml) or mitransient-style Mitsuba XML (.xml); default:
    /// the built-in default scene.
    scene: Option<PathBuf>,
    /// The measured transient (.npy, the render's shape): the loss is --loss against it.
    #[arg(long, required_unless_present = "adjoint", conflicts_with = "adjoint")]
    target: Option<PathBuf>,
    /// Instead of a target and a loss: the adjoint histogram dLoss/dH itself (.npy, the
    /// render's shape), for a loss of your own; `loss` is then written as 0 and no
    /// forward render is done.
    #[arg(long)]
    adjoint: Option<PathBuf>,
    /// Output .npz: `loss`, `vertices` (V x 3, rows in the OBJ's v order; `vertices_<k>`
    /// per object if there are several), `albedo` (one per object), `vertex_albedo[_<k>]`.
    #[arg(short, long, default_value = "grad.npz")]
    output: PathBuf,
    #[command(flatten)]
    flags: RenderFlags,
    /// Loss: l2 or l2-normalized (per scan point).
    #[arg(long, default_value = "l2")]
    loss: String,
    /// Worker threads (default or 0: all cores; at most 4 per core, `umbra::threads`). The output does not depend on it.
    #[arg(long)]
    threads: Option<usize>,
    /// Set a Mitsuba XML `$name` parameter, e.g. -D spp=64.
    #[arg(short = 'D', value_name = "NAME=VALUE")]
    define: Vec<String>,
}

#[derive(clap::Args)]
pub struct GradcheckArgs {
    /// Scene file: Umbra TOML (.toml) or mitransient-style Mitsuba XML (.xml); default:
    /// the built-in default scene.
    scene: Option<PathBuf>,
    #[command(flatten)]
    flags: RenderFlags,
    /// Vertex coordinates checked per object (plus each object's albedo).
    #[arg(long, default_value_t = 6)]
    params: usize,
    /// Finite-difference steps for vertex coordinates (m), comma-separated; albedo steps
    /// are 30x these.
    #[arg(long, value_delimiter = ',', default_value = "1e-4,3e-4,1e-3")]
    h: Vec<f64>,
    /// Largest accepted relative error (against max(|fd|, 2 % of the largest |fd|)).
    #[arg(long, default_value_t = 0.01)]
    tolerance: f64,
    /// Worker threads (default or 0: all cores; at most 4 per core, `umbra::threads`).
    #[arg(long)]
    threads: Option<usize>,
    /// Set a Mitsuba XML `$name` parameter, e.g. -D spp=64.
    #[arg(short = 'D', value_name = "NAME=VALUE")]
    define: Vec<String>,
    /// Check mc3 / path on the scene's box bins as they are (their vertex gradients
    /// then lack the time-of-flight term, and the check fails); by default box bins are
    /// checked on a Gaussian kernel of one bin.
    #[arg(long)]
    keep_box: bool,
}

/// Box bins give mc3 and path vertex gradients no time-of-flight term (a box's derivative
/// in a path's length is zero), so their check could never pass: unless `keep`, the
/// check runs on a Gaussian kernel of one bin instead, and says so.
fn gaussian_for_box_bins(scene: &mut umbra::Scene, model: Model, keep: bool) {
    use umbra::scene::KernelSpec;
    if keep || model == Model::Tri3 || scene.film.kernel != KernelSpec::Box {
        return;
    }
    let sigma_opl = scene.film.bin_width_opl;
    scene.film.kernel = KernelSpec::Gaussian { sigma_opl };
    eprintln!(
        "gradcheck: the scene's box bins give {} vertex gradients no time-of-flight term; checking on a Gaussian kernel of one bin instead (film.kernel = \"gaussian\", sigma_opl = {sigma_opl} m): the gradient to fit with (--keep-box checks the box bins as they are)",
        model.name()
    );
}

/// What a summary line says of the sampling: tri3 is deterministic (no spp).
fn sampling(opts: &RenderOptions) -> String {
    match opts.model {
        Model::Tri3 => format!("subdivision {}", opts.subdivision),
        _ => format!("{} spp", opts.spp),
    }
}

/// Ctrl-C ends `command` at once with a message (exit 130). The gradient is written
/// atomically at the end, so an interrupted run leaves any earlier `output` whole.
fn exit_on_ctrl_c(command: &'static str, output: Option<&std::path::Path>) {
    let note = output.map_or(String::new(), |o| {
        format!("; {} was not written", o.display())
    });
    let _ = ctrlc::set_handler(move || {
        eprintln!("\numbra {command}: interrupted{note}");
        optim::atomic::remove_live_temporaries();
        std::process::exit(130);
    });
}

pub fn grad(args: GradArgs) -> umbra::Result<()> {
    use umbra::adjoint::{self, Loss};
    // Before any work: a typo in the output must not cost a gradient.
    umbra::io::check_output_place(&args.output)?;
    let ext = args.output.extension().and_then(|e| e.to_str());
    if !ext.is_some_and(|e| e.eq_ignore_ascii_case("npz"))
        && !optim::atomic::is_special(&args.output)
    {
        return Err(umbra::Error::Invalid(format!(
            "-o {}: a gradient is written as a .npz archive (loss, vertices, albedo); give a name ending in .npz",
            args.output.display()
        )));
    }
    let mut scene = load_scene(args.scene.as_deref(), &args.define)?;
    for w in &scene.warnings {
        eprintln!("warning: {w}");
    }
    let mut opts = args.flags.overrides().apply(&mut scene)?;
    resolve_auto(&scene, &mut opts)?;
    let loss: Loss = args.loss.parse()?;
    if let Some(w) = adjoint::box_kernel_warning(&scene, opts.model) {
        eprintln!("warning: {w}");
    }
    let pool = umbra::threads::pool(args.threads, "--threads")?;
    exit_on_ctrl_c("grad", Some(&args.output));
    let (input, given) = match (&args.target, &args.adjoint) {
        (_, Some(a)) => (a, true),
        (Some(t), None) => (t, false),
        (None, None) => unreachable!("clap requires one"),
    };
    let array = umbra::io::read_npy(input)?;
    let t0 = std::time::Instant::now();
    let (value, g) = pool.install(|| -> umbra::Result<_> {
        let geom = umbra::geometry::SceneGeometry::build(&scene);
        let shape = scene.output_shape();
        if array.shape != shape {
            return Err(umbra::Error::scene(
                input,
                format!(
                    "shape {:?} differs from the render's {shape:?}",
                    array.shape
                ),
            ));
        }
        // Refused for the gradient before the render is spent on it.
        umbra::transport::gate::check(&scene, &opts, umbra::transport::gate::Pass::Gradient)?;
        // The render and the adjoint play one roulette: its pilot runs once.
        let scene = umbra::transport::roulette::resolved(
            &scene,
            &geom,
            &opts,
            umbra::transport::gate::Pass::Gradient,
        )?;
        let (value, adj) = if given {
            (0.0, array.data.clone())
        } else {
            let primal = umbra::transport::render(&scene, &geom, &opts, None)?;
            if silence::all_zero(&primal.data) {
                eprintln!(
                    "warning: the render is zero everywhere, so the gradient is too: {}",
                    silence::zero_reason(&scene)
                );
            } else if primal.data == array.data {
                eprintln!(
                    "warning: the render equals the target bin for bin ({}): the loss and the gradient are 0; a target rendered with the same seed and spp reproduces the render exactly (use another --seed, or a measured target)",
                    input.display()
                );
            }
            loss.evaluate(&primal.data, &array.data, primal.bins())?
        };
        if given && silence::all_zero(&adj) {
            eprintln!(
                "warning: the adjoint {} is zero everywhere: the gradient is 0",
                input.display()
            );
        }
        Ok((value, adjoint::gradient(&scene, &geom, &opts, &adj, None)?))
    })?;
    if g.truncated > 0 {
        eprintln!(
            "warning: {} of {} path contributions met more than {} hidden triangles; their \
             further triangles' share of the gradient is missing",
            g.truncated,
            g.contributions,
            umbra::transport::path::PATH_TRIANGLES
        );
    }
    umbra::io::write_gradient(&args.output, value, &g)?;
    let norm: f64 = g
        .vertices
        .iter()
        .flatten()
        .flatten()
        .map(|v| v * v)
        .sum::<f64>()
        .sqrt();
    let boundary = if g.boundary {
        format!("boundary terms from {} edge nodes", g.boundary_nodes)
    } else {
        "no boundary terms".to_string()
    };
    eprintln!(
        "umbra: loss {value:.6e}, |d/dvertices| {norm:.3e}, d/dalbedo {:?} ({}, {boundary}, {:.2} s) -> {}",
        g.albedo,
        sampling(&opts),
        t0.elapsed().as_secs_f64(),
        args.output.display()
    );
    Ok(())
}

pub fn gradcheck(args: GradcheckArgs) -> umbra::Result<()> {
    use umbra::adjoint::{self, check};
    let mut scene = load_scene(args.scene.as_deref(), &args.define)?;
    let mut opts = args.flags.overrides().apply(&mut scene)?;
    resolve_auto(&scene, &mut opts)?;
    gaussian_for_box_bins(&mut scene, opts.model, args.keep_box);
    if !(args.tolerance.is_finite() && args.tolerance > 0.0) {
        return Err(umbra::Error::Invalid(format!(
            "--tolerance: must be a number > 0, got {}",
            args.tolerance
        )));
    }
    if args.h.iter().any(|h| !(h.is_finite() && *h > 0.0)) {
        return Err(umbra::Error::Invalid("--h: steps must be > 0".into()));
    }
    if let Some(w) = adjoint::box_kernel_warning(&scene, opts.model) {
        eprintln!("warning: {w}");
    }
    let pool = umbra::threads::pool(args.threads, "--threads")?;
    exit_on_ctrl_c("gradcheck", None);
    // The gate's gradient refusals come first, as for `grad`.
    umbra::transport::gate::check(&scene, &opts, umbra::transport::gate::Pass::Gradient)?;
    // A render of nothing has nothing to check: said at once, with the cause, instead of
    // after every finite difference has come out zero.
    let base = pool.install(|| {
        let geom = umbra::geometry::SceneGeometry::build(&scene);
        umbra::transport::render(&scene, &geom, &opts, None)
    })?;
    if silence::all_zero(&base.data) {
        return Err(umbra::Error::Invalid(format!(
            "gradcheck: the render is zero everywhere, so there is no gradient to check: {}",
            silence::zero_reason(&scene)
        )));
    }
    let params = check::pick_params(&scene, args.params, opts.seed);
    let rows = pool.install(|| check::run(&scene, &opts, &params, &args.h))?;
    let largest = rows
        .iter()
        .flat_map(|r| r.fd.iter().map(|f| f.1.abs()))
        .fold(0.0, f64::max);
    let floor = 0.02 * largest;
    print!("| parameter | adjoint (interior) | boundary terms |");
    for h in &args.h {
        print!(" fd h={h:e} |");
    }
    println!(" best rel. error |");
    println!("|---|---|---|{}---|", "---|".repeat(args.h.len()));
    let mut worst = 0.0f64;
    let mut unstable = 0;
    for r in &rows {
        print!("| {} | {:.6e} | {:+.3e} |", r.param, r.adjoint, r.boundary);
        for (_, fd) in &r.fd {
            print!(" {fd:.6e} |");
        }
        let spread = r.fd_spread(floor);
        if spread > check::FD_UNSTABLE {
            unstable += 1;
            println!(" no reference (steps spread {:.0} %) |", 100.0 * spread);
            continue;
        }
        let e = r.error(floor);
        worst = worst.max(e);
        println!(" {e:.2e} |");
    }
    println!(
        "{} parameters ({} checked), model {}, {}; worst relative error {worst:.2e} (tolerance {:.0e})",
        rows.len(),
        rows.len() - unstable,
        opts.model.name(),
        sampling(&opts),
        args.tolerance
    );
    if rows.iter().any(|r| r.boundary != 0.0) {
        println!(
            "The adjoint compared is the interior derivative: finite differences at fixed \
             random numbers do not see shadows move. The gradient umbra grad returns adds the \
             boundary terms column (checked against an exact reference in tests/gradient_bias.rs; \
             --boundary-terms false leaves them out)."
        );
    }
    if unstable > 0 {
        println!(
            "{unstable} of {} parameters have no finite-difference reference: their differences \
             disagree across the steps by more than {:.0} % (a vertex that moves a shadow across \
             the samples makes the loss jump at fixed random numbers); they are left out of the \
             verdict. More --spp smooths them; tests/gradient_bias.rs checks such gradients \
             against exact references.",
            rows.len(),
            100.0 * check::FD_UNSTABLE
        );
    }
    if unstable == rows.len() {
        return Err(umbra::Error::Invalid(
            "gradcheck: no parameter has a stable finite difference to check against; try more --spp or --params".into(),
        ));
    }
    if largest == 0.0 {
        return Err(umbra::Error::Invalid(
            "gradcheck: every finite difference is zero (nothing in the scene reaches the film?)"
                .into(),
        ));
    }
    if worst > args.tolerance {
        return Err(umbra::Error::Invalid(format!(
            "gradcheck failed: relative error {worst:.2e} above the tolerance {:.0e}",
            args.tolerance
        )));
    }
    Ok(())
}

pub fn bench_grad(args: &BenchArgs) -> umbra::Result<()> {
    use umbra::bench;
    let scene = bench::grad_scene()?;
    let threads = rayon::current_num_threads();
    println!("## Gradient pass: time against the forward pass ({threads} threads)\n");
    println!(
        "Letter T (72 triangles), confocal 16 x 16, {} bins of {} mm, Gaussian kernel sigma 6 mm; \
         median of {} interleaved repetitions. The adjoint pass is given dLoss/dH (L2 against the \
         letter moved 2 cm); it reruns the sampling with derivatives.\n",
        scene.film.temporal_bins,
        scene.film.bin_width_opl * 1000.0,
        args.reps
    );
    println!(
        "Boundary terms (issue 18) on, and off (interior only) for their cost; tri3 with \
         visibility subtriangle. Second scene: the letter before a 1.2 m plate 0.3 m behind \
         it, which it shadows.\n"
    );
    println!(
        "| scene | model | spp | forward s | adjoint s | interior only s | adjoint / interior | adjoint / forward |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (name, mut scene) in [
        ("letter T", scene),
        ("letter T before a plate", bench::grad_scene_occluded()?),
    ] {
        scene.render.visibility = umbra::scene::Visibility::Subtriangle;
        for (model, spp) in [
            (Model::Mc3, 64),
            (Model::Mc3, 512),
            (Model::Path, 64),
            // From 1024 spp the roulette plays (`transport::roulette`); both passes are
            // timed at the pilot's choice, neither paying for the pilot.
            (Model::Path, 1024),
            (Model::Tri3, 1),
        ] {
            let t = bench::grad_timing(&scene, model, spp, args.reps)?;
            println!(
                "| {name} | {} | {} | {:.4} | {:.4} | {:.4} | {:.2} | {:.2} |",
                model.name(),
                if model == Model::Tri3 {
                    "-".to_string()
                } else {
                    spp.to_string()
                },
                t.forward,
                t.adjoint,
                t.interior,
                t.adjoint / t.interior,
                t.adjoint / t.forward
            );
        }
    }
    println!("\n## Gradient pass: peak memory against spp (a fresh process each)\n");
    println!("| model | spp | peak RSS MB |");
    println!("|---|---|---|");
    let exe = std::env::current_exe().map_err(|e| umbra::Error::Invalid(e.to_string()))?;
    let mut ratios = Vec::new();
    for model in ["mc3", "path"] {
        let mut peaks = Vec::new();
        for spp in [1u32, 16, 256, 4096] {
            let out = std::process::Command::new(&exe)
                .args([
                    "bench",
                    "grad-pass",
                    "--model",
                    model,
                    "--spp",
                    &spp.to_string(),
                ])
                .args(["--threads", &threads.to_string()])
                .output()
                .map_err(|e| umbra::Error::Invalid(format!("bench grad-pass: {e}")))?;
            let kb: f64 = String::from_utf8_lossy(&out.stdout)
                .trim()
                .parse()
                .unwrap_or(f64::NAN);
            peaks.push(kb);
            println!("| {model} | {spp} | {:.1} |", kb / 1024.0);
        }
        let (lo, hi) = peaks
            .iter()
            .fold((f64::INFINITY, 0.0f64), |(l, h), &p| (l.min(p), h.max(p)));
        ratios.push(format!("{model} {:.3}", hi / lo));
    }
    println!("\nLargest / smallest: {}", ratios.join(", "));
    Ok(())
}

/// `umbra bench tri3-grad`: the `tri3` gradient against its render (issue 19) on the
/// default scene, the accuracy benchmark's sphere and the 10k-triangle sheet, with the box kernel and a Gaussian of
/// 1.5 bins, each scene's own visibility mode.
pub fn tri3_ratios(args: &BenchArgs) -> umbra::Result<()> {
    use umbra::bench;
    use umbra::scene::KernelSpec;
    println!("\n## tri3: gradient against render\n");
    println!(
        "Each scene with its own visibility mode; adjoint = L2 against the scene moved 2 cm; \
         median of {} interleaved repetitions. Gaussian: sigma = 1.5 bins.\n",
        args.reps
    );
    println!(
        "| scene | kernel | visibility | forward s | adjoint s | interior only s | adjoint / forward | interior / forward |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    let scenes = [
        ("default scene", umbra::scene::default::default_scene()?),
        ("accuracy sphere", bench::accuracy::scene("sphere")?),
        ("10k-triangle sheet", bench::tri3_speed_scene()?),
    ];
    for (name, scene) in scenes {
        for gaussian in [false, true] {
            let mut scene = scene.clone();
            scene.film.kernel = if gaussian {
                KernelSpec::Gaussian {
                    sigma_opl: 1.5 * scene.film.bin_width_opl,
                }
            } else {
                KernelSpec::Box
            };
            let t = bench::grad_timing(&scene, Model::Tri3, 1, args.reps)?;
            println!(
                "| {name} | {} | {:?} | {} |",
                if gaussian { "gaussian" } else { "box" },
                scene.render.visibility,
                t.ratio_cells()
            );
        }
    }
    Ok(())
}

/// Gradients need a concrete model: `auto` runs its pilot and takes what it picks, as
/// `umbra render` and Python's `grad` do.
fn resolve_auto(scene: &umbra::scene::Scene, opts: &mut RenderOptions) -> umbra::Result<()> {
    if opts.model == Model::Auto {
        let geom = umbra::geometry::SceneGeometry::build(scene);
        let r = umbra::transport::Renderer::new(scene, &geom, opts)?;
        if let Some(c) = &r.auto_choice {
            eprintln!("auto: chose {}", c.reason);
        }
        opts.model = r.model;
    }
    Ok(())
}
