//! Umbra: a differentiable transient renderer for non-line-of-sight (NLOS) imaging.
//!
//! See `README.md` for the user's view and `../shared/DESIGN.md` for conventions and
//! physics. Modules follow the concepts: [`scene`] (what is rendered), [`geometry`]
//! (meshes, BVH, sampling), [`film`] (time bins and kernels), [`rng`], [`transport`]
//! (the estimators), [`io`] (files).

pub mod adjoint;
pub mod bench;
pub mod error;
pub mod film;
pub mod fit;
pub mod geometry;
pub mod io;
pub mod recon;
pub mod rng;
pub mod scene;
pub mod threads;
pub mod transport;

pub use error::{Error, Result};
pub use scene::Scene;
