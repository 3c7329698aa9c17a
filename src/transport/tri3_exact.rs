//! The `tri3` model of one (measurement, sub-triangle) pair written once over [`Real`],
//! the oracle of the eight-lane kernels: in `f64` it is the reference that the `f32`
//! render ([`super::tri3_kernel`]) is tested against; in [`Dual`] numbers with respect to
//! the original triangle's corners and corner albedos it is the model's exact derivative,
//! the reference of the `f32` adjoint ([`super::tri3_adjoint`]).
//!
//! Same equations as the kernel (module doc of [`super::tri3`]): corners of the
//! sub-triangle at barycentrics `β` of the original triangle `(v0, v1, v2)`, OPL
//! `τ_i = |x_l − v_i| + |v_i − x_s| + legs`, corner weight
//! `w_i = (ρ_i/π) |p_l p_s| c_l c_s / (r_l² r_s²)²` (`p` the plane terms, `c` the wall
//! terms; retroreflective: `(ρ_i/π) |p_l| c_l / r_l⁴ · 1 m²`, the return leg's geometric
//! factor replaced by a constant), the area of the sub-triangle, the curvature shift `0.75 (τ(c) − mean τ_i)`,
//! and the pulse through the film's kernel ([`Film::triangle_bins`]).

use super::mc3::{TriParams, TRI_PARAMS};
use super::tri3::Tri3Mesh;
use super::MeasurementCtx;
use crate::adjoint::dual::{self, Dual, Real};
use crate::film::Film;
use std::f64::consts::FRAC_1_PI;

/// Derivatives with respect to the original triangle's [`TRI_PARAMS`], in `f64`.
pub type TriDual64 = Dual<f64, TRI_PARAMS>;

/// Sub-triangle `k` of `mesh` for the measurement `ctx`, whose original triangle is
/// `parent`: calls `add(bin, content)` for every bin its pulse reaches, unscaled by the
/// laser power and the wall's BRDF (`ctx.power f_wall²`, applied by the caller).
/// Visibility is the caller's.
pub fn pair_bins<R: Real>(
    mesh: &Tri3Mesh,
    k: usize,
    parent: &Parent<R>,
    ctx: &MeasurementCtx,
    film: &Film,
    add: impl FnMut(usize, R),
) {
    if let Some((tau, w, area)) = pair_pulse(mesh, k, parent, ctx) {
        film.triangle_bins(tau, w, area, add);
    }
}

/// An original triangle with its unit normal and area, which every sub-triangle and
/// measurement share (computed once per gradient, not per pair).
pub struct Parent<R> {
    pub params: TriParams<R>,
    pub n: dual::V3<R>,
    pub area: R,
}

impl<R: Real> Parent<R> {
    pub fn new(params: TriParams<R>) -> Self {
        let (n, area) = params.normal_area();
        Parent { params, n, area }
    }
}

/// The pulse of sub-triangle `k` ([`pair_bins`]): corner OPLs with the curvature shift
/// (m), corner weights and area; `None` where it reflects nothing.
pub fn pair_pulse<R: Real>(
    mesh: &Tri3Mesh,
    k: usize,
    parent: &Parent<R>,
    ctx: &MeasurementCtx,
) -> Option<([R; 3], [R; 3], R)> {
    let (n, parent_area, parent) = (parent.n, parent.area, &parent.params);
    let corner_bary = mesh.corner_bary[k];
    let (x_l, x_s) = (dual::constant::<R>(ctx.x_l), dual::constant::<R>(ctx.x_s));
    let n_w = dual::constant::<R>(ctx.n_w);
    let legs = R::c((ctx.opl_laser_leg(ctx.x_l) + ctx.opl_sensor_leg) as f64);
    // The plane terms r cos θ at x, the same at every point of the (planar) triangle.
    let p_l = dual::dot(n, dual::sub(x_l, parent.v[0]));
    let p_s = dual::dot(n, dual::sub(x_s, parent.v[0]));
    let facing = if parent.two_sided {
        p_l.v() * p_s.v() > 0.0
    } else {
        p_l.v() > 0.0 && p_s.v() > 0.0
    };
    if !facing {
        return None;
    }
    // Retroreflective (confocal): the return leg's p_s c_s / r_s⁴ is the constant 1/m².
    let plane = if parent.retro {
        p_l.abs()
    } else {
        (p_l * p_s).abs()
    };
    let mut tau = [R::c(0.0); 3];
    let mut w = [R::c(0.0); 3];
    // Corner by corner (large dual arrays are not built: their copies dominated).
    for i in 0..3 {
        let corner = parent.point(corner_bary[i]);
        let (d_l, d_s) = (dual::sub(x_l, corner), dual::sub(x_s, corner));
        let (r2_l, r2_s) = (dual::dot(d_l, d_l), dual::dot(d_s, d_s));
        tau[i] = r2_l.sqrt() + r2_s.sqrt() + legs;
        let (c_l, c_s) = (-dual::dot(n_w, d_l), -dual::dot(n_w, d_s));
        if c_l.v() > 0.0 && c_s.v() > 0.0 {
            let brdf = parent.albedo_at(corner_bary[i]).s(FRAC_1_PI);
            w[i] = if parent.retro {
                // The sheeting's angular falloff, cos^m θ_l = (|p_l| / r_l)^m.
                let m = f64::from(parent.retro_falloff);
                let falloff = if m > 0.0 {
                    (p_l.abs() / r2_l.sqrt()).powc(m)
                } else {
                    R::c(1.0)
                };
                brdf * plane * c_l / (r2_l * r2_l) * falloff
            } else {
                let r4 = r2_l * r2_s;
                brdf * plane * c_l * c_s / (r4 * r4)
            };
        }
    }
    if w.iter().all(|w| w.v() <= 0.0) {
        return None;
    }
    // The sub-triangle's corners are affine in the parent's: its area is the parent's
    // times the (fixed) area of its barycentric triangle.
    let [b0, b1, b2] = corner_bary.map(|b| b.map(f64::from));
    let ratio = ((b1[0] - b0[0]) * (b2[1] - b0[1]) - (b1[1] - b0[1]) * (b2[0] - b0[0])).abs();
    let area = parent_area.s(ratio);
    let third = 1.0 / 3.0;
    // The centroid, at the mean of the corners' barycentrics (kept in f64: the shift is a
    // small difference of OPLs).
    let (c1, c2) = (
        (b0[0] + b1[0] + b2[0]) * third,
        (b0[1] + b1[1] + b2[1]) * third,
    );
    let v = &parent.v;
    let centroid: dual::V3<R> =
        std::array::from_fn(|a| v[0][a].s(1.0 - c1 - c2) + v[1][a].s(c1) + v[2][a].s(c2));
    let tau_c =
        dual::length(dual::sub(x_l, centroid)) + dual::length(dual::sub(x_s, centroid)) + legs;
    let shift = (tau_c - (tau[0] + tau[1] + tau[2]).s(third)).s(0.75);
    Some((tau.map(|t| t + shift), w, area))
}

impl TriParams<f64> {
    /// The original triangle `t` in `f64` constants.
    pub fn constant64(t: &crate::geometry::HiddenTri) -> Self {
        TriParams {
            v: t.v.map(|v| v.to_array().map(f64::from)),
            albedo: t.albedo.map(f64::from),
            two_sided: t.two_sided,
            retro: t.retro,
            retro_falloff: t.retro_falloff,
        }
    }
}

/// The `tri3` transient of measurement `ctx` in `f64` through [`pair_bins`] (the
/// reference for the eight-lane kernel): the same model, slower, without its `f32`
/// rounding. Adds into `hist` (`bins` values).
pub fn render_measurement(
    mesh: &Tri3Mesh,
    ctx: &MeasurementCtx,
    film: &Film,
    visibility: crate::scene::Visibility,
    hist: &mut [f64],
) {
    let mut parents = Vec::new();
    mesh.parent_visibility(visibility, &mut parents);
    let scale = ctx.three_bounce_constant() as f64;
    // A Gaussian far wider than the bins goes through its cells, as in the render
    // ([`Film::cells`]): the reference is of the model as rendered.
    let cells = film.cells();
    let mut cell_mass = vec![0.0; cells.as_ref().map_or(0, |c| c.bins)];
    let (binned, out) = match &cells {
        Some(c) => (c, &mut cell_mass[..]),
        None => (film, &mut hist[..]),
    };
    for k in 0..mesh.len() {
        if mesh.visible(k, ctx, visibility, &parents) {
            let parent = Parent::new(TriParams::constant64(
                &ctx.geom.hidden[mesh.parent[k] as usize],
            ));
            pair_bins(mesh, k, &parent, ctx, binned, |b, v: f64| {
                out[b] += scale * v
            });
        }
    }
    if let Some(c) = &cells {
        film.blur_cells(c, 0, cell_mass, 1.0, hist);
    }
}

/// The `tri3` adjoint of measurement `ctx`: adds `Σ_b adjoint_b dH_b/dθ` for every
/// original triangle's local parameters θ (corners, corner albedos) into `tri_grad`, in
/// `f64`, one pair at a time: the pulse's inputs in dual numbers ([`pair_pulse`]), the
/// pulse reversed ([`Film::triangle_bins_reverse`]), chained by the inputs' derivatives.
/// The oracle the lane kernel (`tri3_adjoint`) is tested against. `parents`: every hidden
/// triangle with its corners and albedos as variables.
#[allow(clippy::too_many_arguments)]
pub fn adjoint_measurement(
    mesh: &Tri3Mesh,
    parents: &[Parent<TriDual64>],
    ctx: &MeasurementCtx,
    film: &Film,
    visibility: crate::scene::Visibility,
    adjoint: &[f32],
    tri_grad: &mut [[f64; TRI_PARAMS]],
) {
    let mut seen = Vec::new();
    mesh.parent_visibility(visibility, &mut seen);
    let scale = ctx.three_bounce_constant() as f64;
    for k in 0..mesh.len() {
        if !mesh.visible(k, ctx, visibility, &seen) {
            continue;
        }
        let p = mesh.parent[k] as usize;
        let Some((tau, w, area)) = pair_pulse(mesh, k, &parents[p], ctx) else {
            continue;
        };
        let g = film.triangle_bins_reverse(tau.map(|t| t.v), w.map(|w| w.v), area.v, |b| {
            adjoint[b] as f64 * scale
        });
        for (g, input) in g.iter().zip(tau.iter().chain(&w).chain([&area])) {
            for (acc, d) in tri_grad[p].iter_mut().zip(input.d) {
                *acc += g * d;
            }
        }
    }
}

/// The `tri3` interior gradient through [`adjoint_measurement`] for the measurements
/// `ctxs`.
pub fn gradient_f64(
    mesh: &Tri3Mesh,
    geom: &crate::geometry::SceneGeometry,
    ctxs: &[MeasurementCtx],
    film: &Film,
    visibility: crate::scene::Visibility,
    adjoint: &[f32],
) -> Vec<[f64; TRI_PARAMS]> {
    let parents: Vec<_> = geom
        .hidden
        .iter()
        .map(|t| Parent::new(TriParams::<TriDual64>::variables(t)))
        .collect();
    let mut out = vec![[0.0; TRI_PARAMS]; parents.len()];
    // Through the cells of a wide Gaussian, as the render ([`render_measurement`]).
    let cells = film.cells();
    let mut cell_adj = vec![0.0f32; cells.as_ref().map_or(0, |c| c.bins)];
    for (m, ctx) in ctxs.iter().enumerate() {
        if ctx.legs_visible {
            let adj = &adjoint[m * film.bins..(m + 1) * film.bins];
            let (binned, adj) = match &cells {
                Some(c) => {
                    film.cells_adjoint(c, 0, adj, &mut cell_adj);
                    (c, &cell_adj[..])
                }
                None => (film, adj),
            };
            adjoint_measurement(mesh, &parents, ctx, binned, visibility, adj, &mut out);
        }
    }
    out
}
