//! The pieces `umbra.distributed` splits a render or a gradient into, for Ray workers:
//! a render's measurement range (exactly those rows of `umbra.render`'s output), a
//! gradient's chunks (`umbra::adjoint::gradient_chunks`: each chunk's share depends on
//! the scene, options, chunk index and its adjoint rows only) and their combination in
//! chunk order (the same bits as `umbra.grad`). Private API (`_umbra`): the public one is
//! `umbra.distributed`.

use crate::options;
use crate::scene::PyScene;
use crate::{array_f32, array_f64, c_order, gradient_dict, run_interruptible, UmbraError};
use numpy::{IntoPyArray, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use umbra::adjoint::{self, ChunkGrad};
use umbra::geometry::SceneGeometry;
use umbra::scene::{EarlySurvival, Model, Scene};
use umbra::transport::mc3::TRI_PARAMS;
use umbra::transport::{RenderOptions, Renderer};

/// Rows `start..stop` of the render (measurements in the render's order), shape
/// `(stop - start, T)`.
#[pyfunction]
#[pyo3(signature = (scene, start, stop, **options))]
pub fn render_measurements<'py>(
    py: Python<'py>,
    scene: &PyScene,
    start: usize,
    stop: usize,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let r = options::resolve(&scene.inner, options)?;
    let (s, opts) = (&*r.scene, r.opts);
    let bins = s.film.temporal_bins as usize;
    let rows = run_interruptible(py, r.threads, |progress| {
        let geom = scene.geometry();
        Renderer::new(s, &geom, &opts)?.render_measurements(start..stop, Some(&**progress))
    })?;
    rows.into_pyarray(py).reshape([stop - start, bins])
}

/// What a render's pilots pick for `options` (`model = "auto"`: `transport::auto`;
/// `rr_early_survival = "auto"` with `path`: `transport::roulette`), as options to pass
/// on: `{"model": ..., "rr_early_survival": ...}`, each only where it was `auto`. The
/// shards of one render or gradient then run with those values instead of each running
/// the pilots (deterministic, so the same bits either way).
#[pyfunction]
#[pyo3(signature = (scene, **options))]
pub fn resolve_pilots<'py>(
    py: Python<'py>,
    scene: &PyScene,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyDict>> {
    let r = options::resolve(&scene.inner, options)?;
    let (s, opts) = (&*r.scene, r.opts);
    let auto_survival = s.render.rr_early_survival == EarlySurvival::Auto;
    let (model, survival) =
        if opts.model == Model::Auto || (opts.model == Model::Path && auto_survival) {
            // One driver: it resolves the model and, for `path`, runs the roulette's pilot.
            run_interruptible(py, r.threads, |_| {
                let geom = scene.geometry();
                let driver = Renderer::new(s, &geom, &opts)?;
                let survival = (auto_survival && driver.model == Model::Path)
                    .then(|| driver.roulette.map_or(1.0, |p| p.survival));
                Ok((
                    (opts.model == Model::Auto).then_some(driver.model),
                    survival,
                ))
            })?
        } else {
            (None, None)
        };
    let d = PyDict::new(py);
    if let Some(m) = model {
        d.set_item("model", m.name())?;
    }
    if let Some(q) = survival {
        d.set_item("rr_early_survival", q)?;
    }
    Ok(d)
}

/// The gradient's chunks as measurement ranges `[(start, stop), ...]`, in chunk order.
#[pyfunction]
pub fn grad_chunk_layout(scene: &PyScene) -> Vec<(usize, usize)> {
    let n = scene.inner.num_measurements();
    (0..adjoint::chunk_count(n))
        .map(|c| {
            let r = adjoint::chunk_measurements(c, n);
            (r.start, r.end)
        })
        .collect()
}

/// The options with `auto` resolved as `umbra.grad` resolves it (its pilot is
/// deterministic: every worker resolves it alike).
fn gradient_options(
    s: &Scene,
    geom: &SceneGeometry,
    opts: RenderOptions,
) -> umbra::Result<RenderOptions> {
    Ok(if opts.model == Model::Auto {
        RenderOptions {
            model: Renderer::new(s, geom, &opts)?.model,
            ..opts
        }
    } else {
        opts
    })
}

/// The shares of chunks `start..stop` for `adjoint_rows` (float32, the adjoint rows of
/// exactly those chunks' measurements, `(rows, T)`): a list of dicts (`index`,
/// `tri_grad` (F, 12) float64, `vertex_grad` a list of (N, 3) float64 per object or
/// None, `emitted`, `truncated`, `boundary_nodes`), for `grad_combine`.
#[pyfunction]
#[pyo3(signature = (scene, adjoint_rows, start, stop, **options))]
pub fn grad_chunks<'py>(
    py: Python<'py>,
    scene: &PyScene,
    adjoint_rows: &Bound<'py, PyAny>,
    start: usize,
    stop: usize,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyList>> {
    let r = options::resolve(&scene.inner, options)?;
    let (s, opts) = (&*r.scene, r.opts);
    let a = array_f32(adjoint_rows, "adjoint_rows")?;
    let values = c_order(&a);
    let values: &[f32] = &values;
    let parts = run_interruptible(py, r.threads, |progress| {
        let geom = scene.geometry();
        let opts = gradient_options(s, &geom, opts)?;
        adjoint::gradient_chunks(s, &geom, &opts, values, start..stop, Some(&**progress))
    })?;
    let out = PyList::empty(py);
    for p in parts {
        let d = PyDict::new(py);
        d.set_item("index", p.index)?;
        let flat: Vec<f64> = p.tri_grad.iter().flatten().copied().collect();
        d.set_item(
            "tri_grad",
            flat.into_pyarray(py)
                .reshape([p.tri_grad.len(), TRI_PARAMS])?,
        )?;
        match p.vertex_grad {
            None => d.set_item("vertex_grad", py.None())?,
            Some(v) => {
                let l = PyList::empty(py);
                for o in v {
                    let flat: Vec<f64> = o.iter().flatten().copied().collect();
                    l.append(flat.into_pyarray(py).reshape([o.len(), 3])?)?;
                }
                d.set_item("vertex_grad", l)?;
            }
        }
        d.set_item("emitted", p.emitted)?;
        d.set_item("truncated", p.truncated)?;
        d.set_item("boundary_nodes", p.boundary_nodes)?;
        out.append(d)?;
    }
    Ok(out)
}

/// `(rows, 3)` or `(rows, 12)` float64 as rows.
fn rows<const K: usize>(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[f64; K]>> {
    let a = array_f64(obj, name)?;
    let shape = a.shape().to_vec();
    let a = match a.into_dimensionality::<numpy::ndarray::Ix2>() {
        Ok(a) if shape[1] == K => a,
        _ => {
            return Err(UmbraError::new_err(format!(
                "{name}: expected shape (n, {K}), got {shape:?}"
            )))
        }
    };
    Ok(a.rows()
        .into_iter()
        .map(|r| std::array::from_fn(|k| r[k]))
        .collect())
}

/// The first non-finite value of `rows`: its row and value.
fn non_finite<const K: usize>(rows: &[[f64; K]]) -> Option<(usize, f64)> {
    rows.iter()
        .enumerate()
        .find_map(|(r, row)| row.iter().find(|x| !x.is_finite()).map(|&x| (r, x)))
}

/// Refuses a chunk's share with a NaN or an infinity (a worker gone wrong), naming the
/// chunk: added in, it would make the whole gradient NaN.
fn check_finite(c: &ChunkGrad) -> PyResult<()> {
    let mut bad = non_finite(&c.tri_grad).map(|at| ("tri_grad".to_string(), at));
    for (k, o) in c.vertex_grad.iter().flatten().enumerate() {
        bad = bad.or_else(|| non_finite(o).map(|at| (format!("vertex_grad of object {k}"), at)));
    }
    match bad {
        None => Ok(()),
        Some((what, (row, x))) => Err(UmbraError::new_err(format!(
            "grad_combine: chunk {}'s {what} has {x} at row {row}: a share must be finite \
             (the worker that computed it went wrong)",
            c.index
        ))),
    }
}

/// The gradient from every chunk's share (`grad_chunks`' dicts, in any order): the dict
/// `umbra.grad` returns for an adjoint (no `loss`, no `render`), the same bits.
#[pyfunction]
#[pyo3(signature = (scene, parts, **options))]
pub fn grad_combine<'py>(
    py: Python<'py>,
    scene: &PyScene,
    parts: Vec<Bound<'py, PyDict>>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyDict>> {
    let r = options::resolve(&scene.inner, options)?;
    let (s, opts) = (&*r.scene, r.opts);
    let item = |d: &Bound<'py, PyDict>, k: &str| -> PyResult<Bound<'py, PyAny>> {
        d.get_item(k)?
            .ok_or_else(|| UmbraError::new_err(format!("grad_combine: a part has no '{k}'")))
    };
    let mut chunks = Vec::with_capacity(parts.len());
    for d in &parts {
        let v = item(d, "vertex_grad")?;
        let vertex_grad = if v.is_none() {
            None
        } else {
            let mut objects = Vec::new();
            for o in v.try_iter()? {
                objects.push(rows::<3>(&o?, "vertex_grad")?);
            }
            Some(objects)
        };
        let chunk = ChunkGrad {
            index: item(d, "index")?.extract()?,
            tri_grad: rows::<TRI_PARAMS>(&item(d, "tri_grad")?, "tri_grad")?,
            vertex_grad,
            emitted: item(d, "emitted")?.extract()?,
            truncated: item(d, "truncated")?.extract()?,
            boundary_nodes: item(d, "boundary_nodes")?.extract()?,
        };
        check_finite(&chunk)?;
        chunks.push(chunk);
    }
    let g = run_interruptible(py, r.threads, |_| {
        let geom = scene.geometry();
        let opts = gradient_options(s, &geom, opts)?;
        adjoint::combine(s, &geom, &opts, chunks)
    })?;
    gradient_dict(py, g)
}
