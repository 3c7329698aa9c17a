//! PNG pictures of a reconstruction, with the inferno colour map of
//! [`crate::io::preview::inferno`]:
//!
//! - [`write_volume_png`]: two maximum-intensity projections side by side: the front
//!   view `max_z V(x, y, z)` as seen from the wall looking into the hidden scene (`+y`
//!   up, so `+x` points left: a letter that faces the wall reads correctly) and the top
//!   view `max_y V(x, y, z)` (`+x` left as well, depth growing downward from the wall at
//!   the top);
//!   the value shown is `max(V, 0) / max V` (linear);
//! - [`write_depth_png`]: the depth map, near = dark, far = bright, black where empty;
//! - [`write_comparison_png`]: the front projection and several depth maps on one
//!   depth scale (a backprojection next to a fitted surface).
//!
//! Each panel is upscaled by whole pixels to about 256 pixels on its longer side.

use super::{DepthMap, Volume};
use crate::error::{Error, Result};
use crate::io::preview::inferno;
use std::path::Path;

/// An image of values in `[0, 1]` (NaN = black), row-major, top row first.
struct Panel {
    w: usize,
    h: usize,
    v: Vec<f32>,
}

/// Writes the front and top maximum-intensity projections of `volume` to `path`.
pub fn write_volume_png(path: &Path, volume: &Volume) -> Result<()> {
    let (front, top) = volume_panels(path, volume)?;
    write_panels(path, &[front, top])
}

/// The front and top maximum-intensity projections of `volume`.
fn volume_panels(path: &Path, volume: &Volume) -> Result<(Panel, Panel)> {
    let [nx, ny, nz] = volume.grid.dims;
    if volume.data.len() != nx * ny * nz {
        return Err(Error::Invalid(format!(
            "{}: the volume holds {} values for a grid of {:?}",
            path.display(),
            volume.data.len(),
            volume.grid.dims
        )));
    }
    let max = volume
        .data
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0f32, f32::max);
    let norm = |v: f32| {
        if max > 0.0 && v > 0.0 {
            v / max
        } else {
            0.0
        }
    };
    let col_max = |ix: usize, iy: usize| volume.column(ix, iy).iter().copied().fold(0.0, f32::max);
    let front = Panel {
        w: nx,
        h: ny,
        v: (0..ny)
            .rev()
            .flat_map(|iy| (0..nx).rev().map(move |ix| norm(col_max(ix, iy))))
            .collect(),
    };
    let top = Panel {
        w: nx,
        h: nz,
        v: (0..nz)
            .flat_map(|iz| {
                (0..nx).rev().map(move |ix| {
                    norm(
                        (0..ny)
                            .map(|iy| volume.column(ix, iy)[iz])
                            .fold(0.0, f32::max),
                    )
                })
            })
            .collect(),
    };
    Ok((front, top))
}

/// Writes the depth map of `dm` to `path`, seen from the wall (`+y` up, `+x` left).
pub fn write_depth_png(path: &Path, dm: &DepthMap) -> Result<()> {
    let (lo, hi) = depth_range(&[dm]);
    write_panels(path, &[depth_panel(path, dm, lo, hi)?])
}

/// Writes, side by side: the front maximum-intensity projection of `volume`, the
/// intensity of `surface` (seen from the wall, relative to its maximum), then the depth
/// maps `depths` on one shared scale (near = dark): e.g. a backprojection next to a
/// fitted surface's albedo and both depth maps.
pub fn write_comparison_png(
    path: &Path,
    volume: &Volume,
    surface: &DepthMap,
    depths: &[&DepthMap],
) -> Result<()> {
    let (lo, hi) = depth_range(depths);
    let mut panels = vec![
        volume_panels(path, volume)?.0,
        intensity_panel(path, surface)?,
    ];
    for dm in depths {
        panels.push(depth_panel(path, dm, lo, hi)?);
    }
    write_panels(path, &panels)
}

/// A depth map's intensity as a panel seen from the wall, relative to its maximum.
fn intensity_panel(path: &Path, dm: &DepthMap) -> Result<Panel> {
    let max = dm
        .intensity
        .iter()
        .copied()
        .fold(0.0f32, f32::max)
        .max(1e-12);
    map_panel(path, dm, |_, intensity| intensity.max(0.0) / max)
}

/// The finite depths' `(min, max)` over all maps.
fn depth_range(depths: &[&DepthMap]) -> (f32, f32) {
    depths
        .iter()
        .flat_map(|dm| dm.depth.iter())
        .filter(|v| v.is_finite())
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)))
}

/// A depth map as a panel seen from the wall, `lo..hi` mapped to `0.15..1`.
fn depth_panel(path: &Path, dm: &DepthMap, lo: f32, hi: f32) -> Result<Panel> {
    let span = (hi - lo).max(1e-6);
    map_panel(path, dm, |d, _| {
        if d.is_finite() {
            0.15 + 0.85 * (d - lo) / span
        } else {
            f32::NAN
        }
    })
}

/// `value(depth, intensity)` of each column of `dm`, seen from the wall (`+y` up, `+x`
/// left).
fn map_panel(path: &Path, dm: &DepthMap, value: impl Fn(f32, f32) -> f32) -> Result<Panel> {
    let (nx, ny) = (dm.nx, dm.ny);
    if dm.depth.len() != nx * ny || dm.intensity.len() != nx * ny || nx == 0 || ny == 0 {
        return Err(Error::Invalid(format!(
            "{}: a depth map of {} values is not {nx} x {ny}",
            path.display(),
            dm.depth.len()
        )));
    }
    let v = (0..ny)
        .rev()
        .flat_map(|iy| (0..nx).rev().map(move |ix| iy * nx + ix))
        .map(|i| value(dm.depth[i], dm.intensity[i]))
        .collect();
    Ok(Panel { w: nx, h: ny, v })
}

/// Lays the panels out left to right with a 4-pixel gap, each upscaled by the largest
/// whole factor that keeps its longer side within 256 pixels (at least 1).
fn write_panels(path: &Path, panels: &[Panel]) -> Result<()> {
    const GAP: usize = 4;
    let scale = |p: &Panel| (256 / p.w.max(p.h).max(1)).max(1);
    let width: usize =
        panels.iter().map(|p| p.w * scale(p)).sum::<usize>() + GAP * panels.len().saturating_sub(1);
    let height = panels.iter().map(|p| p.h * scale(p)).max().unwrap_or(1);
    if width == 0 || height == 0 || width > 1 << 15 || height > 1 << 15 {
        return Err(Error::Invalid(format!(
            "{}: image size {width} x {height} is out of range",
            path.display()
        )));
    }
    let mut rgb = vec![0u8; width * height * 3];
    let mut x0 = 0;
    for p in panels {
        let k = scale(p);
        for y in 0..p.h * k {
            for x in 0..p.w * k {
                let v = p.v[(y / k) * p.w + x / k];
                let c = if v.is_finite() { inferno(v) } else { [0, 0, 0] };
                rgb[(y * width + x0 + x) * 3..][..3].copy_from_slice(&c);
            }
        }
        x0 += p.w * k + GAP;
    }
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.write_header()
        .and_then(|mut wr| wr.write_image_data(&rgb))
        .map_err(|e| Error::Invalid(format!("{}: writing PNG: {e}", path.display())))
}
