//! The Mitsuba XML exporter (`scene::mitsuba_xml::write`): a scene written for mitransient
//! and read back by Umbra's importer is the same scene (geometry, capture, film,
//! depths, techniques), and renders the same; what mitransient cannot express is refused
//! naming the field.

mod common;
use common::*;
use umbra::bench::rel_l2;
use umbra::scene::mitsuba_xml::write::write;
use umbra::scene::{LaserEmission, Model, Scene};

const TENT: &str = "v -0.2 -0.15 0.9\nv 0.2 -0.15 0.9\nv 0.2 0.15 0.7\nv -0.2 0.15 0.7\n\
                    v 0.0 0.3 0.8\nf 1 4 3 2\nf 4 5 3\n";

fn toml(capture: &str, scan: f32, laser: &str, extra_render: &str, kernel: &str) -> String {
    format!(
        r#"
capture_type = "{capture}"
[wall]
size = [1.2, 1.0]
albedo = 0.7
[laser]
origin = [0.1, -0.4, 1.2]
target = [0.2, 0.1, 0.0]
{laser}
[detector]
origin = [-0.3, 0.2, 1.1]
[scan]
resolution = [6, 5]
size = [{scan}, 1.0]
[film]
temporal_bins = 120
bin_width_opl = 0.01
start_opl = 1.2
{kernel}
[[objects]]
file = "tent.obj"
albedo = 0.6
two_sided = true
[[objects]]
file = "square.obj"
albedo = 0.9
[render]
spp = 32
seed = 5
max_bounces = 5
{extra_render}
"#
    )
}

fn objs() -> Vec<(&'static str, String)> {
    vec![
        ("tent.obj", TENT.to_string()),
        ("square.obj", square_obj([0.3, 0.0, 1.1], 0.2)),
    ]
}

fn scratch(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("umbra-export-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn build(toml: &str) -> umbra::Result<Scene> {
    let o = objs();
    let refs: Vec<(&str, &str)> = o.iter().map(|(a, b)| (*a, b.as_str())).collect();
    try_scene(toml, &refs)
}

fn round_trip(scene: &Scene, dir: &std::path::Path) -> Scene {
    let out = write(scene, &dir.join("exported.xml")).expect("export");
    assert_eq!(out.objs.len(), scene.objects.len());
    Scene::load(&out.xml).unwrap_or_else(|e| panic!("re-import: {e}"))
}

/// Export -> import gives the same scene; tri3 renders agree to `tol` (relative L2).
fn assert_same_scene(a: &Scene, b: &Scene, capture: &str, tol: f64) {
    assert_eq!(a.capture, b.capture);
    assert_eq!(a.wall, b.wall, "{capture}");
    assert_eq!(a.scan, b.scan);
    assert_eq!(a.detector, b.detector);
    assert_eq!(a.film, b.film);
    assert_eq!(a.laser.origin, b.laser.origin);
    // An unset fov (0) is written as 0.2° (a footprint mitransient needs; the
    // laser-sampled signal does not depend on it), with a warning.
    let mut emission = a.laser.emission;
    if let LaserEmission::Irradiance { fov_deg, .. } = &mut emission {
        if *fov_deg == 0.0 {
            *fov_deg = 0.2;
        }
    }
    assert_eq!(emission, b.laser.emission);
    if a.capture == umbra::scene::CaptureType::Single {
        assert!((a.laser.target - b.laser.target).length() < 1e-6);
    }
    assert_eq!(a.render.max_bounces, b.render.max_bounces);
    assert_eq!(a.render.filter_bounces, b.render.filter_bounces);
    assert_eq!(a.render.spp, b.render.spp);
    assert_eq!(a.render.seed, b.render.seed);
    assert_eq!(a.objects.len(), b.objects.len());
    for (x, y) in a.objects.iter().zip(&b.objects) {
        assert_eq!(x.mesh.positions, y.mesh.positions);
        assert_eq!(x.mesh.triangles, y.mesh.triangles);
        assert_eq!((x.albedo, x.two_sided), (y.albedo, y.two_sided));
    }
    let ra = render(a, Model::Tri3, 1, 0);
    let rb = render(b, Model::Tri3, 1, 0);
    let e = rel_l2(&ra.data, &rb.data);
    assert!(e <= tol, "{capture}: tri3 renders differ by {e:e}");
    assert!(ra.data.iter().any(|&v| v > 0.0));
}

#[test]
fn a_wall_larger_than_its_scan_is_written_as_the_scan_plus_the_rest_and_read_back() {
    // mitransient scans the whole rectangle its sensor sits in: the exporter writes the
    // scanned rectangle as the relay wall and the rest of the wall as plain rectangles
    // of the same BSDF; the importer merges them back into the same wall.
    let dir = scratch("rest");
    let a = build(&toml("confocal", 0.8, "irradiance = 1.0", "", "")).unwrap();
    let out = write(&a, &dir.join("partial.xml")).expect("export");
    let text = std::fs::read_to_string(&out.xml).unwrap();
    // 0.8 of a 1.2 m wide, 1.0 m high wall, centred: a strip left and one right.
    assert_eq!(text.matches("relay_wall_rest_").count(), 2, "{text}");
    let b = Scene::load(&out.xml).unwrap();
    assert_same_scene(&a, &b, "partial scan", 0.0);
    // An off-centre scan gives four strips (two of them full height).
    let mut c = a.clone();
    c.scan.center += glam::Vec3::new(0.1, 0.0, 0.0);
    c.scan.axis_v *= 0.5;
    c.scan.center += glam::Vec3::new(0.0, -0.2, 0.0);
    let out = write(&c, &dir.join("off.xml")).expect("export");
    let text = std::fs::read_to_string(&out.xml).unwrap();
    assert_eq!(text.matches("relay_wall_rest_").count(), 4, "{text}");
    let d = Scene::load(&out.xml).unwrap();
    // The merged wall is computed from the strips' corners: equal to f32 rounding.
    assert!((c.wall.center - d.wall.center).length() < 1e-6);
    assert!((c.wall.axis_u - d.wall.axis_u).length() < 1e-6);
    assert!((c.wall.axis_v - d.wall.axis_v).length() < 1e-6);
    assert_eq!(c.scan, d.scan);
    assert!(d.objects.len() == c.objects.len());
    let e = rel_l2(
        &render(&c, Model::Tri3, 1, 0).data,
        &render(&d, Model::Tri3, 1, 0).data,
    );
    assert!(e <= 1e-5, "off-centre scan: tri3 renders differ by {e:e}");
}

#[test]
fn the_default_scene_is_exported_and_reads_back_the_same() {
    let dir = scratch("default");
    let a = umbra::scene::default::default_scene().unwrap();
    let out = write(&a, &dir.join("default.xml")).expect("export");
    let b = Scene::load(&out.xml).unwrap();
    assert_same_scene(&a, &b, "default scene", 0.0);
}

#[test]
fn export_and_reimport_give_the_same_scene_and_the_same_render() {
    let dir = scratch("rt");
    for (capture, extra) in [("confocal", ""), ("single", "filter_bounces = 3")] {
        let a = build(&toml(
            capture,
            1.2,
            "irradiance = 2.5\nfov = 3.0",
            extra,
            "",
        ))
        .unwrap();
        let b = round_trip(&a, &dir);
        assert_eq!(a.capture, b.capture);
        assert_eq!(a.wall, b.wall, "{capture}");
        assert_eq!(a.scan, b.scan);
        assert_eq!(a.detector, b.detector);
        assert_eq!(a.film, b.film);
        assert_eq!(a.laser.origin, b.laser.origin);
        assert_eq!(a.laser.emission, b.laser.emission);
        if capture == "single" {
            assert!((a.laser.target - b.laser.target).length() < 1e-6);
        }
        assert_eq!(a.render.max_bounces, b.render.max_bounces);
        assert_eq!(a.render.filter_bounces, b.render.filter_bounces);
        assert_eq!(a.render.spp, b.render.spp);
        assert_eq!(a.render.seed, b.render.seed);
        assert_eq!(a.objects.len(), b.objects.len());
        for (x, y) in a.objects.iter().zip(&b.objects) {
            assert_eq!(x.mesh.positions, y.mesh.positions);
            assert_eq!(x.mesh.triangles, y.mesh.triangles);
            assert_eq!((x.albedo, x.two_sided), (y.albedo, y.two_sided));
        }
        // mitransient has no MIS: the file asks for hidden-geometry sampling alone.
        let t = &b.render.techniques;
        assert!(t.laser_sampling && t.hidden_geometry_sampling && !t.bsdf_sampling);
        // Same scene, same render: deterministic tri3 bit for bit, Monte Carlo path
        // with the importer's techniques on both sides.
        let mut settings = b.render.clone();
        settings.techniques = a.render.techniques.clone();
        assert_eq!(a.render, settings, "{capture}");
        let ra = render(&a, Model::Tri3, 1, 0);
        let rb = render(&b, Model::Tri3, 1, 0);
        // Single capture: the importer finds the laser spot by intersecting the beam
        // with the wall, within an ulp of the original (above), so the renders agree
        // to f32 rounding; confocal renders are identical.
        let tol = if capture == "single" { 1e-5 } else { 0.0 };
        let e = rel_l2(&ra.data, &rb.data);
        assert!(e <= tol, "{capture}: tri3 renders differ by {e:e}");
        assert!(ra.data.iter().any(|&v| v > 0.0));
        let mut a_hgs = a.clone();
        a_hgs.render.techniques = b.render.techniques.clone();
        let (pa, pb) = (
            render(&a_hgs, Model::Path, 16, 3),
            render(&b, Model::Path, 16, 3),
        );
        let e = rel_l2(&pa.data, &pb.data);
        assert!(e <= tol, "{capture}: path renders differ by {e:e}");
    }
}

#[test]
fn depths_round_trip_without_laser_sampling_and_unbounded() {
    // Laser sampling off shifts mitransient's depths by one (the importer's
    // mitransient_depth_to_bounces); unbounded depth is max_depth = -1.
    let dir = scratch("depths");
    let mut a = build(&toml(
        "confocal",
        1.2,
        "irradiance = 1.0",
        "filter_bounces = 4",
        "",
    ))
    .unwrap();
    a.render.techniques.laser_sampling = false;
    let b = round_trip(&a, &dir);
    assert_eq!(
        (b.render.max_bounces, b.render.filter_bounces),
        (5, Some(4))
    );
    assert!(!b.render.techniques.laser_sampling);
    a.render.max_bounces = u32::MAX;
    a.render.filter_bounces = None;
    let b = round_trip(&a, &dir);
    assert_eq!(
        (b.render.max_bounces, b.render.filter_bounces),
        (u32::MAX, None)
    );
}

#[test]
fn a_gaussian_kernel_is_written_with_a_warning_and_read_back() {
    let dir = scratch("gauss");
    let a = build(&toml(
        "confocal",
        1.2,
        "irradiance = 1.0",
        "",
        "kernel = \"gaussian\"\nsigma_opl = 0.012",
    ))
    .unwrap();
    let out = write(&a, &dir.join("g.xml")).unwrap();
    assert!(out
        .warnings
        .iter()
        .any(|w| w.contains("mitransient 1.3.1 bins with a box")));
    let b = Scene::load(&out.xml).unwrap();
    assert_eq!(a.film, b.film);
}

#[test]
fn what_mitransient_cannot_express_is_refused_naming_the_field() {
    let dir = scratch("refuse");
    let xml = dir.join("r.xml");
    let field = |s: Scene| match write(&s, &xml) {
        Err(umbra::Error::Field { field, .. }) => field,
        Err(e) => panic!("expected a field error, got {e}"),
        Ok(_) => panic!("expected a refusal"),
    };
    let mut outside = build(&toml("confocal", 0.8, "irradiance = 1.0", "", "")).unwrap();
    outside.scan.center.x += 0.3; // 0.3 + 0.4 > 0.6: past the wall's edge.
    assert_eq!(field(outside.clone()), "scan");
    outside.scan.center.x -= 0.3;
    outside.scan.axis_u = glam::Vec3::new(0.0, 0.8, 0.0);
    outside.scan.axis_v = glam::Vec3::new(-1.0, 0.0, 0.0); // rotated by 90°
    assert_eq!(field(outside), "scan");
    let by_power = build(&toml("confocal", 1.2, "power = 1.0", "", "")).unwrap();
    assert_eq!(field(by_power), "laser.power");
    let mut filtered = build(&toml("confocal", 1.2, "irradiance = 1.0", "", "")).unwrap();
    filtered.render.filter_bounces = Some(1);
    assert_eq!(field(filtered.clone()), "render.filter_bounces");
    filtered.render.filter_bounces = Some(6);
    assert_eq!(
        field(filtered),
        "render.filter_bounces",
        "beyond max_bounces = 5"
    );
    let mut no_rr = build(&toml("confocal", 1.2, "irradiance = 1.0", "", "")).unwrap();
    no_rr.render.rr_bounces = 0;
    assert_eq!(field(no_rr), "render.rr_bounces");
    let mut retro = build(&toml("confocal", 1.2, "irradiance = 1.0", "", "")).unwrap();
    retro.objects[1].reflectance = umbra::scene::Reflectance::RETRO;
    assert_eq!(field(retro), "objects[1]");
    assert!(
        !dir.join("r_0.obj").exists(),
        "nothing written for a refused scene"
    );
}

#[test]
fn cli_export_writes_a_scene_umbra_reads_back_and_the_default_scene() {
    let dir = scratch("cli");
    for (name, text) in objs() {
        std::fs::write(dir.join(name), text).unwrap();
    }
    let toml_path = dir.join("s.toml");
    std::fs::write(
        &toml_path,
        toml("confocal", 1.2, "irradiance = 1.0", "", ""),
    )
    .unwrap();
    let xml = dir.join("s.xml");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args([
            "export-mitsuba",
            toml_path.to_str().unwrap(),
            "-o",
            xml.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let back = Scene::load(&xml).unwrap();
    assert_eq!(back.objects.len(), 2);
    // The default scene scans 1.6 m of a 2 m wall: the rest of the wall is written as
    // four plain rectangles.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(["export-mitsuba", "-o", dir.join("d.xml").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let back = Scene::load(&dir.join("d.xml")).unwrap();
    let default = umbra::scene::default::default_scene().unwrap();
    assert_eq!(back.wall, default.wall);
    assert_eq!(back.scan, default.scan);
}
