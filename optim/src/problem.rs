//! The optimisation problem argmin sees: a parameter vector `θ = [u_x, u_y, u_z, a]`
//! (`u = (I + λL) x` the large-steps coordinates of the vertex positions `x`, one block
//! per axis; `a` the per-vertex values, present when they are fitted) and the cost
//!
//! `C(θ) = loss(x, a) + w ‖L x‖² / (V h²) + w_tv TV(a)`,   `a = clamp(κ a', 0, 1)`
//!
//! (`a'` the values over `κ`) with `loss` from the renderer ([`MeshObjective`]), the
//! smoothness term of [`crate::laplacian`] and the edge-preserving total variation of
//! the values actually used, after the clamp, of [`crate::tv`]
//! (`TV(a) = Σ_e ℓ_e φ(a_i − a_j) / √A`, Charbonnier `φ`; only when the values are
//! fitted). TV's edge lengths `ℓ_e` and area `A` are the stage's template's, fixed for
//! the stage: TV has no position gradient, and a step edge of a given length costs the
//! same at any mesh resolution. The gradient maps back through the parameterisation:
//! `∂C/∂u = (I + λL)⁻¹ ∂C/∂x`, and `∂C/∂a' = κ (∂loss/∂a + w_tv ∂TV/∂a)` inside
//! `[0, 1]` (0 outside, where the clamp holds; [`Project`] keeps the solvers' iterates
//! inside). Cost and gradient are separate calls in argmin; one render serves both (the
//! last evaluation is cached by its exact parameter vector).
//!
//! Deterministic: the CG solves start from fixed guesses (not the previous solution), so
//! the same `θ` gives the same mesh whatever came before it, which resuming relies on.

use crate::laplacian::{join_axes, mean_edge, smoothness, split_axes, Laplacian};
use crate::mesh::Mesh;
use crate::tv::TotalVariation;
use argmin::core::{CostFunction, Error, Gradient};
use std::cell::RefCell;
use std::rc::Rc;

/// The largest coordinate (m, any axis) a fitted vertex may take, whatever the
/// objective's [`MeshObjective::bounds`]: a step that goes further is rejected like a
/// failed render ([`MeshProblem::decode`]). Hidden scenes are metres across; a million
/// metres only comes from a step size many orders of magnitude too large (and beyond
/// it `f32` positions lose their millimetres).
pub const MAX_COORDINATE: f64 = 1e6;

/// How far outside its box a decoded vertex may sit, in m, and still count as inside.
/// A stage starts from the last one's mesh, whose vertices may lie on the box (a step
/// projected onto it); the large-steps round trip `decode(encode(x))` moves them by the
/// conjugate-gradient solve's residual (~1e-11 m). A micrometre is far below any scene's
/// scale and far above that residual.
pub const BOUND_SLACK: f64 = 1e-6;

/// What a renderer gives the fit: the loss of a mesh against the measurement and its
/// gradient.
pub trait MeshObjective {
    /// The loss of `mesh` and its gradient with respect to every vertex position and,
    /// when `mesh.vertex_values` is not empty, every vertex value. An `Err` (bad
    /// geometry, a render that failed) makes the optimiser reject the step.
    fn evaluate(&mut self, mesh: &Mesh) -> Result<Evaluation, String>;

    /// The box (`[min, max]` corners, m) outside which the measurement cannot see a
    /// surface, with a sentence saying what it is; a step that puts a vertex outside it
    /// (or outside the initial mesh's own box, whichever is larger) is rejected before
    /// [`MeshObjective::evaluate`] sees it. `None` (the default): only
    /// [`MAX_COORDINATE`] bounds the vertices.
    fn bounds(&self) -> Option<([[f64; 3]; 2], String)> {
        None
    }

    /// Whether the loss is unchanged when every vertex value is multiplied by one positive
    /// factor (a render linear in albedo, compared through a fitted intensity scale).
    /// Then the values' upper bound is a convention, not a constraint, and a step past it
    /// is projected back by rescaling every value, which leaves the loss as it is, rather
    /// than by clamping the values above it, which flattens the brightest and, with the
    /// scale refitted, lowers the contrast (measured on a chart with a known answer:
    /// bar/board 3.3 with clamping, 4.2 with rescaling, truth 4.5; docs/studies/
    /// chart_truth.md). Default false: clamp.
    fn values_scale_free(&self) -> bool {
        false
    }
}

/// One evaluation of a [`MeshObjective`].
#[derive(Clone, Debug, Default)]
pub struct Evaluation {
    pub loss: f64,
    pub d_vertices: Vec<[f64; 3]>,
    /// Empty unless the mesh has vertex values.
    pub d_values: Vec<f64>,
    /// Whatever the objective wants reported per iteration (e.g. the fitted intensity
    /// scale), as `(name, value)`.
    pub report: Vec<(String, f64)>,
}

/// The regularisation and parameterisation of a stage.
#[derive(Clone, Debug, PartialEq)]
pub struct ProblemSettings {
    /// `λ` of the large-steps operator `I + λ L` (0: plain vertex positions).
    pub large_steps: f64,
    /// Weight `w` of the smoothness term.
    pub laplacian: f64,
    /// Fit the vertex positions (false: they stay at the template's, e.g. an albedo-only
    /// fit on a fixed surface, where the transient is linear in the parameters).
    pub fit_positions: bool,
    /// Fit the per-vertex values (albedo) too.
    pub fit_values: bool,
    /// `κ`: the values enter `θ` as `a / κ`, so an optimiser step of size `η` in `θ`
    /// moves them by `κ η` (albedo wants larger steps than positions in metres).
    pub value_scale: f64,
    /// Weight `w_tv` of the total variation of the values ([`crate::tv`]); used only
    /// when `fit_values` (fixed values add a constant). 0: off.
    pub value_tv: f64,
}

/// The last evaluation, for observers.
#[derive(Clone, Debug, Default)]
pub struct Breakdown {
    pub data_loss: f64,
    /// `w ‖L x‖² / (V h²)`.
    pub smoothness: f64,
    /// `w_tv TV(a)` (0 when off).
    pub value_tv: f64,
    pub report: Vec<(String, f64)>,
}

struct Cache {
    param: Vec<f64>,
    cost: f64,
    grad: Vec<f64>,
}

/// argmin's view of one fitting stage (fixed topology).
pub struct MeshProblem {
    objective: RefCell<Box<dyn MeshObjective>>,
    template: Mesh,
    lap: Laplacian,
    settings: ProblemSettings,
    /// Reference edge length `h` of the smoothness term (the stage's initial mean edge).
    h: f64,
    /// The TV term, when the values are fitted with `value_tv > 0`.
    tv: Option<TotalVariation>,
    cache: RefCell<Option<Cache>>,
    last: Rc<RefCell<Breakdown>>,
    /// Where vertices may go ([`MeshObjective::bounds`] grown to the template's box,
    /// within ±[`MAX_COORDINATE`]) and what that region is.
    bounds: [[f64; 3]; 2],
    bounds_what: String,
}

impl MeshProblem {
    /// The problem for `mesh`'s topology; `mesh` also fixes `h`.
    pub fn new(
        objective: Box<dyn MeshObjective>,
        mesh: &Mesh,
        settings: ProblemSettings,
    ) -> MeshProblem {
        let mut template = mesh.clone();
        if settings.fit_values && template.vertex_values.is_empty() {
            template.vertex_values = vec![1.0; template.vertices.len()];
        }
        let (mut bounds, bounds_what) = objective.bounds().unwrap_or((
            [[-MAX_COORDINATE; 3], [MAX_COORDINATE; 3]],
            format!("the ±{MAX_COORDINATE:e} m any fitted surface may reach"),
        ));
        for p in &mesh.vertices {
            for k in 0..3 {
                bounds[0][k] = bounds[0][k].min(p[k]).max(-MAX_COORDINATE);
                bounds[1][k] = bounds[1][k].max(p[k]).min(MAX_COORDINATE);
            }
        }
        MeshProblem {
            bounds,
            bounds_what,
            objective: RefCell::new(objective),
            lap: Laplacian::new(mesh),
            h: mean_edge(mesh).max(1e-9),
            tv: (settings.fit_values && settings.value_tv > 0.0).then(|| TotalVariation::new(mesh)),
            template,
            settings,
            cache: RefCell::new(None),
            last: Rc::new(RefCell::new(Breakdown::default())),
        }
    }

    pub fn settings(&self) -> &ProblemSettings {
        &self.settings
    }

    /// The breakdown of the last evaluation.
    pub fn last(&self) -> Breakdown {
        self.last.borrow().clone()
    }

    fn value_scale(&self) -> f64 {
        if self.settings.value_scale > 0.0 {
            self.settings.value_scale
        } else {
            1.0
        }
    }

    /// A handle on the breakdown of the last evaluation, for an observer.
    pub fn last_handle(&self) -> Rc<RefCell<Breakdown>> {
        self.last.clone()
    }

    /// Where the value block starts in `θ`.
    fn values_at(&self) -> usize {
        if self.settings.fit_positions {
            3 * self.template.vertices.len()
        } else {
            0
        }
    }

    /// `θ` for `mesh` (same topology as the template).
    pub fn encode(&self, mesh: &Mesh) -> Vec<f64> {
        let n = mesh.vertices.len();
        let mut theta = Vec::with_capacity(4 * n);
        let mut mx = vec![0.0; n];
        let axes = split_axes(&mesh.vertices);
        let positions = if self.settings.fit_positions {
            &axes[..]
        } else {
            &[]
        };
        for x in positions {
            self.lap.apply(x, &mut mx);
            theta.extend(
                x.iter()
                    .zip(&mx)
                    .map(|(x, l)| x + self.settings.large_steps * l),
            );
        }
        if self.settings.fit_values {
            let k = self.value_scale();
            if mesh.vertex_values.len() == n {
                theta.extend(mesh.vertex_values.iter().map(|a| a / k));
            } else {
                theta.extend(self.template.vertex_values.iter().map(|a| a / k));
            }
        }
        theta
    }

    /// The mesh of `θ`: solves `(I + λL) x = u` per axis.
    pub fn decode(&self, theta: &[f64]) -> Result<Mesh, String> {
        let n = self.template.vertices.len();
        let want = self.values_at() + if self.settings.fit_values { n } else { 0 };
        if theta.len() != want {
            return Err(format!(
                "parameter vector has {} values, expected {want}",
                theta.len()
            ));
        }
        if let Some(i) = theta.iter().position(|v| !v.is_finite()) {
            return Err(format!("parameter {i} is not finite"));
        }
        let mut mesh = self.template.clone();
        if self.settings.fit_positions {
            let axes = [0, 1, 2].map(|k| {
                let u = &theta[k * n..(k + 1) * n];
                let mut x = u.to_vec();
                if self.settings.large_steps > 0.0 {
                    self.lap
                        .solve_m(self.settings.large_steps, u, &mut x, 1e-12);
                }
                x
            });
            mesh.vertices = join_axes(&axes);
        }
        if self.settings.fit_values {
            let k = self.value_scale();
            mesh.vertex_values = theta[self.values_at()..]
                .iter()
                .map(|a| (k * a).clamp(0.0, 1.0))
                .collect();
        }
        let [lo, hi] = self.bounds;
        if let Some(i) = mesh.vertices.iter().position(|p| {
            (0..3).any(|k| !(p[k] >= lo[k] - BOUND_SLACK && p[k] <= hi[k] + BOUND_SLACK))
        }) {
            let p = mesh.vertices[i];
            return Err(format!(
                "the step put vertex {i} at ({:.3e}, {:.3e}, {:.3e}) m, outside [{:.3}, {:.3}] x [{:.3}, {:.3}] x [{:.3}, {:.3}] m ({}): the step size (lr) is far too large",
                p[0], p[1], p[2], lo[0], hi[0], lo[1], hi[1], lo[2], hi[2], self.bounds_what
            ));
        }
        Ok(mesh)
    }

    /// Cost and gradient at `θ`, through the cache.
    pub fn evaluate(&self, theta: &[f64]) -> Result<(f64, Vec<f64>), String> {
        if let Some(c) = self.cache.borrow().as_ref() {
            if c.param == theta {
                return Ok((c.cost, c.grad.clone()));
            }
        }
        let mesh = self.decode(theta)?;
        let eval = self.objective.borrow_mut().evaluate(&mesh)?;
        let n = mesh.vertices.len();
        if eval.d_vertices.len() != n
            || (self.settings.fit_values && eval.d_values.len() != n)
            || !eval.loss.is_finite()
        {
            return Err(
                "the objective returned a non-finite loss or a wrong-sized gradient".into(),
            );
        }
        let mut dx = eval.d_vertices.clone();
        let smooth = if self.settings.laplacian > 0.0 {
            let mut g = vec![[0.0; 3]; n];
            let r = smoothness(&self.lap, &mesh.vertices, self.h, &mut g);
            for (d, g) in dx.iter_mut().zip(&g) {
                for k in 0..3 {
                    d[k] += self.settings.laplacian * g[k];
                }
            }
            self.settings.laplacian * r
        } else {
            0.0
        };
        let mut da = eval.d_values.clone();
        let tv = match &self.tv {
            Some(tv) => {
                let mut g = vec![0.0; n];
                let r = tv.evaluate(&mesh.vertex_values, &mut g);
                for (d, g) in da.iter_mut().zip(&g) {
                    *d += self.settings.value_tv * g;
                }
                self.settings.value_tv * r
            }
            None => 0.0,
        };
        let mut grad = Vec::with_capacity(theta.len());
        let axes = split_axes(&dx);
        let positions = if self.settings.fit_positions {
            &axes[..]
        } else {
            &[]
        };
        for axis in positions {
            let mut du = vec![0.0; n];
            if self.settings.large_steps > 0.0 {
                self.lap
                    .solve_m(self.settings.large_steps, axis, &mut du, 1e-12);
            } else {
                du.clone_from(axis);
            }
            grad.extend(du);
        }
        if self.settings.fit_values {
            // a = clamp(κ a', 0, 1): ∂C/∂a' = κ ∂C/∂a inside [0, 1], 0 where the
            // clamp holds (the solvers keep a' inside by `project`).
            let k = self.value_scale();
            let a = &theta[self.values_at()..];
            grad.extend(da.iter().zip(a).map(|(&d, &a)| {
                if (0.0..=1.0).contains(&(k * a)) {
                    k * d
                } else {
                    0.0
                }
            }));
        }
        if grad.iter().any(|g| !g.is_finite()) {
            return Err("the gradient is not finite".into());
        }
        let cost = eval.loss + smooth + tv;
        *self.last.borrow_mut() = Breakdown {
            data_loss: eval.loss,
            smoothness: smooth,
            value_tv: tv,
            report: eval.report,
        };
        *self.cache.borrow_mut() = Some(Cache {
            param: theta.to_vec(),
            cost,
            grad: grad.clone(),
        });
        Ok((cost, grad))
    }
}

/// The feasible set of a problem's parameters, for projected solvers: `project` moves `θ`
/// to the nearest feasible point (in place). The default keeps every `θ`.
pub trait Project {
    fn project(&self, _theta: &mut [f64]) {}
}

impl Project for MeshProblem {
    /// Keeps the value block in `a' ∈ [0, 1/κ]` (albedo in `[0, 1]`): values below 0 are
    /// clamped; values above the top are clamped too, unless the objective's loss is
    /// blind to a common factor ([`MeshObjective::values_scale_free`]), where every value
    /// is first divided by the largest one's excess. A clamped value keeps a live
    /// gradient and can come back.
    fn project(&self, theta: &mut [f64]) {
        if self.settings.fit_values {
            let hi = 1.0 / self.value_scale();
            let rescale = self.objective.borrow().values_scale_free();
            if let Some(values) = theta.get_mut(self.values_at()..) {
                let top = values.iter().copied().fold(0.0f64, f64::max);
                if rescale && top > hi {
                    values.iter_mut().for_each(|a| *a *= hi / top);
                }
                for a in values {
                    *a = a.clamp(0.0, hi);
                }
            }
        }
    }
}

impl CostFunction for MeshProblem {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, theta: &Vec<f64>) -> Result<f64, Error> {
        self.evaluate(theta).map(|(c, _)| c).map_err(Error::msg)
    }
}

impl Gradient for MeshProblem {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, theta: &Vec<f64>) -> Result<Vec<f64>, Error> {
        self.evaluate(theta).map(|(_, g)| g).map_err(Error::msg)
    }
}
