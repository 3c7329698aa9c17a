//! The fit's link to the filtered backprojection (`crate::recon`): the backprojection
//! initial mesh, and `OUTDIR/reconstruction.png`, which puts the fitted surface next to
//! a backprojection of the same measurement.
//!
//! Both use one backprojection: the measurement's bins from the first fitted one on
//! (residual direct light left out), time blurred by one bin, on a voxel grid over the
//! scan rectangle (at most 64 x 64 columns) between the depths the fitted bins can see.
//! Its depth map keeps the columns whose peak is at least [`DEPTH_THRESHOLD`] of the
//! volume's maximum (`recon::depth_map`).
//!
//! The picture has four labelled panels, each with a colour bar in its units, all seen
//! from the wall (`+x` to the left, so a letter
//! facing the wall reads correctly): the backprojection's front maximum-intensity
//! projection; the fitted surface's albedo (the first hidden surface along the wall
//! normal from each column, `recon::surface_depth_map`; all faces, dark ones too, since
//! albedo is what cuts a letter out of a plane); the backprojection's depth map and the
//! fitted surface's, on one depth scale, near dark and far bright.

use crate::error::Result;
use crate::io::plot::{labelled_maps, MapPanel};
use crate::recon::{
    backproject_with, depth_map, depth_map_mesh, BackprojectOptions, DepthMap, Falloff,
    MeshOptions, Volume, VoxelGrid, WallFrame,
};
use crate::scene::Scene;
use optim::Mesh;
use std::path::Path;

/// Columns whose backprojected peak is below this fraction of the maximum are empty.
pub const DEPTH_THRESHOLD: f32 = 0.3;

/// `[nx, ny, nz]` voxels over the scan and the depths the fitted bins (from `first_bin`)
/// can see.
fn fitted_grid(scene: &Scene, first_bin: usize, dims: [usize; 3]) -> Result<VoxelGrid> {
    let grid = VoxelGrid::for_scene(scene, dims)?;
    if !scene.account_first_and_last_bounces && first_bin > 0 {
        let z = 0.5 * (scene.film.start_opl + first_bin as f32 * scene.film.bin_width_opl);
        if z < grid.max.z {
            return VoxelGrid::over_scan(scene, z.max(grid.min.z), grid.max.z, dims);
        }
    }
    Ok(grid)
}

/// The backprojection of the module doc on `[nx, ny, nz]` voxels; `first_bin` is the
/// first bin of each row the fit uses (the measurement is zero before it).
fn backprojection(
    scene: &Scene,
    measured: &[f32],
    first_bin: usize,
    dims: [usize; 3],
    falloff: Falloff,
) -> Result<(Volume, DepthMap)> {
    let grid = fitted_grid(scene, first_bin, dims)?;
    let opts = BackprojectOptions {
        time_sigma_opl: scene.film.bin_width_opl,
        falloff,
        ..BackprojectOptions::default()
    };
    let volume = backproject_with(scene, measured, &grid, &opts)?;
    let depth = depth_map(&volume, DEPTH_THRESHOLD)?;
    Ok((volume, depth))
}

/// The initial mesh of `Init::Backprojection`: the wall-facing height field over the
/// filled columns of a 32 x 32 x 64 backprojection's depth map, the backprojection
/// weighted by `|x_l − v|² |v − x_s|²` (`Falloff::Compensate`) so that a far object is
/// not dimmed below the threshold by the near one: two objects 0.5 m apart in depth both
/// start (docs/BASELINES.md; unweighted, only the near one did).
pub fn backprojection_mesh(scene: &Scene, measured: &[f32], first_bin: usize) -> Result<Mesh> {
    let (volume, depth) = backprojection(
        scene,
        measured,
        first_bin,
        [32, 32, 64],
        Falloff::Compensate,
    )?;
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

/// Writes the picture of the module doc to `path`; `fitted` is the whole fitted mesh
/// with its per-vertex albedo.
pub fn write_reconstruction_png(
    path: &Path,
    scene: &Scene,
    measured: &[f32],
    first_bin: usize,
    fitted: &Mesh,
) -> Result<()> {
    let dims = [
        (scene.scan.nx as usize).clamp(1, 64),
        (scene.scan.ny as usize).clamp(1, 64),
        128,
    ];
    let (volume, fbp_depth) = backprojection(scene, measured, first_bin, dims, Falloff::None)?;
    let fit_depth = super::score::mesh_depth_map(scene, fitted, true, &volume.grid);
    let [nx, ny, _] = volume.grid.dims;
    // Seen from the wall: +y up (top row last), +x to the left (last column first).
    let seen = |f: &dyn Fn(usize, usize) -> f32| -> Vec<f32> {
        (0..ny)
            .rev()
            .flat_map(|iy| (0..nx).rev().map(move |ix| (iy, ix)))
            .map(|(iy, ix)| f(ix, iy))
            .collect()
    };
    let relative = |v: Vec<f32>| {
        let max = v
            .iter()
            .copied()
            .filter(|x| x.is_finite())
            .fold(0.0f32, f32::max);
        v.into_iter()
            .map(|x| if max > 0.0 { x.max(0.0) / max } else { 0.0 })
            .collect::<Vec<f32>>()
    };
    let mip = relative(seen(&|ix, iy| {
        volume.column(ix, iy).iter().copied().fold(0.0, f32::max)
    }));
    let albedo = relative(seen(&|ix, iy| fit_depth.intensity[iy * nx + ix]));
    let depth_of = |dm: &DepthMap| seen(&|ix, iy| dm.at(ix, iy));
    let (fbp_d, fit_d) = (depth_of(&fbp_depth), depth_of(&fit_depth));
    let (lo, hi) = fbp_d
        .iter()
        .chain(&fit_d)
        .filter(|v| v.is_finite())
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let (lo, hi) = if lo <= hi {
        (lo, hi.max(lo + 1e-3))
    } else {
        (0.0, 1.0)
    };
    let threshold = format!("{:.0} %", 100.0 * DEPTH_THRESHOLD);
    let titles = [
        "filtered backprojection:\nmax. over depth (front view)".to_string(),
        "fitted surface: albedo of the\nfirst face along the wall normal".to_string(),
        format!("backprojection: depth of each\ncolumn's peak (black: < {threshold})"),
        "fitted surface: depth\n(black: no surface)".to_string(),
    ];
    let extent = volume.grid.max - volume.grid.min;
    let (su, sv) = (extent.x, extent.y);
    labelled_maps(
        path,
        &format!("umbra fit: the measurement's backprojection next to the fitted surface ({nx} x {ny} columns)"),
        &[
            MapPanel { title: &titles[0], width: nx, height: ny, values: &mip, range: (0.0, 1.0), unit: "intensity / its maximum" },
            MapPanel { title: &titles[1], width: nx, height: ny, values: &albedo, range: (0.0, 1.0), unit: "albedo / its maximum" },
            MapPanel { title: &titles[2], width: nx, height: ny, values: &fbp_d, range: (lo, hi), unit: "depth from the wall (m)" },
            MapPanel { title: &titles[3], width: nx, height: ny, values: &fit_d, range: (lo, hi), unit: "depth from the wall (m)" },
        ],
        &format!("All panels seen from the wall into the hidden scene: +y up, +x to the left (a letter facing the wall reads\ncorrectly); each spans the voxel grid, {su:.2} m x {sv:.2} m. Depths share one scale: near dark, far bright."),
    )
}
