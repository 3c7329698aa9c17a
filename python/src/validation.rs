//! Functions for independent implementations of Umbra's estimators (the Dr.Jit
//! validation in python/validation): the capture as the estimators see it, `mc3`'s
//! random choices, `tri3`'s sub-triangles.

use crate::scene::PyScene;
use crate::UmbraError;
use numpy::{IntoPyArray, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The capture as the estimators see it, for independent implementations (the Dr.Jit
/// validation): per measurement the laser spot `x_l` and sensor point `x_s` (M, 3), the
/// power delivered to the spot `power` (M,), the extra OPL of the laser and detector legs
/// `legs` (M,); the wall normal `n_w`, the wall BRDF `f_wall` (ρ_w/π); per flat hidden
/// triangle (objects in order, their triangles in order) the corners `triangles`
/// (T, 3, 3), corner albedos `albedo` (T, 3) and `two_sided` (T,); the film's `start`,
/// `width`, `bins`, `kernel` and `sigma` (OPL, m).
#[pyfunction]
pub fn capture<'py>(py: Python<'py>, scene: &PyScene) -> PyResult<Bound<'py, PyDict>> {
    let s = &scene.inner;
    let geom = scene.geometry();
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
pub fn mc3_samples<'py>(
    py: Python<'py>,
    scene: &PyScene,
    spp: u32,
    seed: u64,
) -> PyResult<Bound<'py, PyDict>> {
    let s = &scene.inner;
    let geom = scene.geometry();
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
            visible.push(
                !geom.occluded_touching(x, xl, ts.tri)
                    && !geom.occluded_touching(x, ctx.x_s, ts.tri),
            );
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
pub fn tri3_subtriangles<'py>(
    py: Python<'py>,
    scene: &PyScene,
    subdivision: Option<f32>,
) -> PyResult<Bound<'py, PyDict>> {
    let s = &scene.inner;
    let geom = scene.geometry();
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
