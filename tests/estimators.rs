//! The estimators agree where they should, in expectation (DESIGN §3):
//! - multi-bounce path tracing filtered to three bounces = the three-bounce estimator;
//! - each sampling technique switched off (the seed paper's ablation) leaves the
//!   expectation unchanged, for three bounces and for interreflections;
//! - the output does not depend on the thread count.
//!
//! Comparisons are z-tests on total energy over independent seeds (|Δ| < 4.5 σ), with a
//! check that σ is small (< 0.6 % of the total) so the test has power.

mod common;
use common::*;
use umbra::scene::{Model, Scene};

const T_OBJ: &str = include_str!("../scenes/meshes/letter_t.obj");

fn base_toml(capture: &str, render: &str) -> String {
    format!(
        r#"
capture_type = "{capture}"
[wall]
size = [2.0, 2.0]
albedo = 0.8
[laser]
# Below the tilted panel (z >= 0.3), so neither the beam nor the detector's view crosses
# a hidden object: the visible legs are tested.
origin = [0.2, -0.8, 0.2]
target = [0.2, -0.1, 0.0]
power = 1.0
spot_radius = 0.0
[scan]
resolution = [3, 3]
size = [1.2, 1.2]
[film]
temporal_bins = 300
bin_width_opl = 0.01
start_opl = 0.5
kernel = "gaussian"
sigma_opl = 0.01
[[objects]]
file = "t.obj"
albedo = 0.8
transform = {{ translate = [0.0, 0.1, 0.7] }}
[[objects]]
file = "occluder.obj"
albedo = 0.5
[[objects]]
file = "floor.obj"
albedo = 0.9
two_sided = true
[render]
{render}
"#
    )
}

/// The letter T, a small occluder in front of it, and a tilted panel below that lights
/// the T by interreflection.
fn t_scene(capture: &str, render: &str) -> Scene {
    let occluder = square_obj([-0.05, 0.2, 0.5], 0.1);
    let floor = "v -0.5 -0.3 0.3\nv 0.5 -0.3 0.3\nv 0.5 -0.1 1.0\nv -0.5 -0.1 1.0\nf 1 2 3 4\n";
    scene(
        &base_toml(capture, render),
        &[
            ("t.obj", T_OBJ),
            ("occluder.obj", &occluder),
            ("floor.obj", floor),
        ],
    )
}

fn assert_same(name: &str, a: (f64, f64), b: (f64, f64)) {
    assert_same_power(name, a, b, 0.006)
}

/// `max_sigma`: largest relative σ of the difference for which the test still has the
/// power it claims.
fn assert_same_power(name: &str, a: (f64, f64), b: (f64, f64), max_sigma: f64) {
    let sigma = (a.1 * a.1 + b.1 * b.1).sqrt();
    let z = (a.0 - b.0) / sigma;
    eprintln!(
        "{name}: {:.6e} ± {:.2e} vs {:.6e} ± {:.2e}: Δ = {:+.3} % (z = {z:+.2})",
        a.0,
        a.1,
        b.0,
        b.1,
        100.0 * (a.0 - b.0) / b.0
    );
    assert!(
        sigma / b.0.abs() < max_sigma,
        "{name}: test too weak, σ = {:.3} %",
        100.0 * sigma / b.0
    );
    assert!(z.abs() < 4.5, "{name}: estimates differ by {z:.1} σ");
}

#[test]
fn path_filtered_to_three_bounces_equals_mc3() {
    for capture in ["single", "confocal", "exhaustive"] {
        let mc3 = total_energy(&t_scene(capture, ""), Model::Mc3, 4096, 8);
        let s = t_scene(capture, "filter_bounces = 3");
        let path = total_energy(&s, Model::Path, 4096, 8);
        assert_same(&format!("{capture}: path(3) vs mc3"), path, mc3);
    }
}

#[test]
fn ablation_three_bounce_without_hidden_geometry_sampling() {
    let with = total_energy(
        &t_scene("confocal", "filter_bounces = 3"),
        Model::Path,
        4096,
        8,
    );
    let s = t_scene(
        "confocal",
        "filter_bounces = 3\nhidden_geometry_sampling = false",
    );
    let without = total_energy(&s, Model::Path, 65536, 8);
    assert_same("confocal 3-bounce: BSDF-only vs MIS", without, with);
}

#[test]
fn ablation_multibounce_each_technique() {
    // Up to 4 bounces: interreflections between floor, T and occluder. (Hidden-geometry
    // sampling alone cannot reach paths that bounce off the wall mid-way, which need 5+
    // bounces: x_s, y1, wall, y2, x_l.)
    let r = "max_bounces = 4";
    let both = total_energy(&t_scene("single", r), Model::Path, 16384, 8);
    let hg_only = total_energy(
        &t_scene("single", &format!("{r}\nbsdf_sampling = false")),
        Model::Path,
        16384,
        8,
    );
    assert_same("4 bounces: hidden-geometry only vs MIS", hg_only, both);
    let r = "max_bounces = 6";
    let both = total_energy(&t_scene("single", r), Model::Path, 16384, 8);
    let bsdf_only = total_energy(
        &t_scene("single", &format!("{r}\nhidden_geometry_sampling = false")),
        Model::Path,
        131072,
        8,
    );
    assert_same("6 bounces: BSDF only vs MIS", bsdf_only, both);
    // With the wall in hidden-geometry sampling, it alone reaches every path again.
    let hg_wall = total_energy(
        &t_scene(
            "single",
            &format!("{r}\nbsdf_sampling = false\nhidden_geometry_includes_wall = true"),
        ),
        Model::Path,
        65536,
        8,
    );
    assert_same(
        "6 bounces: hidden-geometry + wall only vs MIS",
        hg_wall,
        both,
    );
}

#[test]
fn ablation_laser_sampling_with_a_finite_spot() {
    // A 10 cm lit disk: without laser sampling, only BSDF-sampled paths that land on it
    // see light; with it, NEE and BSDF hits are combined by MIS.
    let spot = |r: &str| t_scene("single", r).with_spot(0.1);
    let r = "max_bounces = 4";
    let nee = total_energy(&spot(r), Model::Path, 16384, 8);
    let no_nee = total_energy(
        &spot(&format!("{r}\nlaser_sampling = false")),
        Model::Path,
        262144,
        8,
    );
    assert_same_power("spot: without laser sampling vs with", no_nee, nee, 0.012);
    // Hidden-geometry sampling of the wall can land on the spot too: its MIS weight
    // against NEE must count that density.
    let hg_wall = total_energy(
        &spot(&format!("{r}\nhidden_geometry_includes_wall = true")),
        Model::Path,
        16384,
        8,
    );
    assert_same(
        "spot: HG incl. wall + BSDF + NEE vs HG + BSDF + NEE",
        hg_wall,
        nee,
    );
    // mc3 over the lit disk = path filtered to three bounces with a finite spot.
    let mc3 = total_energy(&spot(""), Model::Mc3, 4096, 8);
    let p3 = total_energy(&spot("filter_bounces = 3"), Model::Path, 16384, 8);
    assert_same("spot: path(3) vs mc3", p3, mc3);
}

trait WithSpot {
    fn with_spot(self, r: f32) -> Self;
}
impl WithSpot for Scene {
    fn with_spot(mut self, r: f32) -> Self {
        self.laser.spot_radius = r;
        self
    }
}

#[test]
fn same_output_for_any_thread_count() {
    let s = t_scene("confocal", "max_bounces = 6");
    let run = |threads| on_threads(threads, || render(&s, Model::Path, 3000, 42));
    let a = run(1);
    let b = run(2);
    let c = run(3);
    assert!(a.data.iter().any(|&v| v > 0.0));
    assert_eq!(a.data, b.data);
    assert_eq!(a.data, c.data);
    // And a different seed gives a different (independent) estimate.
    let d = render(&s, Model::Path, 3000, 43);
    assert_ne!(a.data, d.data);
}
