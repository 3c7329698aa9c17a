//! The nuisance parameters a capture's model is linear in, fitted in closed form inside
//! every evaluation (issue 48), under L2 or the Poisson likelihood.
//!
//! A [`Design`] says how the model of bin `t` at scan point `p` depends on the render
//! `h = H[p, t]` (already through the detector response) and the parameters `β`:
//!
//! `μ[p, t] = x(p, t, h) · β`,
//!
//! e.g. `x = (h, h x_p, …, 1, x_p, …, D_p τ_k[t], …)` for a gain field, a floor and
//! the direct return's tails ([`super::point_background`]). Some columns are held
//! non-negative (the scale, the tails' gains). Over the fitted bins `U` (bins from
//! `first` on, at the scan points in the fit),
//!
//! - **L2**: `L = min_β ‖μ − M‖²_U / ‖M‖²_U`, a convex quadratic: the normal equations
//!   `G β = r` (`G = Σ x xᵀ`, at most [`MAX_COLS`] square) are solved on every face of
//!   the sign constraints and the best feasible solution kept (the exact constrained
//!   optimum); `dL/dh = 2 (μ − M) (∂μ/∂h) / ‖M‖²`.
//! - **Poisson** (photon counts): the deviance per bin
//!   `D = (2 q / |U|) Σ_U (μ − M + M ln(M / μ))` (`M ln(M/μ) = 0` where `M = 0`;
//!   `q` the number of counts each value averages, `n²` for `n x n` averaged scan
//!   blocks, so that `D ≈ 1` a bin for a perfect model of the counts), convex in `β`:
//!   projected Newton steps (`∇ = Σ x (1 − M/μ)`, `∇² = Σ x xᵀ M/μ²`) from the L2
//!   solution, with a backtracking line search that keeps `μ > 0` on `U`;
//!   `dD/dh = (2 q / |U|) (1 − M/μ) ∂μ/∂h`.
//!
//! Both minimise over `β` for the current render, so by the envelope theorem (which holds
//! at active constraints too) the gradient with respect to the render is the partial
//! derivative at the fitted `β`: no derivative through `β`.
//!
//! Sums run per scan point in parallel and are added in point order: the result does not
//! depend on the thread count.

use rayon::prelude::*;

/// Most columns of a design.
pub const MAX_COLS: usize = 16;

/// How a model is linear in its parameters (module doc).
pub trait Design: Sync {
    /// The number of columns (at most [`MAX_COLS`]).
    fn columns(&self) -> usize;
    /// Fills `out[..columns()]` with the row `x(p, t, h)`.
    fn row(&self, p: usize, t: usize, h: f64, out: &mut [f64; MAX_COLS]);
    /// `∂μ/∂h` at `(p, t)` for the coefficients `beta` (μ is linear in `h`).
    fn d_render(&self, beta: &[f64; MAX_COLS], p: usize) -> f64;
    /// Columns whose coefficient is held `≥ 0`.
    fn nonnegative(&self) -> &[usize];
    /// The column of a constant floor (its row is 1 everywhere), if there is one.
    fn floor_column(&self) -> Option<usize>;
    /// Whether the model adds a floor `f_p` per scan point to `x · β` (fitted with `β`
    /// by [`super::point_floor`]; the design then has no floor column of its own).
    fn point_floor(&self) -> bool {
        false
    }
}

/// The likelihood the nuisances and the loss use.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Likelihood {
    /// Relative squared error `‖μ − M‖² / ‖M‖²`.
    L2,
    /// Poisson deviance per bin; `counts_per_value` is `q` of the module doc.
    Poisson { counts_per_value: f64 },
}

/// The bins and scan points a fit compares.
#[derive(Clone, Copy, Debug)]
pub struct Window<'a> {
    pub bins: usize,
    /// Bins `first..bins` of each row.
    pub first: usize,
    /// Per scan point, whether it is in the fit (empty: all are).
    pub in_fit: &'a [bool],
}

impl Window<'_> {
    /// Whether point `p` is in the fit.
    pub(super) fn uses(&self, p: usize) -> bool {
        self.in_fit.get(p).copied().unwrap_or(true)
    }

    /// The number of fitted bins.
    pub fn size(&self, points: usize) -> usize {
        (0..points).filter(|&p| self.uses(p)).count() * self.bins.saturating_sub(self.first)
    }
}

/// The fitted coefficients and the loss (relative L2, or deviance per bin).
#[derive(Clone, Debug, PartialEq)]
pub struct LinearFit {
    pub beta: [f64; MAX_COLS],
    pub loss: f64,
    /// Each scan point's floor `f_p` (every point, held-out ones too) where the design
    /// has one ([`Design::point_floor`]); empty otherwise.
    pub floors: Vec<f64>,
}

impl LinearFit {
    /// The floor of point `p` (0 without per-point floors).
    pub fn floor(&self, p: usize) -> f64 {
        self.floors.get(p).copied().unwrap_or(0.0)
    }
}

/// Sums of a design over the window: `G = Σ w x xᵀ`, `r = Σ w' x` and `c = Σ c'` for
/// per-bin weights given by `f(h, m, x·β) -> (w, w', c')` (sequential per point, points
/// added in order).
fn sums<D: Design>(
    d: &D,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    beta: &[f64; MAX_COLS],
    f: impl Fn(f64, f64, f64) -> (f64, f64, f64) + Sync,
) -> ([[f64; MAX_COLS]; MAX_COLS], [f64; MAX_COLS], f64) {
    let n = d.columns();
    let per_point: Vec<_> = render
        .par_chunks_exact(win.bins)
        .zip(measured.par_chunks_exact(win.bins))
        .enumerate()
        .map(|(p, (h, m))| {
            let mut g = [[0.0f64; MAX_COLS]; MAX_COLS];
            let mut r = [0.0f64; MAX_COLS];
            let mut c = 0.0;
            if !win.uses(p) {
                return (g, r, c);
            }
            let mut x = [0.0f64; MAX_COLS];
            for t in win.first..win.bins {
                let (h, m) = (f64::from(h[t]), f64::from(m[t]));
                d.row(p, t, h, &mut x);
                let mu: f64 = x[..n].iter().zip(beta).map(|(x, b)| x * b).sum();
                let (w, wr, cc) = f(h, m, mu);
                c += cc;
                for i in 0..n {
                    r[i] += wr * x[i];
                    if w != 0.0 {
                        for j in 0..=i {
                            g[i][j] += w * x[i] * x[j];
                        }
                    }
                }
            }
            (g, r, c)
        })
        .collect();
    let mut g = [[0.0f64; MAX_COLS]; MAX_COLS];
    let mut r = [0.0f64; MAX_COLS];
    let mut c = 0.0;
    for (pg, pr, pc) in per_point {
        for i in 0..n {
            r[i] += pr[i];
            for j in 0..=i {
                g[i][j] += pg[i][j];
            }
        }
        c += pc;
    }
    // The lower triangle was summed; mirror it.
    (symmetric(g, n), r, c)
}

/// Mirrors the lower triangle of the leading `n x n` block into its upper one.
pub(super) fn symmetric(
    mut g: [[f64; MAX_COLS]; MAX_COLS],
    n: usize,
) -> [[f64; MAX_COLS]; MAX_COLS] {
    for i in 1..n {
        let (upper, lower) = g.split_at_mut(i);
        for (j, row) in upper.iter_mut().enumerate() {
            row[i] = lower[0][j];
        }
    }
    g
}

/// The least-squares coefficients and the relative L2 loss.
pub fn fit_l2<D: Design>(d: &D, render: &[f32], measured: &[f32], win: &Window) -> LinearFit {
    let zero = [0.0; MAX_COLS];
    let (g, r, mm) = sums(d, render, measured, win, &zero, |_, m, _| (1.0, m, m * m));
    let (beta, residual) = constrained(&g, &r, mm, d.columns(), d.nonnegative());
    LinearFit {
        beta,
        loss: if mm > 0.0 { residual / mm } else { 0.0 },
        floors: Vec::new(),
    }
}

/// One bin's Poisson deviance term `μ − M + M ln(M/μ)` (`M ln(M/μ) = 0` where `M = 0`;
/// `μ > 0`): the deviance is twice its sum.
pub fn deviance_term(m: f64, mu: f64) -> f64 {
    let log = if m > 0.0 { m * (m / mu).ln() } else { 0.0 };
    mu - m + log
}

/// The Poisson deviance terms `(D, ∇, ∇²)` at `beta` (unnormalised: `Σ (μ − M + M ln(M/μ))`
/// and its derivatives in `β`), or `None` if some `μ ≤ 0` on the window.
fn poisson_terms<D: Design>(
    d: &D,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    beta: &[f64; MAX_COLS],
) -> Option<(f64, [f64; MAX_COLS], [[f64; MAX_COLS]; MAX_COLS])> {
    let (hess, grad, dev) = sums(d, render, measured, win, beta, |_, m, mu| {
        if mu <= 0.0 {
            return (0.0, 0.0, f64::INFINITY);
        }
        (m / (mu * mu), 1.0 - m / mu, deviance_term(m, mu))
    });
    dev.is_finite().then_some((dev, grad, hess))
}

/// The least-deviance coefficients and the deviance per fitted bin (module doc).
pub fn fit_poisson<D: Design>(
    d: &D,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    counts_per_value: f64,
    start: &LinearFit,
) -> LinearFit {
    let size = win.size(render.len() / win.bins.max(1)).max(1) as f64;
    let norm = 2.0 * counts_per_value / size;
    let Some(first) = poisson_terms(d, render, measured, win, &start.beta) else {
        // The L2 solution puts a bin's mean at or below zero: the deviance is not
        // defined there, and the L2 fit is returned with an infinite loss.
        return LinearFit {
            beta: start.beta,
            loss: f64::INFINITY,
            floors: Vec::new(),
        };
    };
    // A column that is zero on the window (a tail of no direct counts) has no curvature
    // and stays where it is ([`projected_newton`]).
    let (beta, cur) = projected_newton(
        d,
        (start.beta, first),
        |s| s.0,
        |_, s| (s.1, s.2),
        |next, _| poisson_terms(d, render, measured, win, next),
    );
    LinearFit {
        beta,
        loss: norm * cur.0,
        floors: Vec::new(),
    }
}

/// Projected Newton steps on a convex loss of `β` with the design's non-negative columns
/// held `≥ 0`, from `start` (`β` and its evaluation state `S`): `value` reads the loss from
/// a state, `terms` gives the gradient and Hessian at `β`, `evaluate` the state at a trial
/// `β` (`None` where the loss is undefined). Free variables are those off their bound or
/// pushed inward, with curvature; a nearly dependent set is damped; a backtracking line
/// search keeps every step downhill. Shared by the Poisson fits with and without a floor
/// per point ([`super::point_floor`]).
pub(super) fn projected_newton<D: Design, S>(
    d: &D,
    start: ([f64; MAX_COLS], S),
    value: impl Fn(&S) -> f64,
    terms: impl Fn(&[f64; MAX_COLS], &S) -> ([f64; MAX_COLS], [[f64; MAX_COLS]; MAX_COLS]),
    evaluate: impl Fn(&[f64; MAX_COLS], &S) -> Option<S>,
) -> ([f64; MAX_COLS], S) {
    let (n, nonneg) = (d.columns(), d.nonnegative());
    let (mut beta, mut cur) = start;
    for _ in 0..50 {
        let (grad, hess) = terms(&beta, &cur);
        let free: Vec<usize> = (0..n)
            .filter(|&i| !(nonneg.contains(&i) && beta[i] <= 0.0 && grad[i] > 0.0))
            .filter(|&i| hess[i][i] > 0.0)
            .collect();
        let neg: [f64; MAX_COLS] = std::array::from_fn(|i| -grad[i]);
        let damped = |k: f64| {
            let mut h = hess;
            (0..n).for_each(|i| h[i][i] *= 1.0 + k);
            h
        };
        let Some(step) = [0.0, 1e-9, 1e-6, 1e-3]
            .iter()
            .find_map(|&k| solve(&damped(k), &neg, &free))
        else {
            break;
        };
        let mut dir = [0.0; MAX_COLS];
        free.iter().zip(&step).for_each(|(&i, &s)| dir[i] = s);
        let (mut t, mut moved) = (1.0, false);
        while t > 1e-10 {
            let mut next = beta;
            for i in 0..n {
                next[i] += t * dir[i];
                if nonneg.contains(&i) {
                    next[i] = next[i].max(0.0);
                }
            }
            if let Some(state) = evaluate(&next, &cur) {
                let (was, now) = (value(&cur), value(&state));
                if now <= was {
                    moved = (was - now) / was.abs().max(1e-300) > 1e-13;
                    (beta, cur) = (next, state);
                    break;
                }
            }
            t *= 0.5;
        }
        if !moved {
            break;
        }
    }
    (beta, cur)
}

/// `f(p, render row, measured row)` for every scan point, in parallel, in point order.
pub(super) fn per_point<T: Send>(
    render: &[f32],
    measured: &[f32],
    bins: usize,
    f: impl Fn(usize, &[f32], &[f32]) -> T + Sync,
) -> Vec<T> {
    render
        .par_chunks_exact(bins)
        .zip(measured.par_chunks_exact(bins))
        .enumerate()
        .map(|(p, (h, m))| f(p, h, m))
        .collect()
}

/// The fit of `likelihood`.
pub fn fit<D: Design>(
    d: &D,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    likelihood: Likelihood,
) -> LinearFit {
    if d.point_floor() {
        return super::point_floor::fit(d, render, measured, win, likelihood);
    }
    let l2 = fit_l2(d, render, measured, win);
    match likelihood {
        Likelihood::L2 => l2,
        Likelihood::Poisson { counts_per_value } => {
            let start = feasible(d, render, measured, win, &l2);
            fit_poisson(d, render, measured, win, counts_per_value, &start)
        }
    }
}

/// `μ` for `beta` at `(p, t)` with render `h`.
pub fn model<D: Design>(d: &D, beta: &[f64; MAX_COLS], p: usize, t: usize, h: f64) -> f64 {
    let mut x = [0.0; MAX_COLS];
    d.row(p, t, h, &mut x);
    x[..d.columns()].iter().zip(beta).map(|(x, b)| x * b).sum()
}

/// `μ` of the fit at `(p, t)` with render `h`: [`model`] plus the point's floor.
pub fn mean<D: Design>(d: &D, fit: &LinearFit, p: usize, t: usize, h: f64) -> f64 {
    model(d, &fit.beta, p, t, h) + fit.floor(p)
}

/// The L2 solution moved until every fitted mean is positive: its non-negative columns
/// kept, the others shrunk towards the pure non-negative model, the first column whose
/// row is 1 everywhere (a floor) raised last. The Poisson steps start from it.
fn feasible<D: Design>(
    d: &D,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    l2: &LinearFit,
) -> LinearFit {
    let lowest = |beta: &[f64; MAX_COLS]| -> f64 {
        render
            .par_chunks_exact(win.bins)
            .enumerate()
            .filter(|(p, _)| win.uses(*p))
            .map(|(p, h)| {
                (win.first..win.bins)
                    .map(|t| model(d, beta, p, t, f64::from(h[t])))
                    .fold(f64::INFINITY, f64::min)
            })
            .reduce(|| f64::INFINITY, f64::min)
    };
    let mean = {
        let size = win.size(measured.len() / win.bins.max(1)).max(1) as f64;
        let total: f64 = measured
            .chunks_exact(win.bins)
            .enumerate()
            .filter(|(p, _)| win.uses(*p))
            .map(|(_, m)| m[win.first..].iter().map(|&v| f64::from(v)).sum::<f64>())
            .sum();
        (total / size).max(1e-12)
    };
    let floor = d.floor_column();
    let mut beta = l2.beta;
    let low = lowest(&beta);
    let want = 1e-3 * mean;
    if low < want {
        if let Some(c) = floor {
            beta[c] += want - low;
        }
    }
    LinearFit {
        beta,
        loss: l2.loss,
        floors: Vec::new(),
    }
}

/// `dL/dH` at the fit (0 outside the window): the envelope theorem's gradient.
pub fn adjoint<D: Design>(
    d: &D,
    fit: &LinearFit,
    render: &[f32],
    measured: &[f32],
    win: &Window,
    likelihood: Likelihood,
) -> Vec<f32> {
    let points = render.len() / win.bins.max(1);
    let norm = match likelihood {
        Likelihood::L2 => {
            let mm: f64 = measured
                .chunks_exact(win.bins)
                .enumerate()
                .filter(|(p, _)| win.uses(*p))
                .map(|(_, m)| {
                    m[win.first..]
                        .iter()
                        .map(|&v| f64::from(v) * f64::from(v))
                        .sum::<f64>()
                })
                .sum();
            if mm > 0.0 {
                2.0 / mm
            } else {
                0.0
            }
        }
        Likelihood::Poisson { counts_per_value } => {
            2.0 * counts_per_value / win.size(points).max(1) as f64
        }
    };
    let mut out = vec![0.0f32; render.len()];
    out.par_chunks_exact_mut(win.bins)
        .zip(render.par_chunks_exact(win.bins))
        .zip(measured.par_chunks_exact(win.bins))
        .enumerate()
        .filter(|(p, _)| win.uses(*p))
        .for_each(|(p, ((o, h), m))| {
            let dmu = d.d_render(&fit.beta, p);
            for t in win.first..win.bins {
                let mu = mean(d, fit, p, t, f64::from(h[t]));
                let m = f64::from(m[t]);
                let r = match likelihood {
                    Likelihood::L2 => mu - m,
                    Likelihood::Poisson { .. } => 1.0 - m / mu,
                };
                o[t] = (norm * r * dmu) as f32;
            }
        });
    out
}

/// The best `β` with the `nonneg` columns `≥ 0`: each face (a subset of them held at 0)
/// solved unconstrained, the best feasible kept; and its residual `βᵀGβ − 2βᵀr + ‖M‖²`.
pub(super) fn constrained(
    g: &[[f64; MAX_COLS]; MAX_COLS],
    r: &[f64; MAX_COLS],
    mm: f64,
    n: usize,
    nonneg: &[usize],
) -> ([f64; MAX_COLS], f64) {
    let mut best = ([0.0; MAX_COLS], mm);
    for face in 0..1usize << nonneg.len() {
        let held = |i: usize| {
            nonneg
                .iter()
                .position(|&c| c == i)
                .is_some_and(|k| face & (1 << k) != 0)
        };
        let free: Vec<usize> = (0..n).filter(|&i| !held(i)).collect();
        let Some(sol) = solve(g, r, &free) else {
            continue;
        };
        let mut beta = [0.0; MAX_COLS];
        free.iter().zip(&sol).for_each(|(&i, &v)| beta[i] = v);
        if nonneg.iter().any(|&i| beta[i] < 0.0) {
            continue;
        }
        let quad: f64 = (0..n)
            .map(|i| (0..n).map(|j| beta[i] * g[i][j] * beta[j]).sum::<f64>())
            .sum();
        let lin: f64 = (0..n).map(|i| beta[i] * r[i]).sum();
        let residual = (quad - 2.0 * lin + mm).max(0.0);
        if residual < best.1 {
            best = (beta, residual);
        }
    }
    best
}

/// Solves `G[free, free] β = r[free]` by Gaussian elimination with partial pivoting,
/// after scaling `G` to unit diagonal (the columns' scales differ by orders of magnitude:
/// a render in counts against a tail in counts per direct count); `None` if singular (an
/// empty `free` gives an empty solution).
fn solve(g: &[[f64; MAX_COLS]; MAX_COLS], r: &[f64; MAX_COLS], free: &[usize]) -> Option<Vec<f64>> {
    let k = free.len();
    let d: Vec<f64> = free
        .iter()
        .map(|&i| {
            let v = g[i][i].abs().sqrt();
            if v > 0.0 {
                1.0 / v
            } else {
                1.0
            }
        })
        .collect();
    let mut a: Vec<Vec<f64>> = free
        .iter()
        .enumerate()
        .map(|(ii, &i)| {
            free.iter()
                .enumerate()
                .map(|(jj, &j)| g[i][j] * d[ii] * d[jj])
                .chain([r[i] * d[ii]])
                .collect()
        })
        .collect();
    for c in 0..k {
        let piv = (c..k).max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))?;
        if a[piv][c].abs() <= 1e-12 {
            return None;
        }
        a.swap(c, piv);
        let pivot_row = a[c].clone();
        for row in a.iter_mut().skip(c + 1) {
            let f = row[c] / pivot_row[c];
            row.iter_mut()
                .zip(&pivot_row)
                .skip(c)
                .for_each(|(v, p)| *v -= f * p);
        }
    }
    let mut x = vec![0.0; k];
    for c in (0..k).rev() {
        let s: f64 = (c + 1..k).map(|j| a[c][j] * x[j]).sum();
        x[c] = (a[c][k] - s) / a[c][c];
    }
    Some(x.iter().zip(&d).map(|(x, d)| x * d).collect())
}

/// Poisson counts of the means `mu` (synthetic photon counts of a model, for tests and
/// studies), by Knuth's method on a linear congruential stream from `seed`; a mean above
/// 500 is drawn as the sum of draws of at most 500 each (Poisson counts add), so
/// `exp(−μ)` never underflows. Deterministic for a seed.
pub fn poisson_counts(mu: impl IntoIterator<Item = f64>, seed: u64) -> Vec<f32> {
    let mut state = seed;
    let mut uniform = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let mut draw = |m: f64| {
        let (limit, mut k, mut p) = ((-m).exp(), 0u64, 1.0);
        loop {
            p *= uniform();
            if p <= limit {
                break k;
            }
            k += 1;
        }
    };
    mu.into_iter()
        .map(|m| {
            let (mut left, mut total) = (m.max(0.0), 0u64);
            loop {
                let part = left.min(500.0);
                total += draw(part);
                left -= part;
                if left <= 0.0 {
                    break total as f32;
                }
            }
        })
        .collect()
}
