//! Issue 17's renders of absurd or meaningless scenes: each is refused up front with a
//! message naming the size or the field, or rendered with a warning naming the share of
//! the signal lost; never an abort, a hang or a silent zero.

mod common;
use common::*;
use std::process::Command;
use umbra::geometry::SceneGeometry;
use umbra::scene::Model;
use umbra::transport::{RenderOptions, Renderer};

fn umbra(dir: &std::path::Path, args: &[&str], env: &[(&str, &str)]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .envs(env.iter().copied())
        .current_dir(dir)
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A 100000 x 100000 scan, 1e9 time bins and a 64 x 64 exhaustive capture are refused
/// before allocating, with the bytes and the field (they aborted with "memory
/// allocation failed"). `UMBRA_MAX_MEMORY` makes the limit the same on every machine.
#[test]
fn absurd_sizes_are_refused_before_allocating() {
    let dir = tmp_dir("absurd-sizes");
    let cases = [
        (
            SceneSpec { scan: [100_000, 100_000], bins: 10, ..SceneSpec::default() },
            "400000000000 bytes (372.5 GiB) for the output (100000 x 100000 scan points (scan.resolution) x 10 time bins",
        ),
        (
            SceneSpec { scan: [2, 2], bins: 1_000_000_000, ..SceneSpec::default() },
            "16000000000 bytes (14.9 GiB) for the output (2 x 2 scan points (scan.resolution) x 1000000000 time bins (film.temporal_bins)",
        ),
        (
            SceneSpec {
                capture: "exhaustive",
                scan: [64, 64],
                bins: 512,
                ..SceneSpec::default()
            },
            "34359738368 bytes (32.0 GiB) for the output (64 x 64 scan points squared (exhaustive capture) x 512 time bins",
        ),
        (
            // 65536^4 measurements overflow 64 bits (the count used to wrap to 0).
            SceneSpec {
                capture: "exhaustive",
                scan: [65536, 65536],
                bins: 16,
                ..SceneSpec::default()
            },
            "would need more than 18446744073709551615 bytes (16 EiB) of memory",
        ),
    ];
    for (spec, says) in cases {
        let scene = spec.write(&dir);
        let (code, err) = umbra(
            &dir,
            &["render", scene.to_str().unwrap(), "-o", "x.npy", "-q"],
            &[("UMBRA_MAX_MEMORY", "8G")],
        );
        assert_eq!(code, Some(1), "{err}");
        assert!(
            err.contains(says)
                && err.contains("more than the 8589934592 bytes (8.0 GiB) UMBRA_MAX_MEMORY allows"),
            "{err}"
        );
        // The library refuses the same way, for the gradient too.
        let scene = spec.scene();
        let geom = SceneGeometry::build(&scene);
        for model in [Model::Tri3, Model::Mc3] {
            let opts = RenderOptions {
                model,
                ..RenderOptions::from_scene(&scene)
            };
            std::env::set_var("UMBRA_MAX_MEMORY", "8G");
            let e = Renderer::new(&scene, &geom, &opts).err().expect("refused");
            assert!(e.to_string().contains(says), "{e}");
            let e = umbra::adjoint::gradient(&scene, &geom, &opts, &[], None).unwrap_err();
            assert!(e.to_string().starts_with("the gradient would need"), "{e}");
        }
    }
    std::env::remove_var("UMBRA_MAX_MEMORY");
    std::fs::remove_dir_all(&dir).ok();
}

/// Vertices beyond `MAX_COORD` or not finite are refused by the loader and, when a
/// program sets them, by the gate (`set_vertices(V * 1e30)` then `render` panicked in
/// the BVH builder).
#[test]
fn absurd_vertices_are_refused() {
    let spec = SceneSpec {
        objects: vec![(
            "v 2e6 0 1\nv 0 2e6 1\nv -2e6 -2e6 1\nf 1 2 3\n".into(),
            0.5,
            "lambertian",
        )],
        ..SceneSpec::default()
    };
    let e = spec.try_scene().unwrap_err().to_string();
    assert!(
        e.contains("vertex 0 is at [2000000, 0, 1], more than 1000000 m"),
        "{e}"
    );
    let mut scene = SceneSpec::default().scene();
    let good = scene.clone();
    scene.objects[0].mesh.positions[1].x = f32::NAN;
    let opts = RenderOptions::from_scene(&scene);
    let e = Renderer::new(&scene, &SceneGeometry::build(&good), &opts)
        .err()
        .expect("refused")
        .to_string();
    assert!(
        e.contains("objects[0] (obj0): vertex 1 is not finite"),
        "{e}"
    );
}

/// `--threads 10000` is refused at once (it ran for minutes).
#[test]
fn thread_counts_are_capped() {
    let dir = tmp_dir("threads");
    let (code, err) = umbra(
        &dir,
        &["render", "--threads", "10000", "-o", "x.npy", "-q"],
        &[],
    );
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("--threads: 10000 threads is more than"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Scenes that would render all zeros are refused naming the field; scenes that lose
/// part of their signal load with a warning naming the share.
#[test]
fn scenes_that_render_nothing_are_refused_and_partial_losses_warned() {
    let refused = |spec: SceneSpec, says: &str| {
        let e = match spec.try_scene() {
            Ok(_) => panic!("accepted: {says}"),
            Err(e) => e.to_string(),
        };
        assert!(e.contains(says), "{says}: {e}");
    };
    for f in [0, 2] {
        refused(
            SceneSpec {
                render_extra: vec![format!("filter_bounces = {f}")],
                ..SceneSpec::default()
            },
            &format!("render.filter_bounces: {f} selects no NLOS light"),
        );
    }
    refused(
        SceneSpec {
            scan_size: 10.0,
            scan: [2, 2],
            ..SceneSpec::default()
        },
        "scan: every scan point lies outside the relay wall",
    );
    refused(
        SceneSpec {
            objects: vec![(square_obj([0.0, 0.0, -0.5], 0.3), 0.8, "lambertian")],
            ..SceneSpec::default()
        },
        "objects[0] (obj0) lies entirely behind or in the relay wall's plane",
    );
    refused(
        SceneSpec {
            objects: vec![(square_obj([0.0, 0.0, 0.0], 0.3), 0.8, "lambertian")],
            ..SceneSpec::default()
        },
        "lies entirely behind or in the relay wall's plane",
    );

    let dir = tmp_dir("partial-loss");
    let straddling = "v -0.2 0 -0.2\nv 0.2 0 -0.2\nv 0.2 0 0.6\nv -0.2 0 0.6\nf 1 2 3 4\n";
    let spec = SceneSpec {
        scan: [10, 10],
        scan_size: 10.0,
        objects: vec![(straddling.into(), 0.8, "lambertian")],
        ..SceneSpec::default()
    };
    let scene = umbra::Scene::load(&spec.write(&dir)).unwrap();
    let w = scene.warnings.join("\n");
    // 2 of 10 columns and rows are on the 2 m wall: 4 % of the points.
    assert!(
        w.contains("scan: 96.0 % of the scan points lie outside the relay wall"),
        "{w}"
    );
    assert!(
        w.contains("objects[0] (obj0): 25.0 % of its area lies behind"),
        "{w}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `tri3` on a film longer than `WINDOW_MIN_BINS` keeps a histogram over the bins the
/// geometry reaches only; the result equals the whole-film histogram's.
#[test]
fn tri3_long_films_render_the_same_in_a_window() {
    let long = umbra::transport::tri3::WINDOW_MIN_BINS as u32 + 5000;
    let short = umbra::transport::tri3::WINDOW_MIN_BINS as u32;
    let spec = |bins| SceneSpec {
        bins,
        bin_width: 0.0001,
        sigma_opl: None,
        scan: [2, 1],
        model: "tri3",
        ..SceneSpec::default()
    };
    let a = render(&spec(long).scene(), Model::Tri3, 1, 0);
    let b = render(&spec(short).scene(), Model::Tri3, 1, 0);
    let total: f64 = b.data.iter().map(|&v| f64::from(v)).sum();
    assert!(total > 0.0);
    for m in 0..2 {
        let (ra, rb) = (
            &a.data[m * long as usize..(m + 1) * long as usize],
            &b.data[m * short as usize..(m + 1) * short as usize],
        );
        assert!(ra[short as usize..].iter().all(|&v| v == 0.0));
        let diff: f64 = ra
            .iter()
            .zip(rb)
            .map(|(x, y)| f64::from((x - y).abs()))
            .sum();
        let sum: f64 = rb.iter().map(|&v| f64::from(v)).sum();
        assert!(
            diff <= 1e-5 * sum,
            "measurement {m}: |a - b| = {diff}, sum {sum}"
        );
    }
}

/// The window holds far geometry with fine bins too, where the kernel's `f32` pulse
/// times round by tens of bins (a 2-bin margin lost 53 % of a plate 1 km away with 1 µm
/// bins): the windowed total equals the whole film's. (Bin by bin the two differ by that
/// rounding, since their time origins differ.)
#[test]
fn tri3_window_keeps_far_geometry_with_fine_bins() {
    let far = |bins, width: f32, start| SceneSpec {
        bins,
        bin_width: width,
        start_opl: start,
        sigma_opl: None,
        scan: [1, 1],
        objects: vec![(square_obj([0.05, 0.02, 1000.0], 0.3), 0.8, "lambertian")],
        model: "tri3",
        ..SceneSpec::default()
    };
    // Where the plate's light arrives, from a coarse film.
    let coarse = render(&far(4000, 0.001, 1999.0).scene(), Model::Tri3, 1, 0);
    let first = coarse.data.iter().position(|&v| v > 0.0).expect("light") as f32;
    let start = 1999.0 + 0.001 * first - 0.002;
    let total = |bins| -> f64 {
        let t = render(&far(bins, 1e-6, start).scene(), Model::Tri3, 1, 0);
        t.data.iter().map(|&v| f64::from(v)).sum()
    };
    let short = umbra::transport::tri3::WINDOW_MIN_BINS as u32;
    let (whole, windowed) = (total(short), total(short + 1));
    assert!(whole > 0.0);
    assert!(
        (windowed - whole).abs() <= 1e-4 * whole,
        "windowed {windowed} vs whole film {whole}"
    );
}

/// Ctrl-C ends `grad` and `gradcheck` with a message and exit code 130 (they died
/// silently); `grad`'s earlier output is left whole.
#[test]
fn grad_and_gradcheck_say_when_interrupted() {
    let dir = tmp_dir("ctrl-c");
    let scene = SceneSpec::default().write(&dir);
    let s = scene.to_str().unwrap();
    let (code, err) = umbra(
        &dir,
        &["render", s, "-o", "target.npy", "-q", "--no-preview"],
        &[],
    );
    assert_eq!(code, Some(0), "{err}");
    std::fs::write(dir.join("g.npz"), b"earlier").unwrap();
    for args in [
        vec![
            "grad",
            s,
            "--target",
            "target.npy",
            "-o",
            "g.npz",
            "--spp",
            "20000000",
        ],
        vec!["gradcheck", s, "--spp", "20000000"],
    ] {
        let child = Command::new(env!("CARGO_BIN_EXE_umbra"))
            .args(&args)
            .current_dir(&dir)
            .stderr(std::process::Stdio::piped())
            .stdout(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(1500));
        let kill = Command::new("kill")
            .args(["-INT", &child.id().to_string()])
            .status()
            .unwrap();
        assert!(kill.success());
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(130), "{}: {err}", args[0]);
        assert!(
            err.contains(&format!("umbra {}: interrupted", args[0])),
            "{err}"
        );
    }
    assert_eq!(std::fs::read(dir.join("g.npz")).unwrap(), b"earlier");
    std::fs::remove_dir_all(&dir).ok();
}

/// `grad` checks where its `.npz` goes before computing anything (a path under a file
/// failed only after the work).
#[test]
fn grad_checks_its_output_first() {
    let dir = tmp_dir("grad-output");
    std::fs::write(dir.join("plain_file"), "x").unwrap();
    let (code, err) = umbra(
        &dir,
        &[
            "grad",
            "no_such_scene.toml",
            "--target",
            "t.npy",
            "-o",
            "plain_file/g.npz",
        ],
        &[],
    );
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("plain_file") && !err.contains("no_such_scene"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
