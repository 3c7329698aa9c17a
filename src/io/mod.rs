//! Files: transients to `.npy` (mitransient's layout) or OpenEXR, and PNG previews.

pub mod exr_out;
pub mod preview;

use crate::error::{Error, Result};
use crate::transport::Transient;
use ndarray::{ArrayD, IxDyn};
use std::path::Path;

/// Writes a transient; the format follows the extension (`.npy` default, `.exr`).
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
        Some(other) => Err(Error::Invalid(format!(
            "{}: unknown output format '.{other}' (use .npy or .exr)",
            path.display()
        ))),
    }
}

/// `.npy`, float32, shape `(sy, sx, T)` or `(ly, lx, sy, sx, T)`, C order.
pub fn write_npy(path: &Path, t: &Transient) -> Result<()> {
    let arr = ArrayD::from_shape_vec(IxDyn(&t.shape), t.data.clone())
        .map_err(|e| Error::Invalid(format!("transient shape: {e}")))?;
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    ndarray_npy::WriteNpyExt::write_npy(&arr, std::io::BufWriter::new(file))
        .map_err(|e| Error::Invalid(format!("{}: writing npy: {e}", path.display())))
}

/// Reads a `.npy` of float32 or float64 values.
pub fn read_npy(path: &Path) -> Result<Transient> {
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
