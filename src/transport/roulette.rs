//! `path`'s Russian roulette before `rr_bounces`, its survival `q` chosen per render
//! (`render.rr_early_survival = "auto"`) by the efficiency it buys.
//!
//! A path records its three-bounce term at its first hidden vertex before the roulette,
//! so the roulette leaves that term's samples alone and thins the longer paths. With
//! `e₃²`, `e_m²` the squared errors the three-bounce term and the longer paths leave at
//! the render's spp, and `C₃`, `C_m` the time spent on each, the roulette leaves
//! `e² ≈ e₃² + e_m²/q` in time `C₃ + q C_m`; their product, the inverse efficiency, is
//! least at
//!
//! `q* = √((e_m² / e₃²) · (C₃ / C_m))`, clamped to `[`[`MIN_SURVIVAL`]`, 1]`.
//!
//! A pilot measures the four. It renders `K = max(1, M/16)` of the `M` measurements
//! (evenly spaced) twice, with two seeds of their own, at `n = spp/8` samples, with
//! `q = 1`, keeping the three-bounce contributions and the rest apart: each term's
//! squared error at `n` is half the squared difference of its two renders. Scrambled
//! Sobol' points converge faster than `n^{-1/2}`, the three-bounce term (low-dimensional)
//! faster than the longer paths, so each term's rate is fitted from the same renders'
//! first quarter (`n/4` samples, a Sobol' prefix) and its error carried to `spp`. The
//! costs are counted, not timed (any load, same answer): a sample and its first step
//! against each later step, weighed by [`STEP_COST`]. The terms of four and of five or
//! more bounces are kept apart, since a path reaches its third vertex with probability
//! `q²`; `q` is the best of a grid over `[MIN_SURVIVAL, 1]`, and 1 unless it is predicted
//! to gain at least [`MIN_GAIN`]. The pilot is `2/8` of a render on `1/16` of the
//! measurements (1.6 % of the render); below [`MIN_PILOT_SPP`]` · 8` spp it is not run
//! and `q = 1`, nor where no path can record anything after its first hidden vertex
//! (a planar or convex object whose paths back off the wall land past the film, as the T
//! letter's). [`resolved`] fixes its choice in the scene for work of several passes. Deterministic: fixed seeds, fixed order
//! (measurements in parallel, summed in their order).
//!
//! Measured (BENCHMARKS.md, "Russian roulette before rr_bounces"; 8 renders each against
//! a 4 x 65536 spp reference): on the arc, multi-bounce, 8192 spp, it picks 0.2–0.3 and
//! reaches equal error 1.4–1.6x sooner than no roulette; on the concave corner it picks
//! 1, where a fixed 0.35 is 2.7x later. What it does not know: the adjoint's variance
//! (gradients use the forward pass's choice), and paths of more than five bounces (taken
//! as five).

use super::gate::Pass;
use super::path::PathScratch;
use super::{run_samples, Contribution, MeasurementCtx, RenderOptions, Renderer, Sink};
use crate::error::Result;
use crate::film::Film;
use crate::geometry::SceneGeometry;
use crate::scene::{EarlySurvival, Model, Scene};
use rayon::prelude::*;

/// Smallest survival the pilot picks.
pub const MIN_SURVIVAL: f32 = 0.2;
/// Fewest pilot samples per measurement (the pilot runs at `spp / 8`).
pub const MIN_PILOT_SPP: u32 = 128;
/// Time of a later step (a continuation, its ray, NEE and splat) over the time of a
/// sample's fixed part (sampler, first step in lanes, NEE at the first hidden vertex).
/// On the arc (1 thread, 8192 spp x 256 measurements): 0.22 s with three bounces only,
/// 0.70 s with six, 1.46 later steps per sample: 105 ns against 157 ns.
pub const STEP_COST: f64 = 1.5;
/// The least predicted gain in efficiency for which the pilot picks `q < 1` (below it,
/// the pilot's own noise could pick a loss).
pub const MIN_GAIN: f64 = 1.1;

/// What the pilot measured and chose.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RoulettePilot {
    /// Squared relative errors at the render's spp (no roulette) of the terms of three,
    /// four, and five or more bounces.
    pub errors: [f64; 3],
    /// Costs per sample: the sample's fixed part (1), the steps from `y_1`, and from
    /// `y_2` on.
    pub costs: [f64; 3],
    /// The chosen survival, and its predicted efficiency over `q = 1`.
    pub survival: f32,
    pub gain: f64,
}

/// Splits contributions into histograms by bounce count: 3 or fewer, 4, 5 or more.
struct SplitSink<'a> {
    film: &'a Film,
    terms: &'a mut [Vec<f64>],
}

impl Sink for SplitSink<'_> {
    fn add(&mut self, c: &Contribution) {
        let t = (c.bounces.max(3) - 3).min(2) as usize;
        self.film.splat(c.opl, c.weight, &mut self.terms[t]);
    }
}

/// The pilot over the measurements' contexts `ctx(m)` (without roulette before
/// `rr_bounces`), or `None` when it cannot pay: `spp` too small, or no vertex before
/// `rr_bounces` to play it at.
pub fn pilot<'a>(
    num_measurements: usize,
    film: &Film,
    seed: u64,
    spp: u32,
    rr_bounces: u32,
    ctx: impl Fn(usize) -> MeasurementCtx<'a> + Sync,
) -> Option<RoulettePilot> {
    if spp / 8 < MIN_PILOT_SPP || rr_bounces <= 3 || !longer_paths_in_film(&ctx(0)) {
        return None;
    }
    // A power of two: its first quarter is a Sobol' prefix of its own.
    let n = 1u32 << (31 - (spp / 8).leading_zeros());
    let quarter = n / 4;
    let k = (num_measurements / 16).max(1);
    let bins = film.bins;
    // Sums of squared differences of the two renders per term, at n/4 and at n, and of
    // the squared means (the relative errors' scale).
    // Per measurement, in parallel (each its own renders), summed in measurement order:
    // `(d2, norm2, samples, steps)`.
    let tally = |i: usize| {
        let mut d2 = [[0.0f64; 2]; 3];
        let mut norm2 = 0.0f64;
        let (mut samples, mut steps) = (0u64, [0u64; 2]);
        let m = (2 * i + 1) * num_measurements / (2 * k);
        let mut ctx = ctx(m);
        ctx.rr_early_survival = 1.0;
        // [seed][part: first quarter, rest][term] histograms.
        let mut h = vec![vec![vec![vec![0.0f64; bins]; 3]; 2]; 2];
        for (s, hs) in h.iter_mut().enumerate() {
            let pilot_seed = seed ^ (s as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
            let mut scratch = PathScratch::default();
            for (part, range) in [0..quarter, quarter..n].into_iter().enumerate() {
                let mut sink = SplitSink {
                    film,
                    terms: &mut hs[part],
                };
                run_samples(
                    Model::Path,
                    &ctx,
                    pilot_seed,
                    m as u64,
                    range,
                    &mut sink,
                    &mut scratch,
                );
            }
            for (a, b) in steps.iter_mut().zip(scratch.later_steps) {
                *a += b;
            }
            samples += n as u64;
        }
        // Per-sample means of each seed's render, [seed][term] at n/4 and at n.
        let means = |s: usize, t: usize| {
            let (first, rest) = (&h[s][0][t], &h[s][1][t]);
            let quarter_mean: Vec<f64> = first.iter().map(|v| v / quarter as f64).collect();
            let full_mean: Vec<f64> = first
                .iter()
                .zip(rest)
                .map(|(a, b)| (a + b) / n as f64)
                .collect();
            (quarter_mean, full_mean)
        };
        let mut total = vec![0.0f64; bins];
        for (t, d) in d2.iter_mut().enumerate() {
            let ((q0, f0), (q1, f1)) = (means(0, t), means(1, t));
            d[0] += q0
                .iter()
                .zip(&q1)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>();
            d[1] += f0
                .iter()
                .zip(&f1)
                .map(|(a, b)| (a - b).powi(2))
                .sum::<f64>();
            for ((tot, a), b) in total.iter_mut().zip(&f0).zip(&f1) {
                *tot += 0.5 * (a + b);
            }
        }
        norm2 += total.iter().map(|v| v * v).sum::<f64>();
        (d2, norm2, samples, steps)
    };
    let tallies: Vec<_> = (0..k).into_par_iter().map(tally).collect();
    let mut d2 = [[0.0f64; 2]; 3];
    let mut norm2 = 0.0f64;
    let (mut samples, mut steps) = (0u64, [0u64; 2]);
    for (d, n2, s, st) in tallies {
        for (acc, x) in d2.iter_mut().flatten().zip(d.iter().flatten()) {
            *acc += x;
        }
        norm2 += n2;
        samples += s;
        for (a, b) in steps.iter_mut().zip(st) {
            *a += b;
        }
    }
    // Each term's squared error carried from n to spp at its own fitted rate
    // (e² ∝ spp^{-2α}, 2α within [0.5, 3]: from Monte Carlo's rate to scrambled
    // Sobol's best on smooth integrands); half the squared difference of two renders.
    let at_spp = |[quarter_d2, full_d2]: [f64; 2]| {
        if full_d2 <= 0.0 {
            return 0.0;
        }
        let two_alpha = if quarter_d2 > 0.0 {
            ((quarter_d2 / full_d2).ln() / 4f64.ln()).clamp(0.5, 3.0)
        } else {
            1.0
        };
        0.5 * full_d2 * (n as f64 / spp as f64).powf(two_alpha) / norm2.max(f64::MIN_POSITIVE)
    };
    let errors = d2.map(at_spp);
    let per_sample = |c: u64| c as f64 / samples as f64 * STEP_COST;
    let costs = [1.0, per_sample(steps[0]), per_sample(steps[1])];
    // With roulette of survival q at the vertices before rr_bounces, a path reaches its
    // second vertex with probability q and its third with q² (q once if rr_bounces is
    // 4): the four-bounce term's variance grows by 1/q, the longer ones' by 1/q², and
    // the later steps' cost shrinks alike.
    let early = (rr_bounces - 3).min(2) as i32;
    let power = [0, 1.min(early), early];
    let inverse_efficiency = |q: f64| {
        let e: f64 = (0..3).map(|t| errors[t] / q.powi(power[t])).sum();
        let c: f64 = (0..3).map(|t| costs[t] * q.powi(power[t])).sum();
        e * c
    };
    let at_one = inverse_efficiency(1.0);
    let (mut survival, mut best) = (1.0f64, at_one);
    for i in 0..=80 {
        let q = MIN_SURVIVAL as f64 + (1.0 - MIN_SURVIVAL as f64) * i as f64 / 80.0;
        let v = inverse_efficiency(q);
        if v < best {
            (survival, best) = (q, v);
        }
    }
    let mut gain = if best > 0.0 { at_one / best } else { 1.0 };
    if gain < MIN_GAIN {
        (survival, gain) = (1.0, 1.0);
    }
    Some(RoulettePilot {
        errors,
        costs,
        survival: survival as f32,
        gain,
    })
}

/// Whether a path can record anything after its first hidden vertex: not where no
/// continuation from the hidden geometry meets hidden geometry (a planar or convex
/// object, `path_step::Onward`), the spot is a point, and a path back off the wall is
/// longer than the film reaches: `x_s → y_1 → wall → y_2 → x_l` is at least `4 d_w`
/// ([`MeasurementCtx::past_film`] ends every walk at `y_1` then, and the roulette would
/// have nothing to thin). The T letter's 4 d_w is 3.6 m against a film ending at 3.14 m.
fn longer_paths_in_film(ctx: &MeasurementCtx) -> bool {
    ctx.geom.hidden_reaches_hidden()
        || ctx.scene.laser.spot_radius > 0.0
        || 4.0 * ctx.geom.wall_gap * (1.0 - 1e-5) < ctx.opl_max
}

/// `scene` with `render.rr_early_survival = "auto"` replaced by the survival the pilot
/// picks for `opts` (what [`Renderer::prepare`] would play: `1` where the pilot does not
/// run), and unchanged otherwise. Work made of several passes over one render's samples
/// resolves it once and pays for one pilot, with the same bits: `umbra grad --target`
/// (the render, then the adjoint), a fit's evaluation, finite differences (whose moved
/// scenes then play the same roulette), Ray shards (`_umbra.resolve_early_survival`).
pub fn resolved(
    scene: &Scene,
    geom: &SceneGeometry,
    opts: &RenderOptions,
    pass: Pass,
) -> Result<Scene> {
    let mut s = scene.clone();
    let may_run = matches!(opts.model, Model::Path | Model::Auto);
    if s.render.rr_early_survival == EarlySurvival::Auto && may_run {
        let driver = Renderer::prepare(scene, geom, opts, pass)?;
        let q = driver.roulette.map_or(1.0, |r| r.survival);
        s.render.rr_early_survival = EarlySurvival::Fixed(q);
    }
    Ok(s)
}
