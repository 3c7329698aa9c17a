//! Hostile input to `umbra fit` (issue 17): nothing crashes, nothing is silently wrong.
//! Checkpoints are resumed only by the fit they belong to and only when intact; the
//! schedule's nonsense is refused naming the file, the stage and the field (CLI and
//! Python spellings); an absurd step size stops the fit with a clear error and its
//! checkpoint intact; Monte Carlo fitting warns; an unsupported reflectance says why.
//! Each test failed on the code before these checks.

mod common;
use common::*;
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::rc::Rc;
use std::time::Duration;
use umbra::fit::request::{run, Front};
use umbra::fit::{FitRequest, Measurement};

/// A small confocal scene (4 x 4 scan points, 200 bins) with a square 0.6 m out.
fn spec() -> SceneSpec {
    SceneSpec::default()
}

/// A scene that differs from [`spec`] only by where its square is.
fn other_spec() -> SceneSpec {
    SceneSpec {
        objects: vec![(square_obj([0.0, 0.0, 0.7], 0.3), 0.8, "lambertian")],
        ..SceneSpec::default()
    }
}

const SCHEDULE: &str = "checkpoint_every = 2\n[[stage]]\niters = 3\nlr = 0.01\nlarge_steps = 2.0\n";

/// `umbra fit` with `args`, killed after `limit` (then the output says so).
fn umbra_fit(scene: &Path, out: &Path, args: &[&str], limit: Duration) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_umbra"));
    cmd.arg("fit")
        .arg(scene)
        .args(["-q", "--target-spp", "16", "-o"])
        .arg(out)
        .args(args);
    output_within(&mut cmd, limit)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A finished fit of [`spec`] in `d/out` (scene in `d/scene.toml`, schedule in
/// `d/schedule.toml`).
fn fitted(name: &str) -> (PathBuf, PathBuf, PathBuf, PathBuf) {
    let d = tmp_dir(name);
    let scene = spec().write(&d);
    let config = d.join("schedule.toml");
    std::fs::write(&config, SCHEDULE).unwrap();
    let out = d.join("out");
    let o = umbra_fit(
        &scene,
        &out,
        &["--config", config.to_str().unwrap()],
        Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    (d, scene, config, out)
}

fn refused(o: &Output, wants: &[&str]) {
    let e = stderr(o);
    assert!(!o.status.success(), "accepted; stderr:\n{e}");
    assert!(!e.contains("panicked"), "panicked:\n{e}");
    for w in wants {
        assert!(e.contains(w), "want {w:?} in:\n{e}");
    }
}

#[test]
fn resume_refuses_a_checkpoint_of_another_fit_naming_what_differs() {
    let (d, scene, config, out) = fitted("fit-other");
    let cfg = config.to_str().unwrap();
    let long = Duration::from_secs(120);
    // The same fit resumes.
    let o = umbra_fit(&scene, &out, &["--config", cfg, "--resume"], long);
    assert!(o.status.success(), "{}", stderr(&o));
    // Another scene: its target differs too.
    let other = d.join("other");
    let other_scene = other_spec().write(&other);
    let o = umbra_fit(&other_scene, &out, &["--config", cfg, "--resume"], long);
    refused(
        &o,
        &[
            "checkpoint/stage.bin was written for another scene (",
            "hash ",
        ],
    );
    for (args, says) in [
        (
            &["--model", "mc3"][..],
            "for another model (tri3, 16 spp vs mc3, 16 spp now",
        ),
        (&["--spp", "8"][..], "for another model"),
        (
            &["--iters", "5"][..],
            "for another schedule (1 stages, 3 iterations vs 1 stages, 5 iterations now",
        ),
        (&["--ignore-before", "0.9"][..], "for another options"),
        (&["--init", "sphere"][..], "for another initial mesh"),
    ] {
        let mut a = vec!["--config", cfg, "--resume"];
        a.extend_from_slice(args);
        let o = umbra_fit(&scene, &out, &a, long);
        refused(&o, &[says, "delete"]);
    }
    // Another schedule file.
    std::fs::write(&config, SCHEDULE.replace("lr = 0.01", "lr = 0.02")).unwrap();
    let o = umbra_fit(&scene, &out, &["--config", cfg, "--resume"], long);
    refused(&o, &["for another schedule"]);
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn damaged_checkpoints_are_refused_naming_the_file() {
    let (d, scene, config, out) = fitted("fit-damaged");
    let cfg = config.to_str().unwrap();
    let stage = out.join("checkpoint/stage.bin");
    let good = std::fs::read(&stage).unwrap();
    let long = Duration::from_secs(120);
    let mut flipped = good.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x40;
    let mut version = good.clone();
    if version.len() > 12 {
        version[8] = version[8].wrapping_add(1);
    }
    for (bytes, says) in [
        (good[..72.min(good.len() - 1)].to_vec(), "truncated"),
        (flipped, "corrupt"),
        (
            b"not a checkpoint at all, just text".to_vec(),
            "not an Umbra fit checkpoint",
        ),
        (version, "format version"),
        (Vec::new(), "not an Umbra fit checkpoint"),
    ] {
        std::fs::write(&stage, &bytes).unwrap();
        let o = umbra_fit(&scene, &out, &["--config", cfg, "--resume"], long);
        refused(&o, &["checkpoint/stage.bin", says]);
    }
    // Restored, it resumes.
    std::fs::write(&stage, &good).unwrap();
    let o = umbra_fit(&scene, &out, &["--config", cfg, "--resume"], long);
    assert!(o.status.success(), "{}", stderr(&o));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn stale_temporaries_go_and_the_saved_target_is_read_back() {
    let (d, scene, config, out) = fitted("fit-stale");
    let cfg = config.to_str().unwrap();
    let ck = out.join("checkpoint");
    let stale = [".solver-0.bin.tmp999999", ".stage.bin.tmp424242"];
    for s in stale {
        std::fs::write(ck.join(s), b"half a file").unwrap();
    }
    let target = out.join("target.npy");
    std::fs::write(out.join(".target.npy.tmp31337"), b"half a target").unwrap();
    let before = std::fs::metadata(&target).unwrap().modified().unwrap();
    std::thread::sleep(Duration::from_millis(20));
    let o = umbra_fit(
        &scene,
        &out,
        &["--config", cfg, "--resume"],
        Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    for s in stale {
        assert!(!ck.join(s).exists(), "{s} is still there");
    }
    assert!(!out.join(".target.npy.tmp31337").exists());
    assert!(
        stderr(&o).contains("target read back from"),
        "{}",
        stderr(&o)
    );
    let after = std::fs::metadata(&target).unwrap().modified().unwrap();
    assert_eq!(before, after, "target.npy was rendered again");
    // Without target.npy the resume renders it again, saying so.
    std::fs::remove_file(&target).unwrap();
    let o = umbra_fit(
        &scene,
        &out,
        &["--config", cfg, "--resume"],
        Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("target.npy is missing: rendering the target again"));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn nonsense_schedules_are_refused_naming_file_stage_and_field() {
    let d = tmp_dir("fit-schedule");
    let scene = spec().write(&d);
    let config = d.join("schedule.toml");
    let two = |second: &str| {
        format!("[[stage]]\niters = 2\nlr = 0.01\n[[stage]]\niters = 2\nlr = 0.01\n{second}\n")
    };
    let cases = [
        (
            two("lr = -0.01").replacen(
                "lr = 0.01\n[[stage]]\niters = 2\nlr = 0.01\n",
                "lr = 0.01\n[[stage]]\niters = 2\n",
                1,
            ),
            "schedule.toml: stage 1: lr = -0.01 must be positive",
        ),
        (
            two("large_steps = -5.0"),
            "schedule.toml: stage 1: large_steps = -5 must be finite and >= 0",
        ),
        (
            two("time_downsample = 0"),
            "schedule.toml: stage 1: time_downsample = 0 must be at least 1",
        ),
        (
            two("scan_downsample = 0"),
            "schedule.toml: stage 1: scan_downsample = 0 must be at least 1",
        ),
        (
            two("laplacian = -1.0"),
            "schedule.toml: stage 1: laplacian = -1 must be finite and >= 0",
        ),
        (
            two("albedo_step = nan"),
            "schedule.toml: stage 1: albedo_step = NaN must be positive",
        ),
        (
            two("remesh = 0.0"),
            "schedule.toml: stage 1: remesh = 0 must be positive",
        ),
        (
            two("remesh_factor = -0.4"),
            "schedule.toml: stage 1: remesh_factor = -0.4 must be positive",
        ),
        (
            two("spp = 0"),
            "schedule.toml: stage 1: spp = 0 must be at least 1",
        ),
        (
            two("model = \"tri4\""),
            "schedule.toml: stage 1: model = 'tri4' is not one of",
        ),
        (
            two("solver = \"lbfgs\"\nlr = inf").replacen("lr = 0.01\nsolver", "solver", 1),
            "schedule.toml: stage 1: lr = inf must be positive",
        ),
        (
            "checkpoint_every = 0\n[[stage]]\niters = 2\n".into(),
            "schedule.toml: checkpoint_every = 0 must be at least 1",
        ),
    ];
    for (text, want) in cases {
        std::fs::write(&config, &text).unwrap();
        let out = d.join("out");
        let _ = std::fs::remove_dir_all(&out);
        // large_steps = -5 hung the fit (no iteration in 300 s) before it was refused.
        let o = umbra_fit(
            &scene,
            &out,
            &["--config", config.to_str().unwrap()],
            Duration::from_secs(60),
        );
        refused(&o, &[want]);
    }
    for (args, want) in [
        (
            &["--ignore-before", "nan"][..],
            "--ignore-before: NaN is not an optical path length",
        ),
        (
            &["--ignore-before", "inf"][..],
            "--ignore-before: inf is not an optical path length",
        ),
    ] {
        let out = d.join("out");
        let _ = std::fs::remove_dir_all(&out);
        std::fs::write(&config, SCHEDULE).unwrap();
        let mut a = vec!["--config", config.to_str().unwrap()];
        a.extend_from_slice(args);
        let o = umbra_fit(&scene, &out, &a, Duration::from_secs(60));
        refused(&o, &[want]);
    }
    let _ = std::fs::remove_dir_all(&d);
}

/// The library's entry point as Python's `umbra.fit` calls it: the same checks, the
/// options spelled as Python keywords.
#[test]
fn python_front_gets_the_same_refusals_in_its_spelling() {
    let d = tmp_dir("fit-python");
    let quiet: optim::fit::Progress =
        Rc::new(RefCell::new(|_: &optim::checkpoint::LossRecord| true));
    let request = |f: &dyn Fn(&mut FitRequest)| {
        let mut r = FitRequest::new(Measurement::Demo { target_spp: 16 }, d.join("out"));
        r.front = Front::Python;
        f(&mut r);
        let _ = std::fs::remove_dir_all(d.join("out"));
        match run(spec().scene(), &r, quiet.clone(), &mut |_| {}) {
            Ok(_) => panic!("accepted"),
            Err(e) => e.to_string(),
        }
    };
    let schedule = |text: &str| umbra::fit::request::parse_schedule(text, Path::new("<schedule>"));
    let e = schedule("[[stage]]\niters = 2\nlr = -1.0\n")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("<schedule>: stage 0: lr = -1 must be positive"),
        "{e}"
    );
    // A schedule built in code is checked too.
    let mut bad = umbra::fit::default_schedule();
    bad.stages[2].large_steps = -5.0;
    let e = request(&|r| r.schedule = Some(bad.clone()));
    assert!(
        e.contains("schedule: stage 2: large_steps = -5 must be finite and >= 0"),
        "{e}"
    );
    let e = request(&|r| r.ignore_before = Some(f32::NAN));
    assert!(
        e.starts_with("ignore_before: NaN is not an optical path length"),
        "{e}"
    );
    let e = request(&|r| {
        r.reflectance = Some("retroreflective".into());
        r.model = "path".into();
    });
    assert!(
        e.contains("objects[0] (fit): retroreflective reflectance is modelled by tri3 only (the model is path) (the fitted surface is reflectance retroreflective): use model tri3"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn an_absurd_step_size_stops_the_fit_with_its_checkpoint_intact() {
    let d = tmp_dir("fit-absurd");
    let scene = spec().write(&d);
    let config = d.join("schedule.toml");
    for (solver, stage) in [
        ("adam", "stage 0, iteration 1"),
        ("lbfgs", "stage 0, iteration 1"),
    ] {
        std::fs::write(
            &config,
            format!("[[stage]]\niters = 3\nsolver = \"{solver}\"\nlr = 1e300\n"),
        )
        .unwrap();
        let out = d.join(format!("out-{solver}"));
        let o = umbra_fit(
            &scene,
            &out,
            &["--config", config.to_str().unwrap()],
            Duration::from_secs(120),
        );
        refused(&o, &[stage, "step size (lr) is far too large", "outside"]);
        // The checkpoint of the start is intact: resuming fails the same way, not on it.
        let stage_bin = out.join("checkpoint/stage.bin");
        assert!(stage_bin.is_file());
        let o = umbra_fit(
            &scene,
            &out,
            &["--config", config.to_str().unwrap(), "--resume"],
            Duration::from_secs(120),
        );
        refused(&o, &[stage, "step size"]);
        assert!(!stderr(&o).contains("stage.bin"), "{}", stderr(&o));
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn monte_carlo_fits_warn_that_their_gradients_are_noisy() {
    let d = tmp_dir("fit-mc3");
    let scene = spec().write(&d);
    let config = d.join("schedule.toml");
    std::fs::write(&config, "[[stage]]\niters = 1\nlr = 0.01\n").unwrap();
    let cfg = config.to_str().unwrap();
    let o = umbra_fit(
        &scene,
        &d.join("a"),
        &["--config", cfg, "--model", "mc3"],
        Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(
        e.contains("warning: --model mc3 fits with Monte Carlo gradients (16 spp)")
            && e.contains("--model tri3"),
        "{e}"
    );
    // tri3: no warning.
    let o = umbra_fit(
        &scene,
        &d.join("b"),
        &["--config", cfg],
        Duration::from_secs(120),
    );
    assert!(
        o.status.success() && !stderr(&o).contains("warning"),
        "{}",
        stderr(&o)
    );
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn retroreflective_with_a_monte_carlo_model_says_why() {
    let d = tmp_dir("fit-retro");
    let scene = spec().write(&d);
    let config = d.join("schedule.toml");
    std::fs::write(&config, SCHEDULE).unwrap();
    let cfg = config.to_str().unwrap();
    for model in ["path", "mc3"] {
        let o = umbra_fit(
            &scene,
            &d.join("out"),
            &[
                "--config",
                cfg,
                "--reflectance",
                "retroreflective",
                "--model",
                model,
            ],
            Duration::from_secs(60),
        );
        refused(
            &o,
            &[
                &format!("objects[0] (fit): retroreflective reflectance is modelled by tri3 only (the model is {model}) (the fitted surface is --reflectance retroreflective)"),
                ": use --model tri3, or --reflectance lambertian",
            ],
        );
        assert!(!stderr(&o).contains("initial mesh"), "{}", stderr(&o));
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_retro_falloff_for_a_lambertian_surface_or_too_steep_is_refused() {
    let d = tmp_dir("fit-falloff");
    let scene = spec().write(&d);
    let config = d.join("schedule.toml");
    std::fs::write(&config, SCHEDULE).unwrap();
    let cfg = config.to_str().unwrap();
    let cases: [(&[&str], &str); 2] = [
        (
            &["--retro-falloff", "2"],
            "--retro-falloff = 2 is for a retroreflective surface, and this one is lambertian",
        ),
        (
            &["--reflectance", "retroreflective", "--retro-falloff", "20"],
            "--retro-falloff = 20: the angular falloff exponent is a number from 0 to 16",
        ),
    ];
    for (args, says) in cases {
        let mut all = vec!["--config", cfg];
        all.extend_from_slice(args);
        let o = umbra_fit(&scene, &d.join("out"), &all, Duration::from_secs(60));
        refused(&o, &[says]);
    }
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_measurement_of_nothing_is_refused_and_a_fit_of_nothing_warns() {
    // The hidden square beyond the film's last bin: the demonstration target is zero
    // (the fit used to end in "loss.png: cannot draw the chart").
    let d = tmp_dir("fit-nothing");
    let far = SceneSpec {
        objects: vec![(square_obj([0.05, 0.02, 3.0], 0.3), 0.8, "lambertian")],
        ..SceneSpec::default()
    };
    let scene = far.write(&d);
    let config = d.join("schedule.toml");
    std::fs::write(&config, SCHEDULE).unwrap();
    let o = umbra_fit(
        &scene,
        &d.join("out"),
        &["--config", config.to_str().unwrap(), "--init", "scene"],
        Duration::from_secs(60),
    );
    refused(&o, &["the measurement is zero in every bin the fit uses"]);
    // A fit whose surface returns nothing usable (here: a measurement a million times
    // brighter than the surface can be, with --known-scale) warns instead of reporting
    // the mesh as a result.
    let s = spec().scene();
    let bright: Vec<f32> = render(&s, umbra::scene::Model::Tri3, 1, 0)
        .data
        .iter()
        .map(|v| v * 1e6)
        .collect();
    let mut r = FitRequest::new(Measurement::Array(bright), d.join("bright"));
    r.known_scale = true;
    r.background = Some(umbra::fit::Background::None);
    r.init = Some("scene".into());
    r.schedule = Some(
        umbra::fit::request::parse_schedule("[[stage]]\niters = 1\nlr = 0.001\n", Path::new("s"))
            .unwrap(),
    );
    let mut notes = Vec::new();
    let quiet: optim::fit::Progress =
        Rc::new(RefCell::new(|_: &optim::checkpoint::LossRecord| true));
    run(s, &r, quiet, &mut |n| notes.push(n.to_string())).unwrap();
    assert!(
        notes
            .iter()
            .any(|n| n.starts_with("warning: the fitted surface returns no light the fit can use")),
        "{notes:?}"
    );
    let _ = std::fs::remove_dir_all(&d);
}
