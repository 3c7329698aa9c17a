//! The comparison of a render with the measurement through the detector's response (a
//! timing-jitter Gaussian, or a measured IRF, [`crate::film::irf`]) and, with the
//! Gaussian, an optional unknown time offset `δ` (OPL, m): with `K_δ` the jitter kernel
//! shifted by `δ` ([`crate::film::jitter::JitterKernel`]) and `Z` the mask of the fitted
//! bins,
//!
//! `L(θ) = min_{|δ| ≤ δ_max} min_{s, b} ‖s Z K_δ H(θ) + b − Z M‖² / ‖Z M‖²`
//!
//! (the inner minimum in closed form, [`super::intensity::intensity_l2`]). Real captures
//! put time zero where the calibration says, which is off by a few millimetres of OPL
//! (the LCT data are "rectified" to the wall); a fit that cannot shift moves the whole
//! surface instead. `δ` is found per evaluation by a grid over `[−δ_max, δ_max]` (steps
//! of σ/4) refined by golden sections to 1e-4 bins: cheap (each trial blurs a render that
//! is already there), and since `δ` minimises `L`, the envelope theorem gives
//! `dL/dθ = Kᵀ_δ* δH'`, the adjoint at the found `δ*` (no derivative through `δ`).
//! The shift is smooth only through a smooth kernel: it needs `σ > 0` (with box bins the
//! loss is piecewise constant in `δ`, the time-shift gradient lost; docs/FITTING.md).

use super::intensity::{intensity_l2, Intensity, IntensityModel};
use super::objective::zero_leading_bins;
use crate::film::jitter::JitterKernel;

/// What [`compare`] returns.
pub struct Comparison {
    pub loss: f64,
    /// `∂L/∂H` with respect to the render before the kernel.
    pub adjoint: Vec<f32>,
    pub intensity: Intensity,
    /// `δ*` in bins (multiply by the bin width for OPL).
    pub offset_bins: f64,
    /// `Z K_δ* H`: the render as it was compared (the fitted transient is `s` times this
    /// plus the background).
    pub fitted: Vec<f32>,
}

/// The settings of [`Comparator::compare`], in bins of the render.
#[derive(Clone, Debug)]
pub struct Comparator {
    pub bins: usize,
    pub first_bin: usize,
    pub intensity: IntensityModel,
    /// Jitter `σ` in bins (0: none).
    pub sigma_bins: f64,
    /// Largest `|δ|` searched, in bins (0: no offset).
    pub offset_max_bins: f64,
    /// A measured impulse response at the render's bin width (lag 0 first), used instead
    /// of the Gaussian when not empty (no offset search then).
    pub irf: Vec<f64>,
}

impl Comparator {
    fn kernel(&self, shift: f64) -> JitterKernel {
        if self.irf.is_empty() {
            JitterKernel::new(self.sigma_bins, shift)
        } else {
            JitterKernel::from_taps(self.irf.clone())
        }
    }

    /// `Z K_δ H`: the render as compared at shift `shift` (bins), without fitting the
    /// intensity or the shift.
    pub fn response(&self, raw: &[f32], shift: f64) -> Vec<f32> {
        self.fitted(raw, shift).0
    }

    /// `Z K_δ H`: the render as compared at shift `shift` (bins), and the kernel.
    fn fitted(&self, raw: &[f32], shift: f64) -> (Vec<f32>, JitterKernel) {
        let kernel = self.kernel(shift);
        let mut fitted = raw.to_vec();
        kernel.apply(&mut fitted, self.bins);
        zero_leading_bins(&mut fitted, self.bins, self.first_bin);
        (fitted, kernel)
    }

    fn at(
        &self,
        raw: &[f32],
        measured: &[f32],
        shift: f64,
    ) -> (f64, Vec<f32>, Intensity, Vec<f32>) {
        let (fitted, kernel) = self.fitted(raw, shift);
        let (loss, mut adjoint, intensity) =
            intensity_l2(&fitted, measured, self.bins, self.first_bin, self.intensity);
        kernel.apply_transpose(&mut adjoint, self.bins);
        (loss, adjoint, intensity, fitted)
    }

    /// The loss alone at `shift` (the offset search's trials: no adjoint).
    fn loss_at(&self, raw: &[f32], measured: &[f32], shift: f64) -> f64 {
        let (fitted, _) = self.fitted(raw, shift);
        intensity_l2(&fitted, measured, self.bins, self.first_bin, self.intensity).0
    }

    /// The best `δ` in `[−δ_max, δ_max]` (bins).
    fn best_offset(&self, raw: &[f32], measured: &[f32]) -> f64 {
        let max = self.offset_max_bins;
        if max <= 0.0 || self.sigma_bins < 0.05 || !self.irf.is_empty() {
            return 0.0;
        }
        let step = (0.25 * self.sigma_bins).max(max / 200.0);
        let n = (2.0 * max / step).ceil() as usize;
        let grid = (0..=n).map(|i| (-max + i as f64 * step).min(max));
        let (mut best, mut best_loss) = (0.0, self.loss_at(raw, measured, 0.0));
        for d in grid {
            let l = self.loss_at(raw, measured, d);
            if l < best_loss {
                (best, best_loss) = (d, l);
            }
        }
        // Golden sections on the grid cell either side of the best point.
        let (mut a, mut b) = ((best - step).max(-max), (best + step).min(max));
        let r = 0.5 * (5f64.sqrt() - 1.0);
        let (mut c, mut d) = (b - r * (b - a), a + r * (b - a));
        let (mut fc, mut fd) = (
            self.loss_at(raw, measured, c),
            self.loss_at(raw, measured, d),
        );
        while b - a > 1e-4 {
            if fc < fd {
                (b, d, fd) = (d, c, fc);
                c = b - r * (b - a);
                fc = self.loss_at(raw, measured, c);
            } else {
                (a, c, fc) = (c, d, fd);
                d = a + r * (b - a);
                fd = self.loss_at(raw, measured, d);
            }
        }
        let m = 0.5 * (a + b);
        if self.loss_at(raw, measured, m) <= best_loss {
            m
        } else {
            best
        }
    }

    /// Compares the render `raw` (before the kernel) with `measured` (leading bins
    /// already zeroed).
    pub fn compare(&self, raw: &[f32], measured: &[f32]) -> Comparison {
        let offset_bins = self.best_offset(raw, measured);
        let (loss, adjoint, intensity, fitted) = self.at(raw, measured, offset_bins);
        Comparison {
            loss,
            adjoint,
            intensity,
            offset_bins,
            fitted,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::Background;

    /// Rows of Gaussian pulses at scan-dependent times.
    fn rows(shift: f64, bins: usize, n: usize) -> Vec<f32> {
        rows_spaced(shift, 3.0, bins, n)
    }

    fn rows_spaced(shift: f64, spacing: f64, bins: usize, n: usize) -> Vec<f32> {
        let mut v = Vec::new();
        for p in 0..n {
            let t0 = 20.0 + spacing * p as f64 + shift;
            for t in 0..bins {
                v.push((-(t as f64 - t0).powi(2) / 8.0).exp() as f32);
            }
        }
        v
    }

    fn comparator(max: f64) -> Comparator {
        Comparator {
            bins: 64,
            first_bin: 5,
            intensity: IntensityModel {
                scale: true,
                background: Background::Constant,
            },
            sigma_bins: 1.5,
            offset_max_bins: max,
            irf: Vec::new(),
        }
    }

    #[test]
    fn finds_the_offset_of_a_delayed_measurement() {
        // The measurement is the (blurred) render delayed by 2.3 bins, times 5.
        let raw = rows(0.0, 64, 6);
        let c = comparator(6.0);
        let mut measured = raw.clone();
        JitterKernel::new(1.5, 2.3).apply(&mut measured, 64);
        measured.iter_mut().for_each(|v| *v *= 5.0);
        zero_leading_bins(&mut measured, 64, 5);
        let r = c.compare(&raw, &measured);
        assert!((r.offset_bins - 2.3).abs() < 1e-3, "{}", r.offset_bins);
        assert!(r.loss < 1e-8, "{}", r.loss);
        assert!((r.intensity.scale - 5.0).abs() < 1e-3);
        // Without the offset the same data leave a residual.
        assert!(comparator(0.0).compare(&raw, &measured).loss > 1e-2);
    }

    #[test]
    fn adjoint_is_the_gradient_at_the_found_offset() {
        // Envelope theorem: FD of the full (re-minimised) loss equals the adjoint.
        // Rows spaced differently: no offset explains the measurement exactly.
        let raw = rows(0.7, 64, 4);
        let mut measured = rows_spaced(0.0, 3.6, 64, 4);
        JitterKernel::new(1.5, 1.1).apply(&mut measured, 64);
        zero_leading_bins(&mut measured, 64, 5);
        let c = comparator(4.0);
        let r = c.compare(&raw, &measured);
        assert!(r.loss > 1e-4);
        for i in [25usize, 64 + 26, 3 * 64 + 31] {
            let h = 1e-2f32;
            let (mut p, mut m) = (raw.clone(), raw.clone());
            p[i] += h;
            m[i] -= h;
            let fd =
                (c.compare(&p, &measured).loss - c.compare(&m, &measured).loss) / (2.0 * h as f64);
            let adj = r.adjoint[i] as f64;
            assert!(
                (fd - adj).abs() < 2e-3 * adj.abs().max(1e-3),
                "bin {i}: FD {fd} vs adjoint {adj}"
            );
        }
    }
}
