//! Phasor-field reconstruction (Liu et al., Nature 572, 2019), in its backprojection
//! form: each histogram is convolved along time with a virtual illumination pulse,
//!
//! `P(τ) = exp(2πi τ/λ) exp(−τ²/2σ²)`,  `σ = cycles λ / 6`
//!
//! (a wave of wavelength `λ`, in m of OPL, whose Gaussian envelope holds `cycles`
//! periods within ±3σ), and the complex result is backprojected (real and imaginary
//! parts through [`super::backproject`], unfiltered); the image is the magnitude. The
//! paper shows this equals propagating the phasor field from the wall with the
//! Rayleigh–Sommerfeld integral in the time domain; its fast RSD solver is a faster
//! route to the same volume, not another estimate. Any capture (single, confocal,
//! exhaustive). Resolution: about `λ/2` laterally and in depth, so `λ` should be a
//! few scan spacings (the paper's rule: at least twice the spacing).

use super::{backproject, Filter, Volume, VoxelGrid};
use crate::error::{Error, Result};
use crate::scene::Scene;
use rayon::prelude::*;

/// Phasor-field settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhasorOptions {
    /// Virtual wavelength (m of OPL).
    pub wavelength: f32,
    /// Periods within the pulse's ±3σ.
    pub cycles: f32,
}

impl PhasorOptions {
    /// `λ` twice the scan's larger spacing, 4 cycles.
    pub fn for_scene(scene: &Scene) -> PhasorOptions {
        let scan = &scene.scan;
        let du = scan.axis_u.length() / scan.nx.max(1) as f32;
        let dv = scan.axis_v.length() / scan.ny.max(1) as f32;
        PhasorOptions {
            wavelength: 2.0 * du.max(dv),
            cycles: 4.0,
        }
    }
}

/// The phasor-field volume of `data` (the scene's layout) on `grid` (module docs).
pub fn phasor_field(
    scene: &Scene,
    data: &[f32],
    grid: &VoxelGrid,
    opts: &PhasorOptions,
) -> Result<Volume> {
    let film = &scene.film;
    let bins = film.temporal_bins as usize;
    let ok = |v: f32| v.is_finite() && v > 0.0;
    if !(ok(opts.wavelength) && ok(opts.cycles)) {
        return Err(Error::Invalid(format!(
            "phasor field: wavelength and cycles must be positive, got {} and {}",
            opts.wavelength, opts.cycles
        )));
    }
    if bins == 0 || !data.len().is_multiple_of(bins) {
        return Err(Error::Invalid(format!(
            "phasor field: {} values are not whole histograms of {bins} bins",
            data.len()
        )));
    }
    let sigma = opts.cycles * opts.wavelength / 6.0 / film.bin_width_opl; // bins
    let half = (3.0 * sigma).ceil() as usize;
    if half > 4 * bins {
        return Err(Error::Invalid(format!(
            "phasor field: the pulse ({} m of OPL) is far longer than the film",
            6.0 * sigma * film.bin_width_opl
        )));
    }
    let k = 2.0 * std::f32::consts::PI * film.bin_width_opl / opts.wavelength; // rad per bin
    let taps: Vec<(f32, f32)> = (0..=2 * half)
        .map(|j| {
            let d = j as f32 - half as f32;
            let g = (-0.5 * d * d / (sigma * sigma)).exp();
            (g * (k * d).cos(), g * (k * d).sin())
        })
        .collect();
    let mut re = vec![0.0f32; data.len()];
    let mut im = vec![0.0f32; data.len()];
    re.par_chunks_mut(bins)
        .zip(im.par_chunks_mut(bins))
        .zip(data.par_chunks(bins))
        .for_each(|((re, im), h)| {
            // (h ⋆ P)[b] = Σ_d h[b − d] P(d)
            for (b, (r, i)) in re.iter_mut().zip(im.iter_mut()).enumerate() {
                let (mut sr, mut si) = (0.0, 0.0);
                for (j, &(pr, pi)) in taps.iter().enumerate() {
                    let src = b as i64 - (j as i64 - half as i64);
                    if src >= 0 && (src as usize) < bins {
                        let v = h[src as usize];
                        sr += v * pr;
                        si += v * pi;
                    }
                }
                (*r, *i) = (sr, si);
            }
        });
    let vr = backproject(scene, &re, grid, Filter::None)?;
    let vi = backproject(scene, &im, grid, Filter::None)?;
    let data = vr
        .data
        .iter()
        .zip(&vi.data)
        .map(|(a, b)| a.hypot(*b))
        .collect();
    Ok(Volume {
        grid: vr.grid,
        data,
    })
}
