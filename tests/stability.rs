//! The stability study (issue 7; docs table in BENCHMARKS.md, "Where methods fail"): each
//! test puts a method where it is expected to fail and pins what happens.
//!
//! - float32 far from the wall: the eight-lane `tri3` kernel computes path lengths in
//!   `f32`; its agreement with the `f64` reference degrades with distance as the ulp of the
//!   OPL grows against the bin width.
//! - grazing angles: a hidden square turned towards edge-on; `tri3` (deterministic,
//!   linear corner weights) against the converged Monte Carlo `mc3` as the signal vanishes.

mod common;
use common::*;
use umbra::geometry::SceneGeometry;
use umbra::scene::{Model, Scene};
use umbra::transport::RenderOptions;

const SQUARE: &str = "v -0.1 -0.1 0\nv 0.1 -0.1 0\nv 0.1 0.1 0\nv -0.1 0.1 0\nf 1 4 3 2\n";

/// A 20 cm square at `depth`, turned `angle_deg` about the vertical axis, confocal 4 x 4
/// over 0.8 m; the film spans the square's returns with 200 bins of `bin` m.
fn square_scene(depth: f32, angle_deg: f32, bin: f32) -> Scene {
    let start = 2.0 * depth - 0.3;
    let toml = format!(
        r#"
capture_type = "confocal"
[wall]
size = [2.0, 2.0]
albedo = 0.8
[laser]
origin = [0.0, -0.5, 1.0]
[scan]
resolution = [4, 4]
size = [0.8, 0.8]
[film]
temporal_bins = 200
bin_width_opl = {bin}
start_opl = {start}
kernel = "gaussian"
sigma_opl = {sigma}
[[objects]]
file = "square.obj"
albedo = 0.8
transform = {{ rotate = [{{ axis = [0.0, 1.0, 0.0], angle = {angle_deg} }}], translate = [0.03, 0.01, {depth}] }}
[render]
model = "tri3"
"#,
        sigma = 1.5 * bin
    );
    scene(&toml, &[("square.obj", SQUARE)])
}

#[test]
fn float32_tri3_keeps_its_accuracy_to_100_m_and_degrades_beyond() {
    let mut errors = Vec::new();
    for depth in [1.0f32, 10.0, 100.0, 1000.0] {
        // Bins of 4 mm at every distance: the OPL's f32 ulp grows as the distance.
        let s = square_scene(depth, 0.0, 0.004);
        let geom = SceneGeometry::build(&s);
        let opts = RenderOptions::from_scene(&s);
        let e = kernel_vs_reference(&s, &geom, &opts);
        println!("depth {depth} m: kernel vs f64 reference {e:.2e}");
        errors.push(e);
    }
    // The error grows about tenfold per tenfold distance (the OPL's ulp against a fixed
    // bin): seen 1.2e-6, 1.3e-5, 3.9e-4, 2.4e-3. At 1 km (OPL 2 km, ulp 0.24 mm, 6 % of a
    // bin) it is 0.24 %: a documented limit, not a failure.
    assert!(
        errors[0] < 5e-6 && errors[1] < 5e-5 && errors[2] < 1e-3,
        "{errors:?}"
    );
    assert!(
        errors[3] > 10.0 * errors[1] && errors[3] < 1e-2,
        "{errors:?}"
    );
}

#[test]
fn grazing_angles_tri3_follows_mc3_until_the_signal_vanishes() {
    for angle in [0.0f32, 60.0, 85.0, 89.0] {
        let s = square_scene(0.8, angle, 0.01);
        let tri3 = render(&s, Model::Tri3, 1, 0);
        let mc3 = render(&s, Model::Mc3, 1 << 14, 3);
        let e = umbra::bench::rel_l2(&tri3.data, &mc3.data);
        let total: f64 = tri3.data.iter().map(|&v| v as f64).sum();
        println!("angle {angle}: total {total:.3e}, tri3 vs mc3 {e:.2e}");
        assert!(total > 0.0);
        // tri3 agrees with mc3 to its noise (16k spp; seen 0.09-0.18 %) at every angle:
        // the weights fall with the cosine and both see the same thinning square.
        assert!(e < 5e-3, "angle {angle}: {e}");
    }
}

#[test]
fn box_kernel_warning_for_monte_carlo_vertex_gradients_only() {
    let gaussian = square_scene(0.8, 0.0, 0.01);
    let mut boxed = gaussian.clone();
    boxed.film.kernel = umbra::scene::KernelSpec::Box;
    use umbra::adjoint::box_kernel_warning;
    assert!(box_kernel_warning(&boxed, Model::Mc3).is_some());
    assert!(box_kernel_warning(&boxed, Model::Path).is_some());
    assert!(box_kernel_warning(&boxed, Model::Tri3).is_none());
    assert!(box_kernel_warning(&gaussian, Model::Mc3).is_none());
}
