//! The retroreflective reflectance (confocal `tri3`, the LCT paper's model): its falloff
//! is 1/r² where a Lambertian surface's is 1/r⁴, the eight-lane kernel matches the f64
//! reference, its adjoint matches finite differences, and scenes it cannot be rendered
//! in are refused with the object named.

mod common;
use common::*;
use umbra::geometry::SceneGeometry;
use umbra::scene::{Model, Reflectance, Scene};
use umbra::transport::{self, RenderOptions};

const LETTER: &str = include_str!("../scenes/meshes/letter_t.obj");

fn scene_of(capture: &str, obj: &str, reflectance: &str, scan: u32, z: f32) -> Scene {
    scene(
        &scene_toml(capture, reflectance, scan, z),
        &[("o.obj", obj)],
    )
}

fn scene_toml(capture: &str, reflectance: &str, scan: u32, z: f32) -> String {
    let transform = format!("{{ translate = [0.0123, 0.0071, {z}] }}");
    scene_toml_at(capture, reflectance, scan, &transform)
}

/// `text` with its object's angular falloff exponent set to `m`.
fn with_falloff(text: &str, m: f32) -> String {
    text.replace(
        "reflectance = \"retroreflective\"",
        &format!("reflectance = \"retroreflective\"\nretro_falloff = {m}"),
    )
}

fn scene_toml_at(capture: &str, reflectance: &str, scan: u32, transform: &str) -> String {
    format!(
        r#"
capture_type = "{capture}"
[wall]
size = [2.0, 2.0]
albedo = 0.8
[laser]
origin = [0.3, -0.4, 1.0]
target = [0.0, 0.0, 0.0]
[scan]
resolution = [{scan}, {scan}]
size = [0.8, 0.8]
[film]
temporal_bins = 400
bin_width_opl = 0.01
start_opl = 0.5
kernel = "gaussian"
sigma_opl = 0.012
[[objects]]
file = "o.obj"
albedo = 0.7
reflectance = "{reflectance}"
transform = {transform}
[render]
model = "tri3"
"#
    )
}

fn total(s: &Scene) -> f64 {
    totals(&render(s, Model::Tri3, 1, 0)).iter().sum()
}

#[test]
fn falloff_is_inverse_square_for_retroreflectors_and_inverse_fourth_for_lambertian() {
    // A 1 cm square in front of a single confocal scan point, at 0.4 m and 0.8 m.
    let patch = square_obj([-0.0123, -0.0071, 0.0], 0.01);
    for (reflectance, expected) in [("retroreflective", 4.0), ("lambertian", 16.0)] {
        let near = total(&scene_of("confocal", &patch, reflectance, 1, 0.4));
        let far = total(&scene_of("confocal", &patch, reflectance, 1, 0.8));
        let ratio = near / far;
        println!("{reflectance}: near/far = {ratio:.4}");
        assert!(
            (ratio / expected - 1.0).abs() < 2e-3,
            "{reflectance}: {ratio}"
        );
    }
}

#[test]
fn angular_falloff_scales_the_return_by_cos_to_the_m() {
    // A 4 mm square 0.5 m in front of a single confocal scan point, turned 40° about x:
    // the entrance angle is 40° all over it (to ±0.23°; at 1 cm, ±0.6° made cos^8's
    // mean 1.8e-3 off its value at the centre).
    let patch = square_obj([0.0, 0.0, 0.0], 0.004);
    let at =
        r#"{ rotate = [{ axis = [1.0, 0.0, 0.0], angle = 40.0 }], translate = [0.0, 0.0, 0.5] }"#;
    let ideal = scene_toml_at("confocal", "retroreflective", 1, at);
    let base = total(&scene(&ideal, &[("o.obj", &patch)]));
    assert!(base > 0.0);
    let cos = 40f64.to_radians().cos();
    for m in [0.5f32, 1.0, 2.0, 3.7, 8.0] {
        let s = scene(&with_falloff(&ideal, m), &[("o.obj", &patch)]);
        assert_eq!(s.objects[0].reflectance.falloff(), m);
        let ratio = total(&s) / base;
        let want = cos.powf(f64::from(m));
        println!("m = {m}: ratio {ratio:.5}, cos^m 40° = {want:.5}");
        assert!(
            (ratio / want - 1.0).abs() < 1e-3,
            "m = {m}: {ratio} against {want}"
        );
    }
}

#[test]
fn adjoint_with_falloff_matches_finite_differences() {
    // The letter turned 35° about y, so that the entrance angles (and the falloff) vary.
    let at = r#"{ rotate = [{ axis = [0.0, 1.0, 0.0], angle = 35.0 }], translate = [0.0123, 0.0071, 0.8] }"#;
    let text = with_falloff(&scene_toml_at("confocal", "retroreflective", 3, at), 2.5);
    check(&scene(&text, &[("o.obj", LETTER)]), Model::Tri3, 1, 6);
}

#[test]
fn a_bad_falloff_names_the_field() {
    let ideal = scene_toml("confocal", "retroreflective", 2, 0.8);
    let too_steep = try_scene(&with_falloff(&ideal, 17.0), &[("o.obj", LETTER)]);
    let e = too_steep.map(|_| ()).unwrap_err().to_string();
    assert!(
        e.contains("objects[0].retro_falloff") && e.contains("0 to 16"),
        "{e}"
    );
    let lambertian = scene_toml("confocal", "lambertian", 2, 0.8)
        .replace("reflectance = \"lambertian\"", "retro_falloff = 2.0");
    let e = try_scene(&lambertian, &[("o.obj", LETTER)])
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("objects[0].retro_falloff") && e.contains("lambertian"),
        "{e}"
    );
}

#[test]
fn kernel_matches_the_f64_reference() {
    // The ideal retroreflector, and one with angular falloff.
    let mut fast = None;
    for m in [0.0, 3.5] {
        let text = with_falloff(&scene_toml("confocal", "retroreflective", 4, 0.8), m);
        let s = scene(&text, &[("o.obj", LETTER)]);
        assert_eq!(
            s.objects[0].reflectance,
            Reflectance::Retroreflective { falloff: m }
        );
        let geom = SceneGeometry::build(&s);
        let opts = RenderOptions {
            model: Model::Tri3,
            ..RenderOptions::from_scene(&s)
        };
        let rel = kernel_vs_reference(&s, &geom, &opts);
        println!("kernel vs reference, falloff {m}: {rel:.2e}");
        assert!(rel < 2e-5, "falloff {m}: {rel}");
        fast.get_or_insert(transport::render(&s, &geom, &opts, None).unwrap());
    }
    let fast = fast.unwrap();
    // And it is not the Lambertian render.
    let lambert = render(
        &scene_of("confocal", LETTER, "lambertian", 4, 0.8),
        Model::Tri3,
        1,
        0,
    );
    let diff: f64 = lambert
        .data
        .iter()
        .zip(&fast.data)
        .map(|(a, b)| (*a as f64 - *b as f64).abs())
        .sum();
    assert!(diff > 0.1 * fast.data.iter().map(|v| *v as f64).sum::<f64>());
}

#[test]
fn adjoint_matches_finite_differences() {
    check(
        &scene_of("confocal", LETTER, "retroreflective", 3, 0.8),
        Model::Tri3,
        1,
        6,
    );
}

#[test]
fn unsupported_scenes_are_refused_naming_the_object() {
    let single = scene_of("single", LETTER, "retroreflective", 2, 0.8);
    let geom = SceneGeometry::build(&single);
    let opts = RenderOptions::from_scene(&single);
    let e = transport::render(&single, &geom, &opts, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("objects[0]") && e.contains("confocal"), "{e}");
    let confocal = scene_of("confocal", LETTER, "retroreflective", 2, 0.8);
    let geom = SceneGeometry::build(&confocal);
    for model in [Model::Mc3, Model::Path, Model::Auto] {
        let opts = RenderOptions {
            model,
            ..RenderOptions::from_scene(&confocal)
        };
        let e = transport::render(&confocal, &geom, &opts, None)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("objects[0]") && e.contains("tri3"),
            "{model:?}: {e}"
        );
    }
    let text = scene_toml("confocal", "mirror", 2, 0.8);
    let bad = try_scene(&text, &[("o.obj", LETTER)]);
    let e = bad.map(|_| ()).unwrap_err().to_string();
    assert!(
        e.contains("objects[0].reflectance") && e.contains("mirror"),
        "{e}"
    );
}
