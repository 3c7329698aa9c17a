//! Scenes exactly as y-tal 0.20.0 writes them for mitransient 1.3.1 (scenes/ytal/, made
//! by `tal render -r` from the YAMLs next to them, run in scenes/ytal/<kind>/ with the
//! mesh at `../meshes/plate.obj`): files found as Mitsuba finds them, y-tal's confocal
//! film (1x1 + original_film_*), its run-time laser aim (`-D laser_lookat_x/y`), `-D`
//! names the scene never uses, and non-NLOS sensors.

mod common;
use common::render;

use glam::Vec3;
use std::path::{Path, PathBuf};
use std::process::Command;
use umbra::bench::rel_l2;
use umbra::scene::mitsuba_xml::{load_in, parse_with_defines};
use umbra::scene::{CaptureType, Model, Scene};

fn ytal(p: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/ytal")).join(p)
}

const CONFOCAL: &str = "confocal/render/nlos_scene.xml";
const EXHAUSTIVE: &str = "exhaustive/render/nlos_scene.xml";

fn defs(d: &[(&str, &str)]) -> Vec<(String, String)> {
    d.iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect()
}

/// Loads a y-tal XML as if run where y-tal ran (the folder above the XML's).
fn load(xml: &str, d: &[(&str, &str)]) -> umbra::Result<Scene> {
    let kind = xml.split('/').next().unwrap();
    load_in(&ytal(xml), &defs(d), Some(&ytal(kind)))
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).length() < 1e-6
}

#[test]
fn relative_mesh_paths_are_found_in_the_working_directory_like_mitsuba() {
    let s = load(CONFOCAL, &[]).unwrap();
    assert_eq!(s.objects.len(), 1);
    // plate.obj's (-0.12, -0.12, 0) rotated 15° about x, then moved by (0.05, -0.03, 0.6).
    let (sin, cos) = 15f32.to_radians().sin_cos();
    let want = Vec3::new(-0.12 + 0.05, -0.12 * cos - 0.03, -0.12 * sin + 0.6);
    assert!(
        close(s.objects[0].mesh.positions[0], want),
        "{}",
        s.objects[0].mesh.positions[0]
    );

    // Run next to the XML: '../meshes/plate.obj' is in neither place; both are named.
    let dir = ytal("confocal/render");
    let e = load_in(&ytal(CONFOCAL), &[], Some(&dir))
        .unwrap_err()
        .to_string();
    for place in ["the XML file's folder", "the current working directory"] {
        assert!(e.contains(place), "{e}");
    }
    let tried = dir.join("../meshes/plate.obj").display().to_string();
    assert!(
        e.contains(&tried) && e.contains("nlos_scene.xml:27:"),
        "{e}"
    );

    // The CLI searches its working directory too.
    let bin = env!("CARGO_BIN_EXE_umbra");
    let out = std::env::temp_dir().join(format!("umbra-ytal-cwd-{}.npy", std::process::id()));
    let run = |cwd: &Path, xml: &str| {
        Command::new(bin)
            .current_dir(cwd)
            .args(["render", xml, "--model", "tri3", "--no-preview", "-q", "-o"])
            .arg(&out)
            .output()
            .unwrap()
    };
    let ok = run(&ytal("confocal"), "render/nlos_scene.xml");
    assert!(
        ok.status.success(),
        "{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    let bad = run(&dir, "nlos_scene.xml");
    assert_eq!(bad.status.code(), Some(1));
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(err.contains("the current working directory"), "{err}");
}

#[test]
fn a_path_element_is_searched_first() {
    // Mitsuba's <path value=".."/> (relative to the XML's folder) comes before the
    // XML's folder and the working directory.
    let text = std::fs::read_to_string(ytal(CONFOCAL)).unwrap();
    let text = text.replacen(
        "<integrator",
        "<path value=\"../../meshes\"/>\n    <integrator",
        1,
    );
    let text = text.replace("../meshes/plate.obj", "plate.obj");
    let s = parse_with_defines(&text, Path::new("p.xml"), &ytal("confocal/render"), &[]).unwrap();
    assert_eq!(s.objects.len(), 1);
    let e = parse_with_defines(
        &text.replace("../../meshes", "../nowhere"),
        Path::new("p.xml"),
        &ytal("confocal/render"),
        &[],
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("<path value=\"../nowhere\">: no such folder"),
        "{e}"
    );
}

#[test]
fn ytal_confocal_film_is_a_confocal_capture_of_the_original_size() {
    let s = load(CONFOCAL, &[]).unwrap();
    assert_eq!(s.capture, CaptureType::Confocal);
    assert_eq!((s.scan.nx, s.scan.ny), (4, 4));
    // Pixel centres of the 1 x 1 m wall (y-tal's scale 0.5).
    assert!(close(s.scan.point(0), Vec3::new(-0.375, -0.375, 0.0)));
    assert!(close(s.scan.point(6), Vec3::new(0.125, -0.125, 0.0)));
    assert_eq!(s.output_shape(), vec![4, 4, 64]);
    assert_eq!(s.render.spp, 4000);

    // One y-tal render: laser (and so the confocal point) aimed at pixel (2, 1).
    let one = load(
        CONFOCAL,
        &[("laser_lookat_x", "2.5"), ("laser_lookat_y", "1.5")],
    )
    .unwrap();
    assert_eq!(one.capture, CaptureType::Confocal);
    assert_eq!(one.output_shape(), vec![1, 1, 64]);
    assert!(close(one.scan.point(0), s.scan.point(6)));
    let (full, single) = (
        render(&s, Model::Tri3, 1, 0),
        render(&one, Model::Tri3, 1, 0),
    );
    let t = 64;
    let e = rel_l2(&full.data[6 * t..7 * t], &single.data);
    assert!(e < 1e-6, "pixel (2, 1): {e:e}");
    assert!(single.data.iter().any(|&v| v > 0.0));

    // A legacy confocal film must be 1x1.
    let text = std::fs::read_to_string(ytal(CONFOCAL)).unwrap().replacen(
        "<integer name=\"width\" value=\"1\"/>",
        "<integer name=\"width\" value=\"4\"/>",
        1,
    );
    let e = parse_with_defines(&text, Path::new("c.xml"), &ytal("confocal"), &[])
        .unwrap_err()
        .to_string();
    assert!(e.contains("must be 1 x 1"), "{e}");
}

#[test]
fn ytal_exhaustive_xml_renders_each_laser_point_as_ytal_aims_it() {
    // y-tal's exhaustive XML is its single-capture XML: the laser is aimed per laser
    // point at run time. Without an aim, y-tal's single default: the film's centre.
    let s = load(EXHAUSTIVE, &[]).unwrap();
    assert_eq!(s.capture, CaptureType::Single);
    assert!(close(s.laser.target, Vec3::ZERO));
    assert!(s.warnings.iter().any(|w| w.contains("laser_lookat_x")));

    // y-tal's laser point (3, 0) of its 4 x 4 laser grid: lookat ((3 + ½)/4 · 4, ½).
    let one = load(
        EXHAUSTIVE,
        &[("laser_lookat_x", "3.5"), ("laser_lookat_y", "0.5")],
    )
    .unwrap();
    assert_eq!(one.capture, CaptureType::Single);
    assert!(close(one.laser.target, Vec3::new(0.375, -0.375, 0.0)));
    assert!(!one.warnings.iter().any(|w| w.contains("translation only")));
    assert!(close(one.laser.origin, Vec3::new(0.25, -0.2, 0.35)));

    // y-tal's whole grid (laser grid = scan grid here), `-D scan_type=exhaustive` with
    // y-tal's YAML keys, is Umbra's exhaustive capture: its laser point (lx 3, ly 0) is
    // that single render.
    let exh = load(
        EXHAUSTIVE,
        &[
            ("scan_type", "exhaustive"),
            ("laser_width", "4"),
            ("laser_height", "4"),
        ],
    )
    .unwrap();
    assert_eq!(exh.capture, CaptureType::Exhaustive);
    assert_eq!(exh.output_shape(), vec![4, 4, 4, 4, 64]);
    assert_eq!(exh.scan, s.scan);
    let (all, single) = (
        render(&exh, Model::Tri3, 1, 0),
        render(&one, Model::Tri3, 1, 0),
    );
    let (n, t) = (16, 64);
    let mut slice = Vec::new();
    for sensor in 0..n {
        let m = sensor * n + 3; // (sy, sx, ly = 0, lx = 3)
        slice.extend_from_slice(&all.data[m * t..(m + 1) * t]);
    }
    let e = rel_l2(&slice, &single.data);
    assert!(e < 1e-6, "laser point (3, 0): {e:e}");

    // Both coordinates, numbers, on the film.
    for (d, want) in [
        (vec![("laser_lookat_x", "1.0")], "give both"),
        (
            vec![("laser_lookat_x", "x"), ("laser_lookat_y", "1")],
            "must be a number",
        ),
        (
            vec![("laser_lookat_x", "4.5"), ("laser_lookat_y", "1")],
            "must lie on the 4x4 film",
        ),
        // Umbra's exhaustive laser grid is the scan grid.
        (
            vec![("scan_type", "exhaustive"), ("laser_width", "2")],
            "y-tal's 2x4 laser grid",
        ),
        (
            vec![("laser_width", "4")],
            "go with -D scan_type=exhaustive",
        ),
        (vec![("scan_type", "confocal")], "only as 'exhaustive'"),
        (
            vec![
                ("scan_type", "exhaustive"),
                ("laser_lookat_x", "1"),
                ("laser_lookat_y", "1"),
            ],
            "exclude each other",
        ),
    ] {
        let e = load(EXHAUSTIVE, &d).unwrap_err().to_string();
        assert!(e.contains(want), "{e}");
    }
}

#[test]
fn the_shared_ytal_scene_aims_at_the_wall_centre_or_where_ytal_says() {
    let xml = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/ytal/nlos_scene.xml"
    ));
    let s = load_in(&xml, &[], None).unwrap();
    assert!(close(s.laser.target, Vec3::ZERO));
    // y-tal's single-capture default is the film's centre pixel coordinate (24 / 2).
    let d = defs(&[("laser_lookat_x", "12"), ("laser_lookat_y", "12")]);
    let t = load_in(&xml, &d, None).unwrap();
    assert!(close(t.laser.target, Vec3::ZERO));
    assert!(t.warnings.iter().all(|w| !w.contains("translation only")));
}

#[test]
fn defines_the_scene_never_uses_are_errors_naming_them() {
    let e = load(EXHAUSTIVE, &[("spp", "64")]).unwrap_err().to_string();
    assert!(e.contains("unused parameter(s) -D spp=64"), "{e}");
    // A scene with parameters lists them.
    let text = std::fs::read_to_string(ytal(EXHAUSTIVE))
        .unwrap()
        .replacen(
            "<integrator",
            "<default name=\"n\" value=\"4\"/>\n    <default name=\"bins\" value=\"64\"/>\n    <integrator",
            1,
        )
        .replacen("name=\"width\" value=\"4\"", "name=\"width\" value=\"$n\"", 1)
        .replacen(
            "name=\"temporal_bins\" value=\"64\"",
            "name=\"temporal_bins\" value=\"$bins\"",
            1,
        );
    let parse = |d: &[(&str, &str)]| {
        parse_with_defines(&text, Path::new("d.xml"), &ytal("exhaustive"), &defs(d))
    };
    assert_eq!(parse(&[("n", "2")]).unwrap().scan.nx, 2);
    let e = parse(&[("n", "2"), ("spp", "8"), ("sample", "1")])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("-D spp=8") && e.contains("-D sample=1") && !e.contains("-D n=2"),
        "{e}"
    );
    assert!(e.contains("<default>s: $n, $bins"), "{e}");
    // The CLI reports it too.
    let out = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .current_dir(ytal("exhaustive"))
        .args([
            "render",
            "render/nlos_scene.xml",
            "-D",
            "laser_lookat=3",
            "-o",
            "/dev/null",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("-D laser_lookat=3"), "{err}");
}

#[test]
fn a_perspective_sensor_is_named_as_unsupported() {
    // y-tal's steady_scene.xml (written next to its nlos_scene.xml): two perspective
    // cameras, the first at line 71.
    let e = load("exhaustive/render/steady_scene.xml", &[])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("steady_scene.xml:71: <sensor type=\"perspective\">: non-NLOS sensors are not supported"),
        "{e}"
    );
    let text = std::fs::read_to_string(ytal(EXHAUSTIVE)).unwrap();
    let top = text.replacen(
        "\n    <emitter",
        "\n    <sensor type=\"perspective\"><float name=\"fov\" value=\"30\"/></sensor>\n    <emitter",
        1,
    );
    let line = top.lines().position(|l| l.contains("perspective")).unwrap() + 1;
    let e = parse_with_defines(&top, Path::new("v.xml"), &ytal("exhaustive"), &[])
        .unwrap_err()
        .to_string();
    assert!(
        e.contains(&format!("v.xml:{line}:"))
            && e.contains("<sensor type=\"perspective\">: non-NLOS sensors are not supported"),
        "{e}"
    );
    let nested = text.replacen("nlos_capture_meter", "perspective", 1);
    let e = parse_with_defines(&nested, Path::new("v.xml"), &ytal("exhaustive"), &[])
        .unwrap_err()
        .to_string();
    assert!(e.contains("non-NLOS sensors are not supported"), "{e}");
}
