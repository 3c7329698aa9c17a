//! y-tal's capture files (`tal.io.NLOSCaptureData`, HDF5), read and written.
//!
//! A file holds one dataset per field at its root:
//!
//! | dataset | y-tal's meaning | Umbra |
//! | --- | --- | --- |
//! | `H` | float32 transient, `(T, Sx, Sy)` or `(T, Lx, Ly, Sx, Sy)` | `(sy, sx, T)` / `(sy, sx, ly, lx, T)`, converted here |
//! | `H_format` | enum `HFormat` (int32, stored as a `(1,)` array): `T_Sx_Sy` = 1, `T_Lx_Ly_Sx_Sy` = 2 | we read those two |
//! | `sensor_grid_xyz` | `(Sx, Sy, 3)` wall points, indexed `[x, y]` | a regular [`ScanGrid`], inferred |
//! | `laser_grid_xyz` | `(1, 1, 3)` for one laser point, the sensor grid for confocal, `(Lx, Ly, 3)` exhaustive | capture type, laser point |
//! | `{sensor,laser}_grid_normals`, `{sensor,laser}_grid_format` (`GridFormat`: `X_Y_3` = 2) | normals, layout | written; `N_3` grids are refused |
//! | `sensor_xyz`, `laser_xyz` | detector and laser positions | the detector and laser origins (read and written) |
//! | `delta_t`, `t_start` | bin width and start, m of OPL (float64 scalars) | `bin_width_opl`, `start_opl` |
//! | `t_accounts_first_and_last_bounces` | HDF5 bool (enum int8 FALSE/TRUE) | the same flag |
//! | `volume_format` | deprecated; `tal render` writes an empty (null) float64 | written the same way |
//! | `scene_info` | YAML text (vlen UTF-8 string) | written: who made the file and the capture; as a `(1,)` array, see below |
//!
//! y-tal marks a confocal capture by `H_format = T_Sx_Sy` with `laser_grid_xyz` equal to
//! `sensor_grid_xyz` (its `is_confocal()` is `np.allclose` of the two), a single capture by a
//! one-point laser grid. Its reader refuses any root dataset it does not know, so we write
//! exactly its fields ([`write`]). Files are written to a temporary name and renamed into place.
//! Enum fields are read by member name, as libhdf5 converts enums; a plain integer is taken
//! as the code. A file shorter than its superblock says is refused as truncated.
//!
//! ## Which crate and why
//!
//! HDF5 goes through [`rust_hdf5`] (pure Rust, default features off: no dependencies, no
//! system library), so a fresh machine builds the CLI and the Python wheel without Debian's
//! `libhdf5-dev`, which `hdf5-metno` linked. Of the pure-Rust crates it is the one that
//! reads and writes every kind of field above with y-tal's types: float32 arrays, float64
//! scalars, int32 enums with y-tal's member names (built by hand as a `DatatypeMessage`),
//! h5py's int8 bool enum, the NULL dataspace of `volume_format`, vlen strings. One
//! difference from h5py: its vlen string datasets are one-dimensional, so `scene_info` is a
//! `(1,)` array where `tal render` writes a scalar; y-tal squeezes it to the same string.
//! `hdf5-pure` 0.47 cannot write a NULL dataspace (y-tal's reader then fails on
//! `volume_format`). The evaluation is in `notes/hdf5-crates.md`.

use super::measured::Measured;
use crate::error::{Error, Result};
use crate::scene::{CaptureType, ScanGrid};
use crate::transport::Transient;
use fields::{field_err, read_bool, read_code, read_point, read_points, read_scalar};
use glam::DVec3;
use rust_hdf5::H5File;
use std::path::Path;

mod fields;
mod write;
pub use write::{chunk_rows, write_ytal, write_ytal_blocks, BlockSink};

/// y-tal's `HFormat` (`tal.enums`): member names, indexed by value. HDF5 converts enums by
/// member name, so every member is here even if we never write it.
const H_FORMAT: [&str; 5] = ["UNKNOWN", "T_Sx_Sy", "T_Lx_Ly_Sx_Sy", "T_Si", "T_Li_Si"];
const T_SX_SY: usize = 1;
const T_LX_LY_SX_SY: usize = 2;

/// y-tal's `GridFormat`.
const GRID_FORMAT: [&str; 3] = ["UNKNOWN", "N_3", "X_Y_3"];
const X_Y_3: usize = 2;

/// The regular grid through `pts` (indexed `[ix * ny + iy]`, pixel-centre convention), or an
/// error naming the dataset if the points are not evenly spaced on a parallelogram. An axis
/// with one point gets a zero edge vector: the file does not say how wide it is.
fn regular_grid(path: &Path, name: &str, nx: usize, ny: usize, pts: &[DVec3]) -> Result<ScanGrid> {
    let too_big = u32::try_from(nx).is_err() || u32::try_from(ny).is_err();
    if nx == 0 || ny == 0 || too_big || pts.len() != nx * ny {
        return Err(field_err(
            path,
            name,
            format!(
                "a {nx} x {ny} grid of {} points is not a usable scan",
                pts.len()
            ),
        ));
    }
    let at = |ix: usize, iy: usize| pts[ix * ny + iy];
    let edge = |n: usize, last: DVec3| {
        if n > 1 {
            (last - at(0, 0)) * n as f64 / (n - 1) as f64
        } else {
            DVec3::ZERO
        }
    };
    let axis_u = edge(nx, at(nx - 1, 0));
    let axis_v = edge(ny, at(0, ny - 1));
    let center = pts.iter().copied().sum::<DVec3>() / pts.len() as f64;
    let size = axis_u.length().max(axis_v.length()).max(1.0);
    let tol = 1e-5 * size;
    if (nx > 1 && axis_u.length() <= tol) || (ny > 1 && axis_v.length() <= tol) {
        return Err(field_err(
            path,
            name,
            "not a regular grid: its points repeat",
        ));
    }
    if nx > 1 && ny > 1 && axis_u.normalize().cross(axis_v.normalize()).length() < 1e-6 {
        return Err(field_err(
            path,
            name,
            "not a regular grid: its x and y directions are parallel",
        ));
    }
    for ix in 0..nx {
        for iy in 0..ny {
            let s = (ix as f64 + 0.5) / nx as f64 - 0.5;
            let t = (iy as f64 + 0.5) / ny as f64 - 0.5;
            let d = at(ix, iy).distance(center + s * axis_u + t * axis_v);
            if d > tol {
                return Err(field_err(
                    path,
                    name,
                    format!(
                        "not a regular grid: point [{ix}, {iy}] = {} is {d:.3e} m off the evenly spaced grid through the corners (Umbra scans a regular rectangular grid)",
                        at(ix, iy)
                    ),
                ));
            }
        }
    }
    Ok(ScanGrid {
        nx: nx as u32,
        ny: ny as u32,
        center: center.as_vec3(),
        axis_u: axis_u.as_vec3(),
        axis_v: axis_v.as_vec3(),
    })
}

/// `data` (C order, `shape`) with its axes reordered: output axis `k` is input axis `perm[k]`.
fn permute(data: &[f32], shape: &[usize], perm: &[usize]) -> (Vec<f32>, Vec<usize>) {
    let n = shape.len();
    let out_shape: Vec<usize> = perm.iter().map(|&a| shape[a]).collect();
    let mut stride_of_input_axis = vec![0usize; n];
    let mut s = 1;
    for k in (0..n).rev() {
        stride_of_input_axis[perm[k]] = s;
        s *= out_shape[k];
    }
    let mut out = vec![0.0f32; data.len()];
    let mut idx = vec![0usize; n];
    let mut off = 0usize;
    for &v in data {
        out[off] = v;
        for a in (0..n).rev() {
            idx[a] += 1;
            off += stride_of_input_axis[a];
            if idx[a] < shape[a] {
                break;
            }
            off -= stride_of_input_axis[a] * shape[a];
            idx[a] = 0;
        }
    }
    (out, out_shape)
}

/// y-tal `(T, Sx, Sy)` -> Umbra `(sy, sx, T)`; `(T, Lx, Ly, Sx, Sy)` -> `(sy, sx, ly, lx, T)`.
const FROM_YTAL_3: [usize; 3] = [2, 1, 0];
const FROM_YTAL_5: [usize; 5] = [4, 3, 2, 1, 0];

/// Reads a y-tal capture (see the module docs); errors name the file and the dataset.
pub fn read_ytal(path: &Path) -> Result<Measured> {
    if !path.is_file() {
        return Err(Error::scene(path, "no such file"));
    }
    fields::check_not_truncated(path)?;
    let file =
        H5File::open(path).map_err(|e| Error::scene(path, format!("not an HDF5 file: {e}")))?;
    let h = fields::dataset(path, &file, "H")?.ok_or_else(|| {
        field_err(
            path,
            "H",
            "missing: a y-tal capture (NLOSCaptureData) stores its transient in H",
        )
    })?;
    let format = read_code(path, &file, "H_format", "HFormat", &H_FORMAT)?.ok_or_else(|| {
        field_err(
            path,
            "H_format",
            "missing (y-tal writes T_Sx_Sy = 1 or T_Lx_Ly_Sx_Sy = 2)",
        )
    })?;
    let exhaustive = match usize::try_from(format) {
        Ok(T_SX_SY) => false,
        Ok(T_LX_LY_SX_SY) => true,
        _ => {
            let v = format;
            let name = usize::try_from(v)
                .ok()
                .and_then(|i| H_FORMAT.get(i))
                .map_or(format!("{v} is not a y-tal HFormat"), |n| {
                    format!("{n} ({v})")
                });
            return Err(field_err(
                path,
                "H_format",
                format!("{name}: not supported, Umbra reads T_Sx_Sy (1) and T_Lx_Ly_Sx_Sy (2)"),
            ));
        }
    };
    for grid in ["sensor_grid_format", "laser_grid_format"] {
        let code = read_code(path, &file, grid, "GridFormat", &GRID_FORMAT)?;
        if let Some(c) = code.filter(|&c| c != X_Y_3 as i64) {
            let name = usize::try_from(c).ok().and_then(|i| GRID_FORMAT.get(i));
            return Err(field_err(
                path,
                grid,
                format!(
                    "{} ({c}) is not supported: Umbra reads X_Y_3 (2) grids",
                    name.unwrap_or(&"not a y-tal GridFormat")
                ),
            ));
        }
    }
    let shape = h.shape();
    let (rank, layout) = if exhaustive {
        (5, "(T, Lx, Ly, Sx, Sy)")
    } else {
        (3, "(T, Sx, Sy)")
    };
    if shape.len() != rank || shape.contains(&0) {
        return Err(field_err(
            path,
            "H",
            format!(
                "has shape {shape:?}, but H_format {} means {layout}",
                H_FORMAT[format as usize]
            ),
        ));
    }
    let (sx, sy) = (shape[rank - 2], shape[rank - 1]);
    let (sensor_shape, sensor_pts) = read_points(path, &file, "sensor_grid_xyz")?;
    if sensor_shape != [sx, sy] {
        return Err(field_err(
            path,
            "sensor_grid_xyz",
            format!("has {sensor_shape:?} points, but H {shape:?} holds a {sx} x {sy} sensor grid"),
        ));
    }
    let scan = regular_grid(path, "sensor_grid_xyz", sx, sy, &sensor_pts)?;
    let (laser_shape, laser_pts) = read_points(path, &file, "laser_grid_xyz")?;
    let tol = 1e-5 * (scan.axis_u.length().max(scan.axis_v.length()).max(1.0) as f64);
    let (capture, laser_point, laser_grid) = if exhaustive {
        let (lx, ly) = (shape[1], shape[2]);
        if laser_shape != [lx, ly] {
            return Err(field_err(
                path,
                "laser_grid_xyz",
                format!(
                    "has {laser_shape:?} points, but H {shape:?} holds a {lx} x {ly} laser grid"
                ),
            ));
        }
        let g = regular_grid(path, "laser_grid_xyz", lx, ly, &laser_pts)?;
        (CaptureType::Exhaustive, None, Some(g))
    } else if laser_pts.len() == 1 {
        (CaptureType::Single, Some(laser_pts[0].as_vec3()), None)
    } else if laser_shape == sensor_shape
        && laser_pts
            .iter()
            .zip(&sensor_pts)
            .all(|(a, b)| a.distance(*b) <= tol)
    {
        (CaptureType::Confocal, None, None)
    } else {
        return Err(field_err(
            path,
            "laser_grid_xyz",
            format!("has {laser_shape:?} points: neither one point (single capture) nor the sensor grid (confocal)"),
        ));
    };
    let data = fields::read_f32s(path, &h, "H")?;
    if data.len() != shape.iter().product::<usize>() {
        return Err(field_err(
            path,
            "H",
            format!("holds {} values for shape {shape:?}", data.len()),
        ));
    }
    if let Some(i) = data.iter().position(|v| !v.is_finite()) {
        return Err(field_err(
            path,
            "H",
            format!("holds a non-finite value at flat index {i}"),
        ));
    }
    let (data, shape) = if exhaustive {
        permute(&data, &shape, &FROM_YTAL_5)
    } else {
        permute(&data, &shape, &FROM_YTAL_3)
    };
    let delta_t = read_scalar(path, &file, "delta_t")?;
    if delta_t.is_some_and(|w| w <= 0.0) {
        return Err(field_err(
            path,
            "delta_t",
            format!("must be > 0, got {}", delta_t.unwrap_or(0.0)),
        ));
    }
    Ok(Measured {
        transient: Transient { data, shape },
        capture: Some(capture),
        scan: Some(scan),
        laser_point,
        laser_grid,
        start_opl: read_scalar(path, &file, "t_start")?.map(|v| v as f32),
        bin_width_opl: delta_t.map(|v| v as f32),
        account_first_and_last_bounces: read_bool(
            path,
            &file,
            "t_accounts_first_and_last_bounces",
        )?,
        laser_origin: read_point(path, &file, "laser_xyz")?,
        detector_origin: read_point(path, &file, "sensor_xyz")?,
        source: path.to_path_buf(),
    })
}
