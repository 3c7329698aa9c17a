//! The fit driver on a toy objective (distance of every vertex to a target position,
//! plus a trap of non-finite losses): convergence with Adam and L-BFGS, rejection of
//! non-finite steps, and a killed-and-resumed fit ending bit-identical to an
//! uninterrupted one.

use optim::checkpoint::LossRecord;
use optim::fit::Progress;
use optim::{
    fit, Evaluation, FitError, Mesh, MeshObjective, ObjectiveFactory, Schedule, SolverKind, Stage,
};
use std::cell::RefCell;
use std::path::PathBuf;
use std::rc::Rc;

fn grid(n: usize, z: f64) -> Mesh {
    let mut v = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            v.push([i as f64 / n as f64, j as f64 / n as f64, z]);
        }
    }
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    let mut f = Vec::new();
    for j in 0..n {
        for i in 0..n {
            f.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            f.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Mesh::new(v, f)
}

/// `Σ |x_i − t_i|² / V` with a bump target `t`; non-finite above `trap` in z, and a
/// little deterministic "noise" that depends on the parameters only.
struct Toy {
    target: Vec<[f64; 3]>,
    trap: f64,
}

impl MeshObjective for Toy {
    fn evaluate(&mut self, mesh: &Mesh) -> Result<Evaluation, String> {
        if mesh.vertices.iter().any(|p| p[2] > self.trap) {
            return Ok(Evaluation {
                loss: f64::NAN,
                d_vertices: vec![[f64::NAN; 3]; mesh.vertices.len()],
                ..Default::default()
            });
        }
        let n = mesh.vertices.len() as f64;
        let mut loss = 0.0;
        let mut d = Vec::new();
        for (p, t) in mesh.vertices.iter().zip(&self.target) {
            let e = [p[0] - t[0], p[1] - t[1], p[2] - t[2]];
            loss += (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) / n;
            d.push(e.map(|e| 2.0 * e / n));
        }
        Ok(Evaluation {
            loss,
            d_vertices: d,
            d_values: mesh.vertex_values.iter().map(|_| 0.0).collect(),
            report: vec![("toy".into(), 1.0)],
        })
    }
}

struct Factory {
    trap: f64,
}

impl ObjectiveFactory for Factory {
    fn objective(
        &mut self,
        _: &Stage,
        _: usize,
        _: &Mesh,
    ) -> Result<Box<dyn MeshObjective>, String> {
        let target = grid(6, 0.0)
            .vertices
            .iter()
            .map(|p| {
                [
                    p[0],
                    p[1],
                    0.3 + 0.1 * (3.0 * p[0]).sin() * (2.0 * p[1]).cos(),
                ]
            })
            .collect();
        Ok(Box::new(Toy {
            target,
            trap: self.trap,
        }))
    }
}

fn stage(iters: u64, solver: SolverKind, lr: f64) -> Stage {
    Stage {
        large_steps: 4.0,
        ..Stage::new(iters, solver, lr)
    }
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("umbra-optim-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn no_remesh(m: &Mesh, _: f64) -> Result<Mesh, String> {
    Ok(m.clone())
}

fn run(
    schedule: &Schedule,
    out: &std::path::Path,
    resume: bool,
    stop_at: Option<u64>,
    trap: f64,
) -> Result<optim::FitOutcome, FitError> {
    let progress: Progress = Rc::new(RefCell::new(move |r: &LossRecord| {
        stop_at.is_none_or(|s| r.iteration < s)
    }));
    fit(
        &grid(6, 0.0),
        schedule,
        &mut Factory { trap },
        &no_remesh,
        out,
        resume,
        &optim::checkpoint::Identity::default(),
        progress,
    )
}

#[test]
fn adam_and_lbfgs_converge_through_stages() {
    let schedule = Schedule {
        stages: vec![
            stage(150, SolverKind::Adam, 0.02),
            stage(20, SolverKind::Lbfgs, 0.0),
        ],
        checkpoint_every: 10,
    };
    let d = dir("converge");
    let out = run(&schedule, &d, false, None, 10.0).unwrap();
    let h = &out.history;
    assert_eq!(h.len(), 170);
    assert!(h[0].cost > 1e-2, "{}", h[0].cost);
    let after_adam = h[149].cost;
    let last = h.last().unwrap().cost;
    eprintln!(
        "costs: start {}, after Adam {after_adam}, after L-BFGS {last}",
        h[0].cost
    );
    assert!(
        after_adam < 1e-2 * h[0].cost,
        "Adam: {} -> {after_adam}",
        h[0].cost
    );
    assert!(last < 1e-2 * after_adam, "L-BFGS: {after_adam} -> {last}");
    assert!(out
        .mesh
        .vertices
        .iter()
        .all(|p| p.iter().all(|c| c.is_finite())));
    // A second fit into the same directory without --resume refuses to overwrite it.
    assert!(run(&schedule, &d, false, None, 10.0).is_err());
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn non_finite_steps_are_rejected() {
    // Step sizes that jump past the trap at z = 0.32 (the target reaches 0.4): every
    // such step is rejected and the step size halved; the mesh stays finite.
    let schedule = Schedule {
        stages: vec![stage(60, SolverKind::Adam, 0.2)],
        checkpoint_every: 10,
    };
    let d = dir("trap");
    let out = run(&schedule, &d, false, None, 0.32).unwrap();
    assert!(out.rejected_steps > 0);
    assert!(out
        .mesh
        .vertices
        .iter()
        .all(|p| p.iter().all(|c| c.is_finite()) && p[2] <= 0.32));
    assert!(out.history.iter().all(|r| r.cost.is_finite()));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn killed_and_resumed_fit_ends_where_an_uninterrupted_one_does() {
    let schedule = Schedule {
        stages: vec![
            stage(25, SolverKind::Adam, 0.02),
            stage(8, SolverKind::Lbfgs, 0.0),
        ],
        checkpoint_every: 4,
    };
    let whole = dir("whole");
    let reference = run(&schedule, &whole, false, None, 10.0).unwrap();
    for stop in [11, 23, 27] {
        let d = dir(&format!("resumed{stop}"));
        match run(&schedule, &d, false, Some(stop), 10.0) {
            Err(FitError::Interrupted { .. }) => {}
            other => panic!("expected an interruption at {stop}, got {other:?}"),
        }
        let resumed = run(&schedule, &d, true, None, 10.0).unwrap();
        assert_eq!(resumed.mesh, reference.mesh, "stopped at {stop}");
        assert_eq!(resumed.history, reference.history, "stopped at {stop}");
        let _ = std::fs::remove_dir_all(&d);
    }
    let _ = std::fs::remove_dir_all(&whole);
}
