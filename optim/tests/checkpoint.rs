//! Checkpoints are resumed only when intact and written for the same fit (issue 17):
//! solver files and stage files with another identity, a broken envelope, an empty mesh
//! or a NaN are refused naming the file; stale temporaries go; a schedule that cannot
//! mean what it says is refused before anything runs.

mod common;

use optim::checkpoint::{encode, Identity, Kind, LossRecord};
use optim::fit::Progress;
use optim::{
    fit, Evaluation, FitError, Mesh, MeshObjective, ObjectiveFactory, Schedule, SolverKind, Stage,
};
use serde::Serialize;
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// A flat 3 x 3 grid (18 faces).
fn grid() -> Mesh {
    common::sheet(3)
}

/// Every vertex pulled towards z = 0.3.
struct Toy;

impl MeshObjective for Toy {
    fn evaluate(&mut self, mesh: &Mesh) -> Result<Evaluation, String> {
        let n = mesh.vertices.len() as f64;
        Ok(Evaluation {
            loss: mesh
                .vertices
                .iter()
                .map(|p| (p[2] - 0.3).powi(2))
                .sum::<f64>()
                / n,
            d_vertices: mesh
                .vertices
                .iter()
                .map(|p| [0.0, 0.0, 2.0 * (p[2] - 0.3) / n])
                .collect(),
            d_values: vec![0.0; mesh.vertex_values.len()],
            report: Vec::new(),
        })
    }
}

struct Factory;

impl ObjectiveFactory for Factory {
    fn objective(
        &mut self,
        _: &Stage,
        _: usize,
        _: &Mesh,
    ) -> Result<Box<dyn MeshObjective>, String> {
        Ok(Box::new(Toy))
    }
}

fn schedule(lr: f64) -> Schedule {
    let stage = Stage {
        large_steps: 1.0,
        ..Stage::new(10, SolverKind::Adam, lr)
    };
    Schedule {
        stages: vec![stage],
        checkpoint_every: 2,
    }
}

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("umbra-ckpt-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn identity(scene: u64) -> Identity {
    Identity::default().with("scene", scene, format!("scene {scene}"))
}

fn run(
    d: &Path,
    s: &Schedule,
    id: &Identity,
    resume: bool,
    stop: Option<u64>,
) -> Result<optim::FitOutcome, FitError> {
    let progress: Progress = Rc::new(RefCell::new(move |r: &LossRecord| {
        stop.is_none_or(|s| r.iteration < s)
    }));
    fit(
        &grid(),
        s,
        &mut Factory,
        &|m: &Mesh, _| Ok(m.clone()),
        d,
        resume,
        id,
        progress,
    )
}

/// A fit of [`schedule`] stopped at iteration 5: `stage.bin` and `solver-0.bin` (of
/// iteration 4) in `d`.
fn interrupted(name: &str) -> (PathBuf, Schedule) {
    let d = dir(name);
    let s = schedule(0.01);
    match run(&d, &s, &identity(1), false, Some(5)) {
        Err(FitError::Interrupted { .. }) => {}
        other => panic!("expected an interruption, got {other:?}"),
    }
    assert!(d.join("solver-0.bin").is_file() && d.join("stage.bin").is_file());
    (d, s)
}

fn err(r: Result<optim::FitOutcome, FitError>) -> String {
    match r {
        Ok(_) => panic!("resumed"),
        Err(e) => e.to_string(),
    }
}

/// `stage.bin`'s body, as `optim::fit` writes it.
#[derive(Serialize)]
struct StageBody {
    stage: usize,
    mesh: Mesh,
    history: Vec<LossRecord>,
    rejected: u64,
}

#[test]
fn the_same_fit_resumes_and_another_is_refused() {
    let (d, s) = interrupted("identity");
    // Another scene: refused, naming the component and the file.
    let e = err(run(&d, &s, &identity(2), true, None));
    assert!(
        e.contains("stage.bin was written for another scene (scene 1 vs scene 2 now; hash"),
        "{e}"
    );
    // Another schedule: refused.
    let e = err(run(&d, &schedule(0.02), &identity(1), true, None));
    assert!(e.contains("for another schedule"), "{e}");
    // A solver file of another fit (the stage file agreeing) is refused too.
    let other = dir("identity-other");
    let _ = run(&other, &s, &identity(2), false, Some(5));
    std::fs::copy(other.join("solver-0.bin"), d.join("solver-0.bin")).unwrap();
    let e = err(run(&d, &s, &identity(1), true, None));
    assert!(
        e.contains("solver-0.bin was written for another scene"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&other);
    let _ = std::fs::remove_dir_all(&d);
    // The same fit resumes to where an uninterrupted one ends.
    let (d, s) = interrupted("identity-same");
    let resumed = run(&d, &s, &identity(1), true, None).unwrap();
    let whole_dir = dir("identity-whole");
    let whole = run(&whole_dir, &s, &identity(1), false, None).unwrap();
    assert_eq!(resumed.mesh, whole.mesh);
    let _ = std::fs::remove_dir_all(&d);
    let _ = std::fs::remove_dir_all(&whole_dir);
}

#[test]
fn damaged_and_impossible_checkpoints_are_refused() {
    let (d, s) = interrupted("damaged");
    let id = identity(1);
    let solver = d.join("solver-0.bin");
    let good = std::fs::read(&solver).unwrap();
    let mut flipped = good.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 1;
    for (bytes, says) in [
        (good[..good.len() - 3].to_vec(), "solver-0.bin: truncated"),
        (flipped, "solver-0.bin: corrupt checkpoint"),
        (
            b"garbage".to_vec(),
            "solver-0.bin: not an Umbra fit checkpoint",
        ),
    ] {
        std::fs::write(&solver, &bytes).unwrap();
        let e = err(run(&d, &s, &id, true, None));
        assert!(e.contains(says), "want {says:?}: {e}");
    }
    std::fs::remove_file(&solver).unwrap();
    // Stage files that are well-formed envelopes of impossible contents. The identity
    // a fit stamps adds the schedule and initial mesh to the caller's.
    let full = optim::fit::full_identity(&id, &s, &grid());
    let stage = d.join("stage.bin");
    let mut nan = grid();
    nan.vertices[3][1] = f64::NAN;
    let mut out_of_range = grid();
    out_of_range.faces[0][2] = 999;
    for (mesh, says) in [
        (Mesh::default(), "its mesh has 0 vertices and 0 faces"),
        (nan, "mesh vertex coordinate[10] = NaN is not finite"),
        (out_of_range, "face [0, 1, 999] of a mesh of 16 vertices"),
    ] {
        let body = StageBody {
            stage: 0,
            mesh,
            history: Vec::new(),
            rejected: 0,
        };
        std::fs::write(&stage, encode(Kind::Stage, &full, &body).unwrap()).unwrap();
        let e = err(run(&d, &s, &id, true, None));
        assert!(
            e.contains("stage.bin: corrupt checkpoint") && e.contains(says),
            "want {says:?}: {e}"
        );
    }
    // A stage file where a solver file belongs: refused by kind.
    std::fs::copy(&stage, &solver).unwrap();
    let body = StageBody {
        stage: 0,
        mesh: grid(),
        history: Vec::new(),
        rejected: 0,
    };
    std::fs::write(&stage, encode(Kind::Stage, &full, &body).unwrap()).unwrap();
    let e = err(run(&d, &s, &id, true, None));
    assert!(e.contains("solver-0.bin: not a solver checkpoint"), "{e}");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn stale_temporaries_and_orphan_solver_files_are_removed() {
    let (d, s) = interrupted("stale");
    for name in [
        ".stage.bin.tmp123",
        ".solver-0.bin.tmp77",
        ".solver-12.bin.tmp5",
    ] {
        std::fs::write(d.join(name), b"half").unwrap();
    }
    std::fs::write(d.join("notes.tmp1"), b"not ours").unwrap();
    run(&d, &s, &identity(1), true, None).unwrap();
    let left: Vec<String> = std::fs::read_dir(&d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        left.iter().all(|n| !n.contains(".bin.tmp")),
        "stale temporaries left: {left:?}"
    );
    assert!(left.contains(&"notes.tmp1".to_string()));
    // A fresh start beside a solver file without its stage.bin does not load it.
    std::fs::remove_file(d.join("stage.bin")).unwrap();
    let (d2, _) = interrupted("stale-orphan");
    std::fs::copy(d2.join("solver-0.bin"), d.join("solver-0.bin")).unwrap();
    let fresh = run(&d, &s, &identity(1), false, None).unwrap();
    assert_eq!(fresh.history.len(), 10);
    assert_eq!(fresh.history[0].iteration, 1);
    let _ = std::fs::remove_dir_all(&d);
    let _ = std::fs::remove_dir_all(&d2);
}

#[test]
fn schedules_that_mean_nothing_are_refused_before_running() {
    let d = dir("schedule");
    let base = schedule(0.01);
    let with = |f: &dyn Fn(&mut Stage)| {
        let mut s = base.clone();
        f(&mut s.stages[0]);
        s
    };
    let cases = [
        (
            with(&|s| s.lr = -0.01),
            "schedule: stage 0: lr = -0.01 must be positive",
        ),
        (
            with(&|s| s.lr = f64::NAN),
            "stage 0: lr = NaN must be positive",
        ),
        (
            with(&|s| s.large_steps = -5.0),
            "stage 0: large_steps = -5 must be finite and >= 0",
        ),
        (
            with(&|s| s.albedo_tv = -0.1),
            "stage 0: albedo_tv = -0.1 must be finite and >= 0",
        ),
        (
            with(&|s| s.albedo_tv = f64::INFINITY),
            "stage 0: albedo_tv = inf must be finite and >= 0",
        ),
        (
            with(&|s| s.time_downsample = 0),
            "stage 0: time_downsample = 0",
        ),
        (
            with(&|s| s.remesh = Some(f64::INFINITY)),
            "stage 0: remesh = inf must be positive",
        ),
        (
            with(&|s| {
                s.fit_positions = false;
                s.fit_albedo = false
            }),
            "fits nothing",
        ),
        (
            Schedule {
                checkpoint_every: 0,
                ..base.clone()
            },
            "checkpoint_every = 0",
        ),
    ];
    for (s, says) in cases {
        let e = err(run(&d, &s, &identity(1), false, None));
        assert!(e.contains(says), "want {says:?}: {e}");
        assert!(!d.join("stage.bin").exists(), "{says}: ran");
    }
    // L-BFGS's lr 0 means its default first step.
    let mut lbfgs = base.clone();
    lbfgs.stages[0].solver = SolverKind::Lbfgs;
    lbfgs.stages[0].lr = 0.0;
    assert!(lbfgs.check().is_ok());
    let _ = std::fs::remove_dir_all(&d);
}

/// The schedule's identity hash (postcard of the `Schedule`) of a schedule that sets no
/// field added since checkpoint format 2 is the one format 2 wrote, so a fit checkpointed
/// by an earlier build still resumes. A new `Stage` field must keep this (serialize
/// nothing at its default: `skip_serializing_if`), or raise `FORMAT_VERSION`.
#[test]
fn a_schedule_without_new_fields_hashes_as_format_2_did() {
    let stage = |iters, solver, lr| Stage {
        large_steps: 2.0,
        laplacian: 0.5,
        fit_albedo: true,
        remesh_factor: Some(0.4),
        time_downsample: 4,
        model: Some("tri3".into()),
        spp: Some(16),
        ..Stage::new(iters, solver, lr)
    };
    let s = Schedule {
        stages: vec![
            stage(100, SolverKind::Adam, 0.03),
            stage(20, SolverKind::Lbfgs, 0.0),
        ],
        checkpoint_every: 5,
    };
    // Computed by the build before `albedo_tv` (commit 4568e57).
    assert_eq!(optim::checkpoint::hash_postcard(&s), 0xbce7_0ba2_e00a_6081);
    // A schedule that uses a new field hashes differently (another schedule).
    let mut tv = s.clone();
    tv.stages[1].albedo_tv = 0.01;
    assert_ne!(optim::checkpoint::hash_postcard(&tv), 0xbce7_0ba2_e00a_6081);
}
