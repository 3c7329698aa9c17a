//! The reverse (adjoint) pass of `tri3`'s per-pair physics ([`super::tri3_exact::pair_pulse`]):
//! given `g = ∂L/∂(τ_0, τ_1, τ_2, w_0, w_1, w_2, A)` of one sub-triangle's pulse, the
//! gradient with respect to its original triangle's corners and corner albedos, by the
//! chain rule written out once per pair instead of 12-slot dual numbers carried through
//! every operation (issue 19, `notes/tri3-adjoint.md`). The dual-number `pair_pulse` stays
//! the oracle this is tested against (`tests` below, and the whole-gradient comparisons).
//!
//! Forward (module doc of [`super::tri3_exact`]): corner `c_i = Σ_j β_ij v_j`,
//! `τ_i = r_l + r_s + legs + shift`, `shift = 0.75 (τ(centroid) − mean τ')`,
//! `w_i = (ρ_i/π) G_i`, `G_i = |p_l p_s| c_l c_s / (r_l² r_s²)²` (retroreflective:
//! `|p_l| c_l / r_l⁴`), `p = n·(x − v_0)`, `c = −n_w·(x − c_i)`, `A = ratio |e_1 × e_2| / 2`.
//! Reverse, for `L` with those partials:
//!
//! - `S = Σ g_τi`: `∂L/∂τ'_i = g_τi − S/4`, `∂L/∂τ(centroid) = 3S/4`;
//! - `∂τ'_i/∂c_i = −(u_l + u_s)` (unit vectors from `c_i` to the wall points);
//! - `∂G_i/∂c_i = G_i (n_w/c_l + n_w/c_s + 4 d_l/r_l² + 4 d_s/r_s²)`, `∂G_i/∂plane = G_i/plane`;
//! - `∂|p_l p_s|/∂p_l = sgn(p_l p_s) p_s`; `∂p/∂n = x − v_0`, `∂p/∂v_0 = −n`;
//! - `∂|c|/∂c = n` (`c = e_1 × e_2`), `∂n/∂c = (I − n nᵀ)/|c|`, `∂(a × b)` by `b × g`, `g × a`.

use super::tri3::Tri3Mesh;
use super::MeasurementCtx;
use glam::DVec3;
use std::f64::consts::FRAC_1_PI;

/// An original triangle in `f64`, with what every pair of it shares.
pub struct ParentGeom {
    pub v: [DVec3; 3],
    pub albedo: [f64; 3],
    pub two_sided: bool,
    pub retro: bool,
    /// `|(v1 − v0) × (v2 − v0)|`, and the unit normal.
    cross_len: f64,
    pub n: DVec3,
}

impl ParentGeom {
    pub fn new(t: &crate::geometry::HiddenTri) -> ParentGeom {
        let v = t.v.map(|p| p.as_dvec3());
        let cross = (v[1] - v[0]).cross(v[2] - v[0]);
        let cross_len = cross.length();
        ParentGeom {
            v,
            albedo: t.albedo.map(f64::from),
            two_sided: t.two_sided,
            retro: t.retro,
            cross_len,
            n: cross / cross_len,
        }
    }

    fn point(&self, [b1, b2]: [f32; 2]) -> DVec3 {
        let b0 = (1.0 - b1 - b2) as f64;
        self.v[0] * b0 + self.v[1] * b1 as f64 + self.v[2] * b2 as f64
    }
}

/// The barycentric weights of `(b1, b2)` on the three corners, as `albedo_at` forms them.
fn weights([b1, b2]: [f32; 2]) -> [f64; 3] {
    [(1.0 - b1 - b2) as f64, b1 as f64, b2 as f64]
}

/// One pair's pulse inputs (values) and what the reverse pass needs of the forward.
pub struct Pair {
    /// Corner OPLs with the shift (m), corner weights, area: the pulse's inputs.
    pub tau: [f64; 3],
    pub w: [f64; 3],
    pub area: f64,
    corner: [Leg; 3],
    centroid: (DVec3, DVec3),
    p: (f64, f64),
    plane: f64,
    ratio: f64,
    bary: [[f32; 2]; 3],
    centroid_weights: [f64; 3],
}

/// A corner's vectors to the wall points, and its geometric factor.
#[derive(Clone, Copy, Default)]
struct Leg {
    d_l: DVec3,
    d_s: DVec3,
    g: f64,
    brdf: f64,
    front: bool,
}

/// The forward pass of sub-triangle `k` in `f64` (the same numbers as `pair_pulse`);
/// `None` where it reflects nothing.
pub fn forward(mesh: &Tri3Mesh, k: usize, t: &ParentGeom, ctx: &MeasurementCtx) -> Option<Pair> {
    let (x_l, x_s, n_w) = (ctx.x_l.as_dvec3(), ctx.x_s.as_dvec3(), ctx.n_w.as_dvec3());
    let legs = (ctx.opl_laser_leg(ctx.x_l) + ctx.opl_sensor_leg) as f64;
    let (p_l, p_s) = (t.n.dot(x_l - t.v[0]), t.n.dot(x_s - t.v[0]));
    let facing = if t.two_sided {
        p_l * p_s > 0.0
    } else {
        p_l > 0.0 && p_s > 0.0
    };
    if !facing {
        return None;
    }
    let plane = if t.retro {
        p_l.abs()
    } else {
        (p_l * p_s).abs()
    };
    let bary = mesh.corner_bary[k];
    let mut corner = [Leg::default(); 3];
    let (mut tau, mut w) = ([0.0; 3], [0.0; 3]);
    for i in 0..3 {
        let c = t.point(bary[i]);
        let (d_l, d_s) = (x_l - c, x_s - c);
        let (r2_l, r2_s) = (d_l.length_squared(), d_s.length_squared());
        tau[i] = r2_l.sqrt() + r2_s.sqrt() + legs;
        let (c_l, c_s) = (-n_w.dot(d_l), -n_w.dot(d_s));
        let front = c_l > 0.0 && c_s > 0.0;
        let g = match (front, t.retro) {
            (false, _) => 0.0,
            (true, true) => plane * c_l / (r2_l * r2_l),
            (true, false) => {
                let r4 = r2_l * r2_s;
                plane * c_l * c_s / (r4 * r4)
            }
        };
        let rho: f64 = weights(bary[i])
            .iter()
            .zip(t.albedo)
            .map(|(b, a)| b * a)
            .sum();
        let brdf = rho * FRAC_1_PI;
        w[i] = brdf * g;
        corner[i] = Leg {
            d_l,
            d_s,
            g,
            brdf,
            front,
        };
    }
    if w.iter().all(|&w| w <= 0.0) {
        return None;
    }
    let [b0, b1, b2] = bary.map(|b| b.map(f64::from));
    let ratio = ((b1[0] - b0[0]) * (b2[1] - b0[1]) - (b1[1] - b0[1]) * (b2[0] - b0[0])).abs();
    let third = 1.0 / 3.0;
    let (c1, c2) = (
        (b0[0] + b1[0] + b2[0]) * third,
        (b0[1] + b1[1] + b2[1]) * third,
    );
    let centroid_weights = [1.0 - c1 - c2, c1, c2];
    let cen = t.v[0] * centroid_weights[0] + t.v[1] * c1 + t.v[2] * c2;
    let (dc_l, dc_s) = (x_l - cen, x_s - cen);
    let tau_c = dc_l.length() + dc_s.length() + legs;
    let shift = 0.75 * (tau_c - (tau[0] + tau[1] + tau[2]) * third);
    Some(Pair {
        tau: tau.map(|t| t + shift),
        w,
        area: 0.5 * t.cross_len * ratio,
        corner,
        centroid: (dc_l, dc_s),
        p: (p_l, p_s),
        plane,
        ratio,
        bary,
        centroid_weights,
    })
}

/// `∂L/∂θ` for the original triangle's corners (slots `3 i + axis`) and corner albedos
/// (slots `9 + i`), given `g = ∂L/∂(τ, w, A)` of `pair`'s pulse, added into `out`.
pub fn reverse(
    pair: &Pair,
    t: &ParentGeom,
    ctx: &MeasurementCtx,
    g: &[f64; 7],
    out: &mut [f64; 12],
) {
    let (x_l, x_s, n_w) = (ctx.x_l.as_dvec3(), ctx.x_s.as_dvec3(), ctx.n_w.as_dvec3());
    let mut g_v = [DVec3::ZERO; 3];
    let mut g_plane = 0.0;
    let sum: f64 = g[..3].iter().sum();
    for i in 0..3 {
        let leg = &pair.corner[i];
        let beta = weights(pair.bary[i]);
        // OPL: ∂τ'_i/∂c_i = −(u_l + u_s).
        let g_tau = g[i] - 0.25 * sum;
        let mut g_c = -(leg.d_l.normalize() + leg.d_s.normalize()) * g_tau;
        if leg.front {
            let g_w = g[3 + i];
            // Albedos: w_i = (Σ_j β_ij ρ_j / π) G_i.
            for (j, b) in beta.iter().enumerate() {
                out[9 + j] += g_w * leg.g * b * FRAC_1_PI;
            }
            let g_g = g_w * leg.brdf;
            if g_g != 0.0 && leg.g != 0.0 {
                let (c_l, c_s) = (-n_w.dot(leg.d_l), -n_w.dot(leg.d_s));
                let (r2_l, r2_s) = (leg.d_l.length_squared(), leg.d_s.length_squared());
                let dg = if t.retro {
                    n_w / c_l + leg.d_l * (4.0 / r2_l)
                } else {
                    n_w / c_l + n_w / c_s + leg.d_l * (4.0 / r2_l) + leg.d_s * (4.0 / r2_s)
                };
                g_c += dg * (g_g * leg.g);
                g_plane += g_g * leg.g / pair.plane;
            }
        }
        for (j, b) in beta.iter().enumerate() {
            g_v[j] += g_c * *b;
        }
    }
    // Centroid: ∂τ_c/∂cen = −(u_l + u_s), weight 3S/4.
    let (dc_l, dc_s) = pair.centroid;
    let g_cen = -(dc_l.normalize() + dc_s.normalize()) * (0.75 * sum);
    for (j, b) in pair.centroid_weights.iter().enumerate() {
        g_v[j] += g_cen * *b;
    }
    // Plane terms p = n·(x − v0).
    let (p_l, p_s) = pair.p;
    let (g_pl, g_ps) = if t.retro {
        (g_plane * p_l.signum(), 0.0)
    } else {
        let sgn = (p_l * p_s).signum();
        (g_plane * sgn * p_s, g_plane * sgn * p_l)
    };
    let g_n = (x_l - t.v[0]) * g_pl + (x_s - t.v[0]) * g_ps;
    g_v[0] -= t.n * (g_pl + g_ps);
    // Area A = ratio |c| / 2 and the normal n = c/|c|, c = e1 × e2.
    let g_cross = t.n * (0.5 * pair.ratio * g[6]) + (g_n - t.n * t.n.dot(g_n)) / t.cross_len;
    let (e1, e2) = (t.v[1] - t.v[0], t.v[2] - t.v[0]);
    let (g_e1, g_e2) = (e2.cross(g_cross), g_cross.cross(e1));
    g_v[1] += g_e1;
    g_v[2] += g_e2;
    g_v[0] -= g_e1 + g_e2;
    for (j, gv) in g_v.iter().enumerate() {
        for (k, c) in gv.to_array().into_iter().enumerate() {
            out[3 * j + k] += c;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adjoint::dual::Real;
    use crate::film::Film;
    use crate::geometry::SceneGeometry;
    use crate::transport::mc3::TriParams;
    use crate::transport::tri3_exact::{pair_pulse, Parent, TriDual64};

    /// Against the dual-number oracle on every pair of the default scene for a few
    /// measurements (confocal), with a one-sided and a retroreflective variant: values and
    /// every parameter's derivative of a random linear functional of the pulse inputs.
    #[test]
    fn reverse_matches_the_dual_oracle() {
        let mut scene = crate::scene::default::default_scene().unwrap();
        for variant in 0..3 {
            match variant {
                1 => scene.objects[0].two_sided = !scene.objects[0].two_sided,
                2 => scene.objects[0].reflectance = crate::scene::Reflectance::Retroreflective,
                _ => {}
            }
            let geom = SceneGeometry::build(&scene);
            let sub = crate::transport::RenderOptions::from_scene(&scene).subdivision;
            let mesh = Tri3Mesh::build(&scene, &geom, sub);
            let film = Film::new(&scene.film);
            let (mut worst, mut pairs) = (0.0f64, 0);
            for m in [0, 37, 500, 1023] {
                let ctx = MeasurementCtx::new(&scene, &geom, &film, m);
                for k in 0..mesh.len() {
                    let p = mesh.parent[k] as usize;
                    let t = ParentGeom::new(&geom.hidden[p]);
                    let dual = Parent::new(TriParams::<TriDual64>::variables(&geom.hidden[p]));
                    let (Some(pair), Some(oracle)) = (
                        forward(&mesh, k, &t, &ctx),
                        pair_pulse(&mesh, k, &dual, &ctx),
                    ) else {
                        continue;
                    };
                    pairs += 1;
                    let g: [f64; 7] = std::array::from_fn(|i| ((i * 7 + k) % 5) as f64 - 2.0);
                    let mut got = [0.0; 12];
                    reverse(&pair, &t, &ctx, &g, &mut got);
                    let inputs = oracle.0.iter().chain(&oracle.1).chain([&oracle.2]);
                    let values = pair.tau.iter().chain(&pair.w).chain([&pair.area]);
                    let mut want = [0.0; 12];
                    let mut scale = 0.0f64;
                    for ((gk, d), v) in g.iter().zip(inputs).zip(values) {
                        assert!(
                            (d.v() - v).abs() <= 1e-9 * d.v().abs().max(1e-12),
                            "{d:?} {v}"
                        );
                        for (w, dd) in want.iter_mut().zip(d.d) {
                            *w += gk * dd;
                            scale = scale.max((gk * dd).abs());
                        }
                    }
                    for (a, b) in got.iter().zip(want) {
                        worst = worst.max((a - b).abs() / scale.max(1e-300));
                    }
                }
            }
            assert!(pairs > 100, "variant {variant}: {pairs} pairs");
            assert!(worst < 1e-9, "variant {variant}: worst {worst:e}");
        }
    }
}
