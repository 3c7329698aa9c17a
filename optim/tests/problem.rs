//! `MeshProblem`'s gradient against central finite differences of its own cost, through
//! everything between the optimiser and the renderer: the large-steps parameterisation
//! (`λ > 0`), the Laplacian smoothness term, and the albedo block scaled by `κ ≠ 1`
//! (albedo_step) and clamped to `[0, 1]`. A line search compares costs with this
//! gradient, so the two must agree.

mod common;

use argmin::core::Gradient;
use optim::{Evaluation, Mesh, MeshObjective, MeshProblem, ProblemSettings, Project};

/// A smooth loss of positions and values: `Σ_i a_i² |x_i − t_i|² + (a_i − 0.3)²·(1 + z_i)`.
struct Smooth;

impl MeshObjective for Smooth {
    fn evaluate(&mut self, mesh: &Mesh) -> Result<Evaluation, String> {
        let mut loss = 0.0;
        let mut dv = Vec::new();
        let mut da = Vec::new();
        for (i, (p, &a)) in mesh.vertices.iter().zip(&mesh.vertex_values).enumerate() {
            let t = [0.1 * i as f64 % 0.7, 0.2, 0.5 + 0.05 * (i as f64).sin()];
            let e = [p[0] - t[0], p[1] - t[1], p[2] - t[2]];
            let r2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
            let w = (a - 0.3) * (a - 0.3);
            loss += a * a * r2 + w * (1.0 + p[2]);
            let mut d = e.map(|e| 2.0 * a * a * e);
            d[2] += w;
            dv.push(d);
            da.push(2.0 * a * r2 + 2.0 * (a - 0.3) * (1.0 + p[2]));
        }
        Ok(Evaluation {
            loss,
            d_vertices: dv,
            d_values: da,
            report: Vec::new(),
        })
    }
}

#[test]
fn gradient_matches_finite_differences_with_large_steps_smoothness_and_scaled_albedo() {
    check_gradient(true);
}

#[test]
fn albedo_only_gradient_matches_and_positions_stay() {
    check_gradient(false);
}

fn check_gradient(fit_positions: bool) {
    let mut mesh = common::sheet(3);
    let n = mesh.vertices.len();
    for (i, p) in mesh.vertices.iter_mut().enumerate() {
        p[2] = 0.3 + 0.02 * (i as f64).cos();
    }
    // Albedo strictly inside (0, 1), away from the clamp.
    mesh.vertex_values = (0..n).map(|i| 0.2 + 0.6 * (i as f64 / n as f64)).collect();
    let problem = MeshProblem::new(
        Box::new(Smooth),
        &mesh,
        ProblemSettings {
            large_steps: 2.0,
            laplacian: 0.3,
            fit_positions,
            fit_values: true,
            value_scale: 10.0,
            value_tv: 0.0,
        },
    );
    let theta = problem.encode(&mesh);
    assert_eq!(theta.len(), if fit_positions { 4 * n } else { n });
    let grad = problem.gradient(&theta).unwrap();
    let mut moved = theta.clone();
    moved.iter_mut().for_each(|v| *v *= 0.9);
    let decoded = problem.decode(&moved).unwrap();
    assert_eq!(decoded.vertices == mesh.vertices, !fit_positions);
    let mut worst: f64 = 0.0;
    for (k, (err, fd)) in common::fd_errors(&problem, &theta, &grad, 1e-6)
        .into_iter()
        .enumerate()
    {
        worst = worst.max(err);
        assert!(err < 1e-5, "parameter {k}: adjoint {} vs FD {fd}", grad[k]);
    }
    eprintln!(
        "worst relative error {worst:.2e} over {} parameters",
        theta.len()
    );
}

#[test]
fn projection_clamps_the_albedo_block_only() {
    let mut mesh = common::sheet(2);
    let n = mesh.vertices.len();
    mesh.vertex_values = vec![0.5; n];
    let problem = MeshProblem::new(
        Box::new(Smooth),
        &mesh,
        ProblemSettings {
            large_steps: 1.0,
            laplacian: 0.0,
            fit_positions: true,
            fit_values: true,
            value_scale: 10.0,
            value_tv: 0.0,
        },
    );
    let mut theta = problem.encode(&mesh);
    let positions = theta[..3 * n].to_vec();
    theta[3 * n] = -1.0; // albedo -10
    theta[3 * n + 1] = 0.5; // albedo 5
    theta[0] = 7.0; // positions are never clamped
    problem.project(&mut theta);
    assert_eq!(theta[3 * n], 0.0);
    assert_eq!(theta[3 * n + 1], 0.1);
    assert_eq!(theta[0], 7.0);
    assert_eq!(&theta[1..3 * n], &positions[1..]);
}

/// A loss blind to a common factor on the values (as a render linear in albedo compared
/// through a fitted scale): `Σ_i (a_i / Σ_j a_j − w_i)²`.
struct ScaleFree;

impl MeshObjective for ScaleFree {
    fn evaluate(&mut self, mesh: &Mesh) -> Result<Evaluation, String> {
        let a = &mesh.vertex_values;
        let total: f64 = a.iter().sum();
        let w = |i: usize| (i + 1) as f64 / 10.0;
        let r: Vec<f64> = a
            .iter()
            .enumerate()
            .map(|(i, &a)| a / total - w(i))
            .collect();
        let loss = r.iter().map(|r| r * r).sum();
        let dot: f64 = r.iter().zip(a).map(|(r, a)| r * a).sum();
        let d_values = r
            .iter()
            .map(|&ri| 2.0 * ri / total - 2.0 * dot / (total * total))
            .collect();
        Ok(Evaluation {
            loss,
            d_vertices: vec![[0.0; 3]; mesh.vertices.len()],
            d_values,
            report: Vec::new(),
        })
    }
    fn values_scale_free(&self) -> bool {
        true
    }
}

/// A scale-free objective's values past the top are rescaled together (ratios and the
/// loss kept), not clamped one by one; negative values are still clamped to 0.
#[test]
fn projection_rescales_the_albedo_of_a_scale_free_loss() {
    let mut mesh = common::sheet(2);
    let n = mesh.vertices.len();
    mesh.vertex_values = (0..n).map(|i| 0.1 + 0.2 * i as f64).collect();
    let settings = ProblemSettings {
        large_steps: 0.0,
        laplacian: 0.0,
        fit_positions: false,
        fit_values: true,
        value_scale: 1.0,
        value_tv: 0.0,
    };
    let problem = MeshProblem::new(Box::new(ScaleFree), &mesh, settings.clone());
    let mut theta = problem.encode(&mesh);
    assert!(theta.iter().any(|&a| a > 1.0), "{theta:?}");
    let before = theta.clone();
    // The loss of the values as they are (a problem's cost would see them decoded).
    let loss = ScaleFree.evaluate(&mesh).unwrap().loss;
    let cost = |t: &[f64]| argmin::core::CostFunction::cost(&problem, &t.to_vec()).unwrap();
    problem.project(&mut theta);
    let top = before.iter().copied().fold(0.0f64, f64::max);
    for (a, b) in theta.iter().zip(&before) {
        assert!((a - b / top).abs() < 1e-12, "{theta:?} from {before:?}");
    }
    assert!((cost(&theta) - loss).abs() < 1e-12 * loss.max(1e-12));
    // The same values under a loss that is not scale-free: clamped one by one.
    let clamped = MeshProblem::new(Box::new(Smooth), &mesh, settings);
    let mut theta = before.clone();
    clamped.project(&mut theta);
    for (a, b) in theta.iter().zip(&before) {
        assert_eq!(*a, b.min(1.0));
    }
}

/// [`Smooth`] seeing nothing outside a point at the origin: the problem's box is the
/// initial mesh's own.
struct Boxed;

impl MeshObjective for Boxed {
    fn evaluate(&mut self, mesh: &Mesh) -> Result<Evaluation, String> {
        Smooth.evaluate(mesh)
    }
    fn bounds(&self) -> Option<([[f64; 3]; 2], String)> {
        Some(([[0.0; 3]; 2], "a point".into()))
    }
}

/// A stage starts from the last one's mesh, whose vertices may sit on the box (a step
/// projected onto it); the large-steps round trip `decode(encode(x))` moves them by the
/// solve's residual (~1e-12 m), which must not count as leaving the box (a 600-iteration
/// LCT fit stopped at its third stage on exactly this: "the initial mesh cannot be
/// evaluated", a vertex at the far bound).
#[test]
fn a_mesh_on_its_box_decodes_after_the_large_steps_round_trip() {
    let mut mesh = common::sheet(6);
    for (i, p) in mesh.vertices.iter_mut().enumerate() {
        p[2] = 0.3 + 0.2 * (1.3 * i as f64).sin(); // many vertices at the box's faces
    }
    let problem = MeshProblem::new(
        Box::new(Boxed),
        &mesh,
        ProblemSettings {
            large_steps: 2.0,
            laplacian: 0.0,
            fit_positions: true,
            fit_values: false,
            value_scale: 1.0,
            value_tv: 0.0,
        },
    );
    let decoded = problem.decode(&problem.encode(&mesh)).unwrap();
    let moved = decoded
        .vertices
        .iter()
        .zip(&mesh.vertices)
        .flat_map(|(a, b)| (0..3).map(move |k| (a[k] - b[k]).abs()))
        .fold(0.0, f64::max);
    assert!(moved < 1e-9, "the round trip moved a vertex by {moved:e} m");
    // A step well outside the box is still refused.
    let mut theta = problem.encode(&mesh);
    theta.iter_mut().for_each(|v| *v *= 2.0);
    let e = problem.decode(&theta).unwrap_err();
    assert!(e.contains("outside") && e.contains("a point"), "{e}");
}
