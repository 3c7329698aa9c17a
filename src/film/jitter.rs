//! A detector's timing jitter applied to a render already binned with the box kernel:
//! each row `H[p, ·]` is convolved along time with a sampled, normalised Gaussian of
//! standard deviation `σ` (OPL, m),
//!
//! `H'[p, t] = Σ_k w_k H[p, t − k]`, `w_k ∝ exp(−k² / 2σ_b²)`, `|k| ≤ 5 σ_b`,
//! `σ_b = σ / bin_width`, `Σ w_k = 1`.
//!
//! It is a linear map; the adjoint pass applies its transpose to `δH'`
//! ([`JitterKernel::apply_transpose`]). Shifted by `δ` (an unknown time offset of the
//! capture), `w_k ∝ exp(−(k − δ_b)² / 2σ_b²)`: a fractional shift, smooth in `δ`, whose
//! derivative ([`JitterKernel::apply_derivative`]) the fit's time-offset search uses. Next to the film's exact Gaussian kernel (`kernel = "gaussian"`, each
//! contribution integrated against `Φ` over every bin) this is the discrete
//! approximation `box ⊛ sampled Gaussian`: as accurate as the box bins already were
//! when `σ` is at least a bin, and it costs about `10σ_b + 1` multiply-adds per bin after
//! the render instead of ten times the `tri3` splat. Used by `umbra fit --jitter` (the
//! LCT captures' SPAD has about 70 ps FWHM, `σ ≈ 9 mm` of OPL).

/// Half-width of the kernel's support, in σ.
const REACH: f64 = 5.0;

/// The jitter kernel, optionally shifted by `δ` (a time offset, OPL): `H'[t] = Σ_j
/// taps[j] H[t − (first + j)]`, with `taps[j] ∝ exp(−(first + j − δ_b)² / 2σ_b²)` over
/// `|first + j − δ_b| ≤ 5σ_b` (less the Gaussian's value there, so taps enter and leave
/// the support continuously as `δ` moves), `δ_b = δ / bin_width`, normalised to 1.
#[derive(Clone, Debug, PartialEq)]
pub struct JitterKernel {
    /// Lag of `taps[0]` in bins.
    pub first: isize,
    pub taps: Vec<f64>,
    /// `∂taps[j]/∂δ_b` (per bin of shift), for the time-offset derivative.
    pub d_taps: Vec<f64>,
}

impl JitterKernel {
    /// The kernel for `σ_b` bins shifted by `δ_b` bins; the identity for `σ_b` below 0.05
    /// bins (then `δ_b` must be 0: a shift needs a smooth kernel to be differentiable).
    pub fn new(sigma_bins: f64, shift_bins: f64) -> JitterKernel {
        if !sigma_bins.is_finite() || sigma_bins < 0.05 {
            return JitterKernel {
                first: 0,
                taps: vec![1.0],
                d_taps: vec![0.0],
            };
        }
        // The Gaussian minus its value at the reach, so a tap fades to 0 as the shift
        // moves it out of the support: the kernel is continuous in δ.
        let reach = REACH * sigma_bins;
        let floor = (-REACH * REACH / 2.0).exp();
        let first = (shift_bins - reach).floor() as isize;
        let last = (shift_bins + reach).ceil() as isize;
        let gauss =
            |k: isize| (-(k as f64 - shift_bins).powi(2) / (2.0 * sigma_bins * sigma_bins)).exp();
        let raw: Vec<f64> = (first..=last)
            .map(|k| (gauss(k) - floor).max(0.0))
            .collect();
        // d raw_k / dδ = G_k (k − δ) / σ² inside the support; the normalised taps'
        // derivative by the quotient rule.
        let d_raw: Vec<f64> = (first..=last)
            .zip(&raw)
            .map(|(k, r)| {
                if *r > 0.0 {
                    gauss(k) * (k as f64 - shift_bins) / (sigma_bins * sigma_bins)
                } else {
                    0.0
                }
            })
            .collect();
        let z: f64 = raw.iter().sum();
        let dz: f64 = d_raw.iter().sum();
        let taps = raw.iter().map(|r| r / z).collect();
        let d_taps = raw
            .iter()
            .zip(&d_raw)
            .map(|(r, d)| d / z - r * dz / (z * z))
            .collect();
        JitterKernel {
            first,
            taps,
            d_taps,
        }
    }

    /// A causal kernel with the given taps (lag 0 first), e.g. a measured impulse
    /// response ([`super::irf::Irf`]); no shift derivative.
    pub fn from_taps(taps: Vec<f64>) -> JitterKernel {
        let d_taps = vec![0.0; taps.len()];
        JitterKernel {
            first: 0,
            taps,
            d_taps,
        }
    }

    /// Applies `weights` (the taps or their derivative) to every `bins`-long row, in
    /// place; `transpose` applies the transposed map (the adjoint).
    fn apply_with(&self, weights: &[f64], data: &mut [f32], bins: usize, transpose: bool) {
        if bins == 0 || (self.taps.len() == 1 && self.first == 0 && weights[0] == 1.0) {
            return;
        }
        let mut row_in = vec![0.0f64; bins];
        for row in data.chunks_mut(bins) {
            for (a, &b) in row_in.iter_mut().zip(row.iter()) {
                *a = b as f64;
            }
            for (t, out) in row.iter_mut().enumerate() {
                let mut acc = 0.0;
                for (j, w) in weights.iter().enumerate() {
                    let lag = self.first + j as isize;
                    // forward: H[t − lag]; transpose: A[t + lag].
                    let s = if transpose {
                        t as isize + lag
                    } else {
                        t as isize - lag
                    };
                    if (0..bins as isize).contains(&s) {
                        acc += w * row_in[s as usize];
                    }
                }
                *out = acc as f32;
            }
        }
    }

    /// `H ← K H` row by row (zero beyond the row's ends).
    pub fn apply(&self, data: &mut [f32], bins: usize) {
        self.apply_with(&self.taps, data, bins, false);
    }

    /// `A ← Kᵀ A`: the adjoint of [`JitterKernel::apply`].
    pub fn apply_transpose(&self, data: &mut [f32], bins: usize) {
        self.apply_with(&self.taps, data, bins, true);
    }

    /// `∂(K H)/∂δ_b`, row by row.
    pub fn apply_derivative(&self, data: &mut [f32], bins: usize) {
        self.apply_with(&self.d_taps, data, bins, false);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn moments(k: &JitterKernel) -> (f64, f64, f64) {
        let lags = (0..k.taps.len()).map(|j| (k.first + j as isize) as f64);
        let m0: f64 = k.taps.iter().sum();
        let m1: f64 = lags.clone().zip(&k.taps).map(|(l, w)| l * w).sum();
        let m2: f64 = lags.zip(&k.taps).map(|(l, w)| (l - m1).powi(2) * w).sum();
        (m0, m1, m2.sqrt())
    }

    #[test]
    fn taps_are_normalised_centred_on_the_shift_and_as_wide_as_sigma() {
        for (sigma, shift) in [(1.0, 0.0), (2.5, 0.0), (1.5, 0.37), (2.0, -3.6)] {
            let (m0, m1, sd) = moments(&JitterKernel::new(sigma, shift));
            assert!((m0 - 1.0).abs() < 1e-12);
            assert!((m1 - shift).abs() < 1e-3, "{sigma} {shift}: mean {m1}");
            assert!((sd - sigma).abs() < 2e-3 * sigma, "{sigma}: sd {sd}");
        }
        let id = JitterKernel::new(0.0, 0.0);
        assert_eq!((id.first, id.taps.clone()), (0, vec![1.0]));
    }

    #[test]
    fn transpose_is_the_adjoint_and_the_shift_derivative_matches_differences() {
        let bins = 40;
        let a: Vec<f32> = (0..2 * bins)
            .map(|i| ((i * 37 % 11) as f32).sin())
            .collect();
        let b: Vec<f32> = (0..2 * bins).map(|i| ((i * 13 % 7) as f32).cos()).collect();
        let dot = |x: &[f32], y: &[f32]| -> f64 {
            x.iter().zip(y).map(|(x, y)| *x as f64 * *y as f64).sum()
        };
        for shift in [0.0, 1.3, -2.7] {
            let k = JitterKernel::new(2.0, shift);
            let (mut ka, mut ktb) = (a.clone(), b.clone());
            k.apply(&mut ka, bins);
            k.apply_transpose(&mut ktb, bins);
            assert!((dot(&ka, &b) - dot(&a, &ktb)).abs() < 1e-5, "shift {shift}");
            // ∂(K a)/∂δ against central differences of the shift.
            let mut da = a.clone();
            k.apply_derivative(&mut da, bins);
            let h = 1e-3;
            let (mut p, mut m) = (a.clone(), a.clone());
            JitterKernel::new(2.0, shift + h).apply(&mut p, bins);
            JitterKernel::new(2.0, shift - h).apply(&mut m, bins);
            for i in 0..a.len() {
                let fd = (p[i] as f64 - m[i] as f64) / (2.0 * h);
                assert!(
                    (fd - da[i] as f64).abs() < 2e-3,
                    "shift {shift} bin {i}: {fd} vs {}",
                    da[i]
                );
            }
        }
        // A pulse far from the ends keeps its mass and moves by the shift.
        let mut x = vec![0.0f32; bins];
        x[20] = 1.0;
        JitterKernel::new(1.5, 2.5).apply(&mut x, bins);
        let m0: f32 = x.iter().sum();
        let c: f32 = x.iter().enumerate().map(|(i, v)| i as f32 * v).sum();
        assert!(
            (m0 - 1.0).abs() < 1e-6 && (c - 22.5).abs() < 1e-3,
            "{m0} {c}"
        );
    }
}
