//! A newcomer's first commands (issue 51): every subcommand takes the built-in scene when
//! none is given, `gradcheck` passes on it for every model (box bins checked on a
//! Gaussian of one bin, said in the output), and summaries say what applies to the model.

use std::process::Command;

fn umbra(args: &[&str]) -> (Option<i32>, String, String) {
    let dir = std::env::temp_dir().join(format!("umbra-first-hour-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_umbra"))
        .args(args)
        .current_dir(&dir)
        .output()
        .unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn gradcheck_passes_on_the_built_in_scene_for_every_model() {
    for model in ["tri3", "mc3", "path"] {
        let (code, out, err) = umbra(&["gradcheck", "--model", model, "--params", "2"]);
        assert_eq!(code, Some(0), "{model}: {out}\n{err}");
        let summary = out
            .lines()
            .find(|l| l.contains("worst relative error"))
            .unwrap_or_default();
        match model {
            "tri3" => assert!(
                summary.contains("subdivision") && !summary.contains("spp"),
                "{summary}"
            ),
            _ => {
                assert!(summary.contains("64 spp"), "{summary}");
                assert!(
                    err.contains("checking on a Gaussian kernel of one bin"),
                    "{err}"
                );
            }
        }
    }
    // --keep-box checks the box bins as they are, and says they lack the term.
    let (_, _, err) = umbra(&["gradcheck", "--model", "mc3", "--params", "2", "--keep-box"]);
    assert!(err.contains("miss the time-of-flight term"), "{err}");
}

#[test]
fn grad_takes_the_built_in_scene_too() {
    let (code, _, err) = umbra(&[
        "render",
        "--model",
        "tri3",
        "-o",
        "t.npy",
        "-q",
        "--no-preview",
        "--seed",
        "3",
    ]);
    assert_eq!(code, Some(0), "{err}");
    let (code, _, err) = umbra(&[
        "grad", "--model", "tri3", "--target", "t.npy", "-o", "g.npz",
    ]);
    assert_eq!(code, Some(0), "{err}");
    let summary = err
        .lines()
        .find(|l| l.starts_with("umbra: loss"))
        .unwrap_or_default();
    assert!(
        summary.contains("subdivision") && !summary.contains("spp"),
        "{err}"
    );
}

#[test]
fn gradcheck_on_an_occluded_scene_sets_aside_what_finite_differences_cannot_check() {
    // The occluder's vertices move shadows across the fixed samples: their differences
    // jump with the step (0.37 relative error was reported as a failure).
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/studies/occluded.toml");
    let (code, out, err) = umbra(&["gradcheck", scene, "--model", "path", "--params", "2"]);
    assert_eq!(code, Some(0), "{out}\n{err}");
    assert!(
        out.contains("no reference (steps spread")
            && out.contains("have no finite-difference reference"),
        "{out}"
    );
    let summary = out
        .lines()
        .find(|l| l.contains("worst relative error"))
        .unwrap_or_default();
    assert!(summary.contains("6 parameters (4 checked)"), "{summary}");
}

/// The README's three pictures are `umbra render`'s previews of the built-in scene, byte
/// for byte (regenerate: `umbra render -o /tmp/d/default.npy` and copy the PNGs to docs/).
#[test]
fn the_readme_pictures_are_what_render_writes() {
    let dir = std::env::temp_dir().join(format!("umbra-readme-pictures-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("default.npy");
    let (code, _, err) = umbra(&["render", "-q", "-o", out.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{err}");
    for name in [
        "default_streak.png",
        "default_image.png",
        "default_first_arrival.png",
    ] {
        let docs = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("docs")
            .join(name);
        let same = std::fs::read(dir.join(name)).unwrap() == std::fs::read(&docs).unwrap();
        assert!(
            same,
            "docs/{name} is not what `umbra render` writes now: regenerate it"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}
