//! The fit: a schedule of stages, each an argmin run on a fixed topology, with the mesh
//! remeshed between stages and everything checkpointed so a killed fit resumes where it
//! stood and ends where an uninterrupted one does.
//!
//! Stage `s` runs [`Adam`] (noisy Monte Carlo gradients) or [`Lbfgs`] (projected,
//! with a capped Armijo line search; the noise-free `tri3` model) on the [`MeshProblem`] of the
//! stage's objective (the renderer at the stage's resolution, from the
//! [`ObjectiveFactory`]) for `iters` iterations.
//!
//! Files in the checkpoint directory, each written atomically:
//! - `stage.bin`: the stage to run next, the mesh it starts from (after remeshing), the
//!   loss history and counters so far;
//! - `solver-<s>.bin`: argmin's solver and iteration state for stage `s` plus the loss
//!   history, every `checkpoint_every` iterations (named per stage, so a stale file of
//!   an earlier stage is never loaded into a later one).
//!
//! Both are [`crate::checkpoint`] envelopes (magic number, format version, checksum)
//! stamped with the fit's [`Identity`]: the caller's components (Umbra: scene,
//! measurement, model, options) plus `schedule` (its postcard bytes) and `initial mesh`
//! (its bits). `resume` refuses a file written for another identity, naming what differs,
//! and a damaged one, naming the file; a stage file whose mesh is empty, out of range or
//! not finite is refused too. Temporaries left by a kill (`.stage.bin.tmp<pid>`,
//! `.solver-<s>.bin.tmp<pid>`) are removed on every start; a fresh start also removes
//! solver files left without their `stage.bin`.
//!
//! The schedule is checked first ([`Schedule::check`]): a negative step size, a zero
//! downsampling factor and the like are refused before anything runs.
//!
//! Determinism: a stage's objective must give the same result for the same parameters
//! (Umbra seeds its samples from the parameters), so the resumed and the uninterrupted
//! runs evaluate the same sequence.

use crate::adam::Adam;
use crate::checkpoint::{
    self, hash_mesh, hash_postcard, mismatch_error, remove_stale_temporaries, write_atomic,
    CheckFinite, History, Identity, Kind, LossRecord, SolverCheckpoint,
};
use crate::lbfgs::Lbfgs;
use crate::mesh::Mesh;
use crate::problem::{Breakdown, MeshObjective, MeshProblem, ProblemSettings};
pub use crate::schedule::{Schedule, SolverKind, Stage};
use argmin::core::observers::{Observe, ObserverMode};
use argmin::core::{Error, Executor, IterState, State as _, KV};
use serde::{Deserialize, Serialize};
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::rc::Rc;

/// Builds each stage's objective (the renderer set up at the stage's resolution).
pub trait ObjectiveFactory {
    /// The objective of stage `index`, which starts from `start` (the mesh the stage's
    /// checkpoint holds, so a resumed stage is built from the same mesh: an objective may
    /// calibrate itself on it, e.g. a detector response, and stay deterministic).
    fn objective(
        &mut self,
        stage: &Stage,
        index: usize,
        start: &Mesh,
    ) -> Result<Box<dyn MeshObjective>, String>;
}

/// Remeshes between stages: `(mesh, target edge) -> mesh`.
pub type Remesher<'a> = &'a dyn Fn(&Mesh, f64) -> Result<Mesh, String>;

#[derive(Debug, thiserror::Error)]
pub enum FitError {
    #[error("{0}")]
    Io(String),
    #[error("stage {stage}: {message}")]
    Stage { stage: usize, message: String },
    #[error("stage {stage}, iteration {iteration}: {message}")]
    Step {
        stage: usize,
        /// Over the whole fit, from 1 (as in the loss history).
        iteration: u64,
        message: String,
    },
    #[error("schedule: {0}")]
    Schedule(String),
    /// A checkpoint that cannot be resumed (damaged, or written for another fit).
    #[error("{0}")]
    Checkpoint(String),
    #[error("interrupted at iteration {iteration}; the last checkpoint is in {dir} (run again with --resume)")]
    Interrupted { iteration: u64, dir: PathBuf },
}

/// What [`fit`] returns.
#[derive(Clone, Debug)]
pub struct FitOutcome {
    pub mesh: Mesh,
    pub history: Vec<LossRecord>,
    /// Optimiser steps rejected (non-finite cost or failed render), all stages.
    pub rejected_steps: u64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
struct StageFile {
    stage: usize,
    mesh: Mesh,
    history: Vec<LossRecord>,
    rejected: u64,
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> FitError {
    FitError::Io(format!("{}: {e}", path.display()))
}

fn save_stage(path: &Path, identity: &Identity, s: &StageFile) -> Result<(), FitError> {
    let bytes = checkpoint::encode(Kind::Stage, identity, s).map_err(|e| io_err(path, e))?;
    write_atomic(path, &bytes).map_err(|e| io_err(path, e))
}

/// Reads `stage.bin` for a resume: refused if damaged, written for another identity,
/// or holding a mesh that cannot be fitted.
fn load_stage(path: &Path, identity: &Identity, stages: usize) -> Result<StageFile, FitError> {
    if !path.exists() {
        return Err(io_err(path, "cannot resume: no checkpoint here"));
    }
    let (saved, s): (Identity, StageFile) =
        checkpoint::read(path, Kind::Stage).map_err(FitError::Checkpoint)?;
    if let Some(d) = identity.differences(&saved) {
        return Err(FitError::Checkpoint(mismatch_error(path, &d)));
    }
    let bad = |what: String| {
        FitError::Checkpoint(format!(
            "{}: corrupt checkpoint: {what}; delete it",
            path.display()
        ))
    };
    if s.stage > stages {
        return Err(bad(format!("stage {} of a schedule of {stages}", s.stage)));
    }
    let m = &s.mesh;
    if m.vertices.len() < 3 || m.faces.is_empty() {
        return Err(bad(format!(
            "its mesh has {} vertices and {} faces",
            m.vertices.len(),
            m.faces.len()
        )));
    }
    if let Some(f) = m
        .faces
        .iter()
        .find(|f| f.iter().any(|&i| i as usize >= m.vertices.len()))
    {
        return Err(bad(format!(
            "face {f:?} of a mesh of {} vertices",
            m.vertices.len()
        )));
    }
    if !m.vertex_values.is_empty() && m.vertex_values.len() != m.vertices.len() {
        return Err(bad(format!(
            "{} vertex values for {} vertices",
            m.vertex_values.len(),
            m.vertices.len()
        )));
    }
    let flat: Vec<f64> = m.vertices.iter().flatten().copied().collect();
    let what = checkpoint::first_non_finite("mesh vertex coordinate", &flat)
        .or_else(|| checkpoint::first_non_finite("mesh vertex value", &m.vertex_values))
        .or_else(|| s.history.iter().find_map(|r| r.non_finite()));
    if let Some(what) = what {
        return Err(bad(format!("{what} is not finite")));
    }
    Ok(s)
}

/// The identity of a fit's checkpoints: the caller's components, the schedule and the
/// initial mesh.
pub fn full_identity(identity: &Identity, schedule: &Schedule, initial: &Mesh) -> Identity {
    identity
        .clone()
        .with(
            "schedule",
            hash_postcard(schedule),
            format!(
                "{} stages, {} iterations",
                schedule.stages.len(),
                schedule.total_iters()
            ),
        )
        .with(
            "initial mesh",
            hash_mesh(initial),
            format!(
                "{} vertices, {} faces",
                initial.vertices.len(),
                initial.faces.len()
            ),
        )
}

/// The identity a checkpoint file in `dir` (`stage.bin`) was written with, checking
/// only its envelope (magic number, version, checksum).
pub fn checkpoint_identity(dir: &Path) -> Result<Identity, String> {
    checkpoint::read_identity(&dir.join("stage.bin"), Kind::Stage)
}

/// Called after every iteration with its record; returning `false` stops the fit (a
/// checkpoint of the last multiple of `checkpoint_every` stays for `--resume`).
pub type Progress = Rc<RefCell<dyn FnMut(&LossRecord) -> bool>>;

struct FitObserver {
    stage: usize,
    offset: u64,
    history: History,
    last: Rc<RefCell<Breakdown>>,
    progress: Progress,
}

type State = IterState<Vec<f64>, Vec<f64>, (), (), (), f64>;

impl Observe<State> for FitObserver {
    fn observe_iter(&mut self, state: &State, _kv: &KV) -> Result<(), Error> {
        let last = self.last.borrow().clone();
        let record = LossRecord {
            iteration: self.offset + state.get_iter() + 1,
            stage: self.stage,
            cost: state.get_cost(),
            data_loss: last.data_loss,
            smoothness: last.smoothness + last.value_tv,
            report: last.report,
        };
        self.history.borrow_mut().push(record.clone());
        if (self.progress.borrow_mut())(&record) {
            Ok(())
        } else {
            Err(Error::msg("interrupted"))
        }
    }
}

/// The target edge length a stage remeshes `mesh` to, if it remeshes.
fn remesh_edge(stage: &Stage, mesh: &Mesh) -> Option<f64> {
    stage.remesh.or_else(|| {
        stage
            .remesh_factor
            .map(|f| f * crate::laplacian::mean_edge(mesh))
    })
}

/// Runs `schedule` from `initial` (or, with `resume`, from the checkpoints in `dir`).
/// `identity` lists what the checkpoints depend on besides the schedule and the initial
/// mesh ([`full_identity`] adds those); a resume from checkpoints of another identity is
/// refused, naming the components that differ.
#[allow(clippy::too_many_arguments)]
pub fn fit(
    initial: &Mesh,
    schedule: &Schedule,
    factory: &mut dyn ObjectiveFactory,
    remesher: Remesher,
    dir: &Path,
    resume: bool,
    identity: &Identity,
    progress: Progress,
) -> Result<FitOutcome, FitError> {
    schedule.check().map_err(FitError::Schedule)?;
    if let Some(i) = schedule
        .stages
        .iter()
        .position(|s| s.remesh_pitch.is_some())
    {
        return Err(FitError::Schedule(format!(
            "stage {i}: remesh_pitch is in scan pitches, which the caller must turn into remesh (m) before the fit"
        )));
    }
    let identity = &full_identity(identity, schedule, initial);
    let stage_path = dir.join("stage.bin");
    remove_stale_temporaries(dir);
    let mut current = if resume {
        load_stage(&stage_path, identity, schedule.stages.len())?
    } else {
        if stage_path.exists() {
            return Err(io_err(
                &stage_path,
                "a checkpoint of an earlier fit is here: pass --resume to continue it, or choose another output directory",
            ));
        }
        // Solver files without their stage.bin belong to no fit that can be resumed.
        if let Ok(entries) = std::fs::read_dir(dir) {
            for e in entries.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                let stage_number = name
                    .strip_prefix("solver-")
                    .and_then(|n| n.strip_suffix(".bin"))
                    .filter(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
                if stage_number.is_some() {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
        let first = schedule.stages.first();
        let mesh = match first.and_then(|s| s.remesh) {
            Some(edge) => {
                remesher(initial, edge).map_err(|message| FitError::Stage { stage: 0, message })?
            }
            None => initial.clone(),
        };
        let s = StageFile {
            stage: 0,
            mesh,
            history: Vec::new(),
            rejected: 0,
        };
        save_stage(&stage_path, identity, &s)?;
        s
    };
    while current.stage < schedule.stages.len() {
        let index = current.stage;
        let stage = &schedule.stages[index];
        let stage_err = |message: String| FitError::Stage {
            stage: index,
            message,
        };
        let solver_path = dir.join(format!("solver-{index}.bin"));
        if solver_path.exists() {
            let saved = checkpoint::read_identity(&solver_path, Kind::Solver)
                .map_err(FitError::Checkpoint)?;
            if let Some(d) = identity.differences(&saved) {
                return Err(FitError::Checkpoint(mismatch_error(&solver_path, &d)));
            }
        }
        let objective = factory
            .objective(stage, index, &current.mesh)
            .map_err(stage_err)?;
        let settings = ProblemSettings {
            large_steps: stage.large_steps,
            laplacian: stage.laplacian,
            fit_positions: stage.fit_positions,
            fit_values: stage.fit_albedo,
            value_scale: stage.albedo_step,
            value_tv: stage.albedo_tv,
        };
        let problem = MeshProblem::new(objective, &current.mesh, settings);
        let theta0 = problem.encode(&current.mesh);
        let history: History = Rc::new(RefCell::new(current.history.clone()));
        let observer = FitObserver {
            stage: index,
            offset: current.history.len() as u64,
            history: history.clone(),
            last: problem.last_handle(),
            progress: progress.clone(),
        };
        let checkpoint = SolverCheckpoint {
            path: solver_path,
            every: schedule.checkpoint_every,
            history: history.clone(),
            identity: identity.clone(),
        };
        let run = |e: Error| -> FitError {
            let done = history.borrow().len() as u64;
            if e.to_string() == "interrupted" {
                FitError::Interrupted {
                    iteration: done,
                    dir: dir.to_path_buf(),
                }
            } else {
                FitError::Step {
                    stage: index,
                    iteration: done + 1,
                    message: format!(
                        "{e}; the fit stopped, its last checkpoint is in {}",
                        dir.display()
                    ),
                }
            }
        };
        let (problem, theta, rejected) = match stage.solver {
            SolverKind::Adam => {
                let res = Executor::new(problem, Adam::new(stage.lr))
                    .configure(|s| s.param(theta0).max_iters(stage.iters))
                    .add_observer(observer, ObserverMode::Always)
                    .checkpointing(checkpoint)
                    .run()
                    .map_err(run)?;
                let theta = res.state.param.clone();
                let rejected = res.solver.rejected;
                (res.problem.problem, theta, rejected)
            }
            SolverKind::Lbfgs => {
                let res = Executor::new(problem, Lbfgs::new(stage.lr))
                    .configure(|s| s.param(theta0).max_iters(stage.iters))
                    .add_observer(observer, ObserverMode::Always)
                    .checkpointing(checkpoint)
                    .run()
                    .map_err(run)?;
                let theta = res.state.best_param.clone().or(res.state.param.clone());
                let rejected = res.solver.rejected;
                (res.problem.problem, theta, rejected)
            }
        };
        let problem = problem.ok_or_else(|| stage_err("argmin lost the problem".into()))?;
        let theta =
            theta.ok_or_else(|| stage_err("the optimiser returned no parameters".into()))?;
        let mesh = problem.decode(&theta).map_err(stage_err)?;
        let next = index + 1;
        let mesh = match schedule
            .stages
            .get(next)
            .and_then(|s| remesh_edge(s, &mesh))
        {
            Some(edge) => remesher(&mesh, edge).map_err(|message| FitError::Stage {
                stage: next,
                message,
            })?,
            None => mesh,
        };
        current = StageFile {
            stage: next,
            mesh,
            history: history.borrow().clone(),
            rejected: current.rejected + rejected,
        };
        save_stage(&stage_path, identity, &current)?;
        let _ = std::fs::remove_file(dir.join(format!("solver-{index}.bin")));
    }
    Ok(FitOutcome {
        mesh: current.mesh,
        history: current.history,
        rejected_steps: current.rejected,
    })
}
