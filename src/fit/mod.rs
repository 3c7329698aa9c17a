//! Fitting hidden geometry to a measured transient: Umbra's side of the `optim` crate.
//!
//! - [`objective`]: the renderer as an `optim::MeshObjective` (scale-free relative L2,
//!   path-replay gradients);
//! - [`intensity`]: the closed-form scale and background of the loss;
//! - [`time_offset`]: the comparison through the detector's jitter and an unknown
//!   time offset;
//! - [`resolution`]: the coarse-to-fine schedule's downsampled measurement and scene;
//! - [`reconstruction`]: the backprojection and LCT initial meshes and the picture of
//!   the fit next to the LCT (or a backprojection);
//! - [`seen`]: the fitted surface seen from the wall (albedo and depth per scan point);
//! - [`init`]: initial meshes (a plane or a sphere in front of the wall at the depth the
//!   data's first returns imply);
//! - [`request`]: a fit as the CLI and Python ask for it (measurement, defaults,
//!   truth), the one entry point of both;
//! - [`starts`]: `--init auto`, a fit from each of several starts, one kept;
//! - [`support`]: which fitted faces some measurement lights and sees (the rest are
//!   left out of `mesh.obj`);
//! - [`determined`]: which fitted faces return a signal the data can tell from noise
//!   (the rest are left out of `mesh.obj`);
//! - [`run`]: the whole fit with its outputs (mesh, loss curve, transients side by side,
//!   checkpoints).

pub mod capture;
pub mod capture_options;
pub mod determined;
pub mod init;
pub mod intensity;
mod iters;
pub mod linear_fit;
pub mod metrics;
pub mod objective;
mod outputs;
pub mod point_background;
pub mod point_floor;
mod prepare;
pub mod reconstruction;
pub mod request;
mod request_options;
pub mod resolution;
pub mod run;
pub mod score;
pub mod seen;
pub mod starts;
pub mod support;
pub mod time_offset;

pub use intensity::{intensity_l2, Background, Intensity, IntensityModel};
pub use objective::UmbraObjective;
pub use prepare::to_mesh;

use crate::geometry::mesh::TriMesh;

/// A renderer mesh as the fit's `f64` mesh (positions and triangles; per-vertex albedo,
/// if any, as vertex values).
pub fn fit_mesh(m: &TriMesh) -> optim::Mesh {
    optim::Mesh {
        vertices: m
            .positions
            .iter()
            .map(|p| [p.x as f64, p.y as f64, p.z as f64])
            .collect(),
        faces: m.triangles.clone(),
        vertex_values: m
            .vertex_albedo
            .as_ref()
            .map_or(Vec::new(), |a| a.iter().map(|&v| v as f64).collect()),
    }
}
pub use request::{FitOutcome, FitRequest, Measurement};
pub use run::{default_schedule, fit, initial_mesh, FitConfig, FitReport, Init};
