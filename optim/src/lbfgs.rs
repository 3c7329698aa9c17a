//! L-BFGS (Nocedal 1980; Nocedal & Wright, *Numerical Optimization*, alg. 7.4 and 7.5)
//! as an argmin [`Solver`], for the noise-free `tri3` model, with a projected Armijo
//! backtracking line search whose cost is bounded.
//!
//! Direction: `d = −H g`, `H` the two-loop recursion over the last `memory` pairs
//! `(s, y) = (θₖ₊₁ − θₖ, gₖ₊₁ − gₖ)`, scaled by `γ = s·y / y·y` of the newest pair; a
//! pair with `s·y ≤ 0` is not stored (it would break the positive-definiteness of `H`),
//! and a `d` that is not a descent direction resets the memory (`d = −g`).
//!
//! Line search along the projected path `θ(α) = P(θ + α d)` ([`Project`]: albedo kept in
//! its bounds): accept the first `α` with the Armijo condition
//!
//! `C(θ(α)) ≤ C(θ) + c₁ g·(θ(α) − θ)`,
//!
//! starting at `α = 1` (the first iteration, with no curvature yet, at a step whose
//! largest component is `first_step`; no step moves any component by more than
//! `max_step`), backtracking by the minimiser of the quadratic through `C(θ)`, the
//! slope and `C(θ(α))`, kept within `[0.1 α, 0.5 α]`.
//!
//! Why not argmin's L-BFGS with Moré–Thuente: that line search has no cap on evaluations
//! (a 32 x 32 fit spent 165 s on 3 iterations), and when it fails argmin's L-BFGS returns
//! without its problem (`argmin lost the problem`). Here:
//! - at most `max_evals` evaluations per iteration (each one render and one adjoint);
//! - an evaluation that fails or is not finite (a render error, a NaN vertex) counts as
//!   rejected and shrinks the step tenfold, like [`crate::Adam`]'s rejected steps;
//! - a search that finds no Armijo point takes the best point it evaluated if that is
//!   lower, otherwise retries once along `−g` with the memory cleared, and otherwise ends
//!   the stage (`SolverExit`) at the current parameters: no error, nothing lost;
//! - but a search none of whose evaluations succeeded (after the retry) is an error
//!   carrying the last reason: every trial point, down to a thousand-billionth of the
//!   first step, failed, which a step size many orders too large does (`lr = 1e300`: the
//!   vertices beyond [`crate::problem::MAX_COORDINATE`]), and ending the stage quietly
//!   there would pass the initial mesh off as a fit.
//!
//! The whole struct serialises, so checkpoints resume exactly.

use crate::step::{evaluate, start, take_point, Objective, State};
use argmin::core::{Error, Problem, Solver, State as _, TerminationReason, KV};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Lbfgs {
    /// Curvature pairs kept.
    pub memory: usize,
    /// Largest component of the first iteration's trial step (units of the parameters).
    pub first_step: f64,
    /// Largest component of any trial step.
    pub max_step: f64,
    /// Armijo's sufficient-decrease constant.
    pub c1: f64,
    /// Evaluations per line search (then the fallbacks above).
    pub max_evals: u32,
    /// Evaluations so far (all iterations).
    pub evaluations: u64,
    /// Evaluations that failed or were not finite.
    pub rejected: u64,
    s: VecDeque<Vec<f64>>,
    y: VecDeque<Vec<f64>>,
}

impl Lbfgs {
    /// L-BFGS whose first step moves no parameter by more than `first_step`.
    pub fn new(first_step: f64) -> Lbfgs {
        let first_step = if first_step > 0.0 { first_step } else { 0.01 };
        Lbfgs {
            memory: 7,
            first_step,
            max_step: 20.0 * first_step,
            c1: 1e-4,
            max_evals: 12,
            evaluations: 0,
            rejected: 0,
            s: VecDeque::new(),
            y: VecDeque::new(),
        }
    }

    /// `−H g` by the two-loop recursion.
    fn direction(&self, g: &[f64]) -> Vec<f64> {
        let mut q = g.to_vec();
        let mut alpha = vec![0.0; self.s.len()];
        for (i, (s, y)) in self.s.iter().zip(&self.y).enumerate().rev() {
            let a = dot(s, &q) / dot(y, s);
            axpy(-a, y, &mut q);
            alpha[i] = a;
        }
        if let (Some(s), Some(y)) = (self.s.back(), self.y.back()) {
            let gamma = dot(s, y) / dot(y, y);
            q.iter_mut().for_each(|v| *v *= gamma);
        }
        for (i, (s, y)) in self.s.iter().zip(&self.y).enumerate() {
            let b = dot(y, &q) / dot(y, s);
            axpy(alpha[i] - b, s, &mut q);
        }
        q.iter_mut().for_each(|v| *v = -*v);
        q
    }

    fn remember(&mut self, s: Vec<f64>, y: Vec<f64>) {
        let sy = dot(&s, &y);
        if sy > 1e-12 * norm(&s) * norm(&y) && sy > 0.0 {
            if self.s.len() == self.memory {
                self.s.pop_front();
                self.y.pop_front();
            }
            self.s.push_back(s);
            self.y.push_back(y);
        }
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

fn norm(a: &[f64]) -> f64 {
    dot(a, a).sqrt()
}

fn axpy(a: f64, x: &[f64], y: &mut [f64]) {
    y.iter_mut().zip(x).for_each(|(y, x)| *y += a * x);
}

fn max_abs(a: &[f64]) -> f64 {
    a.iter().fold(0.0, |m, v| m.max(v.abs()))
}

/// An evaluated point of the line search.
struct Point {
    theta: Vec<f64>,
    cost: f64,
    grad: Vec<f64>,
}

/// What one line search found.
enum Search {
    /// An Armijo point.
    Accepted(Point),
    /// No Armijo point; the lowest point evaluated, if any was finite.
    Failed(Option<Point>),
    /// Every evaluation failed or was not finite: the last reason.
    Rejected(String),
}

impl Lbfgs {
    /// The projected Armijo search from `theta` (cost `cost`, gradient `g`) along `d`.
    fn search<O: Objective>(
        &mut self,
        problem: &mut Problem<O>,
        theta: &[f64],
        cost: f64,
        g: &[f64],
        d: &[f64],
    ) -> Search {
        let d_max = max_abs(d);
        if d_max == 0.0 || !d_max.is_finite() {
            return Search::Failed(None);
        }
        let mut alpha = if self.s.is_empty() {
            self.first_step / d_max
        } else {
            1.0_f64.min(self.max_step / d_max)
        };
        let mut best: Option<Point> = None;
        let mut finite = 0;
        let mut why = String::new();
        for _ in 0..self.max_evals {
            let mut trial: Vec<f64> = theta.iter().zip(d).map(|(x, d)| x + alpha * d).collect();
            if let Some(p) = problem.problem.as_ref() {
                p.project(&mut trial);
            }
            let step: Vec<f64> = trial.iter().zip(theta).map(|(t, x)| t - x).collect();
            let slope = dot(g, &step); // g·(θ(α) − θ), negative along a descent path
            self.evaluations += 1;
            let (c, grad) = match evaluate(problem, &trial) {
                Ok(point) => point,
                Err(e) => {
                    self.rejected += 1;
                    why = e;
                    alpha *= 0.1;
                    continue;
                }
            };
            finite += 1;
            if c <= cost + self.c1 * slope && slope < 0.0 {
                return Search::Accepted(Point {
                    theta: trial,
                    cost: c,
                    grad,
                });
            }
            // Minimiser of the quadratic q(t) = cost + slope t + (c − cost − slope) t²
            // on t ∈ [0, 1] (t = fraction of the current α), kept in [0.1, 0.5].
            let curvature = c - cost - slope;
            let t = if curvature > 0.0 && slope < 0.0 {
                (-slope / (2.0 * curvature)).clamp(0.1, 0.5)
            } else {
                0.5
            };
            if best.as_ref().is_none_or(|b| c < b.cost) {
                best = Some(Point {
                    theta: trial,
                    cost: c,
                    grad,
                });
            }
            alpha *= t;
        }
        if finite == 0 && self.max_evals > 0 {
            return Search::Rejected(format!(
                "all {} evaluations of the line search failed, the last at a step of {:e} (the last: {why})",
                self.max_evals,
                alpha * 10.0 * d_max
            ));
        }
        Search::Failed(best)
    }
}

impl<O: Objective> Solver<O, State> for Lbfgs {
    fn name(&self) -> &str {
        "L-BFGS (projected Armijo, capped)"
    }

    fn init(
        &mut self,
        problem: &mut Problem<O>,
        state: State,
    ) -> Result<(State, Option<KV>), Error> {
        self.evaluations += 1;
        Ok((start(problem, state, "L-BFGS")?, None))
    }

    fn next_iter(
        &mut self,
        problem: &mut Problem<O>,
        mut state: State,
    ) -> Result<(State, Option<KV>), Error> {
        let (theta, g) = take_point(&mut state, "L-BFGS")?;
        let cost = state.get_cost();
        let evals_before = self.evaluations;
        let mut d = self.direction(&g);
        if dot(&d, &g) >= 0.0 {
            self.s.clear();
            self.y.clear();
            d = g.iter().map(|v| -v).collect();
        }
        let mut found = self.search(problem, &theta, cost, &g, &d);
        if matches!(found, Search::Failed(_) | Search::Rejected(_)) {
            let lower = matches!(&found, Search::Failed(Some(b)) if b.cost < cost);
            if !lower && !self.s.is_empty() {
                // Retry along −g with the curvature memory cleared.
                self.s.clear();
                self.y.clear();
                let d: Vec<f64> = g.iter().map(|v| -v).collect();
                found = self.search(problem, &theta, cost, &g, &d);
            }
        }
        let next = match found {
            Search::Accepted(p) => p,
            Search::Failed(Some(p)) if p.cost < cost => p,
            Search::Rejected(why) => return Err(Error::msg(format!("L-BFGS: {why}"))),
            Search::Failed(_) => {
                let kv = argmin::kv!("evaluations" => self.evaluations - evals_before;);
                return Ok((
                    state.param(theta).cost(cost).gradient(g).terminate_with(
                        TerminationReason::SolverExit("the line search found no lower cost".into()),
                    ),
                    Some(kv),
                ));
            }
        };
        let s: Vec<f64> = next.theta.iter().zip(&theta).map(|(a, b)| a - b).collect();
        let y: Vec<f64> = next.grad.iter().zip(&g).map(|(a, b)| a - b).collect();
        self.remember(s, y);
        let kv = argmin::kv!("evaluations" => self.evaluations - evals_before;);
        Ok((
            state.param(next.theta).cost(next.cost).gradient(next.grad),
            Some(kv),
        ))
    }
}

impl crate::checkpoint::CheckFinite for Lbfgs {
    fn non_finite(&self) -> Option<String> {
        use crate::checkpoint::first_non_finite;
        first_non_finite("L-BFGS step bounds", &[self.first_step, self.max_step]).or_else(|| {
            self.s
                .iter()
                .chain(&self.y)
                .find_map(|v| first_non_finite("L-BFGS curvature pair", v))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::Project;
    use argmin::core::{CostFunction, Executor, Gradient};

    /// Rosenbrock's valley, NaN beyond `x[0] > nan_above`, and a box `x[1] ≤ y_max` (by
    /// projection) for the constrained test.
    struct Rosen {
        nan_above: f64,
        y_max: f64,
    }
    impl CostFunction for Rosen {
        type Param = Vec<f64>;
        type Output = f64;
        fn cost(&self, x: &Vec<f64>) -> Result<f64, Error> {
            if x[0] > self.nan_above {
                return Ok(f64::NAN);
            }
            Ok((1.0 - x[0]).powi(2) + 100.0 * (x[1] - x[0] * x[0]).powi(2))
        }
    }
    impl Gradient for Rosen {
        type Param = Vec<f64>;
        type Gradient = Vec<f64>;
        fn gradient(&self, x: &Vec<f64>) -> Result<Vec<f64>, Error> {
            let t = x[1] - x[0] * x[0];
            Ok(vec![-2.0 * (1.0 - x[0]) - 400.0 * x[0] * t, 200.0 * t])
        }
    }
    impl Project for Rosen {
        fn project(&self, theta: &mut [f64]) {
            theta[1] = theta[1].min(self.y_max);
        }
    }

    fn run(problem: Rosen, first_step: f64, iters: u64) -> (Vec<f64>, Lbfgs, u64, String) {
        let res = Executor::new(problem, Lbfgs::new(first_step))
            .configure(|s| s.param(vec![-1.2, 1.0]).max_iters(iters))
            .run()
            .unwrap();
        let reason = res.state.termination_status.to_string();
        (
            res.state.best_param.clone().unwrap(),
            res.solver,
            res.state.iter,
            reason,
        )
    }

    #[test]
    fn minimises_rosenbrock() {
        let (x, solver, iters, _) = run(
            Rosen {
                nan_above: f64::INFINITY,
                y_max: f64::INFINITY,
            },
            0.1,
            200,
        );
        assert!(
            (x[0] - 1.0).abs() < 1e-5 && (x[1] - 1.0).abs() < 1e-5,
            "{x:?}"
        );
        // Capped: never more than max_evals (two searches) per iteration.
        assert!(solver.evaluations <= 1 + iters * 2 * solver.max_evals as u64);
        assert_eq!(solver.rejected, 0);
    }

    #[test]
    fn rejects_non_finite_points_and_stays_finite() {
        // Large first steps land in the NaN half-plane x > 1.02: rejected, not taken.
        let (x, solver, _, _) = run(
            Rosen {
                nan_above: 1.02,
                y_max: f64::INFINITY,
            },
            5.0,
            300,
        );
        assert!(solver.rejected > 0, "no evaluation was rejected");
        assert!(x.iter().all(|v| v.is_finite()) && x[0] <= 1.02, "{x:?}");
        assert!((x[0] - 1.0).abs() < 1e-4, "{x:?}");
    }

    #[test]
    fn projection_keeps_the_bound_and_finds_the_constrained_minimum() {
        // With y ≤ 0.5 the minimum is on the bound: y = 0.5, x = argmin (1−x)² +
        // 100 (0.5 − x²)², near 0.7071.
        let (x, _, _, _) = run(
            Rosen {
                nan_above: f64::INFINITY,
                y_max: 0.5,
            },
            0.1,
            300,
        );
        assert!(x[1] <= 0.5, "{x:?}");
        let f = |x: f64| (1.0 - x).powi(2) + 100.0 * (0.5 - x * x).powi(2);
        let (mut lo, mut hi) = (0.5, 1.0);
        for _ in 0..200 {
            let (a, b) = (lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0);
            if f(a) < f(b) {
                hi = b
            } else {
                lo = a
            }
        }
        assert!(
            (x[0] - lo).abs() < 1e-4 && (x[1] - 0.5).abs() < 1e-9,
            "{x:?} vs {lo}"
        );
    }

    #[test]
    fn ends_cleanly_at_a_minimum() {
        // Far more iterations than needed: the search stops finding decrease and the
        // solver ends the run (no error, parameters kept).
        let (x, _, iters, reason) = run(
            Rosen {
                nan_above: f64::INFINITY,
                y_max: f64::INFINITY,
            },
            0.1,
            10_000,
        );
        assert!((x[0] - 1.0).abs() < 1e-6, "{x:?}");
        assert!(iters < 10_000, "ran all iterations");
        assert!(reason.contains("no lower cost"), "{reason}");
    }
}
