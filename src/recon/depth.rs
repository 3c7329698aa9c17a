//! Depth map of a reconstructed volume, and a height-field mesh from it.
//!
//! Depth of column `(x, y)`: `z* = argmax_z V(x, y, z)`, refined to sub-voxel precision
//! by the vertex of the parabola through the peak and its two neighbours,
//! `z* + Δz · ½ (V₋ − V₊) / (V₋ − 2V₀ + V₊)` (offset clamped to half a voxel). A
//! column is empty (depth NaN) where its peak is below `threshold · max` of the whole
//! volume, or not positive.
//!
//! The mesh has one vertex per non-empty column, at `(x, y, z*)` in the wall frame, and
//! two triangles per square of four non-empty neighbouring columns, wound so that their
//! normals point toward the wall (`−n`): Umbra's hidden surfaces are one-sided and
//! reflect only toward the side their normal points to (`p_l > 0` in `tri3_kernel`).
//! A height field over the wall always faces it: each triangle's normal has the sign of
//! its area projected on the wall.

use super::surfaces::{peak_mesh, refined_depth, MeshOptions, PeakMap};
use super::{Volume, VoxelGrid, WallFrame};
use crate::error::{Error, Result};
use crate::geometry::mesh::TriMesh;
use glam::Vec3;

/// Per-column depth and peak intensity, row-major `(y, x)` (index `iy · nx + ix`).
#[derive(Clone, Debug, PartialEq)]
pub struct DepthMap {
    /// Depth of the brightest voxel, m from the wall; NaN where the column is empty.
    pub depth: Vec<f32>,
    /// The column's peak value (kept for empty columns too).
    pub intensity: Vec<f32>,
    pub nx: usize,
    pub ny: usize,
}

impl DepthMap {
    /// Depth at column `(ix, iy)` (NaN if empty).
    pub fn at(&self, ix: usize, iy: usize) -> f32 {
        self.depth[iy * self.nx + ix]
    }
    /// Number of non-empty columns.
    pub fn filled(&self) -> usize {
        self.depth.iter().filter(|d| d.is_finite()).count()
    }
}

/// The brightest voxel of each column; columns whose peak is below `threshold` times the
/// volume's maximum are empty. `threshold` must be in `[0, 1]`.
pub fn depth_map(volume: &Volume, threshold: f32) -> Result<DepthMap> {
    if !(0.0..=1.0).contains(&threshold) {
        return Err(Error::Invalid(format!(
            "depth map: the threshold is a fraction of the maximum in [0, 1], got {threshold}"
        )));
    }
    let g = &volume.grid;
    let [nx, ny, nz] = g.dims;
    if volume.data.len() != g.len() {
        return Err(Error::Invalid(format!(
            "depth map: the volume holds {} values for a grid of {:?}",
            volume.data.len(),
            g.dims
        )));
    }
    let dz = g.voxel_size().z;
    let mut depth = vec![f32::NAN; nx * ny];
    let mut intensity = vec![0.0f32; nx * ny];
    let mut peak_at = vec![0usize; nx * ny];
    for (i, col) in volume.data.chunks_exact(nz).enumerate() {
        let (k, v) = col
            .iter()
            .copied()
            .enumerate()
            .fold(
                (0, f32::NEG_INFINITY),
                |b, (k, v)| if v > b.1 { (k, v) } else { b },
            );
        intensity[i] = v;
        peak_at[i] = k;
    }
    let global = intensity.iter().copied().fold(0.0f32, f32::max);
    if global <= 0.0 || !global.is_finite() {
        return Ok(DepthMap {
            depth,
            intensity,
            nx,
            ny,
        });
    }
    for (i, col) in volume.data.chunks_exact(nz).enumerate() {
        let (k, v) = (peak_at[i], intensity[i]);
        if v <= 0.0 || v < threshold * global {
            continue;
        }
        depth[i] = refined_depth(col, k, g.min.z, dz);
    }
    Ok(DepthMap {
        depth,
        intensity,
        nx,
        ny,
    })
}

/// A wall-facing height field over the non-empty columns of `dm`, in world space through
/// `frame` (one peak per column: [`super::peak_mesh`], which says how). `grid` is the grid
/// the depth map came from. Errors if no 2 x 2 block of neighbouring columns is non-empty;
/// blocks that touch another at a corner only are dropped, so the mesh is manifold.
pub fn depth_map_mesh(
    dm: &DepthMap,
    grid: &VoxelGrid,
    frame: &WallFrame,
    opts: &MeshOptions,
) -> Result<TriMesh> {
    peak_mesh(&PeakMap::from_depth_map(dm), grid, frame, opts)
}

/// The first hidden surface along the wall normal from the wall point `(x, y)` of the
/// wall frame: its distance from the wall (m) and the albedo at the hit (the hit
/// triangle's per-vertex albedo interpolated at the hit's barycentrics, or its object's
/// albedo); `None` where the ray meets no hidden surface. Either side of a face counts.
pub fn first_surface(
    geometry: &crate::geometry::SceneGeometry,
    frame: &WallFrame,
    x: f32,
    y: f32,
) -> Option<(f32, f32)> {
    let origin = frame.to_world(Vec3::new(x, y, 1e-4));
    let hit = geometry.intersect(origin, frame.n)?;
    matches!(hit.kind, crate::geometry::SurfaceKind::Hidden { .. }).then(|| {
        (
            hit.t + 1e-4,
            geometry.hidden[hit.flat as usize].albedo_at(hit.bary),
        )
    })
}

/// The depth map of the hidden surfaces of `geometry` over the columns of `grid`: the
/// distance (m) from the wall along its normal to the first hidden surface, NaN where
/// the column's ray hits none; the intensity is the albedo at the hit (0 where none)
/// ([`first_surface`] from each column's centre). The same picture as [`depth_map`] for
/// a surface instead of a volume, so the two compare pixel by pixel.
pub fn surface_depth_map(
    geometry: &crate::geometry::SceneGeometry,
    grid: &VoxelGrid,
    frame: &WallFrame,
) -> DepthMap {
    let [nx, ny, _] = grid.dims;
    let (mut depth, mut intensity) = (vec![f32::NAN; nx * ny], vec![0.0f32; nx * ny]);
    for iy in 0..ny {
        for ix in 0..nx {
            let c = grid.center(ix, iy, 0);
            if let Some((d, a)) = first_surface(geometry, frame, c.x, c.y) {
                depth[iy * nx + ix] = d;
                intensity[iy * nx + ix] = a;
            }
        }
    }
    DepthMap {
        depth,
        intensity,
        nx,
        ny,
    }
}
