//! A capture's background per scan point (issue 48): a floor smooth over the scan plus the
//! direct return's tail, scaled by each point's own direct counts.
//!
//! `notes/capture-calibration.md` measures it on the Stanford captures: the light no hidden
//! surface explains is, at scan point `p` and bin `t`,
//!
//! `B[p, t] = f(x_p, y_p) + k D_p τ[t]`,
//!
//! `f` a polynomial of degree ≤ 2 in the scan coordinates (ambient light and dark counts,
//! smooth over the wall), `D_p` the point's direct counts (the wall's own return, measured
//! in its first bins), `τ[t]` the shared shape of the direct return's tail (the detector
//! response's slow tails: [`crate::film::response`]), `k ≥ 0` one number. A per-bin
//! background shared by all points leaves 3–13 σ per 128 ps bin there; this one reaches
//! χ²/bin 1.00. With the render `H` (already blurred by the response), the fit is
//!
//! `L = min_{s ≥ 0, k ≥ 0, c} ‖s H + f_c + k D τ − M‖²_U / ‖M‖²_U`
//!
//! over the fitted bins `U`, linear in `β = (s, c, k)`: the normal equations `G β = r`
//! (`G = XᵀX`, at most 8 x 8) are solved on each face of the two sign constraints and the
//! best feasible solution kept, which is the exact constrained optimum of a convex
//! quadratic. By the envelope theorem `dL/dH = 2 s (s H + B − M) / ‖M‖²` on `U`.

/// The background's fixed inputs, from the capture.
#[derive(Clone, Debug)]
pub struct PointBackground {
    /// `D_p`, per scan point (row of the measurement).
    pub direct: Vec<f64>,
    /// `τ[t]`, per bin.
    pub tail: Vec<f64>,
    /// Scan coordinates of each point, scaled to `[-1, 1]`.
    pub coords: Vec<(f64, f64)>,
    /// The floor's polynomial degree: 0, 1 or 2.
    pub degree: usize,
}

/// The fitted linear parameters and the loss.
#[derive(Clone, Debug, PartialEq)]
pub struct BackgroundFit {
    pub scale: f64,
    /// The floor's coefficients of `1, x, y, x², xy, y²` (as many as the degree takes).
    pub floor: Vec<f64>,
    pub tail_gain: f64,
    /// `L`, relative to `‖M‖²_U`.
    pub loss: f64,
}

impl BackgroundFit {
    /// `β = (s, c, k)` in the design's column order.
    fn coefficients(&self) -> [f64; MAX_COLS] {
        let mut beta = [0.0; MAX_COLS];
        beta[0] = self.scale;
        beta[1..1 + self.floor.len()].copy_from_slice(&self.floor);
        beta[1 + self.floor.len()] = self.tail_gain;
        beta
    }
}

/// Most columns: the render, six floor terms, the tail.
const MAX_COLS: usize = 8;

impl PointBackground {
    fn floor_terms(&self) -> usize {
        [1, 3, 6][self.degree.min(2)]
    }

    /// The design row of point `p`, bin `t`, render value `h`: `(h, 1, x, y, …, D_p τ[t])`.
    fn row(&self, p: usize, t: usize, h: f64, out: &mut [f64; MAX_COLS]) -> usize {
        let (x, y) = self.coords[p];
        let terms = [1.0, x, y, x * x, x * y, y * y];
        let nf = self.floor_terms();
        out[0] = h;
        out[1..1 + nf].copy_from_slice(&terms[..nf]);
        out[1 + nf] = self.direct[p] * self.tail[t];
        2 + nf
    }

    /// The least-squares `(s, c, k)` for `render` against `measured` (rows of `bins`,
    /// bins `first..` fitted).
    pub fn fit(
        &self,
        render: &[f32],
        measured: &[f32],
        bins: usize,
        first: usize,
    ) -> BackgroundFit {
        let mut g = [[0.0f64; MAX_COLS]; MAX_COLS];
        let mut r = [0.0f64; MAX_COLS];
        let (mut mm, mut n) = (0.0f64, 0);
        let mut x = [0.0f64; MAX_COLS];
        for (p, (h, m)) in render
            .chunks_exact(bins)
            .zip(measured.chunks_exact(bins))
            .enumerate()
        {
            for t in first..bins {
                n = self.row(p, t, f64::from(h[t]), &mut x);
                let y = f64::from(m[t]);
                for i in 0..n {
                    r[i] += x[i] * y;
                    for j in 0..n {
                        g[i][j] += x[i] * x[j];
                    }
                }
                mm += y * y;
            }
        }
        let (beta, residual) = constrained(&g, &r, mm, n);
        let nf = self.floor_terms();
        BackgroundFit {
            scale: beta[0],
            floor: beta[1..1 + nf].to_vec(),
            tail_gain: beta[1 + nf],
            loss: if mm > 0.0 { residual / mm } else { 0.0 },
        }
    }

    /// `B[p, t]` for the fitted parameters.
    pub fn background(&self, fit: &BackgroundFit, p: usize, t: usize) -> f64 {
        self.model(&fit.coefficients(), p, t, 0.0)
    }

    /// `s h + B[p, t]` for the coefficients `β` ([`BackgroundFit::coefficients`]).
    fn model(&self, beta: &[f64; MAX_COLS], p: usize, t: usize, h: f64) -> f64 {
        let mut x = [0.0f64; MAX_COLS];
        let n = self.row(p, t, h, &mut x);
        x[..n].iter().zip(beta).map(|(x, b)| x * b).sum()
    }

    /// `dL/dH` at the fit (the envelope theorem's gradient; 0 before `first`).
    pub fn adjoint(
        &self,
        fit: &BackgroundFit,
        render: &[f32],
        measured: &[f32],
        bins: usize,
        first: usize,
    ) -> Vec<f32> {
        let mm: f64 = measured
            .chunks_exact(bins)
            .flat_map(|m| m[first..].iter().map(|&v| f64::from(v) * f64::from(v)))
            .sum();
        let mut out = vec![0.0f32; render.len()];
        let beta = fit.coefficients();
        if mm <= 0.0 {
            return out;
        }
        for (p, ((h, m), o)) in render
            .chunks_exact(bins)
            .zip(measured.chunks_exact(bins))
            .zip(out.chunks_exact_mut(bins))
            .enumerate()
        {
            for t in first..bins {
                let model = self.model(&beta, p, t, f64::from(h[t]));
                o[t] = (2.0 * fit.scale * (model - f64::from(m[t])) / mm) as f32;
            }
        }
        out
    }
}

/// The best `β` with `β_0 ≥ 0` and `β_{n−1} ≥ 0` (the scale and the tail's gain): each of
/// the four faces solved unconstrained, the best feasible kept; and its residual
/// `βᵀGβ − 2βᵀr + ‖M‖²`.
fn constrained(
    g: &[[f64; MAX_COLS]; MAX_COLS],
    r: &[f64; MAX_COLS],
    mm: f64,
    n: usize,
) -> ([f64; MAX_COLS], f64) {
    let mut best = ([0.0; MAX_COLS], f64::INFINITY);
    for (fix_scale, fix_tail) in [(false, false), (true, false), (false, true), (true, true)] {
        let free: Vec<usize> = (0..n)
            .filter(|&i| !((i == 0 && fix_scale) || (i == n - 1 && fix_tail)))
            .collect();
        let Some(sol) = solve(g, r, &free) else {
            continue;
        };
        let mut beta = [0.0; MAX_COLS];
        free.iter().zip(&sol).for_each(|(&i, &v)| beta[i] = v);
        if beta[0] < 0.0 || beta[n - 1] < 0.0 {
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
    if best.1.is_infinite() {
        best.1 = mm;
    }
    best
}

/// Solves `G[free, free] β = r[free]` by Gaussian elimination with partial pivoting;
/// `None` if singular.
fn solve(g: &[[f64; MAX_COLS]; MAX_COLS], r: &[f64; MAX_COLS], free: &[usize]) -> Option<Vec<f64>> {
    let k = free.len();
    let mut a: Vec<Vec<f64>> = free
        .iter()
        .map(|&i| free.iter().map(|&j| g[i][j]).chain([r[i]]).collect())
        .collect();
    let scale = (0..k).map(|i| a[i][i].abs()).fold(0.0, f64::max);
    for c in 0..k {
        let piv = (c..k).max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))?;
        if a[piv][c].abs() <= 1e-13 * scale {
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
    Some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    const BINS: usize = 40;
    const FIRST: usize = 5;

    /// A 6 x 6 scan: a render of pulses, direct counts varying over the scan, a tail.
    fn setup() -> (PointBackground, Vec<f32>) {
        let coords: Vec<(f64, f64)> = (0..36)
            .map(|p| ((p % 6) as f64 / 2.5 - 1.0, (p / 6) as f64 / 2.5 - 1.0))
            .collect();
        let direct: Vec<f64> = (0..36)
            .map(|p| 100.0 + 30.0 * ((p * 7 % 5) as f64))
            .collect();
        let tail: Vec<f64> = (0..BINS).map(|t| (-(t as f64) / 9.0).exp()).collect();
        let render: Vec<f32> = (0..36 * BINS)
            .map(|i| {
                let (p, t) = (i / BINS, i % BINS);
                (-((t as f64 - 15.0 - (p % 4) as f64) / 2.0).powi(2)).exp() as f32
            })
            .collect();
        (
            PointBackground {
                direct,
                tail,
                coords,
                degree: 2,
            },
            render,
        )
    }

    fn measurement(bg: &PointBackground, render: &[f32], s: f64, c: &[f64], k: f64) -> Vec<f32> {
        let fit = BackgroundFit {
            scale: s,
            floor: c.to_vec(),
            tail_gain: k,
            loss: 0.0,
        };
        (0..render.len())
            .map(|i| (s * f64::from(render[i]) + bg.background(&fit, i / BINS, i % BINS)) as f32)
            .collect()
    }

    #[test]
    fn a_measurement_the_model_can_make_is_fitted_exactly() {
        let (bg, h) = setup();
        let c = [0.5, 0.1, -0.05, 0.02, 0.01, -0.03];
        let m = measurement(&bg, &h, 2.0, &c, 0.003);
        let fit = bg.fit(&h, &m, BINS, FIRST);
        assert!(
            (fit.scale - 2.0).abs() < 1e-4 && (fit.tail_gain - 0.003).abs() < 1e-6,
            "{fit:?}"
        );
        for (a, b) in fit.floor.iter().zip(c) {
            assert!((a - b).abs() < 1e-4, "{fit:?}");
        }
        assert!(fit.loss < 1e-10, "{}", fit.loss);
    }

    #[test]
    fn a_tail_the_data_do_not_hold_stays_at_zero() {
        let (bg, h) = setup();
        // A negative tail gain is no physics: the fit holds it at 0.
        let m = measurement(&bg, &h, 1.5, &[0.4, 0.0, 0.0, 0.0, 0.0, 0.0], -0.002);
        let fit = bg.fit(&h, &m, BINS, FIRST);
        assert_eq!(fit.tail_gain, 0.0, "{fit:?}");
        assert!(fit.scale > 0.0 && fit.loss > 0.0, "{fit:?}");
    }

    #[test]
    fn the_adjoint_is_the_derivative_of_the_minimised_loss() {
        let (bg, h) = setup();
        let mut m = measurement(&bg, &h, 2.0, &[0.5, 0.1, -0.05, 0.02, 0.01, -0.03], 0.003);
        // Off the model, so the residual is not zero.
        m.iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v += 0.05 * ((i * 13 % 7) as f32 - 3.0));
        let fit = bg.fit(&h, &m, BINS, FIRST);
        let adj = bg.adjoint(&fit, &h, &m, BINS, FIRST);
        let scale = adj.iter().fold(0.0f32, |a, v| a.max(v.abs()));
        for i in [7, 20, 95, 400, 1001, 36 * BINS - 1] {
            let eps = 1e-2f32;
            let loss = |d: f32| {
                let mut hh = h.clone();
                hh[i] += d;
                bg.fit(&hh, &m, BINS, FIRST).loss
            };
            let fd = (loss(eps) - loss(-eps)) / (2.0 * f64::from(eps));
            assert!(
                (f64::from(adj[i]) - fd).abs() < 2e-3 * f64::from(scale),
                "bin {i}: {} against {fd}",
                adj[i]
            );
        }
        assert_eq!(adj[3], 0.0, "bins before FIRST are not fitted");
    }
}
