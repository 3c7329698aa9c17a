//! The fit's link to the classical reconstructions (`crate::recon`): the backprojection
//! and LCT initial meshes, and `OUTDIR/reconstruction.png`, which puts the fitted surface
//! seen from the wall next to a classical reconstruction of the same measurement.
//!
//! Both use the measurement's bins from the first fitted one on (residual direct light
//! left out), over the depths the fitted bins can see. The backprojection is time
//! blurred by one bin; its depth map, like the LCT's, keeps the columns whose peak is at
//! least [`DEPTH_THRESHOLD`] of the volume's maximum (`recon::depth_map`).
//!
//! The picture has four labelled panels, each with a colour bar in its units and axes
//! in metres on the wall, all over the scan rectangle and seen from the wall (`+y` up,
//! `+x` to the left, so a letter facing the wall reads correctly; `seen::WallView`):
//! the fitted surface's albedo and depth (`albedo.npy`, `depth.npy`: the first face
//! along the wall normal from each scan point, [`super::seen`]); the reconstruction's
//! maximum over depth and its depth map. The reconstruction is Umbra's LCT
//! (`recon::lct`, one column per scan point) for confocal captures of at most
//! [`LCT_MAX_COLUMNS`] scan points, a filtered backprojection (at most 64 x 64 columns)
//! otherwise or where the LCT cannot run (said in a warning). The two depth maps share
//! one scale, near dark and far bright.

use super::seen::{display_max, finite_max, SeenSurface, WallView};
use crate::error::Result;
use crate::io::plot::{labelled_maps, MapPanel};
use crate::recon::{
    backproject_with, depth_map, depth_map_mesh, peak_map, peak_mesh, BackprojectOptions, DepthMap,
    Falloff, MeshOptions, Volume, VoxelGrid, WallFrame,
};
use crate::scene::{CaptureType, Scene};
use optim::Mesh;
use std::path::Path;

/// Columns whose backprojected peak is below this fraction of the maximum are empty.
pub const DEPTH_THRESHOLD: f32 = 0.3;

/// Confocal scans of more points than this get the backprojection in the picture (the
/// LCT's padded volume grows as their number times the bins).
pub const LCT_MAX_COLUMNS: usize = 128 * 128;

/// The depths (m from the wall) the fitted bins (from `first_bin`) can see.
fn fitted_depths(scene: &Scene, first_bin: usize) -> Result<(f32, f32)> {
    let grid = VoxelGrid::for_scene(scene, [1, 1, 1])?;
    let (mut lo, hi) = (grid.min.z, grid.max.z);
    if !scene.account_first_and_last_bounces && first_bin > 0 {
        let z = 0.5 * (scene.film.start_opl + first_bin as f32 * scene.film.bin_width_opl);
        if z < hi {
            lo = z.max(lo);
        }
    }
    Ok((lo, hi))
}

/// `[nx, ny, nz]` voxels over the scan and the depths the fitted bins (from `first_bin`)
/// can see.
fn fitted_grid(scene: &Scene, first_bin: usize, dims: [usize; 3]) -> Result<VoxelGrid> {
    let (lo, hi) = fitted_depths(scene, first_bin)?;
    VoxelGrid::over_scan(scene, lo, hi, dims)
}

/// The filtered backprojection of the module doc on `grid`.
fn backprojection(
    scene: &Scene,
    measured: &[f32],
    grid: &VoxelGrid,
    falloff: Falloff,
) -> Result<(Volume, DepthMap)> {
    let opts = BackprojectOptions {
        time_sigma_opl: scene.film.bin_width_opl,
        falloff,
        ..BackprojectOptions::default()
    };
    let volume = backproject_with(scene, measured, grid, &opts)?;
    let depth = depth_map(&volume, DEPTH_THRESHOLD)?;
    Ok((volume, depth))
}

/// The initial mesh of `Init::Backprojection`: the wall-facing height field over the
/// filled columns of a 32 x 32 x 64 backprojection's depth map, the backprojection
/// weighted by `|x_l − v|² |v − x_s|²` (`Falloff::Compensate`) so that a far object is
/// not dimmed below the threshold by the near one: two objects 0.5 m apart in depth both
/// start (docs/BASELINES.md; unweighted, only the near one did).
pub fn backprojection_mesh(scene: &Scene, measured: &[f32], first_bin: usize) -> Result<Mesh> {
    let grid = fitted_grid(scene, first_bin, [32, 32, 64])?;
    let (volume, depth) = backprojection(scene, measured, &grid, Falloff::Compensate)?;
    let m = depth_map_mesh(
        &depth,
        &volume.grid,
        &WallFrame::of(scene),
        &MeshOptions {
            smooth_iterations: 2,
            ..MeshOptions::default()
        },
    )?;
    Ok(super::fit_mesh(&m))
}

/// Umbra's LCT of `measured` on `grid` as the fit shows and starts from it: Wiener SNR 0.1
/// (the studies' figures), on the capture less each point's floor (`recon::subtract_floor`;
/// the bins before `first_bin` stay zero): without that, the floor, weighted by `r³`, is
/// the brightest thing at the far end of every column.
fn lct_volume(
    scene: &Scene,
    measured: &[f32],
    first_bin: usize,
    grid: &VoxelGrid,
) -> Result<Volume> {
    let mut data = measured.to_vec();
    let bins = scene.film.temporal_bins as usize;
    crate::recon::subtract_floor(&mut data, bins);
    crate::recon::zero_bins_before(&mut data, bins, first_bin);
    crate::recon::lct(scene, &data, grid, &crate::recon::LctOptions { snr: 0.1 })
}

/// Depth peaks of one column closer than this (m) are one surface ([`lct_mesh`]).
const LCT_START_SEPARATION: f32 = 0.15;

/// Neighbouring columns' peaks further apart in depth than this (m) are not one surface
/// ([`lct_mesh`]; less than half the separation, `recon::peak_mesh`).
const LCT_START_MAX_STEP: f32 = 0.05;

/// The LCT start has at most this many columns a side (the LCT's columns averaged in
/// blocks), about as coarse as a plane start: from all 32 x 32 columns of a binned
/// Stanford capture the start had 1900 faces, 10 000 after the schedule's first remesh,
/// and a fit took 264 s (notes/capture-calibration.md §9).
const LCT_START_COLUMNS: u32 = 16;

/// Sheets of fewer quads than this fraction of the largest's are noise ([`lct_mesh`]).
const LCT_START_MIN_SHEET: f32 = 0.1;

/// The LCT's brightness as albedo: each voxel over its depth. The LCT's volume
/// `ρ(x, z) = 2z ρ̃(x, z²)` is sampled uniformly in `z²`, so a surface's peak grows as its
/// depth times its albedo (where the capture's blur is within one sample). Measured on two
/// fronto-parallel squares of albedo 1 and 0.5 at 0.5 and 0.85 m (tests/recon_wave.rs):
/// the start's albedo 0.82 for 0.5 (the peak alone: 0.94; the volume integrated across
/// each peak: 0.18): across depths only roughly, which the fit's albedo stages correct.
/// A far object is then not taken for brighter than a near one: `s_u`'s S, half its U's
/// LCT brightness, passes the threshold that keeps the noise out.
fn over_depth(volume: &mut Volume) {
    let nz = volume.grid.dims[2];
    let depths: Vec<f32> = (0..nz).map(|k| volume.grid.center(0, 0, k).z).collect();
    for col in volume.data.chunks_exact_mut(nz) {
        for (v, z) in col.iter_mut().zip(&depths) {
            *v /= z.max(1e-3);
        }
    }
}

/// The initial mesh of `Init::Lct`, what the light-cone transform sees: surfaces at up to
/// two depths per column (`s_u`'s S in front of its U), each meshed on its own over the
/// columns where it stands out (`recon::peak_map`, `recon::peak_mesh`), with the LCT's
/// brightness over depth ([`over_depth`]) as each vertex's albedo (relative to the median: the fit's scale carries the
/// rest). The LCT (`recon::lct`, one column per scan point, over the depths the fitted bins
/// see, Wiener SNR 0.1 as the study's figures use) runs on the capture less each point's
/// floor (`recon::subtract_floor`; the bins before the first fitted one stay zero): without it the floor, weighted by `r³`, is the
/// brightest thing at the far end of every column. Confocal captures only.
pub fn lct_mesh(scene: &Scene, measured: &[f32], first_bin: usize) -> Result<Mesh> {
    let dims = [scene.scan.nx as usize, scene.scan.ny as usize, 256];
    let grid = fitted_grid(scene, first_bin, dims)?;
    let volume = lct_volume(scene, measured, first_bin, &grid)?;
    let pool = scene.scan.nx.max(scene.scan.ny).div_ceil(LCT_START_COLUMNS) as usize;
    let mut volume = volume.pooled(pool);
    let grid = volume.grid.clone();
    over_depth(&mut volume);
    let peaks = peak_map(&volume, DEPTH_THRESHOLD, LCT_START_SEPARATION, 2)?;
    let m = peak_mesh(
        &peaks,
        &grid,
        &WallFrame::of(scene),
        &MeshOptions {
            smooth_iterations: 2,
            max_step: Some(LCT_START_MAX_STEP),
            albedo: true,
            min_sheet_fraction: LCT_START_MIN_SHEET,
        },
    )?;
    Ok(super::fit_mesh(&m))
}

/// The reconstruction the picture shows (module doc), on columns over the scan
/// rectangle as `view` shows it: its name and volume.
fn reference(
    scene: &Scene,
    measured: &[f32],
    first_bin: usize,
    view: &WallView,
) -> Result<(&'static str, Volume)> {
    let (z_min, z_max) = fitted_depths(scene, first_bin)?;
    let (w, h) = (view.width, view.height);
    if scene.capture == CaptureType::Confocal && w * h <= LCT_MAX_COLUMNS {
        let grid = view.grid([w, h], z_min, z_max, 256)?;
        match lct_volume(scene, measured, first_bin, &grid) {
            Ok(volume) => return Ok(("LCT", volume)),
            Err(e) => eprintln!(
                "umbra fit: warning: reconstruction.png shows the backprojection: the LCT cannot run: {e}"
            ),
        }
    }
    let grid = view.grid([w.clamp(1, 64), h.clamp(1, 64)], z_min, z_max, 128)?;
    let (volume, _) = backprojection(scene, measured, &grid, Falloff::None)?;
    Ok(("filtered backprojection", volume))
}

/// Writes the picture of the module doc to `path`: `seen` is the fitted surface seen
/// from the wall (`super::seen::seen_surface`), `measured` the measurement as fitted
/// (zero before `first_bin`).
pub fn write_reconstruction_png(
    path: &Path,
    scene: &Scene,
    measured: &[f32],
    first_bin: usize,
    seen: &SeenSurface,
) -> Result<()> {
    let view = WallView::of(scene);
    let (name, volume) = reference(scene, measured, first_bin, &view)?;
    let depth = depth_map(&volume, DEPTH_THRESHOLD)?;
    let [gx, gy, _] = volume.grid.dims;
    let column_max = |ix, iy| volume.column(ix, iy).iter().copied().fold(0.0, f32::max);
    let mip = WallView::show_columns(gx, gy, &column_max);
    let top = finite_max(&mip);
    let mip: Vec<f32> = mip
        .iter()
        .map(|&v| if top > 0.0 { v.max(0.0) / top } else { 0.0 })
        .collect();
    let ref_depth = WallView::show_columns(gx, gy, &|ix, iy| depth.at(ix, iy));
    let (fit_albedo, fit_depth) = (view.show(&seen.albedo), view.show(&seen.depth));
    let (lo, hi) = fit_depth
        .iter()
        .chain(&ref_depth)
        .filter(|v| v.is_finite())
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let (lo, hi) = if lo <= hi {
        (lo, hi.max(lo + 1e-3))
    } else {
        (0.0, 1.0)
    };
    let albedo_max = display_max(&seen.albedo);
    let threshold = format!("{:.0} %", 100.0 * DEPTH_THRESHOLD);
    let titles = [
        "fitted surface: albedo of the first\nface along the wall normal\n(albedo.npy; black: no surface)".to_string(),
        "fitted surface: depth of that face\n(depth.npy; black: no surface)".to_string(),
        format!("{name} of the measurement:\nmax. over depth (front view)"),
        format!("{name}: depth of each\ncolumn's peak (black: < {threshold})"),
    ];
    let (w, h) = (view.width, view.height);
    let axes = Some(view.axes());
    let [x0, x1, y0, y1] = view.extent;
    labelled_maps(
        path,
        &format!("umbra fit: the fitted surface seen from the wall next to Umbra's {name} of the same measurement ({} x {} scan points)", seen.nx, seen.ny),
        &[
            MapPanel { title: &titles[0], width: w, height: h, values: &fit_albedo, range: (0.0, if albedo_max > 0.0 { albedo_max } else { 1.0 }), unit: "fitted albedo", axes },
            MapPanel { title: &titles[1], width: w, height: h, values: &fit_depth, range: (lo, hi), unit: "depth from the wall (m)", axes },
            MapPanel { title: &titles[2], width: gx, height: gy, values: &mip, range: (0.0, 1.0), unit: "intensity / its maximum", axes },
            MapPanel { title: &titles[3], width: gx, height: gy, values: &ref_depth, range: (lo, hi), unit: "depth from the wall (m)", axes },
        ],
        &format!("All panels seen from the wall into the hidden scene: +y up, +x to the left (a letter facing the wall reads\ncorrectly); each spans the scan rectangle, x {x0:.2} to {x1:.2} m, y {y0:.2} to {y1:.2} m. Depths share one scale: near dark, far bright."),
    )
}
