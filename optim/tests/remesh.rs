//! Isotropic remeshing: edge lengths, topology, shape, values, orientation, determinism and
//! bad input.

use std::collections::BTreeMap;

use optim::remesh::{
    boundary_loops, edge_length_stats, is_manifold, remesh, RemeshError, RemeshOptions,
};
use optim::Mesh;

// ---------------------------------------------------------------------------------------
// Test meshes and measurements

fn normalize(p: [f64; 3], r: f64) -> [f64; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    [p[0] * r / l, p[1] * r / l, p[2] * r / l]
}

/// Icosahedron subdivided `level` times (4^level * 20 faces), vertices on the sphere of
/// radius `r`, faces counter-clockwise seen from outside.
fn icosphere(level: usize, r: f64) -> Mesh {
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
fn grid(nu: usize, nv: usize, wrap: bool, at: impl Fn(f64, f64) -> [f64; 3]) -> Mesh {
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
fn sheet(n: usize) -> Mesh {
    grid(n, n, false, |x, y| [x, y, 0.0])
}

/// Torus (major radius 1, minor 0.3) as a `nu` x `nv` grid, normals outward.
fn torus(nu: usize, nv: usize) -> Mesh {
    grid(nu, nv, true, |s, t| {
        let (u, w) = (s * std::f64::consts::TAU, t * std::f64::consts::TAU);
        let r = 1.0 + 0.3 * w.cos();
        [r * u.cos(), r * u.sin(), 0.3 * w.sin()]
    })
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| a[(i + 1) % 3] * b[(i + 2) % 3] - a[(i + 2) % 3] * b[(i + 1) % 3])
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

fn corners(m: &Mesh, f: [u32; 3]) -> [[f64; 3]; 3] {
    f.map(|v| m.vertices[v as usize])
}

fn face_normal(m: &Mesh, f: [u32; 3]) -> [f64; 3] {
    let [a, b, c] = corners(m, f);
    cross(sub(b, a), sub(c, a))
}

/// All face angles (degrees), sorted.
fn angles(m: &Mesh) -> Vec<f64> {
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
fn angle_summary(m: &Mesh) -> String {
    let a = angles(m);
    let below = a.iter().filter(|&&x| x < 30.0).count() as f64 / a.len() as f64;
    let (min, p1) = (a[0], a[a.len() / 100]);
    format!(
        "min {min:.1}, 1st pct {p1:.1}, {:.2} % below 30 (deg)",
        100.0 * below
    )
}

/// Prints face counts, edge lengths relative to `target` and angles before and after.
fn report(label: &str, input: &Mesh, out: &Mesh, target: f64) {
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
fn linear_error(m: &Mesh, f: impl Fn([f64; 3]) -> f64) -> f64 {
    assert_eq!(m.vertex_values.len(), m.vertices.len());
    let errors = m
        .vertices
        .iter()
        .zip(&m.vertex_values)
        .map(|(&p, &v)| (v - f(p)).abs());
    errors.fold(0.0, f64::max)
}

/// Undirected edges, one entry per face side, sorted.
fn edge_list(m: &Mesh) -> Vec<(u32, u32)> {
    let sides = m
        .faces
        .iter()
        .flat_map(|f| (0..3).map(move |k| (f[k], f[(k + 1) % 3])));
    let mut edges: Vec<(u32, u32)> = sides.map(|(a, b)| (a.min(b), a.max(b))).collect();
    edges.sort_unstable();
    edges
}

fn euler(m: &Mesh) -> i64 {
    let mut edges = edge_list(m);
    edges.dedup();
    m.vertices.len() as i64 - edges.len() as i64 + m.faces.len() as i64
}

/// Every vertex is used by some face.
fn all_vertices_used(m: &Mesh) -> bool {
    let mut used = vec![false; m.vertices.len()];
    m.faces
        .iter()
        .flatten()
        .for_each(|&v| used[v as usize] = true);
    used.iter().all(|&u| u)
}

fn opts(target: f64, iterations: usize, keep_boundary: bool) -> RemeshOptions {
    RemeshOptions {
        target_edge: target,
        iterations,
        smoothing: 1.0,
        keep_boundary,
    }
}

/// Vertices of `m` on the outline of the unit square (within `tol`).
fn on_square_outline(p: [f64; 3], tol: f64) -> bool {
    let near = |x: f64, c: f64| (x - c).abs() <= tol;
    let inside = |x: f64| (-tol..=1.0 + tol).contains(&x);
    inside(p[0])
        && inside(p[1])
        && (near(p[0], 0.0) || near(p[0], 1.0) || near(p[1], 0.0) || near(p[1], 1.0))
}

/// The vertices on boundary edges (edges with one face).
fn boundary_vertices(m: &Mesh) -> Vec<u32> {
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

// ---------------------------------------------------------------------------------------
// Closed surfaces

#[test]
fn icosphere_refined_to_finer_target() {
    let input = icosphere(3, 1.0);
    let target = 0.5 * edge_length_stats(&input).1;
    let out = remesh(&input, &opts(target, 6, true)).unwrap();
    report("icosphere(3) refined x2", &input, &out, target);
    let (min, _, max) = edge_length_stats(&out);
    assert!(out.faces.len() > 3 * input.faces.len());
    assert!(
        min >= 0.5 * target && max <= 2.0 * target,
        "{min} {max} {target}"
    );
    assert!(is_manifold(&out) && boundary_loops(&out) == 0 && all_vertices_used(&out));
    assert_eq!(euler(&out), 2);
    let radial = out.vertices.iter().map(|&p| (norm(p) - 1.0).abs());
    let worst = radial.fold(0.0, f64::max);
    println!("  largest |r - 1| = {worst:.2e}");
    assert!(worst < 0.01);
    assert!(angles(&out)[0] > 25.0);
}

#[test]
fn remeshed_sphere_normals_point_outward() {
    let out = remesh(&icosphere(2, 2.0), &opts(0.2, 5, true)).unwrap();
    for &f in &out.faces {
        let [a, b, c] = corners(&out, f);
        let centroid = [0, 1, 2].map(|d| (a[d] + b[d] + c[d]) / 3.0);
        assert!(
            dot(face_normal(&out, f), centroid) > 0.0,
            "{f:?} points inward"
        );
    }
    // Inward-wound input stays inward-wound.
    let mut inward = icosphere(2, 2.0);
    inward.faces.iter_mut().for_each(|f| f.swap(1, 2));
    let out = remesh(&inward, &opts(0.2, 5, true)).unwrap();
    let outward = |f: &[u32; 3]| dot(face_normal(&out, *f), out.vertices[f[0] as usize]) > 0.0;
    assert!(!out.faces.iter().any(outward));
}

#[test]
fn fine_sphere_to_coarse_target_shrinks() {
    let input = icosphere(4, 1.0);
    let target = 3.0 * edge_length_stats(&input).1;
    let out = remesh(&input, &opts(target, 8, true)).unwrap();
    report("icosphere(4) coarsened x3", &input, &out, target);
    let (min, _, max) = edge_length_stats(&out);
    assert!(out.faces.len() * 4 < input.faces.len());
    assert!(is_manifold(&out) && euler(&out) == 2);
    assert!(min >= 0.5 * target && max <= 2.0 * target);
}

#[test]
fn torus_keeps_genus_one() {
    let input = torus(60, 12);
    let out = remesh(&input, &opts(0.1, 6, true)).unwrap();
    report("torus 60x12, target 0.1", &input, &out, 0.1);
    assert!(is_manifold(&out) && boundary_loops(&out) == 0);
    assert_eq!(euler(&out), 0);
}

// ---------------------------------------------------------------------------------------
// Open sheets

#[test]
fn open_sheet_keeps_its_outline() {
    let input = sheet(8);
    for target in [0.04, 0.3] {
        let out = remesh(&input, &opts(target, 6, true)).unwrap();
        report(&format!("sheet 8x8, target {target}"), &input, &out, target);
        assert!(is_manifold(&out));
        assert_eq!(boundary_loops(&out), 1);
        assert!(out.vertices.iter().all(|p| p[2] == 0.0));
        assert!(out.faces.iter().all(|&f| face_normal(&out, f)[2] > 0.0));
        let boundary = boundary_vertices(&out);
        for &v in &boundary {
            let p = out.vertices[v as usize];
            assert!(on_square_outline(p, 1e-12), "{p:?}");
        }
        for corner in [
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1.0, 0.0],
        ] {
            let kept = boundary.iter().any(|&v| out.vertices[v as usize] == corner);
            assert!(kept, "corner {corner:?} lost");
        }
        // Coarse: the fixed corners leave some shorter boundary edges.
        let (min, _, max) = edge_length_stats(&out);
        assert!(max <= 2.0 * target && min >= 0.5 * target.min(0.125));
    }
}

#[test]
fn open_sheet_without_keep_boundary_stays_open() {
    let out = remesh(&sheet(8), &opts(0.05, 5, false)).unwrap();
    assert!(is_manifold(&out));
    assert_eq!(boundary_loops(&out), 1);
    // Boundary vertices stay on the sheet and near its outline.
    for &v in &boundary_vertices(&out) {
        let p = out.vertices[v as usize];
        assert!(p[2] == 0.0 && on_square_outline(p, 0.02), "{p:?}");
    }
}

#[test]
fn sheet_with_hole_keeps_two_boundary_loops() {
    let mut m = sheet(9);
    // Drop the two triangles of the middle cell: an annulus.
    let vertices = m.vertices.clone();
    m.faces.retain(|f| {
        let c = f.map(|v| vertices[v as usize]);
        let (x, y) = (
            (c[0][0] + c[1][0] + c[2][0]) / 3.0,
            (c[0][1] + c[1][1] + c[2][1]) / 3.0,
        );
        let middle = 4.0 / 9.0..5.0 / 9.0;
        !(middle.contains(&x) && middle.contains(&y))
    });
    assert_eq!(boundary_loops(&m), 2);
    let out = remesh(&m, &opts(0.04, 5, true)).unwrap();
    assert!(is_manifold(&out));
    assert_eq!(boundary_loops(&out), 2);
    assert_eq!(euler(&out), 0);
}

// ---------------------------------------------------------------------------------------
// Values, determinism

#[test]
fn linear_values_stay_linear() {
    let f = |p: [f64; 3]| 0.3 + 2.0 * p[0] - 1.5 * p[1] + 0.7 * p[2];
    let mut m = sheet(6);
    m.vertex_values = m.vertices.iter().map(|&p| f(p)).collect();
    for (target, keep) in [(0.03, true), (0.03, false), (0.4, true)] {
        let out = remesh(&m, &opts(target, 4, keep)).unwrap();
        let error = linear_error(&out, f);
        assert!(error <= 1e-12, "sheet, target {target}: {error:e}");
    }
    // On a curved surface too (values are interpolated on the flat input faces).
    let mut s = icosphere(2, 1.0);
    s.vertex_values = s.vertices.iter().map(|&p| f(p)).collect();
    let out = remesh(&s, &opts(0.1, 4, true)).unwrap();
    assert!(linear_error(&out, f) <= 1e-12);
    // Splits alone (no relaxation): midpoint values.
    let split_only = RemeshOptions {
        smoothing: 0.0,
        ..opts(0.05, 1, true)
    };
    let out = remesh(&m, &split_only).unwrap();
    assert!(out.vertices.len() > 4 * m.vertices.len());
    assert!(linear_error(&out, f) <= 1e-12);
}

#[test]
fn empty_values_stay_empty() {
    let out = remesh(&sheet(4), &opts(0.1, 3, true)).unwrap();
    assert!(out.vertex_values.is_empty());
}

#[test]
fn deterministic() {
    let mut m = torus(40, 10);
    m.vertex_values = (0..m.vertices.len()).map(|i| (i as f64).sin()).collect();
    let o = RemeshOptions {
        smoothing: 0.7,
        ..opts(0.08, 5, false)
    };
    let (a, b) = (remesh(&m, &o).unwrap(), remesh(&m, &o).unwrap());
    assert_eq!(a.faces, b.faces);
    let bits = |m: &Mesh| -> Vec<u64> {
        let coords = m.vertices.iter().flatten().chain(&m.vertex_values);
        coords.map(|x| x.to_bits()).collect()
    };
    assert_eq!(bits(&a), bits(&b));
}

// ---------------------------------------------------------------------------------------
// Bad input and repairs

fn tri() -> Mesh {
    let v = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
    Mesh::new(v, vec![[0, 1, 2]])
}

fn err(m: &Mesh, o: &RemeshOptions) -> RemeshError {
    remesh(m, o).unwrap_err()
}

#[test]
fn bad_input_is_an_error() {
    use RemeshError::*;
    let o = opts(0.1, 3, true);
    let mut nan = tri();
    nan.vertices[1][2] = f64::NAN;
    assert_eq!(err(&nan, &o), NonFiniteVertex { vertex: 1 });
    let mut inf = tri();
    inf.vertices[0][0] = f64::INFINITY;
    assert_eq!(err(&inf, &o), NonFiniteVertex { vertex: 0 });
    let mut out_of_range = tri();
    out_of_range.faces.push([0, 2, 7]);
    let range_error = IndexOutOfRange {
        face: 1,
        index: 7,
        vertex_count: 3,
    };
    assert_eq!(err(&out_of_range, &o), range_error);
    let mut values = tri();
    values.vertex_values = vec![1.0, 2.0];
    assert_eq!(
        err(&values, &o),
        ValueCount {
            values: 2,
            vertices: 3
        }
    );
    values.vertex_values = vec![1.0, f64::NAN, 2.0];
    assert_eq!(err(&values, &o), NonFiniteValue { vertex: 1 });
    assert_eq!(err(&Mesh::default(), &o), NoFaces);
    assert_eq!(
        err(&Mesh::new(tri().vertices, vec![[0, 0, 1], [2, 2, 2]]), &o),
        NoFaces
    );

    // Three faces on edge 0-1.
    #[rustfmt::skip]
    let v = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [0.5, -1.0, 0.0], [0.5, 0.0, 1.0]];
    let fin = Mesh::new(v.clone(), vec![[0, 1, 2], [1, 0, 3], [0, 1, 4]]);
    assert!(!is_manifold(&fin));
    assert_eq!(err(&fin, &o), NonManifoldEdge { a: 0, b: 1 });
    // Neighbours wound differently.
    let flipped = Mesh::new(v, vec![[0, 1, 2], [0, 1, 3]]);
    assert!(!is_manifold(&flipped));
    assert_eq!(err(&flipped, &o), InconsistentOrientation { a: 0, b: 1 });
    // Two triangles sharing only a vertex (bow tie).
    #[rustfmt::skip]
    let v = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, -1.0, 0.0]];
    let bowtie = Mesh::new(v, vec![[0, 1, 2], [0, 3, 4]]);
    assert!(!is_manifold(&bowtie));
    assert_eq!(err(&bowtie, &o), NonManifoldVertex { vertex: 0 });

    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            err(&tri(), &opts(bad, 1, true)),
            InvalidTargetEdge(_)
        ));
    }
    for bad in [-0.1, 1.5, f64::NAN] {
        let o = RemeshOptions {
            smoothing: bad,
            ..opts(0.1, 1, true)
        };
        assert!(matches!(err(&tri(), &o), InvalidSmoothing(_)));
    }
    // A target so small the result would not fit in memory.
    let limit = optim::remesh::MAX_FACES;
    assert_eq!(err(&tri(), &opts(1e-6, 1, true)), TooManyFaces { limit });
    // Huge coordinates: no panic, whatever the outcome.
    let mut huge = tri();
    huge.vertices[2] = [0.0, 1e300, 0.0];
    let _ = remesh(&huge, &o);
}

#[test]
fn documented_repairs() {
    let o = opts(0.2, 4, true);
    // The sheet cut in two along x = 0.5 with duplicated seam vertices: welded back.
    let m = sheet(4);
    let n = m.vertices.len() as u32;
    let mut split = m.clone();
    split.vertices.extend(m.vertices.clone());
    for f in split.faces.iter_mut() {
        if f.iter().map(|&v| m.vertices[v as usize][0]).sum::<f64>() > 1.5 {
            f.iter_mut().for_each(|v| *v += n);
        }
    }
    assert_eq!(boundary_loops(&split), 2);
    let out = remesh(&split, &o).unwrap();
    assert_eq!(boundary_loops(&out), 1);
    assert!(is_manifold(&out) && all_vertices_used(&out));

    // Faces repeating a vertex and repeated faces are dropped; unused vertices too.
    let mut extra = sheet(4);
    extra.faces.push([0, 0, 1]);
    extra.faces.push(extra.faces[3]);
    extra.vertices.push([5.0, 5.0, 5.0]);
    let out = remesh(&extra, &o).unwrap();
    assert!(is_manifold(&out) && all_vertices_used(&out));

    // Zero-area faces (a vertex on the middle of its opposite edge) are accepted.
    #[rustfmt::skip]
    let v = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.5, 1.0, 0.0], [0.5, -1.0, 0.0]];
    let sliver = Mesh::new(v, vec![[0, 1, 2], [0, 2, 3], [2, 1, 3], [1, 0, 4]]);
    assert!(is_manifold(&sliver));
    let out = remesh(&sliver, &opts(0.2, 5, true)).unwrap();
    assert!(is_manifold(&out) && boundary_loops(&out) == 1);
    assert!(out.vertices.iter().flatten().all(|x| x.is_finite()));

    // Zero iterations: the validated, repaired input.
    let out = remesh(&extra, &opts(0.2, 0, true)).unwrap();
    assert_eq!(out.faces.len(), sheet(4).faces.len());
    assert_eq!(out.vertices, sheet(4).vertices);
}

// ---------------------------------------------------------------------------------------
// Helpers

#[test]
fn helpers() {
    let (min, mean, max) = edge_length_stats(&tri());
    assert_eq!((min, max), (1.0, 2f64.sqrt()));
    assert!((mean - (2.0 + 2f64.sqrt()) / 3.0).abs() < 1e-15);
    assert_eq!(edge_length_stats(&Mesh::default()), (0.0, 0.0, 0.0));
    assert!(is_manifold(&tri()) && is_manifold(&icosphere(1, 1.0)) && is_manifold(&sheet(3)));
    assert_eq!(boundary_loops(&tri()), 1);
    assert_eq!(boundary_loops(&icosphere(1, 1.0)), 0);
    assert_eq!(boundary_loops(&sheet(3)), 1);
    let bad = Mesh::new(tri().vertices, vec![[0, 1, 9]]);
    assert!(!is_manifold(&bad));
    assert_eq!(boundary_loops(&bad), 0);
}

/// Run time on a 10k-face mesh: `cargo test --release -p umbra-optim --test remesh --
/// --ignored --nocapture`. Reports only; asserts nothing about time.
#[test]
#[ignore]
fn report_timing_10k_faces() {
    let input = torus(250, 20); // 10 000 faces, anisotropic (edges 0.025 x 0.094)
    let mean = edge_length_stats(&input).1;
    for (label, target) in [
        ("same mean edge", mean),
        ("refine x2", 0.5 * mean),
        ("coarsen x2", 2.0 * mean),
    ] {
        let t0 = std::time::Instant::now();
        let out = remesh(&input, &opts(target, 5, true)).unwrap();
        let ms = t0.elapsed().as_secs_f64() * 1e3;
        report(
            &format!("torus 250x20, {label}, 5 iterations, {ms:.1} ms"),
            &input,
            &out,
            target,
        );
    }
}

// ---------------------------------------------------------------------------------------
// Randomised robustness

/// Small deterministic generator (splitmix64).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

/// A random test case: jittered spheres, tori and sheets, spheres with holes, and sphere
/// topology with vertices anywhere in a cube (folds, self-intersections), with random
/// options.
fn random_case(rng: &mut Rng, case: usize) -> (Mesh, RemeshOptions) {
    let mut m = match case % 5 {
        0 => icosphere(2, 1.0),
        1 => sheet(6),
        2 => torus(16, 6),
        3 => {
            let mut s = icosphere(1, 1.0);
            s.vertices
                .iter_mut()
                .for_each(|p| *p = [0; 3].map(|_| rng.next()));
            s
        }
        _ => {
            let mut s = icosphere(2, 1.0);
            s.faces.retain(|_| rng.next() > 0.1);
            s
        }
    };
    let noise = rng.range(0.0, 0.3);
    for p in m.vertices.iter_mut() {
        for x in p.iter_mut() {
            *x += noise * rng.range(-1.0, 1.0);
        }
    }
    m.vertex_values = (0..m.vertices.len()).map(|_| rng.next()).collect();
    let o = RemeshOptions {
        target_edge: rng.range(0.03, 1.5),
        iterations: 1 + (rng.next() * 5.0) as usize,
        smoothing: rng.next(),
        keep_boundary: rng.next() < 0.5,
    };
    (m, o)
}

/// Random meshes (see [`random_case`]): never a panic, and a manifold input keeps its
/// Euler characteristic and boundary count. `REMESH_FUZZ_CASES` sets the number of cases.
#[test]
fn random_meshes_keep_their_topology() {
    let cases = std::env::var("REMESH_FUZZ_CASES").map_or(50, |s| s.parse().unwrap());
    let mut rng = Rng(12345);
    for case in 0..cases {
        let (m, o) = random_case(&mut rng, case);
        let result = remesh(&m, &o);
        if !is_manifold(&m) {
            continue;
        }
        let out = result.unwrap_or_else(|e| panic!("case {case}: {e}"));
        assert!(is_manifold(&out), "case {case}: not manifold");
        assert!(all_vertices_used(&out), "case {case}: unused vertices");
        assert_eq!(euler(&out), euler(&m), "case {case}: Euler characteristic");
        assert_eq!(
            boundary_loops(&out),
            boundary_loops(&m),
            "case {case}: boundary"
        );
        assert_eq!(out.vertex_values.len(), out.vertices.len());
        let mut numbers = out.vertices.iter().flatten().chain(&out.vertex_values);
        assert!(numbers.all(|x| x.is_finite()));
    }
}
