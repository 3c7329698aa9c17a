//! Isotropic remeshing in the style of Botsch & Kobbelt, "A remeshing approach to
//! multiresolution modeling" (SGP 2004), used between optimisation stages so the fitted
//! mesh can grow, shrink and keep well-shaped triangles.
//!
//! Each iteration, for a target edge length `L`:
//! 1. split every edge longer than 4/3 `L` at its midpoint, longest first (longest-edge
//!    bisection: it does not degrade the smallest angles and stays bounded on slivers);
//! 2. collapse edges shorter than 4/5 `L` when the collapse keeps the mesh manifold (link
//!    condition, no valence below 3), creates no edge longer than 4/3 `L` and turns no face
//!    normal by more than 60° (so none flips); interior edges collapse to their midpoint;
//! 3. flip edges where that brings the valences closer to 6 (4 on the boundary), except
//!    across creases (face normals more than 60° apart) and where a face would fold;
//! 4. tangential relaxation: each vertex moves by `smoothing` toward the area-weighted
//!    centroid of its neighbours, within its tangent plane, and is projected back onto the
//!    input surface (nearest point through a uniform grid, skipping triangles that face
//!    away from the vertex normal when possible, i.e. the far side of thin parts). A move
//!    that would degenerate or flip a face is skipped.
//!
//! Open meshes: boundary edges are split and collapsed along the boundary, boundary vertices
//! stay boundary vertices (a boundary vertex never merges into an interior one, nor is an
//! interior edge between two boundary vertices collapsed), so the number of boundary loops
//! and the Euler characteristic are kept. With `keep_boundary`, boundary vertices relax
//! toward the midpoint of their two boundary neighbours and are projected onto the input's
//! boundary polyline, and its corners (where it turns by more than 35°) are never moved or
//! removed: the outline is kept exactly. Without it, they relax along the line through
//! their two boundary neighbours and are projected onto the surface: the outline can drift
//! slightly and a corner vertex can be collapsed away (cutting the corner at coarse `L`).
//!
//! Values (`Mesh::vertex_values`) are interpolated linearly at splits and collapses, and
//! every projected vertex takes the value interpolated (barycentrically) from the input at
//! its new position, so a function linear in space stays exactly linear and values stay
//! within the input's range. Face winding is kept, and everything iterates by index (no
//! hash maps), so the result is deterministic.
//!
//! Input problems: non-finite coordinates or values, out-of-range indices, a values count
//! that matches neither 0 nor the vertex count, edges with more than two faces,
//! inconsistently oriented neighbours and non-manifold vertices are errors. Repaired (and
//! documented): vertices with bit-identical positions are welded (unless that alone makes
//! the mesh non-manifold), faces repeating a vertex are dropped, repeated faces are kept
//! once, unreferenced vertices are dropped. Zero-area faces are accepted; no operator turns
//! a non-degenerate face into a degenerate one, and collapses and flips usually remove them.
//!
//! Limitations: sharp creases are not detected as features (flips across them are refused
//! but collapses and relaxation chamfer them by up to about 0.2 `L`); projection onto a
//! very rough or self-intersecting input can leave some short edges whose collapse would
//! fold a face.

mod geom;
mod halfedge;
mod ops;
mod prepare;
mod relax;
mod spatial;
mod stats;

use serde::{Deserialize, Serialize};

use crate::mesh::Mesh;
pub use geom::closest_on_triangle;
pub use stats::{boundary_loops, edge_length_stats, is_manifold};

/// The remesher refuses to produce more faces than this (about 80 bytes of working memory
/// per face).
pub const MAX_FACES: usize = 5_000_000;

/// Settings of [`remesh`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RemeshOptions {
    /// Target edge length (m), finite and > 0. Edges end up roughly within
    /// [4/5, 4/3] of it, before relaxation.
    pub target_edge: f64,
    /// Split / collapse / flip / relax rounds (0 returns the validated, repaired input).
    pub iterations: usize,
    /// Tangential relaxation weight in [0, 1] (0: vertices are only projected back onto
    /// the input; 1: they move all the way to the centroid of their neighbours).
    pub smoothing: f64,
    /// Keep the boundary's outline: boundary vertices stay on the input's boundary
    /// polyline and its corners are never moved or collapsed.
    pub keep_boundary: bool,
}

impl RemeshOptions {
    /// Target edge `target_edge`, 5 iterations, full relaxation, boundary kept.
    pub fn new(target_edge: f64) -> Self {
        RemeshOptions {
            target_edge,
            iterations: 5,
            smoothing: 1.0,
            keep_boundary: true,
        }
    }
}

/// Why [`remesh`] refused its input.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RemeshError {
    #[error("remesh: target edge length must be finite and > 0, got {0}")]
    InvalidTargetEdge(f64),
    #[error("remesh: smoothing must be in [0, 1], got {0}")]
    InvalidSmoothing(f64),
    #[error("remesh: {values} vertex values for {vertices} vertices (must be 0 or equal)")]
    ValueCount { values: usize, vertices: usize },
    #[error("remesh: vertex {vertex} has a non-finite coordinate")]
    NonFiniteVertex { vertex: usize },
    #[error("remesh: vertex {vertex} has a non-finite value")]
    NonFiniteValue { vertex: usize },
    #[error("remesh: face {face} uses vertex {index}, but there are {vertex_count} vertices")]
    IndexOutOfRange {
        face: usize,
        index: u32,
        vertex_count: usize,
    },
    #[error("remesh: the mesh has no usable (non-degenerate) face")]
    NoFaces,
    #[error("remesh: edge {a}-{b} has more than two faces")]
    NonManifoldEdge { a: u32, b: u32 },
    #[error("remesh: the two faces at edge {a}-{b} are oriented inconsistently")]
    InconsistentOrientation { a: u32, b: u32 },
    #[error("remesh: vertex {vertex} is non-manifold (its faces form more than one fan)")]
    NonManifoldVertex { vertex: u32 },
    #[error("remesh: the result would exceed {limit} faces; the target edge is too small")]
    TooManyFaces { limit: usize },
    #[error("remesh: the mesh is too large for 32-bit indices")]
    TooLarge,
}

/// Remeshes `mesh` toward edges of length `opts.target_edge` (see the module docs).
///
/// The result is a consistently oriented manifold with the input's topology (genus,
/// number of boundary loops), its vertices on the input surface, winding as in the input.
pub fn remesh(mesh: &Mesh, opts: &RemeshOptions) -> Result<Mesh, RemeshError> {
    let l = opts.target_edge;
    if !(l.is_finite() && l > 0.0) {
        return Err(RemeshError::InvalidTargetEdge(l));
    }
    if !(0.0..=1.0).contains(&opts.smoothing) {
        return Err(RemeshError::InvalidSmoothing(opts.smoothing));
    }
    let prepare::Prepared { mut he, faces } = prepare::prepare(mesh)?;
    if opts.iterations == 0 {
        return Ok(he.to_mesh());
    }
    if opts.keep_boundary {
        relax::mark_corners(&mut he);
    }
    let reference =
        spatial::Reference::new(&he.pos, &he.val, &faces, &relax::boundary_segments(&he));
    let hi2 = (4.0 / 3.0 * l).powi(2);
    let lo2 = (0.8 * l).powi(2);
    for _ in 0..opts.iterations {
        let estimate = split_estimate(&he, l);
        if estimate.is_nan() || estimate > MAX_FACES as f64 {
            return Err(RemeshError::TooManyFaces { limit: MAX_FACES });
        }
        ops::split_long_edges(&mut he, hi2, MAX_FACES)?;
        ops::collapse_short_edges(&mut he, lo2, hi2, opts.keep_boundary);
        ops::equalize_valences(&mut he);
        relax::relax(&mut he, opts.smoothing, &reference, opts.keep_boundary);
        he.compact()?;
    }
    Ok(he.to_mesh())
}

/// About how many faces splitting at `l` can leave: a triangle whose longest edge is `e`
/// ends up with at most about (e / (2l/3))^2 faces.
fn split_estimate(he: &halfedge::HeMesh, l: f64) -> f64 {
    (0..he.fhe.len() as u32)
        .filter(|&f| he.fhe[f as usize] != halfedge::NONE)
        .map(|f| {
            let p = he.face_verts(f).map(|v| he.p(v));
            let e2 = (0..3)
                .map(|k| geom::dist2(p[k], p[(k + 1) % 3]))
                .fold(0.0, f64::max);
            1.0 + 2.25 * e2 / (l * l)
        })
        .sum()
}
