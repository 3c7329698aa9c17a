//! Initial meshes for a fit: a plane or a sphere in front of the wall, centred on the
//! scan area, at the depth the measurement's first strong returns imply; and the start a
//! fit takes when none is asked for ([`default_init`]).
//!
//! Depth: the OPL `τ₅₀` at which the transient summed over all scan points first reaches
//! half its maximum above the background (the median of the summed transient over the
//! bins the fit uses, those not zeroed: real captures have a floor of dark counts and
//! ambient light, in the LCT `diffuse_s` capture about as strong as the signal, and the
//! signal fills few bins); a hidden point at distance `d` straight in front of a confocal scan
//! point returns at `τ = 2d`, so `d ≈ τ₅₀ / 2` (for single capture `τ ≈ d_l + d_s`, the
//! same to first order). The first/last legs are removed when the scene counts them.

use crate::geometry::shapes::icosphere;
use crate::scene::Scene;
use glam::Vec3;
use optim::Mesh;
use std::path::Path;

use super::Measurement;

/// Distance of the hidden scene from the wall implied by `measured` (m).
pub fn depth_from_data(scene: &Scene, measured: &[f32]) -> Option<f32> {
    let bins = scene.film.temporal_bins as usize;
    let mut total = vec![0.0f64; bins];
    for row in measured.chunks_exact(bins) {
        for (t, v) in total.iter_mut().zip(row) {
            *t += *v as f64;
        }
    }
    let mut used: Vec<f64> = total.iter().copied().filter(|&v| v != 0.0).collect();
    used.sort_by(f64::total_cmp);
    let background = used.get(used.len() / 2).copied().unwrap_or(0.0).max(0.0);
    let max = total.iter().cloned().fold(0.0, f64::max) - background;
    if max <= 0.0 {
        return None;
    }
    let b = total.iter().position(|&v| v - background >= 0.5 * max)?;
    let mut opl = scene.film.start_opl + (b as f32 + 0.5) * scene.film.bin_width_opl;
    if scene.account_first_and_last_bounces {
        let (x_l, x_s) = scene.measurement_points(0);
        opl -= (scene.laser.origin - x_l).length() + (scene.detector.origin - x_s).length();
    }
    (opl > 0.0).then_some(0.5 * opl)
}

/// The scan area's centre on the wall, the wall normal, and the area's half extents.
fn scan_frame(scene: &Scene) -> (Vec3, Vec3, Vec3, Vec3) {
    let s = &scene.scan;
    (
        s.center,
        scene.wall.normal(),
        0.5 * s.axis_u,
        0.5 * s.axis_v,
    )
}

/// An `n x n` grid of side `size` (fraction of the scan area), parallel to the wall at
/// `depth`, its triangles facing the wall.
pub fn plane(scene: &Scene, depth: f32, size: f32, n: usize) -> Mesh {
    let (c, normal, hu, hv) = scan_frame(scene);
    let centre = c + depth * normal;
    let n = n.max(1);
    let mut vertices = Vec::with_capacity((n + 1) * (n + 1));
    for j in 0..=n {
        for i in 0..=n {
            let (s, t) = (
                2.0 * i as f32 / n as f32 - 1.0,
                2.0 * j as f32 / n as f32 - 1.0,
            );
            let p = centre + size * (s * hu + t * hv);
            vertices.push([p.x as f64, p.y as f64, p.z as f64]);
        }
    }
    let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    let mut faces = Vec::with_capacity(2 * n * n);
    for j in 0..n {
        for i in 0..n {
            // (u, v, normal) is right-handed, so (i,j) → (i,j+1) → (i+1,j+1) turns
            // clockwise seen from the wall: the face normal points back at the wall.
            faces.push([id(i, j), id(i, j + 1), id(i + 1, j + 1)]);
            faces.push([id(i, j), id(i + 1, j + 1), id(i + 1, j)]);
        }
    }
    Mesh::new(vertices, faces)
}

/// An icosphere of `radius` centred `depth + radius` in front of the scan centre.
pub fn sphere(scene: &Scene, depth: f32, radius: f32, level: u32) -> Mesh {
    let (c, normal, _, _) = scan_frame(scene);
    super::fit_mesh(&icosphere(c + (depth + radius) * normal, radius, level))
}

/// A Stanford LCT capture (`.mat`): confocal, counts, its geometry in the file.
pub fn is_lct_capture(path: &Path) -> bool {
    path.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mat"))
}

/// The start when none is asked for: the LCT's surfaces for a Stanford `.mat` capture
/// (what a classical reconstruction of it sees: several objects at their depths, their
/// albedo; `fit::reconstruction::lct_mesh`, issue 48), a plane otherwise.
pub fn default_init(measurement: &Measurement) -> &'static str {
    match measurement {
        Measurement::File(p) if is_lct_capture(p) => "lct",
        _ => "plane",
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::default::default_scene;

    /// With no `--init`, a Stanford capture starts from what its LCT sees, anything else
    /// from a plane.
    #[test]
    fn the_default_start_is_the_lct_for_stanford_captures() {
        let file = |p: &str| Measurement::File(p.into());
        assert_eq!(default_init(&file("data/data_s_u.mat")), "lct");
        assert_eq!(default_init(&file("DATA_S_U.MAT")), "lct");
        for other in ["capture.npy", "capture.hdf5", "mat"] {
            assert_eq!(default_init(&file(other)), "plane", "{other}");
        }
        assert_eq!(default_init(&Measurement::Demo { target_spp: 16 }), "plane");
    }

    #[test]
    fn depth_ignores_a_constant_background() {
        let mut scene = default_scene().unwrap();
        scene.scan.nx = 2;
        scene.scan.ny = 1;
        scene.film.temporal_bins = 100;
        scene.film.start_opl = 0.0;
        scene.film.bin_width_opl = 0.01;
        scene.account_first_and_last_bounces = false;
        // Bins 0..10 zeroed (ignored), background 3 from there, a return of 2 at bin 60
        // (below half the maximum: a threshold on the raw sum would stop at bin 10).
        let mut row = vec![0.0f32; 100];
        row[10..].fill(3.0);
        row[60] += 2.0;
        let data = [row.clone(), row].concat();
        let d = depth_from_data(&scene, &data).unwrap();
        assert!((d - 0.5 * 0.605).abs() < 1e-4, "{d}");
    }

    #[test]
    fn plane_faces_the_wall() {
        let scene = default_scene().unwrap();
        let m = plane(&scene, 0.5, 0.5, 3);
        let n_w = scene.wall.normal();
        for f in &m.faces {
            let p = f.map(|i| Vec3::from_array(m.vertices[i as usize].map(|c| c as f32)));
            let n = (p[1] - p[0]).cross(p[2] - p[0]);
            assert!(n.dot(n_w) < 0.0, "a face looks away from the wall");
        }
    }
}
