//! `umbra bench`: built-in benchmarks that print the figures BENCHMARKS.md quotes.
//!
//! - [`tri3_speed`]: the `tri3` forward pass on a confocal 64 x 64 scan, 512 bins, a
//!   10k-triangle mesh, no visibility (the issue's reference case): render time (median
//!   over repetitions, setup excluded) and pairs per second.
//! - [`tri3_error_table`]: `tri3`'s relative L2 error against a converged `mc3` reference
//!   as the subdivision threshold falls, with the cost of each setting.
//! - [`ablation`]: the seed paper's comparison of sampling techniques at equal samples.
//! - [`accuracy`]: error against wall-clock time for every way of computing a transient.
//! - [`grad_accuracy`]: gradient error against wall-clock time (adjoints, replay, FD).
//! - [`scaling`]: time and memory against scan, bins, triangles and spp.
//! - [`rays`]: the path tracer's rays/s against a replay of its rays alone (obvhs's rate).

pub mod ablation;
pub mod accuracy;
pub mod grad_accuracy;
pub mod rays;
pub mod scaling;

use crate::error::Result;
use crate::geometry::mesh::TriMesh;
use crate::geometry::shapes::{icosphere, wavy_sheet};
use crate::geometry::SceneGeometry;
use crate::scene::{toml_format, Model, Scene, Visibility};
use crate::transport::{RenderOptions, Renderer, Transient};
use glam::Vec3;
use std::path::Path;
use std::time::Instant;

/// A confocal scene around one procedural mesh.
pub fn mesh_scene(
    mesh: TriMesh,
    scan: u32,
    bins: u32,
    bin_width: f32,
    start: f32,
) -> Result<Scene> {
    let toml = format!(
        r#"
capture_type = "confocal"
[wall]
size = [2.0, 2.0]
albedo = 0.8
[laser]
origin = [0.3, -0.4, 1.0]
power = 1.0
[scan]
resolution = [{scan}, {scan}]
size = [1.6, 1.6]
[film]
temporal_bins = {bins}
bin_width_opl = {bin_width}
start_opl = {start}
[[objects]]
file = "mesh"
albedo = 0.7
[render]
visibility = "none"
"#
    );
    toml_format::parse(&toml, Path::new("<bench scene>"), &|_| Ok(mesh.clone()))
}

/// The issue's reference case: a wavy sheet of 10 082 triangles at 0.8 m.
pub fn tri3_speed_scene() -> Result<Scene> {
    let sheet = wavy_sheet(Vec3::new(0.0, 0.1, 0.8), 0.6, 71, 0.02, 0.3);
    mesh_scene(sheet, 64, 512, 0.004, 1.5)
}

/// Result of a timing run.
pub struct Timing {
    pub measurements: usize,
    pub subtriangles: usize,
    pub setup_seconds: f64,
    /// Render seconds of each repetition.
    pub seconds: Vec<f64>,
}

impl Timing {
    pub fn median(&self) -> f64 {
        let mut s = self.seconds.clone();
        s.sort_by(f64::total_cmp);
        s[s.len() / 2]
    }
    pub fn mpairs_per_second(&self) -> f64 {
        (self.measurements * self.subtriangles) as f64 / self.median() / 1e6
    }
}

/// Times `tri3` on `scene` (`reps` renders after one warm-up).
pub fn tri3_speed(scene: &Scene, reps: usize, subdivision: f32) -> Result<Timing> {
    let t0 = Instant::now();
    let geom = SceneGeometry::build(scene);
    let opts = RenderOptions {
        model: Model::Tri3,
        visibility: Visibility::None,
        subdivision,
        ..RenderOptions::from_scene(scene)
    };
    let r = Renderer::new(scene, &geom, &opts)?;
    let setup_seconds = t0.elapsed().as_secs_f64();
    r.render(None)?;
    let mut seconds = Vec::with_capacity(reps);
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        std::hint::black_box(r.render(None)?);
        seconds.push(t.elapsed().as_secs_f64());
    }
    Ok(Timing {
        measurements: scene.num_measurements(),
        subtriangles: r.subtriangles(),
        setup_seconds,
        seconds,
    })
}

/// One row of the error-vs-threshold table.
pub struct ErrorRow {
    pub subdivision: f32,
    pub subtriangles: usize,
    pub seconds: f64,
    /// Relative L2 difference from the mc3 reference.
    pub error: f64,
}

impl ErrorRow {
    /// The error with the reference's own noise removed in quadrature (the two are
    /// independent): an estimate of tri3's distance from the exact transient.
    pub fn error_without_noise(&self, noise: f64) -> f64 {
        (self.error * self.error - noise * noise).max(0.0).sqrt()
    }
}

/// `tri3` against an `mc3` reference (two seeds of `spp` samples) on `scene`, for each
/// threshold; returns the reference's own relative noise and the rows.
pub fn tri3_error_table(
    scene: &Scene,
    spp: u32,
    thresholds: &[f32],
) -> Result<(f64, Vec<ErrorRow>)> {
    let geom = SceneGeometry::build(scene);
    let run = |model, seed, subdivision| -> Result<(Transient, f64, usize)> {
        let opts = RenderOptions {
            model,
            spp,
            seed,
            subdivision,
            visibility: Visibility::None,
            ..RenderOptions::from_scene(scene)
        };
        let r = Renderer::new(scene, &geom, &opts)?;
        let t = Instant::now();
        let out = r.render(None)?;
        Ok((out, t.elapsed().as_secs_f64(), r.subtriangles()))
    };
    let (a, _, _) = run(Model::Mc3, 11, 1.0)?;
    let (b, _, _) = run(Model::Mc3, 12, 1.0)?;
    let reference: Vec<f32> = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| 0.5 * (x + y))
        .collect();
    let noise = rel_l2(&a.data, &b.data) / 2.0;
    let mut rows = Vec::new();
    for &s in thresholds {
        let (t, seconds, subtriangles) = run(Model::Tri3, 0, s)?;
        rows.push(ErrorRow {
            subdivision: s,
            subtriangles,
            seconds,
            error: rel_l2(&t.data, &reference),
        });
    }
    Ok((noise, rows))
}

/// The scenes of the error table: the built-in letter T (large flat triangles, 8 x 8
/// scan) and a sphere of 1280 triangles.
pub fn error_table_scenes() -> Result<Vec<(&'static str, Scene)>> {
    let mut letter = crate::scene::default::default_scene()?;
    letter.scan.nx = 8;
    letter.scan.ny = 8;
    let sphere = mesh_scene(
        icosphere(Vec3::new(0.1, 0.0, 0.9), 0.2, 3),
        8,
        160,
        0.01,
        1.3,
    )?;
    Ok(vec![
        ("letter T (default scene, 72 triangles)", letter),
        ("sphere (1280 triangles)", sphere),
    ])
}

/// `scene` with the path tracer's techniques set (the relay-wall option kept).
pub fn with_techniques(scene: &Scene, laser: bool, hidden: bool, bsdf: bool) -> Scene {
    let mut s = scene.clone();
    let t = &mut s.render.techniques;
    t.laser_sampling = laser;
    t.hidden_geometry_sampling = hidden;
    t.bsdf_sampling = bsdf;
    s
}

/// A converged reference computed once: `make(seed)` for two seeds, cached in `path` as
/// one `(2, n)` `.npy`. Returns the mean of the halves and its own relative error, half
/// their relative difference (each half has error `e_h`, their difference `√2 e_h`, the
/// mean `e_h / √2`).
pub(crate) fn reference_halves(
    path: &Path,
    seeds: [u64; 2],
    make: impl Fn(u64) -> Result<Vec<f32>>,
) -> Result<(Vec<f32>, f64)> {
    let (a, b) = if path.is_file() {
        let t = crate::io::read_npy(path)?;
        let n = t.data.len() / 2;
        (t.data[..n].to_vec(), t.data[n..].to_vec())
    } else {
        let (a, b) = (make(seeds[0])?, make(seeds[1])?);
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| crate::Error::io(dir, e))?;
        }
        let t = Transient {
            shape: vec![2, a.len()],
            data: a.iter().chain(&b).copied().collect(),
        };
        crate::io::write_npy(path, &t)?;
        (a, b)
    };
    let mean = a.iter().zip(&b).map(|(x, y)| 0.5 * (x + y)).collect();
    Ok((mean, 0.5 * rel_l2(&a, &b)))
}

/// Relative L2 difference `‖a − b‖ / ‖b‖`.
pub fn rel_l2<T: Copy + Into<f64>>(a: &[T], b: &[T]) -> f64 {
    let d: f64 = a
        .iter()
        .zip(b)
        .map(|(&x, &y)| (x.into() - y.into()).powi(2))
        .sum();
    let n: f64 = b.iter().map(|&y| y.into().powi(2)).sum();
    (d / n).sqrt()
}

/// The gradient benchmark's scene: the default letter T (72 triangles, moved off the
/// scan's symmetry lines), confocal 16 x 16, 512 bins of 4 mm through a Gaussian of
/// σ = 6 mm.
pub fn grad_scene() -> Result<Scene> {
    let mut s = crate::scene::default::default_scene()?;
    s.scan.nx = 16;
    s.scan.ny = 16;
    s.film.kernel = crate::scene::KernelSpec::Gaussian { sigma_opl: 0.006 };
    for o in &mut s.objects {
        o.mesh
            .positions
            .iter_mut()
            .for_each(|p| *p += Vec3::new(0.0123, 0.0071, 0.0));
    }
    Ok(s)
}

/// [`grad_scene`] with a plate 1.2 m square 0.3 m behind the letter, which casts its
/// shadows on it: the boundary terms' cost where they matter.
pub fn grad_scene_occluded() -> Result<Scene> {
    let mut s = grad_scene()?;
    let points = s
        .objects
        .iter()
        .flat_map(|o| o.mesh.positions.iter().copied());
    let (lo, hi) = points.fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(l, h), p| {
        (l.min(p), h.max(p))
    });
    let c = 0.5 * (lo + hi);
    let (h, z) = (0.6, hi.z + 0.3);
    let obj = format!(
        "v {} {} {z}\nv {} {} {z}\nv {} {} {z}\nv {} {} {z}\nf 1 4 3 2\n",
        c.x - h,
        c.y - h,
        c.x + h,
        c.y - h,
        c.x + h,
        c.y + h,
        c.x - h,
        c.y + h
    );
    let mut plate = s.objects[0].clone();
    plate.name = "plate".into();
    plate.mesh =
        crate::geometry::mesh::TriMesh::parse_obj(&obj, std::path::Path::new("plate.obj"))?;
    s.objects.push(plate);
    Ok(s)
}

/// Forward and adjoint times of one model at one spp.
pub struct GradTiming {
    pub model: Model,
    pub spp: u32,
    /// Median seconds of the forward render.
    pub forward: f64,
    /// Median seconds of the adjoint pass alone (given `dLoss/dH`), boundary terms on.
    pub adjoint: f64,
    /// The same without the boundary terms (interior derivative only).
    pub interior: f64,
}

impl GradTiming {
    /// `forward s | adjoint s | interior s | adjoint / forward | interior / forward`, as
    /// the cells of a Markdown row.
    pub fn ratio_cells(&self) -> String {
        format!(
            "{:.4} | {:.4} | {:.4} | {:.2} | {:.2}",
            self.forward,
            self.adjoint,
            self.interior,
            self.adjoint / self.forward,
            self.interior / self.forward
        )
    }
}

/// Times forward and adjoint passes, interleaved, `reps` times each after a warm-up;
/// the adjoint histogram is that of an L2 loss against the scene moved 2 cm.
pub fn grad_timing(scene: &Scene, model: Model, spp: u32, reps: usize) -> Result<GradTiming> {
    use crate::adjoint::{check, gradient};
    let geom = SceneGeometry::build(scene);
    let opts = RenderOptions {
        model,
        spp,
        ..RenderOptions::from_scene(scene)
    };
    // The check's adjoint (L2 against the moved scene); setup's gradient is the warm-up.
    let (_, adj, ..) = check::setup(scene, &opts)?;
    // Both passes at the roulette survival the pilot picks, neither paying for the pilot
    // (as `umbra grad --target` runs it once for both).
    let scene = &crate::transport::roulette::resolved(
        scene,
        &geom,
        &opts,
        crate::transport::gate::Pass::Gradient,
    )?;
    let r = Renderer::new(scene, &geom, &opts)?;
    let mut interior_scene = scene.clone();
    interior_scene.render.boundary_terms = false;
    let (mut fw, mut ad, mut int) = (Vec::new(), Vec::new(), Vec::new());
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        std::hint::black_box(r.render(None)?);
        fw.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        std::hint::black_box(gradient(scene, &geom, &opts, &adj, None)?);
        ad.push(t.elapsed().as_secs_f64());
        let t = Instant::now();
        std::hint::black_box(gradient(&interior_scene, &geom, &opts, &adj, None)?);
        int.push(t.elapsed().as_secs_f64());
    }
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    Ok(GradTiming {
        model,
        spp,
        forward: median(fw),
        adjoint: median(ad),
        interior: median(int),
    })
}

/// Peak resident memory of this process (kB), from `/proc/self/status` (`VmHWM`).
pub fn peak_rss_kb() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// One adjoint pass of `model` at `spp` on [`grad_scene`] (for a fresh process to report
/// its peak memory).
pub fn grad_pass(model: Model, spp: u32) -> Result<()> {
    let scene = grad_scene()?;
    let geom = SceneGeometry::build(&scene);
    let opts = RenderOptions {
        model,
        spp,
        ..RenderOptions::from_scene(&scene)
    };
    let n = scene.num_measurements() * scene.film.temporal_bins as usize;
    let adj: Vec<f32> = (0..n)
        .map(|i| ((i * 37 % 101) as f32 - 50.0) * 1e-2)
        .collect();
    std::hint::black_box(crate::adjoint::gradient(&scene, &geom, &opts, &adj, None)?);
    Ok(())
}
