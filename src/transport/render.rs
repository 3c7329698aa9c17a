//! The measurement driver of the render and of the gradient: [`Renderer::prepare`] checks
//! the scene and options at the gate, resolves the model (`auto` included), builds what
//! the model needs (the film, `tri3`'s sub-triangles), and hands out each measurement's
//! context, its Monte Carlo sample blocks and the progress count; [`Renderer::render`]
//! runs it over all measurements into histograms, `adjoint::gradient` over the same
//! measurements into gradient sums.
//!
//! Determinism: the Monte Carlo models draw sample `i` of measurement `m` from
//! `Sampler::new(seed, m, i)` in fixed blocks of [`BLOCK_SPP`] ([`Renderer::sample_blocks`]);
//! the render sums the blocks' histograms in block order; `tri3` is deterministic. Either
//! way the output does not depend on the number of threads.

use super::auto::{choose_model, AutoChoice};
use super::budget::FOLD_BLOCKS;
use super::gate::{self, Pass};
use super::path::PathScratch;
use super::tri3::{self, Tri3Mesh, Tri3Scratch};
use super::{run_samples, HistogramSink, MeasurementCtx, Sink, BLOCK_SPP};
use crate::error::{Error, Result};
use crate::film::Film;
use crate::geometry::SceneGeometry;
use crate::scene::{EarlySurvival, Model, Scene, Visibility};
use rayon::prelude::*;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

/// What to render: model, samples, seed, and the `tri3` / `auto` settings.
#[derive(Clone, Copy, Debug)]
pub struct RenderOptions {
    pub model: Model,
    pub spp: u32,
    pub seed: u64,
    pub visibility: Visibility,
    pub subdivision: f32,
    pub max_error: f32,
}

impl RenderOptions {
    pub fn from_scene(scene: &Scene) -> Self {
        Self::from_settings(&scene.render)
    }

    pub fn from_settings(r: &crate::scene::RenderSettings) -> Self {
        RenderOptions {
            model: r.model,
            spp: r.spp,
            seed: r.seed,
            visibility: r.visibility,
            subdivision: r.subdivision,
            max_error: r.max_error,
        }
    }
}

/// Shared progress counter and cancellation flag, for progress bars and Ctrl-C.
/// Work is counted in samples (Monte Carlo) or triangle pairs (`tri3`).
#[derive(Default, Debug)]
pub struct Progress {
    pub work_done: AtomicU64,
    pub cancel: AtomicBool,
}

/// A rendered transient in mitransient's layout, row-major.
#[derive(Clone, Debug)]
pub struct Transient {
    pub data: Vec<f32>,
    /// `(sy, sx, T)` or `(sy, sx, ly, lx, T)`.
    pub shape: Vec<usize>,
}

impl Transient {
    pub fn bins(&self) -> usize {
        *self.shape.last().unwrap_or(&0)
    }
}

/// A scene ready to render or differentiate with a resolved model: the one driver both
/// passes run on.
pub struct Renderer<'a> {
    scene: &'a Scene,
    geom: &'a SceneGeometry,
    /// The options, with `model` resolved.
    opts: RenderOptions,
    pub(crate) film: Film,
    /// The model that runs (never `Auto`).
    pub model: Model,
    /// Why `auto` chose `model`, with the pilot's measurements.
    pub auto_choice: Option<AutoChoice>,
    pub(crate) tri3: Option<Tri3Mesh>,
    /// `path`: what the roulette's pilot measured and chose (`roulette`), if it ran.
    pub roulette: Option<super::roulette::RoulettePilot>,
}

impl<'a> Renderer<'a> {
    /// Prepares the forward render ([`Renderer::prepare`] for [`Pass::Render`]).
    pub fn new(scene: &'a Scene, geom: &'a SceneGeometry, opts: &RenderOptions) -> Result<Self> {
        Self::prepare(scene, geom, opts, Pass::Render)
    }

    /// The gate for `pass`, then the model resolved (`auto` runs its pilot; the gate
    /// refuses `auto` for gradients) and checked again, and what it needs built.
    pub fn prepare(
        scene: &'a Scene,
        geom: &'a SceneGeometry,
        opts: &RenderOptions,
        pass: Pass,
    ) -> Result<Self> {
        gate::check(scene, opts, pass)?;
        let (model, auto_choice) = match opts.model {
            Model::Auto => {
                let c = choose_model(scene, geom, opts)?;
                gate::check(
                    scene,
                    &RenderOptions {
                        model: c.model,
                        ..*opts
                    },
                    pass,
                )?;
                (c.model, Some(c))
            }
            m => (m, None),
        };
        let tri3 = (model == Model::Tri3).then(|| Tri3Mesh::build(scene, geom, opts.subdivision));
        let film = Film::new(&scene.film);
        let auto_roulette = scene.render.rr_early_survival == EarlySurvival::Auto;
        let roulette = (model == Model::Path && auto_roulette)
            .then(|| {
                let r = &scene.render;
                super::roulette::pilot(
                    scene.num_measurements(),
                    &film,
                    opts.seed,
                    opts.spp,
                    r.rr_bounces,
                    |m| MeasurementCtx::new(scene, geom, &film, m),
                )
            })
            .flatten();
        Ok(Renderer {
            scene,
            geom,
            opts: RenderOptions { model, ..*opts },
            film,
            model,
            auto_choice,
            tri3,
            roulette,
        })
    }

    /// Measurement `m`'s context (its laser and sensor points, legs, film window).
    pub fn measurement(&self, m: usize) -> MeasurementCtx<'a> {
        let mut ctx = MeasurementCtx::new(self.scene, self.geom, &self.film, m);
        if let Some(r) = &self.roulette {
            ctx.rr_early_survival = r.survival;
        }
        ctx
    }

    /// A Monte Carlo measurement's sample blocks: `BLOCK_SPP` samples each, the last one
    /// shorter. Both passes draw the same samples in these blocks.
    pub fn sample_blocks(&self) -> impl Iterator<Item = std::ops::Range<u32>> {
        let spp = self.opts.spp;
        (0..spp)
            .step_by(BLOCK_SPP as usize)
            .map(move |first| first..(first + BLOCK_SPP).min(spp))
    }

    /// Runs samples `range` of measurement `m` (context `ctx`) into `sink`.
    pub fn run_block<S: Sink>(
        &self,
        ctx: &MeasurementCtx,
        m: usize,
        range: std::ops::Range<u32>,
        sink: &mut S,
        scratch: &mut PathScratch,
    ) {
        run_samples(
            self.model,
            ctx,
            self.opts.seed,
            m as u64,
            range,
            sink,
            scratch,
        );
    }

    /// Counts `work` units done (progress bars).
    pub fn count(progress: Option<&Progress>, work: u64) {
        if let Some(p) = progress {
            p.work_done.fetch_add(work, Ordering::Relaxed);
        }
    }

    /// Whether the caller asked to stop.
    pub fn cancelled(progress: Option<&Progress>) -> bool {
        progress.is_some_and(|p| p.cancel.load(Ordering::Relaxed))
    }

    /// Units of work the render does (for progress bars): samples or triangle pairs.
    pub fn total_work(&self) -> u64 {
        self.scene.num_measurements() as u64 * self.work_per_measurement()
    }

    /// Units of work of one measurement.
    pub fn work_per_measurement(&self) -> u64 {
        match &self.tri3 {
            Some(mesh) => mesh.len() as u64,
            None => self.opts.spp as u64,
        }
    }

    /// What a unit of work is called.
    pub fn work_unit(&self) -> &'static str {
        if self.tri3.is_some() {
            "pairs"
        } else {
            "samples"
        }
    }

    /// Sub-triangles of the `tri3` model (0 for the Monte Carlo models).
    pub fn subtriangles(&self) -> usize {
        self.tri3.as_ref().map_or(0, Tri3Mesh::len)
    }

    /// Hidden triangles that `tri3` left coarser than its `subdivision` threshold asks
    /// (stopped at `tri3::MAX_LEVEL`; 0 for the Monte Carlo models): worth a warning.
    pub fn subdivision_capped(&self) -> usize {
        self.tri3.as_ref().map_or(0, |m| m.capped)
    }

    /// Renders every measurement.
    pub fn render(&self, progress: Option<&Progress>) -> Result<Transient> {
        let data = self.render_measurements(0..self.scene.num_measurements(), progress)?;
        Ok(Transient {
            data,
            shape: self.scene.output_shape(),
        })
    }

    /// Renders measurements `range` (in the render's order: scan points, laser points
    /// for exhaustive captures, row-major), `range.len()` rows of `bins` values: exactly
    /// those rows of [`Renderer::render`]'s output, whatever process runs them (each
    /// measurement's samples depend on the seed and its index alone). `umbra.distributed`
    /// splits a render this way.
    pub fn render_measurements(
        &self,
        range: std::ops::Range<usize>,
        progress: Option<&Progress>,
    ) -> Result<Vec<f32>> {
        let n = self.scene.num_measurements();
        if range.start > range.end || range.end > n {
            return Err(Error::Invalid(format!(
                "measurements {}..{} are not within the scene's 0..{n}",
                range.start, range.end
            )));
        }
        let bins = self.film.bins;
        let first = range.start;
        let mut data = vec![0.0f32; range.len() * bins];
        let cancelled = AtomicBool::new(false);
        let nested = range.len() < rayon::current_num_threads();
        let stop = || {
            let c = cancelled.load(Ordering::Relaxed) || Self::cancelled(progress);
            if c {
                cancelled.store(true, Ordering::Relaxed);
            }
            c
        };
        if !self.geom.hidden.is_empty() {
            data.par_chunks_mut(bins).enumerate().for_each_init(
                Tri3Scratch::default,
                |scratch, (i, out)| {
                    if stop() {
                        return;
                    }
                    let m = first + i;
                    let ctx = self.measurement(m);
                    if !ctx.legs_visible {
                        Self::count(progress, self.work_per_measurement());
                        return;
                    }
                    if let Some(mesh) = &self.tri3 {
                        let v = self.opts.visibility;
                        tri3::render_measurement(mesh, &ctx, &self.film, v, scratch, out);
                        Self::count(progress, mesh.len() as u64);
                        return;
                    }
                    let Some(hist) = self.monte_carlo(&ctx, m, progress, &stop, nested) else {
                        return;
                    };
                    for (o, a) in out.iter_mut().zip(hist) {
                        *o = a as f32;
                    }
                },
            );
        }
        if cancelled.load(Ordering::Relaxed) {
            return Err(Error::Cancelled);
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(Error::Invalid(format!(
                "render produced a non-finite value at flat index {}: refusing to write it (please report this scene)",
                first * bins + i
            )));
        }
        Ok(data)
    }

    /// The Monte Carlo estimate of one measurement (mean over spp), or `None` if
    /// cancelled.
    fn monte_carlo(
        &self,
        ctx: &MeasurementCtx,
        m: usize,
        progress: Option<&Progress>,
        stop: &(dyn Fn() -> bool + Sync),
        nested: bool,
    ) -> Option<Vec<f64>> {
        let (bins, spp) = (self.film.bins, self.opts.spp);
        let ranges: Vec<std::ops::Range<u32>> = self.sample_blocks().collect();
        let blocks = ranges.len();
        let mut acc = vec![0.0f64; bins];
        // Blocks run FOLD_BLOCKS at a time and are added in block order: memory stays
        // flat in spp (it grew by a histogram per block until the measurement ended), and
        // the sum does not depend on the thread count.
        for group in (0..blocks).step_by(FOLD_BLOCKS) {
            let block = |b: usize| {
                if stop() {
                    return None;
                }
                let range = ranges[b].clone();
                let samples = range.len() as u64;
                let mut hist = vec![0.0f64; bins];
                let mut sink = HistogramSink {
                    film: &self.film,
                    hist: &mut hist,
                };
                self.run_block(ctx, m, range, &mut sink, &mut PathScratch::default());
                Self::count(progress, samples);
                Some(hist)
            };
            let range = group..(group + FOLD_BLOCKS).min(blocks);
            // Blocks in parallel only when measurements alone cannot keep the threads
            // busy: a thread waiting on nested work would steal another measurement and
            // hold a second set of histograms (`budget` counts one set per thread).
            let hists: Vec<Option<Vec<f64>>> = if nested {
                range.into_par_iter().map(block).collect()
            } else {
                range.map(block).collect()
            };
            for h in hists {
                for (a, v) in acc.iter_mut().zip(h?) {
                    *a += v;
                }
            }
        }
        let inv_spp = 1.0 / spp as f64;
        acc.iter_mut().for_each(|a| *a *= inv_spp);
        Some(acc)
    }
}

/// Renders the scene's transient (a [`Renderer`] made and run in one call).
pub fn render(
    scene: &Scene,
    geom: &SceneGeometry,
    opts: &RenderOptions,
    progress: Option<&Progress>,
) -> Result<Transient> {
    Renderer::new(scene, geom, opts)?.render(progress)
}
