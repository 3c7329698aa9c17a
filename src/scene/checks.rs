//! Checks of a scene's meaning, beyond each field's range ([`Scene::validate`] checks
//! those): coordinates the renderer can represent, a bounce filter that selects NLOS
//! light, and a capture that sees the hidden objects. A scene that would render all
//! zeros is refused; one that loses part of its signal gets a warning naming the share.

use super::{CaptureType, LaserEmission, Scene};
use crate::error::{Error, Result};
use glam::Vec3;
use std::path::Path;

/// Largest vertex coordinate accepted (m). NLOS scenes span metres (the far-field
/// stability test goes to 100 km); at 1000 km an `f32` position resolves 6 cm, coarser
/// than any time bin, and beyond 1e18 m the BVH builder's surface areas overflow `f32`
/// (a `set_vertices(V * 1e30)` used to panic inside obvhs).
pub const MAX_COORD: f32 = 1.0e6;

/// The first vertex that is not finite or lies farther than [`MAX_COORD`] along an axis.
pub fn bad_vertex(positions: &[Vec3]) -> Option<(usize, Vec3)> {
    positions
        .iter()
        .position(|p| !(p.is_finite() && p.abs().max_element() <= MAX_COORD))
        .map(|i| (i, positions[i]))
}

/// The message for [`bad_vertex`]'s find, for `what` ("objects[0] (letter)").
pub fn bad_vertex_message(what: &str, (i, p): (usize, Vec3)) -> String {
    if p.is_finite() {
        format!(
            "{what}: vertex {i} is at {p}, more than {MAX_COORD} m from the origin along an axis (Umbra works in metres)"
        )
    } else {
        format!("{what}: vertex {i} is not finite ({p})")
    }
}

/// The largest power a laser may deliver to its wall spot (W): [`Scene::validate`].
pub const MAX_SPOT_POWER: f32 = 1e26;

/// The largest power the laser delivers to a spot of this capture (W).
pub fn max_spot_power(scene: &Scene) -> f32 {
    let n_w = scene.wall.normal();
    match scene.capture {
        CaptureType::Single => scene.laser.power_at(scene.laser.target, n_w),
        _ => (0..scene.scan.len())
            .map(|i| scene.laser.power_at(scene.scan.point(i), n_w))
            .fold(0.0, |a: f32, p| if p.is_nan() { p } else { a.max(p) }),
    }
}

/// The spot's power must leave the transient room in `f32`: the rest of the
/// measurement equation (BRDFs, the geometry factors of surfaces millimetres apart,
/// a bin's `1/Δ`) can multiply it by up to ~1e12, and `f32` ends at 3.4e38.
pub(super) fn spot_power(scene: &Scene, err: &dyn Fn(&str, String) -> Result<()>) -> Result<()> {
    let p = max_spot_power(scene);
    if p.is_finite() && p <= MAX_SPOT_POWER {
        return Ok(());
    }
    let (field, value) = match scene.laser.emission {
        LaserEmission::Power(p) => ("laser.power", p),
        LaserEmission::Irradiance { irradiance, .. } => ("laser.irradiance", irradiance),
    };
    err(
        field,
        format!(
            "{value:e} delivers {p:e} W to the wall spot, more than {MAX_SPOT_POWER:e} W: the transient would overflow float32 (max 3.4e38); the output is linear in the laser's power, so scale it afterwards"
        ),
    )
}

/// Refuses what would render nothing or cannot be represented (called by
/// [`Scene::validate`]).
pub(super) fn check(scene: &Scene, origin: &Path) -> Result<()> {
    for (i, o) in scene.objects.iter().enumerate() {
        if let Some(bad) = bad_vertex(&o.mesh.positions) {
            let what = format!("objects[{i}] ({})", o.name);
            return Err(Error::scene(origin, bad_vertex_message(&what, bad)));
        }
    }
    if let Some(f) = scene.render.filter_bounces {
        let max = scene.render.max_bounces;
        if f < 3 || f > max {
            return Err(Error::field(
                origin,
                "render.filter_bounces",
                format!(
                    "{f} selects no NLOS light: paths from the laser spot to the sensor point through a hidden surface have from 3 to {} bounces here (max_depth), so the render would be zero",
                    if max == u32::MAX { "any number of".to_string() } else { max.to_string() }
                ),
            ));
        }
    }
    let off = off_wall_share(scene);
    if off.exact && off.share >= 1.0 {
        return Err(Error::field(
            origin,
            "scan",
            "every scan point lies outside the relay wall: the render would be zero".to_string(),
        ));
    }
    if scene.capture == CaptureType::Single && !on_wall(scene, scene.laser.target) {
        return Err(Error::field(
            origin,
            "laser.target",
            format!(
                "the laser spot {} lies outside the relay wall: the render would be zero",
                scene.laser.target
            ),
        ));
    }
    // Objects wholly behind (or in) the wall plane are warned about; if that is all
    // there is, nothing can be rendered.
    let all_behind = (0..scene.objects.len()).all(|i| behind_wall_share(scene, i) >= 1.0);
    if !scene.objects.is_empty() && all_behind {
        let names: Vec<String> = (scene.objects.iter().enumerate())
            .map(|(i, o)| format!("objects[{i}] ({})", o.name))
            .collect();
        return Err(Error::scene(
            origin,
            format!(
                "{} {} entirely behind or in the relay wall's plane (the hidden scene is on the side of the wall's normal, {}): the render would be zero",
                names.join(", "),
                if names.len() == 1 { "lies" } else { "lie" },
                scene.wall.normal()
            ),
        ));
    }
    Ok(())
}

/// Warnings for a capture that loses part of its signal: scan points off the wall,
/// hidden objects partly behind it.
pub(super) fn warnings(scene: &Scene) -> Vec<String> {
    let mut out = Vec::new();
    let off = off_wall_share(scene);
    if off.share > 0.0 {
        out.push(format!(
            "scan: {}{:.1} % of the scan points lie outside the relay wall and measure nothing (the scan rectangle is {:.2} x {:.2} m, the wall {:.2} x {:.2} m)",
            if off.exact { "" } else { "about " },
            100.0 * off.share,
            scene.scan.axis_u.length(),
            scene.scan.axis_v.length(),
            scene.wall.axis_u.length(),
            scene.wall.axis_v.length()
        ));
    }
    for (i, o) in scene.objects.iter().enumerate() {
        let behind = behind_wall_share(scene, i);
        if behind > 0.0 {
            out.push(format!(
                "objects[{i}] ({}): {:.1} % of its area lies behind or in the relay wall's plane and renders nothing",
                o.name,
                100.0 * behind
            ));
        }
    }
    out
}

/// Is `p` (on the wall's plane) within the wall rectangle?
fn on_wall(scene: &Scene, p: Vec3) -> bool {
    let w = &scene.wall;
    let d = p - w.center;
    let tol = 1e-4;
    [w.axis_u, w.axis_v]
        .iter()
        .all(|a| (d.dot(*a) / a.length_squared()).abs() <= 0.5 + tol)
}

/// The share of the scan points outside the wall rectangle; `exact` unless the scan's
/// axes are oblique to the wall's, when it is estimated on at most 1024 x 1024 points.
struct OffWall {
    share: f64,
    exact: bool,
}

fn off_wall_share(scene: &Scene) -> OffWall {
    let (s, w) = (&scene.scan, &scene.wall);
    let (nx, ny) = (s.nx.max(1), s.ny.max(1));
    // With the scan's x axis orthogonal to the wall's v axis and its y axis orthogonal
    // to the wall's u axis (the usual case, mirrored axes included), a point's wall u
    // depends on its column only and its wall v on its row only: the share factorises,
    // and on each axis the points on the wall form one run, counted in closed form.
    let tol =
        1e-4 * s.axis_u.length().max(s.axis_v.length()) * w.axis_u.length().max(w.axis_v.length());
    if s.axis_u.dot(w.axis_v).abs() <= tol && s.axis_v.dot(w.axis_u).abs() <= tol {
        let cols = on_wall_run(nx, s.center - w.center, s.axis_u, w.axis_u) / f64::from(nx);
        let rows = on_wall_run(ny, s.center - w.center, s.axis_v, w.axis_v) / f64::from(ny);
        return OffWall {
            share: 1.0 - cols * rows,
            exact: true,
        };
    }
    let (kx, ky) = (nx.min(1024), ny.min(1024));
    let pick = |k: u32, of: u32, n: u32| {
        if of <= 1 {
            0
        } else {
            (u64::from(k) * u64::from(n - 1) / u64::from(of - 1)) as usize
        }
    };
    let mut off = 0usize;
    for j in 0..ky {
        for i in 0..kx {
            let index = pick(j, ky, ny) * nx as usize + pick(i, kx, nx);
            off += usize::from(!on_wall(scene, s.point(index)));
        }
    }
    OffWall {
        share: off as f64 / (f64::from(kx) * f64::from(ky)),
        exact: kx == nx && ky == ny,
    }
}

/// How many of the `n` points `offset + ((k + ½)/n − ½) along` (k = 0..n) have a wall
/// coordinate `(· · axis) / |axis|²` within ±½: an interval of `k`.
fn on_wall_run(n: u32, offset: Vec3, along: Vec3, axis: Vec3) -> f64 {
    let len2 = f64::from(axis.length_squared());
    let a = f64::from(offset.dot(axis)) / len2;
    let b = f64::from(along.dot(axis)) / len2;
    let h = 0.5 + 1e-4;
    let n = f64::from(n);
    if b.abs() < 1e-12 {
        return if a.abs() <= h { n } else { 0.0 };
    }
    let (t0, t1) = ((-h - a) / b, (h - a) / b);
    let (t_lo, t_hi) = (t0.min(t1), t0.max(t1));
    // t_k = (k + ½)/n − ½  <=>  k = (t + ½) n − ½.
    let k_lo = ((t_lo + 0.5) * n - 0.5).max(0.0).ceil();
    let k_hi = ((t_hi + 0.5) * n - 0.5).min(n - 1.0).floor();
    (k_hi - k_lo + 1.0).max(0.0)
}

/// Share of object `i`'s area that lies behind or in the wall plane (each triangle
/// clipped by the plane).
fn behind_wall_share(scene: &Scene, i: usize) -> f64 {
    let mesh = &scene.objects[i].mesh;
    let (mut behind, mut total) = (0.0f64, 0.0f64);
    for t in 0..mesh.triangles.len() {
        let tri = mesh.triangle(t);
        // Both areas by the same f64 sum, so a mesh wholly behind has a share of exactly 1
        // (the f32 `TriMesh::area` made it 0.99999, and the refusal never fired).
        total += area_behind(tri, |_| f32::NEG_INFINITY);
        behind += area_behind(tri, |p| scene.wall.height_above(p));
    }
    if total > 0.0 {
        behind / total
    } else {
        0.0
    }
}

/// Area (m²) of the part of triangle `tri` where `height <= 0` (up to 1 µm: a face in
/// the plane counts as behind it).
fn area_behind(tri: [Vec3; 3], height: impl Fn(Vec3) -> f32) -> f64 {
    let h = tri.map(|p| f64::from(height(p)) - 1e-6);
    let mut poly: Vec<glam::DVec3> = Vec::with_capacity(4);
    for k in 0..3 {
        let (a, b) = (tri[k].as_dvec3(), tri[(k + 1) % 3].as_dvec3());
        let (ha, hb) = (h[k], h[(k + 1) % 3]);
        if ha <= 0.0 {
            poly.push(a);
        }
        if (ha <= 0.0) != (hb <= 0.0) {
            poly.push(a + (b - a) * (ha / (ha - hb)));
        }
    }
    (1..poly.len().saturating_sub(1))
        .map(|k| 0.5 * (poly[k] - poly[0]).cross(poly[k + 1] - poly[0]).length())
        .sum()
}
