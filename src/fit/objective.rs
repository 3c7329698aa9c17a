//! The renderer as the fit's objective: the hidden mesh being fitted replaces the scene's
//! hidden objects, Umbra renders it, and the loss against the measurement `M` is the
//! relative squared error (the square of the relative L2 error) after the best intensity
//! scale `s` and constant background `b`
//!
//! `L(θ) = min_{s ≥ 0, b ≥ 0} ‖s H(θ) + b − M‖²_U / ‖M‖²_U`,
//!
//! `U` the bins the fit uses (each row's bins from `first_bin` on). Real data have an
//! unknown scale (laser power, detector efficiency; with it the object's albedo is not
//! identifiable, so `s` absorbs both and per-vertex albedo carries only relative
//! variations) and a floor of dark counts and ambient light that no hidden surface
//! explains (in the LCT `diffuse_s` capture about half of `‖M‖`). `(s, b)` is the
//! non-negative least-squares solution of a 2 x 2 system, in closed form
//! ([`Intensity::fit`]); `s = 1` or `b = 0` when held. Since `(s, b)` minimise `L` for
//! the current render, by the envelope theorem (which holds at the active constraints
//! too) `dL/dθ = 2 s ⟨s H + b − M, dH/dθ⟩_U / ‖M‖²_U`: the adjoint
//! `δH = 2 s (s H + b − M) / ‖M‖²` on `U`, 0 elsewhere, goes through
//! [`crate::adjoint::gradient`] (path replay) as any other loss.
//!
//! Monte Carlo models are seeded from the parameters (a hash of the mesh's bits), so the
//! same mesh renders the same samples (common random numbers between the cost and the
//! gradient, and an exact resume), while every new iterate sees new noise.

use crate::adjoint;
use crate::geometry::{mesh::TriMesh, SceneGeometry};
use crate::scene::{HiddenObject, Model, Scene};
use crate::transport::{RenderOptions, Renderer};
use glam::Vec3;
use optim::{Evaluation, Mesh, MeshObjective};

/// Which of the intensity parameters a fit estimates (the others are held at `s = 1`,
/// `b = 0`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IntensityModel {
    pub scale: bool,
    pub background: bool,
}

/// The fitted scale `s` (measurement units per render unit) and background `b`
/// (measurement units per bin).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intensity {
    pub scale: f64,
    pub background: f64,
}

/// Sums over the fitted bins `U`: `⟨H,H⟩, ⟨H,1⟩, ⟨H,M⟩, ⟨M,1⟩, ⟨M,M⟩, |U|`.
#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    hh: f64,
    h1: f64,
    hm: f64,
    m1: f64,
    mm: f64,
    n: f64,
}

impl Moments {
    /// `‖s H + b − M‖²` from the moments.
    fn residual(&self, s: f64, b: f64) -> f64 {
        let r = s * s * self.hh + b * b * self.n + self.mm + 2.0 * s * b * self.h1
            - 2.0 * s * self.hm
            - 2.0 * b * self.m1;
        r.max(0.0)
    }
}

impl Intensity {
    /// The non-negative least-squares `(s, b)` of the module doc: the unconstrained
    /// solution if it is feasible, else the better of the two edge solutions (`b = 0`
    /// with the best `s`, `s = 0` with the best `b`; the corner `(0, 0)` lies on both
    /// edges, so it is never better).
    fn fit(m: &Moments, model: IntensityModel) -> Intensity {
        let s_only = if model.scale && m.hh > 0.0 {
            (m.hm / m.hh).max(0.0)
        } else {
            1.0
        };
        if !model.background {
            return Intensity {
                scale: s_only,
                background: 0.0,
            };
        }
        let b_only = |s: f64| ((m.m1 - s * m.h1) / m.n.max(1.0)).max(0.0);
        if !model.scale {
            return Intensity {
                scale: 1.0,
                background: b_only(1.0),
            };
        }
        let det = m.hh * m.n - m.h1 * m.h1;
        if det > 1e-12 * m.hh * m.n {
            let s = (m.hm * m.n - m.h1 * m.m1) / det;
            let b = (m.hh * m.m1 - m.h1 * m.hm) / det;
            if s >= 0.0 && b >= 0.0 {
                return Intensity {
                    scale: s,
                    background: b,
                };
            }
        }
        let scale_only = Intensity {
            scale: s_only,
            background: 0.0,
        };
        let background_only = Intensity {
            scale: 0.0,
            background: b_only(0.0),
        };
        if m.residual(scale_only.scale, 0.0) <= m.residual(0.0, background_only.background) {
            scale_only
        } else {
            background_only
        }
    }
}

/// `(loss, δH, intensity)` of the module doc over the bins `first_bin..` of every
/// `bins`-long row (`first_bin = 0`: all).
pub fn intensity_l2(
    render: &[f32],
    measured: &[f32],
    bins: usize,
    first_bin: usize,
    model: IntensityModel,
) -> (f64, Vec<f32>, Intensity) {
    let bins = bins.max(1);
    let used = |i: usize| i % bins >= first_bin;
    let mut m = Moments::default();
    for (i, (&h, &y)) in render.iter().zip(measured).enumerate() {
        if used(i) {
            let (h, y) = (h as f64, y as f64);
            m.hh += h * h;
            m.h1 += h;
            m.hm += h * y;
            m.m1 += y;
            m.mm += y * y;
            m.n += 1.0;
        }
    }
    let k = Intensity::fit(&m, model);
    let mm = m.mm.max(f64::MIN_POSITIVE);
    let mut loss = 0.0;
    let adjoint = render
        .iter()
        .zip(measured)
        .enumerate()
        .map(|(i, (&h, &y))| {
            if !used(i) {
                return 0.0;
            }
            let r = k.scale * h as f64 + k.background - y as f64;
            loss += r * r;
            (2.0 * k.scale * r / mm) as f32
        })
        .collect();
    (loss / mm, adjoint, k)
}

/// The fitted mesh as a hidden object.
pub fn hidden_object(mesh: &Mesh, albedo: f32, two_sided: bool) -> HiddenObject {
    let positions = mesh
        .vertices
        .iter()
        .map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32))
        .collect();
    let vertex_albedo = (!mesh.vertex_values.is_empty())
        .then(|| mesh.vertex_values.iter().map(|&a| a as f32).collect());
    HiddenObject {
        name: "fit".into(),
        mesh: TriMesh {
            positions,
            triangles: mesh.faces.clone(),
            vertex_albedo,
        },
        albedo,
        two_sided,
    }
}

/// A 64-bit FNV-1a hash of the mesh's bits: the seed of Monte Carlo renders.
fn mesh_seed(base: u64, mesh: &Mesh) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64 ^ base;
    let mut eat = |x: u64| {
        for b in x.to_le_bytes() {
            h ^= b as u64;
            h = h.wrapping_mul(0x100_0000_01b3);
        }
    };
    for p in &mesh.vertices {
        p.iter().for_each(|c| eat(c.to_bits()));
    }
    mesh.vertex_values.iter().for_each(|a| eat(a.to_bits()));
    h
}

/// One stage's objective: the scene at the stage's resolution (its hidden objects are
/// replaced by the fitted mesh) and the measurement at the same resolution.
pub struct UmbraObjective {
    pub scene: Scene,
    pub measured: Vec<f32>,
    pub options: RenderOptions,
    pub intensity: IntensityModel,
    /// Albedo of the fitted object where it has no per-vertex albedo.
    pub albedo: f32,
    pub two_sided: bool,
    /// Bins before this one are left out of the loss (zeroed in render and
    /// measurement): e.g. a capture's residual direct light.
    pub first_bin: usize,
}

/// The first bin of the scene's film that starts at or after `ignore_before_opl` (m),
/// 0 when nothing is ignored.
pub fn first_fitted_bin(scene: &Scene, ignore_before_opl: Option<f32>) -> usize {
    ignore_before_opl.map_or(0, |opl| {
        ((opl - scene.film.start_opl) / scene.film.bin_width_opl)
            .ceil()
            .max(0.0) as usize
    })
}

/// Zeroes bins `..first` of every `bins`-long row.
pub fn zero_leading_bins(data: &mut [f32], bins: usize, first: usize) {
    if first == 0 || bins == 0 {
        return;
    }
    for row in data.chunks_mut(bins) {
        row[..first.min(bins)].fill(0.0);
    }
}

/// One forward evaluation: what the adjoint pass needs besides the render.
struct Forward {
    scene: Scene,
    geom: SceneGeometry,
    opts: RenderOptions,
    render: Vec<f32>,
    loss: f64,
    adjoint: Vec<f32>,
    intensity: Intensity,
}

impl UmbraObjective {
    /// Renders `mesh` and returns `(render, loss, (s, b))` without the gradient.
    pub fn render(&self, mesh: &Mesh) -> crate::Result<(Vec<f32>, f64, Intensity)> {
        let f = self.forward(mesh)?;
        Ok((f.render, f.loss, f.intensity))
    }

    /// The scene with `mesh` as its hidden object, its render (leading bins left out)
    /// and the loss with its adjoint.
    fn forward(&self, mesh: &Mesh) -> crate::Result<Forward> {
        let mut scene = self.scene.clone();
        scene.objects = vec![hidden_object(mesh, self.albedo, self.two_sided)];
        let geom = SceneGeometry::build(&scene);
        let mut opts = self.options;
        if opts.model == Model::Auto {
            opts.model = Model::Tri3;
        }
        if opts.model != Model::Tri3 {
            opts.seed = mesh_seed(self.options.seed, mesh);
        }
        let mut render = Renderer::new(&scene, &geom, &opts)?.render(None)?.data;
        zero_leading_bins(
            &mut render,
            scene.film.temporal_bins as usize,
            self.first_bin,
        );
        let (loss, adjoint, intensity) = intensity_l2(
            &render,
            &self.measured,
            scene.film.temporal_bins as usize,
            self.first_bin,
            self.intensity,
        );
        Ok(Forward {
            scene,
            geom,
            opts,
            render,
            loss,
            adjoint,
            intensity,
        })
    }
}

impl MeshObjective for UmbraObjective {
    fn evaluate(&mut self, mesh: &Mesh) -> Result<Evaluation, String> {
        let f = self.forward(mesh).map_err(|e| e.to_string())?;
        let g = adjoint::gradient(&f.scene, &f.geom, &f.opts, &f.adjoint, None)
            .map_err(|e| e.to_string())?;
        let d_vertices = g.vertices.into_iter().next().unwrap_or_default();
        let d_values = if mesh.vertex_values.is_empty() {
            Vec::new()
        } else {
            g.vertex_albedo
                .into_iter()
                .next()
                .flatten()
                .unwrap_or_else(|| vec![0.0; mesh.vertices.len()])
        };
        Ok(Evaluation {
            loss: f.loss,
            d_vertices,
            d_values,
            report: vec![
                ("scale".into(), f.intensity.scale),
                ("background".into(), f.intensity.background),
            ],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: IntensityModel = IntensityModel {
        scale: true,
        background: true,
    };

    fn fd_check(h: &[f32], m: &[f32], bins: usize, first: usize, model: IntensityModel) {
        let (l0, adj, _) = intensity_l2(h, m, bins, first, model);
        assert!(l0 > 0.0);
        for i in 0..h.len() {
            let eps = 1e-3f32;
            let (mut hp, mut hm) = (h.to_vec(), h.to_vec());
            hp[i] += eps;
            hm[i] -= eps;
            let fd = (intensity_l2(&hp, m, bins, first, model).0
                - intensity_l2(&hm, m, bins, first, model).0)
                / (2.0 * eps as f64);
            assert!(
                (fd - adj[i] as f64).abs() < 1e-3 * fd.abs().max(1e-3),
                "{model:?} {i}: {fd} {}",
                adj[i]
            );
        }
    }

    #[test]
    fn loss_gradient_matches_finite_differences() {
        let m = [0.3f32, 1.2, 0.9, 2.5, 0.7, 0.4];
        let h = [0.1f32, 0.5, 0.2, 1.1, 0.2, 0.05];
        for (scale, background) in [(true, false), (true, true), (false, true), (false, false)] {
            fd_check(&h, &m, 3, 0, IntensityModel { scale, background });
            fd_check(&h, &m, 3, 1, IntensityModel { scale, background });
        }
        // Masked bins have no adjoint.
        let (_, adj, _) = intensity_l2(&h, &m, 3, 1, ALL);
        assert!(adj[0] == 0.0 && adj[3] == 0.0 && adj[1] != 0.0);
    }

    #[test]
    fn recovers_scale_and_background() {
        let h = [0.0f32, 0.5, 2.0, 1.0, 0.25, 0.0, 3.0, 0.1];
        let m = h.map(|v| 4.0 * v + 0.75);
        let (l, _, k) = intensity_l2(&h, &m, 8, 0, ALL);
        assert!(l < 1e-12, "{l}");
        assert!(
            (k.scale - 4.0).abs() < 1e-5 && (k.background - 0.75).abs() < 1e-5,
            "{k:?}"
        );
        // Without a background term the same data leave a residual.
        let (l, _, k) = intensity_l2(
            &h,
            &m,
            8,
            0,
            IntensityModel {
                scale: true,
                background: false,
            },
        );
        assert!(l > 1e-3 && k.background == 0.0);
        // A negative background is not allowed: the constrained optimum has b = 0.
        let m = h.map(|v| 4.0 * v - 0.2);
        let (_, _, k) = intensity_l2(&h, &m, 8, 0, ALL);
        assert_eq!(k.background, 0.0);
        assert!(k.scale > 0.0);
    }
}
