//! Why a render came out zero everywhere.
//!
//! A render (or a gradient) that is zero in every bin is almost never what a user meant:
//! the film window misses every return, the only object is one-sided and faces away, there is no
//! hidden object at all.
//! [`zero_reason`] names the first cause it can prove from the scene, so every entry point
//! (the CLI's `render`, `grad`, `gradcheck`; Python's `render` and `grad`) warns with the
//! reason instead of writing silent zeros.
//!
//! The film check bounds the three-bounce optical path length (OPL) of every measurement
//! by the hidden geometry's bounding box `B`:
//!
//! `min_m dist(x_l, B) + dist(B, x_s)  <=  opl  <=  max_m maxdist(x_l, B) + maxdist(B, x_s)`
//!
//! (plus the detector and laser legs when `account_first_and_last_bounces` is set). Paths
//! with more bounces are longer than the lower bound too, so a film ending before it
//! records nothing; a film starting after the upper bound records no three-bounce light.

use crate::scene::Scene;
use glam::Vec3;

/// Whether every value of `data` is zero (or the slice is empty).
pub fn all_zero(data: &[f32]) -> bool {
    data.iter().all(|&v| v == 0.0)
}

/// The reason a render of `scene` is zero everywhere, as one sentence that
/// names the field to change.
pub fn zero_reason(scene: &Scene) -> String {
    if scene.total_hidden_triangles() == 0 {
        return "the scene has no hidden objects (objects): there is nothing to render".to_string();
    }
    if let Some(r) = film_miss(scene) {
        return r;
    }
    if scene
        .objects
        .iter()
        .all(|o| !o.two_sided && faces_away(scene, o))
    {
        return "every hidden object is one-sided (two_sided = false) and faces away from the relay wall: flip its faces or set two_sided = true".to_string();
    }
    if let Some(r) = legs_blocked(scene) {
        return r;
    }
    let t = &scene.render.techniques;
    if scene.laser.spot_radius > 0.0 && !t.laser_sampling {
        return format!(
            "no sampled path landed on the laser spot (radius {} m): with laser sampling off only BSDF-sampled paths reach it, which takes many samples; turn render.laser_sampling on or raise spp",
            scene.laser.spot_radius
        );
    }
    "no light path reached a sensor point: the hidden objects may be occluded from the wall, a Monte Carlo render may have too few samples (spp), or the signal is below float32's range".to_string()
}

/// Most measurements whose visible legs are traced for the cause.
const MAX_LEG_CHECKS: usize = 1 << 16;

/// Whether the laser's or the detector's line to the wall is blocked for every
/// measurement (`render.visible_legs`: the devices stand in the hidden volume).
fn legs_blocked(scene: &Scene) -> Option<String> {
    let n = scene.num_measurements();
    if !scene.render.visible_legs || n == 0 || n > MAX_LEG_CHECKS {
        return None;
    }
    let geom = crate::geometry::SceneGeometry::build(scene);
    let blocked = (0..n).all(|m| {
        let (x_l, x_s) = scene.measurement_points(m);
        geom.occluded(scene.laser.origin, x_l) || geom.occluded(x_s, scene.detector.origin)
    });
    blocked.then(|| format!(
        "the hidden objects block the laser's or the detector's line to the wall at every scan point (laser.origin {}, detector.origin {}): move the devices out of the hidden volume, or set render.visible_legs = false for a capture rectified to the wall",
        scene.laser.origin, scene.detector.origin
    ))
}

/// The film window against the geometry's three-bounce OPL range, if it misses it.
fn film_miss(scene: &Scene) -> Option<String> {
    let boxes = boxes(scene)?;
    let (opl_min, opl_max) = three_bounce_range(scene, &boxes);
    let start = f64::from(scene.film.start_opl);
    let end = start + f64::from(scene.film.temporal_bins) * f64::from(scene.film.bin_width_opl);
    if end < opl_min {
        Some(format!(
            "the film (film.start_opl = {start} m, {} bins of {} m) ends at {end:.4} m of OPL, before the earliest return from the hidden objects (at least {opl_min:.4} m)",
            scene.film.temporal_bins, scene.film.bin_width_opl
        ))
    } else if start > opl_max {
        Some(format!(
            "the film starts at film.start_opl = {start} m of OPL, after the latest three-bounce return from the hidden objects (at most {opl_max:.4} m)"
        ))
    } else {
        None
    }
}

/// Most point-box pairs worked through: beyond, one box for the whole geometry.
const MAX_PAIRS: usize = 20_000_000;

/// Boxes around the hidden geometry: one per triangle (a tight bound) while the scan
/// times the triangles stays under [`MAX_PAIRS`], else one around everything.
fn boxes(scene: &Scene) -> Option<Vec<(Vec3, Vec3)>> {
    let tris = scene.total_hidden_triangles();
    let per_triangle = tris.saturating_mul(scene.scan.len()) <= MAX_PAIRS;
    let mut all = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    let mut out = Vec::new();
    for o in &scene.objects {
        for t in 0..o.mesh.triangles.len() {
            let [a, b, c] = o.mesh.triangle(t);
            let (lo, hi) = (a.min(b).min(c), a.max(b).max(c));
            all = (all.0.min(lo), all.1.max(hi));
            if per_triangle {
                out.push((lo, hi));
            }
        }
    }
    if !per_triangle {
        out.push(all);
    }
    (tris > 0).then_some(out)
}

/// `(min, max)` three-bounce OPL over the measurements, through the geometry's `boxes`:
/// a path through a point of box `B` is at least `dist(x_l, B) + dist(B, x_s)` long and
/// at most the two farthest distances.
fn three_bounce_range(scene: &Scene, boxes: &[(Vec3, Vec3)]) -> (f64, f64) {
    use crate::scene::CaptureType;
    let near = |p: Vec3, (lo, hi): (Vec3, Vec3)| f64::from((p.clamp(lo, hi) - p).length());
    let far =
        |p: Vec3, (lo, hi): (Vec3, Vec3)| f64::from((p - lo).abs().max((p - hi).abs()).length());
    let afl = scene.account_first_and_last_bounces;
    let laser_leg = |x_l: Vec3| afl.then(|| (x_l - scene.laser.origin).length());
    let sensor_leg = |x_s: Vec3| afl.then(|| (x_s - scene.detector.origin).length());
    let leg = |l: Option<f32>| f64::from(l.unwrap_or(0.0));
    let points: Vec<Vec3> = (0..scene.scan.len()).map(|i| scene.scan.point(i)).collect();
    let (mut opl_min, mut opl_max) = (f64::INFINITY, 0.0f64);
    match scene.capture {
        CaptureType::Single | CaptureType::Confocal => {
            for &x_s in &points {
                let x_l = match scene.capture {
                    CaptureType::Single => scene.laser.target,
                    _ => x_s,
                };
                let legs = leg(laser_leg(x_l)) + leg(sensor_leg(x_s));
                for &b in boxes {
                    opl_min = opl_min.min(near(x_l, b) + near(x_s, b) + legs);
                    opl_max = opl_max.max(far(x_l, b) + far(x_s, b) + legs);
                }
            }
        }
        // Every laser point with every sensor point: the extremes of each end apart.
        CaptureType::Exhaustive => {
            let ends =
                |f: &dyn Fn(Vec3, (Vec3, Vec3)) -> f64, l: &dyn Fn(Vec3) -> f64, lo: bool| {
                    let all = points
                        .iter()
                        .flat_map(|&p| boxes.iter().map(move |&b| (p, b)));
                    let vals = all.map(|(p, b)| f(p, b) + l(p));
                    if lo {
                        vals.fold(f64::INFINITY, f64::min)
                    } else {
                        vals.fold(0.0, f64::max)
                    }
                };
            let (ll, sl) = (|p| leg(laser_leg(p)), |p| leg(sensor_leg(p)));
            opl_min = ends(&near, &ll, true) + ends(&near, &sl, true);
            opl_max = ends(&far, &ll, false) + ends(&far, &sl, false);
        }
    }
    (opl_min, opl_max)
}

/// Whether every face of `o` turns its front away from the wall (the hidden side is the
/// side of the wall's normal, so a face the wall sees has a normal against it).
fn faces_away(scene: &Scene, o: &crate::scene::HiddenObject) -> bool {
    let n_w = scene.wall.normal();
    (0..o.mesh.triangles.len()).all(|t| {
        let [a, b, c] = o.mesh.triangle(t);
        (b - a).cross(c - a).dot(n_w) >= 0.0
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_zero_sees_one_value() {
        assert!(all_zero(&[0.0, -0.0]));
        assert!(!all_zero(&[0.0, 1e-30]));
    }
}
