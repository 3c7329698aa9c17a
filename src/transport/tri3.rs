//! Deterministic per-triangle three-bounce model (DESIGN §3 rung 1; after Plack,
//! Callenberg, Schneider, Hullin 2023).
//!
//! For laser spot `x_l`, sensor point `x_s` and a (sub-)triangle `T` of area `A`, centroid
//! `c`, normal `n` and albedo `ρ`, the three-bounce contribution
//!
//! `H_T = P (ρ_w/π) ∫_T (ρ/π) G(x_l, x) V G(x, x_s) dA (ρ_w/π)`
//!
//! is computed with the integrand `w(x) = (ρ/π) G(x_l, x) G(x, x_s)` and the OPL
//! `τ(x) = |x_l − x| + |x − x_s|` evaluated at the three corners and taken as linear over
//! the triangle: the weighted pulse `∫_T w δ(t − τ) dA` is then exact in closed form,
//! integrated over each bin through the film's kernel ([`Film::splat_triangle`]). Its
//! total is the trapezoidal rule `A (w0 + w1 + w2)/3`.
//!
//! The OPL is not linear: its curvature displaces a sub-triangle's pulse by about
//! `h²/r` (`h` the edge, `r` the distance to the wall). The pulse is therefore shifted so
//! its mean is the quadratic-exact mean `(1/12) Σ τ(v_i) + (3/4) τ(c)` (a second-order
//! correction); what remains is a shape error of the same order. Triangles are
//! subdivided, before any measurement, into `4^L` sub-triangles by midpoint subdivision,
//! with the smallest `L` such that every sub-triangle's longest edge `h` satisfies
//! `h² / (r w) ≤ subdivision` (the curvature displacement in units of the film's
//! resolution `w` = max(bin width, σ)) and `h ≤ r / 4` (the weight's linearity), `r` the
//! triangle's smallest height above the wall (a lower bound on its distance to any wall
//! point). The error this leaves is measured against Monte Carlo (`tests/tri3.rs`;
//! error-vs-threshold table in `BENCHMARKS.md`, from `umbra bench tri3`).
//!
//! Visibility: `none`; `centroid` (one shadow ray from the original triangle's centroid
//! to `x_l` and one to `x_s`, shared by its sub-triangles); `subtriangle` (the same per
//! sub-triangle).
//!
//! Supports: all capture types, one- and two-sided surfaces, per-vertex albedo, box and
//! Gaussian kernels, a point laser spot. Does not: interreflections, a finite laser spot
//! (treated as its centre), partial occlusion within a (sub-)triangle.

use super::MeasurementCtx;
use crate::film::Film;
use crate::geometry::{HiddenTri, SceneGeometry};
use crate::scene::{KernelSpec, Scene, Visibility};
use glam::Vec3;
use std::f32::consts::FRAC_1_PI;

/// Subdivision is capped at this level (`4^8` sub-triangles per triangle).
pub const MAX_LEVEL: u32 = 8;

/// The hidden meshes subdivided for the model, structure of arrays. Vertices are not
/// shared between original triangles, so each vertex carries its triangle's normal.
#[derive(Clone, Debug, Default)]
pub struct Tri3Mesh {
    /// Sub-triangle vertices.
    pub vertices: Vec<Vec3>,
    /// Per vertex: the unit normal of the triangle it belongs to.
    pub vertex_normal: Vec<Vec3>,
    /// Per vertex: `ρ/π` (1/sr).
    pub vertex_brdf: Vec<f32>,
    /// Per vertex: one- or two-sided.
    pub vertex_two_sided: Vec<bool>,
    /// Per sub-triangle: vertex indices.
    pub tris: Vec<[u32; 3]>,
    /// Per sub-triangle: area (m²).
    pub area: Vec<f32>,
    /// Per sub-triangle: centroid (for `subtriangle` visibility).
    pub centroid: Vec<Vec3>,
    /// Per sub-triangle: flat index of the original triangle.
    pub parent: Vec<u32>,
    /// Per original triangle: its centroid (for `centroid` visibility).
    pub parent_centroid: Vec<Vec3>,
}

impl Tri3Mesh {
    /// Subdivides every hidden triangle of `geom` for the scene's wall and film (see
    /// the module doc for the rule).
    pub fn build(scene: &Scene, geom: &SceneGeometry, subdivision: f32) -> Tri3Mesh {
        let resolution = match scene.film.kernel {
            KernelSpec::Box => scene.film.bin_width_opl,
            KernelSpec::Gaussian { sigma_opl } => sigma_opl.max(scene.film.bin_width_opl),
        };
        let mut m = Tri3Mesh::default();
        for (flat, t) in geom.hidden.iter().enumerate() {
            let r =
                t.v.iter()
                    .map(|&v| scene.wall.height_above(v))
                    .fold(f32::INFINITY, f32::min)
                    .max(1e-4);
            let edge = (t.v[1] - t.v[0])
                .length()
                .max((t.v[2] - t.v[1]).length())
                .max((t.v[0] - t.v[2]).length());
            let max_edge = (subdivision * resolution * r).sqrt().min(0.25 * r);
            let mut level = 0;
            while level < MAX_LEVEL && edge / (1u32 << level) as f32 > max_edge {
                level += 1;
            }
            m.parent_centroid.push((t.v[0] + t.v[1] + t.v[2]) / 3.0);
            m.push_subdivided(flat as u32, t, level);
        }
        m
    }

    pub fn len(&self) -> usize {
        self.tris.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tris.is_empty()
    }

    /// Midpoint subdivision into `4^level` triangles on a barycentric grid of
    /// `n = 2^level` steps: vertex `(i, j)` has barycentrics `(i/n, j/n)`.
    fn push_subdivided(&mut self, flat: u32, t: &HiddenTri, level: u32) {
        let n = 1u32 << level;
        let base = self.vertices.len() as u32;
        // Row j holds i = 0..=n-j; rows are consecutive.
        let mut row_start = Vec::with_capacity(n as usize + 1);
        let mut count = 0u32;
        for j in 0..=n {
            row_start.push(count);
            for i in 0..=(n - j) {
                let bary = [i as f32 / n as f32, j as f32 / n as f32];
                self.vertices.push(t.point(bary));
                self.vertex_normal.push(t.n);
                self.vertex_brdf.push(t.albedo_at(bary) * FRAC_1_PI);
                self.vertex_two_sided.push(t.two_sided);
                count += 1;
            }
        }
        let vid = |i: u32, j: u32| base + row_start[j as usize] + i;
        let mut push = |a: u32, b: u32, c: u32| {
            let [pa, pb, pc] = [a, b, c].map(|k| self.vertices[k as usize]);
            self.tris.push([a, b, c]);
            self.area.push(0.5 * (pb - pa).cross(pc - pa).length());
            self.centroid.push((pa + pb + pc) / 3.0);
            self.parent.push(flat);
        };
        for j in 0..n {
            for i in 0..(n - j) {
                push(vid(i, j), vid(i + 1, j), vid(i, j + 1));
                if i + j + 1 < n {
                    push(vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1));
                }
            }
        }
    }
}

/// Reusable per-thread buffers.
#[derive(Default)]
pub struct Tri3Scratch {
    /// Per vertex, for the current measurement: OPL (m).
    opl: Vec<f32>,
    /// Per vertex: `(ρ/π) G(x_l, v) G(v, x_s)`, 0 where the vertex faces away.
    weight: Vec<f32>,
    /// Per original triangle: visible from both wall points (centroid visibility).
    visible: Vec<bool>,
}

/// Adds the three-bounce transient of one measurement to `hist`.
pub fn render_measurement(
    mesh: &Tri3Mesh,
    ctx: &MeasurementCtx,
    film: &Film,
    visibility: Visibility,
    scratch: &mut Tri3Scratch,
    hist: &mut [f64],
) {
    let (x_l, x_s, n_w) = (ctx.x_l, ctx.x_s, ctx.n_w);
    let legs = ctx.opl_laser_leg(x_l) + ctx.opl_sensor_leg;
    scratch.opl.clear();
    scratch.weight.clear();
    for (k, &v) in mesh.vertices.iter().enumerate() {
        let (dl, ds) = (x_l - v, x_s - v);
        let (rl2, rs2) = (dl.length_squared(), ds.length_squared());
        let (rl, rs) = (rl2.sqrt(), rs2.sqrt());
        scratch.opl.push(rl + rs + legs);
        let n = mesh.vertex_normal[k];
        let (cos_vl, cos_vs) = (n.dot(dl) / rl, n.dot(ds) / rs);
        let facing = if mesh.vertex_two_sided[k] {
            cos_vl * cos_vs > 0.0
        } else {
            cos_vl > 0.0 && cos_vs > 0.0
        };
        let (cos_wl, cos_ws) = (-n_w.dot(dl) / rl, -n_w.dot(ds) / rs);
        let w = if facing && cos_wl > 0.0 && cos_ws > 0.0 {
            mesh.vertex_brdf[k] * cos_wl * cos_vl.abs() / rl2 * cos_vs.abs() * cos_ws / rs2
        } else {
            0.0
        };
        scratch.weight.push(w);
    }
    if visibility == Visibility::Centroid {
        scratch.visible.clear();
        scratch.visible.extend(
            mesh.parent_centroid
                .iter()
                .map(|&c| !ctx.geom.occluded(c, x_l) && !ctx.geom.occluded(c, x_s)),
        );
    }
    let scale = (ctx.power * ctx.f_wall * ctx.f_wall) as f64;
    for (k, tri) in mesh.tris.iter().enumerate() {
        let w = tri.map(|i| scratch.weight[i as usize]);
        if w[0] <= 0.0 && w[1] <= 0.0 && w[2] <= 0.0 {
            continue;
        }
        let t = tri.map(|i| scratch.opl[i as usize]);
        let t_min = t[0].min(t[1]).min(t[2]);
        let t_max = t[0].max(t[1]).max(t[2]);
        if t_max < ctx.opl_min || t_min >= ctx.opl_max {
            continue;
        }
        let visible = match visibility {
            Visibility::None => true,
            Visibility::Centroid => scratch.visible[mesh.parent[k] as usize],
            Visibility::Subtriangle => {
                let c = mesh.centroid[k];
                !ctx.geom.occluded(c, x_l) && !ctx.geom.occluded(c, x_s)
            }
        };
        if visible {
            // τ is not linear: shift the pulse so its mean is the quadratic-exact mean
            // (1/12) Σ τ(v_i) + (3/4) τ(c), a second-order correction of its position.
            let c = mesh.centroid[k];
            let tau_c = (x_l - c).length() + (x_s - c).length() + legs;
            let shift = 0.75 * (tau_c - (t[0] + t[1] + t[2]) / 3.0);
            film.splat_triangle(
                t.map(|x| (x + shift) as f64),
                w.map(|x| x as f64 * scale),
                mesh.area[k] as f64,
                hist,
            );
        }
    }
}
