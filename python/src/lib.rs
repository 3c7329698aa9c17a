//! `umbra._umbra`: the Python bindings (PyO3 + rust-numpy). The pure-Python package
//! `umbra` (python/umbra) wraps these; `_umbra.pyi` has their signatures and types.
//!
//! - Arrays cross as numpy arrays in mitransient's layout, read by their shape and strides
//!   (any memory order: Fortran, transposed, negative strides) as NumPy indexes them. A
//!   float32 C-contiguous input (`adjoint`, `target`) is read in place; renders are moved
//!   into numpy without a copy.
//! - Options (`model`, `spp`, ...) override the scene's render settings in one place,
//!   [`options::resolve`].
//! - Every Rust error becomes `umbra.UmbraError` with the Rust message (never a crash of
//!   the interpreter); a Ctrl-C during a long render, gradient or fit raises
//!   `KeyboardInterrupt` after cancelling the work.
//! - The GIL is released while rendering: the work runs on a scoped thread while the
//!   calling thread sleeps without the GIL, waking every 20 ms to check for signals and
//!   at once when the work ends.

mod files;
mod fit;
mod object_index;
mod options;
mod scene;
mod shards;
mod validation;

use numpy::ndarray::ArrayD;
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyKeyboardInterrupt};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use scene::PyScene;
use std::borrow::Cow;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use umbra::adjoint::Loss;
use umbra::scene::Model;
use umbra::transport::silence;
use umbra::transport::{Progress, RenderOptions, Renderer};

create_exception!(
    _umbra,
    UmbraError,
    PyException,
    "An error reported by Umbra (bad scene, bad input, unsupported setting)."
);

/// A shape as Python prints a tuple: `(2, 3)`, `(5,)`.
pub fn py_shape(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

pub fn to_py(e: umbra::Error) -> PyErr {
    match e {
        umbra::Error::Cancelled => PyKeyboardInterrupt::new_err("cancelled"),
        e => UmbraError::new_err(e.to_string()),
    }
}

/// `obj` as a float array of `dtype` through `numpy.asarray` (a no-op for an array of
/// that dtype), or an `UmbraError` naming the argument.
fn as_numpy<'py>(obj: &Bound<'py, PyAny>, dtype: &str, name: &str) -> PyResult<Bound<'py, PyAny>> {
    let np = obj.py().import("numpy")?;
    let kind = obj.getattr("dtype").and_then(|d| d.getattr("kind"));
    if let Ok(kind) = kind {
        let kind: String = kind.extract()?;
        if !matches!(kind.as_str(), "f" | "i" | "u") {
            return Err(UmbraError::new_err(format!(
                "{name}: expected an array of real numbers, got dtype {}",
                obj.getattr("dtype")?.str()?
            )));
        }
    }
    np.call_method1("asarray", (obj, dtype)).map_err(|e| {
        match e.is_instance_of::<UmbraError>(obj.py()) {
            // Umbra's own error from the conversion (an `__array__` that changed a scene in use).
            true => e,
            false => UmbraError::new_err(format!("{name}: not an array of real numbers ({e})")),
        }
    })
}

/// A real array-like as an owned float64 array (small inputs: vertices, albedos).
pub fn array_f64(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<ArrayD<f64>> {
    let a = as_numpy(obj, "float64", name)?;
    let a: PyReadonlyArrayDyn<'_, f64> = a.extract()?;
    Ok(a.as_array().to_owned())
}

/// A real array-like as float32: an aligned float32 array in native byte order is
/// borrowed as it is (no copy), any other is converted once.
pub fn array_f32<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
) -> PyResult<PyReadonlyArrayDyn<'py, f32>> {
    if let Ok(a) = obj.extract::<PyReadonlyArrayDyn<'py, f32>>() {
        // An unaligned view (np.frombuffer at an odd offset) is copied: it is read
        // through typed references.
        if obj.getattr("flags")?.getattr("aligned")?.is_truthy()? {
            return Ok(a);
        }
        return obj.call_method0("copy")?.extract();
    }
    as_numpy(obj, "float32", name)?.extract()
}

/// The values of a float32 array in logical C order (by its shape and strides, as NumPy
/// indexes it): in place when it is C-contiguous. rust-numpy's `as_slice` alone would do
/// for a Fortran-contiguous array too, in its memory order: the values scrambled.
pub fn c_order<'a>(a: &'a PyReadonlyArrayDyn<'_, f32>) -> Cow<'a, [f32]> {
    if a.is_c_contiguous() {
        if let Ok(s) = a.as_slice() {
            return Cow::Borrowed(s);
        }
    }
    Cow::Owned(a.as_array().iter().copied().collect())
}

/// An array input of the render's shape, checked.
pub(crate) fn like_render<'py>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    shape: &[usize],
) -> PyResult<PyReadonlyArrayDyn<'py, f32>> {
    let a = array_f32(obj, name)?;
    if a.shape() != shape {
        return Err(UmbraError::new_err(format!(
            "{name} has shape {}, the render {}",
            py_shape(a.shape()),
            py_shape(shape)
        )));
    }
    Ok(a)
}

/// Runs `work` on a scoped thread without the GIL, checking for Ctrl-C every 20 ms (and
/// returning as soon as the work ends): a signal cancels the work (through `progress`)
/// and is re-raised once it has stopped.
pub fn run_interruptible<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    work: impl FnOnce(&Arc<Progress>) -> umbra::Result<T> + Send,
) -> PyResult<T> {
    let progress = Arc::new(Progress::default());
    let pool =
        umbra::threads::pool(threads, "threads").map_err(|e| UmbraError::new_err(e.to_string()))?;
    let mut signal = None;
    let caller = std::thread::current();
    let result = std::thread::scope(|s| {
        let handle = s.spawn(|| {
            let r = pool.install(|| work(&progress));
            // Wake the caller now rather than at its next 20 ms check: a render of a few
            // ms would otherwise cost a whole period (every call took >= 20 ms).
            caller.unpark();
            r
        });
        while !handle.is_finished() {
            if signal.is_none() {
                if let Err(e) = py.check_signals() {
                    progress.cancel.store(true, Ordering::Relaxed);
                    signal = Some(e);
                }
            }
            py.detach(|| std::thread::park_timeout(std::time::Duration::from_millis(20)));
        }
        handle.join()
    });
    if let Some(e) = signal {
        return Err(e);
    }
    match result {
        Ok(r) => r.map_err(to_py),
        Err(_) => Err(UmbraError::new_err(
            "internal error: the render thread panicked (please report)",
        )),
    }
}

/// Renders the scene's transient: a float32 array in mitransient's layout. Options
/// (`options::NAMES`) override the scene's render settings.
#[pyfunction]
#[pyo3(signature = (scene, **options))]
fn render<'py>(
    py: Python<'py>,
    scene: &PyScene,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let r = options::resolve(&scene.inner, options)?;
    let (s, opts) = (&*r.scene, r.opts);
    let t = run_interruptible(py, r.threads, |progress| {
        let geom = scene.geometry();
        umbra::transport::render(s, &geom, &opts, Some(&**progress))
    })?;
    if silence::all_zero(&t.data) {
        warn(
            py,
            &format!("the render is zero everywhere: {}", silence::zero_reason(s)),
        )?;
    }
    t.data.into_pyarray(py).reshape(t.shape)
}

/// A `UserWarning` from the caller's line (what the CLI prints as `warning:`).
fn warn(py: Python<'_>, msg: &str) -> PyResult<()> {
    let msg = std::ffi::CString::new(msg.replace('\0', " ")).expect("no NUL left");
    PyErr::warn(
        py,
        &py.get_type::<pyo3::exceptions::PyUserWarning>(),
        &msg,
        1,
    )
}

/// `dLoss/dθ`, for the adjoint histogram `adjoint` (`dLoss/dH`) or for `loss` against
/// `target` (one of the two): see `umbra.grad` for the dict it returns.
#[pyfunction]
#[pyo3(signature = (scene, adjoint = None, target = None, loss = "l2", **options))]
fn grad<'py>(
    py: Python<'py>,
    scene: &PyScene,
    adjoint: Option<&Bound<'py, PyAny>>,
    target: Option<&Bound<'py, PyAny>>,
    loss: &str,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyDict>> {
    let r = options::resolve(&scene.inner, options)?;
    let (s, opts) = (&*r.scene, r.opts);
    let shape = s.output_shape();
    let (input, with_target) =
        match (adjoint, target) {
            (Some(a), None) => (like_render(a, "adjoint", &shape)?, false),
            (None, Some(t)) => (like_render(t, "target", &shape)?, true),
            _ => return Err(UmbraError::new_err(
                "grad: give either adjoint (dLoss/dH) or target (with loss), not both or neither",
            )),
        };
    let loss: Loss = loss
        .parse()
        .map_err(|e| UmbraError::new_err(format!("loss: {e}")))?;
    let values = c_order(&input);
    let values: &[f32] = &values;
    let (value, primal, g) = run_interruptible(py, r.threads, |progress| {
        let geom = scene.geometry();
        let mut opts = opts;
        let mut primal = None;
        if with_target || opts.model == Model::Auto {
            let renderer = Renderer::new(s, &geom, &opts)?;
            opts = RenderOptions {
                model: renderer.model,
                ..opts
            };
            if with_target {
                primal = Some(renderer.render(Some(&**progress))?);
            }
        }
        let (value, adj) = match &primal {
            Some(h) => {
                let (value, adj) = loss.evaluate(&h.data, values, h.bins())?;
                (Some(value), Cow::Owned(adj))
            }
            None => (None, Cow::Borrowed(values)),
        };
        let g = umbra::adjoint::gradient(s, &geom, &opts, &adj, Some(&**progress))?;
        Ok((value, primal, g))
    })?;
    if let Some(h) = &primal {
        if silence::all_zero(&h.data) {
            let why = silence::zero_reason(s);
            warn(
                py,
                &format!("the render is zero everywhere, so the gradient is too: {why}"),
            )?;
        } else if h.data.as_slice() == values {
            warn(py, "the render equals the target bin for bin: the loss and the gradient are 0 (a target rendered with the same seed and spp reproduces the render exactly; use another seed, or a measured target)")?;
        }
    }
    let out = gradient_dict(py, g)?;
    out.set_item("loss", value)?;
    match primal {
        Some(h) => out.set_item("render", h.data.into_pyarray(py).reshape(h.shape)?)?,
        None => out.set_item("render", py.None())?,
    }
    Ok(out)
}

/// The dict `umbra.grad` returns, without `loss` and `render`.
pub fn gradient_dict(py: Python<'_>, g: umbra::adjoint::Gradient) -> PyResult<Bound<'_, PyDict>> {
    let out = PyDict::new(py);
    let vertices = PyList::empty(py);
    for v in &g.vertices {
        let flat: Vec<f64> = v.iter().flatten().copied().collect();
        vertices.append(flat.into_pyarray(py).reshape([v.len(), 3])?)?;
    }
    out.set_item("vertices", vertices)?;
    out.set_item("albedo", g.albedo.into_pyarray(py))?;
    let va = PyList::empty(py);
    for a in g.vertex_albedo {
        match a {
            Some(a) => va.append(a.into_pyarray(py))?,
            None => va.append(py.None())?,
        }
    }
    out.set_item("vertex_albedo", va)?;
    out.set_item("truncated_paths", g.truncated)?;
    out.set_item("boundary_terms", g.boundary)?;
    Ok(out)
}

/// `options::NAMES`: the keyword options of render and grad.
#[pyfunction]
fn option_names() -> Vec<&'static str> {
    options::NAMES.to_vec()
}

#[pymodule]
fn _umbra(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("UmbraError", m.py().get_type::<UmbraError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<PyScene>()?;
    m.add_function(wrap_pyfunction!(scene::load_scene, m)?)?;
    m.add_function(wrap_pyfunction!(scene::load_scene_xml, m)?)?;
    m.add_function(wrap_pyfunction!(scene::default_scene, m)?)?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(grad, m)?)?;
    m.add_function(wrap_pyfunction!(option_names, m)?)?;
    m.add_function(wrap_pyfunction!(scene::_scene_from_wire, m)?)?;
    m.add_function(wrap_pyfunction!(shards::render_measurements, m)?)?;
    m.add_function(wrap_pyfunction!(shards::resolve_pilots, m)?)?;
    m.add_function(wrap_pyfunction!(shards::grad_chunk_layout, m)?)?;
    m.add_function(wrap_pyfunction!(shards::grad_chunks, m)?)?;
    m.add_function(wrap_pyfunction!(shards::grad_combine, m)?)?;
    m.add_function(wrap_pyfunction!(files::save, m)?)?;
    m.add_function(wrap_pyfunction!(files::ytal_chunk_rows, m)?)?;
    m.add_function(wrap_pyfunction!(files::write_ytal_blocks, m)?)?;
    m.add_function(wrap_pyfunction!(fit::fit, m)?)?;
    m.add_function(wrap_pyfunction!(validation::capture, m)?)?;
    m.add_function(wrap_pyfunction!(validation::mc3_samples, m)?)?;
    m.add_function(wrap_pyfunction!(validation::tri3_subtriangles, m)?)?;
    Ok(())
}
