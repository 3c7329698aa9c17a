//! y-tal's HDF5 captures (io::ytal) and measured-data reading (io::measured): the capture
//! y-tal wrote in ../shared/data/ytal, write -> read round trips for every capture type,
//! bad files, scene checks, and the LCT capture through `read_measured`.
//! UMBRA_YTAL_DIR / UMBRA_LCT_DIR override the data directories.

mod common;
use common::{capture::small_capture, shared_dir};

use glam::Vec3;
use std::path::PathBuf;
use umbra::io::measured::{read_measured, Measured};
use umbra::io::ytal::{read_ytal, write_ytal};
use umbra::scene::{default::default_scene, CaptureType, Scene};
use umbra::transport::Transient;

use rust_hdf5::H5File;

fn lscene() -> PathBuf {
    let p = shared_dir("UMBRA_YTAL_DIR", "ytal").join("lscene.hdf5");
    assert!(
        p.is_file(),
        "y-tal data not found at {} (set UMBRA_YTAL_DIR)",
        p.display()
    );
    p
}

fn tmp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("umbra-ytal-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn close(a: Vec3, b: Vec3, tol: f32) -> bool {
    a.distance(b) <= tol
}

#[test]
fn reads_the_capture_ytal_wrote() {
    let path = lscene();
    let m = read_ytal(&path).unwrap();
    assert_eq!(m.transient.shape, vec![24, 24, 300]);
    assert_eq!(m.capture, Some(CaptureType::Single));
    let g = m.scan.as_ref().unwrap();
    assert_eq!((g.nx, g.ny), (24, 24));
    assert!(close(g.center, Vec3::ZERO, 1e-6), "{}", g.center);
    assert!(close(g.axis_u, Vec3::X, 1e-5), "{}", g.axis_u);
    assert!(close(g.axis_v, Vec3::Y, 1e-5), "{}", g.axis_v);
    assert!(close(m.laser_point.unwrap(), Vec3::ZERO, 1e-6));
    assert!(m.laser_grid.is_none());
    assert_eq!(m.bin_width_opl, Some(0.01));
    assert_eq!(m.start_opl, Some(1.0));
    assert_eq!(m.account_first_and_last_bounces, Some(false));
    assert_eq!(m.laser_origin, Some(Vec3::new(0.3, 0.2, 0.3)));
    assert_eq!(m.detector_origin, Some(Vec3::new(-0.5, 0.0, 0.25)));
    assert!(
        m.transient.data.iter().all(|v| v.is_finite()) && m.transient.data.iter().any(|&v| v > 0.0)
    );

    // Layout: Umbra (sy, sx, T) is y-tal's H (T, Sx, Sy) transposed.
    let h: Vec<f32> = H5File::open(&path)
        .unwrap()
        .dataset("H")
        .unwrap()
        .read_raw()
        .unwrap();
    for (ix, iy, t) in [(0, 0, 0), (3, 17, 120), (20, 5, 299), (11, 12, 150)] {
        assert_eq!(
            m.transient.data[(iy * 24 + ix) * 300 + t],
            h[(t * 24 + ix) * 24 + iy]
        );
    }
    // read_measured dispatches .hdf5 here.
    assert_eq!(
        read_measured(&path).unwrap().transient.data,
        m.transient.data
    );

    // A scene for it, from any base: single capture, the file's grid, film and laser spot.
    let s = m.scene_for(&default_scene().unwrap()).unwrap();
    assert_eq!(s.capture, CaptureType::Single);
    assert_eq!(s.output_shape(), vec![24, 24, 300]);
    assert_eq!((s.film.start_opl, s.film.bin_width_opl), (1.0, 0.01));
    m.check_against(&s).unwrap();
}

#[test]
fn write_then_read_gives_the_same_capture() {
    let dir = tmp_dir("roundtrip");
    for capture in [
        CaptureType::Single,
        CaptureType::Confocal,
        CaptureType::Exhaustive,
    ] {
        let (scene, t) = small_capture(capture);
        let path = dir.join(format!("{}.hdf5", capture.name()));
        write_ytal(&path, &t, &scene).unwrap();
        let m = read_ytal(&path).unwrap();
        assert_eq!(m.capture, Some(capture));
        assert_eq!(m.transient.shape, t.shape);
        assert!(
            m.transient
                .data
                .iter()
                .zip(&t.data)
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "{capture:?}: the transient changed"
        );
        let g = m.scan.as_ref().unwrap();
        assert_eq!((g.nx, g.ny), (3, 2));
        assert!(close(g.center, scene.scan.center, 1e-6));
        assert!(close(g.axis_u, scene.scan.axis_u, 1e-6));
        assert!(close(g.axis_v, scene.scan.axis_v, 1e-6));
        assert_eq!(m.bin_width_opl, Some(0.003));
        assert_eq!(m.start_opl, Some(0.85));
        assert_eq!(
            m.account_first_and_last_bounces,
            Some(scene.account_first_and_last_bounces)
        );
        match capture {
            CaptureType::Single => assert_eq!(m.laser_point, Some(scene.laser.target)),
            CaptureType::Confocal => assert!(m.laser_point.is_none() && m.laser_grid.is_none()),
            CaptureType::Exhaustive => {
                assert!(close(
                    m.laser_grid.as_ref().unwrap().center,
                    scene.scan.center,
                    1e-6
                ))
            }
        }
        assert_eq!(m.laser_origin, Some(scene.laser.origin));
        assert_eq!(m.detector_origin, Some(scene.detector.origin));
        m.check_against(&scene).unwrap();
        let mut base = default_scene().unwrap();
        base.laser.origin = Vec3::new(5.0, 5.0, 5.0);
        base.detector.origin = Vec3::new(-5.0, 5.0, 5.0);
        let again = m.scene_for(&base).unwrap();
        assert_eq!(
            (again.capture, again.output_shape()),
            (capture, t.shape.clone())
        );
        // The file's laser and detector replace the base scene's.
        assert_eq!(again.laser.origin, scene.laser.origin);
        assert_eq!(again.detector.origin, scene.detector.origin);
        // A scene that counts the first and last legs from elsewhere is refused, naming
        // the field.
        let mut moved = scene.clone();
        moved.account_first_and_last_bounces = true;
        moved.laser.origin += Vec3::new(0.0, 0.0, 0.5);
        if m.account_first_and_last_bounces == Some(true) {
            let e = m.check_against(&moved).unwrap_err().to_string();
            assert!(e.contains("laser_xyz") && e.contains("laser.origin"), "{e}");
        }
        // No temporary file is left beside the output.
        let leftovers: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp"))
            .collect();
        assert!(leftovers.is_empty());
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn exhaustive_h_is_t_lx_ly_sx_sy() {
    let dir = tmp_dir("exhaustive");
    let (scene, t) = small_capture(CaptureType::Exhaustive);
    let path = dir.join("e.h5");
    umbra::io::write_capture(&path, &t, &scene).unwrap();
    let f = H5File::open(&path).unwrap();
    let ds = f.dataset("H").unwrap();
    assert_eq!(ds.shape(), vec![7, 3, 2, 3, 2]);
    let h: Vec<f32> = ds.read_raw().unwrap();
    let (nx, ny, bins) = (3, 2, 7);
    for (lx, ly, sx, sy, b) in [(0, 0, 0, 0, 0), (2, 1, 0, 1, 3), (1, 0, 2, 1, 6)] {
        let umbra = t.data[(((sy * nx + sx) * ny + ly) * nx + lx) * bins + b];
        let ytal = h[(((b * nx + lx) * ny + ly) * nx + sx) * ny + sy];
        assert_eq!(umbra, ytal);
    }
    let g: Vec<f32> = f.dataset("sensor_grid_xyz").unwrap().read_raw().unwrap();
    // [x, y] indexing: element [2, 0] is scan point ix = 2, iy = 0.
    let p = scene.scan.point(2);
    assert_eq!(&g[(2 * ny) * 3..(2 * ny) * 3 + 3], &p.to_array());
    std::fs::remove_dir_all(&dir).ok();
}

/// Opens `path` for writing, lets `change` edit it, and closes it.
fn edit(path: &std::path::Path, change: impl FnOnce(&H5File)) {
    let f = H5File::open_rw(path).unwrap();
    change(&f);
    f.close().unwrap();
}

/// A dataset's type as far as h5py and y-tal see it: the class, and for an enum its base
/// and its (name, value) members in name order.
fn kind(f: &H5File, name: &str) -> String {
    use rust_hdf5::DatatypeMessage as T;
    let ds = f.dataset(name).unwrap();
    let space = if ds.is_null() {
        "null".to_string()
    } else {
        format!("{}-d", ds.ndims())
    };
    let t = match ds.datatype().unwrap() {
        T::Enum { base, members } => {
            let mut m: Vec<_> = members.iter().map(|m| (&m.name, &m.value)).collect();
            m.sort();
            format!("enum {base} {m:?}")
        }
        T::FloatingPoint { size, .. } => format!("float{}", size * 8),
        T::FixedPoint { .. } => "integer".to_string(),
        other => other.to_string(),
    };
    format!("{t}, {space}")
}

#[test]
fn written_fields_have_the_types_ytal_writes() {
    // y-tal's own file is the reference: the same datasets, enums with the same members,
    // h5py's bool, the NULL volume_format and a vlen string scene_info.
    let ytal = H5File::open(lscene()).unwrap();
    let dir = tmp_dir("types");
    let (scene, t) = small_capture(CaptureType::Single);
    let path = dir.join("single.hdf5");
    write_ytal(&path, &t, &scene).unwrap();
    let ours = H5File::open(&path).unwrap();
    let mut names = ytal.dataset_names();
    names.sort();
    let mut our_names = ours.dataset_names();
    our_names.sort();
    assert_eq!(our_names, names);
    for name in &names {
        let (want, got) = (kind(&ytal, name), kind(&ours, name));
        match name.as_str() {
            // y-tal's render stored its normals as integers; Umbra's are float32.
            "laser_grid_normals" | "sensor_grid_normals" => assert_eq!(got, "float32, 3-d"),
            // h5py writes a scalar string, rust-hdf5 a (1,) array of one (y-tal squeezes it).
            "scene_info" => {
                assert!(
                    want.starts_with("vlen_string") && want.ends_with("0-d"),
                    "{want}"
                );
                assert_eq!(got, want.replace("0-d", "1-d"));
            }
            _ => assert_eq!(got, want, "{name}"),
        }
    }
    let info = ours
        .dataset("scene_info")
        .unwrap()
        .read_vlen_strings()
        .unwrap();
    assert!(
        info.len() == 1 && info[0].starts_with("generator: umbra"),
        "{info:?}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn truncated_or_garbled_files_are_errors_naming_the_file() {
    let dir = tmp_dir("garbled");
    let (scene, t) = small_capture(CaptureType::Confocal);
    let good = dir.join("good.hdf5");
    write_ytal(&good, &t, &scene).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    let bad = dir.join("bad.hdf5");
    let mut rejected = 0;
    for k in 0..16 {
        std::fs::write(&bad, &bytes[..bytes.len() * k / 16]).unwrap();
        let e = message(read_ytal(&bad));
        assert!(e.contains("bad.hdf5"), "{e}");
        rejected += 1;
    }
    // y-tal's file (h5py, superblock version 0) one byte short.
    let ytal = std::fs::read(lscene()).unwrap();
    std::fs::write(&bad, &ytal[..ytal.len() - 1]).unwrap();
    let e = message(read_ytal(&bad));
    assert!(e.contains("bad.hdf5") && e.contains("truncated"), "{e}");
    // Flip bytes through the metadata (a panic here fails the test); a flip the reader
    // cannot see may still read, anything else must be an error naming the file.
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    for _ in 0..200 {
        let mut b = bytes.clone();
        for _ in 0..3 {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            let i = (state >> 33) as usize % b.len().min(4096);
            b[i] ^= (state >> 17) as u8 | 1;
        }
        std::fs::write(&bad, &b).unwrap();
        if let Err(e) = read_ytal(&bad) {
            assert!(e.to_string().contains("bad.hdf5"), "{e}");
            rejected += 1;
        }
    }
    assert!(rejected > 16, "no garbled file was refused");
    std::fs::remove_dir_all(&dir).ok();
}

fn message(r: umbra::Result<Measured>) -> String {
    match r {
        Ok(_) => panic!("a bad file was accepted"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_files_name_the_file_and_the_dataset() {
    let dir = tmp_dir("bad");
    let (scene, t) = small_capture(CaptureType::Confocal);

    let no_h = dir.join("no_h.hdf5");
    {
        let f = H5File::create(&no_h).unwrap();
        f.new_dataset::<f64>()
            .scalar()
            .create("delta_t")
            .unwrap()
            .write_raw(&[0.01])
            .unwrap();
        f.close().unwrap();
    }
    let e = message(read_ytal(&no_h));
    assert!(
        e.contains("no_h.hdf5") && e.contains("H:") && e.contains("missing"),
        "{e}"
    );

    let wrong_format = dir.join("wrong_format.hdf5");
    write_ytal(&wrong_format, &t, &scene).unwrap();
    edit(&wrong_format, |f| {
        f.delete_dataset("H_format").unwrap();
        f.new_dataset::<i32>()
            .shape([1])
            .create("H_format")
            .unwrap()
            .write_raw(&[3])
            .unwrap();
    });
    let e = message(read_ytal(&wrong_format));
    assert!(
        e.contains("wrong_format.hdf5") && e.contains("H_format") && e.contains("T_Si"),
        "{e}"
    );

    let irregular = dir.join("irregular.hdf5");
    write_ytal(&irregular, &t, &scene).unwrap();
    let mut g: Vec<f32> = H5File::open(&irregular)
        .unwrap()
        .dataset("sensor_grid_xyz")
        .unwrap()
        .read_raw()
        .unwrap();
    g[3] += 0.05; // point [0, 1] moves 5 cm along x
    edit(&irregular, |f| {
        let ds = f.dataset_writer("sensor_grid_xyz").unwrap();
        ds.write_raw(&g).unwrap();
    });
    let e = message(read_ytal(&irregular));
    assert!(
        e.contains("irregular.hdf5") && e.contains("sensor_grid_xyz") && e.contains("regular"),
        "{e}"
    );

    let mismatched = dir.join("mismatched.hdf5");
    write_ytal(&mismatched, &t, &scene).unwrap();
    edit(&mismatched, |f| {
        f.delete_dataset("laser_grid_xyz").unwrap();
        f.new_dataset::<f32>()
            .shape([2, 2, 3])
            .create("laser_grid_xyz")
            .unwrap()
            .write_raw(&[0.0f32; 12])
            .unwrap();
    });
    let e = message(read_ytal(&mismatched));
    assert!(e.contains("laser_grid_xyz") && e.contains("neither"), "{e}");

    let not_hdf5 = dir.join("text.hdf5");
    std::fs::write(&not_hdf5, "not hdf5").unwrap();
    let e = message(read_ytal(&not_hdf5));
    assert!(e.contains("text.hdf5") && e.contains("HDF5"), "{e}");

    let e = message(read_measured(&dir.join("capture.csv")));
    assert!(e.contains("capture.csv") && e.contains(".hdf5"), "{e}");

    // Writing a transient that does not fit the scene is an error, not a file.
    let bad = Transient {
        data: vec![0.0; 6],
        shape: vec![1, 2, 3],
    };
    let out = dir.join("never.hdf5");
    assert!(write_ytal(&out, &bad, &scene)
        .unwrap_err()
        .to_string()
        .contains("never.hdf5"));
    assert!(!out.exists());
    std::fs::remove_dir_all(&dir).ok();
}

fn mismatch(m: &Measured, scene: &Scene) -> String {
    m.check_against(scene).unwrap_err().to_string()
}

#[test]
fn check_against_names_what_disagrees() {
    let m = read_ytal(&lscene()).unwrap();
    let good = m.scene_for(&default_scene().unwrap()).unwrap();
    m.check_against(&good).unwrap();

    let mut s = good.clone();
    s.film.bin_width_opl = 0.02;
    let e = mismatch(&m, &s);
    assert!(
        e.contains("lscene.hdf5") && e.contains("delta_t") && e.contains("film.bin_width_opl"),
        "{e}"
    );

    let mut s = good.clone();
    s.film.start_opl = 0.9;
    let e = mismatch(&m, &s);
    assert!(e.contains("t_start") && e.contains("film.start_opl"), "{e}");

    let mut s = good.clone();
    s.film.temporal_bins = 512;
    let e = mismatch(&m, &s);
    assert!(e.contains("H:") && e.contains("temporal_bins 512"), "{e}");

    let mut s = good.clone();
    s.capture = CaptureType::Confocal;
    let e = mismatch(&m, &s);
    assert!(
        e.contains("single") && e.contains("capture_type is confocal"),
        "{e}"
    );

    let mut s = good.clone();
    s.scan.center.x += 0.01;
    let e = mismatch(&m, &s);
    assert!(
        e.contains("sensor_grid_xyz") && e.contains("scan point"),
        "{e}"
    );

    let mut s = good.clone();
    s.laser.target = Vec3::new(0.2, 0.0, 0.0);
    let e = mismatch(&m, &s);
    assert!(
        e.contains("laser_grid_xyz") && e.contains("laser.target"),
        "{e}"
    );

    let mut s = good.clone();
    s.account_first_and_last_bounces = true;
    let e = mismatch(&m, &s);
    assert!(e.contains("t_accounts_first_and_last_bounces"), "{e}");
}

fn lct_file() -> PathBuf {
    let p = shared_dir("UMBRA_LCT_DIR", "lct").join("data_diffuse_s.mat");
    assert!(
        p.is_file(),
        "LCT data not found at {} (set UMBRA_LCT_DIR)",
        p.display()
    );
    p
}

#[test]
fn lct_capture_reads_with_its_geometry() {
    let path = lct_file();
    let m = read_measured(&path).unwrap();
    let lct = umbra::io::lct::read_lct(&path).unwrap();
    assert_eq!(m.transient.shape, vec![64, 64, 2048]);
    assert_eq!(m.transient.data, lct.transient.data);
    assert_eq!(m.capture, Some(CaptureType::Confocal));
    assert_eq!(
        (m.start_opl, m.bin_width_opl),
        (Some(0.0), Some(umbra::io::lct::LCT_BIN_OPL))
    );
    assert_eq!(m.account_first_and_last_bounces, Some(false));
    let g = m.scan.as_ref().unwrap();
    let w = lct.width;
    assert_eq!((g.nx, g.ny), (64, 64));
    // rect_data(i, j) sits at (x, y) = (p_i, -p_j), p = linspace(-width, width, 64);
    // Umbra's layout keeps sy = i, sx = j.
    let at = |i: usize, j: usize| g.point(i * 64 + j);
    assert!(close(at(0, 0), Vec3::new(-w, w, 0.0), 1e-5), "{}", at(0, 0));
    assert!(
        close(at(63, 0), Vec3::new(w, w, 0.0), 1e-5),
        "{}",
        at(63, 0)
    );
    assert!(
        close(at(0, 63), Vec3::new(-w, -w, 0.0), 1e-5),
        "{}",
        at(0, 63)
    );
    assert!(
        g.axis_u.cross(g.axis_v).normalize().distance(Vec3::Z) < 1e-6,
        "mirrored grid"
    );

    let s = m.scene_for(&default_scene().unwrap()).unwrap();
    assert_eq!(
        (s.capture, s.output_shape()),
        (CaptureType::Confocal, vec![64, 64, 2048])
    );
    assert_eq!(s.film.start_opl, 0.0);
    m.check_against(&s).unwrap();
}

#[test]
fn npy_is_a_bare_transient() {
    let dir = tmp_dir("npy");
    let (scene, t) = small_capture(CaptureType::Confocal);
    let path = dir.join("h.npy");
    umbra::io::write_capture(&path, &t, &scene).unwrap();
    let m = read_measured(&path).unwrap();
    assert_eq!(
        (m.transient.shape.clone(), m.capture),
        (t.shape.clone(), None)
    );
    assert!(m.scan.is_none() && m.start_opl.is_none());
    m.check_against(&scene).unwrap();
    let s = m.scene_for(&scene).unwrap();
    assert_eq!(s.scan, scene.scan);
    let mut wrong = scene.clone();
    wrong.scan.nx = 5;
    let e = m.scene_for(&wrong).unwrap_err().to_string();
    assert!(e.contains("h.npy") && e.contains("scan.resolution"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn write_transient_refuses_hdf5_without_a_scene() {
    let t = Transient {
        data: vec![0.0; 2],
        shape: vec![1, 1, 2],
    };
    let dir = tmp_dir("no-scene");
    let e = umbra::io::write_transient(&dir.join("x.hdf5"), &t);
    assert!(e.unwrap_err().to_string().contains("scene"));
    std::fs::remove_dir_all(&dir).ok();
}
