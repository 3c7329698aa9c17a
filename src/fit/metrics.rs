//! How close a fitted surface is to the true one: the symmetric Chamfer distance
//!
//! `C(A, B) = ½ (mean_{a ∈ S_A} d(a, B) + mean_{b ∈ S_B} d(b, A))`,
//!
//! `S_X` a fixed, area-stratified set of points on surface `X` and `d(p, Y)` the exact
//! distance from `p` to the nearest point of `Y`'s triangles (m). Also the one-sided
//! means and the 90th percentiles, since a fit can cover the truth well and still have
//! a stray flap (or the reverse).
//!
//! NLOS data constrain only the surface the wall sees: the back of a sphere or the
//! inside of a concave fold returns no light, whether it belongs to the true surface or
//! to the fitted one. [`chamfer_seen`] therefore measures each direction over the points
//! of its source surface that face, and are unoccluded from, at least one of nine scan
//! points (the scan rectangle's corners, edge midpoints and centre), against the whole
//! of the other surface. With one laser spot (single capture) a point must also face,
//! and be unoccluded from, the spot: surface the laser does not light returns nothing
//! either (the side of a sphere past the spot's terminator, a surface's continuation in
//! its own shadow); confocal and exhaustive captures light from the scan points
//! themselves.

use crate::geometry::SceneGeometry;
use crate::scene::{CaptureType, Scene};
use glam::{DVec3, Vec3};
use optim::Mesh;
use rayon::prelude::*;

/// Chamfer distance and its parts (m).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chamfer {
    pub symmetric: f64,
    /// Mean distance from the fitted surface to the truth.
    pub fit_to_truth: f64,
    /// Mean distance from the truth to the fitted surface.
    pub truth_to_fit: f64,
    pub fit_to_truth_p90: f64,
    pub truth_to_fit_p90: f64,
}

fn tri(m: &Mesh, f: usize) -> [DVec3; 3] {
    m.faces[f].map(|i| DVec3::from_array(m.vertices[i as usize]))
}

/// `n` points on `m`, area-weighted: each triangle gets points in proportion to its area
/// on a low-discrepancy (R2) sequence of barycentric coordinates.
pub fn sample_surface(m: &Mesh, n: usize) -> Vec<DVec3> {
    sample_faces(m, n).into_iter().map(|(p, _)| p).collect()
}

/// [`sample_surface`]'s points with the face each lies on.
fn sample_faces(m: &Mesh, n: usize) -> Vec<(DVec3, usize)> {
    let areas: Vec<f64> = (0..m.faces.len())
        .map(|f| {
            let [a, b, c] = tri(m, f);
            0.5 * (b - a).cross(c - a).length()
        })
        .collect();
    let total: f64 = areas.iter().sum();
    if total <= 0.0 || n == 0 {
        return Vec::new();
    }
    let mut points = Vec::with_capacity(n);
    let (g1, g2) = (0.754_877_666_246_692_8, 0.569_840_290_998_053_3);
    let mut carry = 0.0;
    let mut k = 0usize;
    for (f, a) in areas.iter().enumerate() {
        carry += a / total * n as f64;
        let count = carry.floor() as usize;
        carry -= count as f64;
        let [p0, p1, p2] = tri(m, f);
        for _ in 0..count {
            k += 1;
            let (mut u, mut v) = ((0.5 + g1 * k as f64).fract(), (0.5 + g2 * k as f64).fract());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            points.push((p0 + u * (p1 - p0) + v * (p2 - p0), f));
        }
    }
    points
}

/// Distance from `p` to the triangle `[a, b, c]` (the remesher's closest-point query).
pub fn point_triangle_distance(p: DVec3, [a, b, c]: [DVec3; 3]) -> f64 {
    let (q, _) =
        optim::remesh::closest_on_triangle(p.to_array(), a.to_array(), b.to_array(), c.to_array());
    p.distance(DVec3::from_array(q))
}

pub(crate) fn distances(points: &[DVec3], m: &Mesh) -> Vec<f64> {
    let tris: Vec<[DVec3; 3]> = (0..m.faces.len()).map(|f| tri(m, f)).collect();
    points
        .par_iter()
        .map(|&p| {
            tris.iter()
                .map(|&t| point_triangle_distance(p, t))
                .fold(f64::INFINITY, f64::min)
        })
        .collect()
}

pub(crate) fn mean_p90(mut d: Vec<f64>) -> (f64, f64) {
    if d.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    d.sort_by(f64::total_cmp);
    (mean, d[(0.9 * (d.len() - 1) as f64).round() as usize])
}

/// The Chamfer distance between `fit` and `truth` with `n` sample points on each.
pub fn chamfer(fit: &Mesh, truth: &Mesh, n: usize) -> Chamfer {
    let (f2t, f2t90) = mean_p90(distances(&sample_surface(fit, n), truth));
    let (t2f, t2f90) = mean_p90(distances(&sample_surface(truth, n), fit));
    Chamfer {
        symmetric: 0.5 * (f2t + t2f),
        fit_to_truth: f2t,
        truth_to_fit: t2f,
        fit_to_truth_p90: f2t90,
        truth_to_fit_p90: t2f90,
    }
}

/// The points of `n` samples on `mesh` that face, and are unoccluded from, one of the
/// nine viewpoints on `scene`'s scan rectangle and, for a single capture, the laser spot,
/// with `mesh` as the scene's only hidden object; and their share of the samples.
pub(crate) fn seen_samples(
    mesh: &Mesh,
    scene: &Scene,
    two_sided: bool,
    n: usize,
) -> (Vec<DVec3>, f64) {
    let scene = Scene {
        objects: vec![super::objective::hidden_object(
            mesh,
            1.0,
            two_sided,
            Default::default(),
        )],
        ..scene.clone()
    };
    let geometry = SceneGeometry::build(&scene);
    let s = &scene.scan;
    let viewpoints: Vec<Vec3> = (0..9)
        .map(|k| {
            let (i, j) = ((k % 3) as f32 - 1.0, (k / 3) as f32 - 1.0);
            s.center + 0.5 * i * s.axis_u + 0.5 * j * s.axis_v
        })
        .collect();
    let samples = sample_faces(mesh, n);
    let seen: Vec<DVec3> = samples
        .par_iter()
        .filter(|(p, f)| {
            let [a, b, c] = tri(mesh, *f);
            let normal = (b - a).cross(c - a).normalize_or_zero().as_vec3();
            let p = p.as_vec3();
            let clear = |x: Vec3| {
                let facing = normal.dot(x - p);
                (facing > 0.0 || (two_sided && facing < 0.0)) && !geometry.occluded(p, x)
            };
            let lit = scene.capture != CaptureType::Single || clear(scene.laser.target);
            lit && viewpoints.iter().any(|&x_s| clear(x_s))
        })
        .map(|(p, _)| *p)
        .collect();
    let share = seen.len() as f64 / samples.len().max(1) as f64;
    (seen, share)
}

/// The Chamfer distance between the parts of `fit` and `truth` that the wall sees
/// (module doc): fit → truth over the fitted surface's seen points (fitted surfaces are
/// two-sided), truth → fit over the truth's (one-sided unless every object of
/// `truth_scene` is two-sided). Also returns the seen shares of the fit's and the
/// truth's area.
pub fn chamfer_seen(
    fit: &Mesh,
    truth: &Mesh,
    truth_scene: &Scene,
    n: usize,
) -> (Chamfer, [f64; 2]) {
    let two_sided = truth_scene.objects.iter().all(|o| o.two_sided);
    let (fit_seen, fit_share) = seen_samples(fit, truth_scene, true, n);
    let (truth_seen, truth_share) = seen_samples(truth, truth_scene, two_sided, n);
    let (f2t, f2t90) = mean_p90(distances(&fit_seen, truth));
    let (t2f, t2f90) = mean_p90(distances(&truth_seen, fit));
    let c = Chamfer {
        symmetric: 0.5 * (f2t + t2f),
        fit_to_truth: f2t,
        truth_to_fit: t2f,
        fit_to_truth_p90: f2t90,
        truth_to_fit_p90: t2f90,
    };
    (c, [fit_share, truth_share])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(z: f64) -> Mesh {
        Mesh::new(
            vec![[0.0, 0.0, z], [1.0, 0.0, z], [1.0, 1.0, z], [0.0, 1.0, z]],
            vec![[0, 1, 2], [0, 2, 3]],
        )
    }

    #[test]
    fn parallel_squares_are_their_gap_apart() {
        let c = chamfer(&square(0.0), &square(0.01), 500);
        assert!((c.symmetric - 0.01).abs() < 1e-12, "{c:?}");
        assert!(chamfer(&square(0.0), &square(0.0), 500).symmetric < 1e-12);
    }

    /// A small plate straight behind a larger one, on the axis through the wall's centre:
    /// the scan's corners see it past the front plate, so confocal it is seen; a single
    /// capture's spot at the centre is shadowed from it, so it is not.
    #[test]
    fn single_capture_counts_only_what_the_spot_lights() {
        let mut scene = crate::scene::default::default_scene().unwrap();
        scene.laser.target = Vec3::ZERO;
        let plate = |z: f64, h: f64| {
            Mesh::new(
                vec![[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]],
                vec![[0, 1, 2], [0, 2, 3]],
            )
        };
        let (front, back) = (plate(0.5, 0.1), plate(1.0, 0.05));
        let mut both = front.clone();
        let base = both.vertices.len() as u32;
        both.vertices.extend(back.vertices.iter());
        both.faces
            .extend(back.faces.iter().map(|f| f.map(|i| i + base)));
        let share_behind = |capture| {
            let scene = Scene {
                capture,
                ..scene.clone()
            };
            let (seen, _) = seen_samples(&both, &scene, true, 4000);
            let behind = sample_surface(&both, 4000)
                .iter()
                .filter(|p| p.z > 0.75)
                .count();
            seen.iter().filter(|p| p.z > 0.75).count() as f64 / behind as f64
        };
        assert!(share_behind(CaptureType::Confocal) > 0.5);
        assert_eq!(share_behind(CaptureType::Single), 0.0);
    }

    #[test]
    fn point_triangle_regions() {
        let t = [DVec3::ZERO, DVec3::X, DVec3::Y];
        assert!((point_triangle_distance(DVec3::new(0.2, 0.2, 0.5), t) - 0.5).abs() < 1e-12);
        assert!(
            (point_triangle_distance(DVec3::new(-1.0, -1.0, 0.0), t) - 2f64.sqrt()).abs() < 1e-12
        );
        assert!(
            (point_triangle_distance(DVec3::new(1.0, 1.0, 0.0), t) - 0.5f64.sqrt()).abs() < 1e-12
        );
        assert!((point_triangle_distance(DVec3::new(0.5, -2.0, 0.0), t) - 2.0).abs() < 1e-12);
    }
}
