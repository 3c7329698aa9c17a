//! Reading the Stanford LCT captures in ../shared/data/lct (the machine's shared data;
//! UMBRA_LCT_DIR overrides the directory).

mod common;

use std::path::PathBuf;
use umbra::io::lct::{read_lct, LCT_BIN_OPL};

fn data_dir() -> PathBuf {
    common::shared_dir("UMBRA_LCT_DIR", "lct")
}

#[test]
fn diffuse_s_reads_with_its_geometry() {
    let path = data_dir().join("data_diffuse_s.mat");
    assert!(
        path.is_file(),
        "LCT data not found at {} (set UMBRA_LCT_DIR)",
        path.display()
    );
    let c = read_lct(&path).unwrap();
    assert_eq!(c.transient.shape, vec![64, 64, 2048]);
    assert!(c.width > 0.1 && c.width < 2.0, "{}", c.width);
    assert!((c.bin_width_opl - 1.1992e-3).abs() < 1e-6);
    assert_eq!(c.bin_width_opl, LCT_BIN_OPL);
    let t = &c.transient.data;
    assert!(t.iter().all(|v| v.is_finite() && *v >= 0.0));
    // Photon counts are integers, and past the residual direct light (the original code
    // zeroes the first 600 bins) the hidden letter returns light.
    assert!(t.iter().all(|v| v.fract() == 0.0));
    let late: f64 = t
        .chunks(2048)
        .map(|h| h[600..].iter().map(|&v| v as f64).sum::<f64>())
        .sum();
    assert!(late > 0.0);
}

#[test]
fn a_file_that_is_not_a_capture_is_a_clear_error() {
    let dir = std::env::temp_dir().join(format!("umbra-lct-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.mat");
    std::fs::write(&bad, b"not a mat file at all").unwrap();
    let e = read_lct(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.mat") && e.contains("MATLAB"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

/// The SPAD's response, read off the capture's own direct return: a long diffusion tail
/// that a Gaussian jitter cannot model (docs/FITTING.md, "Real data"). Pins the figures
/// quoted there: at 9.6 mm bins most of the response lies beyond 24 mm of OPL, and it
/// decays monotonically over its first 100 mm.
#[test]
fn diffuse_s_direct_return_gives_a_long_tailed_impulse_response() {
    let c = read_lct(&data_dir().join("data_diffuse_s.mat")).unwrap();
    let irf =
        umbra::film::irf::Irf::from_direct_return(&c.transient.data, 2048, 600, LCT_BIN_OPL as f64)
            .unwrap();
    let coarse = irf.taps_at(8.0 * LCT_BIN_OPL as f64);
    let beyond_24mm: f64 = irf.taps_at(0.024).iter().skip(1).sum();
    println!(
        "IRF: first coarse taps {:?}, {:.0} % beyond 24 mm",
        &coarse[..6],
        100.0 * beyond_24mm
    );
    assert!(beyond_24mm > 0.5 && beyond_24mm < 0.8, "{beyond_24mm}");
    assert!(
        coarse[..10].windows(2).all(|w| w[1] < w[0]),
        "{:?}",
        &coarse[..10]
    );
}

/// `umbra fit scenes/lct.toml --measured data_diffuse_s.mat` from a plane: its first
/// iteration's render returns light (a fitted scale > 0) and two iterations lower the
/// loss. Guards the scene file: with the device's lines to the wall occlusion-tested
/// (`visible_legs`, on by default), its stand-in laser 1 m in front of the wall is
/// shadowed by the initial plane, the render is zero and the fit has nothing to follow.
#[test]
fn lct_scene_fit_starts_with_light() {
    let out = common::tmp_dir("lct-fit-start");
    let scene = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenes/lct.toml");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(["fit", scene.to_str().unwrap(), "--measured"])
        .arg(data_dir().join("data_diffuse_s.mat"))
        // 2, 1, 1, 1 iterations over the default schedule's four stages: what --iters 3
        // ran before --iters meant exactly N.
        .args(["--init", "plane", "--iters", "5", "-q", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    let csv = std::fs::read_to_string(out.join("loss.csv")).unwrap();
    let rows: Vec<Vec<f64>> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    // Columns: iteration, stage, cost, data_loss, smoothness, scale, background.
    assert!(
        rows[0][5] > 0.0,
        "first render has no light: scale {}",
        rows[0][5]
    );
    assert!(rows.last().unwrap()[3] < rows[0][3], "{csv}");
    // The capture model's coefficients are reported by name, the scale positive.
    let summary: toml::Table = std::fs::read_to_string(out.join("summary.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let nuisance = summary["nuisance"]
        .as_table()
        .expect("summary.toml [nuisance]");
    assert!(nuisance["gain_1"].as_float().unwrap() > 0.0, "{nuisance:?}");
    for key in ["gain_x", "floor_mean", "floor_min", "tail_1", "tail_2"] {
        assert!(
            nuisance[key].as_float().unwrap().is_finite(),
            "{key}: {nuisance:?}"
        );
    }
    // A floor per scan point (fit::point_floor): dark counts, never negative.
    assert!(
        nuisance["floor_min"].as_float().unwrap() >= 0.0,
        "{nuisance:?}"
    );
    // The direct return's tail runs under the fitted bins (notes/capture-calibration.md
    // §3): the model holds it. Until 2026-12-08 the capture model summed each point's
    // direct counts on the measurement with its leading bins already zeroed, every tail
    // column was zero and both gains stayed 0.
    let tails = nuisance["tail_1"].as_float().unwrap() + nuisance["tail_2"].as_float().unwrap();
    assert!(tails > 0.0, "no direct tail fitted: {nuisance:?}");
    // floor.npy holds the floors the summary describes, on the 8,2-binned 32 x 32 scan.
    let floor: ndarray::Array2<f32> = ndarray_npy::read_npy(out.join("floor.npy")).unwrap();
    assert_eq!(floor.dim(), (32, 32));
    let mean = floor.iter().map(|&v| f64::from(v)).sum::<f64>() / floor.len() as f64;
    let want = nuisance["floor_mean"].as_float().unwrap();
    assert!((mean / want - 1.0).abs() < 1e-5, "{mean} against {want}");
    let _ = std::fs::remove_dir_all(&out);
}
