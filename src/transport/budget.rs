//! The memory a render or a gradient will take, computed from the scene before anything
//! is allocated, and refused (by [`super::gate::check`]) when it exceeds what the
//! machine can give, naming the size in bytes and the field that makes it.
//!
//! What is counted (bytes; `M` measurements, `T` time bins, `n` threads):
//! - the output: `4 M T` (`f32`); a 100000 x 100000 scan, `1e9` bins or a 64 x 64
//!   exhaustive capture used to abort allocating it ("memory allocation failed");
//! - Monte Carlo working memory: each measurement in flight folds its sample blocks'
//!   `f64` histograms [`FOLD_BLOCKS`] at a time into one, so `8 T (FOLD_BLOCKS + 1)` per
//!   thread, whatever the spp (blocks run in parallel only when there are fewer
//!   measurements than threads, so a thread never holds two measurements' sets);
//! - `tri3`: one histogram of eight `f32` lanes per thread over the bins the hidden
//!   geometry can reach (at most `T`), `32` bytes a bin, `8 T` more with a Gaussian kernel;
//!   under a Gaussian of `σ ≥ 32` bins the histogram is over its `C` cells instead
//!   ([`Film::cells`], `C ≤ T + 420`), and a gradient holds their adjoint, `4 M C`;
//! - gradients: the forward render, the target and the adjoint histogram (`4 M T` each),
//!   per chunk of measurements a `f64` accumulator of 12 values per triangle, and for
//!   `tri3` its per-thread histograms (the Monte Carlo adjoint keeps none).
//!
//! The limit is the machine's available memory (`MemAvailable` of `/proc/meminfo`), or
//! `UMBRA_MAX_MEMORY` (bytes, or with a `K`, `M`, `G` or `T` suffix) when set.

use super::gate::Pass;
use super::mc3::TRI_PARAMS;
use super::RenderOptions;
use crate::error::{Error, Result};
use crate::film::Film;
use crate::scene::{CaptureType, KernelSpec, Model, Scene};

/// Sample blocks whose histograms are summed before folding into the measurement's.
pub const FOLD_BLOCKS: usize = 16;

/// Chunks of measurements the adjoint splits its work into (each keeps an accumulator).
const GRADIENT_CHUNKS: u64 = 16;

/// What a pass will allocate (bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Footprint {
    /// The transient (and, for gradients, the target and the adjoint).
    pub arrays: u64,
    /// Per-thread histograms and accumulators.
    pub working: u64,
}

impl Footprint {
    pub fn total(&self) -> u64 {
        self.arrays.saturating_add(self.working)
    }
}

/// The footprint of `pass` on `threads` threads (saturating: an absurd scene gives a huge
/// number, never an overflow).
pub fn footprint(scene: &Scene, opts: &RenderOptions, pass: Pass, threads: usize) -> Footprint {
    let points = u64::from(scene.scan.nx) * u64::from(scene.scan.ny);
    let m = match scene.capture {
        CaptureType::Exhaustive => points.saturating_mul(points),
        _ => points,
    };
    let t = u64::from(scene.film.temporal_bins);
    let n = threads.max(1) as u64;
    let output = m.saturating_mul(t).saturating_mul(4);
    // `tri3` under a Gaussian of at least 32 bins works on its cells ([`Film::cells`]).
    let cells = match opts.model {
        Model::Tri3 => Film::new(&scene.film).cells().map(|c| c.bins as u64),
        _ => None,
    };
    let per_thread = match opts.model {
        Model::Tri3 => {
            let gaussian = matches!(scene.film.kernel, KernelSpec::Gaussian { .. });
            // A wide Gaussian: the lanes' histogram spans at most the cells, and the
            // `f64` blur the film.
            let reach = match cells {
                Some(c) => c,
                None => t.min(super::tri3::WINDOW_MIN_BINS.max(reach_bins(scene))),
            };
            reach.saturating_mul(32) + if gaussian { t.saturating_mul(8) } else { 0 }
        }
        // The Monte Carlo adjoint reads the adjoint histogram and keeps no per-thread one.
        _ if pass == Pass::Gradient => 0,
        _ => t.saturating_mul(8 * (FOLD_BLOCKS as u64 + 1)),
    };
    let mut working = per_thread.saturating_mul(n);
    let mut arrays = output;
    if pass == Pass::Gradient {
        let tris = scene.total_hidden_triangles() as u64;
        arrays = output.saturating_mul(3);
        // The cells' adjoint of every measurement (`f32`), computed before the pulses'.
        if let Some(c) = cells {
            arrays = arrays.saturating_add(m.saturating_mul(c).saturating_mul(4));
        }
        working =
            working.saturating_add(GRADIENT_CHUNKS.saturating_mul(tris) * (TRI_PARAMS as u64 * 8));
    }
    Footprint { arrays, working }
}

/// Bins the hidden geometry's OPL can span (its bounding box, both legs), plus a margin.
fn reach_bins(scene: &Scene) -> u64 {
    let mut lo = glam::Vec3::splat(f32::INFINITY);
    let mut hi = -lo;
    for o in &scene.objects {
        for p in &o.mesh.positions {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let d = f64::from((hi - lo).length().max(0.0));
    let wall = f64::from(scene.wall.axis_u.length() + scene.wall.axis_v.length());
    let width = f64::from(scene.film.bin_width_opl);
    // Over all wall points the geometry's OPL spans at most twice (wall + diameter);
    // `Tri3Mesh::reach` adds the curvature shift (under 1.5 diameters), the f32 rounding
    // of the pulse times and the splat's padding.
    let reach = 2.0 * (wall + d);
    let far = f64::from(lo.abs().max(hi.abs()).length()) + wall;
    let rounding =
        8.0 * f64::from(f32::EPSILON) * (2.0 * far + f64::from(scene.film.start_opl).abs());
    let span = (reach + 1.5 * d + rounding) / width + 4.0 + crate::film::SPLAT_PAD as f64;
    if span.is_finite() && span < u64::MAX as f64 {
        span as u64
    } else {
        u64::MAX
    }
}

/// The memory Umbra may use: `UMBRA_MAX_MEMORY`, else the available memory, else no
/// limit (a platform without `/proc/meminfo`).
pub fn limit() -> Result<Option<u64>> {
    if let Ok(v) = std::env::var("UMBRA_MAX_MEMORY") {
        return parse_bytes(&v).map(Some).ok_or_else(|| {
            Error::Invalid(format!(
                "UMBRA_MAX_MEMORY: '{v}' is not a size in bytes (e.g. 8000000000 or 8G)"
            ))
        });
    }
    Ok(available())
}

fn parse_bytes(s: &str) -> Option<u64> {
    let s = s.trim();
    let (num, unit) = match s.char_indices().find(|(_, c)| c.is_ascii_alphabetic()) {
        Some((i, _)) => (&s[..i], s[i..].trim_end_matches(['B', 'b', 'i'])),
        None => (s, ""),
    };
    let shift = match unit.to_ascii_uppercase().as_str() {
        "" => 0,
        "K" => 10,
        "M" => 20,
        "G" => 30,
        "T" => 40,
        _ => return None,
    };
    let v: f64 = num.trim().parse().ok()?;
    (v.is_finite() && v >= 0.0).then(|| (v * (1u64 << shift) as f64) as u64)
}

/// `MemAvailable` of `/proc/meminfo` (bytes).
fn available() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Refuses `pass` if its footprint exceeds [`limit`], naming the sizes and the fields.
pub fn check(scene: &Scene, opts: &RenderOptions, pass: Pass) -> Result<()> {
    let Some(limit) = limit()? else {
        return Ok(());
    };
    let threads = rayon::current_num_threads();
    let f = footprint(scene, opts, pass, threads);
    if f.total() <= limit {
        return Ok(());
    }
    let (sy, sx, bins) = (scene.scan.ny, scene.scan.nx, scene.film.temporal_bins);
    let measurements = match scene.capture {
        CaptureType::Exhaustive => {
            format!("{sy} x {sx} scan points squared (exhaustive capture)")
        }
        _ => format!("{sy} x {sx} scan points (scan.resolution)"),
    };
    let arrays_are = match pass {
        Pass::Render => "the output",
        Pass::Gradient => "the render, target and adjoint (3 arrays)",
    };
    let advice = if f.working > f.arrays {
        match pass {
            Pass::Gradient => "reduce --threads, film.temporal_bins or the hidden triangles",
            Pass::Render => "reduce --threads or film.temporal_bins",
        }
    } else {
        "reduce scan.resolution or film.temporal_bins"
    };
    Err(Error::Invalid(format!(
        "{} would need {} of memory, more than the {} {}: {} for {arrays_are} ({measurements} x {bins} time bins (film.temporal_bins) x 4 bytes{}) and {} of working memory on {threads} threads; {advice}{}",
        match pass {
            Pass::Render => "the render",
            Pass::Gradient => "the gradient",
        },
        bytes(f.total()),
        bytes(limit),
        if std::env::var_os("UMBRA_MAX_MEMORY").is_some() {
            "UMBRA_MAX_MEMORY allows"
        } else {
            "available on this machine"
        },
        bytes(f.arrays),
        if pass == Pass::Gradient { " each" } else { "" },
        bytes(f.working),
        if scene.capture == CaptureType::Exhaustive {
            " (an exhaustive capture measures every pair of scan points)"
        } else {
            ""
        }
    )))
}

/// `n` bytes for people: "34359738368 bytes (32.0 GiB)"; a saturated count (the size
/// does not fit in 64 bits) is "more than 16 EiB".
fn bytes(n: u64) -> String {
    if n == u64::MAX {
        return "more than 18446744073709551615 bytes (16 EiB)".into();
    }
    let units = ["KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    let mut v = n as f64;
    let mut unit = "bytes";
    for u in units {
        if v < 1024.0 {
            break;
        }
        v /= 1024.0;
        unit = u;
    }
    if unit == "bytes" {
        format!("{n} bytes")
    } else {
        format!("{n} bytes ({v:.1} {unit})")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_print() {
        assert_eq!(parse_bytes("8G"), Some(8 << 30));
        assert_eq!(parse_bytes("1.5 MiB"), Some(3 << 19));
        assert_eq!(parse_bytes("123"), Some(123));
        assert_eq!(parse_bytes("lots"), None);
        assert_eq!(bytes(34359738368), "34359738368 bytes (32.0 GiB)");
        assert_eq!(bytes(12), "12 bytes");
        assert!(bytes(u64::MAX).starts_with("more than"));
    }
}
