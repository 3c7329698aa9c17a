//! The fit's objective (render, intensity model, jitter blur, masked leading bins) has
//! the gradient of its own loss: `UmbraObjective::evaluate` against central finite
//! differences of the loss, with `tri3` (deterministic, so differences are clean), the
//! per-bin background and a timing-jitter blur of two bins, on vertex positions and
//! per-vertex albedo.

mod common;

use optim::MeshObjective;
use umbra::fit::objective::UmbraObjective;
use umbra::fit::{Background, IntensityModel};
use umbra::geometry::SceneGeometry;
use umbra::scene::default::default_scene;
use umbra::scene::{KernelSpec, Model, Scene};
use umbra::transport::{RenderOptions, Renderer};

/// The default scene's letter on a 6 x 6 scan of 96 box bins, its tri3 options and
/// render.
fn small_letter() -> (Scene, RenderOptions, Vec<f32>) {
    let mut scene = default_scene().unwrap();
    scene.scan.nx = 6;
    scene.scan.ny = 6;
    scene.film.temporal_bins = 96;
    scene.film.bin_width_opl = 0.02;
    scene.film.kernel = KernelSpec::Box;
    let opts = RenderOptions {
        model: Model::Tri3,
        ..RenderOptions::from_scene(&scene)
    };
    let geom = SceneGeometry::build(&scene);
    let render = Renderer::new(&scene, &geom, &opts)
        .unwrap()
        .render(None)
        .unwrap()
        .data;
    (scene, opts, render)
}

#[test]
fn objective_gradient_matches_finite_differences_with_jitter_and_per_bin_background() {
    gradient_check(None, None);
}

/// Through a real capture's model (`fit::capture`): a response with a tail, a gain field,
/// a floor, the direct tails, the Poisson deviance, one scan point held out.
#[test]
fn objective_gradient_matches_finite_differences_through_the_capture_model() {
    use umbra::fit::capture_options::CaptureOptions;
    use umbra::fit::linear_fit::Likelihood;
    let options = CaptureOptions {
        prior: umbra::film::response::Response {
            sigma: 0.03,
            t0: 0.005,
            tails: vec![(0.3, 0.06)],
        },
        ..CaptureOptions::stanford(Likelihood::Poisson {
            counts_per_value: 1.0,
        })
    };
    gradient_check(None, Some(options));
}

/// The same through a measured impulse response (a SPAD-like exponential tail).
#[test]
fn objective_gradient_matches_finite_differences_through_an_irf() {
    let taps: Vec<f64> = (0..12).map(|k| (-(k as f64) / 3.0).exp()).collect();
    let total: f64 = taps.iter().sum();
    gradient_check(
        Some(umbra::film::irf::Irf {
            bin_width: 0.01,
            taps: taps.iter().map(|t| t / total).collect(),
        }),
        None,
    );
}

fn gradient_check(
    irf: Option<umbra::film::irf::Irf>,
    capture: Option<umbra::fit::capture_options::CaptureOptions>,
) {
    // Measurement: the true letter, scaled, plus a decaying per-bin floor.
    let (scene, opts, mut measured) = small_letter();
    let bins = scene.film.temporal_bins as usize;
    let peak = measured.iter().cloned().fold(0.0f32, f32::max);
    for (i, v) in measured.iter_mut().enumerate() {
        *v = 3.0 * *v + 0.05 * peak * (-((i % bins) as f32) / 30.0).exp();
    }
    if capture.is_some() {
        // Photon counts: a peak of a few hundred, where the deviance is far from zero.
        let k = 200.0 / (3.0 * peak);
        measured.iter_mut().for_each(|v| *v *= k);
    }
    // The fitted mesh: the letter moved 3 cm back and bent, with uneven albedo.
    let mut mesh = umbra::fit::fit_mesh(&scene.objects[0].mesh);
    let n = mesh.vertices.len();
    for p in mesh.vertices.iter_mut() {
        p[2] += 0.03 + 0.01 * (p[0] * 7.0).sin();
    }
    mesh.vertex_values = (0..n)
        .map(|i| 0.4 + 0.5 * ((i * 7 % 11) as f64 / 11.0))
        .collect();
    let mut objective = UmbraObjective {
        intensity: IntensityModel {
            scale: true,
            background: Background::PerBin,
        },
        first_bin: 20,
        jitter_opl: 0.04,
        irf,
        capture: capture.map(|c| {
            let model = c.at_stage(&scene, &measured, 20, 1, (6, 6));
            assert!(model.in_fit.iter().any(|&b| !b), "a point is held out");
            model
        }),
        ..common::objective(&scene, opts, measured)
    };
    let eval = objective.evaluate(&mesh).unwrap();
    assert!(eval.loss > 1e-4, "{}", eval.loss);
    let mut loss_at = |m: &optim::Mesh| objective.evaluate(m).unwrap().loss;
    let mut worst: f64 = 0.0;
    let mut checked = 0;
    // The five largest position derivatives, and two albedo derivatives.
    let mut order: Vec<(usize, usize)> = (0..n).flat_map(|v| (0..3).map(move |k| (v, k))).collect();
    order.sort_by(|a, b| {
        eval.d_vertices[b.0][b.1]
            .abs()
            .total_cmp(&eval.d_vertices[a.0][a.1].abs())
    });
    for &(v, k) in order.iter().take(5) {
        let h = 2e-4;
        let (mut plus, mut minus) = (mesh.clone(), mesh.clone());
        plus.vertices[v][k] += h;
        minus.vertices[v][k] -= h;
        let fd = (loss_at(&plus) - loss_at(&minus)) / (2.0 * h);
        let adj = eval.d_vertices[v][k];
        let err = (adj - fd).abs() / fd.abs().max(1e-12);
        eprintln!("vertex {v} axis {k}: adjoint {adj:.5e}, FD {fd:.5e}, rel. error {err:.2e}");
        worst = worst.max(err);
        checked += 1;
    }
    for v in [0, n / 2] {
        let h = 1e-3;
        let (mut plus, mut minus) = (mesh.clone(), mesh.clone());
        plus.vertex_values[v] += h;
        minus.vertex_values[v] -= h;
        let fd = (loss_at(&plus) - loss_at(&minus)) / (2.0 * h);
        let adj = eval.d_values[v];
        let err = (adj - fd).abs() / fd.abs().max(1e-12);
        eprintln!("albedo {v}: adjoint {adj:.5e}, FD {fd:.5e}, rel. error {err:.2e}");
        worst = worst.max(err);
        checked += 1;
    }
    assert_eq!(checked, 7);
    assert!(worst < 5e-3, "worst relative error {worst:.2e}");
}

#[test]
fn objective_finds_a_time_offset_of_the_measurement() {
    // The measurement is the true letter's render through the jitter kernel, delayed by
    // 1.7 cm of OPL: the objective finds the delay and explains the data exactly.
    let (scene, opts, mut measured) = small_letter();
    let bins = scene.film.temporal_bins as usize;
    umbra::film::jitter::JitterKernel::new(0.03 / 0.02, 0.017 / 0.02).apply(&mut measured, bins);
    let mesh = umbra::fit::fit_mesh(&scene.objects[0].mesh);
    let objective = |max: f64| UmbraObjective {
        jitter_opl: 0.03,
        time_offset_max_opl: max,
        ..common::objective(&scene, opts, measured.clone())
    };
    let r = objective(0.05).render(&mesh).unwrap();
    let (loss, offset) = (r.loss, r.time_offset_opl);
    assert!((offset - 0.017).abs() < 2e-4, "offset {offset}");
    assert!(loss < 1e-8, "loss {loss}");
    let r = objective(0.0).render(&mesh).unwrap();
    let (held, zero) = (r.loss, r.time_offset_opl);
    assert_eq!(zero, 0.0);
    assert!(held > 1e-2, "without the offset: {held}");
}
