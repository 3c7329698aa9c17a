//! The renderer as the fit's objective: the hidden mesh being fitted replaces the scene's
//! hidden objects, Umbra renders it, and the loss against the measurement `M` is the
//! scale-free relative squared error (the square of the relative L2 error)
//!
//! `L(θ) = ‖s* H(θ) − M‖² / ‖M‖²`, with `s* = max(⟨H, M⟩ / ⟨H, H⟩, 0)`
//!
//! (`s` fixed to 1 when the measurement's absolute scale is known). `s*` minimises `L`
//! over `s` for the current render, so by the envelope theorem
//! `dL/dθ = 2 s* ⟨s* H − M, dH/dθ⟩ / ‖M‖²`: the adjoint `δH = 2 s* (s* H − M) / ‖M‖²`
//! goes through [`crate::adjoint::gradient`] (path replay) as any other loss. Real data
//! have an unknown scale (laser power, detector efficiency), and with it the object's
//! albedo is not identifiable: `s*` absorbs both; per-vertex albedo, when fitted,
//! carries only relative variations.
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

/// `(loss, δH, s*)` of the module doc; `fit_scale = false` holds `s = 1`.
pub fn scaled_l2(render: &[f32], measured: &[f32], fit_scale: bool) -> (f64, Vec<f32>, f64) {
    let (mut hh, mut hm, mut mm) = (0.0f64, 0.0f64, 0.0f64);
    for (&h, &m) in render.iter().zip(measured) {
        let (h, m) = (h as f64, m as f64);
        hh += h * h;
        hm += h * m;
        mm += m * m;
    }
    let s = if !fit_scale {
        1.0
    } else if hh > 0.0 {
        (hm / hh).max(0.0)
    } else {
        0.0
    };
    let mm = mm.max(f64::MIN_POSITIVE);
    let mut loss = 0.0;
    let adjoint = render
        .iter()
        .zip(measured)
        .map(|(&h, &m)| {
            let r = s * h as f64 - m as f64;
            loss += r * r;
            (2.0 * s * r / mm) as f32
        })
        .collect();
    (loss / mm, adjoint, s)
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
    pub fit_scale: bool,
    /// Albedo of the fitted object where it has no per-vertex albedo.
    pub albedo: f32,
    pub two_sided: bool,
    /// Bins before this one are left out of the loss (zeroed in render and
    /// measurement): e.g. a capture's residual direct light.
    pub first_bin: usize,
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
    scale: f64,
}

impl UmbraObjective {
    /// Renders `mesh` and returns `(render, loss, s*)` without the gradient.
    pub fn render(&self, mesh: &Mesh) -> crate::Result<(Vec<f32>, f64, f64)> {
        let f = self.forward(mesh)?;
        Ok((f.render, f.loss, f.scale))
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
        let (loss, adjoint, scale) = scaled_l2(&render, &self.measured, self.fit_scale);
        Ok(Forward {
            scene,
            geom,
            opts,
            render,
            loss,
            adjoint,
            scale,
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
            report: vec![("scale".into(), f.scale)],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scaled_l2_gradient_matches_finite_differences() {
        let m = [0.3f32, 1.2, 0.0, 2.5, 0.7];
        let h = [0.1f32, 0.5, 0.2, 1.1, 0.2];
        let (l0, adj, s) = scaled_l2(&h, &m, true);
        assert!(s > 0.0 && l0 > 0.0);
        for i in 0..h.len() {
            let eps = 1e-3f32;
            let (mut hp, mut hm) = (h, h);
            hp[i] += eps;
            hm[i] -= eps;
            let fd = (scaled_l2(&hp, &m, true).0 - scaled_l2(&hm, &m, true).0) / (2.0 * eps as f64);
            assert!(
                (fd - adj[i] as f64).abs() < 1e-3 * fd.abs().max(1e-3),
                "{i}: {fd} {}",
                adj[i]
            );
        }
        // A render proportional to the measurement has zero loss at any scale.
        let (l, _, s) = scaled_l2(&m.map(|v| 0.25 * v), &m, true);
        assert!(l < 1e-12 && (s - 4.0).abs() < 1e-6);
    }
}
