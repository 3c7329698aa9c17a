//! The fit's schedule: its stages, each field with its default (the serde defaults a
//! schedule file gets, and [`Stage::new`]), and the check that refuses a schedule that
//! cannot mean what it says ([`Schedule::check`]). [`crate::fit()`] runs it.
//!
//! A schedule's postcard bytes hash into its checkpoints' identity
//! ([`crate::fit::full_identity`]); a field added to [`Stage`] serializes nothing at its
//! default (`skip_serializing_if`), so a schedule that does not use it keeps the hash an
//! earlier build wrote and its checkpoints still resume (optim/tests/checkpoint.rs pins
//! one). Schedules are only ever serialized for that hash and read from TOML, never
//! read back from postcard (which skipped fields would break).

use serde::{Deserialize, Serialize};

/// The optimiser of a stage.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SolverKind {
    /// Adam, for Monte Carlo gradients.
    #[default]
    Adam,
    /// L-BFGS with a capped projected Armijo line search ([`crate::Lbfgs`]), for the noise-free
    /// `tri3` model.
    Lbfgs,
}

/// One stage of the schedule.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Stage {
    /// Iterations of the optimiser.
    pub iters: u64,
    #[serde(default)]
    pub solver: SolverKind,
    /// Adam's step size, in the units of the parameters (m for positions); for L-BFGS the
    /// largest move of any parameter in its first step (later steps: at most 20x that).
    #[serde(default = "default_lr")]
    pub lr: f64,
    /// `λ` of the large-steps parameterisation `u = (I + λL) x` (0: off).
    #[serde(default)]
    pub large_steps: f64,
    /// Weight of the Laplacian smoothness term.
    #[serde(default)]
    pub laplacian: f64,
    /// Fit the vertex positions (default); `false` with `fit_albedo` fits albedo alone on
    /// the fixed surface.
    #[serde(default = "yes")]
    pub fit_positions: bool,
    /// Fit per-vertex albedo too.
    #[serde(default)]
    pub fit_albedo: bool,
    /// Albedo steps are this many times `lr` (albedo is in [0, 1], positions in m).
    #[serde(default = "default_albedo_step")]
    pub albedo_step: f64,
    /// Weight of the edge-preserving total variation of the albedo
    /// ([`crate::tv`]: `Σ_e ℓ_e φ(a_i − a_j) / √A`, Charbonnier `φ`, edge lengths and
    /// area of the stage's starting mesh), which favours piecewise-constant albedo with
    /// sharp edges; 0 (default): off. Has effect only with `fit_albedo`. Not serialized
    /// at 0 (`skip_serializing_if`), so the schedule's checkpoint identity (its postcard
    /// hash) of a schedule without it is the one earlier builds wrote.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub albedo_tv: f64,
    /// Remesh to this target edge length (m) before the stage.
    #[serde(default)]
    pub remesh: Option<f64>,
    /// Remesh to this fraction of the mesh's mean edge length before the stage (used
    /// when `remesh` is not given).
    #[serde(default)]
    pub remesh_factor: Option<f64>,
    /// Remesh to this many scan pitches (the spacing of the fitted scan's points) before
    /// the stage: per-vertex albedo then resolves what the scan does. Only the caller knows
    /// the scan, so it turns this into `remesh` before the fit (`umbra::fit` does;
    /// [`crate::fit::fit`] refuses it unresolved); not with `remesh`. Not serialized when
    /// absent, so schedules without it keep their checkpoint identity.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub remesh_pitch: Option<f64>,
    /// Sum this many time bins of the measurement (and the render) into one.
    #[serde(default = "one")]
    pub time_downsample: u32,
    /// Average `k x k` blocks of scan points.
    #[serde(default = "one")]
    pub scan_downsample: u32,
    /// Light-transport model for this stage (the renderer's name; `None`: the fit's).
    #[serde(default)]
    pub model: Option<String>,
    /// Samples per measurement for Monte Carlo models (`None`: the fit's).
    #[serde(default)]
    pub spp: Option<u32>,
}

impl Stage {
    /// A stage of `iters` iterations of `solver` at step `lr`, every other field at the
    /// default a schedule file gives it (the serde defaults above).
    pub fn new(iters: u64, solver: SolverKind, lr: f64) -> Stage {
        Stage {
            iters,
            solver,
            lr,
            large_steps: 0.0,
            laplacian: 0.0,
            fit_positions: yes(),
            fit_albedo: false,
            albedo_step: default_albedo_step(),
            albedo_tv: 0.0,
            remesh: None,
            remesh_factor: None,
            remesh_pitch: None,
            time_downsample: one(),
            scan_downsample: one(),
            model: None,
            spp: None,
        }
    }
}

fn default_lr() -> f64 {
    0.01
}

fn default_albedo_step() -> f64 {
    10.0
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn yes() -> bool {
    true
}

fn one() -> u32 {
    1
}

/// The stages, in order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Schedule {
    #[serde(rename = "stage")]
    pub stages: Vec<Stage>,
    /// Iterations between solver checkpoints.
    #[serde(default = "default_every")]
    pub checkpoint_every: u64,
}

fn default_every() -> u64 {
    5
}

impl Schedule {
    /// Refuses a schedule that cannot mean what it says: the first problem as
    /// `stage <i>: <field> = <value> must be …` (stages counted from 0, as in the loss
    /// history), or `checkpoint_every = 0 …`.
    pub fn check(&self) -> Result<(), String> {
        if self.stages.is_empty() {
            return Err("the schedule has no [[stage]]".into());
        }
        if self.checkpoint_every == 0 {
            return Err(
                "checkpoint_every = 0 must be at least 1 (iterations between checkpoints)".into(),
            );
        }
        for (i, s) in self.stages.iter().enumerate() {
            s.check().map_err(|e| format!("stage {i}: {e}"))?;
        }
        Ok(())
    }

    /// Iterations of all stages.
    pub fn total_iters(&self) -> u64 {
        self.stages.iter().map(|s| s.iters).sum()
    }
}

impl Stage {
    /// [`Schedule::check`] for one stage.
    pub fn check(&self) -> Result<(), String> {
        let finite_at_least = |name: &str, v: f64, what: &str| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(format!("{name} = {v} must be {what}"))
            }
        };
        // `iters = 0` is allowed: such a stage evaluates its starting mesh without a step
        // (a baseline: python/tests/test_fit_mitransient.py fits "the initial plane").
        match self.solver {
            SolverKind::Adam if !(self.lr.is_finite() && self.lr > 0.0) => {
                return Err(format!(
                    "lr = {} must be positive and finite (Adam's step size, m)",
                    self.lr
                ))
            }
            SolverKind::Lbfgs => finite_at_least(
                "lr",
                self.lr,
                "positive and finite (L-BFGS's first step, m; 0 for the default 0.01)",
            )?,
            _ => {}
        }
        finite_at_least(
            "large_steps",
            self.large_steps,
            "finite and >= 0 (λ of the large-steps parameterisation; 0: off)",
        )?;
        finite_at_least(
            "laplacian",
            self.laplacian,
            "finite and >= 0 (weight of the smoothness term)",
        )?;
        finite_at_least(
            "albedo_tv",
            self.albedo_tv,
            "finite and >= 0 (weight of the albedo's total variation; 0: off)",
        )?;
        if !(self.albedo_step.is_finite() && self.albedo_step > 0.0) {
            return Err(format!(
                "albedo_step = {} must be positive and finite",
                self.albedo_step
            ));
        }
        if let (Some(e), Some(k)) = (self.remesh, self.remesh_pitch) {
            return Err(format!(
                "remesh = {e} and remesh_pitch = {k} both set: give the edge in metres or in scan pitches, not both"
            ));
        }
        for (name, v) in [
            ("remesh", self.remesh),
            ("remesh_factor", self.remesh_factor),
            ("remesh_pitch", self.remesh_pitch),
        ] {
            if let Some(v) = v {
                if !(v.is_finite() && v > 0.0) {
                    return Err(format!("{name} = {v} must be positive and finite"));
                }
            }
        }
        for (name, v) in [
            ("time_downsample", self.time_downsample),
            ("scan_downsample", self.scan_downsample),
        ] {
            if v == 0 {
                return Err(format!(
                    "{name} = 0 must be at least 1 (1: full resolution)"
                ));
            }
        }
        if self.spp == Some(0) {
            return Err("spp = 0 must be at least 1".into());
        }
        if !self.fit_positions && !self.fit_albedo {
            return Err(
                "fit_positions = false with fit_albedo = false fits nothing: set one".into(),
            );
        }
        Ok(())
    }
}
