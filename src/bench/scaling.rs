//! Scaling (`umbra bench scaling`): render time and peak memory against each size of the
//! problem, one axis at a time from a base case, with the fitted exponent `k` of
//! `time ∝ size^k` (least squares in log-log).
//!
//! Base case: the `tri3` model (default subdivision, no visibility) on a wavy sheet of
//! 10 082 triangles at 0.8 m, confocal 32 x 32, 512 bins of 4 mm. Axes: scan side (8 to
//! 64, so measurements grow as side²), time bins (128 to 2048), triangles (1k to 100k,
//! then 1M, the sheet refined), and samples per measurement on the same sheet (16 x 16
//! scan) for the multi-bounce path tracer (16 to 1024 spp), `mc3` (64 to 4096), and the
//! adjoint passes of both (the gradient for a fixed `dLoss/dH`, no forward render: path
//! replay keeps no tape, so memory must not grow with spp). Each point runs in a fresh process
//! (`umbra bench scaling-point`), so its peak resident memory (`VmHWM`) is its own.

use super::{mesh_scene, peak_rss_kb};
use crate::error::Result;
use crate::geometry::shapes::wavy_sheet;
use crate::geometry::SceneGeometry;
use crate::scene::{Model, Scene, Visibility};
use crate::transport::{RenderOptions, Renderer};
use glam::Vec3;
use std::time::Instant;

/// The axes, with the values each one takes.
pub const AXES: [(&str, &[u32]); 7] = [
    ("scan side", &[8, 16, 32, 64]),
    ("time bins", &[128, 256, 512, 1024, 2048]),
    ("triangles (thousands)", &[1, 4, 10, 40, 100, 1000]),
    ("path spp", &[16, 64, 256, 1024]),
    ("mc3 spp", &[64, 256, 1024, 4096]),
    ("mc3 adjoint spp", &[64, 256, 1024, 4096]),
    ("path adjoint spp", &[16, 64, 256, 1024]),
];

fn sheet_scene(triangles: u32, scan: u32, bins: u32) -> Result<Scene> {
    // (n+1)² vertices, 2n² triangles.
    let n = ((triangles as f64 / 2.0).sqrt().round() as u32).max(2);
    let bin_width = 0.004 * 512.0 / bins as f32;
    mesh_scene(
        wavy_sheet(Vec3::new(0.0, 0.1, 0.8), 0.6, n, 0.02, 0.3),
        scan,
        bins,
        bin_width,
        1.5,
    )
}

/// One point: `(render seconds, peak RSS kB, work units)` for `axis` (an index into
/// [`AXES`]) at `value`.
pub fn point(axis: usize, value: u32) -> Result<(f64, u64, u64)> {
    let (scene, model, spp) = match axis {
        0 => (sheet_scene(10_082, value, 512)?, Model::Tri3, 1),
        1 => (sheet_scene(10_082, 32, value)?, Model::Tri3, 1),
        2 => (sheet_scene(1000 * value, 32, 512)?, Model::Tri3, 1),
        4 | 5 => (sheet_scene(10_082, 16, 512)?, Model::Mc3, value),
        _ => (sheet_scene(10_082, 16, 512)?, Model::Path, value),
    };
    let geom = SceneGeometry::build(&scene);
    let opts = RenderOptions {
        model,
        spp,
        visibility: Visibility::None,
        ..RenderOptions::from_scene(&scene)
    };
    let start;
    let work;
    if axis == 5 || axis == 6 {
        // The adjoint pass for a fixed dLoss/dH (a deterministic pattern).
        let n = scene.num_measurements() * scene.film.temporal_bins as usize;
        let adj: Vec<f32> = (0..n)
            .map(|i| ((i * 37 % 101) as f32 - 50.0) * 1e-2)
            .collect();
        work = scene.num_measurements() as u64 * spp as u64;
        start = Instant::now();
        std::hint::black_box(crate::adjoint::gradient(&scene, &geom, &opts, &adj, None)?);
    } else {
        let r = Renderer::new(&scene, &geom, &opts)?;
        work = r.total_work();
        start = Instant::now();
        std::hint::black_box(r.render(None)?);
    }
    Ok((
        start.elapsed().as_secs_f64(),
        peak_rss_kb().unwrap_or(0),
        work,
    ))
}

/// The least-squares slope of `ln y` against `ln x`.
pub fn exponent(points: &[(f64, f64)]) -> f64 {
    let pts: Vec<(f64, f64)> = points
        .iter()
        .filter(|p| p.0 > 0.0 && p.1 > 0.0)
        .map(|p| (p.0.ln(), p.1.ln()))
        .collect();
    let n = pts.len() as f64;
    if n < 2.0 {
        return f64::NAN;
    }
    let (mx, my) = (
        pts.iter().map(|p| p.0).sum::<f64>() / n,
        pts.iter().map(|p| p.1).sum::<f64>() / n,
    );
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    sxy / sxx
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exponent_of_a_power_law() {
        let pts: Vec<(f64, f64)> = [1.0, 2.0, 4.0, 8.0]
            .iter()
            .map(|&x| (x, 3.0 * x * x))
            .collect();
        assert!((exponent(&pts) - 2.0).abs() < 1e-12);
        assert!(exponent(&pts[..1]).is_nan());
    }

    #[test]
    fn sheet_scene_has_about_the_asked_triangles() {
        let s = sheet_scene(10_082, 8, 128).unwrap();
        let t = s.total_hidden_triangles();
        assert!((t as f64 / 10_082.0 - 1.0).abs() < 0.05, "{t}");
        assert_eq!(s.film.temporal_bins, 128);
    }
}
