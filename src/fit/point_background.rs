//! A capture's model of everything but the hidden surface (issue 48): a gain field over
//! the scan, a floor (per scan point, or smooth over the scan), and the direct return's tail scaled by each
//! point's own direct counts.
//!
//! `notes/capture-calibration.md` measures it on the Stanford captures: at scan point `p`
//! and bin `t`, with `h = (R ⊗ H)[p, t]` the render through the detector response,
//!
//! `μ[p, t] = g(x_p, y_p) h + f(x_p, y_p) + Σ_k κ_k D_p τ_k[t]`,
//!
//! - `g` the gain, a polynomial of degree ≤ 2 in the scan coordinates (the signal's
//!   level changes over the scan as a smooth ramp, R² 0.83–0.98 in log; its degree-0
//!   term is the intensity scale `s ≥ 0`);
//! - `f` the floor (ambient light and dark counts): a polynomial of degree ≤ 2 over the
//!   scan, or one value per scan point ([`Floor::PerPoint`], [`super::point_floor`]: the
//!   Stanford captures' floor changes from one scan column to the next);
//! - `D_p` the point's direct counts (the wall's own return, summed over its first bins),
//!   `τ_k[t]` decaying exponentials of fixed time constants integrated over bin `t`,
//!   `κ_k ≥ 0`: the direct return's tail, which runs under the signal with an amplitude
//!   proportional to `D_p` (correlation 0.95–0.998).
//!
//! A per-bin background shared by all points leaves 3–13 σ per 128 ps bin there; a floor
//! plus a scaled tail reaches χ²/bin 1.00. `μ` is linear in `β = (g, f, κ)`: the
//! nuisances are fitted in closed form by [`super::linear_fit`] (L2 or Poisson).

use super::linear_fit::{Design, LinearFit, MAX_COLS};

/// The monomials `1, x, y, x², xy, y²` of degree ≤ `degree` (≤ 2).
fn monomials(degree: usize) -> usize {
    [1, 3, 6][degree.min(2)]
}

/// The floor's columns in the design (none for a floor per point, fitted apart).
fn floor_columns(floor: Floor) -> usize {
    match floor {
        Floor::Polynomial(degree) => monomials(degree),
        Floor::PerPoint => 0,
    }
}

fn terms(x: f64, y: f64) -> [f64; 6] {
    [1.0, x, y, x * x, x * y, y * y]
}

/// How the floor varies over the scan.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Floor {
    /// A polynomial of this degree (≤ 2) in the scan coordinates.
    Polynomial(usize),
    /// One value per scan point, profiled out of the fit ([`super::point_floor`]).
    PerPoint,
}

/// The model's fixed inputs, from the capture.
#[derive(Clone, Debug)]
pub struct PointBackground {
    /// `D_p`, per scan point (row of the measurement).
    pub direct: Vec<f64>,
    /// `τ_k[t]` per tail, each per bin.
    pub tails: Vec<Vec<f64>>,
    /// Scan coordinates of each point, scaled to `[-1, 1]`.
    pub coords: Vec<(f64, f64)>,
    pub floor: Floor,
    /// The gain's polynomial degree: 0 (one scale), 1 or 2.
    pub gain_degree: usize,
    /// The scale and the tails' columns (held non-negative).
    nonneg: Vec<usize>,
}

impl PointBackground {
    pub fn new(
        direct: Vec<f64>,
        tails: Vec<Vec<f64>>,
        coords: Vec<(f64, f64)>,
        floor: Floor,
        gain_degree: usize,
    ) -> PointBackground {
        let first_tail = monomials(gain_degree) + floor_columns(floor);
        let nonneg = std::iter::once(0)
            .chain(first_tail..first_tail + tails.len())
            .collect();
        PointBackground {
            direct,
            tails,
            coords,
            floor,
            gain_degree,
            nonneg,
        }
    }

    /// The gain `g(x_p, y_p)` for the coefficients `beta`.
    pub fn gain(&self, beta: &[f64; MAX_COLS], p: usize) -> f64 {
        let (x, y) = self.coords[p];
        terms(x, y)[..monomials(self.gain_degree)]
            .iter()
            .zip(beta)
            .map(|(t, b)| t * b)
            .sum()
    }

    /// The coefficients `beta` by name: `gain_1, gain_x, gain_y, ...` (the gain field's
    /// terms in the scan coordinates scaled to `[-1, 1]`, degree ≤ 2 with `xx, xy, yy`;
    /// `gain_1` is the intensity scale), `floor_1, floor_x, ...` (counts per bin), and
    /// `tail_1, tail_2, ...` (each tail's `κ_k`, in the order of [`Self::tails`]); with
    /// a floor per point, `floor_mean`, `floor_min` and `floor_max` over the points.
    pub fn coefficients(&self, fit: &LinearFit) -> Vec<(String, f64)> {
        const NAMES: [&str; 6] = ["1", "x", "y", "xx", "xy", "yy"];
        let (ng, nf) = (monomials(self.gain_degree), floor_columns(self.floor));
        let gain = NAMES[..ng].iter().map(|n| format!("gain_{n}"));
        let floor = NAMES[..nf].iter().map(|n| format!("floor_{n}"));
        let tails = (1..=self.tails.len()).map(|k| format!("tail_{k}"));
        let mut named: Vec<(String, f64)> = gain
            .chain(floor)
            .chain(tails)
            .zip(fit.beta.iter().copied())
            .collect();
        if self.floor == Floor::PerPoint && !fit.floors.is_empty() {
            let n = fit.floors.len() as f64;
            let (lo, hi) = fit
                .floors
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &f| {
                    (a.min(f), b.max(f))
                });
            named.push(("floor_mean".into(), fit.floors.iter().sum::<f64>() / n));
            named.push(("floor_min".into(), lo));
            named.push(("floor_max".into(), hi));
        }
        named
    }

    /// The background `μ − g h` at `(p, t)` of `fit`.
    pub fn background(&self, fit: &LinearFit, p: usize, t: usize) -> f64 {
        super::linear_fit::mean(self, fit, p, t, 0.0)
    }

    /// The background's mean over the bins `bins` of the points `in_fit` marks (empty:
    /// all): the floor's terms averaged over those points, plus each tail's gain times
    /// the points' mean `D_p` times the tail's mean over `bins` (the background is a sum
    /// of products of a point's and a bin's factor, so its mean is `O(points + bins)`).
    pub fn mean_background(
        &self,
        fit: &LinearFit,
        in_fit: &[bool],
        bins: std::ops::Range<usize>,
    ) -> f64 {
        let points: Vec<usize> = (0..self.coords.len())
            .filter(|&p| in_fit.get(p).copied().unwrap_or(true))
            .collect();
        if points.is_empty() || bins.is_empty() {
            return 0.0;
        }
        let n = points.len() as f64;
        let (ng, nf) = (monomials(self.gain_degree), floor_columns(self.floor));
        let mut mean_terms = [0.0; 6];
        let (mut mean_direct, mut point_floor) = (0.0, 0.0);
        let beta = &fit.beta;
        for &p in &points {
            point_floor += fit.floor(p) / n;
            let (x, y) = self.coords[p];
            mean_terms
                .iter_mut()
                .zip(terms(x, y))
                .for_each(|(m, t)| *m += t / n);
            mean_direct += self.direct[p] / n;
        }
        let floor: f64 = (0..nf).map(|i| beta[ng + i] * mean_terms[i]).sum();
        let tails: f64 = self
            .tails
            .iter()
            .enumerate()
            .map(|(k, tail)| {
                let mean_tail = tail[bins.clone()].iter().sum::<f64>() / bins.len() as f64;
                beta[ng + nf + k] * mean_direct * mean_tail
            })
            .sum();
        floor + point_floor + tails
    }
}

impl Design for PointBackground {
    fn columns(&self) -> usize {
        monomials(self.gain_degree) + floor_columns(self.floor) + self.tails.len()
    }

    fn row(&self, p: usize, t: usize, h: f64, out: &mut [f64; MAX_COLS]) {
        let (x, y) = self.coords[p];
        let m = terms(x, y);
        let (ng, nf) = (monomials(self.gain_degree), floor_columns(self.floor));
        for i in 0..ng {
            out[i] = h * m[i];
        }
        out[ng..ng + nf].copy_from_slice(&m[..nf]);
        for (k, tail) in self.tails.iter().enumerate() {
            out[ng + nf + k] = self.direct[p] * tail[t];
        }
    }

    fn d_render(&self, beta: &[f64; MAX_COLS], p: usize) -> f64 {
        self.gain(beta, p)
    }

    fn nonnegative(&self) -> &[usize] {
        &self.nonneg
    }

    fn floor_column(&self) -> Option<usize> {
        (self.floor != Floor::PerPoint).then(|| monomials(self.gain_degree))
    }

    fn point_floor(&self) -> bool {
        self.floor == Floor::PerPoint
    }
}

/// `τ[t]`: `exp(−o/τ)` of the OPL `o` after the direct return, integrated over bin `t` of
/// width `width` starting at `start` (OPL, m), in units of bins.
pub fn exponential_tail(tau: f64, start: f64, width: f64, bins: usize) -> Vec<f64> {
    (0..bins)
        .map(|t| {
            let a = (start + t as f64 * width).max(0.0);
            let b = (start + (t + 1) as f64 * width).max(0.0);
            tau / width * ((-a / tau).exp() - (-b / tau).exp())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::super::linear_fit::{
        adjoint, fit, model, poisson_counts, Likelihood, LinearFit, Window,
    };
    use super::*;

    const BINS: usize = 40;
    const FIRST: usize = 5;

    /// A 6 x 6 scan: a render of pulses, direct counts varying over the scan, two tails.
    fn setup(gain_degree: usize) -> (PointBackground, Vec<f32>) {
        let coords: Vec<(f64, f64)> = (0..36)
            .map(|p| ((p % 6) as f64 / 2.5 - 1.0, (p / 6) as f64 / 2.5 - 1.0))
            .collect();
        let direct: Vec<f64> = (0..36)
            .map(|p| 100.0 + 30.0 * ((p * 7 % 5) as f64))
            .collect();
        let tails = vec![
            exponential_tail(6.0, 0.0, 1.0, BINS),
            exponential_tail(25.0, 0.0, 1.0, BINS),
        ];
        let render: Vec<f32> = (0..36 * BINS)
            .map(|i| {
                let (p, t) = (i / BINS, i % BINS);
                (-((t as f64 - 15.0 - (p % 4) as f64) / 2.0).powi(2)).exp() as f32 * 20.0
            })
            .collect();
        (
            PointBackground::new(direct, tails, coords, Floor::Polynomial(2), gain_degree),
            render,
        )
    }

    fn window() -> Window<'static> {
        Window {
            bins: BINS,
            first: FIRST,
            in_fit: &[],
        }
    }

    fn measurement(d: &PointBackground, render: &[f32], beta: &[f64]) -> Vec<f32> {
        let mut b = [0.0; MAX_COLS];
        b[..beta.len()].copy_from_slice(beta);
        (0..render.len())
            .map(|i| model(d, &b, i / BINS, i % BINS, f64::from(render[i])) as f32)
            .collect()
    }

    /// Gain 2 + 0.3 x, floor of degree 2, tails 0.003 and 0.0005.
    const TRUTH: [f64; 11] = [
        2.0, 0.3, 0.0, 0.5, 0.1, -0.05, 0.02, 0.01, -0.03, 0.003, 0.0005,
    ];

    #[test]
    fn a_measurement_the_model_can_make_is_fitted_exactly() {
        let (d, h) = setup(1);
        let m = measurement(&d, &h, &TRUTH);
        let f = fit(&d, &h, &m, &window(), Likelihood::L2);
        for (a, b) in f.beta.iter().zip(TRUTH) {
            assert!((a - b).abs() < 1e-4 * b.abs().max(1.0), "{:?}", f.beta);
        }
        assert!(f.loss < 1e-10, "{}", f.loss);
        let p = fit(
            &d,
            &h,
            &m,
            &window(),
            Likelihood::Poisson {
                counts_per_value: 1.0,
            },
        );
        assert!(p.loss < 1e-8, "{}", p.loss);
    }

    #[test]
    fn a_tail_the_data_do_not_hold_stays_at_zero() {
        let (d, h) = setup(0);
        // A negative tail gain is no physics: the fit holds it at 0.
        let m = measurement(&d, &h, &[1.5, 0.4, 0.0, 0.0, 0.0, 0.0, 0.0, -0.002, 0.0]);
        let f = fit(&d, &h, &m, &window(), Likelihood::L2);
        assert_eq!(f.beta[7], 0.0, "{:?}", f.beta);
        assert!(f.beta[0] > 0.0 && f.loss > 0.0, "{:?}", f.beta);
    }

    /// Off the model (so the residual is not zero), counts-like and positive.
    fn perturbed(d: &PointBackground, h: &[f32]) -> Vec<f32> {
        let mut m = measurement(d, h, &TRUTH);
        m.iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v = (*v + 0.3 * ((i * 13 % 7) as f32 - 3.0)).max(0.0).round());
        m
    }

    fn gradient_check(likelihood: Likelihood, in_fit: &[bool]) {
        let (d, h) = setup(2);
        let m = perturbed(&d, &h);
        let win = Window { in_fit, ..window() };
        let f: LinearFit = fit(&d, &h, &m, &win, likelihood);
        assert!(f.loss.is_finite() && f.loss > 0.0, "{f:?}");
        let adj = adjoint(&d, &f, &h, &m, &win, likelihood);
        let scale = adj.iter().fold(0.0f32, |a, v| a.max(v.abs()));
        for i in [7, 20, 95, 400, 1001, 36 * BINS - 1] {
            let eps = 1e-2f32;
            let loss = |e: f32| {
                let mut hh = h.clone();
                hh[i] += e;
                fit(&d, &hh, &m, &win, likelihood).loss
            };
            let fd = (loss(eps) - loss(-eps)) / (2.0 * f64::from(eps));
            assert!(
                (f64::from(adj[i]) - fd).abs() < 2e-3 * f64::from(scale),
                "{likelihood:?} bin {i}: {} against {fd}",
                adj[i]
            );
        }
        assert_eq!(adj[3], 0.0, "bins before FIRST are not fitted");
    }

    #[test]
    fn the_l2_adjoint_is_the_derivative_of_the_minimised_loss() {
        gradient_check(Likelihood::L2, &[]);
    }

    #[test]
    fn the_poisson_adjoint_is_the_derivative_of_the_minimised_deviance() {
        gradient_check(
            Likelihood::Poisson {
                counts_per_value: 4.0,
            },
            &[],
        );
    }

    #[test]
    fn points_left_out_of_the_fit_have_no_gradient() {
        let in_fit: Vec<bool> = (0..36).map(|p| p % 5 != 2).collect();
        gradient_check(
            Likelihood::Poisson {
                counts_per_value: 1.0,
            },
            &in_fit,
        );
        let (d, h) = setup(1);
        let m = perturbed(&d, &h);
        let win = Window {
            in_fit: &in_fit,
            ..window()
        };
        let f = fit(&d, &h, &m, &win, Likelihood::L2);
        let adj = adjoint(&d, &f, &h, &m, &win, Likelihood::L2);
        assert!(adj[2 * BINS..3 * BINS].iter().all(|&v| v == 0.0));
        assert!(adj[BINS..2 * BINS].iter().any(|&v| v != 0.0));
    }

    /// The coefficients are named in the design's column order.
    #[test]
    fn coefficients_are_named_in_column_order() {
        let (pb, _) = setup(1);
        let mut beta = [0.0; MAX_COLS];
        for (i, b) in beta.iter_mut().enumerate() {
            *b = i as f64;
        }
        let named = pb.coefficients(&LinearFit {
            beta,
            loss: 0.0,
            floors: Vec::new(),
        });
        let names: Vec<&str> = named.iter().map(|(n, _)| n.as_str()).collect();
        let mut want = vec!["gain_1", "gain_x", "gain_y"];
        want.extend([
            "floor_1", "floor_x", "floor_y", "floor_xx", "floor_xy", "floor_yy",
        ]);
        let tails: Vec<String> = (1..=pb.tails.len()).map(|k| format!("tail_{k}")).collect();
        want.extend(tails.iter().map(String::as_str));
        assert_eq!(names, want);
        assert!(named.iter().enumerate().all(|(i, (_, v))| *v == i as f64));
        assert_eq!(pb.columns(), named.len());
    }

    #[test]
    fn poisson_counts_of_the_model_reach_a_deviance_of_one_a_bin() {
        let (d, h) = setup(1);
        let mu = measurement(
            &d,
            &h,
            &[5.0, 0.5, 0.0, 20.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.002],
        );
        let counts = poisson_counts(mu.iter().map(|&m| f64::from(m)), 0x2545_f491_4f6c_dd1d);
        let f = fit(
            &d,
            &h,
            &counts,
            &window(),
            Likelihood::Poisson {
                counts_per_value: 1.0,
            },
        );
        // At 20 or more counts a bin the true mean's deviance is close to 1 a bin; the
        // fit's is lower by the parameters it spends (11 of 1260 bins).
        assert!((f.loss - 1.0).abs() < 0.1, "{f:?}");
        assert!((f.beta[0] - 5.0).abs() < 0.5, "{:?}", f.beta);
    }

    #[test]
    fn the_mean_background_is_the_mean_of_the_background() {
        let (d, _) = setup(1);
        let mut beta = [0.0; MAX_COLS];
        beta[..TRUTH.len()].copy_from_slice(&TRUTH);
        let fit = LinearFit {
            beta,
            loss: 0.0,
            floors: Vec::new(),
        };
        let in_fit: Vec<bool> = (0..36).map(|p| p % 4 != 1).collect();
        let (mut sum, mut n) = (0.0, 0.0);
        for p in (0..36).filter(|&p| in_fit[p]) {
            for t in FIRST..BINS {
                sum += d.background(&fit, p, t);
                n += 1.0;
            }
        }
        let mean = d.mean_background(&fit, &in_fit, FIRST..BINS);
        assert!(
            (mean - sum / n).abs() < 1e-12 * (sum / n).abs(),
            "{mean} against {}",
            sum / n
        );
    }
}
