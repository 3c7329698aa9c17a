//! Geometry: hidden meshes (a BVH, or SIMD packets when small) and the relay wall (an
//! analytic parallelogram), the surfaces' shading data, and the sampling routines with
//! their pdfs.

pub mod accel;
pub mod blockers;
pub mod mesh;
pub mod overlap;
pub mod packet;
pub mod point_shadow;
pub mod ray_log;
pub mod sampling;
pub mod shapes;
pub mod silhouette;
pub mod wall_plane;

pub use accel::{HiddenTri, Hit, SceneGeometry, SurfaceKind};
