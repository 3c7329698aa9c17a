//! Gradient check (DESIGN §6, check 1): the adjoint against central finite differences
//! with common random numbers, on a handful of parameters, for several step sizes.
//!
//! Both sides differentiate the same estimator: the same seed, and the discrete
//! distribution over triangles frozen at the unperturbed mesh
//! ([`SceneGeometry::with_sampling_of`]), so every sample keeps its triangle. `tri3`'s
//! finite differences use its `f64` reference path ([`tri3_exact`]); the `f32` kernel's
//! rounding would swamp small steps. The loss is L2 against a target rendered from the
//! scene with every hidden object moved 2 cm away from the wall (with another seed), so
//! the gradient is that of a realistic fit's first step.
//!
//! Finite differences at fixed random numbers (or of `tri3`'s piecewise-constant
//! visibility) do not see a shadow move: no sample changes its visibility under a small
//! step. So the adjoint compared is the interior derivative (boundary terms off), and
//! the visibility boundary terms ([`super::boundary`]) are reported next to it; they are
//! checked against an exact reference in `tests/gradient_bias.rs`.

use super::{gradient, Gradient, Loss};
use crate::error::Result;
use crate::film::Film;
use crate::geometry::SceneGeometry;
use crate::scene::{Model, Scene};
use crate::transport::gate::Pass;
use crate::transport::tri3::Tri3Mesh;
use crate::transport::{render, roulette, tri3_exact, MeasurementCtx, RenderOptions};

/// A parameter: a vertex coordinate or an object's albedo.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Param {
    /// Object, vertex (OBJ order), axis.
    Vertex(usize, usize, usize),
    Albedo(usize),
    /// Object, vertex: its albedo (meshes with vertex colours).
    VertexAlbedo(usize, usize),
}

impl std::fmt::Display for Param {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match *self {
            Param::Vertex(o, v, k) => write!(f, "object {o} vertex {v} {}", ["x", "y", "z"][k]),
            Param::Albedo(o) => write!(f, "object {o} albedo"),
            Param::VertexAlbedo(o, v) => write!(f, "object {o} vertex {v} albedo"),
        }
    }
}

/// One parameter's comparison.
#[derive(Clone, Debug)]
pub struct Row {
    pub param: Param,
    /// The interior derivative (what finite differences at fixed random numbers see).
    pub adjoint: f64,
    /// The visibility boundary terms' part of the gradient (0 when they are off or do
    /// not apply); the gradient `umbra grad` returns is `adjoint + boundary`.
    pub boundary: f64,
    /// `(h, finite difference)` per step.
    pub fd: Vec<(f64, f64)>,
}

impl Row {
    /// Smallest relative error over the steps, against `max(|fd|, floor)`.
    pub fn error(&self, floor: f64) -> f64 {
        self.fd
            .iter()
            .map(|&(_, fd)| (self.adjoint - fd).abs() / fd.abs().max(floor))
            .fold(f64::INFINITY, f64::min)
    }

    /// How far the finite differences of the steps disagree with each other:
    /// `(max − min) / max(max |fd|, floor)`. Where a vertex moves a shadow across the
    /// fixed random numbers' samples, differences of the loss jump and do not converge
    /// with the step, so they are no reference: [`FD_UNSTABLE`] marks those rows.
    pub fn fd_spread(&self, floor: f64) -> f64 {
        let (lo, hi, big) = self.fd.iter().fold(
            (f64::INFINITY, f64::NEG_INFINITY, 0.0f64),
            |(lo, hi, big), &(_, fd)| (lo.min(fd), hi.max(fd), big.max(fd.abs())),
        );
        if self.fd.len() < 2 {
            return 0.0;
        }
        (hi - lo) / big.max(floor)
    }
}

/// A finite-difference spread (relative, [`Row::fd_spread`]) above which a row's
/// differences are no reference. Smooth rows spread by the steps' truncation error,
/// `(h/σ)²/6`: under 2 % for the default steps on a kernel of one 4 mm bin.
pub const FD_UNSTABLE: f64 = 0.1;

/// `scene` with `path`'s roulette survival fixed at what the pilot picks for it
/// ([`roulette::resolved`]), so the renders of the moved scenes play the same roulette
/// as the adjoint (common random numbers), as their sampling is frozen at `base`.
fn frozen_roulette(scene: &Scene, opts: &RenderOptions) -> Result<Scene> {
    let geom = SceneGeometry::build(scene);
    roulette::resolved(scene, &geom, opts, Pass::Gradient)
}

/// The scene's loss at its current parameters, sampling frozen at `base`.
fn loss(scene: &Scene, base: &SceneGeometry, opts: &RenderOptions, target: &[f32]) -> Result<f64> {
    let geom = SceneGeometry::build(scene).with_sampling_of(base);
    let h = primal(scene, &geom, opts)?;
    Ok(h.iter()
        .zip(target)
        .map(|(h, &t)| (h - t as f64).powi(2))
        .sum())
}

/// The transient in f64: `tri3` through its reference path, Monte Carlo as rendered.
pub fn primal(scene: &Scene, geom: &SceneGeometry, opts: &RenderOptions) -> Result<Vec<f64>> {
    if opts.model == Model::Tri3 {
        let film = Film::new(&scene.film);
        let mesh = Tri3Mesh::build(scene, geom, opts.subdivision);
        let mut out = vec![0.0; scene.num_measurements() * film.bins];
        for (m, hist) in out.chunks_mut(film.bins).enumerate() {
            let ctx = MeasurementCtx::new(scene, geom, &film, m);
            tri3_exact::render_measurement(&mesh, &ctx, &film, opts.visibility, hist);
        }
        return Ok(out);
    }
    Ok(render(scene, geom, opts, None)?
        .data
        .iter()
        .map(|&v| v as f64)
        .collect())
}

/// The scene with `p` moved by about `h`, and the step actually taken (in f32).
fn perturbed(scene: &Scene, p: Param, h: f64) -> (Scene, f64) {
    let mut s = scene.clone();
    let x = match p {
        Param::Vertex(o, v, k) => &mut s.objects[o].mesh.positions[v][k],
        Param::Albedo(o) => &mut s.objects[o].albedo,
        Param::VertexAlbedo(o, v) => &mut s.objects[o]
            .mesh
            .vertex_albedo
            .as_mut()
            .expect("vertex albedo")[v],
    };
    let old = *x;
    *x += h as f32;
    let step = (*x - old) as f64;
    (s, step)
}

/// `per_object` vertex coordinates of each object (vertices used by a face, picked by a
/// fixed generator), then each object's albedo, or two vertex albedos for a mesh with
/// vertex colours.
pub fn pick_params(scene: &Scene, per_object: usize, seed: u64) -> Vec<Param> {
    let mut state = seed ^ 0x9E37_79B9_7F4A_7C15;
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 33) as usize
    };
    let mut ps = Vec::new();
    for (o, obj) in scene.objects.iter().enumerate() {
        let mut used: Vec<usize> = obj
            .mesh
            .triangles
            .iter()
            .flatten()
            .map(|&i| i as usize)
            .collect();
        used.sort_unstable();
        used.dedup();
        for _ in 0..per_object.min(3 * used.len()) {
            ps.push(Param::Vertex(o, used[next() % used.len()], next() % 3));
        }
        if obj.mesh.vertex_albedo.is_none() {
            ps.push(Param::Albedo(o));
        } else {
            for _ in 0..2 {
                ps.push(Param::VertexAlbedo(o, used[next() % used.len()]));
            }
        }
    }
    ps
}

/// The target of the check, the adjoint histogram at the scene, the gradient and the
/// geometry the finite differences freeze their sampling at.
pub fn setup(
    scene: &Scene,
    opts: &RenderOptions,
) -> Result<(Vec<f32>, Vec<f32>, Gradient, SceneGeometry)> {
    let base = SceneGeometry::build(scene);
    let mut moved = scene.clone();
    for o in &mut moved.objects {
        o.mesh
            .positions
            .iter_mut()
            .for_each(|p| *p += 0.02 * scene.wall.normal());
    }
    let target_opts = RenderOptions {
        seed: opts.seed.wrapping_add(1),
        ..*opts
    };
    let target: Vec<f32> = primal(&moved, &SceneGeometry::build(&moved), &target_opts)?
        .iter()
        .map(|&v| v as f32)
        .collect();
    let h0 = primal(scene, &base, opts)?;
    let h0_32: Vec<f32> = h0.iter().map(|&v| v as f32).collect();
    let bins = scene.film.temporal_bins as usize;
    let (_, adjoint) = Loss::L2.evaluate(&h0_32, &target, bins)?;
    let g = gradient(scene, &base, opts, &adjoint, None)?;
    Ok((target, adjoint, g, base))
}

/// Compares the adjoint with central differences at steps `hs` (vertex steps in m;
/// albedo steps are 30x larger, the albedo's scale being ~1 against a mesh's ~0.03 m).
pub fn run(scene: &Scene, opts: &RenderOptions, params: &[Param], hs: &[f64]) -> Result<Vec<Row>> {
    let scene = &frozen_roulette(scene, opts)?;
    let (target, adjoint, full, base) = setup(scene, opts)?;
    let g = if full.boundary {
        let mut interior_scene = scene.clone();
        interior_scene.render.boundary_terms = false;
        gradient(&interior_scene, &base, opts, &adjoint, None)?
    } else {
        full.clone()
    };
    let value = |g: &Gradient, p: Param| match p {
        Param::Vertex(o, v, k) => g.vertices[o][v][k],
        Param::Albedo(o) => g.albedo[o],
        Param::VertexAlbedo(o, v) => g.vertex_albedo[o].as_ref().map_or(0.0, |a| a[v]),
    };
    let mut rows = Vec::new();
    for &p in params {
        let adjoint = value(&g, p);
        let boundary = value(&full, p) - adjoint;
        let mut fd = Vec::new();
        for &h in hs {
            let h = if matches!(p, Param::Albedo(_)) {
                30.0 * h
            } else {
                h
            };
            let ((up, hp), (down, hm)) = (perturbed(scene, p, h), perturbed(scene, p, -h));
            let plus = loss(&up, &base, opts, &target)?;
            let minus = loss(&down, &base, opts, &target)?;
            fd.push((h, (plus - minus) / (hp - hm)));
        }
        rows.push(Row {
            param: p,
            adjoint,
            boundary,
            fd,
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(fd: &[f64]) -> Row {
        Row {
            param: Param::Albedo(0),
            adjoint: 1.0,
            boundary: 0.0,
            fd: fd.iter().map(|&v| (1e-4, v)).collect(),
        }
    }

    #[test]
    fn jumping_differences_are_no_reference_converging_ones_are() {
        // The occluded study's occluder vertex (path, 64 spp): the steps' differences.
        let jumps = row(&[3.671566e-6, -2.712298e-7, -1.650832e-6]);
        assert!(jumps.fd_spread(1e-7) > FD_UNSTABLE);
        // The letter's: truncation error only.
        let smooth = row(&[-3.917567e-5, -3.914674e-5, -3.910839e-5]);
        assert!(smooth.fd_spread(1e-7) < 0.01);
        assert_eq!(row(&[2.0]).fd_spread(0.0), 0.0);
    }
}
