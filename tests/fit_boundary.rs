//! The fitting study of issue 18 in small (docs/FITTING.md "Boundary terms"): a dark
//! occluder in front of a folded plate, fitted from the same displaced start with and
//! without the visibility boundary terms. Its own return is weak, so its shadow on the
//! plate is most of what the data say about where it is, and the derivative of a moving
//! shadow is exactly the boundary term. The study's scenes and schedule, at 8 x 8 scan
//! points and 128 bins of 16 mm, against a `tri3` target (about 4 s per fit). Measured:
//! final loss 6.9e-3 with, 1.8e-2 without; the occluder's centre 1.6 cm from the truth
//! with, 2.8 cm without.

use std::path::{Path, PathBuf};

const TRUE_CENTRE: [f64; 3] = [0.03, 0.04, 0.65];

/// A study scene at 8 x 8, 128 bins of 16 mm, its meshes named by absolute path.
fn small(name: &str, dir: &Path) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("scenes/studies").join(name)).unwrap();
    let meshes = root.join("scenes/meshes");
    let text = text
        .replace("resolution = [16, 16]", "resolution = [8, 8]")
        .replace("temporal_bins = 512", "temporal_bins = 128")
        .replace("bin_width_opl = 0.004", "bin_width_opl = 0.016")
        .replace("../meshes/", &format!("{}/", meshes.display()));
    assert!(text.contains("resolution = [8, 8]") && text.contains("temporal_bins = 128"));
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn umbra(args: &[&str]) -> String {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "umbra {args:?}: {err}");
    err
}

/// The fit's final cost (loss.csv's last row) and the occluder's centre (the last 25
/// vertices of mesh_all.obj: the start mesh is the receiver's 143 vertices, then the
/// occluder's 25, and this schedule does not remesh).
fn result(out: &Path) -> (f64, [f64; 3]) {
    let csv = std::fs::read_to_string(out.join("loss.csv")).unwrap();
    let last = csv.lines().last().unwrap();
    let cost: f64 = last.split(',').nth(2).unwrap().parse().unwrap();
    let obj = std::fs::read_to_string(out.join("mesh_all.obj")).unwrap();
    let v: Vec<[f64; 3]> = obj
        .lines()
        .filter(|l| l.starts_with("v "))
        .map(|l| {
            let c: Vec<f64> = l[2..]
                .split_whitespace()
                .map(|x| x.parse().unwrap())
                .collect();
            [c[0], c[1], c[2]]
        })
        .collect();
    assert_eq!(v.len(), 168, "the fit kept the start mesh's vertices");
    let occ = &v[143..];
    let centre = [0, 1, 2].map(|k| occ.iter().map(|p| p[k]).sum::<f64>() / occ.len() as f64);
    (cost, centre)
}

#[test]
fn boundary_terms_place_a_dark_occluder_by_its_shadow() {
    let dir = std::env::temp_dir().join(format!("umbra-fit-boundary-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let truth = small("occluded_dark.toml", &dir);
    let start = small("occluded_start.toml", &dir);
    let target = dir.join("target.npy");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    umbra(&[
        "render",
        &s(&truth),
        "-o",
        &s(&target),
        "--model",
        "tri3",
        "-q",
        "--no-preview",
    ]);
    let schedule =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/studies/occluded_schedule.toml");
    let mut results = Vec::new();
    for on in ["true", "false"] {
        let out = dir.join(format!("fit-{on}"));
        umbra(&[
            "fit",
            &s(&start),
            "--measured",
            &s(&target),
            "--background",
            "none",
            "--init",
            "scene",
            "--config",
            &s(&schedule),
            "--boundary-terms",
            on,
            "-o",
            &s(&out),
            "-q",
        ]);
        let (cost, c) = result(&out);
        let err = (0..3)
            .map(|k| (c[k] - TRUE_CENTRE[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        println!(
            "boundary terms {on}: final cost {cost:.4e}, occluder centre {c:.4?}, {:.1} mm off",
            err * 1e3
        );
        results.push((cost, err));
    }
    let ((cost_on, err_on), (cost_off, err_off)) = (results[0], results[1]);
    assert!(
        cost_on < 0.6 * cost_off,
        "loss {cost_on:e} with, {cost_off:e} without"
    );
    assert!(
        err_on < 0.8 * err_off,
        "occluder {err_on} m off with, {err_off} m without"
    );
}
