//! What the fit's two solvers ([`crate::Adam`], [`crate::Lbfgs`]) share: the bound on
//! the problems they solve, one guarded evaluation, and the initial state.

use crate::problem::Project;
use argmin::core::{CostFunction, Error, Gradient, IterState, Problem, State as _};

pub(crate) type State = IterState<Vec<f64>, Vec<f64>, (), (), (), f64>;

/// A problem with a cost, its gradient and a feasible set, over `Vec<f64>`.
pub trait Objective:
    CostFunction<Param = Vec<f64>, Output = f64>
    + Gradient<Param = Vec<f64>, Gradient = Vec<f64>>
    + Project
{
}

impl<T> Objective for T where
    T: CostFunction<Param = Vec<f64>, Output = f64>
        + Gradient<Param = Vec<f64>, Gradient = Vec<f64>>
        + Project
{
}

/// Cost and gradient at `theta`, or the reason (the renderer's own message) when either
/// fails or is not finite.
pub(crate) fn evaluate<O: Objective>(
    problem: &mut Problem<O>,
    theta: &Vec<f64>,
) -> Result<(f64, Vec<f64>), String> {
    let cost = problem.cost(theta).map_err(|e| e.to_string())?;
    let grad = problem.gradient(theta).map_err(|e| e.to_string())?;
    if !cost.is_finite() {
        return Err(format!("the loss is {cost}"));
    }
    if let Some(i) = grad.iter().position(|g| !g.is_finite()) {
        return Err(format!("gradient entry {i} is {}", grad[i]));
    }
    Ok((cost, grad))
}

/// The state's initial parameters projected onto the feasible set and evaluated; an
/// error naming `solver` if there are none or the evaluation fails.
pub(crate) fn start<O: Objective>(
    problem: &mut Problem<O>,
    state: State,
    solver: &str,
) -> Result<State, Error> {
    let mut theta = state
        .get_param()
        .ok_or_else(|| Error::msg(format!("{solver} needs an initial parameter vector")))?
        .clone();
    if let Some(p) = problem.problem.as_ref() {
        p.project(&mut theta);
    }
    let (cost, grad) = evaluate(problem, &theta)
        .map_err(|why| Error::msg(format!("the initial mesh cannot be evaluated: {why}")))?;
    Ok(state.param(theta).cost(cost).gradient(grad))
}

/// The state's parameters and gradient, taken out of it (the state keeps its cost).
pub(crate) fn take_point(state: &mut State, solver: &str) -> Result<(Vec<f64>, Vec<f64>), Error> {
    let theta = state
        .take_param()
        .ok_or_else(|| Error::msg(format!("{solver}: no parameter vector in the state")))?;
    let g = state
        .take_gradient()
        .ok_or_else(|| Error::msg(format!("{solver}: no gradient in the state")))?;
    Ok((theta, g))
}
