//! PNG previews of a transient (single/confocal layout `(sy, sx, T)`; exhaustive shows
//! the first laser point):
//!
//! - `*_streak.png`: x (vertical, scan row through the middle) against time
//!   (horizontal, bin 0 at the left): the hyperbolas of NLOS data;
//! - `*_image.png`: the time-integrated image, `+y` of the scan up;
//! - `*_first_arrival.png`: for each scan point, the first bin reaching 5 % of its peak,
//!   early = dark, late = bright, black where there is no signal.
//!
//! Values are shown with a square-root tone curve and the inferno colour map; images
//! are upscaled by whole pixels to at least 256 pixels on the short side.

use crate::error::{Error, Result};
use crate::transport::Transient;
use std::path::{Path, PathBuf};

/// Writes the three previews next to `out` (`out_streak.png`, …); returns their paths.
pub fn write_previews(out: &Path, t: &Transient) -> Result<Vec<PathBuf>> {
    let n = t.shape.len();
    let (sy, sx, bins) = (t.shape[n - 3], t.shape[n - 2], t.shape[n - 1]);
    let cube = &t.data[..sy * sx * bins];
    let at = |iy: usize, ix: usize, b: usize| cube[(iy * sx + ix) * bins + b];
    let stem = out.with_extension("");
    let name = |suffix: &str| PathBuf::from(format!("{}_{suffix}.png", stem.display()));
    let mut written = Vec::new();

    // Streak: rows = x along the middle scan row (x = 0 at the top), columns = time.
    let row = sy / 2;
    let streak: Vec<f32> = (0..sx)
        .flat_map(|ix| (0..bins).map(move |b| at(row, ix, b)))
        .collect();
    let p = name("streak");
    write_colormapped(&p, &normalise_sqrt(&streak), bins, sx)?;
    written.push(p);

    // Time-integrated image, +y up (scan row sy-1 at the top).
    let image: Vec<f32> = (0..sy)
        .rev()
        .flat_map(|iy| (0..sx).map(move |ix| (0..bins).map(|b| at(iy, ix, b)).sum::<f32>()))
        .collect();
    let p = name("image");
    write_colormapped(&p, &normalise_sqrt(&image), sx, sy)?;
    written.push(p);

    // First arrival: first bin reaching 5 % of the point's peak.
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
                first as f32
            })
        })
        .collect();
    let (lo, hi) = arrival
        .iter()
        .filter(|v| v.is_finite())
        .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
    let span = (hi - lo).max(1.0);
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
    write_colormapped(&p, &arrival_n, sx, sy)?;
    written.push(p);
    Ok(written)
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

/// Writes a `w x h` image of values in [0, 1] through the colour map, upscaled.
fn write_colormapped(path: &Path, v: &[f32], w: usize, h: usize) -> Result<()> {
    let (kx, ky) = ((256 / w.max(1)).max(1), (256 / h.max(1)).max(1));
    let (sw, sh) = (w * kx, h * ky);
    let mut rgb = vec![0u8; sw * sh * 3];
    for y in 0..sh {
        for x in 0..sw {
            let c = inferno(v[(y / ky) * w + x / kx]);
            rgb[(y * sw + x) * 3..][..3].copy_from_slice(&c);
        }
    }
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), sw as u32, sh as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.write_header()
        .and_then(|mut wr| wr.write_image_data(&rgb))
        .map_err(|e| Error::Invalid(format!("{}: writing PNG: {e}", path.display())))
}
