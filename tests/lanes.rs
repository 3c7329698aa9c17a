//! The eight-wide primal passes hand the sink the contributions of the scalar sampling
//! routines, bit for bit and in the same order, with the same derivatives in the
//! adjoint pass: `transport::mc3_lanes` those of `mc3::sample`, `transport::path_lanes`
//! (each path's first step in lanes) those of `path::sample`. Checked on the validation scenes (planar T letter, concave arc; single
//! and confocal), the default scene, and builder scenes that reach the lane code's other
//! branches: a finite laser spot, two-sided surfaces, more triangles than the counted
//! pick handles, a Gaussian film window cut inside the returns, and a range that is not
//! a multiple of eight; for `path` also BSDF sampling (lanes it draws go scalar), the
//! wall in hidden-geometry sampling (lanes that pick it go scalar), and early Russian
//! roulette. Both shadow-test routes are covered: the lane test of which rays need
//! tracing (planar and convex objects: T, the default scene, the square, the sphere)
//! and the per-lane scalar test (objects that shadow themselves: the arc, the wavy
//! sheet).

mod common;

use common::SceneSpec;
use glam::Vec3;
use std::path::Path;
use umbra::film::Film;
use umbra::geometry::shapes::{icosphere, wavy_sheet};
use umbra::geometry::SceneGeometry;
use umbra::rng::StreamSeeds;
use umbra::scene::Model;
use umbra::scene::Scene;
use umbra::transport::path::{self, PathScratch};
use umbra::transport::{
    mc3, mc3_lanes, path_lanes, Contribution, HiddenGrad, MeasurementCtx, Sink,
};

/// Every contribution as bits (OPL, weight, bounces), and in an adjoint pass
/// (`ADJOINT`) its derivatives (each triangle's index, weight and OPL derivatives).
#[derive(Default)]
struct Record<const ADJOINT: bool>(Vec<Vec<u32>>);

impl<const A: bool> Sink for Record<A> {
    const ADJOINT: bool = A;

    fn add(&mut self, c: &Contribution) {
        self.0
            .push(vec![c.opl.to_bits(), c.weight.to_bits(), c.bounces]);
    }

    fn add_grad(&mut self, c: &Contribution, grads: &[HiddenGrad]) {
        self.add(c);
        let last = self.0.last_mut().unwrap();
        for g in grads {
            last.push(g.flat);
            last.extend(g.weight.iter().chain(&g.opl).map(|x| x.to_bits()));
        }
    }
}

/// Scalar and lane passes of `model` over `range` of every measurement, primal and
/// adjoint; returns the number of contributions compared (primal).
fn same_contributions(
    name: &str,
    model: Model,
    scene: &Scene,
    range: std::ops::Range<u32>,
) -> usize {
    let n = compare::<false>(name, model, scene, range.clone());
    assert_eq!(compare::<true>(name, model, scene, range), n, "{name}");
    n
}

fn compare<const ADJOINT: bool>(
    name: &str,
    model: Model,
    scene: &Scene,
    range: std::ops::Range<u32>,
) -> usize {
    let geom = SceneGeometry::build(scene);
    let film = Film::new(&scene.film);
    let mut scratch = PathScratch::default();
    let mut total = 0;
    for m in 0..scene.num_measurements() {
        let ctx = MeasurementCtx::new(scene, &geom, &film, m);
        let seeds = StreamSeeds::new(11, m as u64);
        let mut scalar = Record::<ADJOINT>::default();
        let mut lanes = Record::<ADJOINT>::default();
        for i in range.clone() {
            let mut sampler = seeds.sampler(i);
            match model {
                Model::Mc3 => mc3::sample(&ctx, &mut sampler, &mut scalar),
                _ => path::sample(&ctx, &mut sampler, &mut scratch, &mut scalar),
            }
        }
        match model {
            Model::Mc3 => mc3_lanes::run(&ctx, &seeds, range.clone(), &mut lanes),
            _ => path_lanes::run(&ctx, &seeds, range.clone(), &mut scratch, &mut lanes),
        }
        let what = if ADJOINT { "adjoint" } else { "primal" };
        assert_eq!(
            scalar.0.len(),
            lanes.0.len(),
            "{name} {model:?} {what}, measurement {m}"
        );
        for (j, (s, l)) in scalar.0.iter().zip(&lanes.0).enumerate() {
            assert_eq!(
                s, l,
                "{name} {model:?} {what}, measurement {m}, contribution {j}"
            );
        }
        total += scalar.0.len();
    }
    total
}

/// `scene` with BSDF sampling on (MIS with hidden-geometry sampling).
fn with_bsdf(mut scene: Scene) -> Scene {
    scene.render.techniques.bsdf_sampling = true;
    scene
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
    let mb = [("max_depth", "6"), ("filter_bounces", "-1")];
    for (name, confocal) in [
        ("T.xml", false),
        ("T.xml", true),
        ("arc.xml", false),
        ("arc.xml", true),
    ] {
        let mut defines = vec![];
        if confocal {
            defines.push(("capture_type", "confocal"));
        }
        let scene = xml(name, &defines);
        let self_shadowing = !SceneGeometry::build(&scene).blockers_everywhere_empty();
        assert_eq!(
            self_shadowing,
            name == "arc.xml",
            "{name}: the route tested"
        );
        let n = same_contributions(name, Model::Mc3, &scene, 0..256);
        assert!(n > 1000, "{name} {defines:?}: only {n} contributions");
        defines.extend(mb);
        let scene = xml(name, &defines);
        let n = same_contributions(name, Model::Path, &scene, 0..64);
        assert!(n > 1000, "{name} {defines:?}: only {n} path contributions");
        let n = same_contributions(name, Model::Path, &with_bsdf(scene), 0..64);
        assert!(
            n > 1000,
            "{name} {defines:?} MIS: only {n} path contributions"
        );
    }
}

#[test]
fn default_scene_gives_the_scalar_contributions() {
    let scene = umbra::scene::default::default_scene().unwrap();
    assert!(same_contributions("default", Model::Mc3, &scene, 0..64) > 1000);
    assert!(same_contributions("default", Model::Path, &scene, 0..16) > 1000);
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
    let sheet = with_mesh(
        &two_sided,
        wavy_sheet(Vec3::new(0.0, 0.0, 0.6), 0.5, 6, 0.08, 0.3),
    );
    let sphere = with_mesh(
        &SceneSpec::default(),
        icosphere(Vec3::new(0.0, 0.0, 0.7), 0.2, 2),
    );
    let cases = [
        ("finite spot", spot.scene()),
        ("two-sided sheet", sheet.clone()),
        ("sphere, 320 triangles", sphere),
        ("film cut", cut.scene()),
    ];
    for (name, scene) in &cases {
        assert!(
            same_contributions(name, Model::Mc3, scene, 3..3 + 1021) > 1000,
            "{name}: too few contributions to compare"
        );
    }
    // `path`: the same scenes multi-bounce with MIS, then the sheet with the wall in
    // hidden-geometry sampling, BSDF sampling alone, and Russian roulette from the start.
    let mut path_cases: Vec<(&str, Scene)> = cases
        .iter()
        .map(|(name, s)| {
            let mut s = with_bsdf(s.clone());
            s.render.max_bounces = 5;
            (*name, s)
        })
        .collect();
    let mut wall = sheet.clone();
    wall.render.max_bounces = 6;
    wall.render.techniques.hidden_geometry_includes_wall = true;
    let mut bsdf_only = with_bsdf(sheet.clone());
    bsdf_only.render.techniques.hidden_geometry_sampling = false;
    let mut rr = with_bsdf(sheet);
    (rr.render.max_bounces, rr.render.rr_bounces) = (8, 2);
    path_cases.extend([
        ("sheet, wall sampled", wall),
        ("sheet, BSDF only", bsdf_only),
        ("sheet, Russian roulette", rr),
    ]);
    for (name, scene) in &path_cases {
        let n = same_contributions(name, Model::Path, scene, 3..3 + 1021);
        assert!(
            n > 800,
            "{name}: too few path contributions ({n}) to compare"
        );
    }
}
