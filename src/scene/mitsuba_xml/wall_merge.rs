//! The relay wall can be larger than what mitransient scans: mitransient's
//! `nlos_capture_meter` scans the whole rectangle it sits in, so a wall wider than its
//! scan area is written as the scanned rectangle (carrying the sensor) plus plain
//! rectangles of the same diffuse BSDF around it (the exporter does this). Reading
//! such a file, those rectangles are merged back into one relay wall: the same surface,
//! so the same scene. Merged only when every candidate rectangle (one-sided,
//! Lambertian, the wall's albedo, in the wall's plane facing its way, edges along the
//! wall's axes) together with the wall tiles one rectangle exactly; otherwise they stay
//! hidden objects.

use super::params::Cx;
use crate::scene::{HiddenObject, Reflectance, RelayWall};

/// `[s0, s1] x [t0, t1]` in metres along the wall's unit axes, from its centre.
type Span = [f64; 4];

/// Merges the rectangles (`is_rect`) that extend the wall; returns the wall and the
/// hidden objects left.
pub(super) fn merge(
    cx: &mut Cx,
    wall: RelayWall,
    objects: Vec<(HiddenObject, bool)>,
) -> (RelayWall, Vec<HiddenObject>) {
    let (u, v) = (wall.axis_u.as_dvec3(), wall.axis_v.as_dvec3());
    let (uh, vh) = (u.normalize(), v.normalize());
    let n = uh.cross(vh);
    let c = wall.center.as_dvec3();
    let scale = u.length() + v.length();
    let orthogonal = uh.dot(vh).abs() < 1e-6;
    let span_of = |o: &HiddenObject| -> Option<Span> {
        if o.two_sided || o.reflectance != Reflectance::Lambertian || o.albedo != wall.albedo {
            return None;
        }
        let m = &o.mesh;
        if m.positions.len() != 4 || m.triangles.len() != 2 {
            return None;
        }
        let [a, b, cc] = m.triangle(0);
        let front = (b - a).cross(cc - a).as_dvec3().normalize_or_zero();
        if front.dot(n) < 1.0 - 1e-6 {
            return None;
        }
        let mut sp = [f64::MAX, f64::MIN, f64::MAX, f64::MIN];
        let mut corners = Vec::with_capacity(4);
        for p in &m.positions {
            let d = p.as_dvec3() - c;
            if d.dot(n).abs() > 1e-6 * scale {
                return None;
            }
            let (s, t) = (d.dot(uh), d.dot(vh));
            corners.push((s, t));
            sp = [sp[0].min(s), sp[1].max(s), sp[2].min(t), sp[3].max(t)];
        }
        // Every corner on the bounding box's corners: edges along the wall's axes.
        let tol = 1e-6 * scale;
        let on_corner = |&(s, t): &(f64, f64)| {
            ((s - sp[0]).abs() <= tol || (s - sp[1]).abs() <= tol)
                && ((t - sp[2]).abs() <= tol || (t - sp[3]).abs() <= tol)
        };
        corners.iter().all(on_corner).then_some(sp)
    };
    let spans: Vec<Option<Span>> = objects
        .iter()
        .map(|(o, is_rect)| {
            if *is_rect && orthogonal {
                span_of(o)
            } else {
                None
            }
        })
        .collect();
    let own: Span = {
        let (hw, hh) = (u.length() / 2.0, v.length() / 2.0);
        [-hw, hw, -hh, hh]
    };
    let mut all: Vec<Span> = vec![own];
    all.extend(spans.iter().flatten());
    let done = |objects: Vec<(HiddenObject, bool)>| objects.into_iter().map(|o| o.0).collect();
    if all.len() == 1 {
        return (wall, done(objects));
    }
    let area = |s: &Span| (s[1] - s[0]) * (s[3] - s[2]);
    let bb = all
        .iter()
        .fold([f64::MAX, f64::MIN, f64::MAX, f64::MIN], |b, s| {
            [
                b[0].min(s[0]),
                b[1].max(s[1]),
                b[2].min(s[2]),
                b[3].max(s[3]),
            ]
        });
    let overlap = |a: &Span, b: &Span| {
        let w = (a[1].min(b[1]) - a[0].max(b[0])).max(0.0);
        let h = (a[3].min(b[3]) - a[2].max(b[2])).max(0.0);
        w * h
    };
    let eps = 1e-6 * area(&bb);
    let disjoint =
        (0..all.len()).all(|i| (i + 1..all.len()).all(|j| overlap(&all[i], &all[j]) <= eps));
    let tiles = (all.iter().map(area).sum::<f64>() - area(&bb)).abs() <= eps;
    if !(disjoint && tiles) {
        return (wall, done(objects));
    }
    let merged = all.len() - 1;
    let mid = c + uh * ((bb[0] + bb[1]) / 2.0) + vh * ((bb[2] + bb[3]) / 2.0);
    let wall = RelayWall {
        center: mid.as_vec3(),
        axis_u: (uh * (bb[1] - bb[0])).as_vec3(),
        axis_v: (vh * (bb[3] - bb[2])).as_vec3(),
        albedo: wall.albedo,
    };
    let rest = objects
        .into_iter()
        .zip(&spans)
        .filter(|(_, s)| s.is_none())
        .map(|(o, _)| o.0)
        .collect();
    cx.warnings.push(format!(
        "{}: {merged} rectangle(s) in the relay wall's plane with its BSDF extend it: read as one relay wall of {:.6} x {:.6} m around the scanned {:.6} x {:.6} m",
        cx.origin.display(),
        bb[1] - bb[0],
        bb[3] - bb[2],
        u.length(),
        v.length()
    ));
    (wall, rest)
}
