//! Measured captures as a fit reads them: one entry point ([`read_measured`]) for the three
//! file kinds Umbra meets, the transient in Umbra's layout, and the capture geometry each
//! file implies ([`Measured`]), checked against a scene or turned into one.
//!
//! - `.npy`: the transient only (Umbra's or mitransient's own output); the geometry comes from
//!   the scene.
//! - `.hdf5` / `.h5`: y-tal's `NLOSCaptureData` ([`super::ytal`]): transient, scan grid, laser
//!   point or grid, film and first/last-bounce flag.
//! - `.mat`: a Stanford LCT capture ([`super::lct`]); its geometry is below.
//!
//! # The LCT capture's geometry
//!
//! Confocal, film from OPL 0 (the direct return is rectified to bin 0) in bins of
//! [`LCT_BIN_OPL`], first and last legs not counted, wall `z = 0` with normal `+z`. Where each
//! `rect_data(i, j, :)` sits on the wall is not written in the file; we take it from the
//! original reconstruction code (O'Toole et al.'s `cnlos_reconstruction.m`):
//!
//! - it permutes `rect_data` to `(t, j, i)` and labels `j` with `tic_y` and `i` with `tic_x`,
//!   both `linspace(-width, width, N)`: so the grid points run from `-width` to `+width`
//!   exactly (spacing `2 width / (N - 1)`, not the pixel-centre `2 width / N`), and the
//!   *first* MATLAB index is the code's `x`, the second its `y`;
//! - its "front view" flips `i` and shows `j` growing downwards (`imagesc`). Re-running that
//!   reconstruction (our own short NumPy version of it) on `data_s_u.mat` shows the letters
//!   "S U" readable, upright, left to right; on `data_diffuse_s.mat` a readable "S". So the
//!   front view is the hidden scene seen from the wall, right = decreasing `i`,
//!   down = increasing `j`.
//!
//! In Umbra's right-handed frame seen from the wall (looking along `+z`) with `+y` up, `+x`
//! points to the viewer's left, so `rect_data(i, j, :)` is the wall point
//! `(x, y) = (p_i, -p_j)` with `p_k = -width + 2 width k / (N - 1)`. The transient keeps the
//! reader's layout (`sy = i`, `sx = j`, `T`), hence the scan grid: centre `(0, 0, 0)`,
//! `axis_u = (0, -L, 0)` (along `sx`), `axis_v = (L, 0, 0)` (along `sy`),
//! `L = 2 width N / (N - 1)`; `axis_u x axis_v = +z`, so the grid is not mirrored. (Taking
//! `sx` along `+x` and `sy` along `+y` instead is also unmirrored but turns the scene by 90°
//! about the wall normal: the "S" would lie on its side.) The LCT README's "(y, x, t)" names
//! the dimensions the other way round; we follow the code, which the data agree with.

use super::lct::{read_lct, LCT_BIN_OPL};
use crate::error::{Error, Result};
use crate::scene::{CaptureType, ScanGrid, Scene};
use crate::transport::Transient;
use glam::Vec3;
use std::path::{Path, PathBuf};

/// Largest distance (m) between a file's wall point and the scene's that still agree.
pub const GEOMETRY_TOLERANCE: f32 = 1e-4;

/// A measured (or rendered) capture as a fit reads it: the transient in Umbra's layout and
/// the capture geometry the file implies (`None` where the file does not say).
#[derive(Clone, Debug)]
pub struct Measured {
    /// `(sy, sx, T)` single/confocal; `(sy, sx, ly, lx, T)` exhaustive.
    pub transient: Transient,
    pub capture: Option<CaptureType>,
    /// Sensor grid (= laser grid for confocal).
    pub scan: Option<ScanGrid>,
    /// Single capture: the lit wall point.
    pub laser_point: Option<Vec3>,
    /// Exhaustive only: the grid of laser points.
    pub laser_grid: Option<ScanGrid>,
    pub start_opl: Option<f32>,
    pub bin_width_opl: Option<f32>,
    pub account_first_and_last_bounces: Option<bool>,
    /// Where the laser and the detector sit (y-tal's `laser_xyz`, `sensor_xyz`): the
    /// first and last legs when `account_first_and_last_bounces`.
    pub laser_origin: Option<Vec3>,
    pub detector_origin: Option<Vec3>,
    pub source: PathBuf,
}

fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

/// Reads a capture; the format follows the extension: `.npy` (transient only), `.hdf5` /
/// `.h5` (y-tal), `.mat` (Stanford LCT).
pub fn read_measured(path: &Path) -> Result<Measured> {
    match extension(path).as_str() {
        "npy" => read_npy_measured(path),
        "hdf5" | "h5" => super::ytal::read_ytal(path),
        "mat" => read_lct_measured(path),
        other => Err(Error::scene(
            path,
            format!(
                "unknown measured-data format '.{other}' (use .npy, .hdf5 / .h5 (y-tal) or .mat (LCT))"
            ),
        )),
    }
}

fn read_npy_measured(path: &Path) -> Result<Measured> {
    let transient = super::read_npy(path)?;
    if !matches!(transient.shape.len(), 3 | 5) || transient.shape.contains(&0) {
        return Err(Error::scene(
            path,
            format!(
                "the array has shape {:?}: expected (sy, sx, T) or (sy, sx, ly, lx, T), no empty axis",
                transient.shape
            ),
        ));
    }
    Ok(Measured {
        transient,
        capture: None,
        scan: None,
        laser_point: None,
        laser_grid: None,
        start_opl: None,
        bin_width_opl: None,
        account_first_and_last_bounces: None,
        laser_origin: None,
        detector_origin: None,
        source: path.to_path_buf(),
    })
}

/// The LCT scan grid (see the module docs): `n` points per axis over `[-width, width]`.
pub fn lct_scan_grid(width: f32, nx: usize, ny: usize) -> ScanGrid {
    let side = |n: usize| {
        if n > 1 {
            2.0 * width * n as f32 / (n - 1) as f32
        } else {
            2.0 * width
        }
    };
    ScanGrid {
        nx: nx as u32,
        ny: ny as u32,
        center: Vec3::ZERO,
        axis_u: Vec3::new(0.0, -side(nx), 0.0),
        axis_v: Vec3::new(side(ny), 0.0, 0.0),
    }
}

fn read_lct_measured(path: &Path) -> Result<Measured> {
    let c = read_lct(path)?;
    let &[ny, nx, _] = c.transient.shape.as_slice() else {
        unreachable!("read_lct returns (y, x, t)")
    };
    if u32::try_from(nx.max(ny)).is_err() || nx == 0 || ny == 0 {
        return Err(Error::field(path, "rect_data", "empty or too large a scan"));
    }
    Ok(Measured {
        transient: c.transient,
        capture: Some(CaptureType::Confocal),
        scan: Some(lct_scan_grid(c.width, nx, ny)),
        laser_point: None,
        laser_grid: None,
        start_opl: Some(0.0),
        bin_width_opl: Some(LCT_BIN_OPL),
        account_first_and_last_bounces: Some(false),
        laser_origin: None,
        detector_origin: None,
        source: path.to_path_buf(),
    })
}

/// What each quantity is called in a file of this kind, for messages.
struct Names {
    data: &'static str,
    capture: &'static str,
    scan: &'static str,
    laser: &'static str,
    laser_grid: &'static str,
    start: &'static str,
    width: &'static str,
    legs: &'static str,
}

impl Measured {
    fn names(&self) -> Names {
        match extension(&self.source).as_str() {
            "hdf5" | "h5" => Names {
                data: "H",
                capture: "H_format / laser_grid_xyz",
                scan: "sensor_grid_xyz",
                laser: "laser_grid_xyz",
                laser_grid: "laser_grid_xyz",
                start: "t_start",
                width: "delta_t",
                legs: "t_accounts_first_and_last_bounces",
            },
            "mat" => Names {
                data: "rect_data",
                capture: "capture (LCT data are confocal)",
                scan: "width (the LCT scan grid)",
                laser: "laser point",
                laser_grid: "laser grid",
                start: "start (LCT data start at OPL 0)",
                width: "bin width (LCT bins are 4 ps)",
                legs: "first/last legs (not counted in LCT data)",
            },
            _ => Names {
                data: "array",
                capture: "capture",
                scan: "scan grid",
                laser: "laser point",
                laser_grid: "laser grid",
                start: "start_opl",
                width: "bin_width_opl",
                legs: "account_first_and_last_bounces",
            },
        }
    }

    fn err(&self, field: &str, msg: String) -> Error {
        Error::field(&self.source, field, msg)
    }

    /// Checks that the data fit the scene's capture: shape against the scan grid and
    /// `temporal_bins`, capture type, film start and bin width, scan grid geometry (every
    /// point within [`GEOMETRY_TOLERANCE`]), laser point. Errors name the file's field and
    /// the scene field it disagrees with.
    pub fn check_against(&self, scene: &Scene) -> Result<()> {
        let n = self.names();
        let one_point = scene.scan.len() == 1;
        if let Some(c) = self.capture {
            // A 1 x 1 confocal scan is a single capture lit at its scan point, and back.
            let same_point = |p: Option<Vec3>| {
                p.is_some_and(|p| p.distance(scene.scan.point(0)) <= GEOMETRY_TOLERANCE)
            };
            let equivalent = one_point
                && match (c, scene.capture) {
                    (CaptureType::Single, CaptureType::Confocal) => same_point(self.laser_point),
                    (CaptureType::Confocal, CaptureType::Single) => {
                        same_point(Some(scene.laser.target))
                    }
                    _ => false,
                };
            if c != scene.capture && !equivalent {
                return Err(self.err(
                    n.capture,
                    format!(
                        "the file holds a {} capture but the scene's capture_type is {}",
                        c.name(),
                        scene.capture.name()
                    ),
                ));
            }
        }
        let expected = scene.output_shape();
        if self.transient.shape != expected {
            return Err(self.err(
                n.data,
                format!(
                    "shape {:?} in Umbra's layout, but the scene ({} capture, scan.resolution {} x {}, film.temporal_bins {}) expects {:?}",
                    self.transient.shape,
                    scene.capture.name(),
                    scene.scan.nx,
                    scene.scan.ny,
                    scene.film.temporal_bins,
                    expected
                ),
            ));
        }
        if let Some(w) = self.bin_width_opl {
            let sw = scene.film.bin_width_opl;
            if (w - sw).abs() > 1e-5 * w.abs().max(sw.abs()) {
                return Err(self.err(
                    n.width,
                    format!("bin width {w} m of OPL, but the scene's film.bin_width_opl is {sw}"),
                ));
            }
        }
        if let Some(s) = self.start_opl {
            let ss = scene.film.start_opl;
            if (s - ss).abs() > 1e-3 * scene.film.bin_width_opl {
                return Err(self.err(
                    n.start,
                    format!("start {s} m of OPL, but the scene's film.start_opl is {ss}"),
                ));
            }
        }
        if let Some(a) = self.account_first_and_last_bounces {
            if a != scene.account_first_and_last_bounces {
                return Err(self.err(
                    n.legs,
                    format!(
                        "{a}, but the scene's account_first_and_last_bounces is {}",
                        scene.account_first_and_last_bounces
                    ),
                ));
            }
        }
        if scene.account_first_and_last_bounces {
            for (origin, field, what, theirs) in [
                (
                    self.laser_origin,
                    "laser_xyz",
                    "laser.origin",
                    scene.laser.origin,
                ),
                (
                    self.detector_origin,
                    "sensor_xyz",
                    "detector.origin",
                    scene.detector.origin,
                ),
            ] {
                if let Some(p) = origin {
                    let d = p.distance(theirs);
                    if d > GEOMETRY_TOLERANCE {
                        return Err(self.err(
                            field,
                            format!(
                                "{p}, {d:.3e} m from the scene's {what} {theirs}, and the scene counts the first and last legs"
                            ),
                        ));
                    }
                }
            }
        }
        if let Some(g) = &self.scan {
            self.check_grid(n.scan, g, &scene.scan, "scan")?;
        }
        if let Some(g) = &self.laser_grid {
            self.check_grid(n.laser_grid, g, &scene.scan, "scan (the laser grid)")?;
        }
        if let (Some(p), CaptureType::Single) = (self.laser_point, scene.capture) {
            let d = p.distance(scene.laser.target);
            if d > GEOMETRY_TOLERANCE {
                return Err(self.err(
                    n.laser,
                    format!(
                        "the laser lights {p}, {d:.3e} m from the scene's laser.target {}",
                        scene.laser.target
                    ),
                ));
            }
        }
        Ok(())
    }

    fn check_grid(&self, field: &str, g: &ScanGrid, s: &ScanGrid, what: &str) -> Result<()> {
        if (g.nx, g.ny) != (s.nx, s.ny) {
            return Err(self.err(
                field,
                format!(
                    "a {} x {} grid, but the scene's {what} resolution is {} x {}",
                    g.nx, g.ny, s.nx, s.ny
                ),
            ));
        }
        for i in 0..g.len() {
            let (p, q) = (g.point(i), s.point(i));
            let d = p.distance(q);
            if d.is_nan() || d > GEOMETRY_TOLERANCE {
                let (ix, iy) = (i % g.nx as usize, i / g.nx as usize);
                return Err(self.err(
                    field,
                    format!(
                        "grid point (x {ix}, y {iy}) is {p}, {d:.3e} m from the scene's {what} point {q} (centre {}, axis_u {}, axis_v {})",
                        s.center, s.axis_u, s.axis_v
                    ),
                ));
            }
        }
        Ok(())
    }

    /// A scene for this capture: a copy of `base` with the capture type, scan grid, laser
    /// target, film (start, bin width, bins; the kernel is kept), first/last-bounce flag and
    /// laser and detector origins replaced by what the file says. The result is validated and checked against the
    /// data; an exhaustive capture whose laser grid is not its sensor grid is an error
    /// (Umbra's exhaustive capture uses one grid for both).
    pub fn scene_for(&self, base: &Scene) -> Result<Scene> {
        let n = self.names();
        let mut scene = base.clone();
        if let Some(c) = self.capture {
            scene.capture = c;
        }
        if let Some(g) = &self.scan {
            scene.scan = merge_grid(g, &base.scan);
        }
        if let Some(g) = &self.laser_grid {
            let g = merge_grid(g, &scene.scan);
            self.check_grid(n.laser_grid, &g, &scene.scan, "sensor grid")
                .map_err(|e| {
                    self.err(
                        n.laser_grid,
                        format!("the laser grid is not the sensor grid, which Umbra's exhaustive capture needs: {e}"),
                    )
                })?;
        }
        if let Some(p) = self.laser_point {
            if scene.capture == CaptureType::Single {
                scene.laser.target = p;
            }
        }
        if let Some(s) = self.start_opl {
            scene.film.start_opl = s;
        }
        if let Some(w) = self.bin_width_opl {
            scene.film.bin_width_opl = w;
        }
        if let Some(a) = self.account_first_and_last_bounces {
            scene.account_first_and_last_bounces = a;
        }
        if let Some(p) = self.laser_origin {
            scene.laser.origin = p;
        }
        if let Some(p) = self.detector_origin {
            scene.detector.origin = p;
        }
        let shape = &self.transient.shape;
        let bins = *shape.last().unwrap_or(&0);
        scene.film.temporal_bins = u32::try_from(bins)
            .map_err(|_| self.err(n.data, format!("{bins} time bins is too many")))?;
        if self.scan.is_none() && shape.len() >= 3 {
            // A bare array: the scene keeps its grid if the array fits it.
            let (sy, sx) = (shape[shape.len() - 3], shape[shape.len() - 2]);
            if (sx, sy) != (base.scan.nx as usize, base.scan.ny as usize) {
                return Err(self.err(
                    n.data,
                    format!(
                        "shape {shape:?} holds a {sx} x {sy} scan, but the scene's scan.resolution is {} x {}",
                        base.scan.nx, base.scan.ny
                    ),
                ));
            }
        }
        scene.validate(&self.source)?;
        self.check_against(&scene)?;
        Ok(scene)
    }
}

/// The file's grid, with the base scene's edge vector along an axis that has one point
/// (the file cannot say how wide the area around a single point is).
fn merge_grid(g: &ScanGrid, base: &ScanGrid) -> ScanGrid {
    let mut out = g.clone();
    if g.nx == 1 && g.axis_u == Vec3::ZERO {
        out.axis_u = base.axis_u;
    }
    if g.ny == 1 && g.axis_v == Vec3::ZERO {
        out.axis_v = base.axis_v;
    }
    out
}
