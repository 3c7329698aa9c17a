//! How `umbra fit` sets up a real capture's model ([`super::capture`]): the options a
//! request resolves to (likelihood, the response's prior, the nuisances' degrees, the
//! held-out scan points), and the model built from them at each stage's resolution.

use super::capture::{CaptureModel, RESOLVED_BINS_PER_SIGMA};
use super::linear_fit::Likelihood;
use super::point_background::{Floor, PointBackground};
use crate::error::{Error, Result};
use crate::film::response::{Response, OPL_PER_PS};
use crate::scene::CaptureType;

/// The detector response of the Stanford LCT system measured on its captures
/// (`notes/capture-calibration.md` §2, the resolution and dot charts): σ = 28 ps, tails
/// of 74 ps (38 %) and 262 ps (34 %); in OPL (m). The calibration's start.
pub fn stanford_prior() -> Response {
    Response {
        sigma: 0.0084,
        t0: 0.0,
        tails: vec![(0.38, 0.0222), (0.34, 0.0786)],
    }
}

/// Per scan point of an `nx x ny` grid, whether it is in the fit: the held-out points are
/// the odd-indexed ones (`ix`, `iy` both odd) with `(⌊ix/2⌋ + 3 ⌊iy/2⌋) % every = every / 2`,
/// one in `4 every` of the grid, spread evenly, no two neighbours. Odd indices are the
/// points a stage at half the scan resolution keeps ([`super::resolution`]), so those
/// stages hold out the same points (one in `every` of theirs). `every = 0`: all are in.
pub fn held_out_pattern(nx: usize, ny: usize, every: usize) -> Vec<bool> {
    (0..nx * ny)
        .map(|p| {
            let (ix, iy) = (p % nx, p / nx);
            every == 0 || ix % 2 == 0 || iy % 2 == 0 || (ix / 2 + 3 * (iy / 2)) % every != every / 2
        })
        .collect()
}

/// How `umbra fit` models a real capture (module doc), before it is set up at a stage.
#[derive(Clone, Debug, PartialEq)]
pub struct CaptureOptions {
    pub likelihood: Likelihood,
    /// The response calibration starts from (and the stages too coarse to calibrate use).
    pub prior: Response,
    /// The floor over the scan, and the gain's polynomial degree (≤ 2).
    pub floor: Floor,
    pub gain_degree: usize,
    /// Time constants of the direct return's tail columns (OPL, m).
    pub tail_taus: Vec<f64>,
    /// `D_p` sums each point's bins up to this OPL from the film's start (m): the direct
    /// return of a capture rectified to the wall.
    pub direct_opl: f64,
    /// One in `4 every` scan points is held out ([`held_out_pattern`]; 0: none).
    pub held_out_every: usize,
}

impl CaptureOptions {
    /// The Stanford LCT system's (`notes/capture-calibration.md`): the measured prior
    /// response, a floor per scan point and a degree-1 gain, tails of 333 ps and 1 ns,
    /// the direct return in the first 400 ps, one point in 32 held out.
    pub fn stanford(likelihood: Likelihood) -> CaptureOptions {
        CaptureOptions {
            likelihood,
            prior: stanford_prior(),
            floor: Floor::PerPoint,
            gain_degree: 1,
            tail_taus: vec![0.1, 0.3],
            direct_opl: 0.12,
            held_out_every: 8,
        }
    }

    /// The model at a stage: `scene` and `measured` at the stage's resolution (the
    /// measurement with its leading bins still in, for `D_p`), `first` its first fitted
    /// bin, `scan_step` the stage's scan subsampling of the `nx x ny` fitted grid.
    pub fn at_stage(
        &self,
        scene: &crate::scene::Scene,
        measured: &[f32],
        first: usize,
        scan_step: usize,
        grid: (usize, usize),
    ) -> CaptureModel {
        let bins = scene.film.temporal_bins as usize;
        let width = f64::from(scene.film.bin_width_opl);
        let start = f64::from(scene.film.start_opl);
        let direct_bins = (((self.direct_opl - start) / width).ceil().max(0.0) as usize).min(bins);
        let direct = measured
            .chunks_exact(bins)
            .map(|row| row[..direct_bins].iter().map(|&v| f64::from(v)).sum())
            .collect();
        let (nx, ny) = (scene.scan.nx as usize, scene.scan.ny as usize);
        let unit = |i: usize, n: usize| {
            if n > 1 {
                2.0 * i as f64 / (n - 1) as f64 - 1.0
            } else {
                0.0
            }
        };
        let coords = (0..nx * ny)
            .map(|p| (unit(p % nx, nx), unit(p / nx, ny)))
            .collect();
        let tails = self
            .tail_taus
            .iter()
            .map(|&tau| super::point_background::exponential_tail(tau, start, width, bins))
            .collect();
        let full = held_out_pattern(grid.0, grid.1, self.held_out_every);
        let q = scan_step.max(1);
        let in_fit = (0..nx * ny)
            .map(|p| {
                let (ix, iy) = (q * (p % nx) + q / 2, q * (p / nx) + q / 2);
                full.get(iy * grid.0 + ix).copied().unwrap_or(true)
            })
            .collect();
        CaptureModel {
            design: PointBackground::new(direct, tails, coords, self.floor, self.gain_degree),
            likelihood: self.likelihood,
            response: self.prior.clone(),
            in_fit,
            bins,
            first,
            bin_width: width,
        }
    }

    /// Whether a stage of bin width `width` (OPL, m) resolves the prior's core well
    /// enough to calibrate the response on.
    pub fn calibrates_at(&self, width: f64) -> bool {
        width <= RESOLVED_BINS_PER_SIGMA * self.prior.sigma
    }
}

/// The capture model of `--background per-point` (`fit::capture`), its likelihood and
/// response choices checked against the other options; `None` for other backgrounds.
pub fn from_request(
    n: &dyn Fn(&str) -> String,
    req: &super::request::FitRequest,
    scene: &crate::scene::Scene,
    per_point: bool,
    counts: bool,
    scan_block: u32,
) -> Result<Option<CaptureOptions>> {
    let likelihood = match req.likelihood.as_deref() {
        None if per_point && counts => Likelihood::Poisson {
            counts_per_value: f64::from(scan_block * scan_block),
        },
        None | Some("l2") => Likelihood::L2,
        Some("poisson") if !counts => {
            return Err(Error::Invalid(format!(
                "{} poisson: the measurement is not photon counts (non-negative integers)",
                n("likelihood")
            )))
        }
        Some("poisson") => Likelihood::Poisson {
            counts_per_value: f64::from(scan_block * scan_block),
        },
        Some(other) => {
            return Err(Error::Invalid(format!(
                "{}: '{other}' is not one of poisson, l2",
                n("likelihood")
            )))
        }
    };
    let irf = req.irf.as_deref();
    if !per_point {
        if likelihood != Likelihood::L2 {
            return Err(Error::Invalid(format!(
                "{} poisson needs {} per-point (the calibrated capture model)",
                n("likelihood"),
                n("background")
            )));
        }
        if irf == Some("calibrate") {
            return Err(Error::Invalid(format!(
                "{} calibrate needs {} per-point (the calibrated capture model)",
                n("irf"),
                n("background")
            )));
        }
        return Ok(None);
    }
    if scene.capture == CaptureType::Exhaustive {
        return Err(Error::Invalid(format!(
            "{} per-point models a scanned capture (confocal or single laser spot); this scene's capture is exhaustive",
            n("background")
        )));
    }
    if let Some(other) = irf.filter(|i| *i != "calibrate") {
        return Err(Error::Invalid(format!(
            "{} {other}: with {} per-point the detector response is calibrated from the capture ({} calibrate)",
            n("irf"),
            n("background"),
            n("irf")
        )));
    }
    if req.time_offset.is_some() {
        return Err(Error::Invalid(format!(
            "{}: with {} per-point the time offset is the calibrated response's t0",
            n("time_offset"),
            n("background")
        )));
    }
    Ok(Some(CaptureOptions::stanford(likelihood)))
}

/// A calibrated detector response in picoseconds (`fit::capture`).
#[derive(Clone, Debug, serde::Serialize)]
pub struct ResponseSummary {
    /// The core's standard deviation and its time zero (ps).
    pub sigma_ps: f64,
    pub t0_ps: f64,
    /// Per tail, its weight and time constant (ps).
    pub tail_weights: Vec<f64>,
    pub tail_tau_ps: Vec<f64>,
}

impl ResponseSummary {
    pub fn of(r: &Response) -> ResponseSummary {
        let ps = |opl: f64| opl / OPL_PER_PS;
        ResponseSummary {
            sigma_ps: ps(r.sigma),
            t0_ps: ps(r.t0),
            tail_weights: r.tails.iter().map(|t| t.0).collect(),
            tail_tau_ps: r.tails.iter().map(|t| ps(t.1)).collect(),
        }
    }
}
