//! Russian roulette before `rr_bounces` (`render.rr_early_survival`, `path`): paths go on
//! past each vertex with a constant probability `q`, their throughput divided by it. It
//! must not move the expectation (the arc, which lights itself, multi-bounce, against
//! `q = 1` over seeds), must leave the three-bounce term's samples alone, and a value
//! outside `(0, 1]` is refused naming the setting.

mod common;

use std::path::Path;
use umbra::geometry::SceneGeometry;
use umbra::scene::{EarlySurvival, Model, Scene};
use umbra::transport::gate::{Overrides, Pass};
use umbra::transport::roulette::{self, RoulettePilot, MIN_PILOT_SPP};
use umbra::transport::{RenderOptions, Renderer};

fn arc() -> Scene {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/validation/scenes/arc.xml");
    let d: Vec<(String, String)> = [
        ("max_depth", "6"),
        ("filter_bounces", "-1"),
        ("scan_x", "4"),
        ("scan_y", "4"),
    ]
    .iter()
    .map(|(a, b)| (a.to_string(), b.to_string()))
    .collect();
    let mut s = Scene::load_with_defines(&p, &d).unwrap_or_else(|e| panic!("{e}"));
    s.render.techniques.bsdf_sampling = true;
    s
}

/// `(mean, standard error)` of the energy of paths of four or more bounces (the film's
/// total minus the three-bounce term, which the roulette does not touch) over `seeds`.
fn longer_paths_energy(s: &Scene, spp: u32, seeds: u64) -> (f64, f64) {
    let mut three = s.clone();
    three.render.filter_bounces = Some(3);
    let e: Vec<f64> = (0..seeds)
        .map(|k| {
            let all: f64 = common::totals(&common::render(s, Model::Path, spp, 100 + k))
                .iter()
                .sum();
            let t3: f64 = common::totals(&common::render(&three, Model::Path, spp, 100 + k))
                .iter()
                .sum();
            all - t3
        })
        .collect();
    let n = seeds as f64;
    let m = e.iter().sum::<f64>() / n;
    let var = e.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (var / n).sqrt())
}

#[test]
fn roulette_before_rr_bounces_keeps_the_expectation() {
    let mut full = arc();
    full.render.rr_early_survival = EarlySurvival::Fixed(1.0);
    let mut roulette = full.clone();
    roulette.render.rr_early_survival = EarlySurvival::Fixed(0.35);
    let (m1, e1) = longer_paths_energy(&full, 1024, 8);
    let (mq, eq) = longer_paths_energy(&roulette, 1024, 8);
    let z = (mq - m1) / (e1 * e1 + eq * eq).sqrt();
    println!("longer paths' energy: q = 1 {m1:.5e} ± {e1:.1e}, q = 0.35 {mq:.5e} ± {eq:.1e}, z = {z:+.2}");
    // Not vacuous: the longer paths carry energy, and the roulette adds noise to them.
    assert!(m1 > 20.0 * e1, "no interreflection signal: {m1} ± {e1}");
    assert!(eq > e1, "the roulette added no noise: {eq} vs {e1}");
    assert!(z.abs() < 4.0, "z = {z}");
}

#[test]
fn the_three_bounce_term_is_recorded_before_the_roulette() {
    // Three-bounce contributions of the same samples are the same bits: NEE at the first
    // hidden vertex comes before the roulette there.
    let mut s = arc();
    s.render.filter_bounces = Some(3);
    s.render.max_bounces = 6;
    s.render.rr_early_survival = EarlySurvival::Fixed(1.0);
    let a = common::render(&s, Model::Path, 256, 9).data;
    s.render.rr_early_survival = EarlySurvival::Fixed(0.2);
    let b = common::render(&s, Model::Path, 256, 9).data;
    assert!(a.iter().any(|&v| v > 0.0));
    assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
}

#[test]
fn a_survival_outside_zero_one_is_refused_naming_the_setting() {
    let toml = |q: &str| {
        common::SceneSpec {
            render_extra: vec![format!("rr_early_survival = {q}")],
            ..Default::default()
        }
        .try_scene()
    };
    let q = |t: &str| toml(t).unwrap().render.rr_early_survival;
    assert_eq!(q("0.5"), EarlySurvival::Fixed(0.5));
    assert_eq!(q("\"auto\""), EarlySurvival::Auto);
    let default = common::SceneSpec::default()
        .scene()
        .render
        .rr_early_survival;
    assert_eq!(default, EarlySurvival::Auto);
    for bad in ["0.0", "1.5", "-0.2", "nan", "\"sometimes\""] {
        let e = toml(bad).err().unwrap_or_else(|| panic!("{bad} accepted"));
        assert!(
            e.to_string().contains("render.rr_early_survival"),
            "{bad}: {e}"
        );
    }
    let mut s = arc();
    for bad in ["0", "2", "NaN", "often"] {
        let o = Overrides {
            rr_early_survival: Some(bad.into()),
            ..Default::default()
        };
        let e = o
            .apply(&mut s)
            .err()
            .unwrap_or_else(|| panic!("{bad} accepted"));
        assert!(e.to_string().contains("rr_early_survival"), "{bad}: {e}");
    }
}

/// What the pilot picks for `scene` at `spp` (`None`: it did not run).
fn pilot(scene: &Scene, spp: u32) -> Option<RoulettePilot> {
    let geom = SceneGeometry::build(scene);
    let opts = RenderOptions {
        model: Model::Path,
        spp,
        ..RenderOptions::from_scene(scene)
    };
    Renderer::prepare(scene, &geom, &opts, Pass::Render)
        .unwrap()
        .roulette
}

#[test]
fn the_pilot_plays_the_roulette_where_it_pays_and_not_where_it_loses() {
    // The arc (16 x 16, confocal): the longer paths carry little of the error; measured,
    // survival 0.25 reaches equal error 1.5x sooner than none.
    let mut s = arc();
    (s.scan.nx, s.scan.ny) = (16, 16);
    s.capture = umbra::scene::CaptureType::Confocal;
    let p = pilot(&s, 8192).expect("the pilot runs at 8192 spp");
    println!("arc: {p:?}");
    assert!(p.survival < 0.5 && p.gain > 1.2, "{p:?}");
    // The concave corner of the accuracy chart: four and more bounces carry most of the
    // error, and any roulette loses (0.7: 1.3x later to equal error, measured).
    let corner = umbra::bench::accuracy::scene("corner").unwrap();
    for spp in [4096, 16384] {
        let p = pilot(&corner, spp).expect("the pilot runs");
        println!("corner at {spp} spp: {p:?}");
        assert_eq!(p.survival, 1.0, "{p:?}");
    }
    // Too few samples to pay for a pilot, or no vertex before rr_bounces: none.
    assert!(pilot(&s, 8 * MIN_PILOT_SPP - 1).is_none());
    let mut early = s.clone();
    early.render.rr_bounces = 3;
    assert!(pilot(&early, 8192).is_none());
    // The planar T letter: every walk ends at its first hidden vertex (the paths back off
    // the wall land past the film), so there is nothing to thin and no pilot.
    let t = Path::new(env!("CARGO_MANIFEST_DIR")).join("python/validation/scenes/T.xml");
    let d = [("max_depth", "6"), ("filter_bounces", "-1")].map(|(a, b)| (a.into(), b.into()));
    let mut t = Scene::load_with_defines(&t, &d).unwrap();
    t.render.techniques.bsdf_sampling = true;
    assert!(pilot(&t, 8192).is_none());
    // ... unless its film reaches the paths that come back (4 d_w = 3.6 m).
    t.film.temporal_bins *= 2;
    assert!(pilot(&t, 8192).is_some());
    // A fixed survival is not second-guessed.
    s.render.rr_early_survival = EarlySurvival::Fixed(1.0);
    assert!(pilot(&s, 8192).is_none());
}

/// `roulette::resolved`: the survival the pilot picks, fixed in the scene, renders the
/// same bits as `auto` (so `umbra grad --target`, a fit's evaluation and Ray shards run
/// the pilot once); a fixed survival and models without the roulette stay as they are.
#[test]
fn a_resolved_survival_renders_the_bits_of_auto() {
    let s = arc();
    let geom = SceneGeometry::build(&s);
    let opts = RenderOptions {
        model: Model::Path,
        spp: 1024,
        ..RenderOptions::from_scene(&s)
    };
    let fixed = roulette::resolved(&s, &geom, &opts, Pass::Gradient).unwrap();
    let picked = pilot(&s, 1024)
        .expect("the pilot runs at 1024 spp")
        .survival;
    assert_eq!(fixed.render.rr_early_survival, EarlySurvival::Fixed(picked));
    assert!(picked < 1.0, "the arc plays the roulette: {picked}");
    let render = |scene: &Scene| {
        Renderer::new(scene, &geom, &opts)
            .unwrap()
            .render(None)
            .unwrap()
    };
    let (a, b) = (render(&s), render(&fixed));
    assert!(a
        .data
        .iter()
        .zip(&b.data)
        .all(|(x, y)| x.to_bits() == y.to_bits()));
    assert_eq!(
        roulette::resolved(&fixed, &geom, &opts, Pass::Render)
            .unwrap()
            .render
            .rr_early_survival,
        EarlySurvival::Fixed(picked)
    );
    let mc3 = RenderOptions {
        model: Model::Mc3,
        ..opts
    };
    let untouched = roulette::resolved(&s, &geom, &mc3, Pass::Render).unwrap();
    assert_eq!(untouched.render.rr_early_survival, EarlySurvival::Auto);
}
