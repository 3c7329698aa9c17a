//! `path` stops a walk once everything it could still record lands past the film's end
//! (`MeasurementCtx::past_film`): the rest of a path is at least `|x − x_l| − r` long,
//! and from a wall point at least the bounce off the hidden geometry's nearest plane. If
//! that bound were too large, contributions inside the window would be lost. Here the
//! same scene is rendered with its film and with a film four times as long (same start,
//! same bins): the long film's first bins must be the short film's, bit for bit, while the
//! long film records light past the short one's end (paths the bound does cut).

mod common;

use common::SceneSpec;
use glam::Vec3;
use std::path::Path;
use umbra::geometry::shapes::icosphere;
use umbra::scene::{CaptureType, Model, Scene};

/// The arc of the cross-validation suite (a concave sheet that lights itself; paths that
/// bounce back off the wall end past its film), multi-bounce, BSDF + hidden-geometry
/// sampling under MIS.
fn arc(defines: &[(&str, &str)]) -> Scene {
    xml("arc.xml", 4, defines)
}

/// A cross-validation scene (`arc.xml`, `T.xml`), multi-bounce, MIS.
fn xml(name: &str, scan: u32, defines: &[(&str, &str)]) -> Scene {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("python/validation/scenes")
        .join(name);
    let mut d: Vec<(String, String)> = [("max_depth", "6"), ("filter_bounces", "-1")]
        .iter()
        .chain(defines)
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    d.extend([
        ("scan_x".into(), scan.to_string()),
        ("scan_y".into(), scan.to_string()),
    ]);
    let mut s = Scene::load_with_defines(&p, &d).unwrap_or_else(|e| panic!("{e}"));
    s.render.techniques.bsdf_sampling = true;
    s
}

/// Renders `scene` and the same with a film four times as long; asserts the short film is
/// the long one's first bins bit for bit, and returns the share of the long film's energy
/// past the short film's end.
fn same_bins_and_energy_past(scene: &Scene, spp: u32) -> f64 {
    let bins = scene.film.temporal_bins as usize;
    let mut long = scene.clone();
    long.film.temporal_bins *= 4;
    let short = common::render(scene, Model::Path, spp, 3);
    let long_t = common::render(&long, Model::Path, spp, 3);
    let (mut past, mut total) = (0.0f64, 0.0f64);
    for (m, (a, b)) in short
        .data
        .chunks(bins)
        .zip(long_t.data.chunks(4 * bins))
        .enumerate()
    {
        for (k, (x, y)) in a.iter().zip(&b[..bins]).enumerate() {
            assert_eq!(
                x.to_bits(),
                y.to_bits(),
                "measurement {m}, bin {k}: {x} vs {y}"
            );
        }
        past += b[bins..].iter().map(|&v| v as f64).sum::<f64>();
        total += b.iter().map(|&v| v as f64).sum::<f64>();
    }
    assert!(total > 0.0);
    past / total
}

#[test]
fn stopping_walks_past_the_film_keeps_every_bin_of_it() {
    for capture in ["single", "confocal"] {
        let s = arc(&[("capture_type", capture)]);
        let past = same_bins_and_energy_past(&s, 256);
        // The long film sees the paths that come back off the wall: the cut is not empty.
        assert!(
            past > 1e-3,
            "{capture}: only {past:.2e} of the energy past the film"
        );
        // The planar letter on its whole 16 x 16 scan at 1024 spp, where every walk from
        // the letter ends at once by the wall-only bound `h + 2 d_w`. Before the letter's
        // continuations were traced against the wall alone (`path_step::Onward`), that
        // bound cut in-film paths off coplanar neighbours (rounding, 1e-8 of a bin each),
        // which showed at this size.
        let t = xml("T.xml", 16, &[("capture_type", capture)]);
        let past = same_bins_and_energy_past(&t, 1024);
        assert!(
            past > 1e-4,
            "T {capture}: only {past:.2e} of the energy past the film"
        );
    }
}

#[test]
fn the_bound_holds_with_a_finite_spot_and_the_visible_legs_counted() {
    let mut s = arc(&[]);
    assert!(matches!(s.capture, CaptureType::Single));
    s.laser.spot_radius = 0.05;
    s.account_first_and_last_bounces = true;
    // The legs add about 1.2 m (laser) and 0.9 m (detector): the same window, later.
    s.film.start_opl += 2.0;
    let past = same_bins_and_energy_past(&s, 128);
    assert!(past > 1e-3, "only {past:.2e} of the energy past the film");
}

/// Objects every vertex of which continues to the wall only, or nowhere
/// (`path_step::Onward`): a convex sphere, and a plate seen from both sides. Their walks
/// end by the bound `h + 2 d_w` (to the wall, out to the hidden geometry and back), with
/// a film whose window holds some of the paths that come back off the wall and not
/// others.
#[test]
fn the_wall_only_bound_keeps_every_bin_of_convex_and_planar_objects() {
    for two_sided in [false, true] {
        let spec = SceneSpec {
            model: "path",
            two_sided,
            spp: 256,
            render_extra: vec!["max_bounces = 6".into()],
            ..SceneSpec::default()
        };
        let plate = spec.scene();
        let mut sphere = spec.scene();
        sphere.objects[0].mesh = icosphere(Vec3::new(0.05, 0.0, 0.5), 0.15, 1);
        for (name, s) in [("plate", plate), ("sphere", sphere)] {
            assert!(s.render.techniques.bsdf_sampling);
            let past = same_bins_and_energy_past(&s, 256);
            assert!(
                past > 1e-4,
                "{name} (two-sided {two_sided}): only {past:.2e} of the energy past the film"
            );
        }
    }
}
