//! Light transport: the estimators of DESIGN §3 and the parallel driver that runs them
//! over all measurements.
//!
//! Estimators do not write to a film. For each sample they emit [`Contribution`]s
//! (OPL, weight, bounce count, the path's vertices) to a [`Sink`]. The primal sink
//! splats them through the temporal kernel; the adjoint sink (gradients) reads the
//! adjoint histogram through the same kernel. One sampling routine serves both.
//!
//! Determinism: sample `i` of measurement `m` draws its numbers from
//! `Sampler::new(seed, m, i)`; samples are grouped in fixed blocks of [`BLOCK_SPP`]
//! whose histograms are summed in block order, so the output does not depend on the
//! number of threads.

pub mod mc3;
pub mod path;

use crate::error::{Error, Result};
use crate::film::Film;
use crate::geometry::{SceneGeometry, SurfaceKind};
use crate::rng::Sampler;
use crate::scene::{Model, Scene};
use glam::Vec3;
use rayon::prelude::*;
use std::f32::consts::FRAC_1_PI;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// Samples per block of work (the unit of parallelism and of progress).
pub const BLOCK_SPP: u32 = 1024;

/// A vertex a contribution depends on: where it is and what surface it sits on.
#[derive(Clone, Copy, Debug)]
pub struct PathVertex {
    pub p: Vec3,
    pub kind: SurfaceKind,
    /// Flat hidden-triangle index (`u32::MAX` on the wall).
    pub flat: u32,
    pub bary: [f32; 2],
}

/// One path's contribution to a measurement: radiance `weight` arriving at OPL `opl`.
#[derive(Clone, Copy, Debug)]
pub struct Contribution<'a> {
    /// Optical path length (m), legs to the laser and detector included if requested.
    pub opl: f32,
    /// Monte Carlo weight (radiance, already divided by the sampling pdf).
    pub weight: f32,
    /// Scattering events from the laser spot to the sensor point inclusive (3 = one
    /// hidden bounce).
    pub bounces: u32,
    /// Vertices from the sensor point `x_s` to the laser spot `x_l`.
    pub vertices: &'a [PathVertex],
}

/// Receives contributions.
pub trait Sink {
    fn add(&mut self, c: &Contribution);
}

/// The primal sink: splats weights into a histogram.
pub struct HistogramSink<'a> {
    pub film: &'a Film,
    pub hist: &'a mut [f64],
}

impl Sink for HistogramSink<'_> {
    #[inline]
    fn add(&mut self, c: &Contribution) {
        self.film.splat(c.opl, c.weight, self.hist);
    }
}

/// Everything a sample of one measurement needs: its wall points, the laser's power,
/// radiometric constants and the scene's surfaces.
pub struct MeasurementCtx<'a> {
    pub scene: &'a Scene,
    pub geom: &'a SceneGeometry,
    /// Centre of the laser spot on the wall.
    pub x_l: Vec3,
    /// Sensor point on the wall.
    pub x_s: Vec3,
    pub n_w: Vec3,
    /// Power `P(x_l)` delivered to the spot (DESIGN §2).
    pub power: f32,
    /// Wall BRDF `ρ_w / π`.
    pub f_wall: f32,
    /// OPL of the detector leg `|x_s - detector|` if counted, else 0.
    pub opl_sensor_leg: f32,
    /// OPL range that can reach the film (kernel support included): paths outside skip
    /// their visibility rays.
    pub opl_min: f32,
    pub opl_max: f32,
}

impl<'a> MeasurementCtx<'a> {
    pub fn new(scene: &'a Scene, geom: &'a SceneGeometry, film: &Film, m: usize) -> Self {
        let (x_l, x_s) = scene.measurement_points(m);
        let n_w = geom.wall_normal;
        let margin = match film.kernel {
            crate::scene::KernelSpec::Box => 0.0,
            crate::scene::KernelSpec::Gaussian { sigma_opl } => {
                crate::film::GAUSS_CUTOFF * sigma_opl as f64
            }
        };
        MeasurementCtx {
            scene,
            geom,
            x_l,
            x_s,
            n_w,
            power: scene.laser.power_at(x_l, n_w),
            f_wall: scene.wall.albedo * FRAC_1_PI,
            opl_sensor_leg: if scene.account_first_and_last_bounces {
                (x_s - scene.detector.origin).length()
            } else {
                0.0
            },
            opl_min: (film.start - margin) as f32,
            opl_max: (film.end() + margin) as f32,
        }
    }

    /// OPL of the laser leg `|laser - x_l|` if counted, else 0.
    pub fn opl_laser_leg(&self, x_l: Vec3) -> f32 {
        if self.scene.account_first_and_last_bounces {
            (self.scene.laser.origin - x_l).length()
        } else {
            0.0
        }
    }

    pub fn wall_vertex(&self, p: Vec3) -> PathVertex {
        PathVertex {
            p,
            kind: SurfaceKind::Wall,
            flat: u32::MAX,
            bary: [0.0; 2],
        }
    }
}

/// Sample count, seed and model of one render.
#[derive(Clone, Copy, Debug)]
pub struct RenderOptions {
    pub model: Model,
    pub spp: u32,
    pub seed: u64,
}

impl RenderOptions {
    pub fn from_scene(scene: &Scene) -> Self {
        RenderOptions {
            model: scene.render.model,
            spp: scene.render.spp,
            seed: scene.render.seed,
        }
    }
}

/// Shared progress counter and cancellation flag, for progress bars and Ctrl-C.
#[derive(Default, Debug)]
pub struct Progress {
    pub samples_done: AtomicU64,
    pub cancel: AtomicBool,
}

/// A rendered transient in mitransient's layout, row-major.
#[derive(Clone, Debug)]
pub struct Transient {
    pub data: Vec<f32>,
    /// `(sy, sx, T)` or `(ly, lx, sy, sx, T)`.
    pub shape: Vec<usize>,
}

impl Transient {
    pub fn bins(&self) -> usize {
        *self.shape.last().unwrap_or(&0)
    }
}

/// Total samples a render draws (for progress bars).
pub fn total_samples(scene: &Scene, opts: &RenderOptions) -> u64 {
    scene.num_measurements() as u64 * opts.spp as u64
}

/// Checks that `opts.model` can render `scene` and resolves `auto`.
pub fn resolve_model(scene: &Scene, opts: &RenderOptions) -> Result<Model> {
    let t = &scene.render.techniques;
    match opts.model {
        Model::Tri3 | Model::Auto => Err(Error::Invalid(format!(
            "model '{}' is not available yet: use mc3 or path",
            opts.model.name()
        ))),
        Model::Path if !t.bsdf_sampling && !t.hidden_geometry_sampling => Err(Error::Invalid(
            "path model: bsdf_sampling and hidden_geometry_sampling are both off, so no path can leave the wall".into(),
        )),
        Model::Path if !t.laser_sampling && scene.laser.spot_radius <= 0.0 => Err(Error::Invalid(
            "path model: with laser sampling off, paths must hit the lit spot, which needs laser.spot_radius > 0".into(),
        )),
        m => Ok(m),
    }
}

/// Renders the scene's transient with the given model, spp and seed.
pub fn render(
    scene: &Scene,
    geom: &SceneGeometry,
    opts: &RenderOptions,
    progress: Option<&Progress>,
) -> Result<Transient> {
    let model = resolve_model(scene, opts)?;
    if geom.hidden.is_empty() {
        let shape = scene.output_shape();
        return Ok(Transient {
            data: vec![0.0; shape.iter().product()],
            shape,
        });
    }
    let film = Film::new(&scene.film);
    let bins = film.bins;
    let n_blocks = opts.spp.div_ceil(BLOCK_SPP);
    let mut data = vec![0.0f32; scene.num_measurements() * bins];
    let cancelled = AtomicBool::new(false);
    data.par_chunks_mut(bins).enumerate().for_each(|(m, out)| {
        let ctx = MeasurementCtx::new(scene, geom, &film, m);
        let blocks: Vec<Option<Vec<f64>>> = (0..n_blocks)
            .into_par_iter()
            .map(|b| {
                if cancelled.load(Ordering::Relaxed)
                    || progress.is_some_and(|p| p.cancel.load(Ordering::Relaxed))
                {
                    cancelled.store(true, Ordering::Relaxed);
                    return None;
                }
                let first = b * BLOCK_SPP;
                let last = (first + BLOCK_SPP).min(opts.spp);
                let mut hist = vec![0.0f64; bins];
                let mut sink = HistogramSink {
                    film: &film,
                    hist: &mut hist,
                };
                run_samples(model, &ctx, opts.seed, m as u64, first..last, &mut sink);
                if let Some(p) = progress {
                    p.samples_done
                        .fetch_add((last - first) as u64, Ordering::Relaxed);
                }
                Some(hist)
            })
            .collect();
        let inv_spp = 1.0 / opts.spp as f64;
        let mut acc = vec![0.0f64; bins];
        for h in blocks.into_iter().flatten() {
            for (a, v) in acc.iter_mut().zip(h) {
                *a += v;
            }
        }
        for (o, a) in out.iter_mut().zip(acc) {
            *o = (a * inv_spp) as f32;
        }
    });
    if cancelled.load(Ordering::Relaxed) {
        return Err(Error::Cancelled);
    }
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(Error::Invalid(format!(
            "render produced a non-finite value at flat index {i}: refusing to write it (please report this scene)"
        )));
    }
    Ok(Transient {
        data,
        shape: scene.output_shape(),
    })
}

/// Runs samples `range` of measurement `m` with the model's sampling routine.
pub fn run_samples<S: Sink>(
    model: Model,
    ctx: &MeasurementCtx,
    seed: u64,
    m: u64,
    range: std::ops::Range<u32>,
    sink: &mut S,
) {
    let mut scratch = path::PathScratch::default();
    for i in range {
        let mut sampler = Sampler::new(seed, m, i);
        match model {
            Model::Mc3 => mc3::sample(ctx, &mut sampler, sink),
            Model::Path => path::sample(ctx, &mut sampler, &mut scratch, sink),
            Model::Tri3 | Model::Auto => unreachable!("resolved before rendering"),
        }
    }
}

/// Cosines at a surface point with unit normal `n` between unit directions `to_a` and
/// `to_b` (both pointing away from the point): `(|cos_a|, |cos_b|)` if light can scatter
/// from one to the other there, `None` otherwise. A one-sided surface (Mitsuba's
/// `diffuse`) scatters only on its front; a two-sided one on either side, never across.
#[inline]
pub fn scatter_cosines(n: Vec3, two_sided: bool, to_a: Vec3, to_b: Vec3) -> Option<(f32, f32)> {
    let (ca, cb) = (n.dot(to_a), n.dot(to_b));
    let ok = if two_sided {
        ca * cb > 0.0
    } else {
        ca > 0.0 && cb > 0.0
    };
    ok.then_some((ca.abs(), cb.abs()))
}

/// A point of the laser spot: its centre, or a uniform point of the lit disk.
#[inline]
pub fn sample_spot(ctx: &MeasurementCtx, u: [f32; 2]) -> Vec3 {
    let r = ctx.scene.laser.spot_radius;
    if r > 0.0 {
        crate::geometry::sampling::uniform_disk(ctx.x_l, ctx.n_w, r, u)
    } else {
        ctx.x_l
    }
}
