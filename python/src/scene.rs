//! `umbra.Scene`: a loaded scene whose hidden meshes are read and changed from numpy, and
//! the scene loaders.
//!
//! A scene keeps the acceleration structure of its hidden geometry (BVH, area tables)
//! from its first render or gradient until one of its meshes or albedos changes, so a
//! render followed by a gradient of the same scene (what `umbra.torch` does every step)
//! builds it once.

use crate::{array_f64, py_shape, to_py, UmbraError};
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
    /// order), a new `(V, 3)` float32 array.
    #[pyo3(signature = (object = 0))]
    fn vertices<'py>(&self, py: Python<'py>, object: usize) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let o = self.object(object)?;
        let flat: Vec<f32> = o.mesh.positions.iter().flat_map(|p| p.to_array()).collect();
        flat.into_pyarray(py).reshape([o.mesh.positions.len(), 3])
    }

    /// Replaces the vertex positions of hidden object `object` with a `(V, 3)` array
    /// (same V; any real dtype). Non-finite values are refused.
    #[pyo3(signature = (vertices, object = 0))]
    fn set_vertices(&mut self, vertices: &Bound<'_, PyAny>, object: usize) -> PyResult<()> {
        let n = self.object(object)?.mesh.positions.len();
        let name = format!("vertices of object {object}");
        let vertices = array_f64(vertices, &name)?;
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
        for (p, row) in self.inner.objects[object]
            .mesh
            .positions
            .iter_mut()
            .zip(vertices.rows())
        {
            *p = glam::Vec3::new(row[0] as f32, row[1] as f32, row[2] as f32);
        }
        self.changed();
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
        self.changed();
        Ok(())
    }

    /// Per-vertex albedo of hidden object `object` (vertex colours): a new `(V,)`
    /// float32 array, or None.
    #[pyo3(signature = (object = 0))]
    fn vertex_albedo<'py>(
        &self,
        py: Python<'py>,
        object: usize,
    ) -> PyResult<Option<Bound<'py, PyArray1<f32>>>> {
        Ok(self
            .object(object)?
            .mesh
            .vertex_albedo
            .clone()
            .map(|a| a.into_pyarray(py)))
    }

    /// Sets the per-vertex albedo of hidden object `object`: `(V,)` values in [0, 1]
    /// (any real dtype); None removes it (the object's albedo applies again).
    #[pyo3(signature = (values, object = 0))]
    fn set_vertex_albedo(&mut self, values: &Bound<'_, PyAny>, object: usize) -> PyResult<()> {
        let n = self.object(object)?.mesh.positions.len();
        if values.is_none() {
            self.inner.objects[object].mesh.vertex_albedo = None;
            self.changed();
            return Ok(());
        }
        let name = format!("vertex albedo of object {object}");
        let a = array_f64(values, &name)?;
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
        self.inner.objects[object].mesh.vertex_albedo = Some(a.iter().map(|&x| x as f32).collect());
        self.changed();
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
        let bytes = pyo3::types::PyBytes::new(py, &slf.borrow().inner.to_wire());
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
