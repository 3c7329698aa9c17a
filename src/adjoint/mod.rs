//! Gradients of a loss on the transient with respect to the hidden meshes' vertex
//! positions and albedos, by path replay (DESIGN §4–6).
//!
//! Given the adjoint histogram `δH = dLoss/dH`, the gradient is
//! `Σ_contributions Σ_b δH[m, b] d(w K_b(τ))/dθ = Σ (A dw/dθ + w B dτ/dθ)` with
//! `A = Σ_b δH[m, b] K_b(τ)` and `B = Σ_b δH[m, b] dK_b/dτ` ([`Film::adjoint`]).
//!
//! The adjoint pass reruns the forward pass's sampling routine with the same
//! counter-based random numbers (`Sampler::new(seed, m, i)`), so it sees exactly the
//! forward pass's paths; the routine, handed an adjoint [`Sink`], evaluates each
//! contribution's weight and OPL once more in [`dual::Dual`] numbers with respect to the
//! sampled triangle's corners and corner albedos (the same generic formula as the primal
//! value, so the two cannot drift). Hidden points keep their barycentrics, so they move
//! with the corners, and the area factor `A_t` of the sample's pdf `p_t / A_t` is
//! differentiated while the discrete choice `p_t` stays fixed. Nothing is recorded per
//! sample: memory is one 12-vector per hidden triangle per work chunk, whatever the spp.
//!
//! `tri3` is deterministic: its adjoint is the exact derivative of the model, run in the
//! forward kernel's `f32` lanes ([`tri3_adjoint`]: the same per-pair physics, the pulse
//! reversed through its closed form, so the pulse's time shift, its shape and the
//! sub-triangle's area all move), tested against the `f64` dual-number model
//! (`tri3_exact`).
//!
//! `path` (multi-bounce) replays its paths the same way, with dual numbers over up to four
//! hidden triangles per path (see `transport::path`): area-sampled points keep their
//! barycentrics, ray-found points move along their ray.
//!
//! Supports: `tri3`, `mc3`, `path` (a finite laser spot needs laser sampling), per-object and per-vertex albedo,
//! box and Gaussian kernels (box: no time-shift term for the Monte Carlo models, so vertex
//! gradients miss their largest part; a warning says so). Visibility changes (silhouettes,
//! occlusion between hidden objects) add the boundary terms of [`boundary`] to the
//! interior derivative, by default, for every shadow of the three-bounce transport and of
//! `path`'s longer paths (`boundary_paths`; what is not covered: docs/GRADIENTS.md).

pub mod boundary;
mod boundary_paths;
mod chain;
pub mod check;
pub mod dual;
pub mod edge;
pub mod edge_nodes;
pub mod loss;

pub use loss::Loss;

use crate::error::{Error, Result};
use crate::film::Film;
use crate::geometry::SceneGeometry;
use crate::scene::{KernelSpec, Model, Scene};
use crate::transport::gate::Pass;
use crate::transport::mc3::TRI_PARAMS;
use crate::transport::path::PathScratch;
use crate::transport::tri3_adjoint;
use crate::transport::{
    Contribution, HiddenGrad, MeasurementCtx, Progress, RenderOptions, Renderer, Sink,
};
use boundary::Boundary;
use rayon::prelude::*;

/// `dLoss/dθ`, per hidden object in scene order.
#[derive(Clone, Debug, Default)]
pub struct Gradient {
    /// dLoss/d(vertex position), world space, one row per vertex in the order of the
    /// object's OBJ `v` lines.
    pub vertices: Vec<Vec<[f64; 3]>>,
    /// dLoss/d(object albedo); 0 for an object with per-vertex albedo.
    pub albedo: Vec<f64>,
    /// dLoss/d(vertex albedo) for objects with per-vertex albedo.
    pub vertex_albedo: Vec<Option<Vec<f64>>>,
    /// `path`: contributions emitted, and how many of them met more hidden triangles
    /// than one path's derivatives can follow (`path::PATH_TRIANGLES`): those lose the
    /// further triangles' share of the gradient.
    pub contributions: u64,
    pub truncated: u64,
    /// Whether the visibility boundary terms were added ([`boundary`]), and how many
    /// edge quadrature nodes (summed over measurements) carried them.
    pub boundary: bool,
    pub boundary_nodes: u64,
}

/// The adjoint sink: accumulates `A dw + w B dτ` into per-triangle local gradients.
struct AdjointSink<'a> {
    film: &'a Film,
    /// `δH` of the current measurement.
    adjoint: &'a [f32],
    tri_grad: &'a mut [[f64; TRI_PARAMS]],
    /// 1/spp: the forward estimate is the mean over samples.
    scale: f64,
}

impl Sink for AdjointSink<'_> {
    const ADJOINT: bool = true;

    fn add(&mut self, _c: &Contribution) {}

    fn add_grad(&mut self, c: &Contribution, grads: &[HiddenGrad]) {
        let (a, b) = self.film.adjoint(c.opl, self.adjoint);
        if a == 0.0 && b == 0.0 {
            return;
        }
        let (a, wb) = (a * self.scale, c.weight as f64 * b * self.scale);
        for g in grads {
            let acc = &mut self.tri_grad[g.flat as usize];
            for ((acc, dw), dt) in acc.iter_mut().zip(g.weight).zip(g.opl) {
                *acc += a * dw as f64 + wb * dt as f64;
            }
        }
    }
}

/// Work is split into this many chunks of measurements at most, whatever the thread
/// count, and the chunks' sums are added in order: the gradient is bit-identical for any
/// number of threads, and for any split of the chunks between processes
/// ([`gradient_chunks`], [`combine`]: `umbra.distributed`).
pub const MAX_CHUNKS: usize = 16;

/// How many chunks a gradient over `measurements` measurements has.
pub fn chunk_count(measurements: usize) -> usize {
    MAX_CHUNKS.min(measurements).max(1)
}

/// The measurements of chunk `c` of a gradient over `measurements` measurements.
pub fn chunk_measurements(c: usize, measurements: usize) -> std::ops::Range<usize> {
    let chunks = chunk_count(measurements);
    (c * measurements / chunks)..((c + 1) * measurements / chunks)
}

/// `dLoss/dθ` for the adjoint histogram `adjoint` (`dLoss/dH`, the render's shape), on
/// the render's driver ([`Renderer::prepare`]: the same gate, model, film, measurements
/// and sample blocks as the forward pass): every chunk's share ([`gradient_chunks`]),
/// added in chunk order ([`combine`]).
pub fn gradient(
    scene: &Scene,
    geom: &SceneGeometry,
    opts: &RenderOptions,
    adjoint: &[f32],
    progress: Option<&Progress>,
) -> Result<Gradient> {
    let chunks = chunk_count(scene.num_measurements());
    let parts = gradient_chunks(scene, geom, opts, adjoint, 0..chunks, progress)?;
    combine(scene, geom, opts, parts)
}

/// One chunk's share of the gradient ([`chunk_measurements`]): per-triangle local
/// gradients (corners, corner albedos; flat triangle order) and, with boundary terms,
/// per-vertex gradients. A chunk's share depends on the scene, the options, the chunk's
/// index and its adjoint rows only, not on the process or thread that computed it.
#[derive(Clone, Debug, PartialEq)]
pub struct ChunkGrad {
    pub index: usize,
    pub tri_grad: Vec<[f64; TRI_PARAMS]>,
    /// Boundary terms, per object vertex (`None` when they are off).
    pub vertex_grad: Option<boundary::VertexGrad>,
    pub emitted: u64,
    pub truncated: u64,
    pub boundary_nodes: u64,
}

/// The shares of chunks `chunks` ([`chunk_measurements`]); `adjoint` holds the adjoint
/// rows of exactly their measurements (`bins` values each, in order), not the whole
/// render's.
pub fn gradient_chunks(
    scene: &Scene,
    geom: &SceneGeometry,
    opts: &RenderOptions,
    adjoint: &[f32],
    chunks: std::ops::Range<usize>,
    progress: Option<&Progress>,
) -> Result<Vec<ChunkGrad>> {
    let driver = Renderer::prepare(scene, geom, opts, Pass::Gradient)?;
    let film = &driver.film;
    let (measurements, bins) = (scene.num_measurements(), film.bins);
    let total = chunk_count(measurements);
    if chunks.start >= chunks.end || chunks.end > total {
        return Err(Error::Invalid(format!(
            "gradient chunks {}..{}: the scene's gradient has chunks 0..{total}",
            chunks.start, chunks.end
        )));
    }
    let first = chunk_measurements(chunks.start, measurements).start;
    let last = chunk_measurements(chunks.end - 1, measurements).end;
    if adjoint.len() != (last - first) * bins {
        return Err(Error::Invalid(format!(
            "adjoint has {} values, the render {} ({} measurements x {bins} bins)",
            adjoint.len(),
            (last - first) * bins,
            last - first
        )));
    }
    if let Some(i) = adjoint.iter().position(|v| !v.is_finite()) {
        return Err(Error::Invalid(format!(
            "adjoint has a non-finite value at flat index {}",
            first * bins + i
        )));
    }
    let tris = geom.hidden.len();
    let spp = opts.spp.max(1);
    let boundary = boundary_terms_apply(scene, opts);
    let edges = (boundary && Boundary::occlusion_possible(scene, geom))
        .then(|| Boundary::new(scene, film, opts));
    // tri3's interior pass runs blocks outer over a chunk's measurements: the contexts
    // are built once, for it and the boundary terms.
    let tri3_ctxs: Option<Vec<MeasurementCtx>> = driver.tri3.as_ref().map(|_| {
        (first..last)
            .into_par_iter()
            .map(|m| driver.measurement(m))
            .collect()
    });
    let rows =
        |r: &std::ops::Range<usize>| &adjoint[(r.start - first) * bins..(r.end - first) * bins];
    let mut parts: Vec<ChunkGrad> = chunks
        .clone()
        .into_par_iter()
        .map(|c| {
            let mut tri_grad = vec![[0.0; TRI_PARAMS]; tris];
            let mut vertex_grad = edges.as_ref().map(|_| zero_vertex_grad(scene));
            let mut views = edge_nodes::ViewCache::default();
            let mut scratch = PathScratch::default();
            for m in chunk_measurements(c, measurements) {
                if Renderer::cancelled(progress) {
                    break;
                }
                let built;
                let ctx = match &tri3_ctxs {
                    Some(ctxs) => &ctxs[m - first],
                    None => {
                        built = driver.measurement(m);
                        &built
                    }
                };
                let adj = &adjoint[(m - first) * bins..(m - first + 1) * bins];
                if let (Some(b), Some(g), true) = (&edges, &mut vertex_grad, ctx.legs_visible) {
                    b.measurement(scene, ctx, m, film, adj, &mut views, g);
                }
                if tri3_ctxs.is_some() {
                    // The interior part runs after this loop, blocks outer
                    // (`tri3_adjoint`), and counts the progress.
                    continue;
                }
                if ctx.legs_visible {
                    let mut sink = AdjointSink {
                        film,
                        adjoint: adj,
                        tri_grad: &mut tri_grad,
                        scale: 1.0 / spp as f64,
                    };
                    for range in driver.sample_blocks() {
                        driver.run_block(ctx, m, range, &mut sink, &mut scratch);
                    }
                }
                Renderer::count(progress, spp as u64);
            }
            ChunkGrad {
                index: c,
                tri_grad,
                vertex_grad,
                emitted: scratch.emitted,
                truncated: scratch.truncated,
                boundary_nodes: views.nodes_used,
            }
        })
        .collect();
    if Renderer::cancelled(progress) {
        return Err(Error::Cancelled);
    }
    if let (Some(mesh), Some(ctxs)) = (&driver.tri3, &tri3_ctxs) {
        // One chunk at a time (each pass is parallel over the mesh's blocks), so each
        // chunk's interior share is its own, as for the Monte Carlo models.
        for part in &mut parts {
            let r = chunk_measurements(part.index, measurements);
            let ctx = &ctxs[r.start - first..r.end - first];
            part.tri_grad =
                tri3_adjoint::gradient(mesh, tris, ctx, film, opts.visibility, rows(&r), progress)
                    .ok_or(Error::Cancelled)?;
        }
    }
    Ok(parts)
}

/// The gradient from every chunk's share ([`gradient_chunks`], from one process or many),
/// added in chunk order: the same bits as [`gradient`].
pub fn combine(
    scene: &Scene,
    geom: &SceneGeometry,
    opts: &RenderOptions,
    mut parts: Vec<ChunkGrad>,
) -> Result<Gradient> {
    let total = chunk_count(scene.num_measurements());
    parts.sort_by_key(|p| p.index);
    let tris = geom.hidden.len();
    let vertices = zero_vertex_grad(scene);
    if parts.len() != total || parts.iter().enumerate().any(|(i, p)| p.index != i) {
        return Err(Error::Invalid(format!(
            "gradient chunks: got {:?}, the scene's gradient has chunks 0..{total}, each once",
            parts.iter().map(|p| p.index).collect::<Vec<_>>()
        )));
    }
    if let Some(p) = parts.iter().find(|p| {
        p.tri_grad.len() != tris
            || p.vertex_grad.as_ref().is_some_and(|v| {
                v.len() != vertices.len()
                    || v.iter().zip(&vertices).any(|(a, b)| a.len() != b.len())
            })
    }) {
        return Err(Error::Invalid(format!(
            "gradient chunk {}: its sizes are not this scene's ({} triangles)",
            p.index, tris
        )));
    }
    let mut tri_grad = vec![[0.0f64; TRI_PARAMS]; tris];
    let mut vertex_grad = vertices;
    let (mut contributions, mut truncated, mut nodes) = (0, 0, 0);
    for part in parts {
        for (acc, g) in tri_grad.iter_mut().zip(part.tri_grad) {
            acc.iter_mut().zip(g).for_each(|(a, g)| *a += g);
        }
        for (acc, g) in vertex_grad
            .iter_mut()
            .zip(part.vertex_grad.iter().flatten())
        {
            for (a, g) in acc.iter_mut().zip(g) {
                (0..3).for_each(|k| a[k] += g[k]);
            }
        }
        contributions += part.emitted;
        truncated += part.truncated;
        nodes += part.boundary_nodes;
    }
    let mut g = scatter(scene, geom, &tri_grad, vertex_grad);
    (g.contributions, g.truncated) = (contributions, truncated);
    g.boundary = boundary_terms_apply(scene, opts);
    g.boundary_nodes = nodes;
    Ok(g)
}

fn zero_vertex_grad(scene: &Scene) -> boundary::VertexGrad {
    scene
        .objects
        .iter()
        .map(|o| vec![[0.0; 3]; o.mesh.positions.len()])
        .collect()
}

/// Whether this gradient gets boundary terms: asked for (`render.boundary_terms`), a
/// model with visibility (`tri3` with `visibility = none` has none), and three-bounce
/// paths kept by the bounce filter.
pub fn boundary_terms_apply(scene: &Scene, opts: &RenderOptions) -> bool {
    scene.render.boundary_terms
        && Boundary::applies(scene, opts.model)
        && !(opts.model == Model::Tri3 && opts.visibility == crate::scene::Visibility::None)
}

/// Chains per-triangle local gradients (corners, corner albedos) to the objects'
/// vertices and albedos, on top of per-vertex gradients `vertices` (the boundary terms).
fn scatter(
    scene: &Scene,
    geom: &SceneGeometry,
    tri_grad: &[[f64; TRI_PARAMS]],
    vertices: boundary::VertexGrad,
) -> Gradient {
    let mut g = Gradient {
        contributions: 0,
        truncated: 0,
        boundary: false,
        boundary_nodes: 0,
        vertices,
        albedo: vec![0.0; scene.objects.len()],
        vertex_albedo: scene
            .objects
            .iter()
            .map(|o| o.mesh.vertex_albedo.as_ref().map(|a| vec![0.0; a.len()]))
            .collect(),
    };
    for (flat, local) in tri_grad.iter().enumerate() {
        let (object, tri) = geom.flat_to_local[flat];
        let (o, t) = (object as usize, tri as usize);
        let corners = scene.objects[o].mesh.triangles[t];
        for (i, &v) in corners.iter().enumerate() {
            for k in 0..3 {
                g.vertices[o][v as usize][k] += local[3 * i + k];
            }
            match &mut g.vertex_albedo[o] {
                Some(va) => va[v as usize] += local[9 + i],
                None => g.albedo[o] += local[9 + i],
            }
        }
    }
    g
}

/// The warning for Monte Carlo vertex gradients through a box kernel, if it applies
/// (`tri3`'s pulses have extent, so its box bins move smoothly and need no warning).
pub fn box_kernel_warning(scene: &Scene, model: Model) -> Option<&'static str> {
    (matches!(scene.film.kernel, KernelSpec::Box) && model != Model::Tri3).then_some(
        "vertex gradients of a Monte Carlo model with the box kernel miss the time-of-flight \
         term (a box histogram's derivative with respect to a path's length is zero): they \
         are biased and usually small; use kernel = \"gaussian\" (sigma_opl), or the tri3 \
         model. Albedo gradients are unaffected.",
    )
}
