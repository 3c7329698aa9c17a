//! `fit::determined`: a part of a fitted mesh whose signal is within the photon noise is
//! undetermined, a part the data see clearly is not, and the verdict moves with the
//! photon count (it is not a brightness threshold); a fit to data that are not counts
//! leaves nothing out.

mod common;

use umbra::fit::determined::face_determination;
use umbra::scene::default::default_scene;
use umbra::scene::{KernelSpec, Model};
use umbra::transport::RenderOptions;

/// A deterministic standard normal per index (Irwin-Hall of 12 hashed uniforms).
fn normal(i: usize) -> f32 {
    (0..12)
        .map(|k| {
            let mut x = (i as u64 * 12 + k) ^ 0x9E37_79B9_7F4A_7C15;
            x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((x ^ (x >> 31)) >> 11) as f32 / (1u64 << 53) as f32
        })
        .sum::<f32>()
        - 6.0
}

/// The default scene's letter seen on an 8 x 8 scan (tri3), measured as photon counts
/// with `peak` expected at the brightest bin and 0.1 of background (Poisson, drawn as
/// the rounded normal approximation); the fitted mesh: the letter itself plus a flap of
/// two faces 4 cm wide, 1.3 m out, turned 89.5° from the wall (grazing). Per face: the
/// determination.
fn determination(peak: f32) -> (Vec<f64>, usize) {
    let mut scene = default_scene().unwrap();
    scene.scan.nx = 8;
    scene.scan.ny = 8;
    scene.film.temporal_bins = 160;
    scene.film.bin_width_opl = 0.02;
    scene.film.kernel = KernelSpec::Box;
    let letter = umbra::fit::fit_mesh(&scene.objects[0].mesh);
    let mut mesh = letter.clone();
    let base = mesh.vertices.len() as u32;
    let (c, half, tilt) = ([0.4, 0.1, 1.3], 0.02, 89.5f64.to_radians());
    for (u, v) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
        mesh.vertices.push([
            c[0] + u * half * tilt.cos(),
            c[1] + v * half,
            c[2] + u * half * tilt.sin(),
        ]);
    }
    mesh.faces.push([base, base + 1, base + 2]);
    mesh.faces.push([base, base + 2, base + 3]);
    let opts = RenderOptions {
        model: Model::Tri3,
        ..RenderOptions::from_scene(&scene)
    };
    let mut objective = common::objective(&scene, opts, Vec::new());
    let clean = objective.render(&letter).unwrap().compared;
    let max = clean.iter().cloned().fold(0.0f32, f32::max);
    objective.measured = clean
        .iter()
        .enumerate()
        .map(|(i, &h)| {
            let lambda = peak * h / max + 0.1;
            (lambda + lambda.sqrt() * normal(i)).round().max(0.0)
        })
        .collect();
    let r = objective.render(&mesh).unwrap();
    let (fitted, intensity, offset) = (r.compared, r.intensity, r.time_offset_opl);
    let all = vec![true; mesh.faces.len()];
    let d = face_determination(&objective, &mesh, &all, &fitted, &intensity, offset, 1).unwrap();
    (d, letter.faces.len())
}

#[test]
fn a_grazing_flap_is_undetermined_and_the_seen_letter_is_not() {
    let (d, letter) = determination(200.0);
    eprintln!("letter {:?}\nflap {:?}", &d[..letter], &d[letter..]);
    assert!(d[..letter].iter().all(|&r| r >= 1.0), "{:?}", &d[..letter]);
    assert!(d[letter..].iter().all(|&r| r < 1.0), "{:?}", &d[letter..]);
    assert!(d.iter().all(|r| !r.is_nan()));
}

#[test]
fn fewer_photons_hide_the_letter_too() {
    let (many, letter) = determination(200.0);
    let (few, _) = determination(1.0);
    eprintln!("letter at a 1-count peak {:?}", &few[..letter]);
    for (m, f) in many[..letter].iter().zip(&few[..letter]) {
        assert!(f < m, "{f} !< {m}");
    }
    assert!(
        few[..letter].iter().any(|&r| r < 1.0),
        "{:?}",
        &few[..letter]
    );
}
