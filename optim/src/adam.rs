//! Adam (Kingma & Ba 2015) as an argmin [`Solver`], for noisy (Monte Carlo) gradients:
//!
//! `m ← β₁ m + (1 − β₁) g`, `v ← β₂ v + (1 − β₂) g²`,
//! `θ ← θ − η m̂ / (√v̂ + ε)`, with `m̂ = m / (1 − β₁ᵗ)`, `v̂ = v / (1 − β₂ᵗ)`.
//!
//! Each iteration evaluates the new `θ` before accepting it (the cost argmin records
//! belongs to the parameter it records). A step whose evaluation fails or is not
//! finite (a NaN vertex, a render error) is rejected: `θ` stays, `η` halves, and the
//! step is retried, up to [`Adam::max_retries`] times, then the run ends with an error
//! giving the last step's reason (e.g. a vertex beyond
//! [`crate::problem::MAX_COORDINATE`]: a step size far too large). Each candidate is projected onto
//! the feasible set first ([`Project`]: albedo in its bounds; projected gradient descent). The moments are not updated by
//! a rejected step. The whole struct serialises, so checkpoints resume exactly.

use crate::step::{evaluate, start, take_point, Objective, State};
use argmin::core::{Error, Problem, Solver, State as _, KV};
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Adam {
    /// Step size `η` (units of the parameters).
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    /// Halvings of `η` tried before a failed step ends the run with an error.
    pub max_retries: u32,
    /// Steps rejected so far.
    pub rejected: u64,
    m: Vec<f64>,
    v: Vec<f64>,
    t: i32,
}

impl Adam {
    pub fn new(lr: f64) -> Adam {
        Adam {
            lr,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            max_retries: 12,
            rejected: 0,
            m: Vec::new(),
            v: Vec::new(),
            t: 0,
        }
    }
}

impl<O: Objective> Solver<O, State> for Adam {
    fn name(&self) -> &str {
        "Adam"
    }

    fn init(
        &mut self,
        problem: &mut Problem<O>,
        state: State,
    ) -> Result<(State, Option<KV>), Error> {
        let state = start(problem, state, "Adam")?;
        let n = state.get_param().map_or(0, |t| t.len());
        self.m = vec![0.0; n];
        self.v = vec![0.0; n];
        Ok((state, None))
    }

    fn next_iter(
        &mut self,
        problem: &mut Problem<O>,
        mut state: State,
    ) -> Result<(State, Option<KV>), Error> {
        let (theta, g) = take_point(&mut state, "Adam")?;
        let t = self.t + 1;
        let (b1, b2) = (self.beta1, self.beta2);
        let m: Vec<f64> = self
            .m
            .iter()
            .zip(&g)
            .map(|(m, g)| b1 * m + (1.0 - b1) * g)
            .collect();
        let v: Vec<f64> = self
            .v
            .iter()
            .zip(&g)
            .map(|(v, g)| b2 * v + (1.0 - b2) * g * g)
            .collect();
        let (c1, c2) = (1.0 - b1.powi(t), 1.0 - b2.powi(t));
        let direction: Vec<f64> = m
            .iter()
            .zip(&v)
            .map(|(m, v)| (m / c1) / ((v / c2).sqrt() + self.eps))
            .collect();
        let mut rejected_now = 0;
        loop {
            let mut candidate: Vec<f64> = theta
                .iter()
                .zip(&direction)
                .map(|(x, d)| x - self.lr * d)
                .collect();
            if let Some(p) = problem.problem.as_ref() {
                p.project(&mut candidate);
            }
            let why = match evaluate(problem, &candidate) {
                Ok((cost, grad)) => {
                    (self.m, self.v, self.t) = (m, v, t);
                    let kv = argmin::kv!("lr" => self.lr; "rejected" => rejected_now;);
                    return Ok((state.param(candidate).cost(cost).gradient(grad), Some(kv)));
                }
                Err(why) => why,
            };
            self.rejected += 1;
            rejected_now += 1;
            if rejected_now > self.max_retries {
                return Err(Error::msg(format!(
                    "Adam: {rejected_now} steps in a row failed, the step size halved down to {:e} (the last: {why})",
                    self.lr
                )));
            }
            self.lr *= 0.5;
        }
    }
}

impl crate::checkpoint::CheckFinite for Adam {
    fn non_finite(&self) -> Option<String> {
        use crate::checkpoint::first_non_finite;
        first_non_finite("Adam step size", &[self.lr])
            .or_else(|| first_non_finite("Adam first moment", &self.m))
            .or_else(|| first_non_finite("Adam second moment", &self.v))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::Project;
    use argmin::core::{CostFunction, Executor, Gradient};

    /// A quadratic bowl that returns NaN for x[0] > 2.
    struct Bowl;
    impl CostFunction for Bowl {
        type Param = Vec<f64>;
        type Output = f64;
        fn cost(&self, x: &Vec<f64>) -> Result<f64, Error> {
            Ok(if x[0] > 2.0 {
                f64::NAN
            } else {
                (x[0] - 1.5).powi(2) + 3.0 * (x[1] + 0.5).powi(2)
            })
        }
    }
    impl Project for Bowl {}
    impl Gradient for Bowl {
        type Param = Vec<f64>;
        type Gradient = Vec<f64>;
        fn gradient(&self, x: &Vec<f64>) -> Result<Vec<f64>, Error> {
            Ok(vec![2.0 * (x[0] - 1.5), 6.0 * (x[1] + 0.5)])
        }
    }

    #[test]
    fn converges_and_rejects_nan_steps() {
        // Large steps overshoot into the NaN region: they must be rejected, not taken.
        let res = Executor::new(Bowl, Adam::new(3.0))
            .configure(|s| s.param(vec![0.0, 0.0]).max_iters(400))
            .run()
            .unwrap();
        let x = res.state.best_param.clone().unwrap();
        assert!(
            (x[0] - 1.5).abs() < 1e-3 && (x[1] + 0.5).abs() < 1e-3,
            "{x:?}"
        );
        assert!(res.solver.rejected > 0, "no step was rejected");
        assert!(res.solver.lr < 3.0);
    }
}
