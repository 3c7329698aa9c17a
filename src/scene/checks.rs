//! Checks of a scene's meaning, beyond each field's range ([`Scene::validate`] checks
//! those): coordinates the renderer can represent, a bounce filter that selects NLOS
//! light, and a capture that sees the hidden objects. A scene that would render all
//! zeros is refused; one that loses part of its signal gets a warning naming the share.

use super::{CaptureType, Scene};
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
    if off >= 1.0 {
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
    if off > 0.0 {
        out.push(format!(
            "scan: {:.1} % of the scan points lie outside the relay wall and measure nothing (the scan rectangle is {:.2} x {:.2} m, the wall {:.2} x {:.2} m)",
            100.0 * off,
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

/// Share of the scan points outside the wall rectangle.
fn off_wall_share(scene: &Scene) -> f64 {
    let s = &scene.scan;
    // The grid's rows and columns are off the wall independently, so count per axis
    // rather than per point (a 100000 x 100000 scan is 1e10 points).
    let inside = |n: u32, along: Vec3, axis: Vec3| {
        (0..n)
            .filter(|&k| {
                let t = (k as f32 + 0.5) / n as f32 - 0.5;
                let d = s.center - scene.wall.center + t * along;
                (d.dot(axis) / axis.length_squared()).abs() <= 0.5 + 1e-4
            })
            .count() as f64
    };
    let w = &scene.wall;
    let (nx, ny) = (s.nx.max(1), s.ny.max(1));
    // With the scan's x axis across the wall's v and its y axis across the wall's u
    // (the usual case), a point's wall u depends on its column only and its wall v on
    // its row only, so the share factorises.
    let tol =
        1e-4 * s.axis_u.length().max(s.axis_v.length()) * w.axis_u.length().max(w.axis_v.length());
    if s.axis_u.dot(w.axis_v).abs() <= tol && s.axis_v.dot(w.axis_u).abs() <= tol {
        let cols = inside(nx, s.axis_u, w.axis_u) / nx as f64;
        let rows = inside(ny, s.axis_v, w.axis_v) / ny as f64;
        return 1.0 - cols * rows;
    }
    let n = s.len().min(1 << 20);
    let step = (s.len() / n).max(1);
    let off = (0..n)
        .filter(|&k| !on_wall(scene, s.point(k * step)))
        .count();
    off as f64 / n as f64
}

/// Share of object `i`'s area that lies behind or in the wall plane (each triangle
/// clipped by the plane).
fn behind_wall_share(scene: &Scene, i: usize) -> f64 {
    let mesh = &scene.objects[i].mesh;
    let (mut behind, mut total) = (0.0f64, 0.0f64);
    for t in 0..mesh.triangles.len() {
        let tri = mesh.triangle(t);
        total += f64::from(mesh.area(t));
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
