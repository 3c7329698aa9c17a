//! Output files: `.npy` in mitransient's layout, OpenEXR with the same numbers, PNG
//! previews; the CLI renders the built-in scene and is reproducible across threads.

use std::path::PathBuf;
use std::process::Command;
use umbra::io;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("umbra-out-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

fn umbra(args: &[&str]) -> std::process::Output {
    let out = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "umbra {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

#[test]
fn default_scene_npy_exr_and_previews() {
    let npy = tmp("default.npy");
    let out = umbra(&["render", "-o", npy.to_str().unwrap(), "--spp", "16", "-q"]);
    let summary = String::from_utf8_lossy(&out.stdout);
    assert!(
        summary.contains("samples/s") && summary.contains("confocal"),
        "{summary}"
    );
    let t = io::read_npy(&npy).unwrap();
    assert_eq!(t.shape, vec![32, 32, 512]);
    assert!(t.data.iter().all(|v| v.is_finite() && *v >= 0.0));
    assert!(t.data.iter().sum::<f32>() > 0.0);
    for suffix in ["streak", "image", "first_arrival"] {
        let p = tmp(&format!("default_{suffix}.png"));
        let bytes = std::fs::read(&p).unwrap_or_else(|_| panic!("missing {}", p.display()));
        assert_eq!(&bytes[1..4], b"PNG");
    }

    // The EXR holds the same numbers: width T, one row per scan point.
    let exr_path = tmp("default.exr");
    umbra(&[
        "render",
        "-o",
        exr_path.to_str().unwrap(),
        "--spp",
        "16",
        "-q",
        "--no-preview",
    ]);
    let img = exr::prelude::read_first_flat_layer_from_file(&exr_path).unwrap();
    assert_eq!(img.layer_data.size.width(), 512);
    assert_eq!(img.layer_data.size.height(), 32 * 32);
    let ch = &img.layer_data.channel_data.list[0];
    let vals: Vec<f32> = ch.sample_data.values_as_f32().collect();
    assert_eq!(vals, t.data);
}

#[test]
fn cli_output_is_independent_of_threads() {
    let a = tmp("t1.npy");
    let b = tmp("t2.npy");
    umbra(&[
        "render",
        "-o",
        a.to_str().unwrap(),
        "--spp",
        "40",
        "--threads",
        "1",
        "-q",
        "--no-preview",
    ]);
    umbra(&[
        "render",
        "-o",
        b.to_str().unwrap(),
        "--spp",
        "40",
        "--threads",
        "2",
        "-q",
        "--no-preview",
    ]);
    assert_eq!(
        io::read_npy(&a).unwrap().data,
        io::read_npy(&b).unwrap().data
    );
}

#[test]
fn cli_auto_says_what_it_chose_and_tri3_runs() {
    let out = umbra(&[
        "render",
        "-o",
        tmp("auto.npy").to_str().unwrap(),
        "--model",
        "auto",
        "-q",
        "--no-preview",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("auto: chose tri3"), "{err}");
    assert!(String::from_utf8_lossy(&out.stdout).contains("(tri3,"));
    let bad = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args([
            "render",
            "--model",
            "tri3",
            "--visibility",
            "sometimes",
            "-o",
            "/tmp/x.npy",
        ])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--visibility"));
}
