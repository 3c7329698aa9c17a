//! Geometry: hidden meshes and the relay wall in one BVH, the surfaces' shading data,
//! and the sampling routines with their pdfs.

pub mod accel;
pub mod mesh;
pub mod overlap;
pub mod sampling;
pub mod shapes;
pub mod silhouette;

pub use accel::{HiddenTri, Hit, SceneGeometry, SurfaceKind};
