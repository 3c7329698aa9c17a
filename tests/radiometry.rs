//! Radiometry against a closed form (DESIGN §2): a 2 cm Lambertian square facing the
//! wall at 1 m. For a patch this small the three-bounce integral is the point-patch
//! formula `P (ρ_w/π) (ρ/π) G(x_l, x) G(x, x_s) (ρ_w/π) A` at OPL `|x_l-x| + |x-x_s|`.

mod common;
use common::*;
use glam::Vec3;
use std::f64::consts::PI;
use umbra::scene::{LaserEmission, Model, Scene};

const PATCH_C: [f32; 3] = [0.1, 0.05, 1.0];
const SIDE: f32 = 0.02;

fn patch_scene(capture: &str, laser: &str, filter: &str) -> Scene {
    let toml = format!(
        r#"
capture_type = "{capture}"
[wall]
size = [2.0, 2.0]
albedo = 0.8
[laser]
origin = [0.4, -0.3, 1.2]
target = [0.3, -0.2, 0.0]
{laser}
[scan]
resolution = [4, 4]
size = [1.0, 1.0]
[film]
temporal_bins = 400
bin_width_opl = 0.005
start_opl = 1.5
[[objects]]
file = "patch.obj"
albedo = 0.7
[render]
{filter}
"#
    );
    scene(&toml, &[("patch.obj", &square_obj(PATCH_C, SIDE))])
}

/// The point-patch formula per measurement: (value, OPL).
fn closed_form(s: &Scene) -> Vec<(f64, f64)> {
    let x = Vec3::from(PATCH_C);
    let n = Vec3::new(0.0, 0.0, -1.0);
    let nw = s.wall.normal();
    let area = (SIDE * SIDE) as f64;
    let g = |a: Vec3, na: Vec3, b: Vec3, nb: Vec3| {
        let d = b - a;
        let r2 = d.length_squared() as f64;
        let w = d.normalize();
        (na.dot(w) as f64) * (-nb.dot(w) as f64) / r2
    };
    (0..s.num_measurements())
        .map(|m| {
            let (xl, xs) = s.measurement_points(m);
            let p = match s.laser.emission {
                LaserEmission::Power(p) => p as f64,
                LaserEmission::Irradiance { irradiance, .. } => {
                    let d = s.laser.origin - xl;
                    PI * irradiance as f64 * (nw.dot(d.normalize()) as f64)
                        / d.length_squared() as f64
                }
            };
            let rw = s.wall.albedo as f64 / PI;
            let rho = s.objects[0].albedo as f64 / PI;
            let v = p * rw * rho * g(xl, nw, x, n) * g(x, n, xs, nw) * rw * area;
            (v, ((xl - x).length() + (x - xs).length()) as f64)
        })
        .collect()
}

fn check(s: &Scene, model: Model, spp: u32) {
    let t = render(s, model, spp, 7);
    let got = totals(&t);
    let want = closed_form(s);
    let (mut sum_got, mut sum_want) = (0.0, 0.0);
    for (m, ((g, (w, opl)), c)) in got
        .iter()
        .zip(&want)
        .zip(t.data.chunks(t.bins()))
        .enumerate()
    {
        let rel = (g - w) / w;
        assert!(
            rel.abs() < 0.01,
            "{model:?} {:?} point {m}: got {g:e}, formula {w:e} ({:+.3} %)",
            s.capture,
            rel * 100.0
        );
        // The pulse sits in the bin that holds the formula's OPL.
        let peak = c
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .unwrap()
            .0;
        let want_bin =
            ((opl - s.film.start_opl as f64) / s.film.bin_width_opl as f64).floor() as usize;
        assert!(
            peak.abs_diff(want_bin) <= 1,
            "point {m}: peak bin {peak}, formula bin {want_bin}"
        );
        sum_got += g;
        sum_want += w;
    }
    assert!(((sum_got - sum_want) / sum_want).abs() < 0.01);
}

#[test]
fn patch_single_mc3_and_path() {
    let s = patch_scene("single", "power = 2.0", "");
    check(&s, Model::Mc3, 1024);
    let s = patch_scene("single", "power = 2.0", "filter_bounces = 3");
    check(&s, Model::Path, 4096);
}

#[test]
fn patch_confocal_mc3_and_path_with_irradiance_laser() {
    let s = patch_scene("confocal", "irradiance = 5.0\nfov = 0.2", "");
    check(&s, Model::Mc3, 1024);
    let s = patch_scene(
        "confocal",
        "irradiance = 5.0\nfov = 0.2",
        "filter_bounces = 3",
    );
    check(&s, Model::Path, 4096);
}

#[test]
fn patch_exhaustive_matches_formula() {
    let s = patch_scene("exhaustive", "power = 1.0", "");
    assert_eq!(s.num_measurements(), 256);
    check(&s, Model::Mc3, 512);
}

#[test]
fn per_vertex_albedo_from_obj_colours() {
    // The patch with vertex colours: the three-bounce signal scales with the mean albedo
    // over its two triangles (faces 1 4 3 and 1 3 2 after triangulation of f 1 4 3 2).
    let rho = [0.2f64, 0.4, 0.6, 0.8];
    let plain = square_obj(PATCH_C, SIDE);
    let mut coloured = String::new();
    for (i, line) in plain.lines().enumerate() {
        if line.starts_with("v ") {
            coloured += &format!("{line} {r} {r} {r}\n", r = rho[i]);
        } else {
            coloured += &format!("{line}\n");
        }
    }
    let toml = |file: &str| {
        format!(
            r#"
capture_type = "confocal"
[wall]
size = [2.0, 2.0]
albedo = 0.8
[laser]
origin = [0.4, -0.3, 1.2]
power = 1.0
[scan]
resolution = [3, 3]
[film]
temporal_bins = 400
bin_width_opl = 0.005
start_opl = 1.5
[[objects]]
file = "{file}"
albedo = 1.0
"#
        )
    };
    let a = scene(&toml("plain.obj"), &[("plain.obj", &plain)]);
    let b = scene(&toml("col.obj"), &[("col.obj", &coloured)]);
    let mean = ((rho[0] + rho[3] + rho[2]) / 3.0 + (rho[0] + rho[2] + rho[1]) / 3.0) / 2.0;
    let ta = totals(&render(&a, Model::Mc3, 4096, 3));
    let tb = totals(&render(&b, Model::Mc3, 4096, 3));
    for (x, y) in ta.iter().zip(&tb) {
        let ratio = y / x;
        assert!(
            (ratio - mean).abs() < 0.01 * mean,
            "ratio {ratio}, mean albedo {mean}"
        );
    }
}

#[test]
fn first_and_last_legs_shift_the_pulse() {
    // With account_first_and_last_bounces the OPL gains |laser - x_l| + |x_s - detector|:
    // the same energy, the pulse moved by exactly that much (Gaussian kernel: compare
    // each point's mean OPL).
    let make = |account: bool| {
        let toml = format!(
            r#"
capture_type = "single"
account_first_and_last_bounces = {account}
[wall]
size = [2.0, 2.0]
[laser]
origin = [0.4, -0.3, 1.2]
target = [0.3, -0.2, 0.0]
[detector]
origin = [-0.5, 0.2, 0.8]
[scan]
resolution = [2, 2]
[film]
temporal_bins = 1200
bin_width_opl = 0.005
start_opl = 1.0
kernel = "gaussian"
sigma_opl = 0.01
[[objects]]
file = "patch.obj"
"#
        );
        scene(&toml, &[("patch.obj", &square_obj(PATCH_C, SIDE))])
    };
    let (a, b) = (make(false), make(true));
    let (ta, tb) = (
        render(&a, Model::Path, 1024, 1),
        render(&b, Model::Path, 1024, 1),
    );
    let mean_opl = |c: &[f32]| {
        let w: f64 = c.iter().map(|&v| v as f64).sum();
        c.iter()
            .enumerate()
            .map(|(i, &v)| v as f64 * (1.0 + (i as f64 + 0.5) * 0.005))
            .sum::<f64>()
            / w
    };
    for m in 0..a.num_measurements() {
        let (xl, xs) = b.measurement_points(m);
        let legs = ((b.laser.origin - xl).length() + (xs - b.detector.origin).length()) as f64;
        let (ca, cb) = (&ta.data[m * 1200..][..1200], &tb.data[m * 1200..][..1200]);
        let shift = mean_opl(cb) - mean_opl(ca);
        assert!(
            (shift - legs).abs() < 1e-3,
            "point {m}: shift {shift}, legs {legs}"
        );
        let (ea, eb): (f32, f32) = (ca.iter().sum(), cb.iter().sum());
        assert!(((ea - eb) / ea).abs() < 1e-3, "energy {ea} vs {eb}");
    }
}
