//! Procedural meshes for tests and benchmarks: an icosphere and a wavy height-field
//! sheet, both with outward (wall-facing) winding.

use super::mesh::TriMesh;
use glam::Vec3;
use std::collections::HashMap;

/// A sphere of radius `r` at `center` from an icosahedron subdivided `level` times
/// (`20 · 4^level` triangles), outward normals.
pub fn icosphere(center: Vec3, r: f32, level: u32) -> TriMesh {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut v: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..level {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut midpoint = |a: u32, b: u32, v: &mut Vec<Vec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push(((v[a as usize] + v[b as usize]) * 0.5).normalize());
                v.len() as u32 - 1
            })
        };
        let mut next = Vec::with_capacity(f.len() * 4);
        for [a, b, c] in f {
            let ab = midpoint(a, b, &mut v);
            let bc = midpoint(b, c, &mut v);
            let ca = midpoint(c, a, &mut v);
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = next;
    }
    TriMesh {
        positions: v.into_iter().map(|p| center + r * p).collect(),
        triangles: f,
        vertex_albedo: None,
    }
}

/// A `size x size` sheet at depth `z` facing `-z` (toward a wall at `z = 0`), on an
/// `n x n` grid (`2 n²` triangles), displaced along `z` by
/// `amplitude · sin(2π x / wavelength) · cos(2π y / wavelength)`.
pub fn wavy_sheet(center: Vec3, size: f32, n: u32, amplitude: f32, wavelength: f32) -> TriMesh {
    let k = std::f32::consts::TAU / wavelength;
    let mut positions = Vec::with_capacity(((n + 1) * (n + 1)) as usize);
    for j in 0..=n {
        for i in 0..=n {
            let x = (i as f32 / n as f32 - 0.5) * size;
            let y = (j as f32 / n as f32 - 0.5) * size;
            let dz = amplitude * (k * x).sin() * (k * y).cos();
            positions.push(center + Vec3::new(x, y, dz));
        }
    }
    let id = |i: u32, j: u32| j * (n + 1) + i;
    let mut triangles = Vec::with_capacity((2 * n * n) as usize);
    for j in 0..n {
        for i in 0..n {
            // Winding with normal -z: (v1 - v0) × (v2 - v0) points to the wall.
            triangles.push([id(i, j), id(i, j + 1), id(i + 1, j)]);
            triangles.push([id(i + 1, j), id(i, j + 1), id(i + 1, j + 1)]);
        }
    }
    TriMesh {
        positions,
        triangles,
        vertex_albedo: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn icosphere_area_and_winding() {
        let m = icosphere(Vec3::new(0.0, 0.0, 1.0), 0.2, 3);
        assert_eq!(m.triangles.len(), 1280);
        let area: f32 = (0..m.triangles.len()).map(|t| m.area(t)).sum();
        let exact = 4.0 * std::f32::consts::PI * 0.04;
        assert!((area - exact).abs() / exact < 0.01, "{area} vs {exact}");
        for t in 0..m.triangles.len() {
            let [a, b, c] = m.triangle(t);
            let n = (b - a).cross(c - a);
            assert!(
                n.dot((a + b + c) / 3.0 - Vec3::new(0.0, 0.0, 1.0)) > 0.0,
                "inward face {t}"
            );
        }
    }

    #[test]
    fn wavy_sheet_faces_the_wall() {
        let m = wavy_sheet(Vec3::new(0.0, 0.0, 1.0), 0.5, 10, 0.01, 0.2);
        assert_eq!(m.triangles.len(), 200);
        for t in 0..m.triangles.len() {
            let [a, b, c] = m.triangle(t);
            assert!((b - a).cross(c - a).z < 0.0);
        }
    }
}
