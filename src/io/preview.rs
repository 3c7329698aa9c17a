//! PNG previews of a transient (single/confocal layout `(sy, sx, T)`; exhaustive shows
//! the first laser point):
//!
//! - `*_streak.png`: x (vertical, scan row through the middle) against time
//!   (horizontal, bin 0 at the left): the hyperbolas of NLOS data;
//! - `*_image.png`: the time-integrated image, `+y` of the scan up;
//! - `*_first_arrival.png`: for each scan point, the first bin reaching 5 % of its peak,
//!   early = dark, late = bright, black where there is no signal.
//!
//! Values are shown with a square-root tone curve and the inferno colour map, on axes in
//! metres on the wall (`u`, `v`: the scan rectangle's sides, centred) and in optical path
//! length.

use crate::error::{Error, Result};
use crate::transport::Transient;
use std::path::{Path, PathBuf};

/// Where the previews' axes come from: the scan rectangle's sides (m) and the film's start
/// and bin width (OPL, m).
#[derive(Clone, Copy, Debug)]
pub struct PreviewAxes {
    pub scan_u: f64,
    pub scan_v: f64,
    pub start_opl: f64,
    pub bin_opl: f64,
}

impl PreviewAxes {
    pub fn of(scene: &crate::scene::Scene) -> PreviewAxes {
        PreviewAxes {
            scan_u: f64::from(scene.scan.axis_u.length()),
            scan_v: f64::from(scene.scan.axis_v.length()),
            start_opl: f64::from(scene.film.start_opl),
            bin_opl: f64::from(scene.film.bin_width_opl),
        }
    }
}

/// Writes the three previews next to `out` (`out_streak.png`, …), with axes in metres on
/// the wall and in optical path length; returns their paths.
pub fn write_previews(out: &Path, t: &Transient, axes: &PreviewAxes) -> Result<Vec<PathBuf>> {
    let n = t.shape.len();
    let (sy, sx, bins) = (t.shape[n - 3], t.shape[n - 2], t.shape[n - 1]);
    let cube = &t.data[..sy * sx * bins];
    let at = |iy: usize, ix: usize, b: usize| cube[(iy * sx + ix) * bins + b];
    let stem = out.with_extension("");
    let name = |suffix: &str| PathBuf::from(format!("{}_{suffix}.png", stem.display()));
    let (u, v) = (axes.scan_u / 2.0, axes.scan_v / 2.0);
    let end = axes.start_opl + bins as f64 * axes.bin_opl;
    let mut written = Vec::new();

    // Streak: the middle scan row's points (u) against time, bins summed in groups so
    // that at most MAX_COLUMNS are drawn.
    let group = bins.div_ceil(MAX_COLUMNS).max(1);
    let cols = bins.div_ceil(group);
    let row = sy / 2;
    let streak: Vec<f32> = (0..sx)
        .rev()
        .flat_map(|ix| {
            (0..cols).map(move |c| {
                (c * group..((c + 1) * group).min(bins))
                    .map(|b| at(row, ix, b))
                    .sum()
            })
        })
        .collect();
    let p = name("streak");
    let map = Map {
        values: &normalise_sqrt(&streak),
        width: cols,
        height: sx,
    };
    map.draw(
        &p,
        "streak: the middle scan row against time (square-root scale)",
        (axes.start_opl, end),
        (-u, u),
        ("optical path length (m)", "u on the wall (m)"),
    )?;
    written.push(p);

    // Time-integrated image, +v up (scan row sy-1 at the top).
    let image: Vec<f32> = (0..sy)
        .rev()
        .flat_map(|iy| (0..sx).map(move |ix| (0..bins).map(|b| at(iy, ix, b)).sum::<f32>()))
        .collect();
    let p = name("image");
    let map = Map {
        values: &normalise_sqrt(&image),
        width: sx,
        height: sy,
    };
    map.draw(
        &p,
        "time-integrated image (square-root scale)",
        (-u, u),
        (-v, v),
        ("u on the wall (m)", "v (m)"),
    )?;
    written.push(p);

    // First arrival: the OPL of the first bin reaching 5 % of the point's peak.
    let global_peak = cube.iter().cloned().fold(0.0f32, f32::max);
    let arrival: Vec<f32> = (0..sy)
        .rev()
        .flat_map(|iy| {
            (0..sx).map(move |ix| {
                let peak = (0..bins).map(|b| at(iy, ix, b)).fold(0.0f32, f32::max);
                if peak <= 1e-6 * global_peak || peak <= 0.0 {
                    return f32::NAN;
                }
                let first = (0..bins)
                    .find(|&b| at(iy, ix, b) >= 0.05 * peak)
                    .unwrap_or(0);
                (axes.start_opl + first as f64 * axes.bin_opl) as f32
            })
        })
        .collect();
    let (lo, hi) = arrival
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let span = if hi > lo { hi - lo } else { 1.0 };
    let arrival_n: Vec<f32> = arrival
        .iter()
        .map(|&v| {
            if v.is_finite() {
                0.15 + 0.85 * (v - lo) / span
            } else {
                0.0
            }
        })
        .collect();
    let p = name("first_arrival");
    let title = if lo <= hi {
        format!("first arrival (dark = early): OPL {lo:.3} to {hi:.3} m; black: no signal")
    } else {
        "first arrival: no signal".to_string()
    };
    let map = Map {
        values: &arrival_n,
        width: sx,
        height: sy,
    };
    map.draw(&p, &title, (-u, u), (-v, v), ("u on the wall (m)", "v (m)"))?;
    written.push(p);
    Ok(written)
}

/// Most time columns a streak preview draws.
const MAX_COLUMNS: usize = 600;

/// A `width x height` image of values in [0, 1], top row first.
struct Map<'a> {
    values: &'a [f32],
    width: usize,
    height: usize,
}

impl Map<'_> {
    /// Draws the map through the colour map on axes spanning `x` and `y`.
    fn draw(
        &self,
        path: &Path,
        title: &str,
        x: (f64, f64),
        y: (f64, f64),
        labels: (&str, &str),
    ) -> Result<()> {
        use crate::io::plot::register_font;
        register_font();
        let bad = |e: &dyn std::fmt::Display| {
            Error::Invalid(format!("{}: writing PNG: {e}", path.display()))
        };
        let wide = self.width > 2 * self.height;
        let size: (u32, u32) = if wide { (900, 420) } else { (560, 560) };
        // Drawn in memory, then written atomically as every output is.
        let mut rgb = vec![0u8; size.0 as usize * size.1 as usize * 3];
        self.draw_into(&mut rgb, size, title, x, y, labels)
            .map_err(|e| bad(&e))?;
        let mut png_bytes = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut png_bytes, size.0, size.1);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.write_header()
                .and_then(|mut w| w.write_image_data(&rgb))
                .map_err(|e| bad(&e))?;
        }
        optim::checkpoint::write_atomic(path, &png_bytes).map_err(|e| Error::io(path, e))
    }

    fn draw_into(
        &self,
        rgb: &mut [u8],
        size: (u32, u32),
        title: &str,
        x: (f64, f64),
        y: (f64, f64),
        labels: (&str, &str),
    ) -> std::result::Result<(), String> {
        use crate::io::plot::FAMILY;
        use plotters::prelude::*;
        let bad = |e: &dyn std::fmt::Display| e.to_string();
        let root = BitMapBackend::with_buffer(rgb, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| bad(&e))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (FAMILY, 15))
            .margin(10)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x.0..x.1, y.0..y.1)
            .map_err(|e| bad(&e))?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc(labels.0)
            .y_desc(labels.1)
            .label_style((FAMILY, 13))
            .x_label_formatter(&|v| crate::io::plot::tick(*v))
            .y_label_formatter(&|v| crate::io::plot::tick(*v))
            .draw()
            .map_err(|e| bad(&e))?;
        let (dx, dy) = (
            (x.1 - x.0) / self.width as f64,
            (y.1 - y.0) / self.height as f64,
        );
        let cells = (0..self.height).flat_map(|r| (0..self.width).map(move |c| (r, c)));
        chart
            .draw_series(cells.map(|(r, c)| {
                let [cr, cg, cb] = inferno(self.values[r * self.width + c]);
                let (x0, y1) = (x.0 + c as f64 * dx, y.1 - r as f64 * dy);
                Rectangle::new(
                    [(x0, y1 - dy), (x0 + dx, y1)],
                    RGBColor(cr, cg, cb).filled(),
                )
            }))
            .map_err(|e| bad(&e))?;
        root.present().map_err(|e| bad(&e))
    }
}

/// Maps values to [0, 1] by `sqrt(v / max)`; negatives and non-finite to 0.
fn normalise_sqrt(v: &[f32]) -> Vec<f32> {
    let max = v
        .iter()
        .cloned()
        .filter(|x| x.is_finite())
        .fold(0.0f32, f32::max);
    v.iter()
        .map(|&x| {
            if max > 0.0 && x > 0.0 {
                (x / max).sqrt()
            } else {
                0.0
            }
        })
        .collect()
}

/// Inferno colour map, piecewise linear through 9 samples of matplotlib's table.
pub fn inferno(t: f32) -> [u8; 3] {
    const C: [[f32; 3]; 9] = [
        [0.0015, 0.0005, 0.0139],
        [0.0873, 0.0447, 0.2244],
        [0.2582, 0.0386, 0.4065],
        [0.4163, 0.0902, 0.4329],
        [0.5783, 0.1480, 0.4044],
        [0.7357, 0.2159, 0.3302],
        [0.8650, 0.3168, 0.2261],
        [0.9541, 0.4681, 0.0989],
        [0.9883, 0.9984, 0.6449],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    } * 8.0;
    let i = (t as usize).min(7);
    let f = t - i as f32;
    let c = |k: usize| ((C[i][k] * (1.0 - f) + C[i + 1][k] * f) * 255.0).round() as u8;
    [c(0), c(1), c(2)]
}
