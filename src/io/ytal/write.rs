//! Writing y-tal's HDF5 captures (`umbra render -o X.hdf5`): the layout and fields of
//! the module above, so y-tal's reconstructions run on Umbra's renders.

use super::{permute, GRID_FORMAT, H_FORMAT, TO_YTAL_3, TO_YTAL_5, T_LX_LY_SX_SY, T_SX_SY, X_Y_3};
use crate::error::{Error, Result};
use crate::scene::{CaptureType, ScanGrid, Scene};
use crate::transport::Transient;
use glam::Vec3;
use rust_hdf5::format::messages::datatype::EnumMember;
use rust_hdf5::{DatatypeMessage, H5File};
use std::path::Path;

/// Grid points as y-tal stores them: `(nx, ny, 3)` indexed `[x, y]`, in C order.
fn grid_points(g: &ScanGrid) -> Vec<f32> {
    let (nx, ny) = (g.nx as usize, g.ny as usize);
    let mut v = Vec::with_capacity(nx * ny * 3);
    for ix in 0..nx {
        for iy in 0..ny {
            v.extend_from_slice(&g.point(iy * nx + ix).to_array());
        }
    }
    v
}

fn normals(n: Vec3, count: usize) -> Vec<f32> {
    (0..count).flat_map(|_| n.to_array()).collect()
}

/// An HDF5 enum over `base` whose member `names[i]` has the value `i` (`width` bytes,
/// little-endian), as `h5py.enum_dtype` writes y-tal's enums and h5py's bool.
fn enum_type(base: DatatypeMessage, width: usize, names: &[&str]) -> DatatypeMessage {
    let members = names
        .iter()
        .enumerate()
        .map(|(i, n)| EnumMember {
            name: (*n).to_string(),
            value: (i as u64).to_le_bytes()[..width].to_vec(),
        })
        .collect();
    DatatypeMessage::enumeration(base, members)
}

/// A short YAML `scene_info` (y-tal parses it with `yaml.load`).
fn scene_info(scene: &Scene) -> String {
    let v = |p: Vec3| format!("[{}, {}, {}]", p.x, p.y, p.z);
    let w = &scene.wall;
    format!(
        "generator: umbra {}\ncapture_type: {}\nrelay_wall:\n  center: {}\n  axis_u: {}\n  axis_v: {}\n  albedo: {}\n",
        env!("CARGO_PKG_VERSION"),
        scene.capture.name(),
        v(w.center),
        v(w.axis_u),
        v(w.axis_v),
        w.albedo
    )
}

/// Writes `t` (rendered for `scene`) as a y-tal capture that `tal.io.read_capture` reads.
pub fn write_ytal(path: &Path, t: &Transient, scene: &Scene) -> Result<()> {
    let expected = scene.output_shape();
    if t.shape != expected || t.data.len() != expected.iter().product::<usize>() {
        return Err(Error::Invalid(format!(
            "{}: the transient has shape {:?} ({} values), but the scene's capture has shape {expected:?}",
            path.display(),
            t.shape,
            t.data.len()
        )));
    }
    crate::io::write_via_temp(path, |tmp| {
        write_file(tmp, t, scene)
            .map_err(|e| Error::Invalid(format!("{}: writing HDF5: {e}", path.display())))
    })
}

/// The f64 nearest the shortest decimal that reads back as `v` (0.01f32 -> 0.01, not
/// 0.0099999998): what the user wrote in the scene.
fn decimal(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(v as f64)
}

/// A failed HDF5 call, named after the dataset it was writing.
fn at(name: &str) -> impl Fn(rust_hdf5::Hdf5Error) -> String + '_ {
    move |e| format!("{name}: {e}")
}

fn write_file(tmp: &Path, t: &Transient, scene: &Scene) -> std::result::Result<(), String> {
    let exhaustive = scene.capture == CaptureType::Exhaustive;
    let (h, h_shape) = if exhaustive {
        permute(&t.data, &t.shape, &TO_YTAL_5)
    } else {
        permute(&t.data, &t.shape, &TO_YTAL_3)
    };
    let (nx, ny) = (scene.scan.nx as usize, scene.scan.ny as usize);
    let n_w = scene.wall.normal();
    let sensor = grid_points(&scene.scan);
    let (laser, laser_shape) = match scene.capture {
        CaptureType::Single => (scene.laser.target.to_array().to_vec(), [1, 1, 3]),
        CaptureType::Confocal | CaptureType::Exhaustive => (sensor.clone(), [nx, ny, 3]),
    };
    let h_format = if exhaustive { T_LX_LY_SX_SY } else { T_SX_SY };

    let file = H5File::create(tmp).map_err(|e| e.to_string())?;
    let data = |name: &str, shape: &[usize], v: &[f32]| {
        file.new_dataset::<f32>()
            .shape(shape)
            .create(name)
            .and_then(|ds| ds.write_raw(v))
            .map_err(at(name))
    };
    let code = |name: &str, names: &[&str], value: usize| {
        file.new_dataset::<i32>()
            .datatype(enum_type(DatatypeMessage::i32_type(), 4, names))
            .shape([1])
            .create(name)
            .and_then(|ds| ds.write_raw(&[value as i32]))
            .map_err(at(name))
    };
    let scalar = |name: &str, v: f64| {
        file.new_dataset::<f64>()
            .scalar()
            .create(name)
            .and_then(|ds| ds.write_raw(&[v]))
            .map_err(at(name))
    };
    data("H", &h_shape, &h)?;
    code("H_format", &H_FORMAT, h_format)?;
    data("sensor_xyz", &[3], &scene.detector.origin.to_array())?;
    data("sensor_grid_xyz", &[nx, ny, 3], &sensor)?;
    data("sensor_grid_normals", &[nx, ny, 3], &normals(n_w, nx * ny))?;
    code("sensor_grid_format", &GRID_FORMAT, X_Y_3)?;
    data("laser_xyz", &[3], &scene.laser.origin.to_array())?;
    data("laser_grid_xyz", &laser_shape, &laser)?;
    let laser_normals = normals(n_w, laser_shape[0] * laser_shape[1]);
    data("laser_grid_normals", &laser_shape, &laser_normals)?;
    code("laser_grid_format", &GRID_FORMAT, X_Y_3)?;
    // `tal render` writes None as h5py.Empty(float): the NULL dataspace.
    file.new_dataset::<f64>()
        .null()
        .create("volume_format")
        .map_err(at("volume_format"))?;
    scalar("delta_t", decimal(scene.film.bin_width_opl))?;
    scalar("t_start", decimal(scene.film.start_opl))?;
    // h5py's bool: an int8 enum FALSE = 0, TRUE = 1.
    let flag = "t_accounts_first_and_last_bounces";
    file.new_dataset::<i8>()
        .datatype(enum_type(DatatypeMessage::i8_type(), 1, &["FALSE", "TRUE"]))
        .scalar()
        .create(flag)
        .and_then(|ds| ds.write_raw(&[i8::from(scene.account_first_and_last_bounces)]))
        .map_err(at(flag))?;
    // rust-hdf5 writes a variable-length string dataset with one dimension: (1,) where h5py
    // writes a scalar; y-tal squeezes it to the same string.
    file.write_vlen_strings("scene_info", &[&scene_info(scene)])
        .map_err(at("scene_info"))?;
    file.close().map_err(|e| e.to_string())
}
