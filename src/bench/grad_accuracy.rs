//! Gradient error against wall-clock time (`umbra bench grad-accuracy`): for each way
//! Umbra can compute `dLoss/d(vertex positions)`, the relative L2 error of the gradient
//! vector against a converged reference, as a function of the time it takes.
//!
//! The loss is linear in the transient for this comparison: `L = ⟨δH, H⟩` with a fixed
//! adjoint histogram `δH` (the residual of `tri3` against the scene with every vertex
//! moved 1 cm away from the wall), so every method estimates the same vector
//! `g = Σ δH · dH/dθ` and no forward noise enters through `δH`. In a fit `δH = H − T`
//! needs a forward render at the same spp: the adjoint methods' times include one.
//!
//! Methods (all vertex coordinates of the scene; albedo left out, its derivative is the
//! render itself):
//! - `tri3` adjoint (exact derivative of the deterministic model, `f64` reference path,
//!   sub-triangle visibility) at subdivision thresholds 2, 0.6, 0.15, 0.05;
//! - path replay of `mc3` and of the multi-bounce path tracer (MIS of hidden-geometry and
//!   BSDF sampling), doubling spp;
//! - central finite differences (step 1 mm; the renderers' `f32` kernels) of `tri3`, and of
//!   the path tracer with common
//!   random numbers (same seed, same sampling distribution: the perturbed geometry keeps
//!   the base's triangle-choice pdf), doubling spp; two renders per coordinate.
//!
//! Reference: path replay with all techniques at `reference_spp`, two halves of different
//! seeds (cached next to the transient references); their difference gives its own
//! error, removed from every error in quadrature. The truth is multi-bounce: on the
//! concave corner the three-bounce gradients (`tri3`, `mc3`) level off at the share of
//! the gradient carried by longer paths.
//!
//! Scenes: a 30 cm square tilted 30° (4 vertices, three bounces only) and the concave
//! corner of [`super::accuracy`] (6 vertices, interreflections); both on the accuracy
//! scenes' capture (confocal 16 x 16, 256 bins of 8 mm, Gaussian σ = 8 mm: a box kernel
//! has no time-shift derivative, see the stability study).

use super::accuracy::{self, Point};
use super::{rel_l2, with_techniques};
use crate::adjoint::{check, gradient};
use crate::error::Result;
use crate::geometry::mesh::TriMesh;
use crate::geometry::SceneGeometry;
use crate::scene::{Model, Scene, Visibility};
use crate::transport::{RenderOptions, Renderer};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Finite-difference step for vertex coordinates (m).
pub const FD_STEP: f64 = 1e-3;

/// The two scenes of the module doc, by short name.
pub fn scenes() -> Result<Vec<(&'static str, Scene)>> {
    let (c, s) = (30f32.to_radians().cos(), 30f32.to_radians().sin());
    let square = format!(
        "v {} -0.15 {}\nv {} -0.15 {}\nv {} 0.15 {}\nv {} 0.15 {}\nf 1 4 3 2\n",
        -0.15 * c,
        0.15 * s,
        0.15 * c,
        -0.15 * s,
        0.15 * c,
        -0.15 * s,
        -0.15 * c,
        0.15 * s
    );
    let square = TriMesh::parse_obj(&square, Path::new("tilted_square.obj"))?;
    let corner = accuracy::scene("corner")?;
    Ok(vec![
        (
            "square",
            accuracy::scene_with(square, [0.05, 0.02, 0.9], false)?,
        ),
        ("corner", corner),
    ])
}

/// The fixed adjoint histogram `δH` of the module doc.
pub fn adjoint_histogram(scene: &Scene) -> Result<Vec<f32>> {
    let opts = RenderOptions {
        model: Model::Tri3,
        visibility: Visibility::Subtriangle,
        ..RenderOptions::from_scene(scene)
    };
    let geom = SceneGeometry::build(scene);
    let h = check::primal(scene, &geom, &opts)?;
    let mut moved = scene.clone();
    let n = scene.wall.normal();
    for o in &mut moved.objects {
        o.mesh.positions.iter_mut().for_each(|p| *p += 0.01 * n);
    }
    let t = check::primal(&moved, &SceneGeometry::build(&moved), &opts)?;
    Ok(h.iter().zip(&t).map(|(a, b)| (a - b) as f32).collect())
}

/// All vertex coordinates' derivatives, object by object, vertex by vertex, x y z.
fn flat(g: &crate::adjoint::Gradient) -> Vec<f64> {
    g.vertices.iter().flatten().flatten().copied().collect()
}

/// The gradient of `⟨δH, H⟩` by the adjoint pass of `opts.model`, and its time
/// (forward render at the same settings included).
fn by_adjoint(scene: &Scene, opts: &RenderOptions, adj: &[f32]) -> Result<(Vec<f64>, f64)> {
    let geom = SceneGeometry::build(scene);
    let start = Instant::now();
    std::hint::black_box(Renderer::new(scene, &geom, opts)?.render(None)?);
    let g = gradient(scene, &geom, opts, adj, None)?;
    Ok((flat(&g), start.elapsed().as_secs_f64()))
}

/// The same gradient by central differences of `⟨δH, H⟩`, and its time.
fn by_differences(scene: &Scene, opts: &RenderOptions, adj: &[f32]) -> Result<(Vec<f64>, f64)> {
    let base = SceneGeometry::build(scene);
    let start = Instant::now();
    let mut g = Vec::new();
    for (o, obj) in scene.objects.iter().enumerate() {
        for v in 0..obj.mesh.positions.len() {
            for k in 0..3 {
                let side = |sign: f32| -> Result<(f64, f64)> {
                    let mut s = scene.clone();
                    let x = &mut s.objects[o].mesh.positions[v][k];
                    let old = *x;
                    *x += sign * FD_STEP as f32;
                    let step = (*x - old) as f64;
                    let geom = SceneGeometry::build(&s).with_sampling_of(&base);
                    let h = Renderer::new(&s, &geom, opts)?.render(None)?.data;
                    let loss = h.iter().zip(adj).map(|(&h, &a)| h as f64 * a as f64).sum();
                    Ok((loss, step))
                };
                let ((lp, hp), (lm, hm)) = (side(1.0)?, side(-1.0)?);
                g.push((lp - lm) / (hp - hm));
            }
        }
    }
    Ok((g, start.elapsed().as_secs_f64()))
}

/// The reference gradient and its own relative error (half the halves' difference).
pub struct Reference {
    pub grad: Vec<f64>,
    pub error: f64,
    pub path: PathBuf,
}

pub fn reference(
    name: &str,
    scene: &Scene,
    adj: &[f32],
    spp: u32,
    cache: &Path,
) -> Result<Reference> {
    let path = cache.join(format!(
        "grad_reference_{name}_{spp}_{:016x}.npy",
        accuracy::scene_key(scene)
    ));
    let all = with_techniques(scene, true, true, true);
    let geom = SceneGeometry::build(&all);
    let (grad, error) = super::reference_halves(&path, [9101, 9102], |seed| {
        let opts = RenderOptions {
            model: Model::Path,
            spp: (spp / 2).max(1),
            seed,
            ..RenderOptions::from_scene(&all)
        };
        let g = flat(&gradient(&all, &geom, &opts, adj, None)?);
        Ok(g.iter().map(|&x| x as f32).collect())
    })?;
    let grad = grad.iter().map(|&x| x as f64).collect();
    Ok(Reference { grad, error, path })
}

/// Every method's curve on `scene`; a curve stops after a point longer than `budget` s.
pub fn curves(
    name: &'static str,
    scene: &Scene,
    adj: &[f32],
    r: &Reference,
    budget: f64,
) -> Result<Vec<Point>> {
    let mut out = Vec::new();
    let mut push = |method: &str, setting: f64, g: &[f64], seconds: f64| {
        let raw = rel_l2(g, &r.grad);
        eprintln!(
            "bench grad-accuracy: {name}: {method} {setting}: {seconds:.3} s, {:.3} %",
            100.0 * raw
        );
        out.push(Point::measured(
            name, method, setting, seconds, raw, r.error,
        ));
    };
    let tri3 = |s: f32| RenderOptions {
        model: Model::Tri3,
        subdivision: s,
        visibility: Visibility::Subtriangle,
        ..RenderOptions::from_scene(scene)
    };
    for s in [2.0f32, 0.6, 0.15, 0.05] {
        let (g, t) = by_adjoint(scene, &tri3(s), adj)?;
        push("tri3 adjoint", s as f64, &g, t);
        if t > budget {
            break;
        }
    }
    let (g, t) = by_differences(scene, &tri3(crate::scene::DEFAULT_SUBDIVISION), adj)?;
    push(
        "tri3 finite differences",
        crate::scene::DEFAULT_SUBDIVISION as f64,
        &g,
        t,
    );
    let all = with_techniques(scene, true, true, true);
    type Method = fn(&Scene, &RenderOptions, &[f32]) -> Result<(Vec<f64>, f64)>;
    let ladders: [(&str, Model, Method); 3] = [
        ("mc3 path replay", Model::Mc3, by_adjoint),
        ("path replay (MIS)", Model::Path, by_adjoint),
        (
            "path finite differences (common random numbers)",
            Model::Path,
            by_differences,
        ),
    ];
    for (label, model, method) in ladders {
        let mut spp = 4u32;
        loop {
            let opts = RenderOptions {
                model,
                spp,
                seed: 23,
                ..RenderOptions::from_scene(&all)
            };
            let (g, t) = method(&all, &opts, adj)?;
            push(label, spp as f64, &g, t);
            if t > budget || spp >= 1 << 20 {
                break;
            }
            spp *= 2;
        }
    }
    Ok(out)
}
