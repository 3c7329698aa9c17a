//! The visible legs (laser -> laser spot, sensor point -> detector) are tested for
//! occlusion by the hidden objects, as mitransient traces them: a measurement whose leg
//! is blocked records nothing in every model, and contributes nothing to gradients.
//! `render.visible_legs = false` skips the test. Which scan points a plate blocks is
//! computed here independently, by intersecting each leg with the plate's square.

mod common;

use common::{square_obj, SceneSpec};
use umbra::geometry::SceneGeometry;
use umbra::scene::{Model, Scene};
use umbra::transport::{self, RenderOptions};

const MODELS: [Model; 3] = [Model::Tri3, Model::Mc3, Model::Path];

/// A 0.12 m plate at z = `PLATE_Z`, centred at `c`, facing the wall.
const PLATE_Z: f32 = 0.5;
const PLATE_SIDE: f32 = 0.12;

/// Whether the segment `a -> b` (b on the wall, z = 0) crosses the plate centred at `c`.
fn crosses_plate(a: [f32; 3], b: [f32; 3], c: [f32; 2]) -> bool {
    let t = (a[2] - PLATE_Z) / (a[2] - b[2]);
    let p = [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
    (0.0..1.0).contains(&t)
        && (p[0] - c[0]).abs() < PLATE_SIDE / 2.0
        && (p[1] - c[1]).abs() < PLATE_SIDE / 2.0
}

/// A target square 1 m out, and a plate on the line from `origin` to scan point `aim`.
fn spec(capture: &'static str, laser: [f32; 3], detector: [f32; 3], aim: usize) -> SceneSpec {
    let base = SceneSpec {
        capture,
        laser_origin: laser,
        detector_origin: detector,
        scan: [4, 4],
        bins: 160,
        start_opl: 1.0,
        spp: 64,
        ..SceneSpec::default()
    };
    let x = base.scene().scan.point(aim);
    let through = if capture == "confocal" {
        laser
    } else {
        detector
    };
    let t = (through[2] - PLATE_Z) / through[2];
    let c = [
        through[0] + t * (x.x - through[0]),
        through[1] + t * (x.y - through[1]),
    ];
    SceneSpec {
        objects: vec![
            (square_obj([0.0, 0.1, 1.0], 0.5), 0.8, "lambertian"),
            (
                square_obj([c[0], c[1], PLATE_Z], PLATE_SIDE),
                0.8,
                "lambertian",
            ),
        ],
        ..base
    }
}

/// The scan points whose visible legs the plate blocks (independent geometry).
fn blocked(spec: &SceneSpec, scene: &Scene) -> Vec<bool> {
    let plate = scene.objects[1].mesh.positions[0];
    let c = [plate.x + PLATE_SIDE / 2.0, plate.y + PLATE_SIDE / 2.0];
    (0..scene.num_measurements())
        .map(|m| {
            let (x_l, x_s) = scene.measurement_points(m);
            crosses_plate(spec.laser_origin, x_l.to_array(), c)
                || crosses_plate(spec.detector_origin, x_s.to_array(), c)
        })
        .collect()
}

fn render(scene: &Scene, model: Model) -> Vec<f32> {
    let geom = SceneGeometry::build(scene);
    let opts = RenderOptions {
        model,
        ..RenderOptions::from_scene(scene)
    };
    transport::render(scene, &geom, &opts, None).unwrap().data
}

fn legs_off(scene: &Scene) -> Scene {
    let mut s = scene.clone();
    s.render.visible_legs = false;
    s
}

fn check_blocking(spec: &SceneSpec, what: &str) {
    let scene = spec.scene();
    let blocked = blocked(spec, &scene);
    let n_blocked = blocked.iter().filter(|&&b| b).count();
    assert!(
        (1..blocked.len()).contains(&n_blocked),
        "{what}: the plate should block some scan points, not all: {blocked:?}"
    );
    let bins = scene.film.temporal_bins as usize;
    for model in MODELS {
        let on = render(&scene, model);
        let off = render(&legs_off(&scene), model);
        for (m, &b) in blocked.iter().enumerate() {
            let (on, off) = (&on[m * bins..][..bins], &off[m * bins..][..bins]);
            let total: f32 = off.iter().sum();
            assert!(
                total > 0.0,
                "{what} {model:?}: measurement {m} is dark even unblocked"
            );
            if b {
                assert!(
                    on.iter().all(|&v| v == 0.0),
                    "{what} {model:?}: blocked {m} records light"
                );
            } else {
                assert_eq!(on, off, "{what} {model:?}: clear measurement {m} changed");
            }
        }
    }
}

#[test]
fn a_plate_across_the_laser_beam_darkens_those_confocal_points() {
    let laser = [0.3, -0.4, 1.0];
    check_blocking(&spec("confocal", laser, laser, 5), "laser leg");
}

#[test]
fn a_plate_across_the_detector_view_darkens_those_points() {
    let spec = spec("single", [0.4, 0.3, 0.9], [-0.5, -0.2, 1.1], 9);
    // The plate is not on the laser's line to its spot.
    let scene = spec.scene();
    let c = scene.objects[1].mesh.positions[0];
    let c = [c.x + PLATE_SIDE / 2.0, c.y + PLATE_SIDE / 2.0];
    assert!(!crosses_plate(
        spec.laser_origin,
        scene.laser.target.to_array(),
        c
    ));
    check_blocking(&spec, "detector leg");
}

/// A blocked measurement contributes nothing to gradients: with the adjoint non-zero on
/// the blocked measurements only, every derivative is exactly zero; with the test off it
/// is not.
#[test]
fn blocked_measurements_contribute_no_gradient() {
    let laser = [0.3, -0.4, 1.0];
    let spec = spec("confocal", laser, laser, 5);
    let scene = spec.scene();
    let bins = scene.film.temporal_bins as usize;
    let adjoint: Vec<f32> = blocked(&spec, &scene)
        .iter()
        .flat_map(|&b| std::iter::repeat_n(if b { 1.0 } else { 0.0 }, bins))
        .collect();
    for model in MODELS {
        let grad = |s: &Scene| {
            let geom = SceneGeometry::build(s);
            let opts = RenderOptions {
                model,
                ..RenderOptions::from_scene(s)
            };
            umbra::adjoint::gradient(s, &geom, &opts, &adjoint, None).unwrap()
        };
        let norm = |g: &umbra::adjoint::Gradient| {
            g.vertices
                .iter()
                .flatten()
                .flatten()
                .map(|v| v.abs())
                .sum::<f64>()
                + g.albedo.iter().map(|v| v.abs()).sum::<f64>()
        };
        assert_eq!(norm(&grad(&scene)), 0.0, "{model:?}");
        assert!(norm(&grad(&legs_off(&scene))) > 0.0, "{model:?}");
    }
}
