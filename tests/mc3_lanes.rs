//! `mc3`'s primal pass eight samples at a time (`transport::mc3_lanes`) hands the sink
//! the contributions of the scalar `mc3::sample`, bit for bit and in the same order: the
//! adjoint pass, which replays samples with the scalar routine, depends on it. Checked
//! on the validation scenes (planar T letter, concave arc; single and confocal), the
//! default scene, and builder scenes that reach the lane code's other branches: a
//! finite laser spot, two-sided surfaces, more triangles than the counted pick handles,
//! a Gaussian film window cut inside the returns, and a range that is not a multiple of
//! eight. Both shadow-test routes are covered: the lane test of which rays need tracing
//! (planar and convex objects: T, the default scene, the square, the sphere) and the
//! per-lane scalar test (objects that shadow themselves: the arc, the wavy sheet).

mod common;

use common::SceneSpec;
use glam::Vec3;
use std::path::Path;
use umbra::film::Film;
use umbra::geometry::shapes::{icosphere, wavy_sheet};
use umbra::geometry::SceneGeometry;
use umbra::rng::StreamSeeds;
use umbra::scene::Scene;
use umbra::transport::{mc3, mc3_lanes, Contribution, MeasurementCtx, Sink};

/// Every contribution as bits: (OPL, weight, bounces).
#[derive(Default)]
struct Record(Vec<(u32, u32, u32)>);

impl Sink for Record {
    fn add(&mut self, c: &Contribution) {
        self.0
            .push((c.opl.to_bits(), c.weight.to_bits(), c.bounces));
    }
}

/// Scalar and lane passes over `range` of every measurement; returns the number of
/// contributions compared.
fn same_contributions(name: &str, scene: &Scene, range: std::ops::Range<u32>) -> usize {
    let geom = SceneGeometry::build(scene);
    let film = Film::new(&scene.film);
    let mut total = 0;
    for m in 0..scene.num_measurements() {
        let ctx = MeasurementCtx::new(scene, &geom, &film, m);
        let seeds = StreamSeeds::new(11, m as u64);
        let (mut scalar, mut lanes) = (Record::default(), Record::default());
        for i in range.clone() {
            mc3::sample(&ctx, &mut seeds.sampler(i), &mut scalar);
        }
        mc3_lanes::run(&ctx, &seeds, range.clone(), &mut lanes);
        assert_eq!(scalar.0.len(), lanes.0.len(), "{name}, measurement {m}");
        for (j, (s, l)) in scalar.0.iter().zip(&lanes.0).enumerate() {
            assert_eq!(s, l, "{name}, measurement {m}, contribution {j}");
        }
        total += scalar.0.len();
    }
    total
}

fn xml(name: &str, defines: &[(&str, &str)]) -> Scene {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("python/validation/scenes")
        .join(name);
    let defines: Vec<(String, String)> = defines
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    Scene::load_with_defines(&p, &defines).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn validation_scenes_give_the_scalar_contributions() {
    for (name, defines) in [
        ("T.xml", vec![]),
        ("T.xml", vec![("capture_type", "confocal")]),
        ("arc.xml", vec![]),
        ("arc.xml", vec![("capture_type", "confocal")]),
    ] {
        let scene = xml(name, &defines);
        let self_shadowing = !SceneGeometry::build(&scene).blockers_everywhere_empty();
        assert_eq!(self_shadowing, name == "arc.xml", "{name}: the route tested");
        let n = same_contributions(name, &scene, 0..256);
        assert!(n > 1000, "{name} {defines:?}: only {n} contributions");
    }
}

#[test]
fn default_scene_gives_the_scalar_contributions() {
    let scene = umbra::scene::default::default_scene().unwrap();
    assert!(same_contributions("default", &scene, 0..64) > 1000);
}

#[test]
fn every_lane_branch_gives_the_scalar_contributions() {
    let with_mesh = |spec: &SceneSpec, mesh| {
        let mut s = spec.scene();
        s.objects[0].mesh = mesh;
        s
    };
    let spot = SceneSpec {
        spot_radius: 0.05,
        ..SceneSpec::default()
    };
    let two_sided = SceneSpec {
        two_sided: true,
        ..SceneSpec::default()
    };
    // A window that cuts the returns: lanes outside the film are dropped.
    let cut = SceneSpec {
        start_opl: 1.3,
        bins: 20,
        ..SceneSpec::default()
    };
    let cases = [
        ("finite spot", spot.scene()),
        ("two-sided sheet", {
            with_mesh(
                &two_sided,
                wavy_sheet(Vec3::new(0.0, 0.0, 0.6), 0.5, 6, 0.08, 0.3),
            )
        }),
        ("sphere, 320 triangles", {
            with_mesh(
                &SceneSpec::default(),
                icosphere(Vec3::new(0.0, 0.0, 0.7), 0.2, 2),
            )
        }),
        ("film cut", cut.scene()),
    ];
    for (name, scene) in &cases {
        assert!(
            same_contributions(name, scene, 3..3 + 1021) > 1000,
            "{name}: too few contributions to compare"
        );
    }
}
