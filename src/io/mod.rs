//! Files: transients to `.npy` (mitransient's layout) or OpenEXR, and PNG previews.

pub mod exr_out;
pub mod lct;
pub mod maps;
pub mod mat_layout;
pub mod measured;
mod npy_header;
pub mod plot;
pub mod preview;
pub mod text;
pub mod ytal;

use crate::error::{Error, Result};
use crate::transport::Transient;
use ndarray::{ArrayD, IxDyn};
use std::path::Path;
pub use text::read_text;

/// Writes a render of `scene`; the format follows the extension: `.hdf5` / `.h5` (y-tal's
/// capture format, which needs the scene's geometry), else as [`write_transient`].
pub fn write_capture(path: &Path, t: &Transient, scene: &crate::scene::Scene) -> Result<()> {
    match OutputFormat::of(path)? {
        OutputFormat::Hdf5 => ytal::write_ytal(path, t, scene),
        _ => write_transient(path, t),
    }
}

/// An output file's format, from its extension (none: `.npy`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum OutputFormat {
    Npy,
    Exr,
    Hdf5,
}

impl OutputFormat {
    fn of(path: &Path) -> Result<OutputFormat> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("npy") | None => Ok(OutputFormat::Npy),
            Some("exr") => Ok(OutputFormat::Exr),
            Some("hdf5" | "h5") => Ok(OutputFormat::Hdf5),
            Some(other) => Err(Error::Invalid(format!(
                "{}: unknown output format '.{other}' (use .npy, .exr or .hdf5)",
                path.display()
            ))),
        }
    }
}

/// Writes a transient; the format follows the extension (`.npy` default, `.exr`; `.hdf5`
/// needs the scene: [`write_capture`]).
pub fn write_transient(path: &Path, t: &Transient) -> Result<()> {
    match OutputFormat::of(path)? {
        OutputFormat::Exr => write_via_temp(path, |tmp| exr_out::write(tmp, t)),
        OutputFormat::Npy => write_npy(path, t),
        OutputFormat::Hdf5 => Err(Error::Invalid(format!(
            "{}: a y-tal .hdf5 capture needs the scene's geometry (io::write_capture)",
            path.display()
        ))),
    }
}

/// `.npy`, float32, shape `(sy, sx, T)` or `(sy, sx, ly, lx, T)`, C order, written
/// through [`write_via_temp`].
pub fn write_npy(path: &Path, t: &Transient) -> Result<()> {
    let arr = ndarray::ArrayViewD::from_shape(IxDyn(&t.shape), &t.data)
        .map_err(|e| Error::Invalid(format!("transient shape: {e}")))?;
    write_via_temp(path, |tmp| {
        let file = std::fs::File::create(tmp).map_err(|e| Error::io(tmp, e))?;
        let mut w = std::io::BufWriter::new(file);
        ndarray_npy::WriteNpyExt::write_npy(&arr, &mut w)
            .map_err(|e| Error::Invalid(format!("{}: writing npy: {e}", path.display())))?;
        std::io::Write::flush(&mut w).map_err(|e| Error::io(tmp, e))
    })
}

/// Writes an output file atomically: `write` fills a temporary file in `path`'s folder
/// (made if missing), which is synced and renamed over `path`. An interrupted write never
/// leaves a partial file, nor loses the previous one; on failure the temporary file is
/// removed. Every transient writer (npy, EXR, y-tal HDF5, gradients' npz) goes through it,
/// and it through `optim::atomic::write_file_atomic` (one temporary-name scheme,
/// `.<name>.tmp<pid>-<n>`; special files written in place or refused, never replaced).
pub fn write_via_temp(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    // The writer's own error (it names what failed) is kept apart from the file
    // system's around it.
    let mut failed = None;
    let done = optim::checkpoint::write_file_atomic(path, |tmp| {
        write(tmp).map_err(|e| {
            failed = Some(e);
            std::io::Error::other("writer failed")
        })
    });
    match (failed, done) {
        (Some(e), _) => Err(e),
        (None, r) => r.map_err(|e| Error::io(path, e)),
    }
}

/// Checks, before any work, that `path` can take a transient: a known extension, and a
/// folder that exists or can be made (not a file), the path itself not a folder.
pub fn check_output(path: &Path) -> Result<()> {
    OutputFormat::of(path)?;
    check_output_place(path)
}

/// Checks, before any work, that a file can be written at `path`: not a folder, in a
/// folder that exists or can be made.
pub fn check_output_place(path: &Path) -> Result<()> {
    if path.is_dir() {
        return Err(Error::Invalid(format!(
            "{}: is a folder; give a file name (e.g. {}/out.npy)",
            path.display(),
            path.display()
        )));
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    }
    optim::atomic::check_target(path).map_err(|e| Error::io(path, e))
}

/// Reads a `.npy` of float32 or float64 values.
pub fn read_npy(path: &Path) -> Result<Transient> {
    // The header must announce exactly the file's data before anything is allocated;
    // it also says which of the two dtypes to read.
    let header = npy_header::check(path)?;
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let reader = std::io::BufReader::new(file);
    let bad = |e: ndarray_npy::ReadNpyError| Error::scene(path, format!("reading .npy: {e}"));
    let arr: ArrayD<f32> = if header.item_bytes == 4 {
        ndarray_npy::ReadNpyExt::read_npy(reader).map_err(bad)?
    } else {
        let a: ArrayD<f64> = ndarray_npy::ReadNpyExt::read_npy(reader).map_err(bad)?;
        a.mapv(|v| v as f32)
    };
    let shape = arr.shape().to_vec();
    let data = arr.as_standard_layout().iter().copied().collect();
    Ok(Transient { data, shape })
}

/// Writes a gradient as `.npz`: `loss` (a scalar), `vertices` (V x 3, f64) or
/// `vertices_<k>` per object if there are several, `albedo` (one per object), and
/// `vertex_albedo` / `vertex_albedo_<k>` for objects with per-vertex albedo; atomically
/// ([`write_via_temp`]).
pub fn write_gradient(path: &Path, loss: f64, g: &crate::adjoint::Gradient) -> Result<()> {
    write_via_temp(path, |tmp| write_npz(tmp, path, loss, g))
}

fn write_npz(tmp: &Path, path: &Path, loss: f64, g: &crate::adjoint::Gradient) -> Result<()> {
    use ndarray::{arr0, Array1, Array2};
    let npz_err =
        |e: ndarray_npy::WriteNpzError| Error::Invalid(format!("{}: {e}", path.display()));
    let file = std::fs::File::create(tmp).map_err(|e| Error::io(tmp, e))?;
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
