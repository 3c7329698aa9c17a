//! Which faces of a fitted mesh the measurement says anything about.
//!
//! A face contributes to measurement `m` only through paths laser spot `l_m` → face →
//! sensor point `s_m` whose two hidden legs are clear (DESIGN §2: the three-bounce
//! integrand carries `V(l, x) V(x, s)`). A face that no measurement both lights and
//! sees has no term in the loss: its vertices move only under the regulariser and its
//! albedo keeps whatever value it had, so the fit says nothing about it. With one laser
//! spot this is common: a surface's continuation in its own shadow from the spot (a
//! tilted plate folding back behind itself) is free, and grows into flaps far from any
//! true surface. `mesh.obj` leaves such faces out, as it leaves out the faces the data
//! drove dark; `mesh_all.obj` keeps every face.
//!
//! A face counts as supported when one of a few points on it (the centroid and three
//! points toward its corners) has a measurement, among up to [`MAX_MEASUREMENTS`] spread
//! over the scan, with both legs unoccluded by the fitted mesh, the point in front of
//! the wall, and (for a one-sided face) the wall points in front of the face. Under
//! `visibility = "none"` the model casts no shadow rays, every face is in the loss, and
//! every face is supported.

use crate::geometry::accel::SceneGeometry;
use crate::scene::{Scene, Visibility};
use glam::Vec3;
use rayon::prelude::*;

/// Measurements tested per face point, spread evenly over the capture's.
pub const MAX_MEASUREMENTS: usize = 256;

/// Barycentric coordinates of the points tested on each face.
const POINTS: [[f32; 3]; 4] = [
    [1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0],
    [2.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0],
    [1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0],
    [1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0],
];

/// One flag per face of `scene`'s first hidden object (the fitted mesh, as
/// `objective::hidden_object` puts it there): whether some measurement lights and sees
/// it. `geom` is `SceneGeometry::build(scene)`.
pub fn supported_faces(scene: &Scene, geom: &SceneGeometry) -> Vec<bool> {
    let Some(object) = scene.objects.first() else {
        return Vec::new();
    };
    let n_faces = object.mesh.triangles.len();
    if scene.render.visibility == Visibility::None {
        return vec![true; n_faces];
    }
    let n = scene.num_measurements();
    let stride = n.div_ceil(MAX_MEASUREMENTS).max(1);
    let pairs: Vec<(Vec3, Vec3)> = (0..n)
        .step_by(stride)
        .map(|m| scene.measurement_points(m))
        .collect();
    let normal = scene.wall.normal();
    let two_sided = object.two_sided;
    (0..n_faces)
        .into_par_iter()
        .map(|t| {
            let [a, b, c] = object.mesh.triangle(t);
            let face_n = (b - a).cross(c - a);
            POINTS.iter().any(|w| {
                let x = a * w[0] + b * w[1] + c * w[2];
                let faces = |p: Vec3| two_sided || face_n.dot(p - x) > 0.0;
                let clear = |p: Vec3| (x - p).dot(normal) > 0.0 && faces(p) && !geom.occluded(p, x);
                pairs.iter().any(|&(l, s)| clear(l) && (s == l || clear(s)))
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fit::objective::hidden_object;
    use optim::Mesh;

    fn quad(z: f64, x0: f64, x1: f64) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
        let v = vec![[x0, -0.1, z], [x1, -0.1, z], [x1, 0.1, z], [x0, 0.1, z]];
        (v, vec![[0, 1, 2], [0, 2, 3]])
    }

    /// A plate in front of a single laser spot shadows a second plate straight behind
    /// it: the back plate's faces are unsupported, the front plate's supported; with
    /// visibility none, both are.
    #[test]
    fn a_plate_in_the_shadow_of_another_is_unsupported() {
        let mut scene = crate::scene::default::default_scene().unwrap();
        scene.capture = crate::scene::CaptureType::Single;
        scene.laser.target = Vec3::ZERO;
        scene.render.visibility = Visibility::Centroid;
        // the scan: a small patch around the spot, so every sensor point is shadowed too
        scene.scan.axis_u *= 0.05 / scene.scan.axis_u.length();
        scene.scan.axis_v *= 0.05 / scene.scan.axis_v.length();
        scene.scan.center = Vec3::ZERO;
        let (mut v, mut f) = quad(0.5, -0.3, 0.3);
        let (v2, f2) = quad(0.9, -0.05, 0.05);
        f.extend(f2.iter().map(|t| t.map(|i| i + v.len() as u32)));
        v.extend(v2);
        let mesh = Mesh::new(v, f);
        scene.objects = vec![hidden_object(&mesh, 0.8, true, Default::default())];
        let geom = SceneGeometry::build(&scene);
        assert_eq!(
            supported_faces(&scene, &geom),
            vec![true, true, false, false]
        );
        let kept = mesh.with_faces(&supported_faces(&scene, &geom));
        assert_eq!((kept.faces.len(), kept.vertices.len()), (2, 4));
        scene.render.visibility = Visibility::None;
        let geom = SceneGeometry::build(&scene);
        assert!(supported_faces(&scene, &geom).iter().all(|&k| k));
    }
}
