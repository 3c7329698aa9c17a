//! `umbra.Scene`: a loaded scene whose hidden meshes are read and changed from numpy, and
//! the scene loaders.
//!
//! A scene keeps the acceleration structure of its hidden geometry (BVH, area tables)
//! from its first render or gradient until one of its meshes or albedos changes, so a
//! render followed by a gradient of the same scene (what `umbra.torch` does every step)
//! builds it once.

use crate::object_index::ObjectIndex;
use crate::{array_f64, py_shape, to_py, UmbraError};
use numpy::ndarray::ArrayD;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::Path;
use std::sync::{Arc, Mutex};
use umbra::geometry::SceneGeometry;
use umbra::scene::Scene;

/// A loaded scene: capture setup, hidden meshes (vertices and albedos readable and
/// settable from numpy), film and render settings.
#[pyclass(name = "Scene", module = "umbra")]
pub struct PyScene {
    pub inner: Scene,
    /// The hidden geometry's acceleration structure, built on first use; dropped when a
    /// mesh or an albedo changes.
    geometry: Mutex<Option<Arc<SceneGeometry>>>,
}

impl PyScene {
    pub fn new(inner: Scene) -> PyScene {
        PyScene {
            inner,
            geometry: Mutex::new(None),
        }
    }

    /// The scene's geometry, built now if it is not cached. Call it without the GIL:
    /// building a large mesh's BVH takes a while.
    pub fn geometry(&self) -> Arc<SceneGeometry> {
        let mut cached = self.geometry.lock().unwrap_or_else(|p| p.into_inner());
        cached
            .get_or_insert_with(|| Arc::new(SceneGeometry::build(&self.inner)))
            .clone()
    }

    fn changed(&mut self) {
        *self.geometry.get_mut().unwrap_or_else(|p| p.into_inner()) = None;
    }

    /// The object `object` names (negative: from the end) and its number.
    fn object(&self, object: &ObjectIndex) -> PyResult<(usize, &umbra::scene::HiddenObject)> {
        let k = object.resolve(self.inner.objects.len())?;
        Ok((k, &self.inner.objects[k]))
    }
}

/// Why a scene cannot be changed now: a render, gradient or fit reads it (another
/// thread's, or the one whose callback or input conversion is running).
pub(crate) fn in_use() -> PyErr {
    UmbraError::new_err(
        "the scene is in use by a running render, gradient or fit (in another thread, or the \
         one running this callback): change it once that has returned, or change a scene.copy()",
    )
}

/// The scene to read; an error while it is being changed.
fn readable<'py>(slf: &Bound<'py, PyScene>) -> PyResult<PyRef<'py, PyScene>> {
    slf.try_borrow().map_err(|_| in_use())
}

/// Object `object`'s index and vertex count, read before a setter checks its array.
fn object_and_vertices(slf: &Bound<'_, PyScene>, object: &ObjectIndex) -> PyResult<(usize, usize)> {
    let s = readable(slf)?;
    let (k, o) = s.object(object)?;
    Ok((k, o.mesh.positions.len()))
}

/// The scene to change; [`in_use`] while something reads it (instead of PyO3's bare
/// `RuntimeError: Already borrowed`).
fn mutable<'py>(slf: &Bound<'py, PyScene>) -> PyResult<PyRefMut<'py, PyScene>> {
    slf.try_borrow_mut().map_err(|_| in_use())
}

/// `(n, 3)` finite vertices within [`umbra::scene::checks::MAX_COORD`] of the origin.
fn checked_vertices(vertices: &Bound<'_, PyAny>, name: &str, n: usize) -> PyResult<ArrayD<f64>> {
    let vertices = array_f64(vertices, name)?;
    if vertices.shape() != [n, 3] {
        return Err(UmbraError::new_err(format!(
            "{name}: shape {}, expected ({n}, 3)",
            py_shape(vertices.shape())
        )));
    }
    if let Some(i) = vertices.iter().position(|x| !x.is_finite()) {
        return Err(UmbraError::new_err(format!(
            "{name}: non-finite value at row {}",
            i / 3
        )));
    }
    let max = f64::from(umbra::scene::checks::MAX_COORD);
    if let Some(i) = vertices.iter().position(|x| x.abs() > max) {
        return Err(UmbraError::new_err(format!(
            "{name}: row {} has {:e}, more than {max} m from the origin along an axis (Umbra works in metres)",
            i / 3,
            vertices.iter().nth(i).copied().unwrap_or(f64::NAN)
        )));
    }
    Ok(vertices)
}

/// `(n,)` values in [0, 1].
fn checked_vertex_albedo(values: &Bound<'_, PyAny>, name: &str, n: usize) -> PyResult<Vec<f32>> {
    let a = array_f64(values, name)?;
    if a.shape() != [n] {
        return Err(UmbraError::new_err(format!(
            "{name}: shape {}, expected ({n},)",
            py_shape(a.shape())
        )));
    }
    if let Some(i) = a.iter().position(|x| !(0.0..=1.0).contains(x)) {
        return Err(UmbraError::new_err(format!(
            "{name}: value {} at vertex {i} is outside [0, 1]",
            a.iter().nth(i).copied().unwrap_or(f64::NAN)
        )));
    }
    Ok(a.iter().map(|&x| x as f32).collect())
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

    /// The scene's render settings, the values `render` and `grad` use for options left
    /// unset: a dict with the option names as keys.
    #[getter]
    fn options<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let r = &self.inner.render;
        let d = PyDict::new(py);
        d.set_item("model", r.model.name())?;
        d.set_item("visibility", r.visibility.name())?;
        d.set_item("subdivision", r.subdivision)?;
        d.set_item("max_error", r.max_error)?;
        d.set_item("spp", r.spp)?;
        d.set_item("seed", r.seed)?;
        let depth = if r.max_bounces == u32::MAX {
            -1
        } else {
            r.max_bounces as i64
        };
        d.set_item("max_depth", depth)?;
        d.set_item("laser_sampling", r.techniques.laser_sampling)?;
        d.set_item(
            "hidden_geometry_sampling",
            r.techniques.hidden_geometry_sampling,
        )?;
        d.set_item("bsdf_sampling", r.techniques.bsdf_sampling)?;
        d.set_item("visible_legs", r.visible_legs)?;
        d.set_item("boundary_terms", r.boundary_terms)?;
        match r.rr_early_survival {
            umbra::scene::EarlySurvival::Auto => d.set_item("rr_early_survival", "auto")?,
            umbra::scene::EarlySurvival::Fixed(q) => d.set_item("rr_early_survival", q)?,
        }
        Ok(d)
    }

    /// Vertex positions of hidden object `object` (world space, rows in the OBJ's `v`
    /// order), a new `(V, 3)` float32 array. A negative `object` counts from the end.
    #[pyo3(signature = (object = ObjectIndex::FIRST), text_signature = "($self, object=0)")]
    fn vertices<'py>(
        &self,
        py: Python<'py>,
        object: ObjectIndex,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let (_, o) = self.object(&object)?;
        let flat: Vec<f32> = o.mesh.positions.iter().flat_map(|p| p.to_array()).collect();
        flat.into_pyarray(py).reshape([o.mesh.positions.len(), 3])
    }

    /// Replaces the vertex positions of hidden object `object` with a `(V, 3)` array
    /// (same V; any real dtype, any memory layout). Non-finite values are refused.
    #[pyo3(signature = (vertices, object = ObjectIndex::FIRST), text_signature = "($self, vertices, object=0)")]
    fn set_vertices(
        slf: &Bound<'_, Self>,
        vertices: &Bound<'_, PyAny>,
        object: ObjectIndex,
    ) -> PyResult<()> {
        let (k, n) = object_and_vertices(slf, &object)?;
        let vertices = checked_vertices(vertices, &format!("vertices of object {k}"), n)?;
        let mut s = mutable(slf)?;
        let rows = vertices.rows();
        for (p, row) in s.inner.objects[k].mesh.positions.iter_mut().zip(rows) {
            *p = glam::Vec3::new(row[0] as f32, row[1] as f32, row[2] as f32);
        }
        s.changed();
        Ok(())
    }

    /// Triangles of hidden object `object`: a `(T, 3)` uint32 array of vertex rows.
    #[pyo3(signature = (object = ObjectIndex::FIRST), text_signature = "($self, object=0)")]
    fn triangles<'py>(
        &self,
        py: Python<'py>,
        object: ObjectIndex,
    ) -> PyResult<Bound<'py, PyArray2<u32>>> {
        let (_, o) = self.object(&object)?;
        let flat: Vec<u32> = o.mesh.triangles.iter().flatten().copied().collect();
        flat.into_pyarray(py).reshape([o.mesh.triangles.len(), 3])
    }

    /// Albedo of every hidden object (the object's albedo; meshes with vertex colours use
    /// `vertex_albedo` instead).
    #[getter]
    fn albedo(&self) -> Vec<f32> {
        self.inner.objects.iter().map(|o| o.albedo).collect()
    }

    /// Sets the albedo of hidden object `object` (in [0, 1]). An object with per-vertex
    /// albedo is refused (its vertex albedo takes the place of its albedo): change that
    /// with `set_vertex_albedo`, or remove it with `set_vertex_albedo(None, object)`.
    #[pyo3(signature = (value, object = ObjectIndex::FIRST), text_signature = "($self, value, object=0)")]
    fn set_albedo(slf: &Bound<'_, Self>, value: f32, object: ObjectIndex) -> PyResult<()> {
        let mut s = mutable(slf)?;
        let (k, o) = s.object(&object)?;
        if o.mesh.vertex_albedo.is_some() {
            return Err(UmbraError::new_err(format!(
                "set_albedo: object {k} has per-vertex albedo, which takes the place of its \
                 albedo: change it with set_vertex_albedo(values, {k}), or remove it with \
                 set_vertex_albedo(None, {k}) first"
            )));
        }
        if !(0.0..=1.0).contains(&value) {
            return Err(UmbraError::new_err(format!(
                "albedo {value} is outside [0, 1]"
            )));
        }
        s.inner.objects[k].albedo = value;
        s.changed();
        Ok(())
    }

    /// Per-vertex albedo of hidden object `object` (vertex colours): a new `(V,)`
    /// float32 array, or None.
    #[pyo3(signature = (object = ObjectIndex::FIRST), text_signature = "($self, object=0)")]
    fn vertex_albedo<'py>(
        &self,
        py: Python<'py>,
        object: ObjectIndex,
    ) -> PyResult<Option<Bound<'py, PyArray1<f32>>>> {
        let (_, o) = self.object(&object)?;
        Ok(o.mesh.vertex_albedo.clone().map(|a| a.into_pyarray(py)))
    }

    /// Sets the per-vertex albedo of hidden object `object`: `(V,)` values in [0, 1]
    /// (any real dtype); None removes it (the object's albedo applies again).
    #[pyo3(signature = (values, object = ObjectIndex::FIRST), text_signature = "($self, values, object=0)")]
    fn set_vertex_albedo(
        slf: &Bound<'_, Self>,
        values: &Bound<'_, PyAny>,
        object: ObjectIndex,
    ) -> PyResult<()> {
        let (k, n) = object_and_vertices(slf, &object)?;
        let values = match values.is_none() {
            true => None,
            false => Some(checked_vertex_albedo(
                values,
                &format!("vertex albedo of object {k}"),
                n,
            )?),
        };
        let mut s = mutable(slf)?;
        s.inner.objects[k].mesh.vertex_albedo = values;
        s.changed();
        Ok(())
    }

    /// A copy of the scene (to perturb without touching the original).
    fn copy(&self) -> PyScene {
        PyScene {
            inner: self.inner.clone(),
            geometry: Mutex::new(self.geometry.lock().map_or(None, |g| g.clone())),
        }
    }

    /// Pickling (`umbra.distributed` sends a scene to Ray workers this way): the whole
    /// scene, meshes included, as bytes that read back to the same bits.
    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<(Bound<'py, PyAny>, (Bound<'py, pyo3::types::PyBytes>,))> {
        let py = slf.py();
        let from = py.import("umbra._umbra")?.getattr("_scene_from_wire")?;
        let bytes = pyo3::types::PyBytes::new(py, &readable(slf)?.inner.to_wire());
        Ok((from, (bytes,)))
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
pub fn load_scene(path: &str, defines: Option<Vec<(String, String)>>) -> PyResult<PyScene> {
    let inner =
        Scene::load_with_defines(Path::new(path), &defines.unwrap_or_default()).map_err(to_py)?;
    Ok(PyScene::new(inner))
}

/// Parses Mitsuba XML text (`base_dir` resolves relative file names; `origin` names the
/// source in error messages).
#[pyfunction]
#[pyo3(signature = (text, base_dir = ".", origin = "<dict>"))]
pub fn load_scene_xml(text: &str, base_dir: &str, origin: &str) -> PyResult<PyScene> {
    let inner = umbra::scene::mitsuba_xml::parse(text, Path::new(origin), Path::new(base_dir))
        .map_err(to_py)?
        .with_load_warnings();
    Ok(PyScene::new(inner))
}

/// The built-in default scene (a letter T, confocal 32 x 32).
#[pyfunction]
pub fn default_scene() -> PyResult<PyScene> {
    Ok(PyScene::new(
        umbra::scene::default::default_scene().map_err(to_py)?,
    ))
}

/// A scene from `Scene.__reduce__`'s bytes (pickle's reader), checked like a scene file.
#[pyfunction]
pub fn _scene_from_wire(bytes: &[u8]) -> PyResult<PyScene> {
    Ok(PyScene::new(Scene::from_wire(bytes).map_err(to_py)?))
}
