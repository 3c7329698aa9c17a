//! Fitting a hidden triangle mesh to a measured transient (the inverse problem of NLOS
//! imaging), independent of the renderer: the renderer enters as a [`MeshObjective`]
//! that returns a loss and its gradient with respect to the vertex positions and
//! per-vertex values. Umbra implements it (`umbra::fit`); tests here use toy objectives.

pub mod adam;
pub mod atomic;
pub mod checkpoint;
pub mod fit;
pub mod laplacian;
pub mod lbfgs;
pub mod lock;
pub mod mesh;
pub mod problem;
pub mod remesh;
pub mod schedule;
pub mod step;
pub mod tv;

pub use adam::Adam;
pub use fit::{fit, FitError, FitOutcome, ObjectiveFactory, Schedule, SolverKind, Stage};
pub use lbfgs::Lbfgs;
pub use mesh::Mesh;
pub use problem::{Evaluation, MeshObjective, MeshProblem, ProblemSettings, Project};
