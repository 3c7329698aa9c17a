//! Writing y-tal's HDF5 captures (`umbra render -o X.hdf5`): the layout and fields of
//! the module above, so y-tal's reconstructions run on Umbra's renders.

use super::{permute, GridFormat, HFormat, TO_YTAL_3, TO_YTAL_5};
use crate::error::{Error, Result};
use crate::scene::{CaptureType, ScanGrid, Scene};
use crate::transport::Transient;
use glam::Vec3;
use hdf5::types::VarLenUnicode;
use hdf5::Extents;
use ndarray::{ArrayD, IxDyn};
use std::path::Path;

/// Grid points as y-tal stores them: `(nx, ny, 3)` indexed `[x, y]`.
fn grid_array(g: &ScanGrid) -> ArrayD<f32> {
    let (nx, ny) = (g.nx as usize, g.ny as usize);
    let mut v = Vec::with_capacity(nx * ny * 3);
    for ix in 0..nx {
        for iy in 0..ny {
            v.extend_from_slice(&g.point(iy * nx + ix).to_array());
        }
    }
    ArrayD::from_shape_vec(IxDyn(&[nx, ny, 3]), v).expect("grid shape")
}

fn normals(n: Vec3, nx: usize, ny: usize) -> ArrayD<f32> {
    let v = (0..nx * ny).flat_map(|_| n.to_array()).collect();
    ArrayD::from_shape_vec(IxDyn(&[nx, ny, 3]), v).expect("normals shape")
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
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
    let result = write_file(&tmp, t, scene)
        .map_err(|e| Error::Invalid(format!("{}: writing HDF5: {e}", path.display())))
        .and_then(|()| std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e)));
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

/// The f64 nearest the shortest decimal that reads back as `v` (0.01f32 -> 0.01, not
/// 0.0099999998): what the user wrote in the scene.
fn decimal(v: f32) -> f64 {
    v.to_string().parse().unwrap_or(v as f64)
}

fn write_file(tmp: &Path, t: &Transient, scene: &Scene) -> hdf5::Result<()> {
    let exhaustive = scene.capture == CaptureType::Exhaustive;
    let (h, h_shape) = if exhaustive {
        permute(&t.data, &t.shape, &TO_YTAL_5)
    } else {
        permute(&t.data, &t.shape, &TO_YTAL_3)
    };
    let h = ArrayD::from_shape_vec(IxDyn(&h_shape), h).expect("H shape");
    let (nx, ny) = (scene.scan.nx as usize, scene.scan.ny as usize);
    let n_w = scene.wall.normal();
    let sensor = grid_array(&scene.scan);
    let (laser, laser_normals) = match scene.capture {
        CaptureType::Single => (
            ArrayD::from_shape_vec(IxDyn(&[1, 1, 3]), scene.laser.target.to_array().to_vec())
                .expect("laser shape"),
            normals(n_w, 1, 1),
        ),
        CaptureType::Confocal | CaptureType::Exhaustive => (sensor.clone(), normals(n_w, nx, ny)),
    };
    let h_format = if exhaustive {
        HFormat::T_Lx_Ly_Sx_Sy
    } else {
        HFormat::T_Sx_Sy
    };

    let file = hdf5::File::create(tmp)?;
    {
        let data = |name: &str, a: &ArrayD<f32>| -> hdf5::Result<()> {
            file.new_dataset_builder()
                .with_data(a.view())
                .create(name)
                .map(|_| ())
        };
        data("H", &h)?;
        file.new_dataset_builder()
            .with_data(&[h_format][..])
            .create("H_format")?;
        data(
            "sensor_xyz",
            &ArrayD::from_shape_vec(IxDyn(&[3]), scene.detector.origin.to_array().to_vec())
                .expect("3"),
        )?;
        data("sensor_grid_xyz", &sensor)?;
        data("sensor_grid_normals", &normals(n_w, nx, ny))?;
        file.new_dataset_builder()
            .with_data(&[GridFormat::X_Y_3][..])
            .create("sensor_grid_format")?;
        data(
            "laser_xyz",
            &ArrayD::from_shape_vec(IxDyn(&[3]), scene.laser.origin.to_array().to_vec())
                .expect("3"),
        )?;
        data("laser_grid_xyz", &laser)?;
        data("laser_grid_normals", &laser_normals)?;
        file.new_dataset_builder()
            .with_data(&[GridFormat::X_Y_3][..])
            .create("laser_grid_format")?;
        file.new_dataset::<f64>()
            .shape(Extents::Null)
            .create("volume_format")?;
        file.new_dataset::<f64>()
            .create("delta_t")?
            .write_scalar(&decimal(scene.film.bin_width_opl))?;
        file.new_dataset::<f64>()
            .create("t_start")?
            .write_scalar(&decimal(scene.film.start_opl))?;
        file.new_dataset::<bool>()
            .create("t_accounts_first_and_last_bounces")?
            .write_scalar(&scene.account_first_and_last_bounces)?;
        let info: VarLenUnicode = scene_info(scene)
            .parse()
            .map_err(|e| hdf5::Error::from(format!("scene_info: {e}")))?;
        file.new_dataset::<VarLenUnicode>()
            .create("scene_info")?
            .write_scalar(&info)?;
    }
    file.close()
}
