//! The fitted surface seen from the wall (`fit::seen`): a flat board at a known depth
//! with a per-vertex albedo pattern, on a scan of 10 x 8 points, comes out as
//! `albedo.npy` / `depth.npy` in scan order (the measurement's `[iy, ix]`) and as the
//! view from the wall (`+x` to the left, `+y` up), for Umbra's scan orientation and the
//! Stanford LCT captures' (scan `u` along `−y`); and `umbra fit` writes the files.

mod common;

use optim::Mesh;
use std::path::Path;
use umbra::fit::reconstruction::write_reconstruction_png;
use umbra::fit::seen::{seen_surface, write_seen, SeenSurface, WallView};
use umbra::recon::WallFrame;
use umbra::scene::Scene;

/// The board's depth (m from the wall).
const Z: f64 = 0.6;

/// A confocal scan of 10 x 8 points at 0.1 m spacing (x from −0.45, y from −0.35) on
/// the wall z = 0 (normal +z, `+x` = `e_u`, `+y` = `e_v`).
fn scan_scene() -> Scene {
    common::scene(
        "capture_type = \"confocal\"\n[wall]\nsize = [2.0, 2.0]\n[laser]\norigin = [0.0, -1.0, 1.0]\n\
         [scan]\nresolution = [10, 8]\nsize = [1.0, 0.8]\n[film]\ntemporal_bins = 256\nbin_width_opl = 0.01\n",
        &[],
    )
}

/// The albedo pattern on the board, by wall point: a bright bar on the `+x` side (x ≥
/// 0.1), a mid-grey cap at the top left (x ≤ 0, y ≥ 0.1), dark elsewhere.
fn pattern(x: f64, y: f64) -> f64 {
    if x >= 0.1 - 1e-6 {
        0.9
    } else if x <= 1e-6 && y >= 0.1 - 1e-6 {
        0.5
    } else {
        0.1
    }
}

/// A square board of `n x n` vertices from `-half` to `half` on both axes at depth `z`,
/// facing the wall, each vertex carrying `albedo(x, y)`.
fn grid_board(n: usize, half: f64, z: f64, albedo: impl Fn(f64, f64) -> f64) -> Mesh {
    let at = |k: usize| -half + 2.0 * half * k as f64 / (n - 1) as f64;
    let mut vertices = Vec::new();
    let mut values = Vec::new();
    for j in 0..n {
        for i in 0..n {
            vertices.push([at(i), at(j), z]);
            values.push(albedo(at(i), at(j)));
        }
    }
    let mut faces = Vec::new();
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let a = (j * n + i) as u32;
            let (b, c, d) = (a + 1, a + 1 + n as u32, a + n as u32);
            faces.push([a, c, b]);
            faces.push([a, d, c]);
        }
    }
    let mut m = Mesh::new(vertices, faces);
    m.vertex_values = values;
    m
}

/// A board over `[-0.3, 0.3]²` at depth [`Z`], vertices every 0.1 m carrying
/// [`pattern`], facing the wall.
fn board() -> Mesh {
    grid_board(7, 0.3, Z, pattern)
}

/// What scan point `(x, y)` (wall frame) must see: `None` off the board; on it, the
/// depth and the albedo if the point is 0.05 m or more inside one region of the
/// pattern (all the vertices of its triangle in it), else `None` for the albedo.
fn expected(x: f64, y: f64) -> Option<(f64, Option<f64>)> {
    if x.abs() > 0.3 || y.abs() > 0.3 {
        return None;
    }
    let corners = [(-0.05, -0.05), (0.05, -0.05), (-0.05, 0.05), (0.05, 0.05)];
    let values: Vec<f64> = corners
        .iter()
        .map(|(dx, dy)| pattern(x + dx, y + dy))
        .collect();
    let uniform = values.iter().all(|v| *v == values[0]);
    Some((Z, uniform.then_some(values[0])))
}

/// Checks `seen` against [`expected`] at every scan point of `scene`, in scan order.
fn check_scan_order(scene: &Scene, seen: &SeenSurface) -> (usize, usize) {
    let frame = WallFrame::of(scene);
    let (mut on_board, mut exact) = (0, 0);
    for iy in 0..seen.ny {
        for ix in 0..seen.nx {
            let i = iy * seen.nx + ix;
            let q = frame.to_frame(scene.scan.point(i));
            let (d, a) = (seen.depth[i], seen.albedo[i]);
            match expected(q.x as f64, q.y as f64) {
                None => assert!(
                    d.is_nan() && a.is_nan(),
                    "[{iy}, {ix}] at {q}: off the board, got {d}, {a}"
                ),
                Some((z, albedo)) => {
                    on_board += 1;
                    assert!(
                        (d as f64 - z).abs() < 1e-4,
                        "[{iy}, {ix}] at {q}: depth {d}"
                    );
                    match albedo {
                        Some(v) => {
                            exact += 1;
                            assert!(
                                (a as f64 - v).abs() < 1e-5,
                                "[{iy}, {ix}] at {q}: {a} not {v}"
                            );
                        }
                        None => assert!((0.1..=0.9).contains(&a), "[{iy}, {ix}]: {a}"),
                    }
                }
            }
        }
    }
    (on_board, exact)
}

/// The view of `seen` from the wall: pixel `(r, c)` is the wall point `x = x_max − (c +
/// ½) dx` (`+x` to the left), `y = y_max − (r + ½) dy` (`+y` up), which must see what
/// [`expected`] says.
fn check_view(scene: &Scene, seen: &SeenSurface) {
    let view = WallView::of(scene);
    let image = view.show(&seen.albedo);
    let depth = view.show(&seen.depth);
    let [x0, x1, y0, y1] = view.extent;
    let (dx, dy) = (
        (x1 - x0) as f64 / view.width as f64,
        (y1 - y0) as f64 / view.height as f64,
    );
    assert!(
        (dx - 0.1).abs() < 1e-5 && (dy - 0.1).abs() < 1e-5,
        "{view:?}"
    );
    for r in 0..view.height {
        for c in 0..view.width {
            let x = x1 as f64 - (c as f64 + 0.5) * dx;
            let y = y1 as f64 - (r as f64 + 0.5) * dy;
            let (a, d) = (image[r * view.width + c], depth[r * view.width + c]);
            match expected(x, y) {
                None => assert!(a.is_nan() && d.is_nan(), "view ({r}, {c}) at ({x}, {y})"),
                Some((z, albedo)) => {
                    assert!((d as f64 - z).abs() < 1e-4);
                    if let Some(v) = albedo {
                        assert!((a as f64 - v).abs() < 1e-5, "view ({r}, {c}): {a} not {v}");
                    }
                }
            }
        }
    }
}

#[test]
fn a_board_with_a_bright_bar_is_seen_in_scan_order_and_from_the_wall() {
    let scene = scan_scene();
    let seen = seen_surface(&scene, &board(), 0.7);
    assert_eq!((seen.nx, seen.ny), (10, 8));
    let (on_board, exact) = check_scan_order(&scene, &seen);
    // x at ±0.05, ±0.15, ±0.25 and y likewise: 6 x 6 points on the board; the points
    // at x = 0.05 straddle the bar's edge, those at y = 0.05 (x < 0) the cap's.
    assert_eq!(on_board, 36);
    assert_eq!(exact, 36 - 6 - 3);
    // Umbra's scan runs ix along +x: the bar (x = 0.15, 0.25) is at ix 6 and 7, on
    // every row of the board (iy 1 to 6: y = -0.25 to 0.25); the cap is at ix 2, 3
    // (x = -0.25, -0.15) on iy 5, 6 (y = 0.15, 0.25).
    let at = |iy: usize, ix: usize| seen.albedo[iy * 10 + ix];
    let near = |a: f32, b: f32| (a - b).abs() < 1e-5;
    for iy in 1..=6 {
        assert!(near(at(iy, 6), 0.9) && near(at(iy, 7), 0.9), "row {iy}");
        assert!(at(iy, 0).is_nan() && at(iy, 9).is_nan());
    }
    assert!(near(at(6, 2), 0.5) && near(at(5, 3), 0.5) && near(at(1, 2), 0.1));
    // Seen from the wall (+x to the left): the bar in the view's columns 2 and 3.
    let view = WallView::of(&scene);
    assert_eq!((view.width, view.height), (10, 8));
    let image = view.show(&seen.albedo);
    assert_eq!(view.pixel(7, 6), (1, 2));
    assert!(near(image[10 + 2], 0.9) && near(image[6 * 10 + 3], 0.9));
    check_view(&scene, &seen);
    // As docs/FITTING.md says: this view is numpy's `albedo[::-1, ::-1]`.
    for (i, v) in image.iter().enumerate() {
        assert_eq!(v.to_bits(), seen.albedo[79 - i].to_bits());
    }
    // No per-vertex albedo: the fit's scalar albedo where the board is.
    let mut plain = board();
    plain.vertex_values.clear();
    let flat = seen_surface(&scene, &plain, 0.7);
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&flat.depth), bits(&seen.depth));
    assert!(flat
        .albedo
        .iter()
        .zip(&seen.depth)
        .all(|(a, d)| d.is_nan() == a.is_nan() && (d.is_nan() || near(*a, 0.7))));
}

/// The Stanford LCT captures' scan (`io::measured::lct_scan_grid`): `u` (ix) along −y,
/// `v` (iy) along +x. The arrays stay in scan order; the view turns them.
#[test]
fn a_scan_turned_as_the_lct_captures_keeps_scan_order_and_the_view_turns_it() {
    let mut scene = scan_scene();
    scene.scan.axis_u = glam::Vec3::new(0.0, -1.0, 0.0);
    scene.scan.axis_v = glam::Vec3::new(0.8, 0.0, 0.0);
    let seen = seen_surface(&scene, &board(), 0.7);
    let (on_board, _) = check_scan_order(&scene, &seen);
    assert_eq!(on_board, 36);
    // ix runs along -y (y = 0.45 - 0.1 ix), iy along +x (x = -0.35 + 0.1 iy): the bar
    // (x = 0.15, 0.25) is at iy 5, 6.
    assert!((seen.albedo[5 * 10 + 4] - 0.9).abs() < 1e-5);
    assert!((seen.albedo[6 * 10 + 7] - 0.9).abs() < 1e-5);
    let view = WallView::of(&scene);
    assert_eq!((view.width, view.height), (8, 10));
    check_view(&scene, &seen);
    // As docs/FITTING.md says: this view is numpy's `albedo.T[:, ::-1]`.
    let image = view.show(&seen.albedo);
    for r in 0..10 {
        for c in 0..8 {
            let scan = seen.albedo[(7 - c) * 10 + r];
            assert_eq!(image[r * 8 + c].to_bits(), scan.to_bits(), "({r}, {c})");
        }
    }
}

fn tmp(name: &str) -> std::path::PathBuf {
    common::tmp_dir(&format!("seen-{name}"))
}

/// The `.npy` header's dictionary.
fn npy_header(path: &Path) -> String {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..6], b"\x93NUMPY");
    let len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    String::from_utf8_lossy(&bytes[10..10 + len]).to_string()
}

#[test]
fn the_arrays_are_float32_c_order_ny_by_nx_and_the_pictures_are_drawn() {
    let scene = scan_scene();
    let seen = seen_surface(&scene, &board(), 0.7);
    let out = tmp("write");
    let files = write_seen(&out, &scene, &seen).unwrap();
    let names: Vec<_> = files.iter().map(|f| f.file_name().unwrap()).collect();
    assert_eq!(names, ["albedo.npy", "depth.npy", "albedo.png"]);
    for (name, values) in [("albedo.npy", &seen.albedo), ("depth.npy", &seen.depth)] {
        let header = npy_header(&out.join(name));
        assert!(header.contains("'descr': '<f4'"), "{header}");
        assert!(header.contains("'fortran_order': False"), "{header}");
        assert!(header.contains("'shape': (8, 10)"), "{header}");
        let t = umbra::io::read_npy(&out.join(name)).unwrap();
        assert_eq!(t.shape, [8, 10]);
        assert!(t
            .data
            .iter()
            .zip(values.iter())
            .all(|(a, b)| a.to_bits() == b.to_bits()));
    }
    // The figure beside a classical reconstruction: the LCT (confocal), and the
    // filtered backprojection for a single-spot capture.
    let spec = common::SceneSpec {
        scan: [6, 6],
        bins: 160,
        spp: 8,
        ..Default::default()
    };
    for capture in ["confocal", "single"] {
        let s = common::SceneSpec {
            capture,
            ..spec.clone()
        }
        .scene();
        let measured = common::render(&s, s.render.model, 8, 1).data;
        let base = Scene {
            objects: Vec::new(),
            ..s.clone()
        };
        let fitted = umbra::fit::fit_mesh(&s.objects[0].mesh);
        let seen = seen_surface(&base, &fitted, 0.8);
        assert!(
            seen.depth.iter().any(|d| (d - 0.6).abs() < 1e-4),
            "{capture}"
        );
        let png = out.join(format!("reconstruction_{capture}.png"));
        write_reconstruction_png(&png, &base, &measured, 0, &seen).unwrap();
        assert!(std::fs::metadata(&png).unwrap().len() > 1000);
    }
    let _ = std::fs::remove_dir_all(&out);
}

/// `umbra fit` on the built-in scene (a three-iteration coarse schedule): albedo.npy and
/// depth.npy of the scan's (ny, nx), float32, with the surface where it is, next to
/// albedo.png and reconstruction.png.
#[test]
fn cli_fit_writes_the_seen_surface() {
    let d = tmp("cli");
    let config = d.join("schedule.toml");
    std::fs::write(
        &config,
        "checkpoint_every = 2\n[[stage]]\niters = 3\nlr = 0.01\nlarge_steps = 10.0\ntime_downsample = 8\nscan_downsample = 4\n",
    )
    .unwrap();
    let out = d.join("out");
    let r = std::process::Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(["fit", "-q", "--target-spp", "16", "--config"])
        .arg(&config)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    for f in ["albedo.png", "reconstruction.png"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let albedo = umbra::io::read_npy(&out.join("albedo.npy")).unwrap();
    let depth = umbra::io::read_npy(&out.join("depth.npy")).unwrap();
    for (name, t) in [("albedo.npy", &albedo), ("depth.npy", &depth)] {
        assert!(npy_header(&out.join(name)).contains("'descr': '<f4'"));
        assert_eq!(t.shape, [32, 32], "{name}");
    }
    // The plane starts 1 m out, in front of part of the scan (1.6 m wide) only.
    let hits: Vec<(f32, f32)> = albedo
        .data
        .iter()
        .zip(&depth.data)
        .filter(|(_, d)| d.is_finite())
        .map(|(a, d)| (*a, *d))
        .collect();
    assert!(
        !hits.is_empty() && hits.len() < 32 * 32,
        "{} hits",
        hits.len()
    );
    assert!(albedo
        .data
        .iter()
        .zip(&depth.data)
        .all(|(a, d)| a.is_nan() == d.is_nan()));
    assert!(hits
        .iter()
        .all(|(a, d)| (0.0..=1.0).contains(a) && *d > 0.5 && *d < 1.5));
    let _ = std::fs::remove_dir_all(&d);
}

/// The bar chart's albedo at wall point `x`: three bright bars 8 cm wide, 8 cm apart
/// (albedo 1, centred at x = -0.16, 0, 0.16) on a board of 0.25.
fn bars(x: f64) -> f64 {
    if [-0.16, 0.0, 0.16]
        .iter()
        .any(|c| (x - c).abs() <= 0.04 + 1e-9)
    {
        1.0
    } else {
        0.25
    }
}

/// The board of [`bars`] over `[-0.22, 0.22]²`, 0.5 m from the wall, facing it, as OBJ
/// text with the albedo as each vertex's colour (vertices every 2 cm).
fn bar_chart_obj() -> String {
    grid_board(23, 0.22, 0.5, |x, _| bars(x)).to_obj()
}

/// The mean of `values` (ny x nx, scan order) over the columns `x` of the 16 scan points
/// at 3.75 cm (x from -0.28) within 3 cm of `centre`, the rows within 15 cm of the middle.
fn band_mean(values: &[f32], centre: f64) -> f64 {
    let x = |i: usize| -0.3 + 0.0375 * (i as f64 + 0.5);
    let mut picked = Vec::new();
    for iy in (0..16).filter(|&j| x(j).abs() <= 0.15) {
        for ix in (0..16).filter(|&i| (x(i) - centre).abs() <= 0.03) {
            picked.push(f64::from(values[iy * 16 + ix]));
        }
    }
    assert!(
        picked.iter().all(|v| v.is_finite()),
        "no surface at {centre}: {picked:?}"
    );
    picked.iter().sum::<f64>() / picked.len() as f64
}

/// Issue 48's "small bar chart resolved": the bars of [`bars`], scanned confocally 16 x 16
/// over 0.6 m, rendered by tri3 as Poisson counts (200 at the brightest bin, a floor of
/// 0.5), fitted by `umbra fit` from the LCT start with the defaults for a `.npy`
/// measurement (L2, a constant background; the Poisson deviance needs the capture model's
/// direct returns, which this render has not). Each bar's fitted albedo (seen from the
/// wall) is brighter than each gap beside it, and the gap-to-bar ratio is at most Umbra's
/// LCT's of the same counts: measured 0.37 (0.39 from a plane) against the LCT's 0.92,
/// true 0.25.
#[test]
fn a_small_bar_chart_is_resolved_in_the_fitted_albedo() {
    use common::SceneSpec;
    use umbra::scene::Model;
    let d = tmp("bars");
    let spec = SceneSpec {
        scan: [16, 16],
        scan_size: 0.6,
        bins: 80,
        bin_width: 0.01,
        start_opl: 0.85,
        sigma_opl: None,
        objects: vec![(bar_chart_obj(), 1.0, "lambertian")],
        model: "tri3",
        render_extra: vec!["visible_legs = false".into()],
        ..SceneSpec::default()
    };
    let scene_path = spec.write(&d);
    let scene = spec.scene();
    let t = common::render(&scene, Model::Tri3, 1, 0);
    let peak = t.data.iter().copied().fold(0.0f32, f32::max);
    assert!(peak > 0.0);
    let mu = t.data.iter().map(|&v| f64::from(v / peak) * 200.0 + 0.5);
    let counts = umbra::transport::Transient {
        data: umbra::fit::linear_fit::poisson_counts(mu, 7),
        shape: t.shape.clone(),
    };
    let measured = d.join("bars.npy");
    umbra::io::write_npy(&measured, &counts).unwrap();
    let out = d.join("out");
    let r = std::process::Command::new(env!("CARGO_BIN_EXE_umbra"))
        .arg("fit")
        .arg(&scene_path)
        .arg("--measured")
        .arg(&measured)
        .args(["--init", "lct", "-q", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let albedo = umbra::io::read_npy(&out.join("albedo.npy")).unwrap().data;
    // Umbra's LCT of the same counts (floor subtracted, SNR 0.1), its brightest voxel per column.
    let mut data = counts.data.clone();
    umbra::recon::subtract_floor(&mut data, 80);
    let grid = umbra::recon::VoxelGrid::over_scan(&scene, 0.425, 0.825, [16, 16, 80]).unwrap();
    let volume =
        umbra::recon::lct(&scene, &data, &grid, &umbra::recon::LctOptions { snr: 0.1 }).unwrap();
    let lct: Vec<f32> = (0..256)
        .map(|c| {
            volume
                .column(c % 16, c / 16)
                .iter()
                .copied()
                .fold(0.0, f32::max)
        })
        .collect();
    let contrast = |v: &[f32]| -> f64 {
        let b: Vec<f64> = [-0.16, 0.0, 0.16]
            .iter()
            .map(|&c| band_mean(v, c))
            .collect();
        let g: Vec<f64> = [-0.08, 0.08].iter().map(|&c| band_mean(v, c)).collect();
        eprintln!("bars {b:.3?}, gaps {g:.3?}");
        assert!(
            g[0] < b[0].min(b[1]) && g[1] < b[1].min(b[2]),
            "a gap as bright as a bar"
        );
        g.iter().sum::<f64>() / b.iter().sum::<f64>() * 1.5
    };
    let (fit, reference) = (contrast(&albedo), contrast(&lct));
    eprintln!("gap / bar albedo: fit {fit:.3}, LCT {reference:.3}, true 0.25");
    assert!(
        fit <= reference,
        "the fit's bars ({fit}) less resolved than the LCT's ({reference})"
    );
    let _ = std::fs::remove_dir_all(&d);
}
