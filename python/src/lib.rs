//! `umbra._umbra`: the Python bindings (PyO3 + rust-numpy). The pure-Python package
//! `umbra` (python/umbra) wraps these; see its docstrings for the user-facing API.
//!
//! - Arrays cross as numpy arrays in mitransient's layout; renders and gradients are
//!   copied out once (no copy on the Rust side beyond the result itself).
//! - Every Rust error becomes `umbra.UmbraError` with the Rust message (never a crash of
//!   the interpreter); a Ctrl-C during a long render or gradient raises
//!   `KeyboardInterrupt` after cancelling the work.
//! - The GIL is released while rendering: the work runs on a scoped thread while the
//!   calling thread sleeps without the GIL, waking every 20 ms to check for signals.

use numpy::{
    IntoPyArray, PyArray2, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods,
};
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyKeyboardInterrupt};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::Path;
use std::sync::atomic::Ordering;
use umbra::scene::{Model, Scene};
use umbra::transport::{Progress, RenderOptions};

create_exception!(
    _umbra,
    UmbraError,
    PyException,
    "An error reported by Umbra (bad scene, bad input, unsupported setting)."
);

/// A shape as Python prints a tuple: `(2, 3)`, `(5,)`.
fn py_shape(shape: &[usize]) -> String {
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

fn to_py(e: umbra::Error) -> PyErr {
    match e {
        umbra::Error::Cancelled => PyKeyboardInterrupt::new_err("cancelled"),
        e => UmbraError::new_err(e.to_string()),
    }
}

/// A loaded scene: capture setup, hidden meshes (vertices and albedos readable and
/// settable from numpy), film and render settings.
#[pyclass(name = "Scene", module = "umbra")]
struct PyScene {
    inner: Scene,
}

impl PyScene {
    fn object(&self, object: usize) -> PyResult<&umbra::scene::HiddenObject> {
        self.inner.objects.get(object).ok_or_else(|| {
            UmbraError::new_err(format!(
                "object {object} does not exist: the scene has {} hidden object(s)",
                self.inner.objects.len()
            ))
        })
    }
}

#[pymethods]
impl PyScene {
    /// Shape of a render: `(sy, sx, T)` or `(ly, lx, sy, sx, T)` (mitransient's layout).
    #[getter]
    fn shape(&self) -> Vec<usize> {
        self.inner.output_shape()
    }

    /// Names of the hidden objects, in scene order.
    #[getter]
    fn objects(&self) -> Vec<String> {
        self.inner.objects.iter().map(|o| o.name.clone()).collect()
    }

    /// Warnings raised while loading (unsupported-but-harmless settings).
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.inner.warnings.clone()
    }

    /// Vertex positions of hidden object `object` (world space, rows in the OBJ's `v`
    /// order), a new `(V, 3)` float32 array.
    #[pyo3(signature = (object = 0))]
    fn vertices<'py>(&self, py: Python<'py>, object: usize) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let o = self.object(object)?;
        let flat: Vec<f32> = o.mesh.positions.iter().flat_map(|p| p.to_array()).collect();
        flat.into_pyarray(py).reshape([o.mesh.positions.len(), 3])
    }

    /// Replaces the vertex positions of hidden object `object` with a `(V, 3)` array
    /// (same V; any float dtype). Non-finite values are refused.
    #[pyo3(signature = (vertices, object = 0))]
    fn set_vertices(&mut self, vertices: &Bound<'_, PyAny>, object: usize) -> PyResult<()> {
        let n = self.object(object)?.mesh.positions.len();
        let vertices: PyReadonlyArrayDyn<'_, f64> = match vertices.extract() {
            Ok(a) => a,
            Err(_) => {
                let np = vertices.py().import("numpy")?;
                np.call_method1("asarray", (vertices, "float64"))?
                    .extract()?
            }
        };
        if vertices.shape() != [n, 3] {
            return Err(UmbraError::new_err(format!(
                "vertices of object {object}: shape {}, expected ({n}, 3)",
                py_shape(vertices.shape())
            )));
        }
        let v = vertices.as_array();
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(UmbraError::new_err(format!(
                "vertices of object {object}: non-finite value at row {}",
                i / 3
            )));
        }
        for (p, row) in self.inner.objects[object]
            .mesh
            .positions
            .iter_mut()
            .zip(v.rows())
        {
            *p = glam::Vec3::new(row[0] as f32, row[1] as f32, row[2] as f32);
        }
        Ok(())
    }

    /// Triangles of hidden object `object`: a `(T, 3)` uint32 array of vertex rows.
    #[pyo3(signature = (object = 0))]
    fn triangles<'py>(
        &self,
        py: Python<'py>,
        object: usize,
    ) -> PyResult<Bound<'py, PyArray2<u32>>> {
        let o = self.object(object)?;
        let flat: Vec<u32> = o.mesh.triangles.iter().flatten().copied().collect();
        flat.into_pyarray(py).reshape([o.mesh.triangles.len(), 3])
    }

    /// Albedo of every hidden object (the object's albedo; meshes with vertex colours use
    /// `vertex_albedo` instead).
    #[getter]
    fn albedo(&self) -> Vec<f32> {
        self.inner.objects.iter().map(|o| o.albedo).collect()
    }

    /// Sets the albedo of hidden object `object` (in [0, 1]).
    #[pyo3(signature = (value, object = 0))]
    fn set_albedo(&mut self, value: f32, object: usize) -> PyResult<()> {
        self.object(object)?;
        if !(0.0..=1.0).contains(&value) {
            return Err(UmbraError::new_err(format!(
                "albedo {value} is outside [0, 1]"
            )));
        }
        self.inner.objects[object].albedo = value;
        Ok(())
    }

    /// Per-vertex albedo of hidden object `object` (vertex colours), or None.
    #[pyo3(signature = (object = 0))]
    fn vertex_albedo(&self, object: usize) -> PyResult<Option<Vec<f32>>> {
        Ok(self.object(object)?.mesh.vertex_albedo.clone())
    }

    /// Sets per-vertex albedo of hidden object `object` (length V, values in [0, 1]).
    #[pyo3(signature = (values, object = 0))]
    fn set_vertex_albedo(&mut self, values: Vec<f32>, object: usize) -> PyResult<()> {
        let n = self.object(object)?.mesh.positions.len();
        if values.len() != n || values.iter().any(|a| !(0.0..=1.0).contains(a)) {
            return Err(UmbraError::new_err(format!(
                "vertex albedo of object {object}: expected {n} values in [0, 1]"
            )));
        }
        self.inner.objects[object].mesh.vertex_albedo = Some(values);
        Ok(())
    }

    /// A copy of the scene (to perturb without touching the original).
    fn copy(&self) -> PyScene {
        PyScene {
            inner: self.inner.clone(),
        }
    }

    fn __repr__(&self) -> String {
        let s = &self.inner;
        format!(
            "umbra.Scene(shape={:?}, objects={:?}, model={}, spp={})",
            s.output_shape(),
            self.objects(),
            s.render.model.name(),
            s.render.spp
        )
    }
}

/// Loads a scene file: Umbra TOML (`.toml`) or mitransient-style Mitsuba XML (`.xml`),
/// with `defines` for the XML's `$name` parameters.
#[pyfunction]
#[pyo3(signature = (path, defines = None))]
fn load_scene(path: &str, defines: Option<Vec<(String, String)>>) -> PyResult<PyScene> {
    let inner =
        Scene::load_with_defines(Path::new(path), &defines.unwrap_or_default()).map_err(to_py)?;
    Ok(PyScene { inner })
}

/// Parses Mitsuba XML text (`base_dir` resolves relative file names; `origin` names the
/// source in error messages).
#[pyfunction]
#[pyo3(signature = (text, base_dir = ".", origin = "<dict>"))]
fn load_scene_xml(text: &str, base_dir: &str, origin: &str) -> PyResult<PyScene> {
    let inner = umbra::scene::mitsuba_xml::parse(text, Path::new(origin), Path::new(base_dir))
        .map_err(to_py)?;
    Ok(PyScene { inner })
}

/// The built-in default scene (a letter T, confocal 32 x 32).
#[pyfunction]
fn default_scene() -> PyResult<PyScene> {
    Ok(PyScene {
        inner: umbra::scene::default::default_scene().map_err(to_py)?,
    })
}

fn options(
    scene: &Scene,
    model: Option<&str>,
    spp: Option<u32>,
    seed: Option<u64>,
) -> PyResult<RenderOptions> {
    let mut opts = RenderOptions::from_scene(scene);
    if let Some(m) = model {
        opts.model = Model::parse(m).ok_or_else(|| {
            UmbraError::new_err(format!("model '{m}' is not one of tri3, mc3, path, auto"))
        })?;
    }
    if let Some(s) = spp {
        if s == 0 {
            return Err(UmbraError::new_err("spp must be at least 1"));
        }
        opts.spp = s;
    }
    opts.seed = seed.unwrap_or(opts.seed);
    Ok(opts)
}

/// Runs `work` on a scoped thread without the GIL, checking for Ctrl-C every 20 ms: a
/// signal cancels the work (through `progress`) and is re-raised once it has stopped.
fn run_interruptible<T: Send>(
    py: Python<'_>,
    threads: Option<usize>,
    work: impl FnOnce(&Progress) -> umbra::Result<T> + Send,
) -> PyResult<T> {
    let progress = Progress::default();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.unwrap_or(0))
        .build()
        .map_err(|e| UmbraError::new_err(format!("threads: {e}")))?;
    let mut signal = None;
    let result = std::thread::scope(|s| {
        let handle = s.spawn(|| pool.install(|| work(&progress)));
        while !handle.is_finished() {
            if signal.is_none() {
                if let Err(e) = py.check_signals() {
                    progress.cancel.store(true, Ordering::Relaxed);
                    signal = Some(e);
                }
            }
            py.detach(|| std::thread::sleep(std::time::Duration::from_millis(20)));
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

/// Renders the scene's transient: a float32 array in mitransient's layout.
#[pyfunction]
#[pyo3(signature = (scene, spp = None, model = None, seed = None, threads = None))]
fn render<'py>(
    py: Python<'py>,
    scene: &PyScene,
    spp: Option<u32>,
    model: Option<&str>,
    seed: Option<u64>,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let s = &scene.inner;
    let opts = options(s, model, spp, seed)?;
    let t = run_interruptible(py, threads, |progress| {
        let geom = umbra::geometry::SceneGeometry::build(s);
        umbra::transport::render(s, &geom, &opts, Some(progress))
    })?;
    t.data.into_pyarray(py).reshape(t.shape)
}

/// `dLoss/dθ` for the adjoint histogram `adjoint` (`dLoss/dH`, the render's shape):
/// a dict with `vertices` (`(V, 3)` float64, or a list of them for several objects),
/// `albedo` (one per object), `vertex_albedo` (per object, None without vertex colours).
#[pyfunction]
#[pyo3(signature = (scene, adjoint, spp = None, model = None, seed = None, threads = None))]
fn grad<'py>(
    py: Python<'py>,
    scene: &PyScene,
    adjoint: PyReadonlyArrayDyn<'py, f32>,
    spp: Option<u32>,
    model: Option<&str>,
    seed: Option<u64>,
    threads: Option<usize>,
) -> PyResult<Bound<'py, PyDict>> {
    let s = &scene.inner;
    let opts = options(s, model, spp, seed)?;
    if adjoint.shape() != s.output_shape().as_slice() {
        return Err(UmbraError::new_err(format!(
            "adjoint has shape {}, the render {}",
            py_shape(adjoint.shape()),
            py_shape(&s.output_shape())
        )));
    }
    let adj: Vec<f32> = adjoint.as_array().iter().copied().collect();
    let g = run_interruptible(py, threads, |progress| {
        let geom = umbra::geometry::SceneGeometry::build(s);
        let model = match opts.model {
            Model::Auto => umbra::transport::Renderer::new(s, &geom, &opts)?.model,
            m => m,
        };
        let opts = RenderOptions { model, ..opts };
        umbra::adjoint::gradient(s, &geom, &opts, &adj, Some(progress))
    })?;
    let out = PyDict::new(py);
    let mut vertices = Vec::new();
    for v in &g.vertices {
        let flat: Vec<f64> = v.iter().flatten().copied().collect();
        vertices.push(flat.into_pyarray(py).reshape([v.len(), 3])?);
    }
    if vertices.len() == 1 {
        out.set_item("vertices", vertices.pop())?;
    } else {
        out.set_item("vertices", vertices)?;
    }
    out.set_item("albedo", g.albedo.clone().into_pyarray(py))?;
    let va: Vec<Option<Bound<'py, numpy::PyArray1<f64>>>> = g
        .vertex_albedo
        .iter()
        .map(|a| a.clone().map(|a| a.into_pyarray(py)))
        .collect();
    out.set_item("vertex_albedo", va)?;
    out.set_item("truncated_paths", g.truncated)?;
    Ok(out)
}

#[pymodule]
fn _umbra(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("UmbraError", m.py().get_type::<UmbraError>())?;
    m.add_class::<PyScene>()?;
    m.add_function(wrap_pyfunction!(load_scene, m)?)?;
    m.add_function(wrap_pyfunction!(load_scene_xml, m)?)?;
    m.add_function(wrap_pyfunction!(default_scene, m)?)?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(grad, m)?)?;
    Ok(())
}
