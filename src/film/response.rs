//! A detector's response as a parametric kernel over time bins, for calibrating it from a
//! capture jointly with the geometry (issue 48; `notes/capture-calibration.md` measures it
//! on the Stanford captures: a core of σ ≈ 28 ps and tails of 74, 260 and 450 ps).
//!
//! A SPAD's response is a Gaussian core (its timing jitter, width `σ`, centred at the
//! time zero `t0`) and slow tails (carriers diffusing before they trigger), each tail the
//! core convolved with an exponential of time constant `τ_i` (an exponentially modified
//! Gaussian):
//!
//! `h(t) = w_0 G_σ(t − t0) + Σ_i w_i (G_σ ⊗ E_τi)(t − t0)`,  `w_0 = 1 − Σ_i w_i`,
//!
//! all lengths in optical path (m; 1 ps = 0.3 mm). Its taps are exact integrals over bins
//! of width `Δ` centred on lag `k Δ` (the convention of [`super::jitter::JitterKernel`]),
//! through the closed-form distribution functions
//!
//! core: `Φ(u)`, `u = (t − t0)/σ`;  tail: `F_τ(t) = Φ(u) − exp(σ²/(2τ²) − (t − t0)/τ) Φ(u − σ/τ)`,
//!
//! and their derivatives with respect to every parameter are the same formula run in
//! dual numbers ([`crate::adjoint::dual`]), so the two cannot drift. The kernel is cut
//! where the last tail has decayed to `e^{-TAIL_REACH}`; the mass beyond is reported
//! ([`ResponseKernel::mass`]), not renormalised away.
//!
//! Where it fails: a core narrower than about a third of a bin makes the taps a step
//! function of `t0` (use the box-bin renders' own jitter), and tails longer than the film
//! are cut by it.

use super::jitter::JitterKernel;
use crate::adjoint::dual::{Dual, Real};

/// Most exponential tails the model carries.
pub const MAX_TAILS: usize = 3;
/// Parameters: `σ`, `t0`, then `(w_i, τ_i)` per tail.
pub const PARAMS: usize = 2 + 2 * MAX_TAILS;
/// Optical path light travels in one picosecond (m): the responses' lengths are OPL.
pub const OPL_PER_PS: f64 = 2.997_924_58e-4;
/// Core reach in `σ` on either side.
const CORE_REACH: f64 = 6.0;
/// Tail reach in units of the longest `τ`.
pub const TAIL_REACH: f64 = 12.0;

/// The response's parameters (OPL, m; weights dimensionless).
#[derive(Clone, Debug, PartialEq)]
pub struct Response {
    pub sigma: f64,
    pub t0: f64,
    /// `(w_i, τ_i)`, at most [`MAX_TAILS`].
    pub tails: Vec<(f64, f64)>,
}

/// The response sampled in bins: taps for lags `first..first + taps.len()` (bins), their
/// derivatives with respect to the parameters (in [`PARAMS`] order; unused tails 0).
#[derive(Clone, Debug)]
pub struct ResponseKernel {
    pub first: isize,
    pub taps: Vec<f64>,
    pub d_taps: Vec<[f64; PARAMS]>,
}

impl Response {
    /// The parameters as a vector in [`PARAMS`] order.
    pub fn params(&self) -> [f64; PARAMS] {
        let mut p = [0.0; PARAMS];
        p[0] = self.sigma;
        p[1] = self.t0;
        for (i, &(w, tau)) in self.tails.iter().enumerate() {
            p[2 + 2 * i] = w;
            p[3 + 2 * i] = tau;
        }
        p
    }

    /// Checks the parameters: `σ > 0`, weights in `[0, 1]` summing to at most 1, `τ > 0`.
    pub fn check(&self) -> Result<(), String> {
        let w: f64 = self.tails.iter().map(|t| t.0).sum();
        let bad_tail = self.tails.iter().any(|&(w, tau)| {
            !(w.is_finite() && (0.0..=1.0).contains(&w) && tau.is_finite() && tau > 0.0)
        });
        if !(self.sigma.is_finite() && self.sigma > 0.0 && self.t0.is_finite()) {
            Err(format!(
                "response: σ = {} and t0 = {} must be finite, σ > 0",
                self.sigma, self.t0
            ))
        } else if self.tails.len() > MAX_TAILS || bad_tail || w > 1.0 {
            Err(format!(
                "response: at most {MAX_TAILS} tails of weight in [0, 1] summing to at most 1 and τ > 0, got {:?}",
                self.tails
            ))
        } else {
            Ok(())
        }
    }

    /// The kernel in bins of `bin` (OPL, m), with its derivatives.
    pub fn kernel(&self, bin: f64) -> ResponseKernel {
        let p = self.params();
        let longest = self.tails.iter().map(|t| t.1).fold(0.0, f64::max);
        let first = ((self.t0 - CORE_REACH * self.sigma) / bin).floor() as isize;
        let last =
            ((self.t0 + CORE_REACH * self.sigma + TAIL_REACH * longest) / bin).ceil() as isize;
        let vars: [Dual<f64, PARAMS>; PARAMS] = std::array::from_fn(|i| Dual::var(p[i], i));
        let cdf = |t: f64| cdf(&vars, self.tails.len(), Dual::c(t));
        let mut below = cdf((first as f64 - 0.5) * bin);
        let (mut taps, mut d_taps) = (Vec::new(), Vec::new());
        for k in first..=last {
            let above = cdf((k as f64 + 0.5) * bin);
            let tap = above - below;
            taps.push(tap.v);
            d_taps.push(tap.d);
            below = above;
        }
        ResponseKernel {
            first,
            taps,
            d_taps,
        }
    }
}

impl ResponseKernel {
    /// The share of the response inside the kernel (1 less what the cut leaves out).
    pub fn mass(&self) -> f64 {
        self.taps.iter().sum()
    }

    /// Calls `f(t, s, j)` for every output bin `t`, input bin `s = t − lag_j` and tap `j`
    /// of a row of `bins`.
    fn for_each(&self, bins: usize, mut f: impl FnMut(usize, usize, usize)) {
        for t in 0..bins {
            for j in 0..self.taps.len() {
                let s = t as isize - (self.first + j as isize);
                if (0..bins as isize).contains(&s) {
                    f(t, s as usize, j);
                }
            }
        }
    }

    /// The blur as the fit's convolution ([`JitterKernel`]: `H'[t] = Σ_j taps[j] H[t −
    /// lag_j]` row by row, light beyond a row's ends lost as a detector loses it, and its
    /// transpose for the adjoint to the render).
    pub fn blur(&self) -> JitterKernel {
        JitterKernel {
            first: self.first,
            taps: self.taps.clone(),
            d_taps: vec![0.0; self.taps.len()],
        }
    }

    /// `dL/dθ` for every response parameter, given the unblurred `render` and the adjoint
    /// of the blurred one: `Σ_t dL/dH'[t] Σ_j ∂taps[j]/∂θ H[t − lag_j]`.
    pub fn param_gradient(&self, render: &[f32], adjoint: &[f32], bins: usize) -> [f64; PARAMS] {
        let mut g = [0.0f64; PARAMS];
        for (h, a) in render.chunks_exact(bins).zip(adjoint.chunks_exact(bins)) {
            self.for_each(bins, |t, s, j| {
                let w = f64::from(a[t]) * f64::from(h[s]);
                g.iter_mut()
                    .zip(&self.d_taps[j])
                    .for_each(|(g, d)| *g += w * d);
            });
        }
        g
    }
}

/// The response's distribution function at `t`: `w_0 Φ(u) + Σ_i w_i F_τi(t)`.
fn cdf<R: Real>(p: &[R; PARAMS], tails: usize, t: R) -> R {
    let (sigma, t0) = (p[0], p[1]);
    let u = (t - t0) / sigma;
    let (core, _) = u.normal();
    let mut w_tails = R::c(0.0);
    let mut sum = R::c(0.0);
    for i in 0..tails {
        let (w, tau) = (p[2 + 2 * i], p[3 + 2 * i]);
        let r = sigma / tau;
        // exp(σ²/(2τ²) − (t − t0)/τ) Φ(u − σ/τ), written as one exponent to stay finite
        // far before t0, where Φ underflows and the exponential overflows.
        let (shifted, _) = (u - r).normal();
        let tail = if shifted.v() > 0.0 {
            core - ((r * r).s(0.5) - (t - t0) / tau).exp() * shifted
        } else {
            core
        };
        sum = sum + w * tail;
        w_tails = w_tails + w;
    }
    (R::c(1.0) - w_tails) * core + sum
}

#[cfg(test)]
mod tests {
    use super::*;

    const BIN: f64 = 0.0012; // 4 ps

    fn spad() -> Response {
        // The Stanford charts' response (notes/capture-calibration.md), in OPL.
        Response {
            sigma: 0.0084,
            t0: 0.0006,
            tails: vec![(0.38, 0.0222), (0.34, 0.0786), (0.13, 0.135)],
        }
    }

    #[test]
    fn taps_hold_the_whole_response_and_its_mean() {
        let r = spad();
        r.check().unwrap();
        let k = r.kernel(BIN);
        assert!((k.mass() - 1.0).abs() < 1e-5, "mass {}", k.mass());
        // An exponentially modified Gaussian's mean is t0 + τ.
        let mean: f64 = (k.taps.iter().enumerate())
            .map(|(j, t)| t * (k.first + j as isize) as f64 * BIN)
            .sum::<f64>()
            / k.mass();
        let want = r.t0 + r.tails.iter().map(|(w, tau)| w * tau).sum::<f64>();
        assert!(
            (mean - want).abs() < 0.02 * want,
            "mean {mean} against {want}"
        );
        assert!(k.taps.iter().all(|&t| t >= -1e-15), "negative tap");
    }

    #[test]
    fn derivatives_match_central_differences() {
        let r = spad();
        let k = r.kernel(BIN);
        let p = r.params();
        for (j, &value) in p.iter().enumerate() {
            let h = 1e-6 * value.abs().max(1e-3);
            let moved = |d: f64| {
                let mut q = p;
                q[j] += d;
                let tails = (0..r.tails.len())
                    .map(|i| (q[2 + 2 * i], q[3 + 2 * i]))
                    .collect();
                Response {
                    sigma: q[0],
                    t0: q[1],
                    tails,
                }
                .kernel(BIN)
            };
            let (plus, minus) = (moved(h), moved(-h));
            assert_eq!(
                (plus.first, plus.taps.len()),
                (k.first, k.taps.len()),
                "param {j}: support moved"
            );
            let scale = k.d_taps.iter().map(|d| d[j].abs()).fold(0.0, f64::max);
            for (i, d) in k.d_taps.iter().enumerate() {
                let fd = (plus.taps[i] - minus.taps[i]) / (2.0 * h);
                assert!(
                    (d[j] - fd).abs() <= 1e-5 * scale,
                    "param {j} tap {i}: {} against {fd}",
                    d[j]
                );
            }
        }
    }

    /// Two rows of a pulse train, and a fixed adjoint (the loss is linear in H').
    fn rows(bins: usize) -> (Vec<f32>, Vec<f32>) {
        let h: Vec<f32> = (0..2 * bins)
            .map(|i| {
                if i % bins == 20 || i % bins == 61 {
                    1.0
                } else {
                    0.01 * (i % 7) as f32
                }
            })
            .collect();
        let adj: Vec<f32> = (0..2 * bins)
            .map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.1)
            .collect();
        (h, adj)
    }

    #[test]
    fn the_blur_its_transpose_and_its_parameter_gradient_agree() {
        let bins = 400;
        let r = spad();
        let k = r.kernel(BIN);
        let (h, adj) = rows(bins);
        let dot = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(x, y)| f64::from(*x) * f64::from(*y))
                .sum::<f64>()
        };
        // The blur and its transpose: <A h, y> = <h, Aᵀ y>.
        let (mut ah, mut aty) = (h.clone(), adj.clone());
        k.blur().apply(&mut ah, bins);
        k.blur().apply_transpose(&mut aty, bins);
        let (lhs, rhs) = (dot(&ah, &adj), dot(&h, &aty));
        assert!(
            (lhs - rhs).abs() < 1e-5 * lhs.abs().max(1.0),
            "{lhs} against {rhs}"
        );
        // dL/dθ against central differences of L(θ) = <A(θ) h, adj>.
        let g = k.param_gradient(&h, &adj, bins);
        let p = r.params();
        for j in 0..2 + 2 * r.tails.len() {
            let step = 1e-5 * p[j].abs().max(1e-3);
            let loss = |d: f64| {
                let mut q = p;
                q[j] += d;
                let tails = (0..r.tails.len())
                    .map(|i| (q[2 + 2 * i], q[3 + 2 * i]))
                    .collect();
                let kk = Response {
                    sigma: q[0],
                    t0: q[1],
                    tails,
                }
                .kernel(BIN);
                // The same support, so the difference sees the taps move, not the cut.
                assert_eq!((kk.first, kk.taps.len()), (k.first, k.taps.len()));
                let mut out = vec![0.0f64; h.len()];
                for (row, o) in h.chunks_exact(bins).zip(out.chunks_exact_mut(bins)) {
                    kk.for_each(bins, |t, s, i| o[t] += kk.taps[i] * f64::from(row[s]));
                }
                out.iter()
                    .zip(&adj)
                    .map(|(x, a)| x * f64::from(*a))
                    .sum::<f64>()
            };
            let fd = (loss(step) - loss(-step)) / (2.0 * step);
            assert!(
                (g[j] - fd).abs()
                    <= 1e-4
                        * fd.abs()
                            .max(1e-3 * g.iter().fold(0.0f64, |m, v| m.max(v.abs()))),
                "param {j}: {} against {fd}",
                g[j]
            );
        }
    }

    #[test]
    fn a_core_alone_is_the_gaussian_and_bad_parameters_are_refused() {
        let r = Response {
            sigma: 2.0 * BIN,
            t0: 0.0,
            tails: vec![],
        };
        let k = r.kernel(BIN);
        let peak = k.taps.iter().cloned().fold(0.0, f64::max);
        // The centre tap of a Gaussian of 2 bins: Φ(0.25) − Φ(−0.25).
        assert!((peak - 0.197_413).abs() < 1e-5, "{peak}");
        assert!(Response {
            sigma: 0.0,
            ..r.clone()
        }
        .check()
        .is_err());
        assert!(Response {
            tails: vec![(0.7, 0.01), (0.5, 0.02)],
            ..r.clone()
        }
        .check()
        .is_err());
        assert!(Response {
            tails: vec![(0.2, -0.01)],
            ..r
        }
        .check()
        .is_err());
    }
}
