//! The Poisson deviance of a render against photon counts (issue 48): the likelihood a
//! SPAD's histogram has, where L2 weighs every bin alike and lets the few bright bins
//! outvote the many dim ones.
//!
//! With `μ = s H + b` (scale `s ≥ 0`, a constant background `b ≥ b_min > 0`, so that every
//! bin can hold its counts), over the fitted bins `U`,
//!
//! `D = (2 / |U|) Σ_U (μ − M + M ln(M / μ))`,  `M ln(M/μ) = 0` where `M = 0`,
//!
//! minimised over `(s, b)` by projected Newton steps (D is convex in both) with a
//! backtracking line search. A perfect model of Poisson counts has `D ≈ 1` per bin (0.77 to
//! 1.10 on the Stanford captures' counts, `notes/capture-calibration.md`): the photon
//! floor in this measure. By the envelope theorem, at the minimum,
//! `dD/dH = (2 / |U|) s (1 − M / μ)` on `U`.

/// The fitted intensity and the deviance per fitted bin.
#[derive(Clone, Debug, PartialEq)]
pub struct PoissonFit {
    pub scale: f64,
    pub background: f64,
    pub deviance: f64,
}

/// Sums of the fitted bins for `(s, b)`: the deviance, its gradient and Hessian.
struct Terms {
    d: f64,
    grad: [f64; 2],
    hess: [f64; 3],
}

fn terms(render: &[f32], measured: &[f32], bins: usize, first: usize, s: f64, b: f64) -> Terms {
    let (mut d, mut gs, mut gb, mut hss, mut hsb, mut hbb) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (h, m) in render.chunks_exact(bins).zip(measured.chunks_exact(bins)) {
        for t in first..bins {
            let (h, m) = (f64::from(h[t]), f64::from(m[t]));
            let mu = s * h + b;
            d += mu - m + if m > 0.0 { m * (m / mu).ln() } else { 0.0 };
            let r = 1.0 - m / mu;
            gs += h * r;
            gb += r;
            let w = m / (mu * mu);
            hss += h * h * w;
            hsb += h * w;
            hbb += w;
        }
    }
    Terms {
        d: 2.0 * d,
        grad: [2.0 * gs, 2.0 * gb],
        hess: [2.0 * hss, 2.0 * hsb, 2.0 * hbb],
    }
}

/// The least-deviance `(s, b)` of `render` against the counts `measured` (rows of `bins`,
/// bins `first..` fitted), and the deviance per bin.
pub fn fit(render: &[f32], measured: &[f32], bins: usize, first: usize) -> PoissonFit {
    let n = (render.len() / bins.max(1)) * bins.saturating_sub(first);
    let sum = |v: &[f32]| -> f64 {
        v.chunks_exact(bins)
            .map(|r| r[first..].iter().map(|&x| f64::from(x)).sum::<f64>())
            .sum()
    };
    let (sh, sm) = (sum(render), sum(measured));
    let b_min = 1e-9 * (sm / n.max(1) as f64).max(1e-30);
    // Start: the scale that matches the totals with half the counts as background.
    let (mut s, mut b) = if sh > 0.0 {
        (0.5 * sm / sh, (0.5 * sm / n.max(1) as f64).max(b_min))
    } else {
        (0.0, (sm / n.max(1) as f64).max(b_min))
    };
    let mut cur = terms(render, measured, bins, first, s, b);
    for _ in 0..100 {
        let [hss, hsb, hbb] = cur.hess;
        let [gs, gb] = cur.grad;
        // Newton's step on the free variables (a variable at its bound with a gradient
        // pushing it out stays there).
        let s_free = s > 0.0 || gs < 0.0;
        let b_free = b > b_min || gb < 0.0;
        let (ds, db) = match (s_free, b_free) {
            (true, true) => {
                let det = hss * hbb - hsb * hsb;
                if det <= 0.0 {
                    (-gs / hss.max(1e-300), -gb / hbb.max(1e-300))
                } else {
                    (-(hbb * gs - hsb * gb) / det, -(hss * gb - hsb * gs) / det)
                }
            }
            (true, false) => (-gs / hss.max(1e-300), 0.0),
            (false, true) => (0.0, -gb / hbb.max(1e-300)),
            (false, false) => break,
        };
        let mut step = 1.0;
        let mut moved = false;
        while step > 1e-12 {
            let (ns, nb) = ((s + step * ds).max(0.0), (b + step * db).max(b_min));
            let next = terms(render, measured, bins, first, ns, nb);
            if next.d <= cur.d {
                let done = (ns - s).abs() <= 1e-13 * s.max(1e-300) && (nb - b).abs() <= 1e-13 * b;
                (s, b, cur, moved) = (ns, nb, next, !done);
                break;
            }
            step *= 0.5;
        }
        if !moved {
            break;
        }
    }
    PoissonFit {
        scale: s,
        background: b,
        deviance: cur.d / n.max(1) as f64,
    }
}

/// `dD/dH` at the fit (0 before `first`).
pub fn adjoint(
    fit: &PoissonFit,
    render: &[f32],
    measured: &[f32],
    bins: usize,
    first: usize,
) -> Vec<f32> {
    let n = (render.len() / bins.max(1)) * bins.saturating_sub(first);
    let k = 2.0 * fit.scale / n.max(1) as f64;
    let mut out = vec![0.0f32; render.len()];
    for ((h, m), o) in render
        .chunks_exact(bins)
        .zip(measured.chunks_exact(bins))
        .zip(out.chunks_exact_mut(bins))
    {
        for t in first..bins {
            let mu = fit.scale * f64::from(h[t]) + fit.background;
            o[t] = (k * (1.0 - f64::from(m[t]) / mu)) as f32;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const BINS: usize = 64;

    fn render() -> Vec<f32> {
        (0..20 * BINS)
            .map(|i| {
                let (p, t) = (i / BINS, i % BINS);
                (-((t as f64 - 20.0 - (p % 5) as f64) / 3.0).powi(2)).exp() as f32 * 4.0
            })
            .collect()
    }

    /// Poisson counts of mean `mu` (Knuth's method on a fixed linear congruential stream).
    fn counts(mu: &[f64]) -> Vec<f32> {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        mu.iter()
            .map(|&m| {
                let (limit, mut k, mut p) = ((-m).exp(), 0u32, 1.0);
                loop {
                    p *= uniform();
                    if p <= limit {
                        break k as f32;
                    }
                    k += 1;
                }
            })
            .collect()
    }

    #[test]
    fn a_noise_free_measurement_is_fitted_exactly() {
        let h = render();
        let m: Vec<f32> = h.iter().map(|&v| 3.0 * v + 0.7).collect();
        let f = fit(&h, &m, BINS, 4);
        assert!(
            (f.scale - 3.0).abs() < 1e-6 && (f.background - 0.7).abs() < 1e-6,
            "{f:?}"
        );
        assert!(f.deviance < 1e-10, "{f:?}");
    }

    #[test]
    fn counts_of_the_model_reach_the_photon_floor() {
        let h = render();
        let mu: Vec<f64> = h.iter().map(|&v| 5.0 * f64::from(v) + 20.0).collect();
        let f = fit(&h, &counts(&mu), BINS, 0);
        // At 20 or more counts a bin, the deviance of the true mean is close to 1 a bin.
        assert!((f.deviance - 1.0).abs() < 0.1, "{f:?}");
        assert!(
            (f.scale - 5.0).abs() < 0.5 && (f.background - 20.0).abs() < 1.0,
            "{f:?}"
        );
    }

    #[test]
    fn the_adjoint_is_the_derivative_of_the_minimised_deviance() {
        let h = render();
        let mu: Vec<f64> = h.iter().map(|&v| 2.0 * f64::from(v) + 1.5).collect();
        let m = counts(&mu);
        let f = fit(&h, &m, BINS, 3);
        let adj = adjoint(&f, &h, &m, BINS, 3);
        let scale = adj.iter().fold(0.0f32, |a, v| a.max(v.abs()));
        for i in [5, 21, 88, 300, 20 * BINS - 1] {
            let eps = 1e-2f32;
            let dev = |d: f32| {
                let mut hh = h.clone();
                hh[i] += d;
                fit(&hh, &m, BINS, 3).deviance
            };
            let fd = (dev(eps) - dev(-eps)) / (2.0 * f64::from(eps));
            assert!(
                (f64::from(adj[i]) - fd).abs() < 2e-3 * f64::from(scale),
                "bin {i}: {} against {fd}",
                adj[i]
            );
        }
        assert_eq!(adj[1], 0.0);
    }
}
