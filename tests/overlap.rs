//! Coincident hidden faces are warned about at load time, naming the object and the
//! share of its area (`geometry::overlap`); ordinary meshes are not.

mod common;

use common::{square_obj, tmp_dir, SceneSpec};
use umbra::scene::Scene;

/// A thin solid plate (front and back faces 8 mm apart, facing away from each other)
/// with a second, slightly smaller copy of its front 3 mm behind it: the shape of
/// y-tal's own `Z.obj`, which holds an inner copy of its letter.
fn plate_with_inner_copy() -> String {
    let front = square_obj([0.0, 0.0, 0.8], 0.4);
    let back = square_obj([0.0, 0.0, 0.808], 0.4).replace("f 1 4 3 2", "f 5 6 7 8");
    let inner = square_obj([0.0, 0.0, 0.803], 0.38).replace("f 1 4 3 2", "f 9 12 11 10");
    format!("{front}{back}{inner}")
}

fn warnings(spec: &SceneSpec, name: &str) -> Vec<String> {
    let dir = tmp_dir(name);
    let s = Scene::load(&spec.write(&dir)).unwrap();
    std::fs::remove_dir_all(&dir).ok();
    s.warnings
}

#[test]
fn a_duplicated_layer_is_named_with_its_share() {
    let spec = SceneSpec {
        objects: vec![(plate_with_inner_copy(), 0.8, "lambertian")],
        ..SceneSpec::default()
    };
    let w = warnings(&spec, "overlap-layer");
    assert_eq!(w.len(), 1, "{w:?}");
    // front 0.16 m², back 0.16 m², inner 0.1444 m²: the inner copy (all of it) and
    // the front it covers (90 %) are stacked: (0.1444 + 0.1444) / 0.4644 = 62 %, as
    // probed at four points per triangle (the front's probes fall inside the copy).
    assert!(
        w[0].contains("objects[0] (obj0)") && w[0].contains("its own faces"),
        "{}",
        w[0]
    );
    let share: f64 = w[0]
        .split(": ")
        .nth(1)
        .unwrap()
        .split(" %")
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!((55.0..=75.0).contains(&share), "{}", w[0]);
}

#[test]
fn two_objects_on_top_of_each_other_name_each_other() {
    let sq = square_obj([0.05, 0.0, 0.8], 0.3);
    let spec = SceneSpec {
        objects: vec![(sq.clone(), 0.8, "lambertian"), (sq, 0.5, "lambertian")],
        ..SceneSpec::default()
    };
    let w = warnings(&spec, "overlap-two");
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(w[0].starts_with("objects[0] (obj0): 100 %") && w[0].contains("objects[1] (obj1)'s"));
    assert!(w[1].starts_with("objects[1] (obj1): 100 %") && w[1].contains("objects[0] (obj0)'s"));
}

#[test]
fn ordinary_scenes_load_without_the_warning() {
    // Two separate squares, a two-sided sheet (two faces back to back), the default scene.
    let sheet = square_obj([0.3, 0.0, 0.8], 0.2) + "f 1 2 3 4\n";
    let spec = SceneSpec {
        objects: vec![
            (square_obj([-0.3, 0.0, 0.8], 0.2), 0.8, "lambertian"),
            (sheet, 0.8, "lambertian"),
        ],
        ..SceneSpec::default()
    };
    assert!(warnings(&spec, "overlap-none").is_empty());
    let d = umbra::scene::default::default_scene()
        .unwrap()
        .with_load_warnings();
    assert!(d.warnings.is_empty(), "{:?}", d.warnings);
}
