//! Fitting hidden geometry to a measured transient: Umbra's side of the `optim` crate.
//!
//! - [`objective`]: the renderer as an `optim::MeshObjective` (scale-free relative L2,
//!   path-replay gradients);
//! - [`resolution`]: the coarse-to-fine schedule's downsampled measurement and scene;
//! - [`init`]: initial meshes (a plane or a sphere in front of the wall at the depth the
//!   data's first returns imply);
//! - [`run`]: the whole fit with its outputs (mesh, loss curve, transients side by side,
//!   checkpoints).

pub mod init;
pub mod metrics;
pub mod objective;
pub mod resolution;
pub mod run;

pub use objective::{scaled_l2, UmbraObjective};
pub use run::{default_schedule, fit, initial_mesh, FitConfig, FitReport, Init};
