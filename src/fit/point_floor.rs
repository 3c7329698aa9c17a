//! A floor per scan point in the capture model's linear fit (issue 48).
//!
//! The Stanford captures' floor (dark counts and ambient light) is not smooth over the
//! scan: `dot_chart_65cm`'s doubles from one scan column to the next (the scanner sweeps
//! the wall column by column, and the ambient level drifts between columns), which a
//! degree-2 polynomial leaves as deviance ~2 a bin where nothing hidden returns
//! (`python/studies/residual_anatomy.py`). So the model is
//!
//! `μ[p, t] = x(p, t, h) · β + f_p`,
//!
//! one floor `f_p` per scan point (each has ~180 fitted bins, so its floor is known to a
//! few per cent), profiled out of the fit of `β`:
//!
//! - **L2**: for fixed `β` the best floor is `f_p = m̄_p − x̄_p · β` (means over the
//!   point's fitted bins), so `β` solves the centred normal equations
//!   `Σ_p Σ_t (x − x̄_p)(x − x̄_p)ᵀ β = Σ_p Σ_t (x − x̄_p)(m − m̄_p)` under `β`'s sign
//!   constraints ([`super::linear_fit`]'s face enumeration).
//! - **Poisson**: for fixed `β` each `f_p` solves the one-dimensional convex problem
//!   `Σ_t (1 − m/μ) = 0` on `f_p ≥ max(0, ε − min_t x · β)` (a safeguarded Newton
//!   iteration); `β` takes Newton steps on the profiled deviance, whose Hessian is the
//!   Schur complement `Σ_p (H_ββ − h_p h_pᵀ / H_ff)` (`h_p = Σ_t x m/μ²`,
//!   `H_ff = Σ_t m/μ²`; a point whose floor sits at its bound adds `H_ββ` only), the
//!   floors re-profiled at every trial of the line search, from the L2 solution.
//!
//! Every point gets a floor, held-out ones too (from its own bins, for the fit's `β`):
//! a held-out point's loss then scores the response and the geometry, not its floor.
//! Sums run per point in parallel and are added in point order (thread-count
//! independent).

use super::linear_fit::{
    constrained, deviance_term, per_point, projected_newton, symmetric, Design, Likelihood,
    LinearFit, Window, MAX_COLS,
};

type Matrix = [[f64; MAX_COLS]; MAX_COLS];

/// The fit of `likelihood` with a floor per point (module doc).
pub fn fit<D: Design>(
    d: &D,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    likelihood: Likelihood,
) -> LinearFit {
    let l2 = fit_l2(d, render, measured, win);
    match likelihood {
        Likelihood::L2 => l2,
        Likelihood::Poisson { counts_per_value } => {
            fit_poisson(d, render, measured, win, counts_per_value, l2.beta)
        }
    }
}

/// One point's sums over its fitted bins: count, `Σx`, `Σm`, `Σxxᵀ` (lower triangle),
/// `Σxm`, `Σm²`.
#[derive(Clone, Copy)]
struct Moments {
    n: f64,
    sx: [f64; MAX_COLS],
    sm: f64,
    sxx: Matrix,
    sxm: [f64; MAX_COLS],
    smm: f64,
}

fn moments<D: Design>(d: &D, p: usize, h: &[f32], m: &[f32], win: &Window) -> Moments {
    let cols = d.columns();
    let mut mo = Moments {
        n: 0.0,
        sx: [0.0; MAX_COLS],
        sm: 0.0,
        sxx: [[0.0; MAX_COLS]; MAX_COLS],
        sxm: [0.0; MAX_COLS],
        smm: 0.0,
    };
    let mut x = [0.0; MAX_COLS];
    for t in win.first..win.bins {
        let m = f64::from(m[t]);
        d.row(p, t, f64::from(h[t]), &mut x);
        mo.n += 1.0;
        mo.sm += m;
        mo.smm += m * m;
        for i in 0..cols {
            mo.sx[i] += x[i];
            mo.sxm[i] += x[i] * m;
            for j in 0..=i {
                mo.sxx[i][j] += x[i] * x[j];
            }
        }
    }
    mo
}

#[allow(clippy::needless_range_loop)] // index pairs of a symmetric matrix
fn fit_l2<D: Design>(d: &D, render: &[f32], measured: &[f32], win: &Window) -> LinearFit {
    let cols = d.columns();
    let sums: Vec<Moments> = per_point(render, measured, win.bins, |p, h, m| {
        moments(d, p, h, m, win)
    });
    let (mut g, mut r) = ([[0.0; MAX_COLS]; MAX_COLS], [0.0; MAX_COLS]);
    let (mut centred, mut total) = (0.0, 0.0);
    for (p, mo) in sums.iter().enumerate() {
        if !win.uses(p) || mo.n == 0.0 {
            continue;
        }
        for i in 0..cols {
            r[i] += mo.sxm[i] - mo.sx[i] * mo.sm / mo.n;
            for j in 0..=i {
                g[i][j] += mo.sxx[i][j] - mo.sx[i] * mo.sx[j] / mo.n;
            }
        }
        centred += mo.smm - mo.sm * mo.sm / mo.n;
        total += mo.smm;
    }
    let (beta, residual) = constrained(&symmetric(g, cols), &r, centred, cols, d.nonnegative());
    let floors = sums
        .iter()
        .map(|mo| {
            let xb: f64 = (0..cols).map(|i| mo.sx[i] * beta[i]).sum();
            (mo.sm - xb) / mo.n.max(1.0)
        })
        .collect();
    LinearFit {
        beta,
        loss: if total > 0.0 { residual / total } else { 0.0 },
        floors,
    }
}

/// `(x · β, m)` over a point's fitted bins.
fn rows<'a, D: Design>(
    d: &'a D,
    beta: &'a [f64; MAX_COLS],
    p: usize,
    h: &'a [f32],
    m: &'a [f32],
    win: &Window,
) -> impl Iterator<Item = (f64, f64)> + 'a {
    let mut x = [0.0; MAX_COLS];
    (win.first..win.bins).map(move |t| {
        d.row(p, t, f64::from(h[t]), &mut x);
        let a: f64 = x[..d.columns()].iter().zip(beta).map(|(x, b)| x * b).sum();
        (a, f64::from(m[t]))
    })
}

/// The floor's lower bound for a point whose lowest `x · β` is `low` and whose mean count
/// is `mean`: non-negative and keeping every mean positive.
fn floor_bound(low: f64, mean: f64) -> f64 {
    (1e-6 * (1.0 + mean) - low).max(0.0)
}

/// The Poisson-optimal floor of one point for `x · β = a` (module doc), from `start`.
fn profile(a: &[f64], m: &[f64], start: f64) -> f64 {
    let low = a.iter().copied().fold(f64::INFINITY, f64::min);
    let (n, sm) = (m.len() as f64, m.iter().sum::<f64>());
    let lo = floor_bound(low, sm / n.max(1.0));
    // g(f) = Σ (1 − m/(a + f)) is increasing in f; g(lo) ≥ 0 puts the optimum at lo.
    let g = |f: f64| -> (f64, f64) {
        a.iter().zip(m).fold((0.0, 0.0), |(g, h), (&a, &m)| {
            let mu = a + f;
            (g + 1.0 - m / mu, h + m / (mu * mu))
        })
    };
    let (g_lo, _) = g(lo);
    if sm == 0.0 || g_lo >= 0.0 {
        return lo;
    }
    // At f with min a + f ≥ Σm / n, Σ m/(a + f) ≤ n: g ≥ 0.
    let (mut lo, mut hi) = (lo, (sm / n - low).max(lo) * (1.0 + 1e-12) + 1e-12);
    let mut f = start.clamp(lo, hi);
    for _ in 0..100 {
        let (gf, hf) = g(f);
        if gf.abs() <= 1e-12 * n {
            break;
        }
        if gf < 0.0 {
            lo = f;
        } else {
            hi = f;
        }
        let newton = f - gf / hf;
        f = if hf > 0.0 && newton > lo && newton < hi {
            newton
        } else {
            0.5 * (lo + hi)
        };
        if hi - lo <= 1e-14 * hi.abs().max(1.0) {
            break;
        }
    }
    f
}

/// Every point's profiled floor for `beta` (from `start`).
fn profile_all<D: Design>(
    d: &D,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    beta: &[f64; MAX_COLS],
    start: &[f64],
) -> Vec<f64> {
    per_point(render, measured, win.bins, |p, h, m| {
        let (a, m): (Vec<f64>, Vec<f64>) = rows(d, beta, p, h, m, win).unzip();
        profile(&a, &m, start.get(p).copied().unwrap_or(0.0))
    })
}

/// The deviance (unnormalised) over the window's points for `beta` and `floors`.
fn deviance<D: Design>(
    d: &D,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    beta: &[f64; MAX_COLS],
    floors: &[f64],
) -> f64 {
    let terms: Vec<f64> = per_point(render, measured, win.bins, |p, h, m| {
        if !win.uses(p) {
            return 0.0;
        }
        rows(d, beta, p, h, m, win)
            .map(|(a, m)| deviance_term(m, a + floors[p]))
            .sum()
    });
    terms.iter().sum()
}

/// The profiled deviance's gradient and Hessian in `β` at `(beta, floors)`.
fn newton_terms<D: Design>(
    d: &D,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    beta: &[f64; MAX_COLS],
    floors: &[f64],
) -> ([f64; MAX_COLS], Matrix) {
    let cols = d.columns();
    let terms: Vec<([f64; MAX_COLS], Matrix)> = per_point(render, measured, win.bins, |p, h, m| {
        let (mut grad, mut hess) = ([0.0; MAX_COLS], [[0.0; MAX_COLS]; MAX_COLS]);
        if !win.uses(p) {
            return (grad, hess);
        }
        let (mut hf, mut hff, mut gf) = ([0.0; MAX_COLS], 0.0, 0.0);
        let (mut low, mut sum_m) = (f64::INFINITY, 0.0);
        let mut x = [0.0; MAX_COLS];
        for t in win.first..win.bins {
            let m = f64::from(m[t]);
            d.row(p, t, f64::from(h[t]), &mut x);
            let a = x[..cols].iter().zip(beta).map(|(x, b)| x * b).sum::<f64>();
            let mu = a + floors[p];
            (low, sum_m) = (low.min(a), sum_m + m);
            let (w, r) = (m / (mu * mu), 1.0 - m / mu);
            gf += r;
            hff += w;
            for i in 0..cols {
                grad[i] += r * x[i];
                hf[i] += w * x[i];
                for j in 0..=i {
                    hess[i][j] += w * x[i] * x[j];
                }
            }
        }
        let mean = sum_m / (win.bins - win.first).max(1) as f64;
        let at_bound = floors[p] <= floor_bound(low, mean) && gf > 0.0;
        if hff > 0.0 && !at_bound {
            for i in 0..cols {
                grad[i] -= hf[i] * gf / hff;
                for j in 0..=i {
                    hess[i][j] -= hf[i] * hf[j] / hff;
                }
            }
        }
        (grad, hess)
    });
    let (mut grad, mut hess) = ([0.0; MAX_COLS], [[0.0; MAX_COLS]; MAX_COLS]);
    for (g, h) in terms {
        for i in 0..cols {
            grad[i] += g[i];
            for j in 0..=i {
                hess[i][j] += h[i][j];
            }
        }
    }
    (grad, symmetric(hess, cols))
}

fn fit_poisson<D: Design>(
    d: &D,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    counts_per_value: f64,
    start: [f64; MAX_COLS],
) -> LinearFit {
    let size = win.size(render.len() / win.bins.max(1)).max(1) as f64;
    let floors = profile_all(d, render, measured, win, &start, &[]);
    let dev = deviance(d, render, measured, win, &start, &floors);
    // The state: the floors profiled at β, and the deviance there.
    let (beta, (floors, cur)) = projected_newton(
        d,
        (start, (floors, dev)),
        |s| s.1,
        |beta, s| newton_terms(d, render, measured, win, beta, &s.0),
        |next, s| {
            let floors = profile_all(d, render, measured, win, next, &s.0);
            let dev = deviance(d, render, measured, win, next, &floors);
            Some((floors, dev))
        },
    );
    LinearFit {
        beta,
        loss: 2.0 * counts_per_value / size * cur,
        floors,
    }
}

#[cfg(test)]
mod tests {
    use super::super::linear_fit::{adjoint, mean, poisson_counts};
    use super::super::point_background::{exponential_tail, Floor, PointBackground};
    use super::*;

    const BINS: usize = 60;
    const FIRST: usize = 6;
    const POINTS: usize = 64;

    /// An 8 x 8 scan: pulses, direct counts varying over the scan, one tail, and a floor
    /// that jumps between scan columns (as the captures' does).
    fn setup() -> (PointBackground, Vec<f32>, Vec<f64>) {
        let coords: Vec<(f64, f64)> = (0..POINTS)
            .map(|p| ((p % 8) as f64 / 3.5 - 1.0, (p / 8) as f64 / 3.5 - 1.0))
            .collect();
        let direct: Vec<f64> = (0..POINTS).map(|p| 1e4 * (1.0 + (p % 5) as f64)).collect();
        let tails = vec![exponential_tail(8.0, 0.0, 1.0, BINS)];
        let render: Vec<f32> = (0..POINTS * BINS)
            .map(|i| {
                let (p, t) = (i / BINS, i % BINS);
                (-((t as f64 - 30.0 - (p % 4) as f64) / 3.0).powi(2)).exp() as f32
            })
            .collect();
        let floors: Vec<f64> = (0..POINTS).map(|p| [0.5, 2.0, 0.8, 1.4][p % 4]).collect();
        let design = PointBackground::new(direct, tails, coords, Floor::PerPoint, 1);
        (design, render, floors)
    }

    /// Gain 40 + 5 x − 3 y, tail gain 2e-4, the setup's floors.
    fn truth(d: &PointBackground, render: &[f32], floors: &[f64]) -> Vec<f64> {
        let mut beta = [0.0; MAX_COLS];
        beta[..4].copy_from_slice(&[40.0, 5.0, -3.0, 2e-4]);
        let fit = LinearFit {
            beta,
            loss: 0.0,
            floors: floors.to_vec(),
        };
        (0..render.len())
            .map(|i| mean(d, &fit, i / BINS, i % BINS, f64::from(render[i])))
            .collect()
    }

    fn window(in_fit: &[bool]) -> Window<'_> {
        Window {
            bins: BINS,
            first: FIRST,
            in_fit,
        }
    }

    #[test]
    fn l2_recovers_gain_tail_and_every_floor_exactly() {
        let (d, h, floors) = setup();
        let m: Vec<f32> = truth(&d, &h, &floors).iter().map(|&v| v as f32).collect();
        let f = fit(&d, &h, &m, &window(&[]), Likelihood::L2);
        for (a, b) in f.beta.iter().zip([40.0, 5.0, -3.0, 2e-4]) {
            assert!(
                (a - b).abs() < 1e-4 * b.abs().max(1e-3),
                "{:?}",
                &f.beta[..4]
            );
        }
        for (a, b) in f.floors.iter().zip(&floors) {
            assert!((a - b).abs() < 1e-4, "{a} {b}");
        }
        assert!(f.loss < 1e-10, "{}", f.loss);
    }

    /// Poisson counts of the true model: the profiled Newton fit reaches the truth's
    /// deviance or lower (it is the optimum), recovers the floors within their photon
    /// noise, and a held-out point (left out of the fit) still gets its own floor.
    #[test]
    fn poisson_recovers_the_floors_within_their_noise() {
        let (d, h, floors) = setup();
        let mu = truth(&d, &h, &floors);
        let m = poisson_counts(mu.iter().copied(), 17);
        let mut in_fit = vec![true; POINTS];
        in_fit[9] = false;
        let f = fit(
            &d,
            &h,
            &m,
            &window(&in_fit),
            Likelihood::Poisson {
                counts_per_value: 1.0,
            },
        );
        let size = (POINTS - 1) * (BINS - FIRST);
        let truth_dev = 2.0 / size as f64
            * (0..POINTS)
                .filter(|&p| in_fit[p])
                .flat_map(|p| (FIRST..BINS).map(move |t| (p, t)))
                .map(|(p, t)| deviance_term(f64::from(m[p * BINS + t]), mu[p * BINS + t]))
                .sum::<f64>();
        assert!(f.loss <= truth_dev + 1e-9, "{} > {truth_dev}", f.loss);
        assert!((f.beta[0] / 40.0 - 1.0).abs() < 0.05, "{:?}", &f.beta[..4]);
        for (p, (a, b)) in f.floors.iter().zip(&floors).enumerate() {
            // ~54 bins of counts ~1: a floor's standard error is ~0.15.
            assert!((a - b).abs() < 0.6, "point {p}: {a} against {b}");
        }
        let err: f64 = f
            .floors
            .iter()
            .zip(&floors)
            .map(|(a, b)| (a - b).abs())
            .sum();
        assert!(
            err / (POINTS as f64) < 0.2,
            "mean floor error {}",
            err / POINTS as f64
        );
        // The fit is the optimum: moving any coefficient (floors re-profiled) raises it.
        for i in 0..4 {
            for s in [-1.0, 1.0] {
                let mut beta = f.beta;
                beta[i] += s * 1e-3 * beta[i].abs().max(1e-5);
                let fl = profile_all(&d, &h, &m, &window(&in_fit), &beta, &f.floors);
                let dev = 2.0 / size as f64 * deviance(&d, &h, &m, &window(&in_fit), &beta, &fl);
                assert!(
                    dev >= f.loss - 1e-12,
                    "coefficient {i} {s}: {dev} < {}",
                    f.loss
                );
            }
        }
    }

    /// The loss's gradient in the render (the envelope theorem's, through the floors too)
    /// against central differences of the refitted loss.
    #[test]
    fn the_adjoint_matches_finite_differences_with_floors_refitted() {
        let (d, h, floors) = setup();
        let mu = truth(&d, &h, &floors);
        let m = poisson_counts(mu.iter().copied(), 5);
        let win = window(&[]);
        for likelihood in [
            Likelihood::L2,
            Likelihood::Poisson {
                counts_per_value: 1.0,
            },
        ] {
            let f = fit(&d, &h, &m, &win, likelihood);
            let adj = adjoint(&d, &f, &h, &m, &win, likelihood);
            for i in [
                3 * BINS + 28,
                20 * BINS + 31,
                41 * BINS + 33,
                50 * BINS + 10,
            ] {
                let eps = 1e-3f32;
                let mut hp = h.clone();
                hp[i] += eps;
                let mut hm = h.clone();
                hm[i] -= eps;
                let lp = fit(&d, &hp, &m, &win, likelihood).loss;
                let lm = fit(&d, &hm, &m, &win, likelihood).loss;
                let fd = (lp - lm) / (2.0 * f64::from(eps));
                let a = f64::from(adj[i]);
                assert!(
                    (a - fd).abs() <= 1e-3 * fd.abs().max(1e-6) + 1e-9,
                    "{likelihood:?} bin {i}: adjoint {a:e}, finite differences {fd:e}"
                );
            }
        }
    }
}
