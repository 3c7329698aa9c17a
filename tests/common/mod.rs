//! Helpers shared by the integration tests: scenes from inline TOML and OBJ text,
//! renders, and the total energy's mean and standard error over independent seeds.
#![allow(dead_code)]

use std::path::Path;
use umbra::geometry::mesh::TriMesh;
use umbra::geometry::SceneGeometry;
use umbra::scene::{toml_format, Model, Scene};
use umbra::transport::{self, RenderOptions, Transient};

/// A scene from TOML text whose objects name OBJ texts in `objs`.
pub fn scene(toml: &str, objs: &[(&str, &str)]) -> Scene {
    try_scene(toml, objs).unwrap_or_else(|e| panic!("test scene: {e}"))
}

pub fn try_scene(toml: &str, objs: &[(&str, &str)]) -> umbra::Result<Scene> {
    let objs: Vec<(String, String)> = objs
        .iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    toml_format::parse(toml, Path::new("test.toml"), &move |f| match objs
        .iter()
        .find(|(n, _)| n == f)
    {
        Some((_, text)) => TriMesh::parse_obj(text, Path::new(f)),
        None => Err(umbra::Error::scene(Path::new(f), "no such inline OBJ")),
    })
}

pub fn render(scene: &Scene, model: Model, spp: u32, seed: u64) -> Transient {
    let geom = SceneGeometry::build(scene);
    let opts = RenderOptions {
        model,
        spp,
        seed,
        ..RenderOptions::from_scene(scene)
    };
    transport::render(scene, &geom, &opts, None).expect("render")
}

/// A square of side `side` centred at `c` in the plane z = c.z, facing -z (the wall).
pub fn square_obj(c: [f32; 3], side: f32) -> String {
    let h = side / 2.0;
    format!(
        "v {} {} {z}\nv {} {} {z}\nv {} {} {z}\nv {} {} {z}\nf 1 4 3 2\n",
        c[0] - h,
        c[1] - h,
        c[0] + h,
        c[1] - h,
        c[0] + h,
        c[1] + h,
        c[0] - h,
        c[1] + h,
        z = c[2]
    )
}

/// Per-measurement time-integrated values.
pub fn totals(t: &Transient) -> Vec<f64> {
    t.data
        .chunks(t.bins())
        .map(|c| c.iter().map(|&v| v as f64).sum())
        .collect()
}

/// Total energy over seeds: (mean, standard error of the mean).
pub fn total_energy(scene: &Scene, model: Model, spp: u32, seeds: u64) -> (f64, f64) {
    let t: Vec<f64> = (0..seeds)
        .map(|s| {
            render(scene, model, spp, 5000 + s)
                .data
                .iter()
                .map(|&v| v as f64)
                .sum()
        })
        .collect();
    let k = seeds as f64;
    let m = t.iter().sum::<f64>() / k;
    let var = t.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (k - 1.0);
    (m, (var / k).sqrt())
}

/// `../shared/data/<name>` beside the repository (or `/work/shared/data/<name>`), where
/// the machine's shared captures live; the environment variable `var` overrides it.
pub fn shared_dir(var: &str, name: &str) -> std::path::PathBuf {
    use std::path::PathBuf;
    if let Ok(d) = std::env::var(var) {
        return PathBuf::from(d);
    }
    let beside = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/")
        .join(name);
    if beside.is_dir() {
        return beside;
    }
    PathBuf::from("/work/shared/data").join(name)
}

/// The adjoint against CRN central differences on `params` parameters per object
/// (`adjoint::check`), each within 1 % of `max(|fd|, 2 % of the largest)`.
/// Most scenes sit off the scan grid's symmetry lines (generic positions);
/// `tri3_at_exact_opl_ties` checks a mirror-symmetric placement, where corners of
/// sub-triangles tie in OPL exactly.
pub fn check(scene: &Scene, model: Model, spp: u32, params: usize) {
    let opts = RenderOptions {
        model,
        spp,
        seed: 7,
        ..RenderOptions::from_scene(scene)
    };
    let ps = umbra::adjoint::check::pick_params(scene, params, 12345);
    // Steps small against σ = 12 mm (the difference's own error is (h/σ)² / 6); tri3's
    // f64 reference allows smaller ones.
    let h = if model == Model::Tri3 { 1e-4 } else { 3e-4 };
    let rows = umbra::adjoint::check::run(scene, &opts, &ps, &[h]).unwrap();
    let largest = rows.iter().map(|r| r.fd[0].1.abs()).fold(0.0, f64::max);
    assert!(
        largest > 0.0,
        "no gradient signal: the test scene is broken"
    );
    for r in &rows {
        let err = r.error(0.02 * largest);
        println!(
            "{model:?} {}: adjoint {:.6e} fd {:.6e} rel {err:.2e}",
            r.param, r.adjoint, r.fd[0].1
        );
        assert!(
            err < 0.01,
            "{model:?} {}: adjoint {} vs fd {} ({err:.3e})",
            r.param,
            r.adjoint,
            r.fd[0].1
        );
    }
}

/// Relative L2 between the eight-lane `f32` tri3 kernel's render and its `f64` reference
/// path (`adjoint::check::primal`); panics if the reference is all zero.
pub fn kernel_vs_reference(scene: &Scene, geom: &SceneGeometry, opts: &RenderOptions) -> f64 {
    let opts = RenderOptions {
        model: Model::Tri3,
        ..*opts
    };
    let fast = transport::render(scene, geom, &opts, None).unwrap();
    let reference = umbra::adjoint::check::primal(scene, geom, &opts).unwrap();
    let (mut num, mut den) = (0.0, 0.0);
    for (a, b) in fast.data.iter().zip(&reference) {
        num += (*a as f64 - b).powi(2);
        den += b * b;
    }
    assert!(den > 0.0, "the reference render is zero");
    (num / den).sqrt()
}
