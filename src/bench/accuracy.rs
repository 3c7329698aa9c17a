//! Speed against accuracy (`umbra bench accuracy`): for every way Umbra computes a
//! transient, the relative L2 error against a converged reference as a function of
//! wall-clock time, on four scenes, in one run on one machine.
//!
//! Methods: `tri3` at several subdivision thresholds (deterministic: one point each),
//! with centroid visibility (the default) and with one shadow ray per sub-triangle;
//! `mc3` (Monte Carlo three-bounce) and the multi-bounce path tracer with each
//! combination of the seed paper's techniques that a point laser spot allows (laser
//! sampling must stay on: without it a path has to hit a point, see the ablation,
//! [`super::ablation`]): hidden-geometry sampling with BSDF sampling under MIS, BSDF
//! sampling alone, and hidden-geometry sampling alone (mitransient's estimator), each at
//! doubling sample counts until a render takes longer than the budget.
//!
//! Reference: the path tracer with all techniques at `reference_spp`, as two renders of
//! half the samples with different seeds, cached in the output directory (keyed by scene
//! and sample count); their difference gives the reference's own error, removed from
//! every error in quadrature (`e = sqrt(max(0, e_raw² − e_ref²))`, reported next to the
//! raw one). The truth is multi-bounce, so the three-bounce models (`tri3`, `mc3`) level
//! off at the share of light beyond three bounces: on the concave scene that floor is the
//! point of the comparison.
//!
//! Scenes (confocal 16 x 16 over the whole 1.6 m relay wall, 256 bins of 8 mm from OPL
//! 1.4 m, Gaussian kernel σ = 8 mm; so that [`export_mitsuba`] writes the same scene for
//! mitransient, the laser is a projector of irradiance 1, and it stands below the hidden
//! objects' depth, at (0, −1, 0.5), where no hidden object blocks its beam to a scan point:
//! mitransient traces that beam, Umbra does not model the visible legs): the planar letter T (the default scene's), a sphere (1280 triangles), the
//! bunny-like mesh of the recovery studies (5120 triangles), and a concave corner (two
//! plates at right angles, interreflections).

use super::{rel_l2, with_techniques};
use crate::error::{Error, Result};
use crate::geometry::mesh::TriMesh;
use crate::geometry::shapes::icosphere;
use crate::geometry::SceneGeometry;
use crate::scene::mitsuba_xml::write::write as write_mitsuba;
use crate::scene::{toml_format, FilmSpec, KernelSpec, Model, Scene, Visibility};
use crate::transport::{RenderOptions, Renderer};
use glam::Vec3;
use std::path::Path;
use std::time::Instant;

const LETTER: &str = include_str!("../../scenes/meshes/letter_t.obj");
const BUNNY: &str = include_str!("../../scenes/meshes/bunny_like.obj");
const CORNER: &str = "v -0.3 -0.25 1.0\nv 0.3 -0.25 1.0\nv 0.3 0.25 1.0\nv -0.3 0.25 1.0\n\
                      v 0.3 -0.25 0.6\nv 0.3 0.25 0.6\n\
                      f 1 4 3 2\nf 2 3 6 5\n";

pub(crate) fn scene_with(mesh: TriMesh, translate: [f32; 3], two_sided: bool) -> Result<Scene> {
    let toml = format!(
        r#"
capture_type = "confocal"
[wall]
size = [1.6, 1.6]
albedo = 0.8
[laser]
origin = [0.0, -1.0, 0.5]
irradiance = 1.0
[scan]
resolution = [16, 16]
size = [1.6, 1.6]
[film]
temporal_bins = 256
bin_width_opl = 0.008
start_opl = 1.4
kernel = "gaussian"
sigma_opl = 0.008
[[objects]]
file = "mesh"
albedo = 0.8
two_sided = {two_sided}
transform = {{ translate = [{}, {}, {}] }}
[render]
model = "path"
max_bounces = 8
"#,
        translate[0], translate[1], translate[2]
    );
    toml_format::parse(&toml, Path::new("<accuracy scene>"), &|_| Ok(mesh.clone()))
}

/// The four scenes of the module doc, by short name.
pub fn scenes() -> Result<Vec<(&'static str, Scene)>> {
    let obj = |text: &str, name: &str| TriMesh::parse_obj(text, Path::new(name));
    Ok(vec![
        (
            "letter",
            scene_with(obj(LETTER, "letter_t.obj")?, [0.0, 0.0, 1.0], false)?,
        ),
        (
            "sphere",
            scene_with(icosphere(Vec3::ZERO, 0.2, 3), [0.05, 0.0, 1.0], false)?,
        ),
        (
            "bunny",
            scene_with(obj(BUNNY, "bunny_like.obj")?, [0.0, 0.0, 1.0], false)?,
        ),
        (
            "corner",
            scene_with(obj(CORNER, "corner.obj")?, [0.0, 0.0, 0.0], true)?,
        ),
    ])
}

/// One of [`scenes`] by its short name.
pub fn scene(name: &str) -> Result<Scene> {
    scenes()?
        .into_iter()
        .find(|(n, _)| *n == name)
        .map(|(_, s)| s)
        .ok_or_else(|| {
            Error::Invalid(format!(
                "no accuracy scene '{name}' (letter, sphere, bunny, corner)"
            ))
        })
}

/// One measured point of a method's curve.
#[derive(Clone, Debug)]
pub struct Point {
    pub scene: &'static str,
    pub method: String,
    /// Samples per measurement, or the subdivision threshold for `tri3`.
    pub setting: f64,
    pub seconds: f64,
    /// Relative L2 against the reference, its own error removed in quadrature.
    pub error: f64,
    pub raw_error: f64,
}

impl Point {
    /// A point whose raw error is `raw`, against a reference of own error `ref_error`
    /// (removed in quadrature).
    pub fn measured(
        scene: &'static str,
        method: &str,
        setting: f64,
        seconds: f64,
        raw: f64,
        ref_error: f64,
    ) -> Point {
        Point {
            scene,
            method: method.to_string(),
            setting,
            seconds,
            error: (raw * raw - ref_error * ref_error).max(0.0).sqrt(),
            raw_error: raw,
        }
    }
}

/// A scene's reference: the mean of two half renders, and the relative L2 error of that
/// mean (half the relative difference of the halves).
pub struct Reference {
    pub data: Vec<f32>,
    pub error: f64,
    /// The cache file: both halves, shape (2, measurements · bins).
    pub path: std::path::PathBuf,
}

fn render(scene: &Scene, opts: &RenderOptions) -> Result<(Vec<f32>, f64)> {
    let geom = SceneGeometry::build(scene);
    let start = Instant::now();
    let t = Renderer::new(scene, &geom, opts)?.render(None)?;
    Ok((t.data, start.elapsed().as_secs_f64()))
}

/// A 64-bit FNV-1a hash of the scene's full description: the cache key, so a changed
/// scene never reads an old reference.
pub(crate) fn scene_key(scene: &Scene) -> u64 {
    format!("{scene:?}")
        .bytes()
        .fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ b as u64).wrapping_mul(0x100_0000_01b3)
        })
}

/// The reference of `scene` at `spp`, from `cache` if a file for it (same scene, same
/// spp) is there.
pub fn reference(name: &str, scene: &Scene, spp: u32, cache: &Path) -> Result<Reference> {
    let path = cache.join(format!(
        "reference_{name}_{spp}_{:016x}.npy",
        scene_key(scene)
    ));
    let all = with_techniques(scene, true, true, true);
    let (data, error) = super::reference_halves(&path, [9001, 9002], |seed| {
        let opts = RenderOptions {
            model: Model::Path,
            spp: (spp / 2).max(1),
            seed,
            ..RenderOptions::from_scene(&all)
        };
        render(&all, &opts).map(|r| r.0)
    })?;
    Ok(Reference { data, error, path })
}

/// Writes `scene` as mitransient renders it in this bench (`<name>_3b.xml`: three
/// bounces, `<name>_mb.xml`: the scene's bounces, both with laser and hidden-geometry
/// sampling, mitransient's NLOS techniques; `<name>_mb_bsdf.xml`: the scene's bounces
/// with laser and BSDF sampling) and `<name>.toml`, what the Python suite
/// (`python/bench/bench_accuracy_mitransient.py`) needs to compare it with `r`.
///
/// mitransient 1.3.1 bins with a box only, so the files ask for box bins `factor` times
/// finer than the scene's, over its window widened by 4σ on each side (paths 4σ to
/// `GAUSS_CUTOFF` = 6.5σ outside the window, which reach Umbra's bins, are lost: at
/// most the 3e-5 tail of the window's edge bins); the suite
/// integrates them against the Gaussian, taking the OPL as uniform within a fine bin (a
/// bias of order (w/factor)²/σ², which the suite measures with `tri3`).
pub fn export_mitsuba(
    name: &str,
    scene: &Scene,
    r: &Reference,
    dir: &Path,
    factor: u32,
) -> Result<()> {
    let KernelSpec::Gaussian { sigma_opl } = scene.film.kernel else {
        return Err(Error::Invalid(format!(
            "{name}: the accuracy scenes have Gaussian kernels"
        )));
    };
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let f = &scene.film;
    let fine_width = f.bin_width_opl / factor as f32;
    let pad = (4.0 * sigma_opl / fine_width).ceil() as u32;
    let mut s = with_techniques(scene, true, true, false);
    s.film = FilmSpec {
        temporal_bins: f.temporal_bins * factor + 2 * pad,
        bin_width_opl: fine_width,
        start_opl: f.start_opl - pad as f32 * fine_width,
        kernel: KernelSpec::Box,
    };
    let all = scene.render.max_bounces;
    for (suffix, bounces, filter, hidden) in [
        ("3b", 3, Some(3), true),
        ("mb", all, None, true),
        ("mb_bsdf", all, None, false),
    ] {
        s.render.max_bounces = bounces;
        s.render.filter_bounces = filter;
        s.render.techniques.hidden_geometry_sampling = hidden;
        s.render.techniques.bsdf_sampling = !hidden;
        write_mitsuba(&s, &dir.join(format!("{name}_{suffix}.xml")))?;
    }
    let manifest = format!(
        "# umbra bench accuracy --export-mitsuba: scene {name}\n\
         xml_three_bounce = \"{name}_3b.xml\"\nxml_multi_bounce = \"{name}_mb.xml\"\n\
         xml_multi_bounce_bsdf = \"{name}_mb_bsdf.xml\"\n\
         max_bounces = {}\nreference = {}\nreference_error = {:e}\n\
         bins = {}\nbin_width_opl = {}\nstart_opl = {}\nsigma_opl = {sigma_opl}\n\
         fine_factor = {factor}\nfine_bins = {}\nfine_bin_width_opl = {fine_width}\nfine_start_opl = {}\n",
        scene.render.max_bounces,
        toml::Value::String(r.path.canonicalize().unwrap_or(r.path.clone()).display().to_string()),
        r.error,
        f.temporal_bins,
        f.bin_width_opl,
        f.start_opl,
        s.film.temporal_bins,
        s.film.start_opl,
    );
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, manifest).map_err(|e| Error::io(&path, e))
}

/// Points measured elsewhere (the Python suite's mitransient curves), from a CSV in
/// [`csv`]'s columns; rows of scenes not in `scene_names` are skipped.
pub fn read_points(path: &Path, scene_names: &[&'static str]) -> Result<Vec<Point>> {
    let text = crate::io::read_text(path, "a curve file")?;
    if text.lines().next().map(str::trim) != Some(CSV_HEADER.trim()) {
        return Err(Error::Line {
            file: path.to_path_buf(),
            line: 1,
            msg: format!("the first line must be the header '{}'", CSV_HEADER.trim()),
        });
    }
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        if line.trim().is_empty() {
            continue;
        }
        let bad = |what: &str| Error::Line {
            file: path.to_path_buf(),
            line: i + 1,
            msg: format!("{what} (columns: {})", CSV_HEADER.trim()),
        };
        let cols: Vec<&str> = line.split(',').collect();
        if cols.len() != 6 {
            return Err(bad(&format!("{} columns, not 6", cols.len())));
        }
        let num = |c: &str, what: &str| -> Result<f64> {
            c.trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(&format!("{what} '{c}' is not a finite number")))
        };
        let Some(&scene) = scene_names.iter().find(|n| **n == cols[0].trim()) else {
            continue;
        };
        out.push(Point {
            scene,
            method: cols[1].trim().to_string(),
            setting: num(cols[2], "setting")?,
            seconds: Some(num(cols[3], "seconds")?)
                .filter(|&t| t > 0.0)
                .ok_or_else(|| bad("seconds must be > 0"))?,
            error: num(cols[4], "error")?,
            raw_error: num(cols[5], "raw_error")?,
        });
    }
    Ok(out)
}

/// Every method's curve on `scene`: renders until one takes longer than `budget` s.
pub fn curves(name: &'static str, scene: &Scene, r: &Reference, budget: f64) -> Result<Vec<Point>> {
    let mut out = Vec::new();
    let mut push = |method: &str, setting: f64, data: &[f32], seconds: f64| {
        let raw = rel_l2(data, &r.data);
        out.push(Point::measured(
            name, method, setting, seconds, raw, r.error,
        ));
    };
    for (label, visibility) in [
        ("tri3", Visibility::Centroid),
        ("tri3 (sub-triangle visibility)", Visibility::Subtriangle),
    ] {
        for s in [2.0f32, 0.6, 0.15, 0.05] {
            let opts = RenderOptions {
                model: Model::Tri3,
                subdivision: s,
                visibility,
                ..RenderOptions::from_scene(scene)
            };
            let (d, t) = render(scene, &opts)?;
            push(label, s as f64, &d, t);
            if t > budget {
                break;
            }
        }
    }
    let methods: [(&str, Model, bool, bool); 4] = [
        ("mc3", Model::Mc3, true, true),
        ("path MIS (hidden-geometry + BSDF)", Model::Path, true, true),
        ("path BSDF sampling", Model::Path, false, true),
        (
            "path hidden-geometry sampling only",
            Model::Path,
            true,
            false,
        ),
    ];
    for (label, model, hidden, bsdf) in methods {
        let s = with_techniques(scene, true, hidden, bsdf);
        let mut spp = 4u32;
        loop {
            let opts = RenderOptions {
                model,
                spp,
                seed: 17,
                ..RenderOptions::from_scene(&s)
            };
            let (d, t) = render(&s, &opts)?;
            push(label, spp as f64, &d, t);
            if t > budget || spp >= 1 << 20 {
                break;
            }
            spp *= 2;
        }
    }
    Ok(out)
}

const CSV_HEADER: &str = "scene,method,setting,seconds,error,raw_error\n";

/// The CSV of all points (method names hold no commas).
pub fn csv(points: &[Point]) -> String {
    let mut s = String::from(CSV_HEADER);
    for p in points {
        s += &format!(
            "{},{},{},{:.6},{:.6e},{:.6e}\n",
            p.scene,
            p.method.replace(',', ";"),
            p.setting,
            p.seconds,
            p.error,
            p.raw_error
        );
    }
    s
}

/// Log-log chart, one panel per scene, one line per method.
pub fn write_png(path: &Path, title: &str, points: &[Point], scene_names: &[&str]) -> Result<()> {
    use crate::io::plot::Series;
    let mut panels = Vec::new();
    for &scene in scene_names {
        let mut methods: Vec<&str> = Vec::new();
        for p in points.iter().filter(|p| p.scene == scene) {
            if !methods.contains(&p.method.as_str()) {
                methods.push(&p.method);
            }
        }
        let series = methods
            .iter()
            .map(|&m| Series {
                label: m,
                points: points
                    .iter()
                    .filter(|p| p.scene == scene && p.method == m && p.error > 0.0)
                    .map(|p| (p.seconds, p.error))
                    .collect(),
            })
            .collect();
        panels.push((scene.to_string(), series));
    }
    crate::io::plot::loglog_panel_chart(
        path,
        title,
        "seconds (2 cores)",
        "relative L2 error",
        2,
        &panels,
    )
}

/// The first time (s, interpolated in log-log between measured points) at which a
/// method's error falls to `target`, if it does.
pub fn time_to(points: &[Point], scene: &str, method: &str, target: f64) -> Option<f64> {
    let mut pts: Vec<(f64, f64)> = points
        .iter()
        .filter(|p| p.scene == scene && p.method == method && p.error > 0.0)
        .map(|p| (p.seconds, p.error))
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    if let Some(first) = pts.first() {
        if first.1 <= target {
            return Some(first.0);
        }
    }
    pts.windows(2).find_map(|w| {
        let ((t0, e0), (t1, e1)) = (w[0], w[1]);
        (e0 > target && e1 <= target).then(|| {
            let f = (target.ln() - e0.ln()) / (e1.ln() - e0.ln());
            (t0.ln() + f * (t1.ln() - t0.ln())).exp()
        })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn point(method: &str, seconds: f64, error: f64) -> Point {
        Point {
            scene: "s",
            method: method.into(),
            setting: 0.0,
            seconds,
            error,
            raw_error: error,
        }
    }

    #[test]
    fn time_to_interpolates_in_log_log_and_says_when_a_target_is_not_reached() {
        let pts = [
            point("a", 1.0, 0.1),
            point("a", 4.0, 0.025),
            point("b", 2.0, 0.5),
        ];
        // Error ∝ t^-1 between the points: 5 % at 2 s.
        let t = time_to(&pts, "s", "a", 0.05).unwrap();
        assert!((t - 2.0).abs() < 1e-9, "{t}");
        assert_eq!(time_to(&pts, "s", "a", 0.2), Some(1.0));
        assert_eq!(time_to(&pts, "s", "a", 0.01), None);
        assert_eq!(time_to(&pts, "s", "b", 0.1), None);
        let c = csv(&pts);
        assert_eq!(c.lines().count(), 4);
        assert!(c.starts_with("scene,method,setting,seconds,error,raw_error\n"));
    }
}
