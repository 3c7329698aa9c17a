use super::*;
use std::path::PathBuf;

fn ytal_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/ytal"))
}

fn ytal_text() -> String {
    std::fs::read_to_string(ytal_dir().join("nlos_scene.xml")).unwrap()
}

fn parse_str(text: &str) -> Result<Scene> {
    parse(text, Path::new("t.xml"), &ytal_dir())
}

/// The y-tal scene with `old` replaced by `new` (once; `old` must be there).
fn edit(old: &str, new: &str) -> String {
    let t = ytal_text();
    assert!(t.contains(old), "{old}");
    t.replacen(old, new, 1)
}

/// The line and message of a line error.
fn err_line(r: Result<Scene>) -> (usize, String) {
    match r {
        Err(Error::Line { line, msg, .. }) => (line, msg),
        Err(e) => panic!("expected a line error, got {e}"),
        Ok(_) => panic!("expected an error"),
    }
}

fn close(a: Vec3, b: Vec3) -> bool {
    (a - b).length() < 1e-5
}

#[test]
fn ytal_example_loads() {
    let s = load(&ytal_dir().join("nlos_scene.xml")).unwrap();
    assert!(close(s.wall.center, Vec3::ZERO));
    assert!(close(s.wall.axis_u, Vec3::X) && close(s.wall.axis_v, Vec3::Y));
    assert_eq!(s.wall.albedo, 1.0);
    assert_eq!((s.scan.nx, s.scan.ny), (24, 24));
    assert!(close(s.scan.axis_u, Vec3::X) && close(s.scan.axis_v, Vec3::Y));
    // Pixel centres: the first scan point is at (-0.5 + 1/48, -0.5 + 1/48).
    assert!(close(
        s.scan.point(0),
        Vec3::new(-0.5 + 1.0 / 48.0, -0.5 + 1.0 / 48.0, 0.0)
    ));
    assert!(close(
        s.scan.point(1),
        Vec3::new(-0.5 + 3.0 / 48.0, -0.5 + 1.0 / 48.0, 0.0)
    ));
    assert!(close(s.laser.origin, Vec3::new(0.3, 0.2, 0.3)));
    assert!(close(s.laser.target, Vec3::ZERO)); // y-tal aims at the wall's centre.
    assert_eq!(
        s.laser.emission,
        LaserEmission::Irradiance {
            irradiance: 1.0,
            fov_deg: 0.2
        }
    );
    assert_eq!(s.laser.spot_radius, 0.0);
    assert!(close(s.detector.origin, Vec3::new(-0.5, 0.0, 0.25)));
    assert_eq!(s.capture, CaptureType::Single);
    assert_eq!(
        s.film,
        FilmSpec {
            temporal_bins: 300,
            bin_width_opl: 0.01,
            start_opl: 1.0,
            kernel: KernelSpec::Box
        }
    );
    assert!(!s.account_first_and_last_bounces);
    let r = &s.render;
    assert_eq!(
        (r.spp, r.seed, r.max_bounces, r.filter_bounces),
        (10000, 0, u32::MAX, None)
    );
    assert_eq!(
        (r.model, r.rr_bounces, r.discard_direct_paths),
        (Model::Path, 5, false)
    );
    assert_eq!(
        r.techniques,
        Techniques {
            laser_sampling: true,
            hidden_geometry_sampling: true,
            hidden_geometry_includes_wall: false,
            bsdf_sampling: false
        }
    );
    assert_eq!(s.objects.len(), 1);
    let l = &s.objects[0];
    assert_eq!((l.name.as_str(), l.albedo, l.two_sided), ("L", 1.0, false));
    assert_eq!(l.mesh.triangles.len(), 4);
    // v1 = (-0.15, -0.2, 0): rotated 20° about x, then moved by (0.05, -0.05, 0.8).
    let (c, sn) = (20f32.to_radians().cos(), 20f32.to_radians().sin());
    let v1 = Vec3::new(-0.1, -0.2 * c - 0.05, -0.2 * sn + 0.8);
    assert!(close(l.mesh.positions[0], v1), "{}", l.mesh.positions[0]);
    assert_eq!(s.warnings.len(), 1, "{:?}", s.warnings);
    assert!(
        s.warnings[0].contains("translation only"),
        "{:?}",
        s.warnings
    );
    assert!(s.warnings[0].starts_with(&format!(
        "{}:16:",
        ytal_dir().join("nlos_scene.xml").display()
    )));
}

fn xf(body: &str) -> Mat4 {
    let text = format!("<transform name=\"to_world\">{body}</transform>");
    let node = tree::parse(&text, Path::new("t.xml"), &[]).unwrap().root;
    let cx = Cx {
        origin: Path::new("t.xml"),
        warnings: Vec::new(),
    };
    params::transform(&cx, &node).unwrap()
}

#[test]
fn transforms_compose_like_mitsuba() {
    // Reference values from Mitsuba 3.9.1 (rectangle.sample_position of local points).
    let m =
        xf(r#"<translate x="1" y="2" z="3"/><rotate y="1" angle="90"/><scale x="2" y="3" z="4"/>"#);
    assert!(close(
        m.transform_point3(Vec3::new(1.0, 1.0, 0.0)),
        Vec3::new(6.0, 9.0, -8.0)
    ));
    assert!(close(
        m.transform_point3(Vec3::ZERO),
        Vec3::new(6.0, 6.0, -4.0)
    ));
    let m = xf(r#"<matrix value="1 0 0 5  0 2 0 6  0 0 3 7  0 0 0 1"/><scale value="2"/>"#);
    assert!(close(
        m.transform_point3(Vec3::new(1.0, 1.0, 0.0)),
        Vec3::new(12.0, 16.0, 14.0)
    ));
    let m = xf(r#"<rotate value="0, 0, 1" angle="90"/><translate value="1 0 0"/>"#);
    assert!(close(m.transform_point3(Vec3::X), Vec3::new(1.0, 1.0, 0.0)));
}

#[test]
fn lookat_matches_mitsuba() {
    let m = xf(r#"<lookat origin="1, 2, 3" target="1, 2, 0"/>"#);
    assert!(close(
        m.transform_point3(Vec3::ZERO),
        Vec3::new(1.0, 2.0, 3.0)
    ));
    assert!(close(m.transform_vector3(Vec3::X), Vec3::Y));
    assert!(close(m.transform_vector3(Vec3::Y), Vec3::X));
    assert!(close(m.transform_vector3(Vec3::Z), -Vec3::Z));
    let m = xf(r#"<lookat origin="1, 2, 3" target="2, 4, 0"/>"#);
    let x = m.transform_vector3(Vec3::X);
    let y = m.transform_vector3(Vec3::Y);
    assert!(
        (x - Vec3::new(-0.079287, 0.84143, 0.53452)).length() < 1e-4,
        "{x}"
    );
    assert!(
        (y - Vec3::new(0.96036, -0.079289, 0.26726)).length() < 1e-4,
        "{y}"
    );
    let m = xf(r#"<lookat origin="0, 0, 1" target="0, 0, 0" up="0, 1, 0"/>"#);
    assert!(close(m.transform_vector3(Vec3::X), -Vec3::X));
    assert!(close(m.transform_vector3(Vec3::Y), Vec3::Y));
}

#[test]
fn laser_lookat_sets_target() {
    let t = edit(
        r#"<translate x="0.3"
                       y="0.2"
                       z="0.3"/>"#,
        r#"<lookat origin="0.3, 0.2, 0.3" target="0.1, -0.1, 0" up="0, 1, 0"/>"#,
    );
    let s = parse_str(&t).unwrap();
    assert!(close(s.laser.origin, Vec3::new(0.3, 0.2, 0.3)));
    assert!(
        close(s.laser.target, Vec3::new(0.1, -0.1, 0.0)),
        "{}",
        s.laser.target
    );
    assert!(s.warnings.is_empty(), "{:?}", s.warnings);
}

#[test]
fn laser_pointing_away_or_off_the_wall_is_an_error() {
    let away = edit(
        r#"<translate x="0.3"
                       y="0.2"
                       z="0.3"/>"#,
        r#"<lookat origin="0.3, 0.2, 0.3" target="0.3, 0.2, 1"/>"#,
    );
    let (line, msg) = err_line(parse_str(&away));
    assert_eq!(line, 16, "{msg}");
    assert!(msg.contains("points away"), "{msg}");
    let off = edit(
        r#"<translate x="0.3"
                       y="0.2"
                       z="0.3"/>"#,
        r#"<lookat origin="0.3, 0.2, 0.3" target="3, 0.2, 0"/>"#,
    );
    let (line, msg) = err_line(parse_str(&off));
    assert_eq!(line, 16, "{msg}");
    assert!(msg.contains("outside the wall"), "{msg}");
    // In confocal capture the projector's aim does not matter.
    let confocal = away.replace(
        r#"<string name="temporal_filter" value="box"/>"#,
        r#"<string name="temporal_filter" value="box"/><string name="capture_type" value="confocal"/>"#,
    );
    assert_eq!(parse_str(&confocal).unwrap().capture, CaptureType::Confocal);
}

#[test]
fn mirrored_wall_keeps_mitsubas_front_and_film_orientation() {
    let t = edit(
        r#"<scale x="0.5" y="0.5" z="1"/>"#,
        r#"<scale x="-0.5" y="0.5" z="1"/>"#,
    );
    let s = parse_str(&t).unwrap();
    assert!(close(s.wall.normal(), Vec3::Z));
    assert!(close(s.scan.axis_u, -Vec3::X) && close(s.scan.axis_v, Vec3::Y));
    // Film pixel (0, 0) is at local (-1 + 1/24, -1 + 1/24), mirrored in x.
    assert!(close(
        s.scan.point(0),
        Vec3::new(0.5 - 1.0 / 48.0, -0.5 + 1.0 / 48.0, 0.0)
    ));
}

#[test]
fn depth_conversion() {
    // Laser sampling on: three bounces = max_depth 3, filter_bounces 2 (filter_depth 3).
    assert_eq!(mitransient_depth_to_bounces(3, Some(3), true), (3, Some(3)));
    assert_eq!(
        mitransient_depth_to_bounces(-1, None, true),
        (u32::MAX, None)
    );
    // Laser sampling off: three bounces = max_depth 4, filter_bounces 1 (filter_depth 2).
    assert_eq!(
        mitransient_depth_to_bounces(4, Some(2), false),
        (3, Some(3))
    );
    assert_eq!(
        mitransient_depth_to_bounces(-1, None, false),
        (u32::MAX, None)
    );
    let t = edit(
        r#"<integer name="max_depth" value="-1"/>
        <integer name="filter_bounces" value="-1"/>"#,
        r#"<integer name="max_depth" value="4"/>
        <integer name="filter_bounces" value="2"/>"#,
    );
    let r = parse_str(&t).unwrap().render;
    assert_eq!((r.max_bounces, r.filter_bounces), (4, Some(3)));
    let t = t.replace(
        r#"name="nlos_laser_sampling" value="true""#,
        r#"name="nlos_laser_sampling" value="false""#,
    );
    // Laser sampling off: filter_bounces 2 is four bounces, more than max_depth 4 allows.
    assert_eq!(err_line(parse_str(&t)).0, 6);
    let t = t.replace(
        r#"name="max_depth" value="4""#,
        r#"name="max_depth" value="5""#,
    );
    let r = parse_str(&t).unwrap().render;
    assert_eq!((r.max_bounces, r.filter_bounces), (4, Some(4)));
    let t = edit(
        r#"name="max_depth" value="-1""#,
        r#"name="max_depth" value="2""#,
    );
    assert_eq!(err_line(parse_str(&t)).0, 5);
}

#[test]
fn defaults_are_substituted() {
    let t = edit(
        r#"<scene version="3.9.1">"#,
        r#"<scene version="3.9.1"><default name="spp" value="123"/><default name="w" value="0.5"/>"#,
    )
    .replace(r#"name="sample_count" value="10000""#, r#"name="sample_count" value="$spp""#)
    .replace(r#"<scale x="0.5" y="0.5" z="1"/>"#, r#"<scale x="$w" y="$w" z="1"/>"#);
    let s = parse_str(&t).unwrap();
    assert_eq!(s.render.spp, 123);
    assert!(close(s.wall.axis_u, Vec3::X));
    let t = edit(
        r#"name="sample_count" value="10000""#,
        r#"name="sample_count" value="$nope""#,
    );
    let (line, msg) = err_line(parse_str(&t));
    assert_eq!(line, 56, "{msg}");
    assert!(msg.contains("$nope"), "{msg}");
}

#[test]
fn errors_name_the_line() {
    let cases = [
        // Unknown element.
        (
            edit("    <!-- L -->", "    <texture type=\"bitmap\"/>"),
            25,
            "<texture>",
        ),
        // Unknown parameter.
        (
            edit(
                r#"<float name="start_opl" value="1.0"/>"#,
                r#"<float name="start_opl" value="1.0"/><float name="exposure" value="1"/>"#,
            ),
            72,
            "exposure",
        ),
        // Bad float.
        (
            edit(
                r#"<float name="fov" value="0.2"/>"#,
                r#"<float name="fov" value="abc"/>"#,
            ),
            22,
            "'abc'",
        ),
        // NaN in a transform, and inf in an attribute on a continuation line.
        (
            edit(r#"<translate x="0.05""#, r#"<translate x="nan""#),
            37,
            "nan",
        ),
        (edit(r#"y="0.2""#, r#"y="inf""#), 18, "inf"),
        // Missing OBJ file.
        (edit("./L.obj", "./missing.obj"), 27, "missing.obj"),
        // Wrong parameter type.
        (
            edit(
                r#"<integer name="width" value="24"/>"#,
                r#"<float name="width" value="24"/>"#,
            ),
            66,
            "width",
        ),
        // Unsupported BSDF, unknown attribute, malformed XML.
        (
            edit(r#"<bsdf type="diffuse">"#, r#"<bsdf type="conductor">"#),
            29,
            "conductor",
        ),
        (
            edit(
                r#"<rotate x="1" angle="20.0"/>"#,
                r#"<rotate x="1" angle="20.0" deg="1"/>"#,
            ),
            34,
            "deg",
        ),
        (edit("</sensor>", "</sensr>"), 77, "malformed XML"),
    ];
    for (text, want, needle) in cases {
        let (line, msg) = err_line(parse_str(&text));
        assert_eq!(line, want, "{msg}");
        assert!(msg.contains(needle), "{msg} lacks {needle}");
    }
}

#[test]
fn bsdf_refs_twosided_and_rgb() {
    let t = edit(
        "    <!-- L -->",
        r#"<bsdf type="twosided" id="grey"><bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.3, 0.4"/></bsdf></bsdf>"#,
    )
    .replacen(
        r#"<bsdf type="diffuse">
            <rgb name="reflectance" value="1.0, 1.0, 1.0"/>
        </bsdf>"#,
        r#"<ref id="grey"/>"#,
        1,
    );
    let s = parse_str(&t).unwrap();
    let o = &s.objects[0];
    assert!((o.albedo - 0.3).abs() < 1e-6 && o.two_sided);
    assert!(
        s.warnings.iter().any(|w| w.contains("mean")),
        "{:?}",
        s.warnings
    );
    let bad = t.replace(r#"<ref id="grey"/>"#, r#"<ref id="gray"/>"#);
    assert_eq!(err_line(parse_str(&bad)).0, 29);
}

#[test]
fn hidden_rectangle_and_gaussian_kernel() {
    let t = edit(
        "    <!-- L -->",
        r#"<shape type="rectangle"><transform name="to_world"><scale value="0.1"/><translate z="0.5"/></transform></shape>"#,
    )
    .replace(
        r#"<string name="temporal_filter" value="box"/>"#,
        r#"<string name="temporal_filter" value="gaussian"/><float name="gaussian_stddev" value="0.02"/>"#,
    );
    let s = parse_str(&t).unwrap();
    assert_eq!(s.film.kernel, KernelSpec::Gaussian { sigma_opl: 0.02 });
    let r = &s.objects[0];
    assert_eq!(r.mesh.triangles.len(), 2);
    assert!((r.mesh.area(0) + r.mesh.area(1) - 0.04).abs() < 1e-6);
    let [a, b, c] = r.mesh.triangle(0);
    assert!((b - a).cross(c - a).z > 0.0);
    assert!(
        s.warnings.iter().any(|w| w.contains("gaussian")),
        "{:?}",
        s.warnings
    );
}

#[test]
fn flip_normals_and_smooth_normal_warning() {
    // A hidden rectangle facing away from the wall unless flipped.
    let plate = r#"<shape type="rectangle"><transform name="to_world"><scale value="0.1"/><translate z="0.5"/></transform>FLIP</shape>"#;
    let with = |flip: &str| edit("    <!-- L -->", &plate.replace("FLIP", flip));
    let front = |s: &Scene| {
        let [a, b, c] = s.objects[0].mesh.triangle(0);
        (b - a).cross(c - a).z
    };
    assert!(front(&parse_str(&with("")).unwrap()) > 0.0);
    let flipped = with(r#"<boolean name="flip_normals" value="true"/>"#);
    assert!(front(&parse_str(&flipped).unwrap()) < 0.0);
    // A flipped relay wall faces -z: the laser and detector are then behind it.
    let wall = edit(
        r#"<sensor type="nlos_capture_meter">"#,
        r#"<boolean name="flip_normals" value="true"/><sensor type="nlos_capture_meter">"#,
    );
    let (line, msg) = err_line(parse_str(&wall));
    assert_eq!(line, 16, "{msg}");
    assert!(msg.contains("behind"), "{msg}");
    // A bent OBJ without face_normals: Mitsuba would shade it with smoothed normals.
    let dir = std::env::temp_dir().join(format!("umbra_xml_test_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(
        dir.join("bent.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\n",
    )
    .unwrap();
    let t = ytal_text().replace("./L.obj", "bent.obj").replace(
        r#"<scale x="1.0" y="1.0" z="1.0"/>"#,
        r#"<scale value="0.1"/>"#,
    );
    let s = parse(&t, Path::new("t.xml"), &dir).unwrap();
    assert!(
        s.warnings.iter().any(|w| w.contains("smoothed")),
        "{:?}",
        s.warnings
    );
    let t = t.replace(
        r#"<string name="filename" value="bent.obj"/>"#,
        r#"<string name="filename" value="bent.obj"/><boolean name="face_normals" value="true"/>"#,
    );
    let s = parse(&t, Path::new("t.xml"), &dir).unwrap();
    assert!(
        !s.warnings.iter().any(|w| w.contains("smoothed")),
        "{:?}",
        s.warnings
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn hidden_geometry_flags_need_hidden_geometry_sampling() {
    // mitransient ignores do_rroulette and includes_relay_wall without HGS; they are
    // still known parameters.
    let t = edit(
        r#"name="nlos_hidden_geometry_sampling" value="true""#,
        r#"name="nlos_hidden_geometry_sampling" value="false""#,
    )
    .replace(
        r#"name="nlos_hidden_geometry_sampling_includes_relay_wall" value="false""#,
        r#"name="nlos_hidden_geometry_sampling_includes_relay_wall" value="true""#,
    );
    let tech = parse_str(&t).unwrap().render.techniques;
    assert!(!tech.hidden_geometry_sampling && tech.bsdf_sampling);
    assert!(!tech.hidden_geometry_includes_wall);
    let t = edit(
        r#"name="nlos_hidden_geometry_sampling_includes_relay_wall" value="false""#,
        r#"name="nlos_hidden_geometry_sampling_includes_relay_wall" value="true""#,
    );
    let tech = parse_str(&t).unwrap().render.techniques;
    assert!(tech.hidden_geometry_sampling && tech.hidden_geometry_includes_wall);
}

#[test]
fn rectangles_extending_the_relay_wall_are_merged_into_it() {
    // The y-tal wall is 1 x 1 m at the origin (albedo 1). A 0.5 x 1 m strip to its right
    // in its plane, facing its way, with its BSDF, is more relay wall.
    let strip = |x: f32, rho: f32| {
        edit(
            "    <!-- L -->",
            &format!(
                r#"<shape type="rectangle"><transform name="to_world"><scale x="0.25" y="0.5" z="1"/><translate x="{x}"/></transform><bsdf type="diffuse"><float name="reflectance" value="{rho}"/></bsdf></shape>"#
            ),
        )
    };
    let s = parse_str(&strip(0.75, 1.0)).unwrap();
    assert_eq!(s.objects.len(), 1, "only the L is left");
    assert!(close(s.wall.center, Vec3::new(0.25, 0.0, 0.0)));
    assert!(close(s.wall.axis_u, Vec3::new(1.5, 0.0, 0.0)));
    assert!(close(s.wall.axis_v, Vec3::Y));
    // The scan stays on the sensor's rectangle.
    assert!(close(s.scan.center, Vec3::ZERO) && close(s.scan.axis_u, Vec3::X));
    assert!(s.warnings.iter().any(|w| w.contains("extend it")));
    // Another albedo, or a gap: a hidden object, the wall unchanged.
    for t in [strip(0.75, 0.5), strip(0.8, 1.0)] {
        let s = parse_str(&t).unwrap();
        assert_eq!(s.objects.len(), 2);
        assert!(close(s.wall.axis_u, Vec3::X) && close(s.wall.center, Vec3::ZERO));
    }
}
