//! `umbra.fit`: the binding of `umbra::fit::request::run`, the function `umbra fit`
//! runs, so Python and the CLI fit by the same code with the same defaults.

use crate::scene::{in_use, PyScene};
use crate::{array_f32, py_shape, run_interruptible, UmbraError};
use numpy::{IntoPyArray, PyArrayMethods, PyUntypedArrayMethods};
use optim::checkpoint::LossRecord;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::cell::RefCell;
use std::path::{Path, PathBuf};
use std::rc::Rc;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use umbra::fit::request::{parse_schedule, run, Front};
use umbra::fit::{FitRequest, Measurement};

/// A mesh as a dict of numpy arrays: `vertices` (N, 3) float64, `triangles` (F, 3)
/// uint32, `vertex_albedo` (N,) float64 or None.
fn mesh_dict<'py>(py: Python<'py>, m: &optim::Mesh) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let v: Vec<f64> = m.vertices.iter().flatten().copied().collect();
    let f: Vec<u32> = m.faces.iter().flatten().copied().collect();
    d.set_item(
        "vertices",
        v.into_pyarray(py).reshape([m.vertices.len(), 3])?,
    )?;
    d.set_item("triangles", f.into_pyarray(py).reshape([m.faces.len(), 3])?)?;
    if m.vertex_values.is_empty() {
        d.set_item("vertex_albedo", py.None())?;
    } else {
        d.set_item("vertex_albedo", m.vertex_values.clone().into_pyarray(py))?;
    }
    Ok(d)
}

/// Fits a hidden mesh to a measurement: see `umbra.fit` for the arguments and the dict
/// returned.
#[pyfunction]
#[pyo3(signature = (
    scene, measured, output, *, init = None, schedule = None, iters = None, resume = false,
    model = "tri3", spp = 16, known_scale = false, background = None, likelihood = None, jitter = None, irf = None,
    time_offset = None, reflectance = None, retro_falloff = None, ignore_before = None, truth = false, bin = None,
    target_spp = 4096, threads = None, progress = None, boundary_terms = None
))]
#[allow(clippy::too_many_arguments)]
pub fn fit<'py>(
    py: Python<'py>,
    scene: &Bound<'py, PyScene>,
    measured: Option<&Bound<'py, PyAny>>,
    output: PathBuf,
    init: Option<String>,
    schedule: Option<String>,
    iters: Option<u64>,
    resume: bool,
    model: &str,
    spp: u32,
    known_scale: bool,
    background: Option<String>,
    likelihood: Option<String>,
    jitter: Option<f64>,
    irf: Option<String>,
    time_offset: Option<f64>,
    reflectance: Option<String>,
    retro_falloff: Option<f32>,
    ignore_before: Option<f32>,
    truth: bool,
    bin: Option<(u32, u32)>,
    target_spp: u32,
    threads: Option<usize>,
    progress: Option<Py<PyAny>>,
    boundary_terms: Option<bool>,
) -> PyResult<Bound<'py, PyDict>> {
    // The fit works on its own copy: the scene is free again at once (a progress callback
    // may change it, another thread may render it).
    let base = scene.try_borrow().map_err(|_| in_use())?.inner.clone();
    let shape = base.output_shape();
    let measurement = match measured {
        None => Measurement::Demo { target_spp },
        Some(m) if m.is_instance_of::<pyo3::types::PyString>() || m.hasattr("__fspath__")? => {
            let os = py.import("os")?;
            let path: PathBuf = os.call_method1("fspath", (m,))?.extract()?;
            Measurement::File(path)
        }
        Some(m) => {
            let a = array_f32(m, "measured")?;
            if a.shape() != shape.as_slice() {
                return Err(UmbraError::new_err(format!(
                    "measured has shape {}, the scene's renders {}",
                    py_shape(a.shape()),
                    py_shape(&shape)
                )));
            }
            Measurement::Array(crate::c_order(&a).into_owned())
        }
    };
    let schedule = schedule
        .map(|text| parse_schedule(&text, Path::new("<schedule>")))
        .transpose()
        .map_err(crate::to_py)?;
    let background = background
        .map(|b| b.parse())
        .transpose()
        .map_err(|e| UmbraError::new_err(format!("background: {e}")))?;
    let req = FitRequest {
        front: Front::Python,
        init,
        schedule,
        iters,
        resume,
        model: model.to_string(),
        spp,
        known_scale,
        background,
        likelihood,
        jitter,
        irf,
        time_offset,
        reflectance,
        retro_falloff,
        ignore_before,
        truth,
        bin,
        boundary_terms,
        ..FitRequest::new(measurement, output)
    };
    // An exception of the progress callback stops the fit and is raised in its place.
    let failure: Arc<Mutex<Option<PyErr>>> = Arc::default();
    let callback = progress.map(Arc::new);
    let notes: Arc<Mutex<Vec<String>>> = Arc::default();
    let outcome = run_interruptible(py, threads, |work| {
        let (failure, work) = (failure.clone(), work.clone());
        let report: optim::fit::Progress = Rc::new(RefCell::new(move |r: &LossRecord| {
            if work.cancel.load(Ordering::Relaxed) {
                return false;
            }
            let Some(cb) = callback.as_deref() else {
                return true;
            };
            Python::attach(|py| {
                let d = PyDict::new(py);
                let call = (|| {
                    d.set_item("iteration", r.iteration)?;
                    d.set_item("stage", r.stage)?;
                    d.set_item("loss", r.cost)?;
                    d.set_item("data_loss", r.data_loss)?;
                    d.set_item("smoothness", r.smoothness)?;
                    cb.call1(py, (d,))
                })();
                match call {
                    Ok(_) => true,
                    Err(e) => {
                        *failure.lock().unwrap_or_else(|p| p.into_inner()) = Some(e);
                        false
                    }
                }
            })
        }));
        let notes = notes.clone();
        run(base, &req, report, &mut |note: &str| {
            if let Some(w) = note.strip_prefix("warning: ") {
                notes
                    .lock()
                    .unwrap_or_else(|p| p.into_inner())
                    .push(w.to_string());
            }
        })
    });
    // The fit's warnings (e.g. noisy Monte Carlo gradients) as Python UserWarnings.
    for w in notes.lock().unwrap_or_else(|p| p.into_inner()).drain(..) {
        let category = py.get_type::<pyo3::exceptions::PyUserWarning>();
        let text = std::ffi::CString::new(w).unwrap_or_default();
        PyErr::warn(py, &category, &text, 1)?;
    }
    if let Some(e) = failure.lock().unwrap_or_else(|p| p.into_inner()).take() {
        return Err(e);
    }
    let umbra::fit::FitOutcome {
        report,
        summary,
        measured,
        shape,
    } = outcome?;
    let d = PyDict::new(py);
    let surface = mesh_dict(py, &report.mesh)?;
    d.set_item("vertices", surface.get_item("vertices")?)?;
    d.set_item("triangles", surface.get_item("triangles")?)?;
    d.set_item("full_mesh", mesh_dict(py, &report.full_mesh)?)?;
    if report.face_determination.is_empty() {
        d.set_item("face_determination", py.None())?;
    } else {
        d.set_item(
            "face_determination",
            report.face_determination.clone().into_pyarray(py),
        )?;
    }
    let h = &report.history;
    let history = PyDict::new(py);
    let col = |f: &dyn Fn(&LossRecord) -> f64| h.iter().map(f).collect::<Vec<f64>>();
    history.set_item(
        "iteration",
        h.iter()
            .map(|r| r.iteration)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    history.set_item(
        "stage",
        h.iter()
            .map(|r| r.stage as u64)
            .collect::<Vec<_>>()
            .into_pyarray(py),
    )?;
    history.set_item("loss", col(&|r| r.cost).into_pyarray(py))?;
    history.set_item("data_loss", col(&|r| r.data_loss).into_pyarray(py))?;
    history.set_item("smoothness", col(&|r| r.smoothness).into_pyarray(py))?;
    d.set_item("history", history)?;
    d.set_item("final_loss", summary.final_loss)?;
    d.set_item("relative_l2", summary.relative_l2)?;
    d.set_item("deviance_per_bin", summary.deviance_per_bin)?;
    d.set_item("held_out_loss", summary.held_out_loss)?;
    if let Some(r) = &summary.response {
        let resp = PyDict::new(py);
        resp.set_item("sigma_ps", r.sigma_ps)?;
        resp.set_item("t0_ps", r.t0_ps)?;
        resp.set_item("tail_weights", r.tail_weights.clone())?;
        resp.set_item("tail_tau_ps", r.tail_tau_ps.clone())?;
        d.set_item("response", resp)?;
    } else {
        d.set_item("response", py.None())?;
    }
    match &summary.nuisance {
        Some(n) => {
            let named = PyDict::new(py);
            for (k, v) in n {
                named.set_item(k, v)?;
            }
            d.set_item("nuisance", named)?;
        }
        None => d.set_item("nuisance", py.None())?,
    }
    d.set_item("scale", summary.scale)?;
    d.set_item("background", summary.background)?;
    d.set_item("time_offset", summary.time_offset)?;
    d.set_item("seconds", summary.seconds)?;
    d.set_item("rejected_steps", summary.rejected_steps)?;
    d.set_item("unsupported_faces", summary.unsupported_faces)?;
    d.set_item("undetermined_faces", summary.undetermined_faces)?;
    d.set_item("init", &summary.init)?;
    let starts = PyDict::new(py);
    for st in &summary.starts {
        starts.set_item(&st.init, st.final_loss)?;
    }
    d.set_item("starts", starts)?;
    d.set_item("photon_noise_floor", summary.photon_noise_floor)?;
    match &summary.chamfer {
        None => d.set_item("chamfer", py.None())?,
        Some(c) => {
            let cd = PyDict::new(py);
            cd.set_item("seen_mm", c.seen_mm)?;
            cd.set_item("seen_fit_to_truth_mm", c.seen_fit_to_truth_mm)?;
            cd.set_item("seen_truth_to_fit_mm", c.seen_truth_to_fit_mm)?;
            cd.set_item("whole_mm", c.whole_mm)?;
            cd.set_item("fit_seen_area_fraction", c.fit_seen_area_fraction)?;
            cd.set_item("truth_seen_area_fraction", c.truth_seen_area_fraction)?;
            d.set_item("chamfer", cd)?;
        }
    }
    let files: Vec<String> = report
        .files
        .iter()
        .map(|p| p.display().to_string())
        .collect();
    d.set_item("files", files)?;
    // The fitted surface seen from the wall (albedo.npy, depth.npy): (ny, nx) per scan
    // point, NaN where no surface.
    let seen = &report.seen;
    for (name, values) in [("albedo", &seen.albedo), ("depth", &seen.depth)] {
        d.set_item(
            name,
            values
                .clone()
                .into_pyarray(py)
                .reshape([seen.ny, seen.nx])?,
        )?;
    }
    // The capture model's floor per scan point (floor.npy), or None.
    if report.floors.len() == seen.ny * seen.nx {
        d.set_item(
            "floor",
            report
                .floors
                .clone()
                .into_pyarray(py)
                .reshape([seen.ny, seen.nx])?,
        )?;
    } else {
        d.set_item("floor", py.None())?;
    }
    d.set_item(
        "render",
        report.render.into_pyarray(py).reshape(shape.clone())?,
    )?;
    d.set_item("measured", measured.into_pyarray(py).reshape(shape)?)?;
    Ok(d)
}
