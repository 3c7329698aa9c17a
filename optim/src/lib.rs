//! Fitting a hidden triangle mesh to a measured transient (the inverse problem of NLOS
//! imaging), independent of the renderer: the renderer enters as a [`MeshObjective`]
//! that returns a loss and its gradient with respect to the vertex positions and
//! per-vertex values. Umbra implements it (`umbra::fit`); tests here use toy objectives.

pub mod mesh;
pub mod remesh;

pub use mesh::Mesh;
