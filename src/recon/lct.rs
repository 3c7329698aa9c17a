//! The light-cone transform (LCT; O'Toole, Lindell and Wetzstein, Nature 555, 2018): a
//! confocal capture's closed-form reconstruction, written from the paper's equations.
//!
//! A confocal scan point `x'` on the wall sees, at round-trip distance `2r`, every
//! hidden point at distance `r` (cosines neglected, as in the paper):
//!
//! `τ(x', r) = ∫ ρ(p) δ(|x' − p| − r) / r⁴ dp`.
//!
//! With `δ(|x' − p| − r) = 2r δ(|x' − p|² − r²)`, `v = r²` and `u = z²`
//! (`dz = du / 2√u`), this is a 3-D convolution:
//!
//! `r³ τ(x', √v) / 2 = ∫ ρ̃(x, u) h(x' − x, v − u) dx du`,
//! `ρ̃(x, u) = ρ(x, √u) / 2√u`,  `h(a, w) = δ(|a|² − w)` (a cone),
//!
//! solved for `ρ̃` by a Wiener filter, `ρ̂̃ = H̄ F / (|H|² + 1/snr)`, with `h` scaled to
//! unit L2 norm so `|H|²` averages 1 (the paper's code does the same). Steps:
//!
//! 1. each scan point's histogram as a density in `r` (the OPL `2r + legs`), averaged
//!    over each of `M` bins uniform in `v` over `[0, R²]` (`R`: the farthest distance the
//!    film sees; every count lands in one `v` bin, as the paper's resampling operator
//!    sums its fine samples), times `r³` at the bin's centre;
//! 2. zero-padded to `2 ny × 2 nx × 2 M` so the convolution does not wrap, FFT, filter,
//!    inverse FFT (`rustfft`, one axis at a time, lines in parallel: deterministic);
//! 3. `ρ(x, z) = 2z ρ̃(x, z²)` read at the grid's depths, negative values set to 0.
//!
//! Confocal captures only, on a regular scan whose cells are the grid's columns
//! ([`VoxelGrid::over_scan`]); anything else is refused with the reason.

use super::{legs, Volume, VoxelGrid, WallFrame};
use crate::error::{Error, Result};
use crate::scene::{CaptureType, Scene};
use rayon::prelude::*;
use rustfft::num_complex::Complex32;
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// LCT settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LctOptions {
    /// Signal-to-noise ratio of the Wiener filter (`1/snr` is added to `|H|²`, which
    /// averages 1). The LCT code's 0.8 by default; larger is sharper and noisier.
    pub snr: f32,
}

impl Default for LctOptions {
    fn default() -> Self {
        LctOptions { snr: 0.8 }
    }
}

/// The LCT of a confocal `data` (`(sy, sx, T)`, the scene's layout) on `grid`, whose
/// columns must be the scan's cells (`VoxelGrid::over_scan(scene, .., [sx, sy, nz])`).
pub fn lct(scene: &Scene, data: &[f32], grid: &VoxelGrid, opts: &LctOptions) -> Result<Volume> {
    let film = &scene.film;
    let bins = film.temporal_bins as usize;
    let nm = scene.num_measurements();
    if scene.capture != CaptureType::Confocal {
        return Err(Error::Invalid(format!(
            "LCT needs a confocal capture; this scene's capture_type is {}",
            scene.capture.name()
        )));
    }
    if bins == 0 || data.len() != nm * bins {
        return Err(Error::Invalid(format!(
            "LCT: the data hold {} values, but the scene's capture has {nm} measurements x {bins} bins",
            data.len()
        )));
    }
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(Error::Invalid(format!("LCT: data value {i} is not finite")));
    }
    if !(opts.snr.is_finite() && opts.snr > 0.0) {
        return Err(Error::Invalid(format!(
            "LCT: snr must be positive, got {}",
            opts.snr
        )));
    }
    let [nx, ny, nz] = grid.dims;
    let cells = scan_cells(scene, grid)?;
    // 1. r³ τ on bins uniform in v = r² over [0, R²].
    let end = film.start_opl + bins as f32 * film.bin_width_opl;
    let lg: Vec<f32> = (0..nm)
        .map(|m| {
            if scene.account_first_and_last_bounces {
                legs(scene, m)
            } else {
                0.0
            }
        })
        .collect();
    let r_max = lg
        .iter()
        .map(|l| 0.5 * (end - l))
        .fold(grid.max.z, f32::max);
    let m_bins = bins.max(nz).next_power_of_two();
    let dv = r_max * r_max / m_bins as f32;
    let dims = [2 * ny, 2 * nx, 2 * m_bins];
    let mut f = vec![Complex32::new(0.0, 0.0); dims[0] * dims[1] * dims[2]];
    let mut cumulative = vec![0.0f64; bins + 1];
    for (m, &(ix, iy)) in cells.iter().enumerate() {
        let h = &data[m * bins..(m + 1) * bins];
        for (b, &v) in h.iter().enumerate() {
            cumulative[b + 1] = cumulative[b] + v as f64;
        }
        // The histogram's integral up to OPL `2r + legs`, in counts (linear within a bin).
        let integral = |r: f64| {
            let fb = (2.0 * r + lg[m] as f64 - film.start_opl as f64) / film.bin_width_opl as f64;
            let fb = fb.clamp(0.0, bins as f64);
            let b = (fb.floor() as usize).min(bins - 1);
            cumulative[b] + (fb - b as f64) * h[b] as f64
        };
        let line = &mut f[(iy * dims[1] + ix) * dims[2]..][..m_bins];
        let mut below = integral(0.0);
        for (j, out) in line.iter_mut().enumerate() {
            // The v bin [j, j + 1) Δv is r in [√(j Δv), √((j + 1) Δv)): the mean density
            // over it (every count lands in one v bin, none is skipped), times r³.
            let (r_lo, r_hi) = (
                ((j as f64) * dv as f64).sqrt(),
                (((j + 1) as f64) * dv as f64).sqrt(),
            );
            let above = integral(r_hi);
            let r = ((j as f64 + 0.5) * dv as f64).sqrt();
            out.re = (r * r * r * (above - below) / (r_hi - r_lo)) as f32;
            below = above;
        }
    }
    // 2. the cone, unit L2 norm, on the padded lattice (offsets wrap).
    let (dx, dy) = (grid.voxel_size().x, grid.voxel_size().y);
    let mut psf = vec![Complex32::new(0.0, 0.0); f.len()];
    for oy in -(ny as i64 - 1)..ny as i64 {
        for ox in -(nx as i64 - 1)..nx as i64 {
            let (a, b) = (ox as f32 * dx, oy as f32 * dy);
            let q = (a * a + b * b) / dv;
            let k = q.floor() as usize;
            if k + 1 >= m_bins {
                continue;
            }
            let t = q - k as f32;
            let wy = oy.rem_euclid(dims[0] as i64) as usize;
            let wx = ox.rem_euclid(dims[1] as i64) as usize;
            let col = (wy * dims[1] + wx) * dims[2];
            psf[col + k].re += 1.0 - t;
            psf[col + k + 1].re += t;
        }
    }
    let norm = psf.iter().map(|c| c.re * c.re).sum::<f32>().sqrt();
    psf.iter_mut().for_each(|c| c.re /= norm);
    let mut planner = FftPlanner::<f32>::new();
    fft3(&mut f, dims, &mut planner, false);
    fft3(&mut psf, dims, &mut planner, false);
    let alpha = 1.0 / opts.snr;
    f.par_iter_mut().zip(&psf).for_each(|(fk, hk)| {
        *fk = hk.conj() * *fk / (hk.norm_sqr() + alpha);
    });
    drop(psf);
    fft3(&mut f, dims, &mut planner, true);
    // 3. ρ(z) = 2z ρ̃(z²) at the grid's depths.
    let scale = 1.0 / f.len() as f32;
    let mut out = vec![0.0f32; grid.len()];
    out.par_chunks_mut(nx * nz)
        .enumerate()
        .for_each(|(iy, row)| {
            for ix in 0..nx {
                let line = &f[(iy * dims[1] + ix) * dims[2]..][..m_bins];
                for iz in 0..nz {
                    let z = grid.center(ix, iy, iz).z;
                    let q = z * z / dv - 0.5;
                    let v = interpolate_complex_re(line, q) * scale;
                    row[ix * nz + iz] = (2.0 * z * v).max(0.0);
                }
            }
        });
    Ok(Volume {
        grid: grid.clone(),
        data: out,
    })
}

/// The grid column `(ix, iy)` of each measurement's scan point; an error unless every
/// column holds exactly one scan point at its centre.
fn scan_cells(scene: &Scene, grid: &VoxelGrid) -> Result<Vec<(usize, usize)>> {
    let [nx, ny, _] = grid.dims;
    let frame = WallFrame::of(scene);
    let size = grid.voxel_size();
    let mut seen = vec![false; nx * ny];
    let nm = scene.num_measurements();
    if nm != nx * ny {
        return Err(Error::Invalid(format!(
            "LCT: the grid has {nx} x {ny} columns but the scan {nm} points; use a grid over the scan with its resolution"
        )));
    }
    (0..nm)
        .map(|m| {
            let q = frame.to_frame(scene.measurement_points(m).1);
            let fx = (q.x - grid.min.x) / size.x - 0.5;
            let fy = (q.y - grid.min.y) / size.y - 0.5;
            let (ix, iy) = (fx.round(), fy.round());
            let off = (fx - ix).abs().max((fy - iy).abs()).max(q.z.abs() / size.x);
            let inside = ix >= 0.0 && iy >= 0.0 && (ix as usize) < nx && (iy as usize) < ny;
            if !inside || off > 0.01 {
                return Err(Error::Invalid(format!(
                    "LCT needs a regular scan along the wall's axes: scan point {m} is not at a column centre of the grid"
                )));
            }
            let c = (ix as usize, iy as usize);
            if std::mem::replace(&mut seen[c.1 * nx + c.0], true) {
                return Err(Error::Invalid(format!(
                    "LCT: two scan points fall in grid column ({}, {})",
                    c.0, c.1
                )));
            }
            Ok(c)
        })
        .collect()
}

fn interpolate_complex_re(line: &[Complex32], q: f32) -> f32 {
    if !(q > -1.0 && q < line.len() as f32) {
        return 0.0;
    }
    let i = q.floor() as i64;
    let t = q - i as f32;
    let at = |i: i64| {
        if i < 0 || i >= line.len() as i64 {
            0.0
        } else {
            line[i as usize].re
        }
    };
    (1.0 - t) * at(i) + t * at(i + 1)
}

/// In-place 3-D DFT of `data` (`dims`, last axis fastest); `inverse` unnormalised.
fn fft3(data: &mut [Complex32], dims: [usize; 3], planner: &mut FftPlanner<f32>, inverse: bool) {
    let plan = |n: usize, planner: &mut FftPlanner<f32>| -> Arc<dyn Fft<f32>> {
        if inverse {
            planner.plan_fft_inverse(n)
        } else {
            planner.plan_fft_forward(n)
        }
    };
    // Last axis: contiguous lines.
    let fz = plan(dims[2], planner);
    data.par_chunks_mut(dims[2])
        .for_each(|line| fz.process(line));
    // Middle axis: within each slab of the first axis.
    let fx = plan(dims[1], planner);
    data.par_chunks_mut(dims[1] * dims[2]).for_each(|slab| {
        let mut line = vec![Complex32::new(0.0, 0.0); dims[1]];
        for z in 0..dims[2] {
            for (x, c) in line.iter_mut().enumerate() {
                *c = slab[x * dims[2] + z];
            }
            fx.process(&mut line);
            for (x, c) in line.iter().enumerate() {
                slab[x * dims[2] + z] = *c;
            }
        }
    });
    // First axis: lines gathered per (x, z), transformed in parallel, scattered back.
    let fy = plan(dims[0], planner);
    let stride = dims[1] * dims[2];
    let lines: Vec<Vec<Complex32>> = (0..stride)
        .into_par_iter()
        .map(|i| {
            let mut line: Vec<Complex32> = (0..dims[0]).map(|y| data[y * stride + i]).collect();
            fy.process(&mut line);
            line
        })
        .collect();
    for (i, line) in lines.iter().enumerate() {
        for (y, c) in line.iter().enumerate() {
            data[y * stride + i] = *c;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fft3_round_trip_is_identity() {
        let dims = [4, 6, 8];
        let orig: Vec<Complex32> = (0..dims.iter().product::<usize>())
            .map(|i| Complex32::new((i as f32 * 0.37).sin(), (i as f32 * 0.11).cos()))
            .collect();
        let mut d = orig.clone();
        let mut p = FftPlanner::new();
        fft3(&mut d, dims, &mut p, false);
        fft3(&mut d, dims, &mut p, true);
        let n = d.len() as f32;
        for (a, b) in d.iter().zip(&orig) {
            assert!((a / n - b).norm() < 1e-5, "{a} vs {b}");
        }
    }

    #[test]
    fn fft3_of_a_shifted_delta_has_unit_magnitude() {
        let dims = [4, 4, 8];
        let mut d = vec![Complex32::new(0.0, 0.0); 128];
        d[(4 + 2) * 8 + 3] = Complex32::new(1.0, 0.0);
        fft3(&mut d, dims, &mut FftPlanner::new(), false);
        assert!(d.iter().all(|c| (c.norm() - 1.0).abs() < 1e-5));
        // and a nontrivial phase: not all equal
        assert!((d[1] - d[0]).norm() > 0.1);
    }
}
