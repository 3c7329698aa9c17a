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
/// The names y-tal's users give at run time (y-tal's own YAML keys).
const YTAL: [&str; 5] = [
    "laser_lookat_x",
    "laser_lookat_y",
    "scan_type",
    "laser_width",
    "laser_height",
];

/// y-tal's run-time aim: film pixel coordinates (continuous).
#[derive(Clone, Copy, Debug)]
pub(super) struct Aim {
    pub x: f32,
    pub y: f32,
}

/// y-tal's run-time requests, from the command line's defines.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Run {
    /// `-D laser_lookat_x/y`: one laser point.
    pub aim: Option<Aim>,
    /// `-D scan_type=exhaustive` (y-tal's YAML key): every laser point of y-tal's grid,
    /// with its `laser_width` / `laser_height` if given.
    pub exhaustive: Option<(Option<u32>, Option<u32>)>,
}

/// Splits the command line's defines: y-tal's names (unless the XML uses them) become
/// a [`Run`]; any other define the XML never uses is an error.
pub(super) fn split_defines(
    parsed: &Parsed,
    origin: &Path,
    defines: &[(String, String)],
) -> Result<Run> {
    let ytal_name = |n: &str| YTAL.contains(&n) && !parsed.referenced.contains(n);
    let rest: Vec<(String, String)> = defines
        .iter()
        .filter(|(n, _)| !ytal_name(n))
        .cloned()
        .collect();
    tree::unused_defines(parsed, origin, &rest)?;
    let value = |name: &str| {
        defines
            .iter()
            .rev()
            .find(|(n, _)| n == name && ytal_name(n))
            .map(|(_, v)| v.trim())
    };
    let bad =
        |name: &str, v: &str, what: &str| Error::scene(origin, format!("-D {name}={v}: {what}"));
    let float = |name: &str| -> Result<Option<f32>> {
        match value(name) {
            None => Ok(None),
            Some(v) => match v.parse::<f32>() {
                Ok(f) if f.is_finite() => Ok(Some(f)),
                _ => Err(bad(
                    name,
                    v,
                    "y-tal's laser aim must be a number (film pixel units)",
                )),
            },
        }
    };
    let count = |name: &str| -> Result<Option<u32>> {
        match value(name) {
            None => Ok(None),
            Some(v) => match v.parse::<u32>() {
                Ok(n) if n > 0 => Ok(Some(n)),
                _ => Err(bad(name, v, "must be a positive count")),
            },
        }
    };
    let aim = match (float(LOOKAT[0])?, float(LOOKAT[1])?) {
        (None, None) => None,
        (Some(x), Some(y)) => Some(Aim { x, y }),
        _ => return Err(Error::scene(
            origin,
            "y-tal aims the laser with both -D laser_lookat_x=.. and -D laser_lookat_y=.. (film pixel units); give both",
        )),
    };
    let (lw, lh) = (count("laser_width")?, count("laser_height")?);
    let exhaustive = match value("scan_type") {
        None if lw.is_some() || lh.is_some() => {
            return Err(Error::scene(origin, "-D laser_width/laser_height (y-tal's laser grid) go with -D scan_type=exhaustive"))
        }
        None => None,
        Some("exhaustive") => Some((lw, lh)),
        Some(v) => {
            return Err(bad("scan_type", v, "Umbra reads y-tal's scan_type only as 'exhaustive' (every laser point of a single-capture XML); y-tal's single and confocal scans are in the XML itself"))
        }
    };
    if aim.is_some() && exhaustive.is_some() {
        return Err(Error::scene(origin, "-D laser_lookat_x/y (one laser point) and -D scan_type=exhaustive (all of them) exclude each other"));
    }
    Ok(Run { aim, exhaustive })
}

/// The capture, laser aim and scan grid, given y-tal's run-time requests `run`: the
/// scene's `capture` (its `capture_type`, at `capture_line`), its legacy confocal
/// sensor (`legacy`: the line of `original_film_*`) and its film's `scan`.
pub(super) fn resolve(
    cx: &Cx,
    run: Run,
    capture: CaptureType,
    capture_line: usize,
    legacy: Option<usize>,
    scan: &ScanGrid,
) -> Result<(CaptureType, Option<Vec3>, ScanGrid)> {
    let capture_after = match legacy {
        Some(line) => legacy_confocal_capture(cx, capture, line)?,
        None => capture,
    };
    if (run.aim.is_some() || run.exhaustive.is_some()) && capture != CaptureType::Single {
        return Err(cx.err(capture_line, format!("-D laser_lookat_x/y and -D scan_type=exhaustive are y-tal's run-time laser aim for its single-capture XMLs (and laser_lookat for its 1x1 confocal film), but this scene's capture_type is {}", capture.name())));
    }
    if let Some((lw, lh)) = run.exhaustive {
        if let Some(line) = legacy {
            return Err(cx.err(line, "-D scan_type=exhaustive: this is y-tal's confocal XML (1x1 film with original_film_width/height); its exhaustive XML has a full-size film"));
        }
        let (nx, ny) = (lw.unwrap_or(scan.nx), lh.unwrap_or(scan.ny));
        if (nx, ny) != (scan.nx, scan.ny) {
            return Err(Error::scene(cx.origin, format!("-D scan_type=exhaustive with y-tal's {nx}x{ny} laser grid: Umbra's exhaustive capture lights the scan grid's points, here {}x{}; render y-tal's laser points one at a time with -D laser_lookat_x=.. -D laser_lookat_y=..", scan.nx, scan.ny)));
        }
        return Ok((CaptureType::Exhaustive, None, scan.clone()));
    }
    match run.aim {
        None => Ok((capture_after, None, scan.clone())),
        Some(a) => {
            let p = aim_point(cx, a, scan)?;
            let scan = if legacy.is_some() {
                one_point_scan(scan, p)
            } else {
                scan.clone()
            };
            Ok((capture_after, Some(p), scan))
        }
    }
}

/// The capture a scene with mitransient's legacy confocal sensor (1x1 film plus
/// `original_film_width/height`, at `line`) describes: confocal over the original grid.
fn legacy_confocal_capture(cx: &Cx, capture: CaptureType, line: usize) -> Result<CaptureType> {
    match capture {
        CaptureType::Single | CaptureType::Confocal => Ok(CaptureType::Confocal),
        CaptureType::Exhaustive => Err(cx.err(line, "original_film_width/height (mitransient's one-point-per-render confocal sensor) with capture_type exhaustive: use a full-size film for exhaustive capture")),
    }
}

/// The wall point y-tal aims at: Mitsuba's `rectangle.sample_position(uv)` with
/// `uv = aim / film size`, on the scan grid's rectangle (the relay wall).
fn aim_point(cx: &Cx, aim: Aim, scan: &ScanGrid) -> Result<Vec3> {
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
fn one_point_scan(scan: &ScanGrid, p: Vec3) -> ScanGrid {
    ScanGrid {
        nx: 1,
        ny: 1,
        center: p,
        axis_u: scan.axis_u / scan.nx as f32,
        axis_v: scan.axis_v / scan.ny as f32,
    }
}
