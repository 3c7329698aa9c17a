//! A render or a gradient split into pieces, as `umbra.distributed` splits it over
//! processes, gives the same bits as the whole: measurement ranges of a render
//! concatenated, gradient chunks computed apart and combined, for single, confocal and
//! exhaustive captures, `tri3` and the Monte Carlo models, boundary terms included.

mod common;

use common::{square_obj, SceneSpec};
use umbra::adjoint::{chunk_count, chunk_measurements, combine, gradient, gradient_chunks};
use umbra::geometry::SceneGeometry;
use umbra::scene::{Model, Scene};
use umbra::transport::{RenderOptions, Renderer};

/// Two squares, the nearer shadowing part of the farther (boundary terms apply), on a
/// 3 x 5 scan (15 measurements; 225 exhaustive).
fn scene(capture: &'static str) -> Scene {
    SceneSpec {
        capture,
        scan: [3, 5],
        bins: 96,
        bin_width: 0.03,
        objects: vec![
            (square_obj([0.05, 0.02, 0.5], 0.2), 0.8, "lambertian"),
            (square_obj([0.1, 0.05, 0.8], 0.4), 0.6, "lambertian"),
        ],
        ..SceneSpec::default()
    }
    .scene()
}

fn options(scene: &Scene, model: Model) -> RenderOptions {
    RenderOptions {
        model,
        spp: 40, // blocks of 32 and a short one
        seed: 7,
        ..RenderOptions::from_scene(scene)
    }
}

#[test]
fn measurement_ranges_concatenate_to_the_render() {
    for capture in ["single", "confocal", "exhaustive"] {
        let s = scene(capture);
        let geom = SceneGeometry::build(&s);
        for model in [Model::Tri3, Model::Mc3, Model::Path] {
            let r = Renderer::new(&s, &geom, &options(&s, model)).unwrap();
            let whole = r.render(None).unwrap().data;
            let n = s.num_measurements();
            let cuts = [0, 1, n / 3, n / 3 + 1, n - 2, n];
            let mut joined = Vec::new();
            for w in cuts.windows(2) {
                joined.extend(r.render_measurements(w[0]..w[1], None).unwrap());
            }
            assert!(
                whole.iter().any(|&v| v > 0.0),
                "{capture} {model:?}: empty render"
            );
            assert!(
                joined
                    .iter()
                    .zip(&whole)
                    .all(|(a, b)| a.to_bits() == b.to_bits())
                    && joined.len() == whole.len(),
                "{capture} {model:?}: the pieces differ from the whole"
            );
        }
    }
}

#[test]
fn a_range_outside_the_scene_is_refused() {
    let s = scene("confocal");
    let geom = SceneGeometry::build(&s);
    let r = Renderer::new(&s, &geom, &options(&s, Model::Tri3)).unwrap();
    let e = r.render_measurements(10..16, None).unwrap_err().to_string();
    assert!(e.contains("10..16") && e.contains("0..15"), "{e}");
}

#[test]
fn gradient_chunks_computed_apart_combine_to_the_gradient() {
    for capture in ["single", "confocal", "exhaustive"] {
        let s = scene(capture);
        let geom = SceneGeometry::build(&s);
        let bins = s.film.temporal_bins as usize;
        let n = s.num_measurements();
        let adjoint: Vec<f32> = (0..n * bins)
            .map(|i| ((i * 37 % 101) as f32 / 50.0 - 1.0) * 1e-3)
            .collect();
        for model in [Model::Tri3, Model::Path] {
            let opts = options(&s, model);
            let whole = gradient(&s, &geom, &opts, &adjoint, None).unwrap();
            assert!(
                whole.boundary,
                "{capture} {model:?}: boundary terms expected"
            );
            let chunks = chunk_count(n);
            // Three "workers": chunks [0, 1), [1, k), [k, chunks), each given its rows only.
            let k = chunks / 2 + 1;
            let mut parts = Vec::new();
            for r in [0..1, 1..k, k..chunks] {
                let (a, b) = (
                    chunk_measurements(r.start, n).start,
                    chunk_measurements(r.end - 1, n).end,
                );
                let rows = &adjoint[a * bins..b * bins];
                parts.extend(gradient_chunks(&s, &geom, &opts, rows, r, None).unwrap());
            }
            parts.reverse(); // arrival order does not matter
            let joined = combine(&s, &geom, &opts, parts).unwrap();
            let bits = |g: &umbra::adjoint::Gradient| {
                let mut v: Vec<u64> = g
                    .vertices
                    .iter()
                    .flatten()
                    .flatten()
                    .map(|x| x.to_bits())
                    .collect();
                v.extend(g.albedo.iter().map(|x| x.to_bits()));
                v
            };
            assert!(
                bits(&whole).iter().any(|&b| b != 0),
                "{capture} {model:?}: zero gradient"
            );
            assert_eq!(bits(&joined), bits(&whole), "{capture} {model:?}");
            assert_eq!(joined.boundary_nodes, whole.boundary_nodes);
        }
    }
}

#[test]
fn missing_or_repeated_chunks_are_refused() {
    let s = scene("confocal");
    let geom = SceneGeometry::build(&s);
    let opts = options(&s, Model::Tri3);
    let bins = s.film.temporal_bins as usize;
    let n = s.num_measurements();
    let adjoint = vec![1e-3f32; n * bins];
    let mut parts = gradient_chunks(&s, &geom, &opts, &adjoint, 0..chunk_count(n), None).unwrap();
    let last = parts.pop().unwrap();
    let e = combine(&s, &geom, &opts, parts.clone())
        .unwrap_err()
        .to_string();
    assert!(e.contains("each once"), "{e}");
    parts.push(parts[0].clone());
    let e = combine(&s, &geom, &opts, parts).unwrap_err().to_string();
    assert!(e.contains("each once"), "{e}");
    let e = gradient_chunks(&s, &geom, &opts, &adjoint, 0..1, None)
        .unwrap_err()
        .to_string();
    assert!(e.contains("adjoint has"), "{e}");
    drop(last);
}
