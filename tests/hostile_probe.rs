//! Issue 52's probe, cause by cause, on the CLI: no crash, hang or destroyed file; each
//! silent case warned or correct; each message naming the user's field or flag. Each
//! test failed on the code before its fix (the commit says how).

mod common;
use common::*;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// `umbra args` in `dir`, killed after 60 s (then the output says HUNG).
fn umbra(dir: &Path, args: &[&str]) -> Output {
    umbra_in(dir, args, &[])
}

fn umbra_in(dir: &Path, args: &[&str], env: &[(&str, &str)]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_umbra"));
    cmd.args(args).envs(env.iter().copied()).current_dir(dir);
    output_within(&mut cmd, Duration::from_secs(60))
}

/// `umbra` with the words of `line` (no word holds a space).
fn cli(dir: &Path, line: &str) -> Output {
    umbra(dir, &line.split_whitespace().collect::<Vec<_>>())
}

fn err(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Exit 1 (a clear error, not a crash's 101 or 134) with every one of `says`.
fn refused(o: &Output, says: &[&str]) {
    let e = err(o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    for s in says {
        assert!(e.contains(s), "wanted '{s}' in: {e}");
    }
}

/// Exit 0 with every one of `says` on stderr.
fn warned(o: &Output, says: &[&str]) {
    let e = err(o);
    assert_eq!(o.status.code(), Some(0), "{e}");
    for s in says {
        assert!(e.contains(s), "wanted '{s}' in: {e}");
    }
}

fn mkfifo(p: &Path) {
    let ok = Command::new("mkfifo").arg(p).status().unwrap().success();
    assert!(ok, "mkfifo {}", p.display());
}

fn file_type(p: &Path) -> std::fs::FileType {
    std::fs::symlink_metadata(p).unwrap().file_type()
}

/// No `.NAME.tmp...` temporaries left in `dir`.
fn no_temporaries(dir: &Path) {
    let left: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.') && n.contains(".tmp"))
        .collect();
    assert!(left.is_empty(), "temporaries left: {left:?}");
}

/// A scene and a render of it (`target.npy`) in a fresh folder.
fn scene_with_target(name: &str, spec: &SceneSpec) -> (PathBuf, PathBuf) {
    let dir = tmp_dir(name);
    let scene = spec.write(&dir);
    let o = cli(
        &dir,
        &format!(
            "render {} -o target.npy -q --no-preview",
            scene.to_str().unwrap()
        ),
    );
    assert!(o.status.success(), "{}", err(&o));
    (dir, scene)
}

#[test]
fn crashes_are_clear_errors() {
    let spec = SceneSpec {
        model: "tri3",
        sigma_opl: None,
        ..SceneSpec::default()
    };
    let (dir, scene) = scene_with_target("probe-crash", &spec);
    let s = scene.to_str().unwrap();
    // --jitter far beyond the film aborted on a 12.5 TB allocation (1e10) or a capacity
    // overflow (1e30).
    for j in ["1e10", "1e30"] {
        let o = cli(
            &dir,
            &format!(
                "fit {} --measured target.npy -o fit -q --jitter {} --iters 1",
                s, j
            ),
        );
        refused(&o, &["--jitter", "longer than the whole film"]);
    }
    // Gradients of a scene without hidden triangles: index out of bounds in mc3's area
    // sampling.
    let empty = SceneSpec {
        objects: vec![],
        ..SceneSpec::default()
    };
    let e = empty.write(&dir.join("empty"));
    let e = e.to_str().unwrap();
    for model in ["mc3", "path", "tri3"] {
        let o = cli(
            &dir,
            &format!("grad {} --target target.npy --model {} -o g.npz", e, model),
        );
        refused(&o, &["no hidden objects"]);
        let o = umbra(&dir, &["gradcheck", e, "--model", model]);
        refused(&o, &["no hidden objects"]);
    }
    // ... and the render is zero, with the reason (it panicked for mc3 and path).
    for model in ["mc3", "path"] {
        let o = umbra(&dir, &["render", e, "--model", model, "-o", "z.npy", "-q"]);
        warned(
            &o,
            &["the render is zero everywhere: the scene has no hidden objects"],
        );
    }
    // An irradiance near f32's end passed validation and overflowed in the render.
    let hot = std::fs::read_to_string(&scene)
        .unwrap()
        .replace("[laser]\n", "[laser]\nirradiance = 3e38\n");
    std::fs::write(dir.join("hot.toml"), hot).unwrap();
    let o = umbra(&dir, &["render", "hot.toml", "-o", "x.npy", "-q"]);
    refused(&o, &["laser.irradiance", "would overflow float32"]);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn special_files_neither_hang_nor_get_replaced() {
    let dir = tmp_dir("probe-special");
    let spec = SceneSpec::default();
    let scene = spec.write(&dir);
    let s = scene.to_str().unwrap();
    // A mesh that is a FIFO without a writer blocked forever.
    let toml = std::fs::read_to_string(&scene)
        .unwrap()
        .replace("obj0.obj", "fifo.obj");
    std::fs::write(dir.join("fifo.toml"), toml).unwrap();
    mkfifo(&dir.join("fifo.obj"));
    let o = umbra(&dir, &["render", "fifo.toml", "-o", "x.npy", "-q"]);
    refused(&o, &["fifo.obj: is a FIFO (named pipe), not an OBJ mesh"]);
    // An output FIFO nobody reads was replaced by a regular file.
    mkfifo(&dir.join("out.npy"));
    let o = umbra(&dir, &["render", s, "-o", "out.npy", "-q"]);
    refused(
        &o,
        &["out.npy", "FIFO (named pipe) that no process is reading"],
    );
    use std::os::unix::fs::FileTypeExt;
    assert!(file_type(&dir.join("out.npy")).is_fifo());
    // /dev/null (as root it was replaced by a regular file) is written in place, and no
    // previews are made beside it.
    let o = umbra(&dir, &["render", s, "-o", "/dev/null"]);
    warned(&o, &[]);
    assert!(file_type(Path::new("/dev/null")).is_char_device());
    assert!(!Path::new("/dev/null_image.png").exists());
    // A FIFO with a reader gets the bytes.
    let reader = {
        let p = dir.join("out.npy");
        std::thread::spawn(move || std::fs::read(p).unwrap())
    };
    let mut o = umbra(&dir, &["render", s, "-o", "out.npy", "-q", "--no-preview"]);
    for _ in 0..100 {
        if o.status.success() {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
        o = umbra(&dir, &["render", s, "-o", "out.npy", "-q", "--no-preview"]);
    }
    warned(&o, &[]);
    let bytes = reader.join().unwrap();
    assert_eq!(&bytes[..6], b"\x93NUMPY");
    no_temporaries(&dir);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_file_size_limit_fails_the_write_and_leaves_no_temporary() {
    let dir = tmp_dir("probe-ulimit");
    let spec = SceneSpec {
        scan: [16, 16],
        bins: 2000,
        ..SceneSpec::default()
    };
    let scene = spec.write(&dir);
    // 16 x 16 x 2000 floats = 2 MB past a 100 kB limit: SIGXFSZ killed the process and
    // left `.big.npy.tmp<pid>`.
    let cmd = format!(
        "ulimit -f 100; exec '{}' render '{}' -o big.npy -q --no-preview --spp 1",
        env!("CARGO_BIN_EXE_umbra"),
        scene.display()
    );
    let o = Command::new("sh")
        .arg("-c")
        .arg(cmd)
        .current_dir(&dir)
        .output()
        .unwrap();
    refused(&o, &["big.npy", "File too large"]);
    assert!(!dir.join("big.npy").exists());
    no_temporaries(&dir);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn two_fits_into_one_folder_the_second_is_refused() {
    let spec = SceneSpec {
        model: "tri3",
        sigma_opl: None,
        ..SceneSpec::default()
    };
    let (dir, scene) = scene_with_target("probe-lock", &spec);
    let s = scene.to_str().unwrap();
    let first = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args([
            "fit",
            s,
            "--measured",
            "target.npy",
            "-o",
            "fit",
            "-q",
            "--iters",
            "100000",
        ])
        .current_dir(&dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let lock = dir.join("fit/.umbra.lock");
    let start = Instant::now();
    while std::fs::read_to_string(&lock).map_or(true, |t| t.is_empty()) {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "the first fit never locked"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let fit = |more: &[&str]| {
        let args = [
            &[
                "fit",
                s,
                "--measured",
                "target.npy",
                "-o",
                "fit",
                "-q",
                "--iters",
                "2",
            ],
            more,
        ]
        .concat();
        umbra(&dir, &args)
    };
    let o = fit(&[]);
    let mut first = first;
    let _ = first.kill();
    let _ = first.wait();
    refused(
        &o,
        &[
            "fit: the folder is in use by another run (umbra fit, pid",
            ".umbra.lock",
        ],
    );
    // Once the first is gone, the folder is free again (the lock died with it).
    let o = fit(&["--resume"]);
    assert!(!err(&o).contains("in use by another run"), "{}", err(&o));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn renders_of_nothing_are_warned_with_their_cause() {
    let dir = tmp_dir("probe-zero");
    let cases: Vec<(SceneSpec, &str)> = vec![
        (
            SceneSpec {
                start_opl: 100.0,
                ..SceneSpec::default()
            },
            "after the latest three-bounce return",
        ),
        (
            SceneSpec {
                start_opl: 0.0,
                bins: 10,
                bin_width: 0.001,
                ..SceneSpec::default()
            },
            "before the earliest return",
        ),
        (
            SceneSpec {
                objects: vec![(square_obj([0.0, 0.0, 1e5], 0.3), 0.8, "lambertian")],
                ..SceneSpec::default()
            },
            "before the earliest return",
        ),
        (
            SceneSpec {
                objects: vec![(
                    "v -0.1 -0.1 0.6\nv 0.1 -0.1 0.6\nv 0.1 0.1 0.6\nv -0.1 0.1 0.6\nf 1 2 3 4\n"
                        .into(),
                    0.8,
                    "lambertian",
                )],
                ..SceneSpec::default()
            },
            "one-sided (two_sided = false) and faces away",
        ),
    ];
    for (i, (spec, says)) in cases.into_iter().enumerate() {
        let scene = spec.write(&dir.join(format!("c{i}")));
        let o = cli(
            &dir,
            &format!(
                "render {} -o z.npy -q --no-preview",
                scene.to_str().unwrap()
            ),
        );
        assert!(
            err(&o).contains("warning: the render is zero everywhere"),
            "case {i}: {}",
            err(&o)
        );
        warned(&o, &[says]);
    }
    // The devices behind a plate that covers the wall: the lines to the wall are blocked.
    let walled = SceneSpec {
        laser_origin: [0.0, 0.0, 1.0],
        detector_origin: [0.0, 0.0, 1.0],
        objects: vec![(square_obj([0.0, 0.0, 0.6], 3.0), 0.8, "lambertian")],
        ..SceneSpec::default()
    };
    let scene = walled.write(&dir.join("walled"));
    let o = umbra(
        &dir,
        &["render", scene.to_str().unwrap(), "-o", "z.npy", "-q"],
    );
    warned(
        &o,
        &["block the laser's or the detector's line to the wall at every scan point"],
    );
    // gradcheck says so at once (it ran every finite difference, minutes on a large
    // scan, before saying they were all zero).
    let o = umbra(
        &dir,
        &["gradcheck", scene.to_str().unwrap(), "--params", "2"],
    );
    refused(&o, &["gradcheck: the render is zero everywhere, so there is no gradient to check: the hidden objects block"]);
    // mc3 and tri3 rendered three-bounce light whatever filter_bounces asked for.
    for model in ["mc3", "tri3"] {
        let spec = SceneSpec {
            render_extra: vec!["max_bounces = 6".into(), "filter_bounces = 5".into()],
            ..SceneSpec::default()
        };
        let scene = spec.write(&dir.join("filter"));
        let o = cli(
            &dir,
            &format!(
                "render {} --model {} -o z.npy -q",
                scene.to_str().unwrap(),
                model
            ),
        );
        refused(
            &o,
            &["render.filter_bounces: tri3 and mc3 make three-bounce light only"],
        );
    }
    // A render that is not zero says nothing of the kind.
    let scene = SceneSpec::default().write(&dir.join("ok"));
    let o = cli(
        &dir,
        &format!(
            "render {} -o ok.npy -q --no-preview",
            scene.to_str().unwrap()
        ),
    );
    assert!(!err(&o).contains("zero everywhere"), "{}", err(&o));
    // The gradient against a target equal to the render says why it is zero.
    let o = cli(
        &dir,
        &format!("grad {} --target ok.npy -o g.npz", scene.to_str().unwrap()),
    );
    warned(
        &o,
        &["the render equals the target bin for bin", "another --seed"],
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_object_wholly_behind_the_wall_is_refused_whatever_its_triangles() {
    // A fine mesh behind the wall: its f32 area summed to a share of 0.99999, so the
    // refusal never fired.
    let mut obj = String::new();
    let n = 40;
    for j in 0..=n {
        for i in 0..=n {
            obj += &format!(
                "v {} {} -0.3\n",
                0.013 * i as f32 - 0.26,
                0.017 * j as f32 - 0.34
            );
        }
    }
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i + 1;
            obj += &format!("f {} {} {} {}\n", a, a + n + 1, a + n + 2, a + 1);
        }
    }
    let spec = SceneSpec {
        objects: vec![(obj, 0.8, "lambertian")],
        ..SceneSpec::default()
    };
    let e = spec
        .try_scene()
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(
        e.contains("lies entirely behind or in the relay wall's plane"),
        "{e}"
    );
}

#[test]
fn toml_arrays_have_their_exact_length() {
    let toml = SceneSpec::default().toml();
    for (from, to, says) in [
        (
            "resolution = [4, 4]",
            "resolution = [8, 8, 8]",
            "expected an array of 2 values, got 3",
        ),
        (
            "origin = [0.3, -0.4, 1.0]\nspot",
            "origin = [0.3, -0.4, 1.0, 0.0, 2.0]\nspot",
            "expected an array of 3 values, got 5",
        ),
        (
            "size = [2.0, 2.0]",
            "size = [2.0]",
            "expected an array of 2 values, got 1",
        ),
    ] {
        assert!(toml.contains(from), "{from}");
        let objs = [("obj0.obj", square_obj([0.05, 0.02, 0.6], 0.3))];
        let refs: Vec<(&str, &str)> = objs.iter().map(|(a, b)| (*a, b.as_str())).collect();
        let e = try_scene(&toml.replacen(from, to, 1), &refs)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains(says), "{to}: {e}");
    }
}

#[test]
fn obj_vertex_colours_are_all_or_none_and_never_silently_override() {
    let some = "v 0 0 0.6 1 0 0\nv 0.1 0 0.6\nv 0 0.1 0.6 0 1 0\nf 1 3 2\n";
    let e = umbra::geometry::mesh::TriMesh::parse_obj(some, Path::new("m.obj"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("2 of 3 vertices have colours") && e.contains("first at line 2"),
        "{e}"
    );
    let all = "v -0.1 -0.1 0.6 0.5 0.5 0.5\nv 0.1 -0.1 0.6 0.5 0.5 0.5\nv 0 0.1 0.6 0.5 0.5 0.5\nf 1 3 2\n";
    let spec = SceneSpec {
        objects: vec![(all.into(), 0.3, "lambertian")],
        ..SceneSpec::default()
    };
    let s = spec.scene();
    let w = s.warnings.join("\n");
    assert!(
        w.contains("objects[0].albedo = 0.3 is not used: obj0.obj has vertex colours"),
        "{w}"
    );
}

#[test]
fn outputs_and_counts_mean_what_they_say() {
    let spec = SceneSpec {
        model: "tri3",
        sigma_opl: None,
        ..SceneSpec::default()
    };
    let (dir, scene) = scene_with_target("probe-outputs", &spec);
    let s = scene.to_str().unwrap();
    // grad -o g.npy wrote .npz bytes under a .npy name.
    let o = umbra(&dir, &["grad", s, "--target", "target.npy", "-o", "g.npy"]);
    refused(&o, &["-o g.npy", "give a name ending in .npz"]);
    // export-mitsuba -o x.npy wrote XML; into a missing folder it failed on the OBJ.
    let o = umbra(&dir, &["export-mitsuba", s, "-o", "x.npy"]);
    refused(&o, &["x.npy", "give a name ending in .xml"]);
    let o = umbra(&dir, &["export-mitsuba", "-o", "new/folder/scene.xml"]);
    warned(&o, &[]);
    assert!(dir.join("new/folder/scene.xml").exists());
    // --time-bin 0 ran as 1.
    let o = cli(
        &dir,
        &format!("convert {} --measured target.npy -o c.npy --time-bin 0", s),
    );
    assert_eq!(o.status.code(), Some(2), "{}", err(&o));
    assert!(
        err(&o).contains("--time-bin") && err(&o).contains("must be at least 1"),
        "{}",
        err(&o)
    );
    // --iters 20 ran 23 iterations (each stage's share rounded up).
    let o = cli(
        &dir,
        &format!("fit {} --measured target.npy -o fit -q --iters 20", s),
    );
    assert!(o.status.success(), "{}", err(&o));
    let csv = std::fs::read_to_string(dir.join("fit/loss.csv")).unwrap();
    let rows = csv.lines().skip(1).filter(|l| !l.trim().is_empty()).count();
    assert_eq!(rows, 20, "{csv}");
    // --ignore-before past the film: an OPL of 2.9e17 m, the flag unnamed.
    let o = cli(
        &dir,
        &format!(
            "fit {} --measured target.npy -o fit2 -q --ignore-before 1e30",
            s
        ),
    );
    refused(
        &o,
        &[
            "--ignore-before: 1000000000000000000000000000000 m",
            "every bin would be ignored",
        ],
    );
    // A legal 250-byte output name failed on its temporary's name.
    let long = format!("{}.npy", "n".repeat(246));
    let o = umbra(&dir, &["render", s, "-o", &long, "-q", "--no-preview"]);
    warned(&o, &[]);
    assert!(dir.join(&long).exists());
    no_temporaries(&dir);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn messages_name_the_users_field_and_cut_long_values() {
    let dir = tmp_dir("probe-messages");
    let toml = SceneSpec::default().toml();
    let objs = [("obj0.obj", square_obj([0.05, 0.02, 0.6], 0.3))];
    let refs: Vec<(&str, &str)> = objs.iter().map(|(a, b)| (*a, b.as_str())).collect();
    let fails = |text: String| {
        try_scene(&text, &refs)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    };
    // wall.size = inf was reported as wall.axis_u.
    let e = fails(toml.replacen("size = [2.0, 2.0]", "size = [inf, 2.0]", 1));
    assert!(e.contains("wall.size: must be finite and positive"), "{e}");
    // fov = nan was reported as "laser.irradiance ... got 1".
    let e = fails(toml.replacen("[laser]\n", "[laser]\nirradiance = 1.0\nfov = nan\n", 1));
    assert!(e.contains("laser.fov: must be finite, got NaN"), "{e}");
    // A 1 MB value was echoed whole.
    let big = "x".repeat(1 << 20);
    let e = fails(toml.replacen(
        "capture_type = \"confocal\"",
        &format!("capture_type = \"{big}\""),
        1,
    ));
    assert!(
        e.len() < 400 && e.contains("capture_type") && e.contains("characters)"),
        "{}",
        e.len()
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// A MATLAB v5 file of uncompressed variables `(name, class code, dims, values)`.
fn mat_v5(vars: &[(&str, u8, &[u32], &[f64])]) -> Vec<u8> {
    let mut b = vec![b' '; 116];
    b[..9].copy_from_slice(b"MATLAB 5.");
    b.extend_from_slice(&[0u8; 8]);
    b.extend_from_slice(&0x0100u16.to_le_bytes());
    b.extend_from_slice(b"IM");
    let pad = |v: &mut Vec<u8>| v.resize(v.len().next_multiple_of(8), 0);
    for (name, class, dims, values) in vars {
        let mut m = Vec::new();
        let tag = |m: &mut Vec<u8>, t: u32, n: usize| {
            m.extend_from_slice(&t.to_le_bytes());
            m.extend_from_slice(&(n as u32).to_le_bytes());
        };
        tag(&mut m, 6, 8);
        m.extend_from_slice(&u32::from(*class).to_le_bytes());
        m.extend_from_slice(&0u32.to_le_bytes());
        tag(&mut m, 5, 4 * dims.len());
        dims.iter()
            .for_each(|d| m.extend_from_slice(&d.to_le_bytes()));
        pad(&mut m);
        tag(&mut m, 1, name.len());
        m.extend_from_slice(name.as_bytes());
        pad(&mut m);
        tag(&mut m, 9, 8 * values.len());
        values
            .iter()
            .for_each(|v| m.extend_from_slice(&v.to_le_bytes()));
        pad(&mut m);
        tag(&mut b, 14, m.len());
        b.extend_from_slice(&m);
    }
    b
}

#[test]
fn mat_captures_say_what_is_wrong_with_a_variable() {
    use umbra::io::lct::read_lct;
    let dir = tmp_dir("probe-mat");
    let rect: Vec<f64> = (0..2 * 2 * 8).map(|i| (i % 5) as f64).collect();
    let write = |name: &str, bytes: Vec<u8>| {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let ok = mat_v5(&[
        ("rect_data", 6, &[2, 2, 8], &rect),
        ("width", 6, &[1, 1], &[0.5]),
    ]);
    let c = read_lct(&write("ok.mat", ok.clone())).unwrap();
    assert_eq!((c.transient.shape.clone(), c.width), (vec![2, 2, 8], 0.5));
    // width = [0.5, 7.0] took 0.5.
    let two = mat_v5(&[
        ("rect_data", 6, &[2, 2, 8], &rect),
        ("width", 6, &[1, 2], &[0.5, 7.0]),
    ]);
    let e = read_lct(&write("two.mat", two)).unwrap_err().to_string();
    assert!(
        e.contains("width must be one number (m), got 2 values [0.5, 7.0]"),
        "{e}"
    );
    // A file cut inside rect_data, and a rect_data of another class, read as absent.
    let cut = ok[..ok.len() - 200].to_vec();
    let e = read_lct(&write("cut.mat", cut)).unwrap_err().to_string();
    assert!(e.contains("truncated"), "{e}");
    let cell = mat_v5(&[
        ("rect_data", 1, &[2, 2, 8], &rect),
        ("width", 6, &[1, 1], &[0.5]),
    ]);
    let e = read_lct(&write("cell.mat", cell)).unwrap_err().to_string();
    assert!(
        e.contains("variable 'rect_data' is a cell array, not a numeric one"),
        "{e}"
    );
    let none = mat_v5(&[("width", 6, &[1, 1], &[0.5])]);
    let e = read_lct(&write("none.mat", none)).unwrap_err().to_string();
    assert!(e.contains("no variable 'rect_data'"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_hdf5_file_with_a_user_block_is_not_called_truncated() {
    // h5py, userblock_size = 512: an HDF5 file whose superblock sits at 512 (it holds
    // one dataset `H`, not a whole y-tal capture).
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/userblock_512.h5");
    let e = umbra::io::ytal::read_ytal(&p)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(!e.contains("truncated"), "{e}");
    // Cut, it is truncated.
    let dir = tmp_dir("probe-h5");
    let bytes = std::fs::read(&p).unwrap();
    let cut = dir.join("cut.h5");
    std::fs::write(&cut, &bytes[..bytes.len() - 100]).unwrap();
    let e = umbra::io::ytal::read_ytal(&cut)
        .map(|_| ())
        .unwrap_err()
        .to_string();
    assert!(e.contains("truncated HDF5 file"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}
