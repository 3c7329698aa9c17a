//! The transient film: temporal kernels and the splat of a path into time bins
//! (DESIGN §4).
//!
//! A contribution of weight `w` and optical path length `τ` adds
//! `w * ∫_{t_b}^{t_{b+1}} k(τ' - τ) dτ'` to bin `b`, with bin edges
//! `t_b = start_opl + b * bin_width_opl`. The integral is exact for both kernels:
//! - `box`: `k = δ`, the path lands in the one bin holding `τ` (a histogram, as
//!   mitransient's `transient_hdr_film`);
//! - `gaussian(σ)`: `∫ k = Φ((t_{b+1} - τ)/σ) - Φ((t_b - τ)/σ)`, evaluated over the bins
//!   within `GAUSS_CUTOFF` = 6.5 σ of `τ` (the mass beyond is 8e-11).
//!
//! Its derivative with respect to `τ` is `w * (k(t_b - τ) - k(t_{b+1} - τ))`, zero almost
//! everywhere for `box`.

use crate::adjoint::dual::{Dual, Real};
use crate::scene::{FilmSpec, KernelSpec};

#[cfg(test)]
mod adjoint_tests;
mod box_pulse;
mod box_reverse;
mod cells;
pub mod irf;
pub mod jitter;
pub mod normal;
mod pulse;
mod pulse_reverse;
pub mod response;
pub use pulse_reverse::Arith;

pub use box_pulse::{splat_lanes, BoxPulse, LaneRow, PulseLanes, LANES, SPLAT_PAD};
pub use box_reverse::{reverse_lanes, LaneGrad};

/// Half-width of the evaluated Gaussian support, in σ.
pub const GAUSS_CUTOFF: f64 = 6.5;

/// Bin geometry and kernel, in f64 for the splat arithmetic.
#[derive(Clone, Copy, Debug)]
pub struct Film {
    pub bins: usize,
    pub start: f64,
    pub width: f64,
    pub kernel: KernelSpec,
}

impl Film {
    pub fn new(spec: &FilmSpec) -> Self {
        Film {
            bins: spec.temporal_bins as usize,
            start: spec.start_opl as f64,
            width: spec.bin_width_opl as f64,
            kernel: spec.kernel,
        }
    }

    /// OPL of the far edge of the last bin (m).
    pub fn end(&self) -> f64 {
        self.start + self.bins as f64 * self.width
    }

    /// The adjoint of [`Film::splat`] for a contribution at OPL `opl`, given the adjoint
    /// histogram `adj` (`dLoss/dH`, length `bins`): `(Σ_b adj_b K_b(τ), Σ_b adj_b dK_b/dτ)`
    /// with `K_b(τ) = ∫_bin k(t − τ) dt`, so a contribution of weight `w` adds
    /// `first · dw + w · second · dτ` to the loss's derivative. With the box kernel the
    /// second is 0 (DESIGN §4): the time-of-flight part of a vertex gradient is lost.
    #[inline]
    pub fn adjoint(&self, opl: f32, adj: &[f32]) -> (f64, f64) {
        let (mut value, mut slope) = (0.0, 0.0);
        let tau = Dual::<f64, 1>::var(opl as f64, 0);
        self.point_bins(tau, Dual::c(1.0), |b, k| {
            value += adj[b] as f64 * k.v;
            slope += adj[b] as f64 * k.d[0];
        });
        (value, slope)
    }

    /// `Σ_b adj_b K_b(opl)` alone (the first half of [`Film::adjoint`], without the
    /// derivative's work): what the visibility boundary terms weight by.
    pub fn adjoint_value(&self, opl: f32, adj: &[f32]) -> f64 {
        let mut value = 0.0;
        self.point_bins(opl as f64, 1.0, |b, k| value += adj[b] as f64 * k);
        value
    }

    /// Adds weight `w` at OPL `opl` into `hist` (length `bins`).
    #[inline]
    pub fn splat(&self, opl: f32, w: f32, hist: &mut [f64]) {
        self.point_bins(opl as f64, w as f64, |b, v| hist[b] += v);
    }

    /// Weight `w` at OPL `opl` through the kernel: calls `add(b, w K_b(opl))` for every
    /// bin `b` it reaches. Generic, so the same code gives values (`f64`) and derivatives
    /// ([`Dual`]).
    #[inline]
    pub fn point_bins<R: Real>(&self, opl: R, w: R, mut add: impl FnMut(usize, R)) {
        match self.kernel {
            KernelSpec::Box => {
                let x = (opl.v() - self.start) / self.width;
                if x >= 0.0 && x < self.bins as f64 {
                    add(x as usize, w);
                }
            }
            KernelSpec::Gaussian { sigma_opl } => {
                let sigma = sigma_opl as f64;
                let lo = ((opl.v() - GAUSS_CUTOFF * sigma - self.start) / self.width).floor();
                let hi = ((opl.v() + GAUSS_CUTOFF * sigma - self.start) / self.width).floor();
                if hi < 0.0 || lo >= self.bins as f64 {
                    return;
                }
                let lo = lo.max(0.0) as usize;
                let hi = (hi as usize).min(self.bins - 1);
                let inv = 1.0 / sigma;
                let mut prev = edge_cdf(self.start + lo as f64 * self.width, opl, inv);
                for b in lo..=hi {
                    let next = edge_cdf(self.start + (b + 1) as f64 * self.width, opl, inv);
                    add(b, w * (next - prev));
                    prev = next;
                }
            }
        }
    }
}

/// `Φ((edge − τ)/σ)` for a bin edge at OPL `edge` (m), `inv = 1/σ` (film::normal's
/// table for `f64`). Inlined into the bin loop: called there out of line, its dual
/// result came back through memory and stalled the gradient's loop (`mc3`'s adjoint
/// spent ~30 % of its time there; measured).
#[inline(always)]
fn edge_cdf<R: Real>(edge: f64, opl: R, inv: f64) -> R {
    (R::c(edge) - opl).s(inv).normal().0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn film(kernel: KernelSpec) -> Film {
        Film::new(&FilmSpec {
            temporal_bins: 100,
            bin_width_opl: 0.01,
            start_opl: 1.0,
            kernel,
        })
    }

    #[test]
    fn box_lands_in_its_bin() {
        let f = film(KernelSpec::Box);
        let mut h = vec![0.0; 100];
        f.splat(1.2349, 2.0, &mut h);
        f.splat(0.99, 5.0, &mut h); // before the first bin: dropped
        f.splat(2.0, 5.0, &mut h); // at the end edge: dropped
        assert_eq!(h[23], 2.0);
        assert_eq!(h.iter().sum::<f64>(), 2.0);
    }

    #[test]
    fn gaussian_conserves_mass_and_mean() {
        let f = film(KernelSpec::Gaussian { sigma_opl: 0.017 });
        let mut h = vec![0.0; 100];
        f.splat(1.4321, 3.0, &mut h);
        let total: f64 = h.iter().sum();
        assert!((total - 3.0).abs() < 1e-9, "{total}");
        // The mean of a Gaussian integrated over bins is the mean of the bin centres
        // weighted by their mass, up to the bin width's quantisation (zero for a
        // symmetric kernel, by symmetry of the edges' erf differences: check ~1e-6).
        let mean: f64 = h
            .iter()
            .enumerate()
            .map(|(b, v)| v * (1.0 + (b as f64 + 0.5) * 0.01))
            .sum::<f64>()
            / total;
        assert!((mean - 1.4321).abs() < 1e-6, "{mean}");
        // Mass near the film's ends is cut, not wrapped.
        let mut e = vec![0.0; 100];
        f.splat(1.0, 1.0, &mut e);
        assert!((e.iter().sum::<f64>() - 0.5).abs() < 1e-9);
    }
}
