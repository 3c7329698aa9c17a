//! The deterministic per-triangle model `tri3` against the Monte Carlo three-bounce
//! estimator `mc3` at high spp (DESIGN §3 rungs 1 and 2), with the default subdivision.
//!
//! The comparison is the relative L2 difference over every bin, with mc3's own noise
//! measured from two independent seeds and required to be below 0.3 %, so the < 1 %
//! agreement is a statement about tri3, not about the noise.

mod common;
use common::*;
use glam::Vec3;
use umbra::bench::rel_l2;
use umbra::geometry::mesh::TriMesh;
use umbra::geometry::shapes::{icosphere, wavy_sheet};
use umbra::scene::{Model, Scene, Visibility};
use umbra::transport::{RenderOptions, Renderer, Transient};

pub fn obj_text(m: &TriMesh) -> String {
    let mut s = String::new();
    for p in &m.positions {
        s += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for [a, b, c] in &m.triangles {
        s += &format!("f {} {} {}\n", a + 1, b + 1, c + 1);
    }
    s
}

fn scene_with(capture: &str, obj: &str, film: &str) -> Scene {
    let toml = format!(
        r#"
capture_type = "{capture}"
[wall]
size = [2.0, 2.0]
albedo = 0.8
[laser]
origin = [0.3, -0.4, 1.0]
target = [0.2, -0.1, 0.0]
power = 1.0
[scan]
resolution = [4, 4]
size = [1.2, 1.2]
[film]
{film}
[[objects]]
file = "m.obj"
albedo = 0.7
"#
    );
    scene(&toml, &[("m.obj", obj)])
}

fn render_with(s: &Scene, model: Model, spp: u32, seed: u64, visibility: Visibility) -> Transient {
    let geom = umbra::geometry::SceneGeometry::build(s);
    let opts = RenderOptions {
        model,
        spp,
        seed,
        visibility,
        ..RenderOptions::from_scene(s)
    };
    Renderer::new(s, &geom, &opts)
        .unwrap()
        .render(None)
        .unwrap()
}

/// (tri3 vs mc3 relative L2, mc3 noise) for a scene.
fn compare(s: &Scene, spp: u32, visibility: Visibility) -> (f64, f64) {
    let a = render_with(s, Model::Mc3, spp, 1, visibility);
    let b = render_with(s, Model::Mc3, spp, 2, visibility);
    let mean: Vec<f32> = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| 0.5 * (x + y))
        .collect();
    // Noise of the two-seed mean: ||a - b|| / 2.
    let noise = rel_l2(&a.data, &b.data) / 2.0;
    let t = render_with(s, Model::Tri3, 1, 0, visibility);
    (rel_l2(&t.data, &mean), noise)
}

const FILM: &str = "temporal_bins = 160\nbin_width_opl = 0.01\nstart_opl = 1.5";

fn check(name: &str, obj: &str, spp: u32, visibility: Visibility) {
    for capture in ["single", "confocal"] {
        let s = scene_with(capture, obj, FILM);
        let (err, noise) = compare(&s, spp, visibility);
        eprintln!(
            "{name} {capture}: tri3 vs mc3 {:.3} %, mc3 noise {:.3} %",
            100.0 * err,
            100.0 * noise
        );
        assert!(
            noise < 0.003,
            "{name} {capture}: mc3 noise {noise} too high for the test"
        );
        assert!(
            err < 0.01,
            "{name} {capture}: tri3 differs from mc3 by {:.2} %",
            100.0 * err
        );
    }
}

#[test]
fn planar_letter() {
    let obj = include_str!("../scenes/meshes/letter_t.obj").replace(" 0\n", " 0.8\n");
    check("letter T", &obj, 1 << 18, Visibility::None);
}

#[test]
fn sphere() {
    let m = icosphere(Vec3::new(0.1, 0.0, 0.9), 0.2, 3);
    check(
        "sphere (1280 triangles)",
        &obj_text(&m),
        1 << 18,
        Visibility::None,
    );
}

#[test]
fn wavy_mesh_with_5k_triangles() {
    let m = wavy_sheet(Vec3::new(0.0, 0.1, 0.8), 0.6, 52, 0.02, 0.3);
    assert!(m.triangles.len() >= 5000);
    check(
        "wavy sheet (5408 triangles)",
        &obj_text(&m),
        1 << 18,
        Visibility::Centroid,
    );
}

fn auto_choice(s: &Scene) -> umbra::transport::auto::AutoChoice {
    let geom = umbra::geometry::SceneGeometry::build(s);
    let opts = RenderOptions {
        model: Model::Auto,
        ..RenderOptions::from_scene(s)
    };
    let r = Renderer::new(s, &geom, &opts).unwrap();
    let c = r.auto_choice.clone().expect("auto reports its choice");
    eprintln!("{}", c.reason);
    assert_eq!(r.model, c.model);
    c
}

#[test]
fn auto_picks_tri3_for_a_convex_object() {
    let m = icosphere(Vec3::new(0.1, 0.0, 0.9), 0.2, 3);
    let s = scene_with("confocal", &obj_text(&m), FILM);
    let c = auto_choice(&s);
    assert_eq!(c.model, Model::Tri3, "{}", c.reason);
}

#[test]
fn auto_picks_path_for_a_concave_corner() {
    // Two 40 cm panels meeting at a right angle, the opening toward the wall: each lights
    // the other.
    let corner = "v -0.2 -0.2 0.8\nv 0 -0.2 1.0\nv 0 0.2 1.0\nv -0.2 0.2 0.8\n\
                  v 0 -0.2 1.0\nv 0.2 -0.2 0.8\nv 0.2 0.2 0.8\nv 0 0.2 1.0\n\
                  f 1 4 3 2\nf 5 8 7 6\n";
    let s = scene_with(
        "confocal",
        corner,
        "temporal_bins = 300\nbin_width_opl = 0.01\nstart_opl = 1.4",
    );
    let c = auto_choice(&s);
    assert_eq!(c.model, Model::Path, "{}", c.reason);
    assert!(
        c.beyond_three > 0.02,
        "interreflections {:.3}",
        c.beyond_three
    );
    // And a looser request accepts tri3 for the same scene.
    let mut loose = s.clone();
    loose.render.max_error = 0.9;
    assert_eq!(auto_choice(&loose).model, Model::Tri3);
}

#[test]
fn gaussian_kernel_matches_mc3() {
    let m = icosphere(Vec3::new(0.1, 0.0, 0.9), 0.2, 3);
    let film = "temporal_bins = 160\nbin_width_opl = 0.01\nstart_opl = 1.5\nkernel = \"gaussian\"\nsigma_opl = 0.008";
    for capture in ["single", "confocal"] {
        let s = scene_with(capture, &obj_text(&m), film);
        let (err, noise) = compare(&s, 1 << 17, Visibility::None);
        eprintln!(
            "sphere, Gaussian kernel, {capture}: tri3 vs mc3 {:.3} %, mc3 noise {:.3} %",
            100.0 * err,
            100.0 * noise
        );
        assert!(noise < 0.003 && err < 0.01);
    }
}

/// Partial occlusion: a small square in front of the letter T. Visibility per
/// sub-triangle converges to the exact (mc3) answer; per original triangle is coarser;
/// none ignores the shadow. Quantified, not hidden.
#[test]
fn visibility_modes_under_partial_occlusion() {
    let letter = include_str!("../scenes/meshes/letter_t.obj").replace(" 0\n", " 0.8\n");
    let toml = format!(
        r#"
capture_type = "confocal"
[wall]
size = [2.0, 2.0]
albedo = 0.8
[laser]
origin = [0.3, -0.4, 1.0]
[scan]
resolution = [4, 4]
size = [1.2, 1.2]
[film]
{FILM}
[[objects]]
file = "t.obj"
albedo = 0.7
[[objects]]
file = "occ.obj"
albedo = 0.5
"#
    );
    let s = scene(
        &toml,
        &[
            ("t.obj", &letter),
            ("occ.obj", &square_obj([0.02, 0.12, 0.5], 0.12)),
        ],
    );
    let mut errs = Vec::new();
    for v in [
        Visibility::Subtriangle,
        Visibility::Centroid,
        Visibility::None,
    ] {
        let (err, noise) = compare(&s, 1 << 16, v);
        eprintln!(
            "occluded T, visibility {}: tri3 vs mc3 {:.3} %, mc3 noise {:.3} %",
            v.name(),
            100.0 * err,
            100.0 * noise
        );
        errs.push(err);
    }
    assert!(
        errs[0] < 0.05,
        "subtriangle visibility {:.2} %",
        100.0 * errs[0]
    );
    assert!(errs[0] <= errs[1] && errs[1] < errs[2], "{errs:?}");
}
