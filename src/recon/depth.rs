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
        let mut off = 0.0;
        if k > 0 && k + 1 < nz {
            let (a, c) = (col[k - 1], col[k + 1]);
            let den = a - 2.0 * v + c;
            if den < 0.0 {
                off = (0.5 * (a - c) / den).clamp(-0.5, 0.5);
            }
        }
        depth[i] = g.min.z + (k as f32 + 0.5 + off) * dz;
    }
    Ok(DepthMap {
        depth,
        intensity,
        nx,
        ny,
    })
}

/// Options of [`depth_map_mesh`].
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct MeshOptions {
    /// Rounds of smoothing of the depths before meshing: each non-empty column moves
    /// halfway to the mean of its non-empty 4-neighbours. 0 keeps the recovered depths.
    pub smooth_iterations: usize,
}

/// Removes quads (by lower-left column) until no two of them touch at a corner only: two
/// quads meeting diagonally at a column with neither of the other two quads around it
/// would make that vertex non-manifold (two fans), which the fit's remesher refuses. Of
/// such a pair, the one further up the scan goes; repeated until none is left.
fn drop_bowties(quads: &mut Vec<(usize, usize)>, nx: usize, ny: usize) {
    let mut has = vec![false; nx * ny];
    for &(ix, iy) in quads.iter() {
        has[iy * nx + ix] = true;
    }
    loop {
        let mut dropped = false;
        for y in 1..ny.saturating_sub(1) {
            for x in 1..nx.saturating_sub(1) {
                // the four quads around column (x, y): lower-left (x-1, y-1), lower-right
                // (x, y-1), upper-left (x-1, y), upper-right (x, y)
                let q = |x: usize, y: usize| has[y * nx + x];
                let (ll, lr, ul, ur) = (q(x - 1, y - 1), q(x, y - 1), q(x - 1, y), q(x, y));
                if ll && ur && !lr && !ul {
                    has[y * nx + x] = false;
                    dropped = true;
                } else if lr && ul && !ll && !ur {
                    has[y * nx + x - 1] = false;
                    dropped = true;
                }
            }
        }
        if !dropped {
            break;
        }
    }
    quads.retain(|&(ix, iy)| has[iy * nx + ix]);
}

/// A wall-facing height field over the non-empty columns of `dm` (see the module doc),
/// in world space through `frame`. `grid` is the grid the depth map came from. Errors if
/// no 2 x 2 block of neighbouring columns is non-empty; blocks that touch another at a
/// corner only are dropped ([`drop_bowties`]), so the mesh is manifold.
pub fn depth_map_mesh(
    dm: &DepthMap,
    grid: &VoxelGrid,
    frame: &WallFrame,
    opts: &MeshOptions,
) -> Result<TriMesh> {
    let (nx, ny) = (dm.nx, dm.ny);
    if grid.dims[0] != nx || grid.dims[1] != ny || dm.depth.len() != nx * ny {
        return Err(Error::Invalid(format!(
            "depth-map mesh: the depth map is {nx} x {ny} but the grid is {:?}",
            grid.dims
        )));
    }
    let depth = smooth(dm, opts.smooth_iterations);
    let filled = |ix: usize, iy: usize| depth[iy * nx + ix].is_finite();
    // Squares of four non-empty columns, by their lower-left column.
    let mut quads = Vec::new();
    for iy in 0..ny.saturating_sub(1) {
        for ix in 0..nx.saturating_sub(1) {
            if filled(ix, iy) && filled(ix + 1, iy) && filled(ix, iy + 1) && filled(ix + 1, iy + 1)
            {
                quads.push((ix, iy));
            }
        }
    }
    drop_bowties(&mut quads, nx, ny);
    if quads.is_empty() {
        return Err(Error::Invalid(format!(
            "depth-map mesh: no 2 x 2 block of neighbouring columns is above the threshold ({} of {} columns are): lower the threshold or check the reconstruction",
            dm.filled(),
            nx * ny
        )));
    }
    // Vertices for the columns the quads use, in column order.
    let mut vid = vec![u32::MAX; nx * ny];
    for &(ix, iy) in &quads {
        for (x, y) in [(ix, iy), (ix + 1, iy), (ix, iy + 1), (ix + 1, iy + 1)] {
            vid[y * nx + x] = 0;
        }
    }
    let mut positions = Vec::new();
    for iy in 0..ny {
        for ix in 0..nx {
            let i = iy * nx + ix;
            if vid[i] == 0 {
                vid[i] = positions.len() as u32;
                let c = grid.center(ix, iy, 0);
                positions.push(frame.to_world(Vec3::new(c.x, c.y, depth[i])));
            }
        }
    }
    let mut triangles = Vec::with_capacity(2 * quads.len());
    for &(ix, iy) in &quads {
        let at = |x: usize, y: usize| (vid[y * nx + x], depth[y * nx + x]);
        let ((a, za), (b, zb)) = (at(ix, iy), at(ix + 1, iy));
        let ((c, zc), (d, zd)) = (at(ix + 1, iy + 1), at(ix, iy + 1));
        // Counter-clockwise seen from the wall side (normal toward -z in the wall
        // frame); split along the diagonal with the smaller depth step.
        if (za - zc).abs() <= (zb - zd).abs() {
            triangles.push([a, c, b]);
            triangles.push([a, d, c]);
        } else {
            triangles.push([a, d, b]);
            triangles.push([b, d, c]);
        }
    }
    Ok(TriMesh {
        positions,
        triangles,
        vertex_albedo: None,
    })
}

/// The depths after `iterations` rounds of neighbour averaging (empty columns stay empty).
fn smooth(dm: &DepthMap, iterations: usize) -> Vec<f32> {
    let (nx, ny) = (dm.nx, dm.ny);
    let mut d = dm.depth.clone();
    let mut next = d.clone();
    for _ in 0..iterations {
        for iy in 0..ny {
            for ix in 0..nx {
                let i = iy * nx + ix;
                if !d[i].is_finite() {
                    continue;
                }
                let mut sum = 0.0;
                let mut n = 0;
                let neighbours = [
                    (ix > 0).then(|| i - 1),
                    (ix + 1 < nx).then(|| i + 1),
                    (iy > 0).then(|| i - nx),
                    (iy + 1 < ny).then(|| i + nx),
                ];
                for j in neighbours.into_iter().flatten() {
                    if d[j].is_finite() {
                        sum += d[j];
                        n += 1;
                    }
                }
                next[i] = if n > 0 {
                    0.5 * d[i] + 0.5 * sum / n as f32
                } else {
                    d[i]
                };
            }
        }
        std::mem::swap(&mut d, &mut next);
    }
    d
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Quads (by lower-left column) meeting at one corner only, as the letter's
    /// backprojection start had: one of the pair goes, so every vertex has one fan of
    /// faces; three quads around a vertex are one fan and stay.
    #[test]
    fn quads_touching_at_a_corner_only_are_not_kept_both() {
        let (nx, ny) = (5, 5);
        for (pair, kept) in [
            (vec![(0, 0), (1, 1)], vec![(0, 0)]),
            (vec![(1, 0), (0, 1)], vec![(1, 0)]),
            (vec![(0, 0), (1, 0), (1, 1)], vec![(0, 0), (1, 0), (1, 1)]),
            (vec![(0, 0), (2, 2)], vec![(0, 0), (2, 2)]),
        ] {
            let mut quads = pair.clone();
            drop_bowties(&mut quads, nx, ny);
            assert_eq!(quads, kept, "{pair:?}");
        }
        // a diagonal chain: each removal can expose no new corner-only contact
        let mut chain: Vec<_> = (0..4).map(|i| (i, i)).collect();
        drop_bowties(&mut chain, nx, ny);
        assert_eq!(chain, vec![(0, 0), (2, 2)]);
    }
}
