//! Surfaces at several depths per column, and the wall-facing mesh through them.
//!
//! A column `(x, y)` of a reconstructed volume `V` may hold more than one surface (an
//! object in front of another: `s_u`'s S at 0.5 m and its U at 1.0 m). Its **peaks** are
//! the local maxima `V(z_{k−1}) ≤ V(z_k) > V(z_{k+1})` inside the volume (not its first
//! or last voxel, where a reconstruction's edge effects pile up) that reach `threshold · max V` of
//! the whole volume, kept brightest first while each stands at least `separation` from
//! every kept one (at most `max_peaks`), each refined to sub-voxel depth by the parabola
//! through the peak and its neighbours (as [`super::depth_map`] does), sorted near to far.
//! A depth map is the special case of one peak per column ([`PeakMap::from_depth_map`]).
//!
//! The **mesh** ([`peak_mesh`]) has one vertex per peak it uses, at `(x, y, z)` in the wall
//! frame, and two triangles per quad of four neighbouring columns' peaks whose depths agree
//! pairwise within `max_step`. With `separation > 2 max_step`, a peak agrees with at most
//! one peak of each neighbouring column, so each surface is meshed on its own and never
//! joined to another across a depth jump. Triangles are wound so that their normals point
//! toward the wall (`−n`): Umbra's hidden surfaces reflect only toward the side their
//! normal points to, and a height field over the wall faces it. Quads meeting at a corner
//! only are thinned until none is left (the vertex would have two fans, which the fit's
//! remesher refuses); sheets (quads connected through shared peaks) much smaller than the
//! largest can be dropped as islands of noise. With `albedo`, every vertex carries its peak's
//! value relative to the median over the mesh: the albedo up to one scale where the volume
//! is the albedo (for the LCT, see `fit::reconstruction::lct_mesh`).

use super::{DepthMap, Volume, VoxelGrid, WallFrame};
use crate::error::{Error, Result};
use crate::geometry::mesh::TriMesh;
use glam::Vec3;

/// One surface crossing a column.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Peak {
    /// Depth, m from the wall.
    pub depth: f32,
    /// The volume's value at the peak voxel.
    pub value: f32,
}

/// The peaks of every column, row-major `(y, x)` (index `iy · nx + ix`), near to far.
#[derive(Clone, Debug, PartialEq)]
pub struct PeakMap {
    pub peaks: Vec<Vec<Peak>>,
    pub nx: usize,
    pub ny: usize,
}

impl PeakMap {
    /// One peak per non-empty column of `dm`.
    pub fn from_depth_map(dm: &DepthMap) -> PeakMap {
        let peaks = dm
            .depth
            .iter()
            .zip(&dm.intensity)
            .map(|(&depth, &value)| {
                if depth.is_finite() {
                    vec![Peak { depth, value }]
                } else {
                    Vec::new()
                }
            })
            .collect();
        PeakMap {
            peaks,
            nx: dm.nx,
            ny: dm.ny,
        }
    }

    /// Number of peaks over all columns.
    pub fn len(&self) -> usize {
        self.peaks.iter().map(Vec::len).sum()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// The sub-voxel depth of the peak at voxel `k` of `col` (module doc of `depth`): the
/// vertex of the parabola through it and its two neighbours, offset clamped to half a voxel.
pub(super) fn refined_depth(col: &[f32], k: usize, z_min: f32, dz: f32) -> f32 {
    let mut off = 0.0;
    if k > 0 && k + 1 < col.len() {
        let (a, v, c) = (col[k - 1], col[k], col[k + 1]);
        let den = a - 2.0 * v + c;
        if den < 0.0 {
            off = (0.5 * (a - c) / den).clamp(-0.5, 0.5);
        }
    }
    z_min + (k as f32 + 0.5 + off) * dz
}

/// The peaks of every column of `volume` (module doc): local maxima of at least
/// `threshold` (in `[0, 1]`) times the volume's maximum, at least `separation` (m) apart,
/// at most `max_peaks` per column.
pub fn peak_map(
    volume: &Volume,
    threshold: f32,
    separation: f32,
    max_peaks: usize,
) -> Result<PeakMap> {
    let separation_ok = separation.is_finite() && separation >= 0.0;
    if !(0.0..=1.0).contains(&threshold) || !separation_ok || max_peaks == 0 {
        return Err(Error::Invalid(format!(
            "peak map: threshold in [0, 1], separation >= 0 and at least one peak per column, got {threshold}, {separation} m, {max_peaks}"
        )));
    }
    let g = &volume.grid;
    let [nx, ny, nz] = g.dims;
    if volume.data.len() != g.len() {
        return Err(Error::Invalid(format!(
            "peak map: the volume holds {} values for a grid of {:?}",
            volume.data.len(),
            g.dims
        )));
    }
    let dz = g.voxel_size().z;
    let global = volume
        .data
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0f32, f32::max);
    let floor = (threshold * global).max(f32::MIN_POSITIVE);
    let peaks = volume
        .data
        .chunks_exact(nz)
        .map(|col| {
            let mut maxima: Vec<usize> = (0..nz)
                .filter(|&k| {
                    let v = col[k];
                    v >= floor && (k == 0 || col[k - 1] <= v) && (k + 1 == nz || col[k + 1] < v)
                })
                .collect();
            maxima.sort_by(|&a, &b| col[b].total_cmp(&col[a]).then(a.cmp(&b)));
            let mut kept: Vec<usize> = Vec::new();
            for k in maxima {
                if kept.len() == max_peaks {
                    break;
                }
                if kept
                    .iter()
                    .all(|&j| (k as f32 - j as f32).abs() * dz >= separation)
                {
                    kept.push(k);
                }
            }
            kept.sort_unstable();
            kept.into_iter()
                .map(|k| Peak {
                    depth: refined_depth(col, k, g.min.z, dz),
                    value: col[k],
                })
                .collect()
        })
        .collect();
    Ok(PeakMap { peaks, nx, ny })
}

/// Options of [`peak_mesh`] (and [`super::depth_map_mesh`]).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct MeshOptions {
    /// Rounds of smoothing of the depths before meshing: each peak moves halfway to the
    /// mean of the peaks it agrees with in its 4-neighbour columns. 0 keeps the depths.
    pub smooth_iterations: usize,
    /// Neighbouring columns' peaks are one surface where their depths differ by at most
    /// this (m); `None`: any two (one peak per column, a single height field).
    pub max_step: Option<f32>,
    /// Give each vertex its peak's value relative to the median of the mesh's (module doc).
    pub albedo: bool,
    /// Drop each sheet (quads connected through shared peaks) of fewer quads than this
    /// fraction of the largest one's: islands of noise. 0 keeps every sheet.
    pub min_sheet_fraction: f32,
}

/// The peak of column `col` that agrees with `depth` (the nearest within `max_step`).
fn agreeing(peaks: &[Peak], depth: f32, max_step: Option<f32>) -> Option<usize> {
    let (k, p) = peaks.iter().enumerate().min_by(|a, b| {
        (a.1.depth - depth)
            .abs()
            .total_cmp(&(b.1.depth - depth).abs())
    })?;
    max_step
        .is_none_or(|s| (p.depth - depth).abs() <= s)
        .then_some(k)
}

/// The depths after `iterations` rounds of smoothing (see [`MeshOptions`]).
fn smooth(pm: &PeakMap, iterations: usize, max_step: Option<f32>) -> Vec<Vec<Peak>> {
    let (nx, ny) = (pm.nx, pm.ny);
    let mut d = pm.peaks.clone();
    for _ in 0..iterations {
        let mut next = d.clone();
        for iy in 0..ny {
            for ix in 0..nx {
                let i = iy * nx + ix;
                let neighbours = [
                    (ix > 0).then(|| i - 1),
                    (ix + 1 < nx).then(|| i + 1),
                    (iy > 0).then(|| i - nx),
                    (iy + 1 < ny).then(|| i + nx),
                ];
                for (k, p) in d[i].iter().enumerate() {
                    let (mut sum, mut n) = (0.0, 0);
                    for j in neighbours.into_iter().flatten() {
                        if let Some(m) = agreeing(&d[j], p.depth, max_step) {
                            sum += d[j][m].depth;
                            n += 1;
                        }
                    }
                    if n > 0 {
                        next[i][k].depth = 0.5 * p.depth + 0.5 * sum / n as f32;
                    }
                }
            }
        }
        d = next;
    }
    d
}

/// A quad's four peaks as `(column, peak)`, counter-clockwise in the scan: lower-left,
/// lower-right, upper-right, upper-left.
type Quad = [(usize, usize); 4];

/// The quads of `peaks` (module doc), by lower-left column and peak.
fn quads(peaks: &[Vec<Peak>], nx: usize, ny: usize, max_step: Option<f32>) -> Vec<Quad> {
    let mut out = Vec::new();
    for iy in 0..ny.saturating_sub(1) {
        for ix in 0..nx.saturating_sub(1) {
            let i = iy * nx + ix;
            let corners = [i + 1, i + 1 + nx, i + nx];
            for (k, p) in peaks[i].iter().enumerate() {
                let found: Option<Vec<usize>> = corners
                    .iter()
                    .map(|&j| agreeing(&peaks[j], p.depth, max_step))
                    .collect();
                let Some(found) = found else { continue };
                let quad = [
                    (i, k),
                    (corners[0], found[0]),
                    (corners[1], found[1]),
                    (corners[2], found[2]),
                ];
                let depth = |(c, m): (usize, usize)| peaks[c][m].depth;
                let agree = max_step.is_none_or(|s| {
                    quad.iter()
                        .all(|&a| quad.iter().all(|&b| (depth(a) - depth(b)).abs() <= s))
                });
                if agree {
                    out.push(quad);
                }
            }
        }
    }
    out
}

/// Drops quads until no two meet at a vertex by a corner only (module doc): at each
/// vertex, in column order, of a lower-left and upper-right pair with neither of the
/// other two the upper-right goes; of a lower-right and upper-left pair, the upper-left.
fn drop_bowties(quads: &mut Vec<Quad>) {
    use std::collections::HashMap;
    let mut alive = vec![true; quads.len()];
    // around each vertex: the quad of which it is corner c, for c = 0..4
    let mut around: HashMap<(usize, usize), [Option<usize>; 4]> = HashMap::new();
    for (q, quad) in quads.iter().enumerate() {
        for (c, &v) in quad.iter().enumerate() {
            around.entry(v).or_default()[c] = Some(q);
        }
    }
    let mut vertices: Vec<(usize, usize)> = around.keys().copied().collect();
    vertices.sort_unstable();
    loop {
        let mut dropped = false;
        for v in &vertices {
            let live = |c: usize| around[v][c].filter(|&q| alive[q]);
            // the vertex is the upper-right corner (2) of its lower-left quad, and so on
            let (ll, lr, ul, ur) = (live(2), live(3), live(1), live(0));
            if let (Some(_), Some(q), None, None) = (ll, ur, lr, ul) {
                alive[q] = false;
                dropped = true;
            } else if let (Some(_), Some(q), None, None) = (lr, ul, ll, ur) {
                alive[q] = false;
                dropped = true;
            }
        }
        if !dropped {
            break;
        }
    }
    let mut q = 0;
    quads.retain(|_| {
        q += 1;
        alive[q - 1]
    });
}

/// Drops the sheets (quads connected through shared peaks) of fewer quads than
/// `fraction` of the largest sheet's.
fn drop_small_sheets(quads: &mut Vec<Quad>, fraction: f32) {
    use std::collections::HashMap;
    if fraction <= 0.0 || quads.is_empty() {
        return;
    }
    // union-find over quads, joined through the first quad seen at each peak
    let mut parent: Vec<usize> = (0..quads.len()).collect();
    fn root(parent: &mut [usize], mut q: usize) -> usize {
        while parent[q] != q {
            parent[q] = parent[parent[q]];
            q = parent[q];
        }
        q
    }
    let mut first_at: HashMap<(usize, usize), usize> = HashMap::new();
    for (q, quad) in quads.iter().enumerate() {
        for v in quad {
            let other = *first_at.entry(*v).or_insert(q);
            let (a, b) = (root(&mut parent, q), root(&mut parent, other));
            parent[a.max(b)] = a.min(b);
        }
    }
    let roots: Vec<usize> = (0..quads.len()).map(|q| root(&mut parent, q)).collect();
    let mut size = vec![0usize; quads.len()];
    roots.iter().for_each(|&r| size[r] += 1);
    let largest = size.iter().copied().max().unwrap_or(0);
    let keep = |r: usize| size[r] as f32 >= fraction * largest as f32;
    let mut q = 0;
    quads.retain(|_| {
        q += 1;
        keep(roots[q - 1])
    });
}

/// A wall-facing mesh through the peaks of `pm` (module doc), in world space through
/// `frame`; `grid` is the grid the peaks came from. Errors if no quad agrees.
pub fn peak_mesh(
    pm: &PeakMap,
    grid: &VoxelGrid,
    frame: &WallFrame,
    opts: &MeshOptions,
) -> Result<TriMesh> {
    let (nx, ny) = (pm.nx, pm.ny);
    if grid.dims[0] != nx || grid.dims[1] != ny || pm.peaks.len() != nx * ny {
        return Err(Error::Invalid(format!(
            "depth-map mesh: the depth map is {nx} x {ny} but the grid is {:?}",
            grid.dims
        )));
    }
    let peaks = smooth(pm, opts.smooth_iterations, opts.max_step);
    let mut quads = quads(&peaks, nx, ny, opts.max_step);
    drop_bowties(&mut quads);
    drop_small_sheets(&mut quads, opts.min_sheet_fraction);
    if quads.is_empty() {
        let filled = pm.peaks.iter().filter(|p| !p.is_empty()).count();
        return Err(Error::Invalid(format!(
            "depth-map mesh: no 2 x 2 block of neighbouring columns is above the threshold ({filled} of {} columns are) at one depth: lower the threshold or check the reconstruction",
            nx * ny
        )));
    }
    // Vertices for the peaks the quads use, in column order.
    let mut id: Vec<Vec<u32>> = peaks.iter().map(|p| vec![u32::MAX; p.len()]).collect();
    for quad in &quads {
        for &(c, k) in quad {
            id[c][k] = 0;
        }
    }
    let (mut positions, mut values) = (Vec::new(), Vec::new());
    for (c, column) in peaks.iter().enumerate() {
        for (k, p) in column.iter().enumerate() {
            if id[c][k] == 0 {
                id[c][k] = positions.len() as u32;
                let centre = grid.center(c % nx, c / nx, 0);
                positions.push(frame.to_world(Vec3::new(centre.x, centre.y, p.depth)));
                values.push(pm.peaks[c][k].value);
            }
        }
    }
    let mut triangles = Vec::with_capacity(2 * quads.len());
    for quad in &quads {
        let at = |(c, k): (usize, usize)| (id[c][k], peaks[c][k].depth);
        let ((a, za), (b, zb), (c, zc), (d, zd)) =
            (at(quad[0]), at(quad[1]), at(quad[2]), at(quad[3]));
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
    let vertex_albedo = opts.albedo.then(|| relative_to_median(&values));
    Ok(TriMesh {
        positions,
        triangles,
        vertex_albedo,
    })
}

/// `values` over their median (all 1 where the median is not positive).
fn relative_to_median(values: &[f32]) -> Vec<f32> {
    let mut sorted = values.to_vec();
    sorted.sort_by(f32::total_cmp);
    let median = sorted.get(sorted.len() / 2).copied().unwrap_or(0.0);
    if median > 0.0 && median.is_finite() {
        values.iter().map(|v| v / median).collect()
    } else {
        vec![1.0; values.len()]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad_at(ix: usize, iy: usize, nx: usize) -> Quad {
        let i = iy * nx + ix;
        [(i, 0), (i + 1, 0), (i + 1 + nx, 0), (i + nx, 0)]
    }

    /// Quads meeting at one corner only, as the letter's backprojection start had: one of
    /// the pair goes, so every vertex has one fan of faces; three quads around a vertex are
    /// one fan and stay.
    #[test]
    fn quads_touching_at_a_corner_only_are_not_kept_both() {
        let nx = 5;
        let q = |list: &[(usize, usize)]| -> Vec<Quad> {
            list.iter().map(|&(x, y)| quad_at(x, y, nx)).collect()
        };
        for (pair, kept) in [
            (vec![(0, 0), (1, 1)], vec![(0, 0)]),
            (vec![(1, 0), (0, 1)], vec![(1, 0)]),
            (vec![(0, 0), (1, 0), (1, 1)], vec![(0, 0), (1, 0), (1, 1)]),
            (vec![(0, 0), (2, 2)], vec![(0, 0), (2, 2)]),
        ] {
            let mut quads = q(&pair);
            drop_bowties(&mut quads);
            assert_eq!(quads, q(&kept), "{pair:?}");
        }
        // a diagonal chain: each removal can expose no new corner-only contact
        let mut chain = q(&(0..4).map(|i| (i, i)).collect::<Vec<_>>());
        drop_bowties(&mut chain);
        assert_eq!(chain, q(&[(0, 0), (2, 2)]));
    }

    /// Two surfaces over the same columns at 0.4 and 0.9 m: two peaks in each column and
    /// two separate sheets, never a face across the jump; with one peak per column, the
    /// brighter surface alone.
    #[test]
    fn two_surfaces_in_one_column_make_two_sheets() {
        let dims = [4, 4, 50];
        let grid = VoxelGrid {
            min: Vec3::new(-0.2, -0.2, 0.0),
            max: Vec3::new(0.2, 0.2, 1.0),
            dims,
        };
        let mut data = vec![0.0f32; grid.len()];
        for col in data.chunks_exact_mut(dims[2]) {
            col[20] = 1.0; // 0.41 m
            col[45] = 0.5; // 0.91 m
        }
        let volume = Volume {
            grid: grid.clone(),
            data,
        };
        let frame = WallFrame {
            origin: Vec3::ZERO,
            e_u: Vec3::X,
            e_v: Vec3::Y,
            n: Vec3::Z,
        };
        let two = peak_map(&volume, 0.3, 0.2, 2).unwrap();
        assert_eq!(two.len(), 32);
        let opts = MeshOptions {
            max_step: Some(0.05),
            albedo: true,
            ..MeshOptions::default()
        };
        let mesh = peak_mesh(&two, &grid, &frame, &opts).unwrap();
        assert_eq!((mesh.positions.len(), mesh.triangles.len()), (32, 36));
        for t in &mesh.triangles {
            let z: Vec<f32> = t.iter().map(|&i| mesh.positions[i as usize].z).collect();
            assert!(
                z.iter().all(|&d| (d - z[0]).abs() < 1e-4),
                "a face across the jump: {z:?}"
            );
        }
        let albedo = mesh.vertex_albedo.unwrap();
        for (p, a) in mesh.positions.iter().zip(albedo) {
            let want = if p.z < 0.6 { 1.0 } else { 0.5 };
            assert!((a - want).abs() < 1e-6, "albedo {a} at depth {}", p.z);
        }
        let one = peak_map(&volume, 0.3, 0.2, 1).unwrap();
        let mesh = peak_mesh(&one, &grid, &frame, &opts).unwrap();
        assert_eq!(mesh.positions.len(), 16);
        assert!(mesh.positions.iter().all(|p| (p.z - 0.41).abs() < 1e-4));
    }
}
