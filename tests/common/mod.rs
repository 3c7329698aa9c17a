//! Helpers shared by the integration tests: scenes from inline TOML and OBJ text,
//! renders, and the total energy's mean and standard error over independent seeds.
#![allow(dead_code)]

pub mod capture;
pub mod exact_interreflection;
pub mod exact_shadows;
pub mod patch;

use std::path::Path;
use umbra::geometry::mesh::TriMesh;
use umbra::geometry::SceneGeometry;
use umbra::scene::{toml_format, Model, Scene};
use umbra::transport::{self, RenderOptions, Transient};

/// A scene from TOML text whose objects name OBJ texts in `objs`.
pub fn scene(toml: &str, objs: &[(&str, &str)]) -> Scene {
    try_scene(toml, objs).unwrap_or_else(|e| panic!("test scene: {e}"))
}

pub fn try_scene(toml: &str, objs: &[(&str, &str)]) -> umbra::Result<Scene> {
    let objs: Vec<(String, String)> = objs
        .iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
    toml_format::parse(toml, Path::new("test.toml"), &move |f| match objs
        .iter()
        .find(|(n, _)| n == f)
    {
        Some((_, text)) => TriMesh::parse_obj(text, Path::new(f)),
        None => Err(umbra::Error::scene(Path::new(f), "no such inline OBJ")),
    })
}

pub fn render(scene: &Scene, model: Model, spp: u32, seed: u64) -> Transient {
    let geom = SceneGeometry::build(scene);
    let opts = RenderOptions {
        model,
        spp,
        seed,
        ..RenderOptions::from_scene(scene)
    };
    transport::render(scene, &geom, &opts, None).expect("render")
}

/// A square of side `side` centred at `c` in the plane z = c.z, facing -z (the wall).
pub fn square_obj(c: [f32; 3], side: f32) -> String {
    let h = side / 2.0;
    format!(
        "v {} {} {z}\nv {} {} {z}\nv {} {} {z}\nv {} {} {z}\nf 1 4 3 2\n",
        c[0] - h,
        c[1] - h,
        c[0] + h,
        c[1] - h,
        c[0] + h,
        c[1] + h,
        c[0] - h,
        c[1] + h,
        z = c[2]
    )
}

/// Per-measurement time-integrated values.
pub fn totals(t: &Transient) -> Vec<f64> {
    t.data
        .chunks(t.bins())
        .map(|c| c.iter().map(|&v| v as f64).sum())
        .collect()
}

/// Total energy over seeds: (mean, standard error of the mean).
pub fn total_energy(scene: &Scene, model: Model, spp: u32, seeds: u64) -> (f64, f64) {
    let t: Vec<f64> = (0..seeds)
        .map(|s| {
            render(scene, model, spp, 5000 + s)
                .data
                .iter()
                .map(|&v| v as f64)
                .sum()
        })
        .collect();
    let k = seeds as f64;
    let m = t.iter().sum::<f64>() / k;
    let var = t.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (k - 1.0);
    (m, (var / k).sqrt())
}

/// `../shared/data/<name>` beside the repository (or `/work/shared/data/<name>`), where
/// the machine's shared captures live; the environment variable `var` overrides it.
pub fn shared_dir(var: &str, name: &str) -> std::path::PathBuf {
    use std::path::PathBuf;
    if let Ok(d) = std::env::var(var) {
        return PathBuf::from(d);
    }
    let beside = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/")
        .join(name);
    if beside.is_dir() {
        return beside;
    }
    PathBuf::from("/work/shared/data").join(name)
}

/// The adjoint against CRN central differences on `params` parameters per object
/// (`adjoint::check`), each within 1 % of `max(|fd|, 2 % of the largest)`.
/// Most scenes sit off the scan grid's symmetry lines (generic positions);
/// `tri3_at_exact_opl_ties` checks a mirror-symmetric placement, where corners of
/// sub-triangles tie in OPL exactly.
pub fn check(scene: &Scene, model: Model, spp: u32, params: usize) {
    // Steps small against σ = 12 mm (the difference's own error is (h/σ)² / 6); tri3's
    // f64 reference allows smaller ones.
    let h = if model == Model::Tri3 { 1e-4 } else { 3e-4 };
    check_at(scene, model, spp, params, h);
}

/// [`check`] with finite-difference step `h` (m).
pub fn check_at(scene: &Scene, model: Model, spp: u32, params: usize, h: f64) {
    let opts = RenderOptions {
        model,
        spp,
        seed: 7,
        ..RenderOptions::from_scene(scene)
    };
    let ps = umbra::adjoint::check::pick_params(scene, params, 12345);
    let rows = umbra::adjoint::check::run(scene, &opts, &ps, &[h]).unwrap();
    let largest = rows.iter().map(|r| r.fd[0].1.abs()).fold(0.0, f64::max);
    assert!(
        largest > 0.0,
        "no gradient signal: the test scene is broken"
    );
    for r in &rows {
        let err = r.error(0.02 * largest);
        println!(
            "{model:?} {}: adjoint {:.6e} fd {:.6e} rel {err:.2e}",
            r.param, r.adjoint, r.fd[0].1
        );
        assert!(
            err < 0.01,
            "{model:?} {}: adjoint {} vs fd {} ({err:.3e})",
            r.param,
            r.adjoint,
            r.fd[0].1
        );
    }
}

/// Relative L2 between the eight-lane `f32` tri3 kernel's render and its `f64` reference
/// path (`adjoint::check::primal`); panics if the reference is all zero.
pub fn kernel_vs_reference(scene: &Scene, geom: &SceneGeometry, opts: &RenderOptions) -> f64 {
    let opts = RenderOptions {
        model: Model::Tri3,
        ..*opts
    };
    let fast = transport::render(scene, geom, &opts, None).unwrap();
    let reference = umbra::adjoint::check::primal(scene, geom, &opts).unwrap();
    let (mut num, mut den) = (0.0, 0.0);
    for (a, b) in fast.data.iter().zip(&reference) {
        num += (*a as f64 - b).powi(2);
        den += b * b;
    }
    assert!(den > 0.0, "the reference render is zero");
    (num / den).sqrt()
}

/// The shared test-scene builder: a wall at z = 0, a laser and detector in front of it,
/// a scan grid, a film and hidden objects given as OBJ text. `toml()` is the Umbra TOML
/// it stands for, `scene()` parses it, `write(dir)` puts the TOML and OBJ files on disk
/// for CLI tests: one description for the library and the command line.
#[derive(Clone, Debug)]
pub struct SceneSpec {
    pub capture: &'static str,
    pub laser_origin: [f32; 3],
    pub detector_origin: [f32; 3],
    pub spot_radius: f32,
    pub scan: [u32; 2],
    pub scan_size: f32,
    pub bins: u32,
    pub bin_width: f32,
    pub start_opl: f32,
    /// `Some(sigma)`: a Gaussian kernel.
    pub sigma_opl: Option<f32>,
    /// (OBJ text, albedo, reflectance)
    pub objects: Vec<(String, f32, &'static str)>,
    /// Every object two-sided.
    pub two_sided: bool,
    pub model: &'static str,
    pub spp: u32,
    /// Extra `[render]` lines, e.g. `"visible_legs = false"`.
    pub render_extra: Vec<String>,
}

impl Default for SceneSpec {
    fn default() -> Self {
        SceneSpec {
            capture: "confocal",
            laser_origin: [0.3, -0.4, 1.0],
            detector_origin: [0.3, -0.4, 1.0],
            spot_radius: 0.0,
            scan: [4, 4],
            scan_size: 1.0,
            bins: 200,
            bin_width: 0.01,
            start_opl: 0.8,
            sigma_opl: Some(0.012),
            objects: vec![(square_obj([0.05, 0.02, 0.6], 0.3), 0.8, "lambertian")],
            two_sided: false,
            model: "mc3",
            spp: 32,
            render_extra: Vec::new(),
        }
    }
}

impl SceneSpec {
    pub fn toml(&self) -> String {
        let v = |a: [f32; 3]| format!("[{:?}, {:?}, {:?}]", a[0], a[1], a[2]);
        let mut t = format!(
            "capture_type = \"{}\"\n[wall]\nsize = [2.0, 2.0]\n[laser]\norigin = {}\nspot_radius = {:?}\n\
             [detector]\norigin = {}\n[scan]\nresolution = [{}, {}]\nsize = [{:?}, {:?}]\n\
             [film]\ntemporal_bins = {}\nbin_width_opl = {:?}\nstart_opl = {:?}\n",
            self.capture,
            v(self.laser_origin),
            self.spot_radius,
            v(self.detector_origin),
            self.scan[0],
            self.scan[1],
            self.scan_size,
            self.scan_size,
            self.bins,
            self.bin_width,
            self.start_opl
        );
        if let Some(s) = self.sigma_opl {
            t += &format!("kernel = \"gaussian\"\nsigma_opl = {s:?}\n");
        }
        for (i, (_, albedo, refl)) in self.objects.iter().enumerate() {
            t += &format!(
                "[[objects]]\nfile = \"obj{i}.obj\"\nalbedo = {albedo:?}\nreflectance = \"{refl}\"\n"
            );
            if self.two_sided {
                t += "two_sided = true\n";
            }
        }
        t += &format!("[render]\nmodel = \"{}\"\nspp = {}\n", self.model, self.spp);
        for l in &self.render_extra {
            t += l;
            t.push('\n');
        }
        t
    }

    fn objs(&self) -> Vec<(String, String)> {
        self.objects
            .iter()
            .enumerate()
            .map(|(i, (obj, _, _))| (format!("obj{i}.obj"), obj.clone()))
            .collect()
    }

    pub fn try_scene(&self) -> umbra::Result<Scene> {
        let objs = self.objs();
        let refs: Vec<(&str, &str)> = objs.iter().map(|(a, b)| (a.as_str(), b.as_str())).collect();
        try_scene(&self.toml(), &refs)
    }

    pub fn scene(&self) -> Scene {
        self.try_scene()
            .unwrap_or_else(|e| panic!("test scene: {e}\n{}", self.toml()))
    }

    /// Writes `scene.toml` and its OBJ files into `dir`; returns the TOML's path.
    pub fn write(&self, dir: &Path) -> std::path::PathBuf {
        std::fs::create_dir_all(dir).unwrap();
        for (name, text) in self.objs() {
            std::fs::write(dir.join(name), text).unwrap();
        }
        let p = dir.join("scene.toml");
        std::fs::write(&p, self.toml()).unwrap();
        p
    }
}

/// A fresh temporary directory for one test.
pub fn tmp_dir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("umbra-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// `s` with coordinate `k` of vertex `v` of object `o` moved by `h`, and the step actually
/// taken (after rounding to `f32`): for central differences.
pub fn moved(s: &Scene, (o, v, k): (usize, usize, usize), h: f64) -> (Scene, f64) {
    let mut m = s.clone();
    let x = &mut m.objects[o].mesh.positions[v][k];
    let old = *x;
    *x += h as f32;
    let step = (*x - old) as f64;
    (m, step)
}

/// `f` on a pool of `threads` threads (the thread-count independence tests).
pub fn on_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

/// The fit's objective on `scene` (scale and constant background fitted, albedo 0.8,
/// two-sided, Lambertian, every bin fitted, no jitter, offset or detector response):
/// tests override the fields they are about.
pub fn objective(
    scene: &Scene,
    options: RenderOptions,
    measured: Vec<f32>,
) -> umbra::fit::UmbraObjective {
    umbra::fit::UmbraObjective {
        scene: scene.clone(),
        measured,
        options,
        intensity: umbra::fit::IntensityModel {
            scale: true,
            background: umbra::fit::Background::Constant,
        },
        albedo: 0.8,
        two_sided: true,
        reflectance: Default::default(),
        first_bin: 0,
        jitter_opl: 0.0,
        time_offset_max_opl: 0.0,
        irf: None,
        capture: None,
    }
}

/// Runs `cmd` with piped stdout and stderr, killed after `limit` (its stderr then ends
/// with "HUNG"); the pipes are read as the child writes, so a chatty child cannot block.
pub fn output_within(
    cmd: &mut std::process::Command,
    limit: std::time::Duration,
) -> std::process::Output {
    use std::process::Stdio;
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let drain = |mut p: Box<dyn std::io::Read + Send>| {
        std::thread::spawn(move || {
            let mut b = Vec::new();
            let _ = p.read_to_end(&mut b);
            b
        })
    };
    let out = drain(Box::new(child.stdout.take().unwrap()));
    let err = drain(Box::new(child.stderr.take().unwrap()));
    let start = std::time::Instant::now();
    let mut hung = false;
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            hung = true;
            break child.wait().unwrap();
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    let mut stderr = err.join().unwrap();
    if hung {
        stderr.extend_from_slice(format!("\n(killed after {limit:?}: HUNG)").as_bytes());
    }
    std::process::Output {
        status,
        stdout: out.join().unwrap(),
        stderr,
    }
}
