//! The albedo's total variation (`optim::tv`, `albedo_tv`): its gradient against
//! central finite differences on an irregular mesh, its independence of the mesh
//! resolution, `MeshProblem`'s gradient with it, and an albedo-only fit it denoises.

mod common;

use argmin::core::{CostFunction, Gradient};
use optim::checkpoint::{Identity, LossRecord};
use optim::fit::Progress;
use optim::tv::{TotalVariation, EPSILON};
use optim::{
    fit, Evaluation, Mesh, MeshObjective, MeshProblem, ObjectiveFactory, ProblemSettings, Schedule,
    SolverKind, Stage,
};
use std::cell::RefCell;
use std::rc::Rc;

/// SplitMix64: uniform in [0, 1).
struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller).
    fn normal(&mut self) -> f64 {
        let (u, v) = (1.0 - self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

#[test]
fn tv_gradient_matches_finite_differences_on_an_irregular_mesh() {
    // An icosphere (valences 5 and 6) with every vertex moved by up to 0.1 of the radius
    // (the mean edge is about 0.3): irregular edge lengths and face areas.
    let mut rng = Rng(7);
    let mut mesh = common::icosphere(2, 1.0);
    for p in &mut mesh.vertices {
        for c in p.iter_mut() {
            *c += 0.2 * (rng.uniform() - 0.5);
        }
    }
    let n = mesh.vertices.len();
    let values: Vec<f64> = (0..n).map(|_| rng.uniform()).collect();
    let tv = TotalVariation::new(&mesh);
    let mut grad = vec![0.0; n];
    let t0 = tv.evaluate(&values, &mut grad);
    assert!(t0 > 0.0);
    // Vertices all of whose edges have |a_i − a_j| > 20 ε (φ is |d|-like there; within
    // ε of 0 its curvature is 1/ε and FD steps see it).
    let mut near_zero = vec![false; n];
    for &(i, j) in tv.edges() {
        if (values[i as usize] - values[j as usize]).abs() <= 20.0 * EPSILON {
            near_zero[i as usize] = true;
            near_zero[j as usize] = true;
        }
    }
    let (mut worst, mut checked) = (0.0f64, 0);
    for i in (0..n).filter(|&i| !near_zero[i]) {
        let h = 1e-5;
        let mut v = values.clone();
        v[i] += h;
        let plus = tv.evaluate(&v, &mut vec![0.0; n]);
        v[i] -= 2.0 * h;
        let minus = tv.evaluate(&v, &mut vec![0.0; n]);
        let fd = (plus - minus) / (2.0 * h);
        let err = (grad[i] - fd).abs() / fd.abs().max(1e-3);
        assert!(err < 1e-6, "vertex {i}: analytic {} vs FD {fd}", grad[i]);
        worst = worst.max(err);
        checked += 1;
    }
    eprintln!(
        "{} vertices, {} edges: {checked} checked, worst relative error {worst:.1e}",
        n,
        tv.edges().len()
    );
    assert!(checked > n / 2, "only {checked} of {n} vertices checked");
}

/// Which side of a line a point `(x, y)` of the unit square is on.
type Side = dyn Fn(f64, f64) -> bool;

/// The TV of values 1 on one side of a straight line and 0 on the other, on an `n` x `n`
/// grid of the square `[0, s]²`.
fn step_tv(n: usize, s: f64, one_side: impl Fn(f64, f64) -> bool) -> f64 {
    let mesh = common::grid(n, n, false, |x, y| [s * x, s * y, 0.0]);
    let values: Vec<f64> = mesh
        .vertices
        .iter()
        .map(|p| {
            if one_side(p[0] / s, p[1] / s) {
                1.0
            } else {
                0.0
            }
        })
        .collect();
    let tv = TotalVariation::new(&mesh);
    assert!((tv.area() - s * s).abs() < 1e-12 * s * s);
    tv.evaluate(&values, &mut vec![0.0; values.len()])
}

#[test]
fn a_step_costs_the_same_at_any_mesh_resolution_and_scale() {
    // A line along the grid (x = 0.45, of length 1 in the unit square) and an oblique
    // one (x + 0.4 y = 0.7, of length 1.08).
    let lines: [(&str, &Side); 2] = [
        ("x = 0.45", &|x, _| x > 0.45),
        ("x + 0.4 y = 0.7", &|x, y| x + 0.4 * y > 0.7),
    ];
    for (name, side) in lines {
        let (coarse, fine) = (step_tv(8, 1.0, side), step_tv(32, 1.0, side));
        let change = (coarse - fine).abs() / fine;
        eprintln!(
            "{name}: TV {coarse:.4} on 8 x 8, {fine:.4} on 32 x 32 ({:.1} %)",
            100.0 * change
        );
        // Measured: along the grid 2.5367 vs 2.4430 (3.8 %: the crossed edges are n + 1
        // of length 1/n and n diagonals of length √2/n, so 0.999 (1 + √2 + 1/n) with
        // φ(1) = 0.999); oblique 3.4411 vs 3.4228 (0.5 %).
        assert!(change < 0.05, "{name}: {coarse} vs {fine}");
        // The square scaled by 3: the same TV (lengths over √A are dimensionless).
        let scaled = step_tv(8, 3.0, side);
        assert!(
            (scaled - coarse).abs() < 1e-12 * coarse,
            "{scaled} vs {coarse}"
        );
    }
}

/// A smooth loss of positions and values (as in tests/problem.rs):
/// `Σ_i a_i² |x_i − t_i|² + (a_i − 0.3)²·(1 + z_i)`.
struct Smooth;

impl MeshObjective for Smooth {
    fn evaluate(&mut self, mesh: &Mesh) -> Result<Evaluation, String> {
        let mut e = Evaluation::default();
        for (i, (p, &a)) in mesh.vertices.iter().zip(&mesh.vertex_values).enumerate() {
            let t = [0.1 * i as f64 % 0.7, 0.2, 0.5 + 0.05 * (i as f64).sin()];
            let d = [p[0] - t[0], p[1] - t[1], p[2] - t[2]];
            let r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
            let w = (a - 0.3) * (a - 0.3);
            e.loss += a * a * r2 + w * (1.0 + p[2]);
            let mut dv = d.map(|d| 2.0 * a * a * d);
            dv[2] += w;
            e.d_vertices.push(dv);
            e.d_values
                .push(2.0 * a * r2 + 2.0 * (a - 0.3) * (1.0 + p[2]));
        }
        Ok(e)
    }
}

fn settings(fit_positions: bool, value_tv: f64) -> ProblemSettings {
    ProblemSettings {
        large_steps: 2.0,
        laplacian: 0.3,
        fit_positions,
        fit_values: true,
        value_scale: 10.0,
        value_tv,
    }
}

#[test]
fn problem_gradient_with_albedo_tv_matches_finite_differences() {
    for fit_positions in [true, false] {
        let mut mesh = common::sheet(4);
        let n = mesh.vertices.len();
        let mut rng = Rng(11);
        for p in &mut mesh.vertices {
            p[2] = 0.3 + 0.05 * rng.uniform();
        }
        // Albedo inside (0, 1), away from the clamp; neighbours differ by 0.05 or more.
        mesh.vertex_values = (0..n)
            .map(|i| 0.15 + 0.05 * ((7 * i) % 15) as f64 + 0.01 * rng.uniform())
            .collect();
        let w = 0.05;
        let problem = MeshProblem::new(Box::new(Smooth), &mesh, settings(fit_positions, w));
        let theta = problem.encode(&mesh);
        let grad = problem.gradient(&theta).unwrap();
        // The breakdown: w TV of the (clamped) values, in the cost.
        let last = problem.last();
        let tv = w * TotalVariation::new(&mesh).evaluate(&mesh.vertex_values, &mut vec![0.0; n]);
        assert!(
            tv > 0.0 && (last.value_tv - tv).abs() < 1e-15 * tv,
            "{} vs {tv}",
            last.value_tv
        );
        let cost = problem.cost(&theta).unwrap();
        assert_eq!(cost, last.data_loss + last.smoothness + last.value_tv);
        // TV has no position gradient: the position block is the one without TV.
        let plain = MeshProblem::new(Box::new(Smooth), &mesh, settings(fit_positions, 0.0));
        let plain_grad = plain.gradient(&theta).unwrap();
        let values_at = if fit_positions { 3 * n } else { 0 };
        assert_eq!(grad[..values_at], plain_grad[..values_at]);
        assert_ne!(grad[values_at..], plain_grad[values_at..]);
        // Per block: [positions (the large-steps solve's 1e-12 residual, ~1e-12 |u| per
        // decode, limits the FD), values].
        let mut worst = [0.0f64; 2];
        for (k, (err, fd)) in common::fd_errors(&problem, &theta, &grad, 1e-5)
            .into_iter()
            .enumerate()
        {
            let block = usize::from(k >= values_at);
            worst[block] = worst[block].max(err);
            assert!(
                err < [1e-5, 1e-6][block],
                "parameter {k}: adjoint {} vs FD {fd}",
                grad[k]
            );
        }
        eprintln!(
            "fit_positions {fit_positions}: worst relative error {:.1e} (positions), {:.1e} (values) over {} parameters",
            worst[0], worst[1],
            theta.len()
        );
    }
}

/// `Σ_i (a_i − y_i)² / V`: noisy albedo observed directly (positions ignored).
struct Noisy {
    observed: Rc<Vec<f64>>,
}

impl MeshObjective for Noisy {
    fn evaluate(&mut self, mesh: &Mesh) -> Result<Evaluation, String> {
        let n = mesh.vertices.len() as f64;
        let a = &mesh.vertex_values;
        let r: Vec<f64> = a
            .iter()
            .zip(self.observed.iter())
            .map(|(a, y)| a - y)
            .collect();
        Ok(Evaluation {
            loss: r.iter().map(|r| r * r).sum::<f64>() / n,
            d_vertices: vec![[0.0; 3]; a.len()],
            d_values: r.iter().map(|r| 2.0 * r / n).collect(),
            report: Vec::new(),
        })
    }
}

struct Factory(Rc<Vec<f64>>);

impl ObjectiveFactory for Factory {
    fn objective(
        &mut self,
        _: &Stage,
        _: usize,
        _: &Mesh,
    ) -> Result<Box<dyn MeshObjective>, String> {
        Ok(Box::new(Noisy {
            observed: self.0.clone(),
        }))
    }
}

/// An albedo-only fit (positions fixed) with `albedo_tv = w`: the RMS error of the
/// fitted albedo to `truth`, and the last loss record.
fn denoise(mesh: &Mesh, truth: &[f64], observed: &Rc<Vec<f64>>, w: f64) -> (f64, LossRecord) {
    let schedule = Schedule {
        stages: vec![Stage {
            fit_positions: false,
            fit_albedo: true,
            albedo_tv: w,
            ..Stage::new(1000, SolverKind::Lbfgs, 0.0)
        }],
        checkpoint_every: 1000,
    };
    let d = std::env::temp_dir().join(format!("umbra-optim-tv-{w}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let progress: Progress = Rc::new(RefCell::new(|_: &LossRecord| true));
    let out = fit(
        mesh,
        &schedule,
        &mut Factory(observed.clone()),
        &|m: &Mesh, _| Ok(m.clone()),
        &d,
        false,
        &Identity::default(),
        progress,
    )
    .unwrap();
    let _ = std::fs::remove_dir_all(&d);
    assert_eq!(out.mesh.vertices, mesh.vertices, "positions moved");
    let a = &out.mesh.vertex_values;
    let sq: f64 = a.iter().zip(truth).map(|(a, t)| (a - t) * (a - t)).sum();
    let rms = (sq / a.len() as f64).sqrt();
    (rms, out.history.last().unwrap().clone())
}

#[test]
fn albedo_tv_denoises_a_piecewise_constant_albedo() {
    // Truth: albedo 0.8 in a disc of radius 0.3 and in a bar, 0.2 elsewhere, on a
    // 48 x 48 grid of the unit square (2401 vertices); observed with Gaussian noise
    // σ = 0.3 (half the contrast). Without TV the fit returns the observation clamped to
    // [0, 1]; measured RMS error to the truth 0.2430 without TV, 0.0726 with
    // albedo_tv = 0.006 (3.3x smaller; what is left is mostly TV's loss of contrast,
    // ~ w / (feature size), and the vertices next to the edges). A sweep of the weight
    // (0.002 to 0.015) on 24 x 24, 32 x 32 and 48 x 48 grids, σ 0.2 and 0.3, found the
    // best weight between 0.004 and 0.01 on all of them (TV is resolution independent),
    // improving the error 2.4x to 3.4x.
    let mut mesh = common::sheet(48);
    let truth: Vec<f64> = mesh
        .vertices
        .iter()
        .map(|p| {
            let disc = (p[0] - 0.4).powi(2) + (p[1] - 0.5).powi(2) < 0.09;
            let bar = p[0] > 0.8 && p[1] > 0.2 && p[1] < 0.8;
            if disc || bar {
                0.8
            } else {
                0.2
            }
        })
        .collect();
    let mut rng = Rng(3);
    let observed = truth.iter().map(|t| t + 0.3 * rng.normal()).collect();
    let observed = Rc::new(observed);
    mesh.vertex_values = vec![0.5; mesh.vertices.len()];
    let w = 0.006;
    let (plain, plain_record) = denoise(&mesh, &truth, &observed, 0.0);
    let (with_tv, tv_record) = denoise(&mesh, &truth, &observed, w);
    eprintln!(
        "RMS albedo error to the truth: {plain:.4} without TV, {with_tv:.4} with albedo_tv = {w}"
    );
    assert!(with_tv < 0.5 * plain, "{with_tv} vs {plain}");
    // The record's smoothness is the TV term here (no Laplacian).
    assert_eq!(plain_record.smoothness, 0.0);
    assert!(tv_record.smoothness > 0.0);
    assert_eq!(tv_record.cost, tv_record.data_loss + tv_record.smoothness);
}
