//! The files a fit writes besides its meshes and maps: `loss.csv` and `loss.png` (the
//! loss per iteration, stage boundaries marked) and `transients.png` (measured and
//! fitted streak images), and the relative L2 of the fitted transient.

use crate::error::{Error, Result};
use crate::io::plot::{log_chart, side_by_side, Series};
use crate::scene::{CaptureType, Scene};
use optim::checkpoint::{write_atomic, LossRecord};
use std::path::{Path, PathBuf};

/// `‖μ − M‖ / ‖M‖` over bins `first..` of every `bins`-long row.
pub fn relative_l2(model: &[f32], measured: &[f32], bins: usize, first: usize) -> f64 {
    let (mut rr, mut mm) = (0.0f64, 0.0f64);
    for (mu, m) in model.chunks_exact(bins).zip(measured.chunks_exact(bins)) {
        for t in first..bins {
            let (a, b) = (f64::from(mu[t]), f64::from(m[t]));
            rr += (a - b) * (a - b);
            mm += b * b;
        }
    }
    if mm > 0.0 {
        (rr / mm).sqrt()
    } else {
        0.0
    }
}

pub fn write_loss(out: &Path, history: &[LossRecord]) -> Result<Vec<PathBuf>> {
    let csv_path = out.join("loss.csv");
    let mut csv = String::from(
        "iteration,stage,cost,data_loss,smoothness,scale,background,held_out,response_sigma\n",
    );
    for r in history {
        let value = |key: &str| {
            r.report
                .iter()
                .find(|(k, _)| k == key)
                .map_or(f64::NAN, |(_, v)| *v)
        };
        csv.push_str(&format!(
            "{},{},{:e},{:e},{:e},{:e},{:e},{:e},{:e}\n",
            r.iteration,
            r.stage,
            r.cost,
            r.data_loss,
            r.smoothness,
            value("scale"),
            value("background"),
            value("held_out"),
            value("response_sigma")
        ));
    }
    write_atomic(&csv_path, csv.as_bytes()).map_err(|e| Error::io(&csv_path, e))?;
    let png = out.join("loss.png");
    let marks: Vec<f64> = history
        .windows(2)
        .filter(|w| w[0].stage != w[1].stage)
        .map(|w| w[1].iteration as f64 - 0.5)
        .collect();
    let points = |f: &dyn Fn(&LossRecord) -> f64| -> Vec<(f64, f64)> {
        history.iter().map(|r| (r.iteration as f64, f(r))).collect()
    };
    let mut series = vec![
        Series {
            label: "total = data + smoothness (+ albedo TV)",
            points: points(&|r| r.cost),
        },
        Series {
            label: "data loss: |sH + b - M|^2 / |M|^2, or Poisson deviance per bin (at the stage's resolution)",
            points: points(&|r| r.data_loss),
        },
    ];
    if history.iter().any(|r| r.smoothness > 0.0) {
        series.push(Series {
            label: "smoothness (Laplacian + albedo TV) term",
            points: points(&|r| r.smoothness),
        });
    }
    if !history.is_empty() {
        log_chart(
            &png,
            "umbra fit: loss per iteration",
            "iteration",
            "loss (relative, dimensionless)",
            &series,
            &marks,
        )?;
    }
    Ok(vec![csv_path, png])
}

/// Streak images (scan x along the middle row, time) of the measurement, the fit (times
/// the scale, plus the background) and their absolute difference, over the bins where
/// the measurement has signal (above 1 % of its peak, with a margin), at most 140
/// columns.
pub fn write_transients(
    out: &Path,
    scene: &Scene,
    measured: &[f32],
    fitted: &[f32],
) -> Result<PathBuf> {
    let bins = scene.film.temporal_bins as usize;
    let (nx, ny) = (scene.scan.nx as usize, scene.scan.ny as usize);
    let row0 = match scene.capture {
        CaptureType::Exhaustive => 0,
        _ => (ny / 2) * nx,
    };
    let rows = &measured[row0 * bins..(row0 + nx) * bins];
    let peak = rows.iter().cloned().fold(0.0f32, f32::max);
    let lit: Vec<usize> = (0..bins)
        .filter(|&b| (0..nx).any(|ix| rows[ix * bins + b] > 0.01 * peak))
        .collect();
    let (first, last) = match (lit.first(), lit.last()) {
        (Some(&a), Some(&b)) => {
            let margin = (b - a) / 10 + 2;
            (a.saturating_sub(margin), (b + margin).min(bins - 1))
        }
        _ => (0, bins - 1),
    };
    let span = last + 1 - first;
    let k = span.div_ceil(140).max(1);
    let cols = span / k;
    let streak = |data: &[f32]| -> Vec<f32> {
        let mut img = vec![0.0f32; nx * cols];
        for ix in 0..nx {
            let row = &data[(row0 + ix) * bins + first..(row0 + ix + 1) * bins];
            for c in 0..cols {
                img[ix * cols + c] = row[c * k..(c + 1) * k].iter().sum::<f32>();
            }
        }
        img
    };
    let (m, f) = (streak(measured), streak(fitted));
    let d: Vec<f32> = m.iter().zip(&f).map(|(a, b)| (a - b).abs()).collect();
    let path = out.join("transients.png");
    let opl = |b: usize| scene.film.start_opl + b as f32 * scene.film.bin_width_opl;
    side_by_side(
        &path,
        &format!(
            "middle scan row: scan x (down) vs OPL {:.2}-{:.2} m (right)",
            opl(first),
            opl(first + cols * k)
        ),
        &[
            ("measured", cols, nx, &m),
            ("fitted x scale + background", cols, nx, &f),
            ("|difference|", cols, nx, &d),
        ],
    )?;
    Ok(path)
}
