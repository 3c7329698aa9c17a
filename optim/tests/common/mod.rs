//! Test meshes and measurements shared by the remeshing tests.
#![allow(dead_code)]

use optim::remesh::{edge_length_stats, RemeshOptions};
use optim::Mesh;
use std::collections::BTreeMap;

// ---------------------------------------------------------------------------------------
// Test meshes and measurements

pub fn normalize(p: [f64; 3], r: f64) -> [f64; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] * r / l, p[1] * r / l, p[2] * r / l]
}

/// Icosahedron subdivided `level` times (4^level * 20 faces), vertices on the sphere of
/// radius `r`, faces counter-clockwise seen from outside.
pub fn icosphere(level: usize, r: f64) -> Mesh {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    #[rustfmt::skip]
    let corners = [
        [-1.0, t, 0.0], [1.0, t, 0.0], [-1.0, -t, 0.0], [1.0, -t, 0.0],
        [0.0, -1.0, t], [0.0, 1.0, t], [0.0, -1.0, -t], [0.0, 1.0, -t],
        [t, 0.0, -1.0], [t, 0.0, 1.0], [-t, 0.0, -1.0], [-t, 0.0, 1.0],
    ];
    let mut v: Vec<[f64; 3]> = corners.iter().map(|&p| normalize(p, r)).collect();
    #[rustfmt::skip]
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
        [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
        [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ];
    for _ in 0..level {
        let mut mid = BTreeMap::new();
        let mut nf = Vec::new();
        for tri in &f {
            let mut m = [0u32; 3];
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                let key = (a.min(b), a.max(b));
                m[k] = *mid.entry(key).or_insert_with(|| {
                    let (pa, pb) = (v[a as usize], v[b as usize]);
                    v.push(normalize([pa[0] + pb[0], pa[1] + pb[1], pa[2] + pb[2]], r));
                    (v.len() - 1) as u32
                });
            }
            nf.push([tri[0], m[0], m[2]]);
            nf.push([tri[1], m[1], m[0]]);
            nf.push([tri[2], m[2], m[1]]);
            nf.push([m[0], m[1], m[2]]);
        }
        f = nf;
    }
    Mesh::new(v, f)
}

/// A `nu` x `nv` grid of cells, two triangles each, vertex (i, j) at `at(i / nu, j / nv)`;
/// `wrap` closes it in both directions (a torus), otherwise it has (nu + 1)(nv + 1) vertices.
pub fn grid(nu: usize, nv: usize, wrap: bool, at: impl Fn(f64, f64) -> [f64; 3]) -> Mesh {
    let (cu, cv) = if wrap { (nu, nv) } else { (nu + 1, nv + 1) };
    let v = (0..cu * cv).map(|k| at((k % cu) as f64 / nu as f64, (k / cu) as f64 / nv as f64));
    let id = |i: usize, j: usize| ((j % cv) * cu + (i % cu)) as u32;
    let quads = (0..nu * nv).map(|k| (k % nu, k / nu));
    let f = quads.flat_map(|(i, j)| {
        let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
        [[a, b, c], [a, c, d]]
    });
    Mesh::new(v.collect(), f.collect())
}

/// The unit square [0, 1]^2 at z = 0 as an `n` x `n` grid, normals +z.
pub fn sheet(n: usize) -> Mesh {
    grid(n, n, false, |x, y| [x, y, 0.0])
}

/// Torus (major radius 1, minor 0.3) as a `nu` x `nv` grid, normals outward.
pub fn torus(nu: usize, nv: usize) -> Mesh {
    grid(nu, nv, true, |s, t| {
        let (u, w) = (s * std::f64::consts::TAU, t * std::f64::consts::TAU);
        let r = 1.0 + 0.3 * w.cos();
        [r * u.cos(), r * u.sin(), 0.3 * w.sin()]
    })
}

pub fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

pub fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| a[(i + 1) % 3] * b[(i + 2) % 3] - a[(i + 2) % 3] * b[(i + 1) % 3])
}

pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

pub fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

pub fn corners(m: &Mesh, f: [u32; 3]) -> [[f64; 3]; 3] {
    f.map(|v| m.vertices[v as usize])
}

pub fn face_normal(m: &Mesh, f: [u32; 3]) -> [f64; 3] {
    let [a, b, c] = corners(m, f);
    cross(sub(b, a), sub(c, a))
}

/// All face angles (degrees), sorted.
pub fn angles(m: &Mesh) -> Vec<f64> {
    let mut angles: Vec<f64> = Vec::new();
    for &f in &m.faces {
        let p = corners(m, f);
        for k in 0..3 {
            let (u, w) = (sub(p[(k + 1) % 3], p[k]), sub(p[(k + 2) % 3], p[k]));
            let c = (dot(u, w) / (norm(u) * norm(w))).clamp(-1.0, 1.0);
            angles.push(c.acos().to_degrees());
        }
    }
    angles.sort_by(f64::total_cmp);
    angles
}

/// "min / 1st percentile / share below 30°" of the face angles.
pub fn angle_summary(m: &Mesh) -> String {
    let a = angles(m);
    let below = a.iter().filter(|&&x| x < 30.0).count() as f64 / a.len() as f64;
    let (min, p1) = (a[0], a[a.len() / 100]);
    format!(
        "min {min:.1}, 1st pct {p1:.1}, {:.2} % below 30 (deg)",
        100.0 * below
    )
}

/// Prints face counts, edge lengths relative to `target` and angles before and after.
pub fn report(label: &str, input: &Mesh, out: &Mesh, target: f64) {
    let (min, mean, max) = edge_length_stats(out);
    let (fi, fo) = (input.faces.len(), out.faces.len());
    let (min, mean, max) = (min / target, mean / target, max / target);
    println!("{label}: faces {fi} -> {fo}, edge / target min {min:.3} mean {mean:.3} max {max:.3}");
    println!(
        "  angles before: {}\n  angles after:  {}",
        angle_summary(input),
        angle_summary(out)
    );
}

/// Largest |value - f(position)| over the vertices.
pub fn linear_error(m: &Mesh, f: impl Fn([f64; 3]) -> f64) -> f64 {
    assert_eq!(m.vertex_values.len(), m.vertices.len());
    let errors = m
        .vertices
        .iter()
        .zip(&m.vertex_values)
        .map(|(&p, &v)| (v - f(p)).abs());
    errors.fold(0.0, f64::max)
}

/// Undirected edges, one entry per face side, sorted.
pub fn edge_list(m: &Mesh) -> Vec<(u32, u32)> {
    let sides = m
        .faces
        .iter()
        .flat_map(|f| (0..3).map(move |k| (f[k], f[(k + 1) % 3])));
    let mut edges: Vec<(u32, u32)> = sides.map(|(a, b)| (a.min(b), a.max(b))).collect();
    edges.sort_unstable();
    edges
}

pub fn euler(m: &Mesh) -> i64 {
    let mut edges = edge_list(m);
    edges.dedup();
    m.vertices.len() as i64 - edges.len() as i64 + m.faces.len() as i64
}

/// Every vertex is used by some face.
pub fn all_vertices_used(m: &Mesh) -> bool {
    let mut used = vec![false; m.vertices.len()];
    m.faces
        .iter()
        .flatten()
        .for_each(|&v| used[v as usize] = true);
    used.iter().all(|&u| u)
}

pub fn opts(target: f64, iterations: usize, keep_boundary: bool) -> RemeshOptions {
    RemeshOptions {
        target_edge: target,
        iterations,
        smoothing: 1.0,
        keep_boundary,
    }
}

/// Vertices of `m` on the outline of the unit square (within `tol`).
pub fn on_square_outline(p: [f64; 3], tol: f64) -> bool {
    let near = |x: f64, c: f64| (x - c).abs() <= tol;
    let inside = |x: f64| (-tol..=1.0 + tol).contains(&x);
    inside(p[0])
        && inside(p[1])
        && (near(p[0], 0.0) || near(p[0], 1.0) || near(p[1], 0.0) || near(p[1], 1.0))
}

/// The vertices on boundary edges (edges with one face).
pub fn boundary_vertices(m: &Mesh) -> Vec<u32> {
    let e = edge_list(m);
    let single = |i: usize| (i == 0 || e[i - 1] != e[i]) && e.get(i + 1) != Some(&e[i]);
    let mut vs: Vec<u32> = (0..e.len())
        .filter(|&i| single(i))
        .flat_map(|i| [e[i].0, e[i].1])
        .collect();
    vs.sort_unstable();
    vs.dedup();
    vs
}

/// Per parameter of `theta`, the relative error `|g − FD| / max(|FD|, 1e-3)` of the
/// gradient `grad` against central differences of `problem`'s cost with step `h`, and the
/// difference itself.
pub fn fd_errors(
    problem: &optim::MeshProblem,
    theta: &[f64],
    grad: &[f64],
    h: f64,
) -> Vec<(f64, f64)> {
    use argmin::core::CostFunction;
    (0..theta.len())
        .map(|k| {
            let (mut plus, mut minus) = (theta.to_vec(), theta.to_vec());
            plus[k] += h;
            minus[k] -= h;
            let fd = (problem.cost(&plus).unwrap() - problem.cost(&minus).unwrap()) / (2.0 * h);
            ((grad[k] - fd).abs() / fd.abs().max(1e-3), fd)
        })
        .collect()
}
