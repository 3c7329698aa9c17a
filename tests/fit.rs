//! Fitting on small versions of the recovery cases (the full studies are in
//! docs/FITTING.md): a fit against a multi-bounce (`path`) target moves a plane onto
//! the letter T, small versions of the sphere and angled-letter studies reach the
//! surface the wall sees, and a killed-and-resumed fit ends bit-identical to an
//! uninterrupted one.

use optim::checkpoint::LossRecord;
use optim::fit::Progress;
use optim::{Schedule, SolverKind, Stage};
use std::cell::RefCell;
use std::path::PathBuf;
use std::rc::Rc;
use umbra::fit::metrics::chamfer;
use umbra::fit::run::initial_mesh;
use umbra::fit::{fit, FitConfig, Init};
use umbra::geometry::SceneGeometry;
use umbra::scene::default::default_scene;
use umbra::scene::{Model, Scene};
use umbra::transport::{RenderOptions, Renderer};

fn small_scene() -> Scene {
    let mut scene = default_scene().unwrap();
    scene.scan.nx = 8;
    scene.scan.ny = 8;
    scene.film.temporal_bins = 128;
    scene.film.bin_width_opl = 0.016;
    scene
}

fn target(scene: &Scene) -> Vec<f32> {
    let geom = SceneGeometry::build(scene);
    let opts = RenderOptions {
        model: Model::Path,
        spp: 512,
        ..RenderOptions::from_scene(scene)
    };
    Renderer::new(scene, &geom, &opts)
        .unwrap()
        .render(None)
        .unwrap()
        .data
}

fn truth(scene: &Scene) -> optim::Mesh {
    umbra::fit::fit_mesh(&scene.objects[0].mesh)
}

fn stage(iters: u64, solver: SolverKind, lr: f64, time: u32, fit_albedo: bool) -> Stage {
    Stage {
        large_steps: 10.0,
        fit_albedo,
        time_downsample: time,
        ..Stage::new(iters, solver, lr)
    }
}

fn config(schedule: Schedule) -> FitConfig {
    FitConfig {
        schedule,
        init: Init::Plane,
        model: Model::Tri3,
        spp: 8,
        intensity: umbra::fit::IntensityModel {
            scale: true,
            background: umbra::fit::Background::None,
        },
        two_sided: true,
        albedo: 0.9,
        resume: false,
        ignore_before_opl: None,
        jitter_opl: 0.0,
        time_offset_max_opl: 0.0,
        irf: None,
        reflectance: Default::default(),
        photon_counts: None,
        capture: None,
    }
}

fn out_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("umbra-fit-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn quiet(stop_at: Option<u64>) -> Progress {
    Rc::new(RefCell::new(move |r: &LossRecord| {
        stop_at.is_none_or(|s| r.iteration < s)
    }))
}

#[test]
fn a_plane_fits_the_letter_rendered_by_the_path_tracer() {
    let scene = small_scene();
    let measured = target(&scene);
    let schedule = Schedule {
        stages: vec![
            stage(40, SolverKind::Adam, 0.01, 2, false),
            stage(40, SolverKind::Adam, 0.004, 1, true),
        ],
        checkpoint_every: 10,
    };
    let cfg = config(schedule);
    let d = out_dir("letter");
    let report = fit(&scene, &measured, &cfg, &d, quiet(None)).unwrap();
    let t = truth(&scene);
    let before = chamfer(
        &initial_mesh(&scene, &measured, 0, &Init::Plane).unwrap(),
        &t,
        2000,
    );
    let after = chamfer(&report.mesh, &t, 2000);
    let first = report.history[0].data_loss;
    eprintln!(
        "loss {first:.4} -> {:.4} (full resolution {:.4}); Chamfer {:.1} mm -> {:.1} mm (fit->truth {:.1}, truth->fit {:.1})",
        report.history.last().unwrap().data_loss,
        report.final_loss,
        1e3 * before.symmetric,
        1e3 * after.symmetric,
        1e3 * after.fit_to_truth,
        1e3 * after.truth_to_fit
    );
    assert!(
        report.final_loss < 0.25 * first,
        "loss {first} -> {}",
        report.final_loss
    );
    assert!(
        after.symmetric < 0.5 * before.symmetric,
        "{before:?} -> {after:?}"
    );
    assert!(report
        .mesh
        .vertices
        .iter()
        .all(|p| p.iter().all(|c| c.is_finite())));
    for f in [
        "mesh.obj",
        "mesh_all.obj",
        "loss.csv",
        "loss.png",
        "transients.png",
    ] {
        assert!(d.join(f).is_file(), "{f} missing");
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_killed_fit_resumes_to_the_same_mesh() {
    let scene = small_scene();
    let measured = target(&scene);
    let schedule = Schedule {
        stages: vec![
            stage(8, SolverKind::Adam, 0.01, 2, false),
            stage(6, SolverKind::Lbfgs, 0.0, 1, true),
        ],
        checkpoint_every: 3,
    };
    let whole_dir = out_dir("whole");
    let whole = fit(
        &scene,
        &measured,
        &config(schedule.clone()),
        &whole_dir,
        quiet(None),
    )
    .unwrap();
    let d = out_dir("killed");
    assert!(fit(
        &scene,
        &measured,
        &config(schedule.clone()),
        &d,
        quiet(Some(10))
    )
    .is_err());
    let mut resume = config(schedule);
    resume.resume = true;
    let resumed = fit(&scene, &measured, &resume, &d, quiet(None)).unwrap();
    assert_eq!(resumed.full_mesh, whole.full_mesh);
    assert_eq!(resumed.history, whole.history);
    let _ = std::fs::remove_dir_all(&d);
    let _ = std::fs::remove_dir_all(&whole_dir);
}

/// A study scene (`scenes/studies/NAME.toml`) at 16 x 16 scan points and 128 bins of
/// 16 mm, its target rendered by the path tracer.
fn small_study(name: &str) -> (Scene, Vec<f32>) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("scenes/studies")
        .join(format!("{name}.toml"));
    let mut scene = Scene::load(&path).unwrap();
    scene.scan.nx = 16;
    scene.scan.ny = 16;
    scene.film.temporal_bins = 128;
    scene.film.bin_width_opl = 0.016;
    let measured = target(&scene);
    (scene, measured)
}

/// Small versions of the recovery studies (docs/FITTING.md): the default schedule's
/// first stage shape (Adam, large steps λ = 2, step 0.03, coarse scan subsampled) brings
/// a generic mesh within a centimetre or two of the surface the wall sees.
#[test]
fn small_recovery_studies_reach_the_seen_surface() {
    for (name, init, limit_mm) in [
        ("sphere", Init::Sphere, 15.0),
        ("letter_angled", Init::Plane, 6.0),
    ] {
        let (scene, measured) = small_study(name);
        let mut adam = stage(60, SolverKind::Adam, 0.03, 2, false);
        adam.large_steps = 2.0;
        adam.scan_downsample = 2;
        let mut albedo = stage(30, SolverKind::Adam, 0.01, 1, true);
        albedo.large_steps = 2.0;
        albedo.remesh_factor = Some(0.5);
        let mut cfg = config(Schedule {
            stages: vec![adam, albedo],
            checkpoint_every: 100,
        });
        cfg.init = init.clone();
        let d = out_dir(name);
        let report = fit(&scene, &measured, &cfg, &d, quiet(None)).unwrap();
        let t = truth(&scene);
        let start = initial_mesh(&scene, &measured, 0, &init).unwrap();
        let (before, _) = umbra::fit::metrics::chamfer_seen(&start, &t, &scene, 2000);
        let (after, _) = umbra::fit::metrics::chamfer_seen(&report.mesh, &t, &scene, 2000);
        eprintln!(
            "{name}: seen Chamfer {:.1} mm -> {:.1} mm (fit->truth {:.1}, truth->fit {:.1}); relative L2 {:.3}",
            1e3 * before.symmetric,
            1e3 * after.symmetric,
            1e3 * after.fit_to_truth,
            1e3 * after.truth_to_fit,
            report.final_loss.sqrt()
        );
        assert!(1e3 * after.symmetric < limit_mm, "{name}: {after:?}");
        assert!(
            after.symmetric < 0.5 * before.symmetric,
            "{name}: {before:?} -> {after:?}"
        );
        assert!(d.join("reconstruction.png").is_file());
        let _ = std::fs::remove_dir_all(&d);
    }
}

/// A fresh test folder `name` with a three-iteration coarse schedule (checkpoints every
/// two iterations) in it: the folder and the schedule's path.
fn tiny_schedule(name: &str) -> (PathBuf, PathBuf) {
    let d = out_dir(name);
    std::fs::create_dir_all(&d).unwrap();
    let config = d.join("schedule.toml");
    std::fs::write(
        &config,
        "checkpoint_every = 2\n[[stage]]\niters = 3\nlr = 0.01\nlarge_steps = 10.0\ntime_downsample = 8\nscan_downsample = 4\n",
    )
    .unwrap();
    (d, config)
}

/// The CLI end to end on the default scene with a tiny schedule: outputs written, a
/// second run refuses to overwrite the checkpoint, `--resume` of the finished fit
/// rewrites the outputs, and a missing measurement is an error naming the file.
#[test]
fn cli_fit_runs_resumes_and_reports_bad_input() {
    let exe = env!("CARGO_BIN_EXE_umbra");
    let (d, config) = tiny_schedule("cli");
    let out = d.join("out");
    let run = |extra: &[&str]| {
        std::process::Command::new(exe)
            .args(["fit", "-q", "--target-spp", "16", "--config"])
            .arg(&config)
            .arg("-o")
            .arg(&out)
            .args(extra)
            .output()
            .unwrap()
    };
    let first = run(&[]);
    let stdout = String::from_utf8_lossy(&first.stdout);
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    assert!(stdout.contains("Chamfer distance"), "{stdout}");
    for f in [
        "mesh.obj",
        "loss.png",
        "transients.png",
        "target.npy",
        "checkpoint/stage.bin",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let again = run(&[]);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("--resume"));
    std::fs::remove_file(out.join("mesh.obj")).unwrap();
    let resumed = run(&["--resume"]);
    assert!(
        resumed.status.success(),
        "{}",
        String::from_utf8_lossy(&resumed.stderr)
    );
    assert!(out.join("mesh.obj").is_file());
    let bad = run(&["--measured", "/nonexistent/capture.npy"]);
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("/nonexistent/capture.npy"));
    // Options that contradict each other or name nothing: refused, saying which.
    let fresh = d.join("fresh");
    for (args, says) in [
        (&["--time-offset", "0.02"][..], "--jitter"),
        (
            &["--jitter", "0.01", "--irf", "direct"][..],
            "--jitter and --irf",
        ),
        (&["--irf", "direct"][..], "--ignore-before"),
        (&["--reflectance", "mirror"][..], "mirror"),
        (&["--background", "sometimes"][..], "sometimes"),
        (&["--jitter=-1"][..], "--jitter"),
    ] {
        let r = std::process::Command::new(exe)
            .args(["fit", "-q", "--target-spp", "4", "--config"])
            .arg(&config)
            .arg("-o")
            .arg(&fresh)
            .args(args)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{args:?} was accepted");
        assert!(err.contains(says), "{args:?}: {err}");
    }
    let _ = std::fs::remove_dir_all(&d);
}

/// `--init auto` on the (confocal) default scene: a fit from each start (plane, sphere,
/// LCT) in its own folder, the summary listing their losses, the kept start the one the
/// rule picks (the last within 1 % of the lowest loss), its outputs copied to the top
/// (mesh.obj byte for byte), and a `--resume` of the finished fits ending the same.
#[test]
fn cli_init_auto_fits_every_start_and_keeps_the_rule_s_choice() {
    let exe = env!("CARGO_BIN_EXE_umbra");
    let (d, config) = tiny_schedule("auto");
    let out = d.join("out");
    let run = |extra: &[&str]| {
        let r = std::process::Command::new(exe)
            .args([
                "fit",
                "-q",
                "--target-spp",
                "16",
                "--init",
                "auto",
                "--config",
            ])
            .arg(&config)
            .arg("-o")
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
        String::from_utf8_lossy(&r.stderr).into_owned()
    };
    let said = run(&[]);
    assert!(said.contains("kept the"), "{said}");
    let summary: toml::Value =
        toml::from_str(&std::fs::read_to_string(out.join("summary.toml")).unwrap()).unwrap();
    let starts = summary["starts"].as_array().unwrap();
    let names: Vec<&str> = starts.iter().map(|s| s["init"].as_str().unwrap()).collect();
    assert_eq!(names, ["plane", "sphere", "lct"]);
    let losses: Vec<f64> = starts
        .iter()
        .map(|s| s["final_loss"].as_float().unwrap())
        .collect();
    let lowest = losses.iter().cloned().fold(f64::INFINITY, f64::min);
    let margin = umbra::fit::starts::AUTO_LOSS_MARGIN;
    let k = (0..3)
        .rev()
        .find(|&i| losses[i] * (1.0 - margin) <= lowest)
        .unwrap();
    let kept = names[k];
    assert_eq!(
        summary["init"].as_str(),
        Some(format!("auto: {kept}").as_str())
    );
    assert_eq!(summary["final_loss"].as_float(), Some(losses[k]));
    let mesh = std::fs::read(out.join("mesh.obj")).unwrap();
    assert_eq!(
        mesh,
        std::fs::read(out.join(format!("start-{kept}")).join("mesh.obj")).unwrap()
    );
    for start in ["plane", "lct"] {
        assert!(out
            .join(format!("start-{start}/checkpoint/stage.bin"))
            .is_file());
    }
    std::fs::remove_file(out.join("mesh.obj")).unwrap();
    run(&["--resume"]);
    assert_eq!(std::fs::read(out.join("mesh.obj")).unwrap(), mesh);
    let _ = std::fs::remove_dir_all(&d);
}

/// `remesh_pitch` (a stage's remesh in scan pitches) becomes `remesh` in metres from the
/// scan as fitted; given with `remesh` it is refused by name, and `optim::fit` refuses it
/// unresolved rather than ignore it.
#[test]
fn remesh_in_scan_pitches_resolves_from_the_scan() {
    use umbra::fit::run::{scan_pitch, with_scan_pitch};
    let scene = small_scene();
    let pitch = scan_pitch(&scene);
    let s = &scene.scan;
    let want =
        f64::from(s.axis_u.length() / s.nx as f32).min(f64::from(s.axis_v.length() / s.ny as f32));
    assert!(
        (pitch - want).abs() < 1e-9 && pitch > 0.0,
        "{pitch} against {want}"
    );
    let mut schedule = Schedule {
        stages: vec![
            stage(2, SolverKind::Adam, 0.01, 1, false),
            Stage {
                remesh_pitch: Some(1.5),
                ..stage(2, SolverKind::Lbfgs, 0.0, 1, true)
            },
        ],
        checkpoint_every: 5,
    };
    assert!(schedule.check().is_ok());
    let resolved = with_scan_pitch(&schedule, &scene);
    assert_eq!(resolved.stages[0].remesh, None);
    assert_eq!(resolved.stages[1].remesh, Some(1.5 * pitch));
    assert_eq!(resolved.stages[1].remesh_pitch, None);
    schedule.stages[1].remesh = Some(0.01);
    let e = schedule.check().unwrap_err();
    assert!(e.contains("stage 1") && e.contains("remesh_pitch"), "{e}");
    schedule.stages[1].remesh = None;
    schedule.stages[1].remesh_pitch = Some(0.0);
    assert!(schedule.check().unwrap_err().contains("remesh_pitch = 0"));
    // unresolved, optim::fit refuses it
    schedule.stages[1].remesh_pitch = Some(1.0);
    struct Unreached;
    impl optim::fit::ObjectiveFactory for Unreached {
        fn objective(
            &mut self,
            _: &Stage,
            _: usize,
            _: &optim::Mesh,
        ) -> Result<Box<dyn optim::MeshObjective>, String> {
            Err("the refused schedule built an objective".into())
        }
    }
    let start = initial_mesh(&scene, &target(&scene), 0, &Init::Plane).unwrap();
    let e = optim::fit::fit(
        &start,
        &schedule,
        &mut Unreached,
        &|m: &optim::Mesh, _: f64| Ok(m.clone()),
        &out_dir("remesh-pitch"),
        false,
        &optim::checkpoint::Identity { components: vec![] },
        quiet(None),
    )
    .unwrap_err();
    assert!(e.to_string().contains("remesh_pitch"), "{e}");
}
