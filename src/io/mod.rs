//! Files: transients to `.npy` (mitransient's layout) or OpenEXR, and PNG previews.

pub mod exr_out;
pub mod lct;
pub mod measured;
mod npy_header;
pub mod plot;
pub mod preview;
pub mod ytal;

use crate::error::{Error, Result};
use crate::transport::Transient;
use ndarray::{ArrayD, IxDyn};
use std::path::Path;

/// Writes a render of `scene`; the format follows the extension: `.hdf5` / `.h5` (y-tal's
/// capture format, which needs the scene's geometry), else as [`write_transient`].
pub fn write_capture(path: &Path, t: &Transient, scene: &crate::scene::Scene) -> Result<()> {
    if is_hdf5(path) {
        ytal::write_ytal(path, t, scene)
    } else {
        write_transient(path, t)
    }
}

fn is_hdf5(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("hdf5") || e.eq_ignore_ascii_case("h5"))
}

/// Writes a transient; the format follows the extension (`.npy` default, `.exr`; `.hdf5`
/// needs the scene: [`write_capture`]).
pub fn write_transient(path: &Path, t: &Transient) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("exr") => exr_out::write(path, t),
        Some("npy") | None => write_npy(path, t),
        Some("hdf5" | "h5") => Err(Error::Invalid(format!(
            "{}: a y-tal .hdf5 capture needs the scene's geometry (io::write_capture)",
            path.display()
        ))),
        Some(other) => Err(Error::Invalid(format!(
            "{}: unknown output format '.{other}' (use .npy, .exr or .hdf5)",
            path.display()
        ))),
    }
}

/// `.npy`, float32, shape `(sy, sx, T)` or `(sy, sx, ly, lx, T)`, C order. Written to a
/// temporary file in the same folder and renamed over `path`: an interrupted write never
/// leaves a partial file, nor loses the previous one.
pub fn write_npy(path: &Path, t: &Transient) -> Result<()> {
    let arr = ndarray::ArrayViewD::from_shape(IxDyn(&t.shape), &t.data)
        .map_err(|e| Error::Invalid(format!("transient shape: {e}")))?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.{}.tmp", std::process::id()));
    let written = std::fs::File::create(&tmp)
        .map_err(|e| Error::io(&tmp, e))
        .and_then(|file| {
            let mut w = std::io::BufWriter::new(file);
            ndarray_npy::WriteNpyExt::write_npy(&arr, &mut w)
                .map_err(|e| Error::Invalid(format!("{}: writing npy: {e}", path.display())))?;
            let file = w
                .into_inner()
                .map_err(|e| Error::io(&tmp, e.into_error()))?;
            file.sync_all().map_err(|e| Error::io(&tmp, e))
        })
        .and_then(|()| std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e)));
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

/// Checks, before any work, that `path` can take a transient: a known extension, and a
/// folder that exists or can be made (not a file), the path itself not a folder.
pub fn check_output(path: &Path) -> Result<()> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("npy" | "exr" | "hdf5" | "h5") | None => {}
        Some(other) => {
            return Err(Error::Invalid(format!(
                "{}: unknown output format '.{other}' (use .npy, .exr or .hdf5)",
                path.display()
            )))
        }
    }
    if path.is_dir() {
        return Err(Error::Invalid(format!(
            "{}: is a folder; give a file name (e.g. {}/transient.npy)",
            path.display(),
            path.display()
        )));
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    Ok(())
}

/// Reads a `.npy` of float32 or float64 values.
pub fn read_npy(path: &Path) -> Result<Transient> {
    // The header must announce exactly the file's data before anything is allocated.
    npy_header::check(path)?;
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let reader = std::io::BufReader::new(file);
    let arr: ArrayD<f32> = match ndarray_npy::ReadNpyExt::read_npy(reader) {
        Ok(a) => a,
        Err(_) => {
            let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
            let a: ArrayD<f64> =
                ndarray_npy::ReadNpyExt::read_npy(std::io::BufReader::new(file))
                    .map_err(|e| Error::scene(path, format!("not a float32/float64 .npy: {e}")))?;
            a.mapv(|v| v as f32)
        }
    };
    let shape = arr.shape().to_vec();
    let data = arr.as_standard_layout().iter().copied().collect();
    Ok(Transient { data, shape })
}

/// Writes a gradient as `.npz`: `loss` (a scalar), `vertices` (V x 3, f64) or
/// `vertices_<k>` per object if there are several, `albedo` (one per object), and
/// `vertex_albedo` / `vertex_albedo_<k>` for objects with per-vertex albedo.
pub fn write_gradient(path: &Path, loss: f64, g: &crate::adjoint::Gradient) -> Result<()> {
    use ndarray::{arr0, Array1, Array2};
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    let npz_err =
        |e: ndarray_npy::WriteNpzError| Error::Invalid(format!("{}: {e}", path.display()));
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut npz = ndarray_npy::NpzWriter::new(file);
    npz.add_array("loss", &arr0(loss)).map_err(npz_err)?;
    let several = g.vertices.len() > 1;
    let name = |base: &str, k: usize| {
        if several {
            format!("{base}_{k}")
        } else {
            base.to_string()
        }
    };
    for (k, v) in g.vertices.iter().enumerate() {
        let a = Array2::from_shape_vec((v.len(), 3), v.iter().flatten().copied().collect())
            .map_err(|e| Error::Invalid(e.to_string()))?;
        npz.add_array(name("vertices", k).as_str(), &a)
            .map_err(npz_err)?;
    }
    npz.add_array("albedo", &Array1::from(g.albedo.clone()))
        .map_err(npz_err)?;
    for (k, va) in g.vertex_albedo.iter().enumerate() {
        if let Some(va) = va {
            npz.add_array(name("vertex_albedo", k).as_str(), &Array1::from(va.clone()))
                .map_err(npz_err)?;
        }
    }
    npz.finish().map_err(npz_err)?;
    Ok(())
}
