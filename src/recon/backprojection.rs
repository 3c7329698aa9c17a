//! Backprojection of a transient into a voxel grid (module doc of [`crate::recon`]):
//!
//! `V(v) = Σ_m w_m(v) H_m(τ_m(v))`,  `τ_m(v) = |x_l − v| + |v − x_s| + legs_m`,
//!
//! then optionally `F[z] = −(V[z−1] − 2V[z] + V[z+1])` along depth.
//!
//! `H_m(τ)` is read at the continuous bin coordinate `f = (τ − start)/width − ½` (bin
//! `b`'s value sits at its centre) by linear interpolation, with `H = 0` at the centres
//! of the (virtual) bins just outside the film, so the interpolant falls to zero over
//! the last bin at either end and OPLs farther out add nothing.
//!
//! The work is parallel over rows of voxel columns. Within a row, each measurement's
//! histogram (stored as interpolation pieces, see [`pieces`]) is loaded once and used
//! by every column of the row while it sits in cache. For one column and measurement,
//! the lateral part of `|x − v|²` is computed once; a vectorised loop turns the column's
//! depths into piece indices and offsets, and a scalar loop gathers and accumulates.
//! Confocal captures (`x_l = x_s`) take one square root per voxel and measurement.
//! Measured: 64 x 64 confocal measurements x 64³ voxels in about 2 s on one core.

use super::{legs, BackprojectOptions, Falloff, Filter, Volume, VoxelGrid, WallFrame};
use crate::error::{Error, Result};
use crate::scene::{FilmSpec, Scene};
use glam::Vec3;
use rayon::prelude::*;

/// A measurement's constants in the wall frame.
#[derive(Clone, Copy)]
struct Meas {
    l: Vec3,
    s: Vec3,
    /// `legs − start` (m): added to the hidden path length to get OPL past the film start.
    offset: f32,
}

/// Filtered backprojection of `data` (the scene's layout, `(sy, sx, T)` or
/// `(sy, sx, ly, lx, T)`, `T = scene.film.temporal_bins`) into `grid`, unweighted
/// ([`Falloff::None`]).
pub fn backproject(
    scene: &Scene,
    data: &[f32],
    grid: &VoxelGrid,
    filter: Filter,
) -> Result<Volume> {
    backproject_with(
        scene,
        data,
        grid,
        &BackprojectOptions {
            filter,
            ..Default::default()
        },
    )
}

/// [`backproject`] with every option.
pub fn backproject_with(
    scene: &Scene,
    data: &[f32],
    grid: &VoxelGrid,
    opts: &BackprojectOptions,
) -> Result<Volume> {
    let film = &scene.film;
    let bins = film.temporal_bins as usize;
    let nm = scene.num_measurements();
    if bins == 0 || data.len() != nm * bins {
        return Err(Error::Invalid(format!(
            "backprojection: the data hold {} values, but the scene's capture has {nm} measurements x {bins} bins",
            data.len()
        )));
    }
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(Error::Invalid(format!(
            "backprojection: data value {i} is not finite"
        )));
    }
    if !(film.bin_width_opl.is_finite() && film.bin_width_opl > 0.0 && film.start_opl.is_finite()) {
        return Err(Error::Invalid(
            "backprojection: the film needs a finite start and a positive bin width".into(),
        ));
    }
    if bins >= 1 << 22 {
        return Err(Error::Invalid(format!(
            "backprojection: {bins} bins is too many (at most 2^22); downsample the time axis"
        )));
    }
    // Re-check the grid: its fields are public.
    let grid = VoxelGrid::new(grid.min, grid.max, grid.dims)?;
    let sigma = opts.time_sigma_opl / film.bin_width_opl;
    if !(sigma.is_finite() && sigma >= 0.0) {
        return Err(Error::Invalid(format!(
            "backprojection: time_sigma_opl must be finite and >= 0, got {}",
            opts.time_sigma_opl
        )));
    }
    let smoothed;
    let data = if sigma > 0.0 {
        smoothed = gaussian_blur(data, bins, sigma);
        &smoothed[..]
    } else {
        data
    };

    let frame = WallFrame::of(scene);
    let meas: Vec<Meas> = (0..nm)
        .map(|m| {
            let (x_l, x_s) = scene.measurement_points(m);
            let legs = if scene.account_first_and_last_bounces {
                legs(scene, m)
            } else {
                0.0
            };
            Meas {
                l: frame.to_frame(x_l),
                s: frame.to_frame(x_s),
                offset: legs - film.start_opl,
            }
        })
        .collect();
    let confocal = meas.iter().all(|k| k.l == k.s);
    let [nx, _, nz] = grid.dims;
    let zs: Vec<f32> = (0..nz).map(|iz| grid.center(0, 0, iz).z).collect();
    let inv_w = 1.0 / film.bin_width_opl;
    let compensate = opts.falloff == Falloff::Compensate;
    // Largest piece coordinate: the zero piece after the film's last virtual bin.
    let top = (bins + 1) as f32;

    let pieces = pieces(data, bins);
    let xs: Vec<f32> = (0..nx).map(|ix| grid.center(ix, 0, 0).x).collect();
    let mut out = vec![0.0f32; grid.len()];
    // One task per row of columns: each measurement's histogram is read once per row
    // and stays in cache while the row's columns use it.
    out.par_chunks_mut(nx * nz)
        .enumerate()
        .for_each(|(iy, row_acc)| {
            let y = grid.center(0, iy, 0).y;
            let mut ts = vec![0.0f32; nz];
            let mut ix = vec![0i32; nz];
            let mut ws = vec![1.0f32; nz];
            for (k, hist) in meas.iter().zip(pieces.chunks_exact(bins + 2)) {
                let (dyl, dys) = ((y - k.l.y).powi(2), (y - k.s.y).powi(2));
                // `g = f + 1` indexes the pieces: `g = τ_hidden / width + a`.
                let a = k.offset * inv_w + 0.5;
                // Piece index and position in it, split off `g`; `max` first maps NaN
                // to 0. Loops without branches or loads, which the compiler vectorises.
                let split = |g: f32, i: &mut i32, t: &mut f32| {
                    let g = g.max(0.0).min(top);
                    let fl = g.floor();
                    *i = int_below_2_23(fl);
                    *t = g - fl;
                };
                for (acc, &x) in row_acc.chunks_exact_mut(nz).zip(&xs) {
                    let lat_l = (x - k.l.x).powi(2) + dyl;
                    let lat_s = (x - k.s.x).powi(2) + dys;
                    let voxels = ts.iter_mut().zip(ix.iter_mut()).zip(&zs);
                    if confocal {
                        for ((t, i), &z) in voxels {
                            let r2 = lat_l + (z - k.l.z).powi(2);
                            split(2.0 * r2.sqrt() * inv_w + a, i, t);
                        }
                    } else {
                        for ((t, i), &z) in voxels {
                            let rl = (lat_l + (z - k.l.z).powi(2)).sqrt();
                            let rs = (lat_s + (z - k.s.z).powi(2)).sqrt();
                            split((rl + rs) * inv_w + a, i, t);
                        }
                    }
                    if compensate {
                        for (w, &z) in ws.iter_mut().zip(&zs) {
                            *w = (lat_l + (z - k.l.z).powi(2)) * (lat_s + (z - k.s.z).powi(2));
                        }
                        gather::<true>(acc, &ix, &ts, &ws, hist);
                    } else {
                        gather::<false>(acc, &ix, &ts, &ws, hist);
                    }
                }
            }
            if opts.filter == Filter::DepthLaplacian {
                row_acc.chunks_exact_mut(nz).for_each(depth_laplacian);
            }
        });
    Ok(Volume { grid, data: out })
}

/// Each histogram as `(H[b−1], H[b] − H[b−1])` for `b = 0 ..= T + 1`, with `H[−1] =
/// H[T] = 0`: the value and slope of the piece of the interpolant that starts at bin
/// coordinate `b − 1`, so a sample needs one load and no branch.
fn pieces(data: &[f32], bins: usize) -> Vec<[f32; 2]> {
    let mut out = Vec::with_capacity(data.len() / bins * (bins + 2));
    for h in data.chunks_exact(bins) {
        let mut prev = 0.0;
        for &v in h.iter().chain([0.0, 0.0].iter()) {
            out.push([prev, v - prev]);
            prev = v;
        }
    }
    out
}

/// `x` as an integer, for whole `x` in `[0, 2²³)`: adding 2²³ puts `x` in the mantissa.
/// Unlike `as i32` (which saturates and maps NaN to 0) this is plain arithmetic, so
/// loops using it vectorise.
#[inline(always)]
fn int_below_2_23(x: f32) -> i32 {
    const TWO_23: f32 = 8_388_608.0;
    (x + TWO_23).to_bits().wrapping_sub(TWO_23.to_bits()) as i32
}

/// `acc[i] += ws[i] · (v + t d)` with `[v, d] = p[ix[i]]`, `t = ts[i]` (`ws` ignored
/// unless `WEIGHTED`): the histogram whose [`pieces`] are `p`, at bin coordinate
/// `ix + t − 1` (bin centres at integers), linear between centres, falling linearly to
/// zero over the bin past either end, zero beyond (`ix` is clamped to `p`).
#[inline(always)]
fn gather<const WEIGHTED: bool>(
    acc: &mut [f32],
    ix: &[i32],
    ts: &[f32],
    ws: &[f32],
    p: &[[f32; 2]],
) {
    for (((a, &i), &t), &w) in acc.iter_mut().zip(ix).zip(ts).zip(ws) {
        let [v, d] = p[i as usize];
        let h = v + t * d;
        *a += if WEIGHTED { w * h } else { h };
    }
}

/// Each histogram of `bins` bins convolved with a Gaussian of `sigma` bins (truncated at
/// 3σ, zero outside the film).
fn gaussian_blur(data: &[f32], bins: usize, sigma: f32) -> Vec<f32> {
    let r = ((3.0 * sigma).ceil() as usize).min(bins);
    let mut k: Vec<f32> = (0..=2 * r)
        .map(|i| (-0.5 * ((i as f32 - r as f32) / sigma).powi(2)).exp())
        .collect();
    let sum: f32 = k.iter().sum();
    k.iter_mut().for_each(|w| *w /= sum);
    let mut out = vec![0.0f32; data.len()];
    out.par_chunks_mut(bins)
        .zip(data.par_chunks(bins))
        .for_each(|(o, h)| {
            for (b, &v) in h.iter().enumerate() {
                if v == 0.0 {
                    continue;
                }
                let lo = b.saturating_sub(r);
                let hi = (b + r + 1).min(bins);
                for (t, w) in o[lo..hi].iter_mut().zip(&k[lo + r - b..]) {
                    *t += w * v;
                }
            }
        });
    out
}

/// In place `c[z] ← 2c[z] − c[z−1] − c[z+1]`, the ends repeated.
fn depth_laplacian(c: &mut [f32]) {
    let n = c.len();
    let mut prev = c.first().copied().unwrap_or(0.0);
    for z in 0..n {
        let cur = c[z];
        let next = if z + 1 < n { c[z + 1] } else { cur };
        c[z] = 2.0 * cur - prev - next;
        prev = cur;
    }
}

/// Sums groups of `k` bins: bin `b` of the result is bins `[bk, (b+1)k)` of the input
/// (the last group may be shorter). Returns the matching film (`k` times wider bins, the
/// same start) and the data. `data` holds whole histograms of `film.temporal_bins` bins.
pub fn downsample_time(film: &FilmSpec, data: &[f32], k: usize) -> Result<(FilmSpec, Vec<f32>)> {
    let bins = film.temporal_bins as usize;
    if k == 0 || bins == 0 || !data.len().is_multiple_of(bins) {
        return Err(Error::Invalid(format!(
            "downsample_time: need k >= 1 and whole histograms of {bins} bins, got k = {k} and {} values",
            data.len()
        )));
    }
    let out_bins = bins.div_ceil(k);
    let out: Vec<f32> = data
        .chunks_exact(bins)
        .flat_map(|h| h.chunks(k).map(|g| g.iter().sum::<f32>()))
        .collect();
    let film = FilmSpec {
        temporal_bins: out_bins as u32,
        bin_width_opl: film.bin_width_opl * k as f32,
        ..film.clone()
    };
    Ok((film, out))
}

/// Zeroes the first `first` bins of every histogram of `bins` bins (e.g. the residual
/// direct light of the LCT captures, which the original code zeroes up to bin 600).
pub fn zero_bins_before(data: &mut [f32], bins: usize, first: usize) {
    if bins == 0 {
        return;
    }
    for h in data.chunks_mut(bins) {
        let n = first.min(h.len());
        h[..n].fill(0.0);
    }
}

/// Each histogram of `bins` bins less the mean of its last tenth (a capture's floor of dark
/// counts and ambient light, which the LCT's `r³` weight would otherwise make the
/// brightest thing at the far end of every column).
pub fn subtract_floor(data: &mut [f32], bins: usize) {
    if bins == 0 {
        return;
    }
    let tail = (bins / 10).max(1);
    for h in data.chunks_exact_mut(bins) {
        let floor = h[bins - tail..].iter().map(|&v| v as f64).sum::<f64>() / tail as f64;
        h.iter_mut().for_each(|v| *v -= floor as f32);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The histogram at bin coordinate `f`, as the backprojection reads it.
    fn sample(row: &[f32], f: f32) -> f32 {
        let top = (row.len() + 1) as f32;
        let g = (f + 1.0).max(0.0).min(top);
        let i = int_below_2_23(g.floor());
        let mut a = [0.0];
        gather::<true>(
            &mut a,
            &[i],
            &[g - g.floor()],
            &[2.0],
            &pieces(row, row.len()),
        );
        a[0] / 2.0
    }

    #[test]
    fn sample_interpolates_between_centres() {
        let row = [1.0, 3.0, 5.0];
        assert_eq!(sample(&row, 0.0), 1.0);
        assert_eq!(sample(&row, 0.5), 2.0);
        assert_eq!(sample(&row, 2.0), 5.0);
        assert_eq!(sample(&row, -0.5), 0.5);
        assert_eq!(sample(&row, 2.75), 1.25);
        for out in [-1.0, -7.0, 3.0, 3.5, 1e9, f32::NAN] {
            assert_eq!(sample(&row, out), 0.0, "{out}");
        }
        assert_eq!(sample(&[8.0], 0.25), 6.0);
        for x in [0.0, 1.0, 77.0, 4_194_305.0] {
            assert_eq!(int_below_2_23(x), x as i32);
        }
    }

    #[test]
    fn laplacian_of_a_line_is_zero_inside() {
        let mut c = [1.0, 2.0, 3.0, 4.0];
        depth_laplacian(&mut c);
        assert_eq!(c, [-1.0, 0.0, 0.0, 1.0]);
        let mut p = [0.0, 0.0, 1.0, 0.0, 0.0];
        depth_laplacian(&mut p);
        assert_eq!(p, [0.0, -1.0, 2.0, -1.0, 0.0]);
    }

    #[test]
    fn blur_keeps_the_mass_and_the_mean() {
        let mut h = vec![0.0f32; 41];
        h[20] = 1.0;
        h[0] = 0.5;
        let b = gaussian_blur(&h, 41, 2.0);
        let mid: f32 = b[10..31].iter().sum();
        assert!((mid - 1.0).abs() < 1e-4, "{mid}");
        let mean: f32 = (10..31).map(|i| i as f32 * b[i]).sum::<f32>() / mid;
        assert!((mean - 20.0).abs() < 1e-4);
        assert!((b[19] - b[21]).abs() < 1e-7 && b[20] > b[19]);
    }

    #[test]
    fn downsampling_sums_groups() {
        let film = FilmSpec {
            temporal_bins: 5,
            bin_width_opl: 0.01,
            start_opl: 1.0,
            kernel: crate::scene::KernelSpec::Box,
        };
        let d: Vec<f32> = (0..10).map(|v| v as f32).collect();
        let (f, o) = downsample_time(&film, &d, 2).unwrap();
        assert_eq!(o, vec![1.0, 5.0, 4.0, 11.0, 15.0, 9.0]);
        assert_eq!(
            (f.temporal_bins, f.bin_width_opl, f.start_opl),
            (3, 0.02, 1.0)
        );
        assert!(downsample_time(&film, &d[..7], 2).is_err());
        assert!(downsample_time(&film, &d, 0).is_err());
    }
}
