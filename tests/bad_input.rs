//! Bad scene input gives one clear error naming the file and the field or line, never
//! a panic; the TOML and OBJ readers survive mutated input (proptest).

mod common;
use common::*;
use proptest::prelude::*;
use std::path::Path;
use std::process::Command;
use umbra::geometry::mesh::TriMesh;

const GOOD: &str = r#"
capture_type = "single"
[wall]
size = [2.0, 2.0]
[laser]
origin = [0.0, 0.0, 1.0]
target = [0.1, 0.0, 0.0]
[scan]
resolution = [2, 2]
[film]
temporal_bins = 10
bin_width_opl = 0.1
[[objects]]
file = "sq.obj"
transform = { translate = [0.0, 0.0, 1.0] }
"#;

fn err_of(toml: &str) -> String {
    let sq = square_obj([0.0, 0.0, 0.0], 0.2);
    match try_scene(toml, &[("sq.obj", &sq)]) {
        Ok(_) => panic!("accepted bad input:\n{toml}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn good_scene_loads() {
    let sq = square_obj([0.0, 0.0, 0.0], 0.2);
    try_scene(GOOD, &[("sq.obj", &sq)]).unwrap();
}

#[test]
fn errors_name_file_and_field() {
    let cases = [
        (
            GOOD.replace("temporal_bins = 10", "temporal_bins = -4"),
            "test.toml: film.temporal_bins: must be a positive count, got -4",
        ),
        (
            GOOD.replace("origin = [0.0, 0.0, 1.0]", "origin = [0.0, 0.0, -1.0]"),
            "test.toml: laser.origin: the laser is behind",
        ),
        (
            GOOD.replace("translate = [0.0, 0.0, 1.0]", "translate = [0.0, nan, 1.0]"),
            "test.toml: objects[0].transform: translate must be finite",
        ),
        (
            GOOD.replace("bin_width_opl = 0.1", "bin_width_opl = 0.0"),
            "test.toml: film.bin_width_opl: must be > 0",
        ),
        (
            GOOD.replace("capture_type = \"single\"", "capture_type = \"sweep\""),
            "test.toml: capture_type: 'sweep' is not one of",
        ),
        (
            GOOD.replace("target = [0.1, 0.0, 0.0]", "target = [0.1, 0.0, 0.5]"),
            "test.toml: laser.target: the laser target",
        ),
        (
            GOOD.replace("[film]", "[film]\nkernel = \"gaussian\""),
            "test.toml: film.sigma_opl: kernel = \"gaussian\" needs sigma_opl",
        ),
        (
            format!("{GOOD}\n[render]\nspp = 0\n"),
            "test.toml: render.spp: must be at least 1",
        ),
    ];
    for (toml, want) in cases {
        let e = err_of(&toml);
        assert!(e.starts_with(want), "got: {e}\nwant: {want}");
    }
    // A typo is an error with its line, not a silent default.
    let e = err_of(&GOOD.replace("bin_width_opl", "bin_widht_opl"));
    assert!(
        e.starts_with("test.toml:") && e.contains("bin_widht_opl"),
        "{e}"
    );
    let e = err_of(&GOOD.replace("[scan]", "[scan"));
    assert!(e.starts_with("test.toml:8:"), "{e}");
}

#[test]
fn missing_and_malformed_files() {
    let dir = std::env::temp_dir().join(format!("umbra-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // Missing scene file.
    let e = umbra::Scene::load(&dir.join("nope.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope.toml") && e.contains("No such file"), "{e}");
    // Missing OBJ named by the scene.
    std::fs::write(dir.join("s.toml"), GOOD.replace("sq.obj", "missing.obj")).unwrap();
    let e = umbra::Scene::load(&dir.join("s.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.obj"), "{e}");
    // Malformed OBJ: the line is named.
    std::fs::write(dir.join("s.toml"), GOOD).unwrap();
    std::fs::write(
        dir.join("sq.obj"),
        "v 0 0 0\nv 1 0 0\nv 0 1 zero\nf 1 2 3\n",
    )
    .unwrap();
    let e = umbra::Scene::load(&dir.join("s.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("sq.obj:3:") && e.contains("zero"), "{e}");
    // Only degenerate faces.
    std::fs::write(dir.join("sq.obj"), "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n").unwrap();
    let e = umbra::Scene::load(&dir.join("s.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("objects[0]") && e.contains("no non-degenerate"),
        "{e}"
    );
    // Unknown extension.
    let e = umbra::Scene::load(&dir.join("s.json"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("s.json") && e.contains(".toml"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn cli_reports_errors_without_panicking() {
    let out = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(["render", "/nonexistent/scene.toml", "-o", "/tmp/x.npy"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.starts_with("error: /nonexistent/scene.toml:"), "{err}");
    assert!(!err.contains("panicked"));
    let out = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(["render", "--spp", "0", "-o", "/tmp/x.npy"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("spp: must be"));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 400, .. ProptestConfig::default() })]

    /// Random edits of a good TOML scene (deletions, duplications, random ASCII):
    /// the reader returns Ok or Err, never panics.
    #[test]
    fn toml_reader_never_panics(edits in prop::collection::vec((0usize..400, 0usize..12, "[ -~\n]{0,8}"), 1..6)) {
        let mut text = GOOD.to_string();
        for (at, len, ins) in edits {
            let at = at.min(text.len());
            let end = (at + len).min(text.len());
            if text.is_char_boundary(at) && text.is_char_boundary(end) {
                text.replace_range(at..end, &ins);
            }
        }
        let sq = square_obj([0.0, 0.0, 0.0], 0.2);
        let _ = try_scene(&text, &[("sq.obj", &sq)]);
    }

    /// Random OBJ text built from plausible tokens: never a panic.
    #[test]
    fn obj_reader_never_panics(lines in prop::collection::vec(
        prop_oneof![
            "v( -?[0-9]{1,3}(\\.[0-9]{1,3})?){2,4}",
            "f( -?[0-9]{1,2}(/[0-9]{0,2}){0,2}){1,5}",
            "(vn|vt|o|g|s|usemtl|mtllib)( [a-z0-9.]{1,5}){0,3}",
            "[ -~]{0,20}",
        ], 0..30)) {
        let text = lines.join("\n");
        if let Ok(mut m) = TriMesh::parse_obj(&text, Path::new("fuzz.obj")) {
            m.drop_degenerate();
            for t in &m.triangles {
                prop_assert!(t.iter().all(|&i| (i as usize) < m.positions.len()));
            }
        }
    }
}

/// A `.npy` whose header claims far more data than the file holds is refused by its
/// header, naming the file and both sizes, by every command that reads one (it used to
/// abort allocating terabytes); `gradcheck --tolerance nan` is refused (it used to pass).
#[test]
fn npy_headers_are_checked_against_the_file_and_nan_tolerance_refused() {
    let dir = common::tmp_dir("npy-header");
    let scene = common::SceneSpec::default().write(&dir);
    let s = scene.to_str().unwrap();
    let mut header =
        "{'descr': '<f4', 'fortran_order': False, 'shape': (1000000, 1000000, 1000000), }"
            .to_string();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend((header.len() as u16).to_le_bytes());
    bytes.extend(header.as_bytes());
    bytes.extend([0u8; 64]);
    std::fs::write(dir.join("huge.npy"), bytes).unwrap();
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_umbra"))
            .args(args)
            .current_dir(&dir)
            .output()
            .unwrap()
    };
    for args in [
        vec!["grad", s, "--adjoint", "huge.npy", "-o", "g.npz"],
        vec!["grad", s, "--target", "huge.npy", "-o", "g.npz"],
        vec!["fit", s, "--measured", "huge.npy", "-o", "fit", "-q"],
    ] {
        let out = run(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains("huge.npy") && err.contains("truncated .npy"),
            "{args:?}: {err}"
        );
    }
    let out = run(&["gradcheck", s, "--tolerance", "nan", "--params", "1"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("--tolerance: must be a number > 0"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

/// The output's format and folder are checked before the render (they used to fail after
/// the work was done), and a written `.npy` leaves no temporary file behind.
#[test]
fn render_output_is_checked_before_the_work_and_written_atomically() {
    let dir = common::tmp_dir("output-check");
    let scene = common::SceneSpec::default().write(&dir);
    let s = scene.to_str().unwrap();
    std::fs::write(dir.join("plain_file"), "x").unwrap();
    let run = |scene: &str, out: &str| {
        Command::new(env!("CARGO_BIN_EXE_umbra"))
            .args(["render", scene, "-o", out, "--no-preview", "-q"])
            .current_dir(&dir)
            .output()
            .unwrap()
    };
    for (out, says) in [
        ("h.txt", "unknown output format '.txt'"),
        ("plain_file/h.npy", "plain_file"),
        (".", "is a folder"),
    ] {
        // The output is refused first: even a scene that is not there is not reached.
        let o = run("no_such_scene.toml", out);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{out}: {err}");
        assert!(
            err.contains(says) && !err.contains("no_such_scene"),
            "{out}: {err}"
        );
    }
    let o = run(s, "sub/h.npy");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let left: Vec<_> = std::fs::read_dir(dir.join("sub"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(left, ["h.npy"]);
    std::fs::remove_dir_all(&dir).ok();
}

/// `fit` counts of 0 are refused naming the option (`--spp 0` ran as 1, `--iters 0` as
/// 4, `--target-spp 0` rendered a NaN target).
#[test]
fn fit_refuses_zero_counts() {
    let dir = common::tmp_dir("fit-zero");
    let scene = common::SceneSpec::default().write(&dir);
    let s = scene.to_str().unwrap();
    for flag in ["--spp", "--iters", "--target-spp"] {
        let out = Command::new(env!("CARGO_BIN_EXE_umbra"))
            .args(["fit", s, flag, "0", "-q", "-o", "fit"])
            .current_dir(&dir)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{flag}: {err}");
        assert!(
            err.contains(&format!("{flag}: must be at least 1")),
            "{flag}: {err}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// A deeply nested XML (40,000 elements) is refused by its depth, naming the file and
/// line; it used to overflow the stack (the CLI aborted, Python segfaulted).
#[test]
fn deeply_nested_xml_is_refused() {
    let dir = common::tmp_dir("deep-xml");
    let deep = format!(
        "<scene version=\"3.0.0\">{}{}</scene>",
        "<a>".repeat(40_000),
        "</a>".repeat(40_000)
    );
    let path = dir.join("deep.xml");
    std::fs::write(&path, deep).unwrap();
    let e = umbra::Scene::load(&path).unwrap_err().to_string();
    assert!(
        e.contains("deep.xml:1: elements nested more than 64 deep"),
        "{e}"
    );
    let out = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(["render", path.to_str().unwrap(), "-o", "x.npy", "-q"])
        .current_dir(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("nested more than 64 deep"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

/// A malformed face line is refused with its line (it was half read); a binary file
/// given as a mesh (`/dev/zero` read 4 GB before running out of memory) is refused at
/// its first NUL byte; a TOML cut after `albedo =` says so (the message was empty).
#[test]
fn malformed_faces_binary_meshes_and_truncated_toml() {
    let dir = common::tmp_dir("bad-mesh");
    let spec = SceneSpec {
        objects: vec![(
            "v 0 0 0.5\nv 0.2 0 0.5\nv 0 0.2 0.5\nf 1/2/3/4 2// 3/x\n".into(),
            0.5,
            "lambertian",
        )],
        ..SceneSpec::default()
    };
    let path = spec.write(&dir);
    let e = umbra::Scene::load(&path).unwrap_err().to_string();
    assert!(
        e.contains("obj0.obj:4: face vertex '1/2/3/4' has more than v/vt/vn"),
        "{e}"
    );

    let toml = std::fs::read_to_string(&path).unwrap();
    std::fs::write(
        &path,
        toml.replace("file = \"obj0.obj\"", "file = \"/dev/zero\""),
    )
    .unwrap();
    let e = umbra::Scene::load(&path).unwrap_err().to_string();
    assert!(
        // Refused by its type before it is opened (a FIFO would block the read).
        e.contains("/dev/zero: is a character device, not an OBJ mesh"),
        "{e}"
    );

    let cut = &toml[..toml.find("albedo = ").unwrap() + "albedo =".len()];
    std::fs::write(&path, cut).unwrap();
    let e = umbra::Scene::load(&path).unwrap_err().to_string();
    assert!(
        e.ends_with("the file ends where a value was expected (truncated?)"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
