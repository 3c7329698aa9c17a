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

use super::seen::{finite_max, SeenSurface, WallView};
use crate::error::Result;
use crate::io::plot::{labelled_maps, MapPanel};
use crate::recon::{
    backproject_with, depth_map, depth_map_mesh, BackprojectOptions, DepthMap, Falloff,
    MeshOptions, Volume, VoxelGrid, WallFrame,
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
        },
    )?;
    Ok(super::fit_mesh(&m))
}

/// The initial mesh of `Init::Lct`: the height field over the filled columns of the
/// light-cone transform's depth map, one column per scan point, over the depths the fitted
/// bins see (`recon::lct`, confocal captures only).
pub fn lct_mesh(scene: &Scene, measured: &[f32], first_bin: usize) -> Result<Mesh> {
    let dims = [scene.scan.nx as usize, scene.scan.ny as usize, 256];
    let grid = fitted_grid(scene, first_bin, dims)?;
    let volume = crate::recon::lct(scene, measured, &grid, &crate::recon::LctOptions::default())?;
    let depth = depth_map(&volume, DEPTH_THRESHOLD)?;
    let m = depth_map_mesh(
        &depth,
        &grid,
        &WallFrame::of(scene),
        &MeshOptions {
            smooth_iterations: 2,
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
        match crate::recon::lct(scene, measured, &grid, &crate::recon::LctOptions::default()) {
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
    let albedo_max = finite_max(&seen.albedo);
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
