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
use std::collections::HashMap;
use std::f32::consts::FRAC_1_PI;

/// Subdivision is capped at this level (`4^8` sub-triangles per triangle).
pub const MAX_LEVEL: u32 = 8;

/// The hidden meshes subdivided for the model, structure of arrays. Vertices at the
/// same position within an object are shared, so the per-vertex work of a measurement
/// (distances, cosines at the wall) is done once per vertex, not once per corner.
#[derive(Clone, Debug, Default)]
pub struct Tri3Mesh {
    /// Sub-triangle vertices.
    pub vertices: Vec<Vec3>,
    /// Per vertex: `ρ/π` (1/sr).
    pub vertex_brdf: Vec<f32>,
    /// Per sub-triangle: vertex indices.
    pub tris: Vec<[u32; 3]>,
    /// Per sub-triangle: unit normal (its original triangle's).
    pub normal: Vec<Vec3>,
    /// Per sub-triangle: reflects on both sides.
    pub two_sided: Vec<bool>,
    /// Per sub-triangle: area (m²).
    pub area: Vec<f32>,
    /// Per sub-triangle: centroid (curvature shift, `subtriangle` visibility).
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
        let mut shared: HashMap<(u32, [u32; 3], u32), u32> = HashMap::new();
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
            let object = geom.flat_to_local[flat].0;
            m.push_subdivided(flat as u32, object, t, level, &mut shared);
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
    fn push_subdivided(
        &mut self,
        flat: u32,
        object: u32,
        t: &HiddenTri,
        level: u32,
        shared: &mut HashMap<(u32, [u32; 3], u32), u32>,
    ) {
        let n = 1u32 << level;
        let mut grid = Vec::with_capacity(((n + 1) * (n + 2) / 2) as usize);
        for j in 0..=n {
            for i in 0..=(n - j) {
                let bary = [i as f32 / n as f32, j as f32 / n as f32];
                let p = t.point(bary);
                let brdf = t.albedo_at(bary) * FRAC_1_PI;
                let key = (object, p.to_array().map(f32::to_bits), brdf.to_bits());
                let next = self.vertices.len() as u32;
                let id = *shared.entry(key).or_insert(next);
                if id == next {
                    self.vertices.push(p);
                    self.vertex_brdf.push(brdf);
                }
                grid.push(id);
            }
        }
        // Row j of the grid starts after rows 0..j, of n + 1, n, … entries.
        let row = |j: u32| (j * (n + 1) - j * j.saturating_sub(1) / 2) as usize;
        let vid = |i: u32, j: u32| grid[row(j) + i as usize];
        for j in 0..n {
            for i in 0..(n - j) {
                let up = [vid(i, j), vid(i + 1, j), vid(i, j + 1)];
                // The "down" triangle exists only inside the grid's diagonal.
                let tris = if i + j + 1 < n {
                    &[up, [vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)]][..]
                } else {
                    &[up][..]
                };
                for &tri in tris {
                    let [pa, pb, pc] = tri.map(|k| self.vertices[k as usize]);
                    self.tris.push(tri);
                    self.normal.push(t.n);
                    self.two_sided.push(t.two_sided);
                    self.area.push(0.5 * (pb - pa).cross(pc - pa).length());
                    self.centroid.push((pa + pb + pc) / 3.0);
                    self.parent.push(flat);
                }
            }
        }
    }
}

/// What a measurement needs of a vertex, in one record (one cache access per corner).
#[derive(Clone, Copy, Debug, Default)]
struct VertexTerm {
    /// Unit directions to the laser spot and to the sensor point.
    to_l: Vec3,
    to_s: Vec3,
    /// OPL (m).
    opl: f32,
    /// `(ρ/π) cos θ_wall,l cos θ_wall,s / (r_l² r_s²)`, 0 behind the wall's front.
    base: f32,
}

/// Reusable per-thread buffers.
#[derive(Default)]
pub struct Tri3Scratch {
    /// Per vertex, for the current measurement.
    vertex: Vec<VertexTerm>,
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
    scratch.vertex.clear();
    scratch.vertex.extend(
        mesh.vertices
            .iter()
            .zip(&mesh.vertex_brdf)
            .map(|(&v, &brdf)| {
                let (dl, ds) = (x_l - v, x_s - v);
                let (rl2, rs2) = (dl.length_squared(), ds.length_squared());
                let (inv_rl, inv_rs) = (rl2.sqrt().recip(), rs2.sqrt().recip());
                let (to_l, to_s) = (dl * inv_rl, ds * inv_rs);
                let (cos_wl, cos_ws) = (-n_w.dot(to_l), -n_w.dot(to_s));
                let front = cos_wl > 0.0 && cos_ws > 0.0;
                VertexTerm {
                    to_l,
                    to_s,
                    opl: rl2 * inv_rl + rs2 * inv_rs + legs,
                    base: if front {
                        brdf * cos_wl * cos_ws / (rl2 * rs2)
                    } else {
                        0.0
                    },
                }
            }),
    );
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
        let n = mesh.normal[k];
        let two_sided = mesh.two_sided[k];
        let corners = [
            scratch.vertex[tri[0] as usize],
            scratch.vertex[tri[1] as usize],
            scratch.vertex[tri[2] as usize],
        ];
        let corner = |v: &VertexTerm| {
            let (cl, cs) = (n.dot(v.to_l), n.dot(v.to_s));
            let facing = if two_sided {
                cl * cs > 0.0
            } else {
                cl > 0.0 && cs > 0.0
            };
            if facing {
                v.base * (cl * cs).abs()
            } else {
                0.0
            }
        };
        let w = [
            corner(&corners[0]),
            corner(&corners[1]),
            corner(&corners[2]),
        ];
        if w[0] <= 0.0 && w[1] <= 0.0 && w[2] <= 0.0 {
            continue;
        }
        let t = [corners[0].opl, corners[1].opl, corners[2].opl];
        let t_min = t[0].min(t[1]).min(t[2]);
        let t_max = t[0].max(t[1]).max(t[2]);
        if t_max < ctx.opl_min || t_min >= ctx.opl_max {
            continue;
        }
        let c = mesh.centroid[k];
        let visible = match visibility {
            Visibility::None => true,
            Visibility::Centroid => scratch.visible[mesh.parent[k] as usize],
            Visibility::Subtriangle => !ctx.geom.occluded(c, x_l) && !ctx.geom.occluded(c, x_s),
        };
        if visible {
            // τ is not linear: shift the pulse so its mean is the quadratic-exact mean
            // (1/12) Σ τ(v_i) + (3/4) τ(c), a second-order correction of its position.
            let tau_c = (x_l - c).length() + (x_s - c).length() + legs;
            let shift = 0.75 * (tau_c - (t[0] + t[1] + t[2]) / 3.0);
            film.splat_triangle(
                [
                    (t[0] + shift) as f64,
                    (t[1] + shift) as f64,
                    (t[2] + shift) as f64,
                ],
                [
                    w[0] as f64 * scale,
                    w[1] as f64 * scale,
                    w[2] as f64 * scale,
                ],
                mesh.area[k] as f64,
                hist,
            );
        }
    }
}
