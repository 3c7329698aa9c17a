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
    /// Shape of a render: `(sy, sx, T)` or `(sy, sx, ly, lx, T)` (mitransient's layout).
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

/// The capture as the estimators see it, for independent implementations (the Dr.Jit
/// validation): per measurement the laser spot `x_l` and sensor point `x_s` (M, 3), the
/// power delivered to the spot `power` (M,), the extra OPL of the laser and detector legs
/// `legs` (M,); the wall normal `n_w`, the wall BRDF `f_wall` (ρ_w/π); per flat hidden
/// triangle (objects in order, their triangles in order) the corners `triangles`
/// (T, 3, 3), corner albedos `albedo` (T, 3) and `two_sided` (T,); the film's `start`,
/// `width`, `bins`, `kernel` and `sigma` (OPL, m).
#[pyfunction]
fn capture<'py>(py: Python<'py>, scene: &PyScene) -> PyResult<Bound<'py, PyDict>> {
    let s = &scene.inner;
    let geom = umbra::geometry::SceneGeometry::build(s);
    let film = umbra::film::Film::new(&s.film);
    let m = s.num_measurements();
    let (mut x_l, mut x_s, mut power, mut legs) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut f_wall = 0.0;
    for i in 0..m {
        let ctx = umbra::transport::MeasurementCtx::new(s, &geom, &film, i);
        x_l.extend(ctx.x_l.to_array());
        x_s.extend(ctx.x_s.to_array());
        power.push(ctx.power);
        legs.push(ctx.opl_laser_leg(ctx.x_l) + ctx.opl_sensor_leg);
        f_wall = ctx.f_wall;
    }
    let t = geom.hidden.len();
    let corners: Vec<f32> = geom
        .hidden
        .iter()
        .flat_map(|h| h.v.iter().flat_map(|v| v.to_array()))
        .collect();
    let albedo: Vec<f32> = geom.hidden.iter().flat_map(|h| h.albedo).collect();
    let two_sided: Vec<bool> = geom.hidden.iter().map(|h| h.two_sided).collect();
    let d = PyDict::new(py);
    d.set_item("x_l", x_l.into_pyarray(py).reshape([m, 3])?)?;
    d.set_item("x_s", x_s.into_pyarray(py).reshape([m, 3])?)?;
    d.set_item("power", power.into_pyarray(py))?;
    d.set_item("legs", legs.into_pyarray(py))?;
    d.set_item("n_w", s.wall.normal().to_array().to_vec())?;
    d.set_item("f_wall", f_wall)?;
    d.set_item("triangles", corners.into_pyarray(py).reshape([t, 3, 3])?)?;
    d.set_item("albedo", albedo.into_pyarray(py).reshape([t, 3])?)?;
    d.set_item("two_sided", two_sided)?;
    d.set_item("start", film.start)?;
    d.set_item("width", film.width)?;
    d.set_item("bins", film.bins)?;
    let (kernel, sigma) = match s.film.kernel {
        umbra::scene::KernelSpec::Box => ("box", 0.0),
        umbra::scene::KernelSpec::Gaussian { sigma_opl } => ("gaussian", sigma_opl as f64),
    };
    d.set_item("kernel", kernel)?;
    d.set_item("sigma", sigma)?;
    Ok(d)
}

/// The random choices of `mc3` for `spp` samples of every measurement (seed `seed`):
/// flat triangle `tri` (M, spp), barycentrics `bary` (M, spp, 2), its probability
/// `prob` (M, spp), the laser-spot point `x_l` (M, spp, 3), and whether the hidden
/// point sees both wall points `visible` (M, spp). `umbra.render(..., model="mc3")` is
/// the mean over samples of the three-bounce integrand over `prob / A_tri`, for these.
#[pyfunction]
#[pyo3(signature = (scene, spp, seed = 0))]
fn mc3_samples<'py>(
    py: Python<'py>,
    scene: &PyScene,
    spp: u32,
    seed: u64,
) -> PyResult<Bound<'py, PyDict>> {
    let s = &scene.inner;
    let geom = umbra::geometry::SceneGeometry::build(s);
    if geom.hidden.is_empty() {
        return Err(UmbraError::new_err("the scene has no hidden triangles"));
    }
    let film = umbra::film::Film::new(&s.film);
    let m = s.num_measurements();
    let n = m * spp as usize;
    let (mut tri, mut bary, mut prob, mut x_l, mut visible) = (
        Vec::with_capacity(n),
        Vec::with_capacity(2 * n),
        Vec::with_capacity(n),
        Vec::with_capacity(3 * n),
        Vec::with_capacity(n),
    );
    for i in 0..m {
        let ctx = umbra::transport::MeasurementCtx::new(s, &geom, &film, i);
        for k in 0..spp {
            let mut sampler = umbra::rng::Sampler::new(seed, i as u64, k);
            let (ts, xl) = umbra::transport::mc3::draw(&ctx, &mut sampler);
            let x = geom.hidden[ts.tri as usize].point(ts.bary);
            tri.push(ts.tri);
            bary.extend(ts.bary);
            prob.push(ts.prob);
            x_l.extend(xl.to_array());
            visible.push(!geom.occluded(x, xl) && !geom.occluded(x, ctx.x_s));
        }
    }
    let sp = spp as usize;
    let d = PyDict::new(py);
    d.set_item("tri", tri.into_pyarray(py).reshape([m, sp])?)?;
    d.set_item("bary", bary.into_pyarray(py).reshape([m, sp, 2])?)?;
    d.set_item("prob", prob.into_pyarray(py).reshape([m, sp])?)?;
    d.set_item("x_l", x_l.into_pyarray(py).reshape([m, sp, 3])?)?;
    let vis: Vec<u8> = visible.into_iter().map(u8::from).collect();
    d.set_item("visible", vis.into_pyarray(py).reshape([m, sp])?)?;
    Ok(d)
}

/// The sub-triangles `tri3` renders with (subdivision threshold `subdivision`, default
/// the scene's): for each, its flat parent triangle `parent` (S,) and the barycentrics
/// `(b1, b2)` of its three corners in the parent `corner_bary` (S, 3, 2).
#[pyfunction]
#[pyo3(signature = (scene, subdivision = None))]
fn tri3_subtriangles<'py>(
    py: Python<'py>,
    scene: &PyScene,
    subdivision: Option<f32>,
) -> PyResult<Bound<'py, PyDict>> {
    let s = &scene.inner;
    let geom = umbra::geometry::SceneGeometry::build(s);
    let mesh = umbra::transport::tri3::Tri3Mesh::build(
        s,
        &geom,
        subdivision.unwrap_or(s.render.subdivision),
    );
    let n = mesh.len();
    let bary: Vec<f32> = mesh
        .corner_bary
        .iter()
        .flat_map(|c| c.iter().flatten().copied())
        .collect();
    let d = PyDict::new(py);
    d.set_item("parent", mesh.parent.clone().into_pyarray(py))?;
    d.set_item("corner_bary", bary.into_pyarray(py).reshape([n, 3, 2])?)?;
    Ok(d)
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
    m.add_function(wrap_pyfunction!(capture, m)?)?;
    m.add_function(wrap_pyfunction!(mc3_samples, m)?)?;
    m.add_function(wrap_pyfunction!(tri3_subtriangles, m)?)?;
    Ok(())
}
