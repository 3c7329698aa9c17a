//! Splat of a *triangle pulse*: the time profile of a triangle on which both the OPL `τ`
//! and the radiometric weight `w` are linear (the per-triangle three-bounce model,
//! DESIGN §3 rung 1, after Plack et al. 2023, with a linear instead of a constant weight).
//!
//! Sort the corners by OPL, `t0 ≤ t1 ≤ t2`, with weights `w0, w1, w2` and area `A`. The
//! weighted area with `τ ≤ t` is, exactly,
//!
//! - on `[t0, t1]`: the corner triangle at `v0`, `W(t) = A a b (3 w0 + a (w1 − w0) + b (w2 − w0)) / 3`
//!   with `a = (t − t0)/(t1 − t0)`, `b = (t − t0)/(t2 − t0)`;
//! - on `[t1, t2]`: all but the corner triangle at `v2`,
//!   `W(t) = W_tot − A c d (3 w2 + c (w1 − w2) + d (w0 − w2)) / 3` with
//!   `c = (t2 − t)/(t2 − t1)`, `d = (t2 − t)/(t2 − t0)`, `W_tot = A (w0 + w1 + w2) / 3`;
//!
//! a cubic in `t` on each piece. A box bin receives `W(t_hi) − W(t_lo)`. Through a
//! Gaussian kernel of deviation `σ` the mass below an edge `x` is
//! `H(x) = ∫ Φ((x − t)/σ) dW(t) = W_tot Φ((x − t2)/σ) + ∫ W(t) φ((x − t)/σ) dt/σ`
//! (by parts), and with `t = x − σu` the integral is a sum of Gaussian moments
//! `∫ u^k φ(u) du` (antiderivatives `Φ`, `−φ`, `Φ − uφ`, `−(u² + 2)φ`) over each piece.

use super::{Film, GAUSS_CUTOFF};
use crate::adjoint::dual::Real;
use crate::scene::KernelSpec;

/// Pulses narrower than this fraction of a bin (or of σ) are splatted as a point at
/// their weighted mean: the shape is then below f64's resolution of the CDF.
const NARROW: f64 = 1e-7;

/// Through a Gaussian kernel, pieces narrower than this fraction of σ are integrated
/// by quadrature rather than in closed form.
const NARROW_FOR_GAUSS: f64 = 1e-2;

/// A triangle's corners sorted by OPL, with the constants of its two cubic pieces.
/// Generic over [`Real`], so the same code yields bin values (`f64`) and their
/// derivatives (the `tri3` adjoint).
#[derive(Clone, Copy, Debug)]
pub(super) struct Pulse<R> {
    pub(super) t: [R; 3],
    pub(super) w: [R; 3],
    pub(super) total: R,
    /// `[t0, t1]`: `W = ka z² (3 w0 + ga z)`, `z = t − t0`.
    pub(super) ka: R,
    pub(super) ga: R,
    /// `[t1, t2]`: `W = total − kb y² (3 w2 + gb y)`, `y = t2 − t`.
    pub(super) kb: R,
    pub(super) gb: R,
}

impl<R: Real> Pulse<R> {
    /// `narrow`: pieces `[t0, t1]`, `[t1, t2]` narrower than this (m) are dropped (their
    /// mass goes to the other piece): a near-tie of two corners' OPLs would otherwise put
    /// the rounding noise of their difference in a denominator.
    #[inline]
    pub(super) fn new(t: [R; 3], w: [R; 3], area: R, narrow: f64) -> Self {
        // Sorting network on (t, w) pairs.
        let (mut t, mut w) = (t, w);
        let mut swap = |i: usize, j: usize| {
            if t[j].v() < t[i].v() {
                t.swap(i, j);
                w.swap(i, j);
            }
        };
        swap(0, 1);
        swap(1, 2);
        swap(0, 1);
        let ([t0, t1, t2], [w0, w1, w2]) = (t, w);
        // Three reciprocals serve all four constants (a pulse narrower than NARROW
        // never gets here with t2 == t0).
        let one = R::c(1.0);
        let inv_span = one / (t2 - t0);
        let third_area = area.s(1.0 / 3.0);
        let zero = R::c(0.0);
        let (ka, ga) = if t1.v() - t0.v() > narrow {
            let inv = one / (t1 - t0);
            (
                third_area * inv * inv_span,
                (w1 - w0) * inv + (w2 - w0) * inv_span,
            )
        } else {
            (zero, zero)
        };
        let (kb, gb) = if t2.v() - t1.v() > narrow {
            let inv = one / (t2 - t1);
            (
                third_area * inv * inv_span,
                (w1 - w2) * inv + (w0 - w2) * inv_span,
            )
        } else {
            (zero, zero)
        };
        Pulse {
            t,
            w,
            total: third_area * (w0 + w1 + w2),
            ka,
            ga,
            kb,
            gb,
        }
    }

    /// Weighted area with OPL below `x`, for `t0 ≤ x ≤ t2` (box kernel).
    #[inline]
    fn cdf_inside(&self, x: R) -> R {
        let ([t0, t1, t2], [w0, _, w2]) = (self.t, self.w);
        if x.v() <= t1.v() {
            let z = x - t0;
            self.ka * z * z * (w0.s(3.0) + self.ga * z)
        } else {
            let y = t2 - x;
            self.total - self.kb * y * y * (w2.s(3.0) + self.gb * y)
        }
    }

    /// `H(x) = ∫ Φ((x − t)/σ) dW(t)` (Gaussian kernel). `Φ` and `φ` are needed at
    /// `u_k = (x − t_k)/σ` only (and at quadrature nodes for narrow pieces): evaluated
    /// once per corner.
    fn gauss_cdf(&self, sigma: f64, x: f64) -> R {
        let ([t0, t1, t2], [w0, _, w2]) = (self.t, self.w);
        let (xr, inv_s, s) = (R::c(x), 1.0 / sigma, sigma);
        let at = |t: R| {
            let u = (xr - t).s(inv_s);
            let (c, p) = u.normal();
            (u, c, p)
        };
        let (n0, n1, n2) = (at(t0), at(t1), at(t2));
        // The by-parts boundary term sits at the top of the last piece present: with an
        // empty [t1, t2] (an exact tie of the two latest corners) that is t1, which is
        // where the limit of a vanishing piece puts its time derivative.
        let top = if self.kb.v() != 0.0 { n2 } else { n1 };
        let mut h = self.total * top.1;
        // A piece much narrower than σ: its closed form below subtracts terms
        // ~ (span/δ)² larger than the result (~ (span/δ)³ in the derivative), so it is
        // integrated by 3-point Gauss–Legendre instead: W is cubic and φ varies by
        // (δ/σ)² across it, so the rule's error is ~ (δ/σ)⁶.
        let narrow = NARROW_FOR_GAUSS * sigma;
        // Piece [t0, t1]: W = ka (3 w0 z² + ga z³), z = t − t0 = d − σu.
        if self.ka.v() != 0.0 {
            let (k, g, d) = (self.ka, self.ga, xr - t0);
            if t1.v() - t0.v() < narrow {
                let (nodes, half) = gauss_legendre_nodes(t0, t1);
                for (t, weight) in nodes.into_iter().zip(GL_WEIGHTS) {
                    let z = t - t0;
                    let dens = (xr - t).s(inv_s).normal().1;
                    h = h + (half * k * z * z * (w0.s(3.0) + g * z) * dens).s(weight * inv_s);
                }
            } else {
                let e = [
                    k * (w0.s(3.0) * d * d + g * d * d * d),
                    k * (w0.s(-6.0) * d.s(s) - g.s(3.0) * d * d.s(s)),
                    k * (w0.s(3.0 * s * s) + g.s(3.0 * s * s) * d),
                    -(k * g).s(s * s * s),
                ];
                h = h + moments(e, n1, n0);
            }
        }
        // Piece [t1, t2]: W = total − kb (3 w2 y² + gb y³), y = t2 − t = e + σu.
        if self.kb.v() != 0.0 {
            let (k, g, e_) = (self.kb, self.gb, t2 - xr);
            if t2.v() - t1.v() < narrow {
                let (nodes, half) = gauss_legendre_nodes(t1, t2);
                for (t, weight) in nodes.into_iter().zip(GL_WEIGHTS) {
                    let y = t2 - t;
                    let dens = (xr - t).s(inv_s).normal().1;
                    let w_t = self.total - k * y * y * (w2.s(3.0) + g * y);
                    h = h + (half * w_t * dens).s(weight * inv_s);
                }
            } else {
                let e = [
                    self.total - k * (w2.s(3.0) * e_ * e_ + g * e_ * e_ * e_),
                    -(k * (w2.s(6.0) * e_.s(s) + g.s(3.0) * e_ * e_.s(s))),
                    -(k * (w2.s(3.0 * s * s) + g.s(3.0 * s * s) * e_)),
                    -(k * g).s(s * s * s),
                ];
                h = h + moments(e, n2, n1);
            }
        }
        h
    }
}

/// 3-point Gauss–Legendre weights on [−1, 1].
const GL_WEIGHTS: [f64; 3] = [5.0 / 9.0, 8.0 / 9.0, 5.0 / 9.0];

/// The 3-point Gauss–Legendre nodes on `[a, b]` and the half width: `∫_a^b f ≈
/// half Σ GL_WEIGHTS_i f(node_i)`.
fn gauss_legendre_nodes<R: Real>(a: R, b: R) -> ([R; 3], R) {
    const X: f64 = 0.774_596_669_241_483_4; // √(3/5)
    let (mid, half) = ((a + b).s(0.5), (b - a).s(0.5));
    ([mid - half.s(X), mid, mid + half.s(X)], half)
}

/// `∫_{lo}^{hi} Σ_k e_k u^k φ(u) du`, each end given as `(u, Φ(u), φ(u))`.
fn moments<R: Real>(e: [R; 4], lo: (R, R, R), hi: (R, R, R)) -> R {
    let anti = |(u, c, p): (R, R, R)| {
        e[0] * c - e[1] * p + e[2] * (c - u * p) - e[3] * (u * u + R::c(2.0)) * p
    };
    anti(hi) - anti(lo)
}

/// What the splat of a triangle pulse needs of the film's kernel.
pub(super) struct PulseKernel {
    /// σ (m); 0 for the box kernel.
    pub(super) sigma: f64,
    /// How far past its corners the pulse reaches (m): `GAUSS_CUTOFF σ`, or 0.
    pub(super) margin: f64,
    /// Pulses narrower than this (m) are splatted as a point at their weighted mean.
    pub(super) point: f64,
    /// Pieces narrower than this (m) are dropped ([`Pulse::new`]). Box: `NARROW` bins
    /// (their mass moves by less). Gaussian: only empty pieces go; narrow ones take the
    /// quadrature branch of `gauss_cdf`. Dropping them there would leave the
    /// t2-derivative of its `W Φ((x − t2)/σ)` term uncancelled, splitting a tie's time
    /// derivative wrongly between its corners (found by the independent Dr.Jit
    /// reference, python/tests/test_vs_drjit.py).
    pub(super) narrow: f64,
}

/// The bins a pulse reaches: `first_bin ..= last_bin` unclipped, `lo ..= hi` within the
/// film.
pub(super) struct PulseBins {
    pub(super) first_bin: i64,
    pub(super) last_bin: i64,
    pub(super) lo: usize,
    pub(super) hi: usize,
}

impl Film {
    pub(super) fn pulse_kernel(&self) -> PulseKernel {
        let (sigma, margin, scale) = match self.kernel {
            KernelSpec::Box => (0.0, 0.0, self.width),
            KernelSpec::Gaussian { sigma_opl } => {
                let s = sigma_opl as f64;
                (s, GAUSS_CUTOFF * s, s.min(self.width))
            }
        };
        PulseKernel {
            sigma,
            margin,
            point: NARROW * scale,
            narrow: if sigma > 0.0 { 0.0 } else { NARROW * scale },
        }
    }

    /// The bins that a pulse with corners between `t0` and `t2` (m) reaches with
    /// `margin`; `None` if it misses the film.
    pub(super) fn pulse_bins(&self, t0: f64, t2: f64, margin: f64) -> Option<PulseBins> {
        let inv_width = 1.0 / self.width;
        let first = ((t0 - margin - self.start) * inv_width).floor();
        let last = ((t2 + margin - self.start) * inv_width).floor();
        if last < 0.0 || first >= self.bins as f64 {
            return None;
        }
        let (first_bin, last_bin) = (first as i64, last as i64);
        Some(PulseBins {
            first_bin,
            last_bin,
            lo: first_bin.max(0) as usize,
            hi: (last_bin as usize).min(self.bins - 1),
        })
    }

    /// Adds the triangle pulse with corner OPLs `t`, corner weights `w` (linear over the
    /// triangle) and area `area` into `hist`: `area · mean(w)` in all, over the bins.
    #[inline]
    pub fn splat_triangle(&self, t: [f64; 3], w: [f64; 3], area: f64, hist: &mut [f64]) {
        self.triangle_bins(t, w, area, |b, v| hist[b] += v);
    }

    /// The triangle pulse through the kernel: calls `add(b, content of bin b)` for every
    /// bin it reaches. Generic, so the same code gives values and derivatives.
    #[inline]
    pub fn triangle_bins<R: Real>(
        &self,
        t: [R; 3],
        w: [R; 3],
        area: R,
        mut add: impl FnMut(usize, R),
    ) {
        let k = self.pulse_kernel();
        let p = Pulse::new(t, w, area, k.narrow);
        let [t0, t1, t2] = p.t;
        if t2.v() - t0.v() <= k.point {
            let wsum = p.w[0] + p.w[1] + p.w[2];
            let mean = if wsum.v() != 0.0 {
                (t0 * p.w[0] + t1 * p.w[1] + t2 * p.w[2]) / wsum
            } else {
                (t0 + t2).s(0.5)
            };
            self.point_bins(mean, p.total, add);
            return;
        }
        let Some(PulseBins {
            first_bin,
            last_bin,
            lo,
            hi,
        }) = self.pulse_bins(t0.v(), t2.v(), k.margin)
        else {
            return;
        };
        let sigma = k.sigma;
        let edge = |b: usize| self.start + b as f64 * self.width;
        if sigma == 0.0 {
            // Box: W is 0 at or before the first edge, `total` from the last bin's far edge.
            if first_bin == last_bin {
                add(lo, p.total);
                return;
            }
            let mut prev = if first_bin < 0 {
                p.cdf_inside(R::c(edge(0)).max(t0))
            } else {
                R::c(0.0)
            };
            // Bins before the pulse's last one end inside it; the last one takes the rest.
            let inner_end = (last_bin as usize).min(hi + 1);
            for b in lo..inner_end.max(lo) {
                let next = p.cdf_inside(R::c(edge(b + 1)).min(t2));
                add(b, next - prev);
                prev = next;
            }
            if last_bin as usize <= hi {
                add(last_bin as usize, p.total - prev);
            }
        } else {
            let mut prev = p.gauss_cdf(sigma, edge(lo));
            for b in lo..=hi {
                let next = p.gauss_cdf(sigma, edge(b + 1));
                add(b, next - prev);
                prev = next;
            }
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::scene::FilmSpec;

    /// A film of 200 bins of 1 cm from 1 m (the pulse tests').
    pub(crate) fn film(kernel: KernelSpec) -> Film {
        Film::new(&FilmSpec {
            temporal_bins: 200,
            bin_width_opl: 0.01,
            start_opl: 1.0,
            kernel,
        })
    }

    /// Reference: a fine grid of points over the triangle (barycentric midpoints of a
    /// 600 x 600 subdivision), each with its interpolated OPL and weight, splatted as points.
    fn brute(f: &Film, t: [f64; 3], w: [f64; 3], area: f64) -> Vec<f64> {
        let n = 600;
        let mut h = vec![0.0; f.bins];
        let cell = area / (n * n) as f64;
        let mut add = |b1: f64, b2: f64| {
            let b0 = 1.0 - b1 - b2;
            let tau = b0 * t[0] + b1 * t[1] + b2 * t[2];
            let wt = b0 * w[0] + b1 * w[1] + b2 * w[2];
            f.splat(tau as f32, (wt * cell) as f32, &mut h);
        };
        for j in 0..n {
            for i in 0..(n - j) {
                let (x, y) = (i as f64, j as f64);
                let nf = n as f64;
                add((x + 1.0 / 3.0) / nf, (y + 1.0 / 3.0) / nf);
                if i + j + 1 < n {
                    add((x + 2.0 / 3.0) / nf, (y + 2.0 / 3.0) / nf);
                }
            }
        }
        h
    }

    #[test]
    fn pulse_matches_a_fine_point_cloud() {
        let cases = [
            ([1.2031, 1.2417, 1.2244], [1.0, 1.0, 1.0]),
            ([1.2031, 1.2417, 1.2244], [0.2, 1.7, 0.9]),
            ([1.5, 1.5, 1.537], [0.5, 1.0, 2.0]),      // t0 = t1
            ([1.30, 1.3413, 1.3413], [1.0, 0.1, 0.6]), // t1 = t2
            ([1.0004, 1.0202, 0.998], [1.0, 2.0, 0.0]), // cut at the film's start
        ];
        for kernel in [KernelSpec::Box, KernelSpec::Gaussian { sigma_opl: 0.013 }] {
            let f = film(kernel);
            for (t, w) in cases {
                let mut exact = vec![0.0; f.bins];
                f.splat_triangle(t, w, 0.3, &mut exact);
                let reference = brute(&f, t, w, 0.3);
                let scale = exact.iter().cloned().fold(0.0, f64::max);
                for (b, (e, r)) in exact.iter().zip(&reference).enumerate() {
                    assert!(
                        (e - r).abs() < 3e-3 * scale,
                        "{kernel:?} {t:?} {w:?} bin {b}: {e} vs {r}"
                    );
                }
            }
        }
    }

    #[test]
    fn pulse_conserves_its_total() {
        for kernel in [KernelSpec::Box, KernelSpec::Gaussian { sigma_opl: 0.004 }] {
            let f = film(kernel);
            let mut h = vec![0.0; f.bins];
            f.splat_triangle([1.5, 1.61, 1.52], [0.3, 0.9, 1.2], 2.0, &mut h);
            let want = 2.0 * (0.3 + 0.9 + 1.2) / 3.0;
            assert!(
                (h.iter().sum::<f64>() - want).abs() < 1e-9 * want,
                "{kernel:?}"
            );
        }
    }

    /// Bin values of a pulse by composite 3-point Gauss–Legendre over its density
    /// `dW/dt` with `libm`'s `erfc`: an independent reference for the closed form.
    fn quadrature_bins(f: &Film, t: [f64; 3], w: [f64; 3], area: f64, sigma: f64) -> Vec<f64> {
        let p = Pulse::<f64>::new(t, w, area, 0.0);
        let ([t0, t1, t2], [w0, _, w2]) = (p.t, p.w);
        let density = |x: f64| {
            if x <= t1 {
                let z = x - t0;
                p.ka * (6.0 * w0 * z + 3.0 * p.ga * z * z)
            } else {
                let y = t2 - x;
                p.kb * (6.0 * w2 * y + 3.0 * p.gb * y * y)
            }
        };
        let cdf = |u: f64| 0.5 * libm::erfc(-u * std::f64::consts::FRAC_1_SQRT_2);
        let mut h = vec![0.0; f.bins];
        for (a, b) in [(t0, t1), (t1, t2)] {
            let panels = 256;
            for k in 0..panels {
                let lo = a + (b - a) * k as f64 / panels as f64;
                let hi = a + (b - a) * (k + 1) as f64 / panels as f64;
                let (nodes, half) = gauss_legendre_nodes(lo, hi);
                for (x, g) in nodes.into_iter().zip(GL_WEIGHTS) {
                    let m = half * g * density(x);
                    for (bin, v) in h.iter_mut().enumerate() {
                        let e0 = f.start + bin as f64 * f.width;
                        *v += m * (cdf((e0 + f.width - x) / sigma) - cdf((e0 - x) / sigma));
                    }
                }
            }
        }
        h
    }

    #[test]
    fn gaussian_pulse_with_a_narrow_piece_matches_quadrature_on_both_sides_of_the_switch() {
        // The closed form subtracts terms ~ (σ/δ)² larger than a piece of width δ: with
        // Φ and φ from film::normal's table (absolute error ~1e-13) it must not be used
        // below NARROW_FOR_GAUSS · σ. Widths on both sides of the switch.
        let sigma = 0.013;
        let f = film(KernelSpec::Gaussian {
            sigma_opl: sigma as f32,
        });
        let mut worst = 0.0f64;
        for frac in [0.011, 0.03, 0.049, 0.06, 0.2, 1.0] {
            // Both pieces δ wide: each holds about half the pulse.
            let t = [1.3, 1.3 + frac * sigma, 1.3 + 1.9 * frac * sigma];
            let w = [1.0, 0.7, 1.3];
            let mut got = vec![0.0; f.bins];
            f.splat_triangle(t, w, 0.3, &mut got);
            let want = quadrature_bins(&f, t, w, 0.3, sigma);
            let total: f64 = want.iter().sum();
            let err = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
                / total;
            println!("narrow piece {frac} σ: max bin error {err:.1e} of the total");
            worst = worst.max(err);
        }
        assert!(worst < 2e-8, "worst {worst:e}");
    }
}
