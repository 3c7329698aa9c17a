//! The choices of a fit request besides the measurement and the schedule, resolved and
//! checked against each other, with errors that name the options as the front end
//! spells them: how the fitted surface reflects, and how the detector's response enters
//! (a measured or calibrated impulse response, a Gaussian jitter, a time offset).

use super::prepare::detector_response as read_response;
use super::request::FitRequest;
use crate::error::{Error, Result};
use crate::film::irf::Irf;
use crate::scene::{Model, Reflectance, Scene};
use optim::Schedule;

/// The fitted surface's reflectance: `req.reflectance` (default the scene's first hidden
/// object's) with `req.retro_falloff`; a retroreflective one only where the model and
/// every stage's model can render it.
pub fn reflectance(
    req: &FitRequest,
    scene: &Scene,
    model: Model,
    schedule: &Schedule,
) -> Result<Reflectance> {
    let n = |name: &str| req.front.name(name);
    let reflectance = match &req.reflectance {
        None => scene
            .objects
            .first()
            .map_or(Default::default(), |o| o.reflectance),
        Some(r) => Reflectance::parse(r).ok_or_else(|| {
            Error::Invalid(format!(
                "{}: '{r}' is not one of lambertian, retroreflective",
                n("reflectance")
            ))
        })?,
    };
    let reflectance = match req.retro_falloff {
        None => reflectance,
        Some(m) => reflectance
            .with_falloff(m, &n("retro_falloff"))
            .map_err(Error::Invalid)?,
    };
    if reflectance.is_retro() {
        let whose = if req.reflectance.is_none() {
            " (the scene's first hidden object's)"
        } else {
            ""
        };
        // The gate's words for the fitted object (`objects[0] (fit)`), as the renderer
        // would say them at the first evaluation, then where the reflectance comes from
        // and what to change.
        let refuse = |problem: String, fix: String| {
            Error::Invalid(format!(
                "objects[0] (fit): {problem} (the fitted surface is {} retroreflective{whose}){fix}",
                n("reflectance")
            ))
        };
        if let Some(problem) = crate::transport::gate::retroreflective_problem(scene.capture, model)
        {
            let fix = if scene.capture == crate::scene::CaptureType::Confocal {
                format!(
                    ": use {} tri3, or {} lambertian",
                    n("model"),
                    n("reflectance")
                )
            } else {
                format!(": use {} lambertian", n("reflectance"))
            };
            return Err(refuse(problem, fix));
        }
        if let Some((i, name)) = schedule.stages.iter().enumerate().find_map(|(i, s)| {
            s.model
                .as_deref()
                .filter(|m| Model::parse(m) != Some(Model::Tri3))
                .map(|m| (i, m))
        }) {
            return Err(refuse(
                format!("retroreflective reflectance is modelled by tri3 only, and the schedule's stage {i} has model = '{name}'"),
                String::new(),
            ));
        }
    }
    Ok(reflectance)
}

/// How the render meets the detector's response.
pub struct DetectorResponse {
    /// A measured impulse response (`--irf direct` or a file).
    pub irf: Option<Irf>,
    /// The Gaussian jitter σ (OPL, m; 0: none).
    pub jitter_opl: f64,
    /// The time offset searched, ± this (OPL, m; 0: none).
    pub time_offset_max_opl: f64,
}

/// `--irf`, `--jitter` and `--time-offset` resolved and checked against each other and
/// the film; `per_point`: the capture model calibrates the response (`--irf calibrate`,
/// its default).
pub fn detector_response(
    req: &FitRequest,
    scene: &Scene,
    measured: &[f32],
    ignore_before_opl: Option<f32>,
    per_point: bool,
    log: &mut dyn FnMut(&str),
) -> Result<DetectorResponse> {
    let n = |name: &str| req.front.name(name);
    let irf_choice = req
        .irf
        .clone()
        .unwrap_or_else(|| if per_point { "calibrate" } else { "none" }.into());
    if irf_choice != "none" && req.jitter.is_some() {
        let (jitter, irf) = (n("jitter"), n("irf"));
        return Err(Error::Invalid(if req.irf.is_some() {
            format!("{jitter} and {irf} both give the detector's response: give one")
        } else {
            format!("{jitter} and {irf} both give the detector's response: with {} per-point the response is calibrated from the capture ({irf} calibrate)", n("background"))
        }));
    }
    let irf_choice = if irf_choice == "calibrate" {
        "none".to_string()
    } else {
        irf_choice
    };
    let irf = read_response(&n, &irf_choice, scene, measured, ignore_before_opl, log)?;
    let jitter_opl = req.jitter.unwrap_or(0.0);
    if irf.is_some() && req.time_offset.is_some() {
        return Err(Error::Invalid(format!(
            "{} shifts the {} Gaussian: use it with {} none",
            n("time_offset"),
            n("jitter"),
            n("irf")
        )));
    }
    if !(jitter_opl.is_finite() && jitter_opl >= 0.0) {
        return Err(Error::Invalid(format!(
            "{}: {jitter_opl} is not a standard deviation (OPL, m, >= 0)",
            n("jitter")
        )));
    }
    let film_opl = scene.film.temporal_bins as f64 * scene.film.bin_width_opl as f64;
    if jitter_opl > film_opl {
        return Err(Error::Invalid(format!(
            "{}: {jitter_opl} m is a blur longer than the whole film ({} bins x {} m = {film_opl} m); a detector's jitter is a few bins (OPL, m)",
            n("jitter"),
            scene.film.temporal_bins,
            scene.film.bin_width_opl
        )));
    }
    let time_offset_max_opl = req.time_offset.unwrap_or(0.0);
    if !(time_offset_max_opl.is_finite() && time_offset_max_opl >= 0.0) {
        return Err(Error::Invalid(format!(
            "{}: {time_offset_max_opl} is not a search range (OPL, m, >= 0)",
            n("time_offset")
        )));
    }
    if time_offset_max_opl > film_opl {
        return Err(Error::Invalid(format!(
            "{}: {time_offset_max_opl} m is a search range longer than the whole film ({film_opl} m)",
            n("time_offset")
        )));
    }
    if time_offset_max_opl > 0.0 && jitter_opl <= 0.0 {
        return Err(Error::Invalid(format!(
            "{} needs {} SIGMA > 0: with box bins the loss is piecewise constant in the offset (no gradient to find it by)",
            n("time_offset"),
            n("jitter")
        )));
    }
    Ok(DetectorResponse {
        irf,
        jitter_opl,
        time_offset_max_opl,
    })
}
