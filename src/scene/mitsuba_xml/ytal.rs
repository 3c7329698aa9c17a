//! What y-tal 0.20.0 adds around the XML it writes (read from its `tal/render`
//! sources): it renders a scene one laser point at a time, aiming the laser at run time
//! with `mitransient.nlos.focus_emitter_at_relay_wall_pixel(Point2f(x, y), ...)`, where
//! `(x, y)` are its `laser_lookat_x` / `laser_lookat_y` in the film's pixel units
//! (`(i + ½) / laser_width · sensor_width`). It passes them in the same `defines` as
//! Mitsuba's `-D` values but takes them out before `mi.load_file`: they are not XML
//! parameters, and the XML never uses `$laser_lookat_x`.
//!
//! - single: one render, aimed at `laser_lookat_*` (default: the film's centre).
//! - exhaustive: the *same* XML as single (byte for byte), rendered once per laser
//!   point of a `laser_width x laser_height` grid; y-tal stacks the results.
//! - confocal: a 1x1 film with `original_film_width/height` = the scan grid; mitransient
//!   then points the sensor at the laser's target, so each of the w x h renders is one
//!   confocal measurement.
//!
//! Umbra therefore reads `-D laser_lookat_x=.. -D laser_lookat_y=..` (when the XML does
//! not use those names itself) as y-tal's aim: the laser target of a single capture,
//! or the one confocal point of a legacy confocal scene. Both are the exact render
//! mitransient makes for that laser point.

use super::params::Cx;
use super::tree::{self, Parsed};
use crate::error::{Error, Result};
use crate::scene::{CaptureType, ScanGrid};
use glam::Vec3;
use std::path::Path;

const LOOKAT: [&str; 2] = ["laser_lookat_x", "laser_lookat_y"];

/// y-tal's run-time aim: film pixel coordinates (continuous).
#[derive(Clone, Copy, Debug)]
pub(super) struct Aim {
    pub x: f32,
    pub y: f32,
}

/// Splits the command line's defines: y-tal's `laser_lookat_x/y` (unless the XML uses
/// those names) become an [`Aim`]; any other define the XML never uses is an error.
pub(super) fn split_defines(
    parsed: &Parsed,
    origin: &Path,
    defines: &[(String, String)],
) -> Result<Option<Aim>> {
    let is_aim = |n: &str| LOOKAT.contains(&n) && !parsed.referenced.contains(n);
    let rest: Vec<(String, String)> = defines
        .iter()
        .filter(|(n, _)| !is_aim(n))
        .cloned()
        .collect();
    tree::unused_defines(parsed, origin, &rest)?;
    let get = |name: &str| -> Result<Option<f32>> {
        let Some((_, v)) = defines.iter().rev().find(|(n, _)| n == name) else {
            return Ok(None);
        };
        match v.trim().parse::<f32>() {
            Ok(f) if f.is_finite() => Ok(Some(f)),
            _ => Err(Error::scene(
                origin,
                format!("-D {name}={v}: y-tal's laser aim must be a number (film pixel units)"),
            )),
        }
    };
    match (get(LOOKAT[0])?, get(LOOKAT[1])?) {
        (None, None) => Ok(None),
        (Some(x), Some(y)) => Ok(Some(Aim { x, y })),
        _ => Err(Error::scene(
            origin,
            "y-tal aims the laser with both -D laser_lookat_x=.. and -D laser_lookat_y=.. (film pixel units); give both",
        )),
    }
}

/// The capture a scene with mitransient's legacy confocal sensor (1x1 film plus
/// `original_film_width/height`, at `line`) describes: confocal over the original grid.
pub(super) fn legacy_confocal_capture(
    cx: &Cx,
    capture: CaptureType,
    line: usize,
) -> Result<CaptureType> {
    match capture {
        CaptureType::Single | CaptureType::Confocal => Ok(CaptureType::Confocal),
        CaptureType::Exhaustive => Err(cx.err(line, "original_film_width/height (mitransient's one-point-per-render confocal sensor) with capture_type exhaustive: use a full-size film for exhaustive capture")),
    }
}

/// The wall point y-tal aims at: Mitsuba's `rectangle.sample_position(uv)` with
/// `uv = aim / film size`, on the scan grid's rectangle (the relay wall).
pub(super) fn aim_point(cx: &Cx, aim: Aim, scan: &ScanGrid) -> Result<Vec3> {
    let (nx, ny) = (scan.nx as f32, scan.ny as f32);
    if !(0.0..=nx).contains(&aim.x) || !(0.0..=ny).contains(&aim.y) {
        return Err(Error::scene(
            cx.origin,
            format!(
                "-D laser_lookat_x={} -D laser_lookat_y={}: y-tal's aim is in film pixel units and must lie on the {}x{} film (0..{nx}, 0..{ny})",
                aim.x, aim.y, scan.nx, scan.ny
            ),
        ));
    }
    let (u, v) = (aim.x / nx - 0.5, aim.y / ny - 0.5);
    Ok(scan.center + u * scan.axis_u + v * scan.axis_v)
}

/// A legacy confocal scene aimed at one point renders that point alone (a 1x1 film):
/// a one-point scan there, one pixel of the original grid wide.
pub(super) fn one_point_scan(scan: &ScanGrid, p: Vec3) -> ScanGrid {
    ScanGrid {
        nx: 1,
        ny: 1,
        center: p,
        axis_u: scan.axis_u / scan.nx as f32,
        axis_v: scan.axis_v / scan.ny as f32,
    }
}
