//! `model = "auto"`: the cheapest model accurate enough for the scene ("model no more than
//! a scene needs", DESIGN §3).
//!
//! The rule is a measurement, not a guess: a short pilot of the multi-bounce path tracer
//! (all techniques on, so no path is missed) on up to [`PILOT_MEASUREMENTS`] measurements
//! spread over the scan, [`PILOT_SPP`] samples each, splits the energy that lands in the
//! film's time window into three-bounce `E3` and beyond-three-bounce `E+` (hidden
//! interreflections and paths through the wall). `tri3` is chosen when
//! `(E+ + 2σ(E+)) / E3` is below `max_error`, the multi-bounce `path` model otherwise.
//! The three-bounce estimate `tri3` leaves out exactly `E+`, so this bounds the energy
//! error of choosing it (tri3's own discretisation error is measured separately,
//! `tests/tri3.rs`).

use super::path::{self, PathScratch};
use super::{Contribution, MeasurementCtx, RenderOptions, Sink};
use crate::error::Result;
use crate::film::Film;
use crate::geometry::SceneGeometry;
use crate::rng::Sampler;
use crate::scene::{Model, Scene};
use rayon::prelude::*;

/// Measurements the pilot renders (spread evenly over the scan).
pub const PILOT_MEASUREMENTS: usize = 16;
/// Samples per pilot measurement.
pub const PILOT_SPP: u32 = 512;
/// Seed offset that keeps the pilot's samples apart from the render's.
const PILOT_SEED: u64 = 0xA070_5EED;

/// What `auto` chose, and the measurement behind it.
#[derive(Clone, Debug)]
pub struct AutoChoice {
    pub model: Model,
    /// `E+ / E3` measured by the pilot.
    pub beyond_three: f64,
    /// Its standard error.
    pub beyond_three_sigma: f64,
    /// One sentence for the user.
    pub reason: String,
}

/// Energy in the film window by bounce class, for one sample and in total.
struct BounceEnergy {
    start: f32,
    end: f32,
    sample_three: f64,
    sample_more: f64,
}

impl Sink for BounceEnergy {
    fn add(&mut self, c: &Contribution) {
        if c.opl >= self.start && c.opl < self.end {
            if c.bounces == 3 {
                self.sample_three += c.weight as f64;
            } else {
                self.sample_more += c.weight as f64;
            }
        }
    }
}

/// Runs the pilot and picks `tri3` or `path`.
pub fn choose_model(
    scene: &Scene,
    geom: &SceneGeometry,
    opts: &RenderOptions,
) -> Result<AutoChoice> {
    let mut pilot = scene.clone();
    let t = &mut pilot.render.techniques;
    t.laser_sampling = true;
    t.hidden_geometry_sampling = true;
    t.bsdf_sampling = true;
    pilot.render.filter_bounces = None;
    let film = Film::new(&pilot.film);
    let n = pilot.num_measurements();
    let picks: Vec<usize> = (0..PILOT_MEASUREMENTS.min(n))
        .map(|i| i * n / PILOT_MEASUREMENTS.min(n))
        .collect();
    // Per measurement: (Σ E3, Σ E+, Σ E+², samples).
    let sums: Vec<[f64; 3]> = picks
        .par_iter()
        .map(|&m| {
            let ctx = MeasurementCtx::new(&pilot, geom, &film, m);
            let mut sink = BounceEnergy {
                start: film.start as f32,
                end: film.end() as f32,
                sample_three: 0.0,
                sample_more: 0.0,
            };
            let mut scratch = PathScratch::default();
            let mut acc = [0.0f64; 3];
            for i in 0..PILOT_SPP {
                let mut sampler = Sampler::new(opts.seed ^ PILOT_SEED, m as u64, i);
                path::sample(&ctx, &mut sampler, &mut scratch, &mut sink);
                acc[0] += sink.sample_three;
                acc[1] += sink.sample_more;
                acc[2] += sink.sample_more * sink.sample_more;
                sink.sample_three = 0.0;
                sink.sample_more = 0.0;
            }
            acc
        })
        .collect();
    let spp = PILOT_SPP as f64;
    let (mut e3, mut more, mut var) = (0.0, 0.0, 0.0);
    for [s3, sm, sm2] in sums {
        e3 += s3 / spp;
        more += sm / spp;
        var += (sm2 / spp - (sm / spp).powi(2)).max(0.0) / spp;
    }
    let (ratio, sigma) = if e3 > 0.0 {
        (more / e3, var.sqrt() / e3)
    } else {
        (0.0, 0.0)
    };
    let bound = ratio + 2.0 * sigma;
    let limit = opts.max_error as f64;
    let pilot_desc = format!("{} measurements x {} spp", picks.len(), PILOT_SPP);
    let (model, reason) = if e3 <= 0.0 && more <= 0.0 {
        (
            Model::Tri3,
            format!("tri3: the pilot ({pilot_desc}) saw no light in the time window"),
        )
    } else if bound < limit {
        (
            Model::Tri3,
            format!(
                "tri3: the pilot ({pilot_desc}) puts {:.3} % ± {:.3} % of the energy beyond three bounces, below max_error {:.2} %",
                100.0 * ratio,
                100.0 * sigma,
                100.0 * limit
            ),
        )
    } else {
        (
            Model::Path,
            format!(
                "path: the pilot ({pilot_desc}) puts {:.3} % ± {:.3} % of the energy beyond three bounces (interreflections), above max_error {:.2} %",
                100.0 * ratio,
                100.0 * sigma,
                100.0 * limit
            ),
        )
    };
    Ok(AutoChoice {
        model,
        beyond_three: ratio,
        beyond_three_sigma: sigma,
        reason,
    })
}
