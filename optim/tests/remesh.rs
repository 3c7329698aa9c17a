//! Isotropic remeshing: edge lengths, topology, shape, values, orientation, determinism and
//! bad input.

use optim::remesh::{
    boundary_loops, edge_length_stats, is_manifold, remesh, RemeshError, RemeshOptions,
};
use optim::Mesh;

mod common;
use common::*;

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
