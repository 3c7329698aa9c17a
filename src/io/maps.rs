//! Images side by side as labelled maps ([`labelled_maps`]): each with its title, its
//! axes in the units of its coordinates (optional) and a colour bar in the units of its
//! values; the picture drawn in memory and written atomically.

use super::plot::{err, register_font, tick, FAMILY};
use crate::error::{Error, Result};
use crate::io::preview::inferno;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::Path;

/// One labelled image of [`labelled_maps`]: `values` row-major, top row first, NaN for
/// "nothing here" (drawn black); the colour map spans `range` (`lo` dark, `hi` bright),
/// explained under the image by a colour bar from `lo` to `hi` with `unit`.
pub struct MapPanel<'a> {
    /// What the panel shows (lines separated by `\n`).
    pub title: &'a str,
    pub width: usize,
    pub height: usize,
    pub values: &'a [f32],
    pub range: (f32, f32),
    /// The colour bar's caption, e.g. "depth from the wall (m)".
    pub unit: &'a str,
    /// Coordinates along the image's edges, drawn as ticks left of and under it.
    pub axes: Option<MapAxes<'a>>,
}

/// The coordinates a [`MapPanel`]'s image spans: `x` the values at its left and right
/// edges, `y` at its top and bottom edges (either pair may run from high to low, as a
/// view with `+x` to the left does), and the axes' names.
#[derive(Clone, Copy, Debug)]
pub struct MapAxes<'a> {
    pub x: (f32, f32),
    pub y: (f32, f32),
    pub x_label: &'a str,
    pub y_label: &'a str,
}

/// Room left of an image for its y ticks, and under it for its x ticks and name.
const AXES_LEFT: i32 = 58;
const AXES_BELOW: i32 = 38;

/// Round tick values (1, 2 or 5 times a power of ten apart, three to six of them) between
/// `a` and `b`, each with its place along the edge from `a` (0) to `b` (1); none within
/// 4 % of an end, where its label would run into the other axis's.
fn ticks(a: f32, b: f32) -> Vec<(f32, f32)> {
    let (lo, hi) = (a.min(b) as f64, a.max(b) as f64);
    let span = hi - lo;
    if !(span > 0.0 && span.is_finite()) {
        return Vec::new();
    }
    let raw = span / 5.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .map(|k| k * mag)
        .find(|&s| s >= raw * (1.0 - 1e-6))
        .unwrap_or(10.0 * mag);
    let first = (lo / step - 1e-6).ceil() as i64;
    let last = (hi / step + 1e-6).floor() as i64;
    (first..=last)
        .map(|k| {
            let v = k as f64 * step;
            (v as f32, ((v - a as f64) / (b as f64 - a as f64)) as f32)
        })
        .filter(|(_, t)| (0.04..=0.96).contains(t))
        .collect()
}

/// Draws `axes` around the `w x h` image whose top-left corner is `(x, y)`.
fn draw_map_axes<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    path: &Path,
    axes: &MapAxes,
    (x, y, w, h): (i32, i32, i32, i32),
) -> Result<()> {
    let style = |h: HPos, v: VPos| TextStyle::from((FAMILY, 12).into_font()).pos(Pos::new(h, v));
    let label = |v: f32| {
        let s = tick(v as f64);
        if s == "-0" {
            "0".to_string()
        } else {
            s
        }
    };
    for (v, t) in ticks(axes.x.0, axes.x.1) {
        let px = x + (t * w as f32).round() as i32;
        root.draw(&PathElement::new([(px, y + h), (px, y + h + 4)], BLACK))
            .map_err(|e| err(path, e))?;
        root.draw(&Text::new(
            label(v),
            (px, y + h + 6),
            style(HPos::Center, VPos::Top),
        ))
        .map_err(|e| err(path, e))?;
    }
    for (v, t) in ticks(axes.y.0, axes.y.1) {
        let py = y + (t * h as f32).round() as i32;
        root.draw(&PathElement::new([(x - 4, py), (x, py)], BLACK))
            .map_err(|e| err(path, e))?;
        root.draw(&Text::new(
            label(v),
            (x - 6, py),
            style(HPos::Right, VPos::Center),
        ))
        .map_err(|e| err(path, e))?;
    }
    root.draw(&Text::new(
        axes.x_label.to_string(),
        (x + w / 2, y + h + 21),
        style(HPos::Center, VPos::Top),
    ))
    .map_err(|e| err(path, e))?;
    root.draw(&Text::new(
        axes.y_label.to_string(),
        (x - AXES_LEFT + 2, y + h / 2),
        style(HPos::Center, VPos::Top).transform(FontTransform::Rotate270),
    ))
    .map_err(|e| err(path, e))
}

/// Images side by side, each with its title above, its axes (if it has them) and a
/// labelled colour bar below; `title` heads the picture and `footer` (e.g. the
/// orientation) ends it. Drawn in memory, then written atomically as every output is.
pub fn labelled_maps(path: &Path, title: &str, panels: &[MapPanel], footer: &str) -> Result<()> {
    register_font();
    const SIDE: usize = 256;
    const GAP: i32 = 24;
    const TOP: i32 = 84;
    for p in panels {
        if p.values.len() != p.width * p.height || p.width == 0 || p.height == 0 {
            return Err(err(
                path,
                format!(
                    "a panel of {} values is not {} x {}",
                    p.values.len(),
                    p.width,
                    p.height
                ),
            ));
        }
    }
    let zoom = |p: &MapPanel| (SIDE / p.width.max(p.height)).max(1);
    let left = |p: &MapPanel| if p.axes.is_some() { AXES_LEFT } else { 0 };
    let below = if panels.iter().any(|p| p.axes.is_some()) {
        AXES_BELOW
    } else {
        0
    };
    let image_h = panels.iter().map(|p| p.height * zoom(p)).max().unwrap_or(1) as i32;
    let total_w: i32 = panels
        .iter()
        .map(|p| left(p) + (p.width * zoom(p)).max(SIDE) as i32 + GAP)
        .sum::<i32>()
        + GAP;
    let footer_lines = footer.lines().count() as i32;
    // Room for the heading and the footer too (DejaVu Sans Mono advances 0.52 of the
    // type size per character).
    let text_w = |t: &str, size: f32| (0.52 * size * t.chars().count() as f32).ceil() as i32;
    let words_w = footer
        .lines()
        .map(|l| text_w(l, 12.0))
        .chain([text_w(title, 16.0)])
        .max()
        .unwrap_or(0)
        + 2 * GAP;
    let (w, h) = (
        total_w.max(words_w).max(400) as u32,
        (TOP + image_h + below + 72 + 16 * footer_lines) as u32,
    );
    let mut rgb = vec![0u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(path, e))?;
        let text = |t: &str, x: i32, y: i32, size: u32| {
            root.draw(&Text::new(t.to_string(), (x, y), (FAMILY, size)))
                .map_err(|e| err(path, e))
        };
        text(title, GAP, 8, 16)?;
        let mut x = GAP;
        for p in panels {
            let k = zoom(p);
            for (i, line) in p.title.lines().enumerate() {
                text(line, x, 36 + 16 * i as i32, 13)?;
            }
            x += left(p);
            let (lo, hi) = p.range;
            let span = if hi > lo { hi - lo } else { 1.0 };
            for r in 0..p.height {
                for c in 0..p.width {
                    let v = p.values[r * p.width + c];
                    let [cr, cg, cb] = if v.is_finite() {
                        inferno(((v - lo) / span).clamp(0.0, 1.0))
                    } else {
                        [0, 0, 0]
                    };
                    let (px, py) = (x + (c * k) as i32, TOP + (r * k) as i32);
                    root.draw(&Rectangle::new(
                        [(px, py), (px + k as i32, py + k as i32)],
                        RGBColor(cr, cg, cb).filled(),
                    ))
                    .map_err(|e| err(path, e))?;
                }
            }
            let (iw, ih) = ((p.width * k) as i32, (p.height * k) as i32);
            if let Some(axes) = &p.axes {
                draw_map_axes(&root, path, axes, (x, TOP, iw, ih))?;
            }
            // The colour bar: lo at the left, hi at the right.
            let y = TOP + image_h + below + 10;
            for i in 0..iw {
                let [cr, cg, cb] = inferno(i as f32 / (iw - 1).max(1) as f32);
                root.draw(&Rectangle::new(
                    [(x + i, y), (x + i + 1, y + 12)],
                    RGBColor(cr, cg, cb).filled(),
                ))
                .map_err(|e| err(path, e))?;
            }
            let fmt = |v: f32| {
                if v.abs() >= 100.0 || v == 0.0 {
                    format!("{v:.0}")
                } else {
                    format!("{v:.3}")
                }
            };
            text(&fmt(lo), x, y + 16, 12)?;
            let hi_label = fmt(hi);
            text(&hi_label, x + iw - 7 * hi_label.len() as i32, y + 16, 12)?;
            text(p.unit, x, y + 32, 12)?;
            x += iw.max(SIDE as i32) + GAP;
        }
        for (i, line) in footer.lines().enumerate() {
            text(line, GAP, TOP + image_h + below + 62 + 16 * i as i32, 12)?;
        }
        root.present().map_err(|e| err(path, e))?;
    }
    write_png(path, &rgb, (w, h))
}

/// Encodes an RGB image as PNG and writes it atomically (`optim::checkpoint::write_atomic`).
fn write_png(path: &Path, rgb: &[u8], (w, h): (u32, u32)) -> Result<()> {
    let mut bytes = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut bytes, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .and_then(|mut wr| wr.write_image_data(rgb))
            .map_err(|e| err(path, e))?;
    }
    optim::checkpoint::write_atomic(path, &bytes).map_err(|e| Error::io(path, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_ticks_are_round_and_inside_the_edges() {
        let values = |a, b| ticks(a, b).iter().map(|t| t.0).collect::<Vec<f32>>();
        assert_eq!(values(0.5, -0.5), [-0.4, -0.2, 0.0, 0.2, 0.4]);
        assert_eq!(values(0.36, -0.36), [-0.2, 0.0, 0.2]);
        assert_eq!(values(0.4, -0.4), [-0.2, 0.0, 0.2]);
        // places run from the first end (0) to the second (1)
        let t = ticks(0.5, -0.5);
        assert!(
            (t[0].1 - 0.9).abs() < 1e-6 && (t[4].1 - 0.1).abs() < 1e-6,
            "{t:?}"
        );
        assert!(ticks(1.0, 1.0).is_empty());
    }
}
