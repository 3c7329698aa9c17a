//! Filtered backprojection (`umbra::recon`) on transients Umbra renders of known planes
//! (confocal, single and exhaustive capture), the height-field mesh of its depth map, and
//! the real Stanford LCT capture `data_diffuse_s.mat`.

mod common;
use common::patch::*;
use common::*;
use glam::Vec3;
use std::path::PathBuf;
use umbra::io::lct::read_lct;
use umbra::recon::*;
use umbra::scene::{Model, Scene};

/// 2.5 cm columns over the scan, 5 mm voxels in depth from 0.3 to 0.7 m.
fn grid(s: &Scene) -> VoxelGrid {
    VoxelGrid::over_scan(s, 0.3, 0.7, [32, 32, 80]).unwrap()
}

/// The options the synthetic tests use: depth Laplacian, falloff compensation, and a
/// one-bin Gaussian along time (rendered histograms have no detector jitter).
const OPTS: BackprojectOptions = BackprojectOptions {
    filter: Filter::DepthLaplacian,
    falloff: Falloff::Compensate,
    time_sigma_opl: BIN,
};

fn reconstruct(s: &Scene, threshold: f32) -> (VoxelGrid, DepthMap) {
    let t = render(s, Model::Tri3, 1, 0);
    let g = grid(s);
    let v = backproject_with(s, &t.data, &g, &OPTS).unwrap();
    (g, depth_map(&v, threshold).unwrap())
}

#[test]
fn confocal_plane_depth_and_extent() {
    let s = patch_scene("confocal", 0.0, 16);
    let (g, d) = reconstruct(&s, 0.5);
    let slope = check_patch("confocal plane", &g, &d, 0.0);
    assert!(slope.abs() < 0.02, "slope {slope}");
}

#[test]
fn confocal_tilted_plane_slope() {
    let s = patch_scene("confocal", 20.0, 16);
    let (g, d) = reconstruct(&s, 0.5);
    let tan = 20f32.to_radians().tan();
    let slope = check_patch("confocal tilted", &g, &d, tan);
    eprintln!("slope {slope:.3}, true {tan:.3}");
    assert!((slope / tan - 1.0).abs() < 0.2, "slope {slope} vs {tan}");
}

#[test]
fn single_capture_planes() {
    for tilt in [0.0f32, 20.0] {
        let s = patch_scene("single", tilt, 16);
        let (g, d) = reconstruct(&s, 0.3);
        let tan = tilt.to_radians().tan();
        let slope = check_patch(&format!("single, tilt {tilt}°"), &g, &d, tan);
        eprintln!("slope {slope:.3}, true {tan:.3}");
        assert!((slope - tan).abs() < 0.2 * tan.max(0.1), "slope {slope}");
    }
}

#[test]
fn exhaustive_capture_finds_the_plane() {
    let s = patch_scene("exhaustive", 0.0, 6);
    let t = render(&s, Model::Tri3, 1, 0);
    assert_eq!(t.data.len(), 36 * 36 * 128);
    let g = VoxelGrid::over_scan(&s, 0.3, 0.7, [8, 8, 80]).unwrap();
    let v = backproject_with(&s, &t.data, &g, &OPTS).unwrap();
    let d = depth_map(&v, 0.5).unwrap();
    for (ix, iy) in [(3, 3), (4, 4), (3, 4)] {
        let z = d.at(ix, iy);
        assert!((z - DEPTH).abs() <= DEPTH_TOL, "({ix}, {iy}): {z}");
    }
}

#[test]
fn depth_map_mesh_faces_the_wall_at_the_recovered_depths() {
    let s = patch_scene("confocal", 20.0, 16);
    let (g, d) = reconstruct(&s, 0.5);
    let frame = WallFrame::of(&s);
    let mesh = depth_map_mesh(&d, &g, &frame, &MeshOptions::default()).unwrap();
    assert!(
        mesh.triangles.len() >= 2 * 7 * 7,
        "{}",
        mesh.triangles.len()
    );
    for t in 0..mesh.triangles.len() {
        let [a, b, c] = mesh.triangle(t);
        let n = (b - a).cross(c - a).normalize();
        // One-sided surfaces reflect toward their normal: every scan point must be on
        // that side (tri3's p_l > 0).
        assert!(n.dot(s.wall.normal()) < -0.5, "triangle {t}: normal {n}");
        for m in 0..s.num_measurements() {
            let (x_l, _) = s.measurement_points(m);
            assert!(n.dot(x_l - a) > 0.0);
        }
    }
    // Each vertex sits on its column at the depth map's depth.
    let mut matched = 0;
    for p in &mesh.positions {
        let q = frame.to_frame(*p);
        let v = g.voxel_size();
        let ix = ((q.x - g.min.x) / v.x) as usize;
        let iy = ((q.y - g.min.y) / v.y) as usize;
        let c = g.center(ix, iy, 0);
        assert!((c.x - q.x).abs() < 1e-5 && (c.y - q.y).abs() < 1e-5);
        assert_eq!(q.z, d.at(ix, iy));
        matched += 1;
    }
    assert!(matched <= d.filled());
    // Smoothing keeps a plane a plane (here: the depths of a tilted plane move little).
    let smooth = depth_map_mesh(
        &d,
        &g,
        &frame,
        &MeshOptions {
            smooth_iterations: 5,
            ..MeshOptions::default()
        },
    )
    .unwrap();
    // The same quads (their diagonals may flip with the depths).
    assert_eq!(smooth.triangles.len(), mesh.triangles.len());
    assert_eq!(smooth.positions.len(), mesh.positions.len());
    let tan = 20f32.to_radians().tan();
    for (p, q) in smooth.positions.iter().zip(&mesh.positions) {
        assert!((p.z - q.z).abs() < 0.02, "{p} vs {q}");
        let inner = p.x.abs().max(p.y.abs()) < HALF - 0.03;
        if inner {
            assert!((p.z - DEPTH - tan * p.x).abs() <= DEPTH_TOL, "{p}");
        }
    }
}

#[test]
fn bad_inputs_are_errors() {
    let s = patch_scene("confocal", 0.0, 4);
    let g = VoxelGrid::over_scan(&s, 0.3, 0.7, [4, 4, 8]).unwrap();
    let bins = s.film.temporal_bins as usize;
    let e = backproject(&s, &[0.0; 10], &g, Filter::None).unwrap_err();
    assert!(e.to_string().contains("16 measurements x 128 bins"), "{e}");
    let mut nan = vec![0.0; 16 * bins];
    nan[5] = f32::NAN;
    assert!(backproject(&s, &nan, &g, Filter::None).is_err());
    let bad = BackprojectOptions {
        time_sigma_opl: -1.0,
        ..Default::default()
    };
    assert!(backproject_with(&s, &vec![0.0; 16 * bins], &g, &bad).is_err());
    assert!(VoxelGrid::new(Vec3::ZERO, Vec3::ONE, [0, 1, 1]).is_err());
    assert!(VoxelGrid::new(Vec3::ONE, Vec3::ZERO, [1, 1, 1]).is_err());
    assert!(VoxelGrid::new(Vec3::ZERO, Vec3::splat(f32::NAN), [1, 1, 1]).is_err());
    let mut bad_grid = g.clone();
    bad_grid.dims = [0, 4, 4];
    assert!(backproject(&s, &vec![0.0; 16 * bins], &bad_grid, Filter::None).is_err());

    // No light: an empty depth map, and a mesh error that says what to do.
    let v = backproject(&s, &vec![0.0; 16 * bins], &g, Filter::DepthLaplacian).unwrap();
    let d = depth_map(&v, 0.5).unwrap();
    assert_eq!(d.filled(), 0);
    let e = depth_map_mesh(&d, &g, &WallFrame::of(&s), &MeshOptions::default()).unwrap_err();
    assert!(e.to_string().contains("lower the threshold"), "{e}");
    assert!(depth_map(&v, 1.5).is_err());
    assert!(depth_map(&v, f32::NAN).is_err());
    assert!(confocal_scene(-1.0, 4, 4, 10, 0.01).is_err());
    assert!(downsample_time(&s.film, &[0.0; 5], 2).is_err());
}

#[test]
fn default_grid_covers_the_scan_and_the_films_depths() {
    let s = patch_scene("confocal", 0.0, 16);
    let g = VoxelGrid::for_scene(&s, [16, 16, 64]).unwrap();
    assert!((g.min.x + 0.4).abs() < 1e-6 && (g.max.y - 0.4).abs() < 1e-6);
    // OPL 0.8 .. 2.08 m: depths 0.4 .. 1.04 m.
    assert!(
        (g.min.z - 0.4).abs() < 1e-5 && (g.max.z - 1.04).abs() < 1e-5,
        "{g:?}"
    );
}

fn data_dir() -> PathBuf {
    common::shared_dir("UMBRA_LCT_DIR", "lct")
}

/// The diffuse letter S: FBP of the real capture, 8x coarser time (9.6 mm of OPL per
/// bin), the original code's first 600 bins of residual direct light zeroed. The
/// letter is a flat cut-out, so its columns share one depth; the LCT README puts the
/// scenes at roughly 0.3-0.5 m. Writes `recon_diffuse_s.png` (and `_depth.png`) to the
/// temp directory.
#[test]
fn lct_diffuse_s_letter_depth() {
    let path = data_dir().join("data_diffuse_s.mat");
    assert!(
        path.is_file(),
        "LCT data not found at {} (set UMBRA_LCT_DIR)",
        path.display()
    );
    let c = read_lct(&path).unwrap();
    let mut s = lct_scene(&c).unwrap();
    let mut data = c.transient.data;
    zero_bins_before(&mut data, s.film.temporal_bins as usize, 600);
    let (film, data) = downsample_time(&s.film, &data, 8).unwrap();
    s.film = film;
    let g = VoxelGrid::over_scan(&s, 0.2, 1.0, [32, 32, 64]).unwrap();
    let v = backproject(&s, &data, &g, Filter::DepthLaplacian).unwrap();
    let d = depth_map(&v, 0.3).unwrap();
    let dir = std::env::temp_dir();
    write_volume_png(&dir.join("recon_diffuse_s.png"), &v).unwrap();
    write_depth_png(&dir.join("recon_diffuse_s_depth.png"), &d).unwrap();

    let mut z: Vec<f32> = d.depth.iter().copied().filter(|z| z.is_finite()).collect();
    z.sort_by(f32::total_cmp);
    let q = |p: f32| z[((z.len() - 1) as f32 * p).round() as usize];
    eprintln!(
        "diffuse_s: {} of {} columns filled; depth 5/25/50/75/95 %: {:.3} {:.3} {:.3} {:.3} {:.3} m",
        z.len(),
        d.depth.len(),
        q(0.05),
        q(0.25),
        q(0.5),
        q(0.75),
        q(0.95)
    );
    // A letter: a good part of the scanned square, not all of it.
    let frac = z.len() as f32 / d.depth.len() as f32;
    assert!((0.1..0.7).contains(&frac), "filled fraction {frac}");
    // One depth, in the expected range.
    assert!((0.3..0.6).contains(&q(0.5)), "median depth {}", q(0.5));
    assert!(
        q(0.75) - q(0.25) < 0.03,
        "spread {} .. {}",
        q(0.25),
        q(0.75)
    );
    let mesh = depth_map_mesh(&d, &g, &WallFrame::of(&s), &MeshOptions::default()).unwrap();
    assert!(!mesh.triangles.is_empty());
}

/// Timing of the reference case (confocal 64 x 64 scan, 64³ voxels), and a finer
/// reconstruction of `diffuse_s` (full time resolution, 64 x 64 x 128 voxels) written to
/// `recon_diffuse_s_fine.png` in the temp directory; run with
/// `cargo test --release --test recon -- --ignored --nocapture`.
#[test]
#[ignore]
fn timing_confocal_64_scan_64_cubed() {
    let c = read_lct(&data_dir().join("data_diffuse_s.mat")).unwrap();
    let mut s = lct_scene(&c).unwrap();
    let mut data = c.transient.data;
    zero_bins_before(&mut data, s.film.temporal_bins as usize, 600);
    let g = VoxelGrid::over_scan(&s, 0.2, 1.0, [64, 64, 128]).unwrap();
    let t = std::time::Instant::now();
    std::hint::black_box(backproject(&s, &data, &g, Filter::DepthLaplacian).unwrap());
    eprintln!(
        "diffuse_s, 2048 bins, 64 x 64 x 128 voxels: {:.2} s",
        t.elapsed().as_secs_f64()
    );
    // Photon noise in 1.2 mm bins swamps the Laplacian: sum 8 bins and blur by one.
    let (film, data) = downsample_time(&s.film, &data, 8).unwrap();
    s.film = film;
    let opts = BackprojectOptions {
        filter: Filter::DepthLaplacian,
        time_sigma_opl: s.film.bin_width_opl,
        ..Default::default()
    };
    let v = backproject_with(&s, &data, &g, &opts).unwrap();
    write_volume_png(&std::env::temp_dir().join("recon_diffuse_s_fine.png"), &v).unwrap();

    for bins in [256usize, 2048] {
        let s = confocal_scene(0.35, 64, 64, bins, 2.4 / bins as f32).unwrap();
        let data: Vec<f32> = (0..64 * 64 * bins)
            .map(|i| ((i as u64).wrapping_mul(2_654_435_761) % 1000) as f32)
            .collect();
        let g = VoxelGrid::over_scan(&s, 0.2, 1.0, [64, 64, 64]).unwrap();
        for filter in [Filter::None, Filter::DepthLaplacian] {
            let t = std::time::Instant::now();
            let v = backproject(&s, &data, &g, filter).unwrap();
            let secs = t.elapsed().as_secs_f64();
            std::hint::black_box(v);
            eprintln!(
                "{bins} bins, {filter:?}: {secs:.2} s ({:.0} M voxel-measurement pairs/s)",
                (g.len() * 4096) as f64 / secs / 1e6
            );
        }
    }
}

/// `umbra recon --mesh` of a fit's mesh writes the mesh's albedo at each column's first
/// hit (`albedo.npy`, as the vertex colours say), on the depth map's columns: the value
/// where the square is, NaN beside it.
#[test]
fn recon_of_a_mesh_writes_its_albedo() {
    let dir = tmp_dir("recon-mesh-albedo");
    let scene = SceneSpec::default().write(&dir);
    // A 0.2 m square 0.6 m from the wall, every vertex of albedo 0.35.
    let obj = "v -0.1 -0.1 0.6 0.35 0.35 0.35\nv 0.1 -0.1 0.6 0.35 0.35 0.35\n\
               v 0.1 0.1 0.6 0.35 0.35 0.35\nv -0.1 0.1 0.6 0.35 0.35 0.35\nf 1 2 3\nf 1 3 4\n";
    let mesh = dir.join("fit.obj");
    std::fs::write(&mesh, obj).unwrap();
    let out = dir.join("out");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_umbra"))
        .arg("recon")
        .arg(&scene)
        .arg("--mesh")
        .arg(&mesh)
        .args(["--grid", "8,8,16", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    let albedo = umbra::io::read_npy(&out.join("albedo.npy")).unwrap();
    let depth = umbra::io::read_npy(&out.join("depth.npy")).unwrap();
    assert_eq!(albedo.shape, depth.shape);
    let hits = depth.data.iter().filter(|d| d.is_finite()).count();
    assert!(hits > 0 && hits < depth.data.len(), "{hits} columns hit");
    for (a, d) in albedo.data.iter().zip(&depth.data) {
        if d.is_finite() {
            assert!((a - 0.35).abs() < 1e-5, "albedo {a}");
        } else {
            assert!(a.is_nan(), "albedo {a} where nothing is hit");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
