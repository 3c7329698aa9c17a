//! Where the interior derivative is biased (DESIGN §5): the adjoint differentiates each
//! path's contribution with visibility held fixed, so when an occluder's shadow edge moves
//! across a hidden surface, the boundary term is missing. This test measures that bias
//! against finite differences of the converged estimate (common random numbers, a step
//! large enough that the visibility jumps average out, several seeds for an error bar),
//! prints the table the docs quote, and pins the behaviour: no bias without occlusion,
//! a significant one with it.

mod common;
use common::*;
use umbra::adjoint::check::{self, Param};
use umbra::scene::{Model, Scene};
use umbra::transport::RenderOptions;

const PLATE: &str =
    "v -0.15 -0.15 0.9\nv 0.15 -0.15 0.9\nv 0.15 0.15 0.9\nv -0.15 0.15 0.9\nf 1 4 3 2\n";
/// A concave corner whose side plate hides part of the back plate from the scan points
/// beyond x = 0.15: self-occlusion, a silhouette that moves with the shared edge.
const CORNER: &str = "v -0.15 -0.15 0.9\nv 0.15 -0.15 0.9\nv 0.15 0.15 0.9\nv -0.15 0.15 0.9\n\
                      v 0.15 -0.15 0.6\nv 0.15 0.15 0.6\nf 1 4 3 2\nf 2 3 6 5\n";
const OCCLUDER: &str =
    "v -0.02 -0.05 0.6\nv 0.08 -0.05 0.6\nv 0.08 0.05 0.6\nv -0.02 0.05 0.6\nf 1 4 3 2\n";

fn scene_of(objects: &[(&str, &str)]) -> Scene {
    scene_with(objects, "")
}

fn scene_with(objects: &[(&str, &str)], render: &str) -> Scene {
    let mut toml = String::from(
        r#"
capture_type = "confocal"
[wall]
size = [2.0, 2.0]
[laser]
origin = [0.3, -0.4, 1.0]
[scan]
resolution = [4, 4]
size = [0.9, 0.9]
[film]
temporal_bins = 200
bin_width_opl = 0.01
start_opl = 0.9
kernel = "gaussian"
sigma_opl = 0.012
"#,
    );
    for (f, _) in objects {
        toml += &format!("[[objects]]\nfile = \"{f}\"\nalbedo = 0.7\ntwo_sided = true\n");
    }
    toml += &format!("[render]\n{render}\n");
    scene(&toml, objects)
}

/// (mean adjoint, mean fd, standard error of adjoint − fd) over seeds.
fn measure(s: &Scene, model: Model, p: Param, h: f64, spp: u32) -> (f64, f64, f64) {
    let mut diffs = Vec::new();
    let (mut ad, mut fd) = (0.0, 0.0);
    let seeds = 6;
    for seed in 0..seeds {
        let opts = RenderOptions {
            model,
            spp,
            seed,
            ..RenderOptions::from_scene(s)
        };
        let row = &check::run(s, &opts, &[p], &[h]).unwrap()[0];
        ad += row.adjoint / seeds as f64;
        fd += row.fd[0].1 / seeds as f64;
        diffs.push(row.adjoint - row.fd[0].1);
    }
    let mean = diffs.iter().sum::<f64>() / seeds as f64;
    let var = diffs.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (seeds - 1) as f64;
    (ad, fd, (var / seeds as f64).sqrt())
}

#[test]
fn visibility_changes_bias_the_interior_derivative_and_nothing_else_does() {
    let plate_alone = scene_of(&[("plate.obj", PLATE)]);
    let both = scene_of(&[("plate.obj", PLATE), ("occ.obj", OCCLUDER)]);
    let objects = [("plate.obj", PLATE), ("occ.obj", OCCLUDER)];
    let hgs = scene_with(&objects, "max_bounces = 5\nbsdf_sampling = false");
    let mis = scene_with(&objects, "max_bounces = 5");
    let corner = scene_of(&[("corner.obj", CORNER)]);
    let cases = [
        (
            "mc3: plate alone, plate corner x",
            Model::Mc3,
            &plate_alone,
            Param::Vertex(0, 1, 0),
            false,
        ),
        (
            "mc3: plate behind an occluder, plate corner x",
            Model::Mc3,
            &both,
            Param::Vertex(0, 1, 0),
            true,
        ),
        (
            "mc3: occluder corner x (its shadow moves)",
            Model::Mc3,
            &both,
            Param::Vertex(1, 1, 0),
            true,
        ),
        (
            "path (area sampling): occluder corner x",
            Model::Path,
            &hgs,
            Param::Vertex(1, 1, 0),
            true,
        ),
        (
            "mc3: self-occluding corner, shared edge vertex x",
            Model::Mc3,
            &corner,
            Param::Vertex(0, 2, 0),
            true,
        ),
        (
            "path (MIS): occluder corner x",
            Model::Path,
            &mis,
            Param::Vertex(1, 1, 0),
            true,
        ),
    ];
    println!("| case | adjoint | finite difference | bias (adjoint − fd) / |fd| | ± |");
    println!("|---|---|---|---|---|");
    for (name, model, s, p, occluded) in cases {
        let (ad, fd, se) = measure(s, model, p, 2e-3, 4096);
        let bias = (ad - fd) / fd.abs();
        let err = se / fd.abs();
        println!(
            "| {name} | {ad:.4e} | {fd:.4e} | {:.1} % | {:.1} % |",
            100.0 * bias,
            100.0 * err
        );
        if occluded {
            assert!(
                (ad - fd).abs() > 3.0 * se,
                "{name}: expected a measurable bias, got {bias:.3} ± {err:.3}"
            );
        } else {
            assert!(
                (ad - fd).abs() < 4.0 * se + 0.01 * fd.abs(),
                "{name}: {bias:.3} ± {err:.3}"
            );
        }
    }
}
