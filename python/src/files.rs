//! Renders to files from Python: `umbra.save` (a whole transient, in the CLI's formats:
//! `.npy`, `.exr`, y-tal `.hdf5`) and the y-tal capture streamed in blocks of rows that
//! `umbra.distributed.render(out="x.hdf5")` writes as its shards arrive
//! (`umbra::io::ytal::write_ytal_blocks`). Every file is written at a temporary name and
//! moved into place when complete.

use crate::scene::PyScene;
use crate::{c_order, like_render, to_py};
use pyo3::prelude::*;
use std::path::PathBuf;
use umbra::io::ytal;
use umbra::transport::Transient;

/// Writes `transient` (the scene's render shape) to `path`; the format follows the
/// extension, as `umbra render -o`.
#[pyfunction]
pub fn save(path: PathBuf, transient: &Bound<'_, PyAny>, scene: &PyScene) -> PyResult<()> {
    let shape = scene.inner.output_shape();
    let a = like_render(transient, "transient", &shape)?;
    umbra::io::check_output(&path).map_err(to_py)?;
    let t = Transient {
        data: c_order(&a).into_owned(),
        shape,
    };
    umbra::io::write_capture(&path, &t, &scene.inner).map_err(to_py)
}

/// Rows per HDF5 chunk of the y-tal capture's `H`: blocks cut on multiples fill whole
/// chunks.
#[pyfunction]
pub fn ytal_chunk_rows(scene: &PyScene) -> usize {
    ytal::chunk_rows(&scene.inner)
}

/// Writes a y-tal capture of `scene` from `blocks`, an iterable of `(first_row, rows)`
/// (`rows`: float32, whole measurement rows of the render in its order, any shape with
/// `T` values per row), in any order. An exception raised by the iterable (a shard that
/// failed) is raised again as it was, and no file is left.
#[pyfunction]
pub fn write_ytal_blocks(
    py: Python<'_>,
    path: PathBuf,
    scene: &PyScene,
    blocks: &Bound<'_, PyAny>,
) -> PyResult<()> {
    umbra::io::check_output_place(&path).map_err(to_py)?;
    let mut raised: Option<PyErr> = None;
    let mut keep = |e: PyErr| {
        raised = Some(e);
        umbra::Error::Invalid("stopped by a Python exception".into())
    };
    let written = ytal::write_ytal_blocks(&path, &scene.inner, |sink| {
        let iter = blocks.try_iter().map_err(&mut keep)?;
        for item in iter {
            let (first, rows): (usize, Bound<'_, PyAny>) =
                item.and_then(|i| i.extract()).map_err(&mut keep)?;
            let a = crate::array_f32(&rows, "rows").map_err(&mut keep)?;
            sink(first, &c_order(&a))?;
            py.check_signals().map_err(&mut keep)?;
        }
        Ok(())
    });
    match (raised, written) {
        (Some(e), _) => Err(e),
        (None, r) => r.map_err(to_py),
    }
}
