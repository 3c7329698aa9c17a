//! Umbra's own scene format (TOML), documented field by field in `scenes/README.md`.
//!
//! Unknown fields are errors (a typo must not silently fall back to a default), every
//! error names the file and the field or line, and relative OBJ paths are resolved
//! against the scene file's folder.

use super::exact_len::{exact, exact_matrix_opt, exact_opt};
use super::{
    CaptureType, Detector, EarlySurvival, FilmSpec, HiddenObject, KernelSpec, Laser, LaserEmission,
    Model, Reflectance, RelayWall, RenderSettings, ScanGrid, Scene, Techniques, Visibility,
};
use crate::error::{Error, Result};
use crate::geometry::mesh::TriMesh;
use glam::{Affine3A, Mat4, Quat, Vec3};
use serde::Deserialize;
use std::path::{Path, PathBuf};

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default = "default_capture")]
    capture_type: String,
    #[serde(default)]
    account_first_and_last_bounces: bool,
    wall: WallT,
    laser: LaserT,
    detector: Option<DetectorT>,
    scan: ScanT,
    film: FilmT,
    #[serde(default)]
    objects: Vec<ObjectT>,
    #[serde(default)]
    render: RenderT,
}

fn default_capture() -> String {
    "confocal".into()
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct WallT {
    #[serde(default, deserialize_with = "exact")]
    center: [f32; 3],
    #[serde(deserialize_with = "exact")]
    size: [f32; 2],
    #[serde(default = "plus_z", deserialize_with = "exact")]
    normal: [f32; 3],
    #[serde(default = "plus_y", deserialize_with = "exact")]
    up: [f32; 3],
    #[serde(default = "one")]
    albedo: f32,
}

fn plus_z() -> [f32; 3] {
    [0.0, 0.0, 1.0]
}
fn plus_y() -> [f32; 3] {
    [0.0, 1.0, 0.0]
}
fn one() -> f32 {
    1.0
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct LaserT {
    #[serde(deserialize_with = "exact")]
    origin: [f32; 3],
    #[serde(default, deserialize_with = "exact_opt")]
    target: Option<[f32; 3]>,
    power: Option<f32>,
    irradiance: Option<f32>,
    #[serde(default)]
    fov: f32,
    #[serde(default)]
    spot_radius: f32,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct DetectorT {
    #[serde(deserialize_with = "exact")]
    origin: [f32; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ScanT {
    #[serde(deserialize_with = "exact")]
    resolution: [u32; 2],
    #[serde(default, deserialize_with = "exact_opt")]
    center: Option<[f32; 3]>,
    #[serde(default, deserialize_with = "exact_opt")]
    size: Option<[f32; 2]>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct FilmT {
    temporal_bins: i64,
    bin_width_opl: f32,
    #[serde(default)]
    start_opl: f32,
    #[serde(default = "box_kernel")]
    kernel: String,
    sigma_opl: Option<f32>,
}

fn box_kernel() -> String {
    "box".into()
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectT {
    file: String,
    name: Option<String>,
    /// Default 1; unused (with a warning) where the OBJ has vertex colours.
    albedo: Option<f32>,
    #[serde(default)]
    two_sided: bool,
    /// `lambertian` (default) or `retroreflective`.
    reflectance: Option<String>,
    /// A retroreflective surface's angular falloff exponent `m` (`cos^m θ`; default 0).
    retro_falloff: Option<f32>,
    #[serde(default)]
    transform: TransformT,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
struct TransformT {
    scale: Option<ScaleT>,
    #[serde(default)]
    rotate: Vec<RotateT>,
    #[serde(default, deserialize_with = "exact_opt")]
    translate: Option<[f32; 3]>,
    #[serde(default, deserialize_with = "exact_matrix_opt")]
    matrix: Option<[[f32; 4]; 4]>,
}

#[derive(Deserialize)]
#[serde(untagged)]
enum ScaleT {
    Uniform(f32),
    PerAxis(#[serde(deserialize_with = "exact")] [f32; 3]),
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RotateT {
    #[serde(deserialize_with = "exact")]
    axis: [f32; 3],
    /// Degrees.
    angle: f32,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RenderT {
    #[serde(default = "default_model")]
    model: String,
    #[serde(default = "default_spp")]
    spp: u32,
    #[serde(default = "default_max_bounces")]
    max_bounces: i64,
    filter_bounces: Option<u32>,
    #[serde(default)]
    discard_direct_paths: bool,
    #[serde(default = "default_rr")]
    rr_bounces: u32,
    /// `"auto"` or a number.
    #[serde(default)]
    rr_early_survival: Option<SurvivalT>,
    #[serde(default)]
    seed: u64,
    #[serde(default = "yes")]
    laser_sampling: bool,
    #[serde(default = "yes")]
    hidden_geometry_sampling: bool,
    #[serde(default)]
    hidden_geometry_includes_wall: bool,
    #[serde(default = "yes")]
    bsdf_sampling: bool,
    #[serde(default = "default_visibility")]
    visibility: String,
    #[serde(default = "default_subdivision")]
    subdivision: f32,
    #[serde(default = "default_max_error")]
    max_error: f32,
    #[serde(default = "yes")]
    visible_legs: bool,
    #[serde(default = "yes")]
    boundary_terms: bool,
}

fn default_visibility() -> String {
    "centroid".into()
}
fn default_subdivision() -> f32 {
    super::DEFAULT_SUBDIVISION
}
fn default_max_error() -> f32 {
    super::DEFAULT_MAX_ERROR
}

impl Default for RenderT {
    fn default() -> Self {
        toml::from_str("").expect("defaults")
    }
}

fn default_model() -> String {
    "path".into()
}
fn default_spp() -> u32 {
    64
}
fn default_max_bounces() -> i64 {
    -1
}
fn default_rr() -> u32 {
    5
}
/// `render.rr_early_survival` as written: a number, or a word (`"auto"`).
#[derive(Deserialize)]
#[serde(untagged)]
enum SurvivalT {
    Number(f64),
    Word(String),
}
fn yes() -> bool {
    true
}

/// Reads a TOML scene from disk.
pub fn load(path: &Path) -> Result<Scene> {
    let text = crate::io::read_text(path, "a scene")?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    parse(&text, path, &|file| {
        let p = base.join(file);
        TriMesh::load_obj(&p)
    })
}

/// Parses TOML scene text. `origin` names it in errors; `load_mesh` resolves an
/// object's `file` (from disk, or from memory for the built-in scene).
pub fn parse(
    text: &str,
    origin: &Path,
    load_mesh: &dyn Fn(&str) -> Result<TriMesh>,
) -> Result<Scene> {
    let f: File = toml::from_str(text).map_err(|e| {
        let line = e
            .span()
            .map(|s| {
                text.as_bytes()[..s.start.min(text.len())]
                    .iter()
                    .filter(|&&b| b == b'\n')
                    .count()
                    + 1
            })
            .unwrap_or(0);
        // toml's messages can span lines, and are empty for a file that ends where a
        // value should start (`albedo =` at the end).
        let msg = e
            .message()
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty())
            .collect::<Vec<_>>()
            .join("; ");
        let at_end = e.span().is_some_and(|s| s.start >= text.trim_end().len());
        let msg = match (msg.is_empty(), at_end) {
            (true, true) => "the file ends where a value was expected (truncated?)".into(),
            (true, false) => "malformed TOML".into(),
            (false, _) => msg,
        };
        Error::line(origin, line, msg)
    })?;
    let field = |name: &str, msg: String| Error::field(origin, name, msg);

    let capture = CaptureType::parse(&f.capture_type).ok_or_else(|| {
        field(
            "capture_type",
            format!(
                "'{}' is not one of single, confocal, exhaustive",
                f.capture_type
            ),
        )
    })?;

    let normal = v3(f.wall.normal);
    let up = v3(f.wall.up);
    if !(normal.is_finite() && up.is_finite()) || normal.length() < 1e-6 {
        return Err(field(
            "wall.normal",
            "must be a finite non-zero vector".into(),
        ));
    }
    let normal = normal.normalize();
    let e_u = up.cross(normal);
    if e_u.length() < 1e-6 {
        return Err(field(
            "wall.up",
            "must not be parallel to wall.normal".into(),
        ));
    }
    let e_u = e_u.normalize();
    let e_v = normal.cross(e_u);
    let wall = RelayWall {
        center: v3(f.wall.center),
        axis_u: f.wall.size[0] * e_u,
        axis_v: f.wall.size[1] * e_v,
        albedo: f.wall.albedo,
    };
    if !f.wall.size.iter().all(|s| s.is_finite() && *s > 0.0) {
        return Err(field(
            "wall.size",
            format!("must be finite and positive, got {:?}", f.wall.size),
        ));
    }

    let emission = match (f.laser.power, f.laser.irradiance) {
        (Some(p), None) => LaserEmission::Power(p),
        (None, Some(e)) => LaserEmission::Irradiance {
            irradiance: e,
            fov_deg: f.laser.fov,
        },
        (None, None) => LaserEmission::Power(1.0),
        (Some(_), Some(_)) => {
            return Err(field(
                "laser",
                "give either power or irradiance, not both".into(),
            ))
        }
    };
    let laser = Laser {
        origin: v3(f.laser.origin),
        target: f.laser.target.map(v3).unwrap_or(wall.center),
        emission,
        spot_radius: f.laser.spot_radius,
    };
    let detector = Detector {
        origin: f.detector.map(|d| v3(d.origin)).unwrap_or(laser.origin),
    };
    let scan_size = f.scan.size.unwrap_or(f.wall.size);
    if !(scan_size[0] > 0.0 && scan_size[1] > 0.0) {
        return Err(field(
            "scan.size",
            format!("must be positive, got {scan_size:?}"),
        ));
    }
    let scan = ScanGrid {
        nx: f.scan.resolution[0],
        ny: f.scan.resolution[1],
        center: f.scan.center.map(v3).unwrap_or(wall.center),
        axis_u: scan_size[0] * e_u,
        axis_v: scan_size[1] * e_v,
    };

    if f.film.temporal_bins <= 0 || f.film.temporal_bins > u32::MAX as i64 {
        return Err(field(
            "film.temporal_bins",
            format!("must be a positive count, got {}", f.film.temporal_bins),
        ));
    }
    let kernel = match (f.film.kernel.as_str(), f.film.sigma_opl) {
        ("box", None) => KernelSpec::Box,
        ("box", Some(_)) => {
            return Err(field(
                "film.sigma_opl",
                "only used with kernel = \"gaussian\"".into(),
            ))
        }
        ("gaussian", Some(s)) => KernelSpec::Gaussian { sigma_opl: s },
        ("gaussian", None) => {
            return Err(field(
                "film.sigma_opl",
                "kernel = \"gaussian\" needs sigma_opl (m)".into(),
            ))
        }
        (k, _) => {
            return Err(field(
                "film.kernel",
                format!("'{k}' is not one of box, gaussian"),
            ))
        }
    };
    let film = FilmSpec {
        temporal_bins: f.film.temporal_bins as u32,
        bin_width_opl: f.film.bin_width_opl,
        start_opl: f.film.start_opl,
        kernel,
    };

    let mut warnings = Vec::new();
    let mut objects = Vec::new();
    for (i, o) in f.objects.iter().enumerate() {
        let xf =
            transform(&o.transform).map_err(|m| field(&format!("objects[{i}].transform"), m))?;
        let mut mesh = load_mesh(&o.file)?;
        mesh.transform(&xf);
        let dropped = mesh.drop_degenerate();
        let name = o.name.clone().unwrap_or_else(|| {
            PathBuf::from(&o.file)
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| format!("object{i}"))
        });
        if dropped > 0 {
            warnings.push(format!(
                "{}: objects[{i}] ({name}): dropped {dropped} degenerate triangle(s)",
                origin.display()
            ));
        }
        if mesh.triangles.is_empty() {
            return Err(field(
                &format!("objects[{i}]"),
                format!("{name} has no non-degenerate triangles"),
            ));
        }
        let reflectance = match &o.reflectance {
            None => Reflectance::Lambertian,
            Some(r) => Reflectance::parse(r).ok_or_else(|| {
                field(
                    &format!("objects[{i}].reflectance"),
                    format!("'{r}' is not one of lambertian, retroreflective"),
                )
            })?,
        };
        let reflectance = match o.retro_falloff {
            None => reflectance,
            Some(m) => reflectance
                .with_falloff(m, "retro_falloff")
                .map_err(|e| field(&format!("objects[{i}].retro_falloff"), e))?,
        };
        if let (Some(a), Some(_)) = (o.albedo, &mesh.vertex_albedo) {
            warnings.push(format!(
                "{}: objects[{i}].albedo = {a} is not used: {} has vertex colours (v x y z r g b), which are {name}'s albedo",
                origin.display(),
                o.file
            ));
        }
        objects.push(HiddenObject {
            name,
            mesh,
            albedo: o.albedo.unwrap_or(1.0),
            two_sided: o.two_sided,
            reflectance,
        });
    }

    let r = &f.render;
    let model = Model::parse(&r.model).ok_or_else(|| {
        field(
            "render.model",
            format!("'{}' is not one of tri3, mc3, path, auto", r.model),
        )
    })?;
    let max_bounces = match r.max_bounces {
        -1 => u32::MAX,
        n if n >= 3 && n <= u32::MAX as i64 => n as u32,
        n => {
            return Err(field(
                "render.max_bounces",
                format!("must be -1 (unbounded) or >= 3, got {n}"),
            ))
        }
    };
    let visibility = Visibility::parse(&r.visibility).ok_or_else(|| {
        field(
            "render.visibility",
            format!(
                "'{}' is not one of none, centroid, subtriangle",
                r.visibility
            ),
        )
    })?;
    let render = RenderSettings {
        spp: r.spp,
        max_bounces,
        filter_bounces: r.filter_bounces,
        discard_direct_paths: r.discard_direct_paths,
        rr_bounces: r.rr_bounces,
        rr_early_survival: match &r.rr_early_survival {
            None => EarlySurvival::Auto,
            Some(SurvivalT::Number(q)) => {
                EarlySurvival::fixed(*q as f32).map_err(|e| field("render.rr_early_survival", e))?
            }
            Some(SurvivalT::Word(w)) => {
                EarlySurvival::parse(w).map_err(|e| field("render.rr_early_survival", e))?
            }
        },
        seed: r.seed,
        model,
        techniques: Techniques {
            laser_sampling: r.laser_sampling,
            hidden_geometry_sampling: r.hidden_geometry_sampling,
            hidden_geometry_includes_wall: r.hidden_geometry_includes_wall,
            bsdf_sampling: r.bsdf_sampling,
        },
        visibility,
        subdivision: r.subdivision,
        max_error: r.max_error,
        visible_legs: r.visible_legs,
        boundary_terms: r.boundary_terms,
    };

    let scene = Scene {
        wall,
        laser,
        detector,
        scan,
        capture,
        film,
        account_first_and_last_bounces: f.account_first_and_last_bounces,
        objects,
        render,
        warnings,
    };
    scene.validate(origin)?;
    Ok(scene)
}

fn v3(a: [f32; 3]) -> Vec3 {
    Vec3::from_array(a)
}

/// `matrix` alone, or scale, then rotations in order, then translation.
fn transform(t: &TransformT) -> std::result::Result<Affine3A, String> {
    if let Some(m) = t.matrix {
        if t.scale.is_some() || !t.rotate.is_empty() || t.translate.is_some() {
            return Err("matrix excludes scale, rotate and translate".into());
        }
        // Row-major in the file, as written on paper.
        let m = Mat4::from_cols_array_2d(&m).transpose();
        if !m.is_finite() {
            return Err("matrix has a non-finite entry".into());
        }
        if m.row(3) != glam::Vec4::new(0.0, 0.0, 0.0, 1.0) {
            return Err("matrix must be affine (last row 0 0 0 1)".into());
        }
        if m.determinant().abs() < 1e-12 {
            return Err("matrix is singular".into());
        }
        return Ok(Affine3A::from_mat4(m));
    }
    let scale = match t.scale {
        None => Vec3::ONE,
        Some(ScaleT::Uniform(s)) => Vec3::splat(s),
        Some(ScaleT::PerAxis(s)) => v3(s),
    };
    if !scale.is_finite() || scale.x * scale.y * scale.z == 0.0 {
        return Err(format!("scale must be finite and non-zero, got {scale}"));
    }
    let mut rot = Quat::IDENTITY;
    for r in &t.rotate {
        let axis = v3(r.axis);
        if !axis.is_finite() || axis.length() < 1e-9 || !r.angle.is_finite() {
            return Err("rotate needs a finite non-zero axis and a finite angle".into());
        }
        rot = Quat::from_axis_angle(axis.normalize(), r.angle.to_radians()) * rot;
    }
    let tr = t.translate.map(v3).unwrap_or(Vec3::ZERO);
    if !tr.is_finite() {
        return Err(format!("translate must be finite, got {tr}"));
    }
    Ok(Affine3A::from_scale_rotation_translation(scale, rot, tr))
}
