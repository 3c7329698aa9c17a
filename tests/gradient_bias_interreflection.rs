//! Vertex gradients of four-bounce transport (two hidden vertices) where something hides
//! something: `path` with `filter_bounces = 4`, the interior derivative alone and with the
//! visibility boundary terms, both against an independent reference. The four-bounce
//! counterpart of `tests/gradient_bias.rs`.
//!
//! The reference ([`common::exact_interreflection`]) integrates the four-bounce
//! measurement by nested quadrature over exactly clipped visible domains (`y1` lit from
//! the sensor point; `y2` seen from `y1` and lit from the laser spot): deterministic and
//! smooth in the vertices, so its central differences use a small step. Its own error is
//! stated (the change when both quadratures are refined and when the step is doubled),
//! and its primal is checked against `path`'s render first. Both sides differentiate the
//! same linear functional `⟨λ, H⟩`, `λ` fixed: the adjoint of an L2 loss against the scene
//! moved 2 cm away from the wall, both rendered by `path` with `filter_bounces = 4`.
//!
//! The scene: a back plate (z = 0.9), a side plate at x = 0.15 (z 0.55–0.8, facing the
//! back plate's right part across a 10 cm gap) and a small tilted occluder floating in
//! the corner between them (z ≈ 0.72), all two-sided, albedo 0.7, confocal 4 x 4 scan.
//! The occluder blocks part of the back ↔ side interreflection (`V(y1, y2)`) and part of
//! the wall legs to the back plate; the side plate shadows the back plate from the scan
//! points beyond x = 0.15. The side plate does not touch the back plate: at a shared edge
//! `G(y1, y2)` grows like `1/|y1-y2|²`, which a fixed quadrature does not resolve and
//! area sampling estimates with infinite variance. No edge of the occluder is parallel to
//! a plate's (parallel edges put kinks in the inner integral that move with the vertices).

mod common;
use common::exact_interreflection::{interreflection_integral, three_bounce_integral};
use common::exact_shadows::lit_integral;
use common::*;
use std::sync::OnceLock;
use std::time::Instant;
use umbra::adjoint::{gradient, Loss};
use umbra::geometry::SceneGeometry;
use umbra::scene::{Model, Scene};
use umbra::transport::RenderOptions;

const BACK: &str =
    "v -0.15 -0.15 0.9\nv 0.15 -0.15 0.9\nv 0.15 0.15 0.9\nv -0.15 0.15 0.9\nf 1 4 3 2\n";
const SIDE: &str =
    "v 0.15 -0.15 0.55\nv 0.15 0.15 0.55\nv 0.15 0.15 0.8\nv 0.15 -0.15 0.8\nf 1 2 3 4\n";
/// A parallelogram tilted about both axes, its edges turned ~25° from the plates'.
const OCCLUDER: &str = "v 0.021 -0.065 0.716\nv 0.105 -0.029 0.732\nv 0.069 0.055 0.724\n\
                        v -0.015 0.019 0.708\nf 1 4 3 2\n";

/// Quadrature orders of the reference (`n²` sub-triangles per fan triangle for `y1`,
/// `y2`), and the refined ones its error is measured against.
const ORDERS: (usize, usize) = (8, 4);
const REFINED: (usize, usize) = (12, 6);

fn spec(render: &[&str]) -> SceneSpec {
    SceneSpec {
        scan_size: 0.9,
        start_opl: 0.9,
        two_sided: true,
        objects: [BACK, SIDE, OCCLUDER]
            .iter()
            .map(|o| (o.to_string(), 0.7, "lambertian"))
            .collect(),
        model: "path",
        render_extra: render.iter().map(|s| s.to_string()).collect(),
        ..SceneSpec::default()
    }
}

fn four_bounce(extra: &[&str]) -> Scene {
    let mut lines = vec!["filter_bounces = 4"];
    lines.extend_from_slice(extra);
    spec(&lines).scene()
}

/// The moved scene's four-bounce render minus this one's, times 2: a fixed adjoint
/// (computed once for every test here).
fn fixed_adjoint() -> &'static [f32] {
    static LAMBDA: OnceLock<Vec<f32>> = OnceLock::new();
    LAMBDA.get_or_init(|| {
        let s = four_bounce(&[]);
        let mut moved = s.clone();
        for o in &mut moved.objects {
            o.mesh.positions.iter_mut().for_each(|p| p.z += 0.02);
        }
        let h = common::render(&s, Model::Path, 1 << 14, 7);
        let t = common::render(&moved, Model::Path, 1 << 14, 8);
        Loss::L2
            .evaluate(&h.data, &t.data, s.film.temporal_bins as usize)
            .unwrap()
            .1
    })
}

fn mean_se(v: &[f64]) -> (f64, f64) {
    let k = v.len() as f64;
    let mean = v.iter().sum::<f64>() / k;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (k - 1.0);
    (mean, (var / k).sqrt())
}

/// The reference's primal against `path`'s render: `⟨λ, H⟩` and the total `⟨1, H⟩`
/// (which checks the constant without the adjoint's signs), mean over seeds, in the
/// confocal scan and in a single capture (fixed laser spot: no `y1 ↔ y2` symmetry); and
/// the three-bounce integral by this reference's parts against `exact_shadows`'.
#[test]
fn reference_primal_matches_path() {
    let lambda = fixed_adjoint();
    let ones = vec![1.0f32; lambda.len()];
    for capture in ["confocal", "single"] {
        let s = SceneSpec {
            capture,
            ..spec(&["filter_bounces = 4"])
        }
        .scene();
        let t = Instant::now();
        let (j, j1) = (
            interreflection_integral(&s, lambda, ORDERS.0, ORDERS.1),
            interreflection_integral(&s, &ones, ORDERS.0, ORDERS.1),
        );
        let t_ref = t.elapsed();
        let (spp, seeds) = (1 << 17, 8);
        let t = Instant::now();
        let (mut dots, mut totals) = (Vec::new(), Vec::new());
        for seed in 0..seeds {
            let h = common::render(&s, Model::Path, spp, 100 + seed);
            let dot = |w: &[f32]| {
                h.data
                    .iter()
                    .zip(w)
                    .map(|(&a, &b)| a as f64 * b as f64)
                    .sum()
            };
            dots.push(dot(lambda));
            totals.push(dot(&ones));
        }
        let t_mc = t.elapsed();
        for (name, reference, mc) in [("<λ, H>", j, dots), ("<1, H>", j1, totals)] {
            let (m, se) = mean_se(&mc);
            let rel = (m - reference) / reference.abs();
            println!(
                "four-bounce {name}, {capture}: reference {reference:.6e}, path {m:.6e} ± \
                 {se:.1e} ({:+.3} % ± {:.3} %)",
                100.0 * rel,
                100.0 * se / reference.abs()
            );
            assert!(
                rel.abs() < 0.002 + 3.0 * se / reference.abs(),
                "{name}, {capture}: the reference's primal is off"
            );
        }
        println!(
            "({capture}: reference {t_ref:.1?} for both, path {seeds} x {spp} spp {t_mc:.1?})"
        );
    }
    // The same functional on three bounces, by this reference's parts and by
    // exact_shadows': the same rule on the same polygons, so they agree to rounding.
    let s3 = spec(&[]).scene();
    let (a, b) = (
        lit_integral(&s3, lambda, 24),
        three_bounce_integral(&s3, lambda, 24),
    );
    println!("three-bounce: exact_shadows {a:.9e}, this reference's parts {b:.9e}");
    assert!((a - b).abs() < 1e-6 * a.abs());
}

/// Central difference of the reference at step `h` and quadrature orders `n`.
fn reference_fd(
    s: &Scene,
    lambda: &[f32],
    p: (usize, usize, usize),
    h: f64,
    n: (usize, usize),
) -> f64 {
    let ((up, hu), (down, hd)) = (moved(s, p, h), moved(s, p, -h));
    (interreflection_integral(&up, lambda, n.0, n.1)
        - interreflection_integral(&down, lambda, n.0, n.1))
        / (hu - hd)
}

/// Mean and standard error over `seeds` of the adjoint's components `ps` (one gradient
/// per seed gives them all), and the boundary nodes used in all.
fn estimate(
    s: &Scene,
    lambda: &[f32],
    spp: u32,
    seeds: u64,
    ps: &[(usize, usize, usize)],
) -> (Vec<(f64, f64)>, u64) {
    let geom = SceneGeometry::build(s);
    let mut nodes = 0;
    let values: Vec<Vec<f64>> = (0..seeds)
        .map(|seed| {
            let opts = RenderOptions {
                model: Model::Path,
                spp,
                seed,
                ..RenderOptions::from_scene(s)
            };
            let g = gradient(s, &geom, &opts, lambda, None).unwrap();
            assert_eq!(g.truncated, 0);
            nodes += g.boundary_nodes;
            ps.iter().map(|p| g.vertices[p.0][p.1][p.2]).collect()
        })
        .collect();
    let stats = (0..ps.len())
        .map(|k| mean_se(&values.iter().map(|v| v[k]).collect::<Vec<_>>()))
        .collect();
    (stats, nodes)
}

struct Param {
    name: &'static str,
    param: (usize, usize, usize),
    /// Whether the interior derivative alone is asserted to be off, with area sampling
    /// only, with the default MIS and with BSDF sampling only.
    biased: [bool; 3],
}

const PARAMS: [Param; 4] = [
    Param {
        name: "occluder corner x",
        param: (2, 0, 0),
        biased: [true, true, true],
    },
    Param {
        name: "occluder corner y",
        param: (2, 0, 1),
        biased: [true, true, true],
    },
    // The side plate shadows the back plate only from the scan points beyond x = 0.15,
    // from where no second hidden point sees both the back plate and the spot: for four
    // bounces it is a receiver only. Tilted, its points move under the occluder's shadow
    // cast from y1; with area sampling (barycentrics kept) the interior derivative alone
    // is within 1 % here (not asserted either way), with MIS (points found by rays from
    // y1 slide along them) it is off by ~9 %.
    Param {
        name: "side-plate corner x (tilt)",
        param: (1, 3, 0),
        biased: [false, true, true],
    },
    // In-plane: the occluder's and the side plate's shadows stay where they are while
    // the plate's material points move under them.
    Param {
        name: "back-plate corner x (in plane)",
        param: (0, 0, 0),
        biased: [true, true, true],
    },
];

#[test]
fn four_bounce_boundary_terms_against_the_exact_reference() {
    let s = four_bounce(&[]);
    let lambda = fixed_adjoint();
    let ps: Vec<_> = PARAMS.iter().map(|p| p.param).collect();
    // The reference: value, and its own error (refined quadrature; doubled step).
    let t = Instant::now();
    let references: Vec<(f64, f64)> = ps
        .iter()
        .map(|&p| {
            let base = reference_fd(&s, lambda, p, 2e-4, ORDERS);
            let refined = reference_fd(&s, lambda, p, 2e-4, REFINED);
            let wider = reference_fd(&s, lambda, p, 4e-4, ORDERS);
            let err = (refined - base).abs().max((wider - base).abs());
            (refined, err)
        })
        .collect();
    println!("reference: {:.1?}", t.elapsed());
    println!(
        "| case | reference (± its error) | interior only: bias | with boundary terms: error | ± (MC) |"
    );
    println!("|---|---|---|---|---|");
    let mut failures = Vec::new();
    // (label, extra render lines, spp, seeds): area sampling alone needs more samples.
    // BSDF sampling alone moves every hidden point along a ray that turns with the
    // previous vertex's normal, and its boundary terms have foreground parts: the
    // interior derivative alone is off by up to 120 % there; noisier (48 seeds: ±1–3 %).
    let modes = [
        ("area sampling", &["bsdf_sampling = false"][..], 1 << 18, 8),
        ("MIS", &[][..], 1 << 17, 8),
        (
            "BSDF sampling only",
            &["hidden_geometry_sampling = false"][..],
            1 << 17,
            48,
        ),
    ];
    for (mi, (mode, extra, spp, seeds)) in modes.into_iter().enumerate() {
        let on = four_bounce(extra);
        let mut off = on.clone();
        off.render.boundary_terms = false;
        let t = Instant::now();
        let (with, nodes) = estimate(&on, lambda, spp, seeds, &ps);
        let t_on = t.elapsed();
        let t = Instant::now();
        let (without, _) = estimate(&off, lambda, spp, seeds, &ps);
        let t_off = t.elapsed();
        for (k, p) in PARAMS.iter().enumerate() {
            let (reference, ref_err) = references[k];
            let ((with, se), (without, se_off)) = (with[k], without[k]);
            let rel = |v: f64| (v - reference) / reference.abs();
            let name = format!("path, 4 bounces ({mode}): {}", p.name);
            println!(
                "| {name} | {reference:.4e} (± {:.2} %) | {:+.1} % | {:+.2} % | {:.2} % |",
                100.0 * ref_err / reference.abs(),
                100.0 * rel(without),
                100.0 * rel(with),
                100.0 * se / reference.abs(),
            );
            assert!(ref_err < 0.002 * reference.abs(), "{name}: reference error");
            if rel(with).abs() > 0.02 + 3.0 * se / reference.abs() {
                failures.push(format!("{name}: {:+.2} %", 100.0 * rel(with)));
            }
            if p.biased[mi] && rel(without).abs() < 0.05 + 3.0 * se_off / reference.abs() {
                failures.push(format!(
                    "{name}: interior only within {:+.2} % (no bias to fix?)",
                    100.0 * rel(without)
                ));
            }
        }
        println!(
            "({mode}: {seeds} seeds x {spp} spp, {t_on:.1?} with ({nodes} boundary nodes), \
             {t_off:.1?} without boundary terms)"
        );
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// How much of the transient energy in the film paths of 4 or more bounces carry on this
/// scene (`path`, up to 6 bounces): each length by `filter_bounces`, against the
/// unfiltered total.
#[test]
fn energy_share_of_longer_paths() {
    let (spp, seeds) = (1 << 14, 4);
    let energy = |extra: &[&str]| {
        let mut lines = vec!["max_bounces = 6"];
        lines.extend_from_slice(extra);
        total_energy(&spec(&lines).scene(), Model::Path, spp, seeds)
    };
    let (total, total_se) = energy(&[]);
    let mut sum = (0.0, 0.0);
    let mut shares = Vec::new();
    for b in 3..=6 {
        let (e, se) = energy(&[&format!("filter_bounces = {b}")]);
        sum = (sum.0 + e, sum.1 + se * se);
        shares.push(format!("{b}: {:.2} %", 100.0 * e / total));
        if b == 3 {
            println!(
                "paths of >= 4 bounces: {:.2} % of the energy (up to 6 bounces)",
                100.0 * (1.0 - e / total)
            );
        }
    }
    println!("by bounces: {}", shares.join(", "));
    // The lengths add up to the unfiltered render.
    let se = (sum.1 + total_se * total_se).sqrt();
    assert!(
        (sum.0 - total).abs() < 4.0 * se,
        "{sum:?} vs {total} ± {se}"
    );
}
