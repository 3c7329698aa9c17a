//! One gate for every entry point: a scene and options refused by one of render, grad,
//! gradcheck and fit (library and CLI) are refused by all, with the same message
//! (`transport::gate`). Python's entry points are checked against the same table in
//! python/tests/test_gate.py.

mod common;

use common::{tmp_dir, SceneSpec};
use std::path::Path;
use std::process::Command;
use umbra::geometry::SceneGeometry;
use umbra::scene::Scene;
use umbra::transport::gate::Overrides;
use umbra::transport::{RenderOptions, Renderer};

/// A refused combination: the scene, the model, and the message's key words.
struct Case {
    name: &'static str,
    spec: SceneSpec,
    model: &'static str,
    /// `None`: the render is accepted.
    render: Option<&'static str>,
    /// `None`: gradients are accepted.
    gradient: Option<&'static str>,
}

fn cases() -> Vec<Case> {
    let base = SceneSpec::default();
    let retro = SceneSpec {
        objects: vec![(base.objects[0].0.clone(), 0.8, "retroreflective")],
        ..base.clone()
    };
    let spot = SceneSpec {
        spot_radius: 0.01,
        ..base.clone()
    };
    let no_direction = SceneSpec {
        render_extra: vec![
            "bsdf_sampling = false".into(),
            "hidden_geometry_sampling = false".into(),
        ],
        ..base.clone()
    };
    let no_laser = SceneSpec {
        render_extra: vec!["laser_sampling = false".into()],
        ..base.clone()
    };
    const RETRO_MC3: &str =
        "retroreflective reflectance is modelled by tri3 only (the model is mc3)";
    const TRI3_SPOT: &str = "tri3 model: the laser spot must be a point";
    vec![
        Case {
            name: "mc3 with a retroreflective object",
            spec: retro.clone(),
            model: "mc3",
            render: Some(RETRO_MC3),
            gradient: Some(RETRO_MC3),
        },
        Case {
            name: "retroreflective in single capture",
            spec: SceneSpec {
                capture: "single",
                ..retro.clone()
            },
            model: "tri3",
            render: Some("retroreflective reflectance needs confocal capture"),
            gradient: Some("retroreflective reflectance needs confocal capture"),
        },
        Case {
            name: "tri3 with a finite spot",
            spec: spot.clone(),
            model: "tri3",
            render: Some(TRI3_SPOT),
            gradient: Some(TRI3_SPOT),
        },
        Case {
            name: "path with no way off the wall",
            spec: no_direction,
            model: "path",
            render: Some("bsdf_sampling and hidden_geometry_sampling are both off"),
            gradient: Some("bsdf_sampling and hidden_geometry_sampling are both off"),
        },
        Case {
            name: "path without laser sampling at a point spot",
            spec: no_laser,
            model: "path",
            render: Some("with laser sampling off"),
            gradient: Some("with laser sampling off"),
        },
        Case {
            name: "path gradients with a finite spot reached only by BSDF-sampled rays",
            spec: SceneSpec {
                render_extra: vec!["laser_sampling = false".into()],
                ..spot.clone()
            },
            model: "path",
            render: None,
            gradient: Some(
                "gradients of the path model with a finite laser spot need laser_sampling",
            ),
        },
        Case {
            name: "path gradients with a finite spot and laser sampling (accepted)",
            spec: spot.clone(),
            model: "path",
            render: None,
            gradient: None,
        },
        Case {
            name: "retroreflective tri3 confocal (accepted)",
            spec: retro,
            model: "tri3",
            render: None,
            gradient: None,
        },
        Case {
            name: "mc3 with a finite spot (accepted)",
            spec: spot,
            model: "mc3",
            render: None,
            gradient: None,
        },
    ]
}

fn with_model(spec: &SceneSpec, model: &str) -> (Scene, RenderOptions) {
    let mut scene = spec.scene();
    let opts = Overrides {
        model: Some(model.into()),
        spp: Some(4),
        ..Default::default()
    }
    .apply(&mut scene)
    .unwrap();
    (scene, opts)
}

fn outcome<T>(r: umbra::Result<T>) -> Option<String> {
    r.err().map(|e| e.to_string())
}

fn agrees(case: &str, entry: &str, got: Option<String>, want: Option<&str>) {
    match (got, want) {
        (None, None) => {}
        (Some(msg), Some(w)) => {
            assert!(msg.contains(w), "{case}: {entry} said {msg:?}, want {w:?}")
        }
        (got, want) => panic!("{case}: {entry} gave {got:?}, the table says {want:?}"),
    }
}

#[test]
fn library_render_and_gradient_follow_the_table() {
    for c in cases() {
        let (scene, opts) = with_model(&c.spec, c.model);
        let geom = SceneGeometry::build(&scene);
        let render = outcome(Renderer::new(&scene, &geom, &opts).and_then(|r| r.render(None)));
        agrees(c.name, "Renderer", render, c.render);
        let adj = vec![1.0f32; scene.num_measurements() * scene.film.temporal_bins as usize];
        let grad = outcome(umbra::adjoint::gradient(&scene, &geom, &opts, &adj, None));
        agrees(c.name, "gradient", grad, c.gradient);
    }
}

fn umbra(args: &[&str], dir: &Path) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Every CLI entry point gives the library's verdict, and the same message.
#[test]
fn every_cli_entry_point_follows_the_table() {
    let root = tmp_dir("gate-cli");
    for (k, c) in cases().iter().enumerate() {
        let dir = root.join(format!("case{k}"));
        let scene = c.spec.write(&dir);
        let s = scene.to_str().unwrap();
        let parsed = c.spec.scene();
        let shape: Vec<usize> = parsed.output_shape();
        let n: usize = shape.iter().product();
        let ramp =
            ndarray::ArrayD::from_shape_vec(shape, (0..n).map(|i| 1.0 + (i % 7) as f32).collect())
                .unwrap();
        ndarray_npy::write_npy(dir.join("m.npy"), &ramp).unwrap();
        let m = c.model;
        // With a target, gradcheck and fit the forward render runs first: its refusal,
        // else the gradient's.
        let after_render = c.render.or(c.gradient);
        let common = ["--model", m, "--spp", "4"];
        let entries: [(&str, Vec<&str>, Option<&str>); 5] = [
            (
                "render",
                vec!["-q", "--no-preview", "-o", "h.npy"],
                c.render,
            ),
            (
                "grad",
                vec!["--adjoint", "m.npy", "-o", "g.npz"],
                c.gradient,
            ),
            (
                "grad",
                vec!["--target", "m.npy", "-o", "g.npz"],
                after_render,
            ),
            (
                "gradcheck",
                vec!["--params", "1", "--tolerance", "1e9"],
                after_render,
            ),
            (
                "fit",
                vec!["--measured", "m.npy", "--iters", "1", "-q", "-o", "fit"],
                after_render,
            ),
        ];
        for (cmd, extra, want) in entries {
            let args: Vec<&str> = [cmd, s].into_iter().chain(common).chain(extra).collect();
            let (ok, err) = umbra(&args, &dir);
            agrees(c.name, &args.join(" "), (!ok).then_some(err), want);
        }
    }
    std::fs::remove_dir_all(&root).ok();
}

/// Overrides name the option they refuse, for the CLI and Python alike.
#[test]
fn overrides_name_the_option() {
    let spec = SceneSpec::default();
    let refused = [
        (
            Overrides {
                spp: Some(0),
                ..Default::default()
            },
            "spp: must be",
        ),
        (
            Overrides {
                spp: Some(-3),
                ..Default::default()
            },
            "spp: must be",
        ),
        (
            Overrides {
                model: Some("pathh".into()),
                ..Default::default()
            },
            "model: 'pathh'",
        ),
        (
            Overrides {
                max_depth: Some(2),
                ..Default::default()
            },
            "max_depth: must be -1 or >= 3",
        ),
        (
            Overrides {
                visibility: Some("all".into()),
                ..Default::default()
            },
            "visibility: 'all'",
        ),
        (
            Overrides {
                subdivision: Some(f32::NAN),
                ..Default::default()
            },
            "subdivision: must be > 0",
        ),
        (
            Overrides {
                max_error: Some(0.0),
                ..Default::default()
            },
            "max_error: must be > 0",
        ),
    ];
    for (o, want) in refused {
        let e = o.apply(&mut spec.scene()).unwrap_err().to_string();
        assert!(e.contains(want), "{o:?}: {e}");
    }
    let dir = tmp_dir("gate-flags");
    let s = spec.write(&dir);
    let s = s.to_str().unwrap();
    for args in [
        vec!["render", s, "--spp", "0", "-o", "x.npy"],
        vec!["gradcheck", s, "--spp", "0"],
    ] {
        let (ok, err) = umbra(&args, &dir);
        assert!(!ok && err.contains("spp: must be"), "{args:?}: {err}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
