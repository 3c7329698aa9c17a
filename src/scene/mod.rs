//! The scene: relay wall, laser, detector, scan grid, film, hidden meshes and render
//! settings (DESIGN §1–2).
//!
//! Everything here is in world space, metres, with time as optical path length (OPL).
//! Two readers build a [`Scene`]: our TOML format ([`toml_format`], documented in
//! `scenes/README.md`) and the subset of Mitsuba XML that mitransient users write
//! ([`mitsuba_xml`]). Both end in [`Scene::validate`], so the renderers can trust what
//! they get: finite numbers, positive sizes, a laser and a detector in front of the wall.

pub mod checks;
pub mod default;
mod early_survival;
mod exact_len;
pub mod mitsuba_xml;
pub mod reflectance;
pub mod toml_format;
pub mod wire;

pub use early_survival::EarlySurvival;
pub use reflectance::{Reflectance, MAX_RETRO_FALLOFF};

use crate::error::{Error, Result};
use crate::geometry::mesh::TriMesh;
use glam::Vec3;
use std::path::Path;

/// Which wall points the laser and the detector look at (mitransient's `capture_type`).
#[derive(serde::Serialize, serde::Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum CaptureType {
    /// One laser point (`Laser::target`), a grid of sensor points.
    Single,
    /// Laser point = sensor point, for every grid point.
    Confocal,
    /// Every grid point as laser point x every grid point as sensor point.
    Exhaustive,
}

impl CaptureType {
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "single" => Some(Self::Single),
            "confocal" => Some(Self::Confocal),
            "exhaustive" => Some(Self::Exhaustive),
            _ => None,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Self::Single => "single",
            Self::Confocal => "confocal",
            Self::Exhaustive => "exhaustive",
        }
    }
}

/// Light-transport model (DESIGN §3); the same names in the CLI, scene files and Python.
#[derive(serde::Serialize, serde::Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Model {
    /// Deterministic per-triangle three-bounce model (rung 1).
    Tri3,
    /// Monte Carlo three-bounce with hidden-geometry area sampling (rung 2).
    Mc3,
    /// Multi-bounce path tracing with laser / hidden-geometry / BSDF sampling and MIS (rung 3).
    Path,
    /// The cheapest model accurate enough for the scene.
    Auto,
}

impl Model {
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "tri3" => Some(Self::Tri3),
            "mc3" => Some(Self::Mc3),
            "path" => Some(Self::Path),
            "auto" => Some(Self::Auto),
            _ => None,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Self::Tri3 => "tri3",
            Self::Mc3 => "mc3",
            Self::Path => "path",
            Self::Auto => "auto",
        }
    }
}

/// Which shadow rays the deterministic `tri3` model casts.
#[derive(serde::Serialize, serde::Deserialize, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Visibility {
    /// None: every triangle sees both wall points (fastest; exact for convex objects
    /// facing the wall).
    None,
    /// One shadow ray from each triangle's centroid to each wall point.
    Centroid,
    /// One shadow ray per sub-triangle and wall point.
    Subtriangle,
}

impl Visibility {
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "none" => Some(Self::None),
            "centroid" => Some(Self::Centroid),
            "subtriangle" => Some(Self::Subtriangle),
            _ => None,
        }
    }
    pub fn name(self) -> &'static str {
        match self {
            Self::None => "none",
            Self::Centroid => "centroid",
            Self::Subtriangle => "subtriangle",
        }
    }
}

/// The visible diffuse relay wall: a rectangle `center + s * axis_u + t * axis_v`,
/// `s, t ∈ [-1/2, 1/2]`. Its front (the side the hidden scene is on) is
/// `axis_u × axis_v`. y-tal's convention puts it at `z = 0` with normal `+z`.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, PartialEq)]
pub struct RelayWall {
    pub center: Vec3,
    /// Full edge vector along the scan's x direction (m).
    pub axis_u: Vec3,
    /// Full edge vector along the scan's y direction (m).
    pub axis_v: Vec3,
    /// Lambertian albedo ρ_w in [0, 1].
    pub albedo: f32,
}

impl RelayWall {
    pub fn normal(&self) -> Vec3 {
        self.axis_u.cross(self.axis_v).normalize()
    }
    /// Signed distance of `p` in front of the wall plane.
    pub fn height_above(&self, p: Vec3) -> f32 {
        (p - self.center).dot(self.normal())
    }
}

/// How much light the laser delivers to its wall spot.
#[derive(serde::Serialize, serde::Deserialize, Clone, Copy, Debug, PartialEq)]
pub enum LaserEmission {
    /// Power delivered to the spot, whatever the spot's position (W).
    Power(f32),
    /// mitransient's `projector`: the spot receives `π E0 cosθ_l / |x_e - x_l|²`
    /// (DESIGN §2), whatever `fov`. `fov` (degrees) only sets the footprint.
    Irradiance { irradiance: f32, fov_deg: f32 },
}

/// The laser: where it stands, the wall point it aims at (single capture), its emission.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, PartialEq)]
pub struct Laser {
    pub origin: Vec3,
    /// Wall point hit in single capture (m).
    pub target: Vec3,
    pub emission: LaserEmission,
    /// Radius of the lit spot on the wall (m). Zero makes it a point (the usual NLOS
    /// idealisation); a positive radius makes the spot a uniformly lit disk, which
    /// BSDF-sampled paths can hit, so the renderer works with laser sampling off.
    pub spot_radius: f32,
}

impl Laser {
    /// Power `P(x_l)` delivered to a wall spot at `x_l` with wall normal `n_w` (W).
    pub fn power_at(&self, x_l: Vec3, n_w: Vec3) -> f32 {
        match self.emission {
            LaserEmission::Power(p) => p,
            LaserEmission::Irradiance { irradiance, .. } => {
                let d = self.origin - x_l;
                let d2 = d.length_squared();
                let cos_l = n_w.dot(d) / d2.sqrt();
                std::f32::consts::PI * irradiance * cos_l.max(0.0) / d2
            }
        }
    }
}

/// The time-resolved detector (SPAD); it records radiance leaving the wall toward it.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, PartialEq)]
pub struct Detector {
    pub origin: Vec3,
}

/// Scan points at the pixel centres of a rectangle on the wall (mitransient's
/// `nlos_capture_meter`): point `(ix, iy)` is
/// `center + ((ix + ½)/nx - ½) axis_u + ((iy + ½)/ny - ½) axis_v`.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, PartialEq)]
pub struct ScanGrid {
    pub nx: u32,
    pub ny: u32,
    pub center: Vec3,
    pub axis_u: Vec3,
    pub axis_v: Vec3,
}

impl ScanGrid {
    pub fn len(&self) -> usize {
        self.nx as usize * self.ny as usize
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Wall point of scan index `i = iy * nx + ix` (row-major, matching `(sy, sx, T)`).
    pub fn point(&self, i: usize) -> Vec3 {
        let ix = (i % self.nx as usize) as f32;
        let iy = (i / self.nx as usize) as f32;
        let s = (ix + 0.5) / self.nx as f32 - 0.5;
        let t = (iy + 0.5) / self.ny as f32 - 0.5;
        self.center + s * self.axis_u + t * self.axis_v
    }
}

/// Temporal response `k(τ)` of the detector (DESIGN §4).
#[derive(serde::Serialize, serde::Deserialize, Clone, Copy, Debug, PartialEq)]
pub enum KernelSpec {
    /// A histogram: a path lands in the bin that holds its OPL (mitransient's default).
    Box,
    /// Gaussian jitter with standard deviation `sigma_opl` (m of OPL), integrated exactly
    /// over each bin.
    Gaussian { sigma_opl: f32 },
}

/// The transient film (mitransient's `transient_hdr_film`): bin `b` holds OPL in
/// `[start_opl + b * bin_width_opl, start_opl + (b + 1) * bin_width_opl)`.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, PartialEq)]
pub struct FilmSpec {
    pub temporal_bins: u32,
    pub bin_width_opl: f32,
    pub start_opl: f32,
    pub kernel: KernelSpec,
}

/// A hidden Lambertian object: a world-space triangle mesh and its albedo.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
pub struct HiddenObject {
    /// Name used in messages and outputs (the file stem or the scene's `name`).
    pub name: String,
    pub mesh: TriMesh,
    /// Albedo ρ in [0, 1], used where the mesh has no per-vertex albedo.
    pub albedo: f32,
    /// Reflect on both sides. Mitsuba's `diffuse` is one-sided (black from the back);
    /// the default is one-sided to match it.
    pub two_sided: bool,
    pub reflectance: Reflectance,
}

/// Which sampling techniques the Monte Carlo estimators use (the seed paper's ablation).
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, PartialEq)]
pub struct Techniques {
    /// Next-event estimation to the laser spot (mitransient `nlos_laser_sampling`).
    pub laser_sampling: bool,
    /// Area sampling of hidden surfaces (mitransient `nlos_hidden_geometry_sampling`).
    pub hidden_geometry_sampling: bool,
    /// Hidden-geometry sampling also samples the relay wall's area, so it reaches paths
    /// that bounce off the wall mid-way (mitransient
    /// `nlos_hidden_geometry_sampling_includes_relay_wall`).
    pub hidden_geometry_includes_wall: bool,
    /// Cosine-weighted (BSDF) sampling of the next direction.
    pub bsdf_sampling: bool,
}

/// Render settings: sample count, depth, seed, model, techniques, bounce filter.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug, PartialEq)]
pub struct RenderSettings {
    pub spp: u32,
    /// Longest path, counted in bounces: 3 = laser spot, one hidden point, sensor point.
    /// `u32::MAX` means unbounded (mitransient `max_depth = -1`).
    pub max_bounces: u32,
    /// Keep only paths with exactly this many bounces (mitransient's `filter_bounces`,
    /// converted to our count when a Mitsuba scene is imported).
    pub filter_bounces: Option<u32>,
    /// Drop paths that never leave the wall (laser spot straight to the sensor point).
    pub discard_direct_paths: bool,
    /// Russian roulette by albedo starts after this many bounces (survival `ρ`, clamped
    /// to `[0.05, 0.95]`).
    pub rr_bounces: u32,
    /// `path`: the probability that a path goes on past a vertex before `rr_bounces`
    /// (Russian roulette of constant survival from the first hidden vertex on, after
    /// the vertex's own contribution: the three-bounce term keeps all its samples).
    /// `Auto`, the default, has a pilot choose it per render by the efficiency it buys
    /// (`transport::roulette`; 1 where the longer paths carry much of the error, as on
    /// the concave corner). Does not change the expectation.
    #[serde(default)]
    pub rr_early_survival: EarlySurvival,
    pub seed: u64,
    pub model: Model,
    pub techniques: Techniques,
    /// `tri3`: shadow rays.
    pub visibility: Visibility,
    /// `tri3`: largest `h² / (r w)` of a sub-triangle (edge `h`, height above the wall
    /// `r`, film resolution `w`): the OPL curvature across it, in bins.
    pub subdivision: f32,
    /// `auto`: the relative error the chosen model may leave (fraction, e.g. 0.01).
    pub max_error: f32,
    /// Test the visible legs (laser -> laser spot, sensor point -> detector) for
    /// occlusion by hidden objects; a blocked measurement records nothing, as in
    /// mitransient. `false` skips the two rays per measurement when the user knows the
    /// legs are clear.
    pub visible_legs: bool,
    /// Gradients: add the visibility boundary terms (shadow curves moving across hidden
    /// surfaces, `adjoint::boundary`) to the interior derivative. On by default; off
    /// reproduces the interior-only gradient (faster where nothing occludes).
    pub boundary_terms: bool,
}

impl RenderSettings {
    /// The longest path kept, in bounces: `max_bounces`, or the bounce filter's length.
    pub fn longest_bounces(&self) -> u32 {
        self.max_bounces
            .min(self.filter_bounces.unwrap_or(u32::MAX))
    }

    /// Whether paths of `bounces` bounces are kept (depth and bounce filter).
    pub fn keeps_bounces(&self, bounces: u32) -> bool {
        bounces <= self.max_bounces && self.filter_bounces.is_none_or(|f| f == bounces)
    }
}

/// Default `subdivision` of the `tri3` model (see `BENCHMARKS.md` for its error).
pub const DEFAULT_SUBDIVISION: f32 = 0.15;
/// Default `max_error` of `auto`.
pub const DEFAULT_MAX_ERROR: f32 = 0.01;

/// A complete NLOS scene, validated.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
pub struct Scene {
    pub wall: RelayWall,
    pub laser: Laser,
    pub detector: Detector,
    pub scan: ScanGrid,
    pub capture: CaptureType,
    pub film: FilmSpec,
    /// Add laser→`x_l` and `x_s`→detector to each path's OPL (mitransient's
    /// `account_first_and_last_bounces`; default false).
    pub account_first_and_last_bounces: bool,
    pub objects: Vec<HiddenObject>,
    pub render: RenderSettings,
    /// Things the readers fixed or ignored on the way (degenerate triangles dropped, …);
    /// the CLI prints them.
    pub warnings: Vec<String>,
}

pub use checks::MAX_SPOT_POWER;

impl Scene {
    /// Loads a scene file, choosing the reader by extension (`.toml` or `.xml`).
    pub fn load(path: &Path) -> Result<Scene> {
        Self::load_with_defines(path, &[])
    }

    /// [`Scene::load`] with Mitsuba-style `-D name=value` defines (XML scenes only).
    pub fn load_with_defines(path: &Path, defines: &[(String, String)]) -> Result<Scene> {
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        match ext.to_ascii_lowercase().as_str() {
            "toml" if !defines.is_empty() => Err(Error::scene(
                path,
                "-D name=value defines apply to Mitsuba XML scenes only",
            )),
            "toml" => toml_format::load(path).map(Scene::with_load_warnings),
            "xml" => mitsuba_xml::load_with_defines(path, defines).map(Scene::with_load_warnings),
            _ => Err(Error::scene(
                path,
                "unknown scene format: the extension must be .toml (Umbra) or .xml (Mitsuba)",
            )),
        }
    }

    /// The scene with a warning for every hidden object whose faces coincide with other
    /// faces (a duplicated layer renders up to twice as bright; [`overlap`]), that lies
    /// partly behind the wall, and for scan points off the wall ([`checks::warnings`]).
    /// The file loaders and Python's loaders call it.
    ///
    /// [`overlap`]: crate::geometry::overlap
    pub fn with_load_warnings(mut self) -> Scene {
        let more = checks::warnings(&self);
        self.warnings.extend(more);
        let meshes: Vec<_> = self
            .objects
            .iter()
            .map(|o| (&o.mesh.positions[..], &o.mesh.triangles[..]))
            .collect();
        let min_stack = 0.5 * self.film.bin_width_opl;
        for c in crate::geometry::overlap::coincident_faces(&meshes, min_stack) {
            let by: Vec<String> = c
                .covered_by
                .iter()
                .map(|&k| match k == c.object {
                    true => "its own faces".to_string(),
                    false => format!("objects[{k}] ({})'s", self.objects[k].name),
                })
                .collect();
            self.warnings.push(format!(
                "objects[{}] ({}): {:.0} % of its area lies on top of other faces facing the same way, \
                 within {:.1} mm ({}): a duplicated layer? Without visibility both copies \
                 reflect, so that surface renders up to twice as bright; remove the duplicate \
                 faces",
                c.object,
                self.objects[c.object].name,
                100.0 * c.share,
                1e3 * c.stack_distance,
                by.join(" and ")
            ));
        }
        self
    }

    /// Number of (laser point, sensor point) pairs the capture measures.
    pub fn num_measurements(&self) -> usize {
        match self.capture {
            CaptureType::Single | CaptureType::Confocal => self.scan.len(),
            // Saturating: a scene this large is refused by the memory budget
            // (`transport::budget`), which counts in u64 itself.
            CaptureType::Exhaustive => self.scan.len().saturating_mul(self.scan.len()),
        }
    }

    /// Laser and sensor wall points of measurement `m`, in the output's row-major order
    /// (`(sy, sx)` or, exhaustive, `(sy, sx, ly, lx)`: mitransient 1.3.1's order, sensor
    /// point outermost).
    pub fn measurement_points(&self, m: usize) -> (Vec3, Vec3) {
        match self.capture {
            CaptureType::Single => (self.laser.target, self.scan.point(m)),
            CaptureType::Confocal => {
                let p = self.scan.point(m);
                (p, p)
            }
            CaptureType::Exhaustive => {
                let n = self.scan.len();
                (self.scan.point(m % n), self.scan.point(m / n))
            }
        }
    }

    /// Output array shape in mitransient's layout.
    pub fn output_shape(&self) -> Vec<usize> {
        let (sy, sx, t) = (
            self.scan.ny as usize,
            self.scan.nx as usize,
            self.film.temporal_bins as usize,
        );
        match self.capture {
            CaptureType::Exhaustive => vec![sy, sx, sy, sx, t],
            _ => vec![sy, sx, t],
        }
    }

    pub fn total_hidden_triangles(&self) -> usize {
        self.objects.iter().map(|o| o.mesh.triangles.len()).sum()
    }

    /// Checks every invariant the renderers rely on; `origin` names the file in messages.
    pub fn validate(&self, origin: &Path) -> Result<()> {
        let err = |field: &str, msg: String| Err(Error::field(origin, field, msg));
        let finite3 = |v: Vec3| v.is_finite();
        for (name, v) in [
            ("wall.center", self.wall.center),
            ("wall.axis_u", self.wall.axis_u),
            ("wall.axis_v", self.wall.axis_v),
            ("laser.origin", self.laser.origin),
            ("laser.target", self.laser.target),
            ("detector.origin", self.detector.origin),
            ("scan.center", self.scan.center),
            ("scan.axis_u", self.scan.axis_u),
            ("scan.axis_v", self.scan.axis_v),
        ] {
            if !finite3(v) {
                return err(name, format!("must be finite, got {v}"));
            }
        }
        let area = self.wall.axis_u.cross(self.wall.axis_v).length();
        if area.is_nan() || area <= 1e-12 {
            return err("wall.size", "the relay wall has zero area".into());
        }
        if !(0.0..=1.0).contains(&self.wall.albedo) {
            return err(
                "wall.albedo",
                format!("must be in [0, 1], got {}", self.wall.albedo),
            );
        }
        if self.scan.nx == 0 || self.scan.ny == 0 {
            return err("scan.resolution", "must be at least 1 x 1".into());
        }
        let n_w = self.wall.normal();
        if self.wall.height_above(self.laser.origin) <= 0.0 {
            return err(
                "laser.origin",
                "the laser is behind (or on) the relay wall: it must be on the side the wall's normal points to".into(),
            );
        }
        if self.wall.height_above(self.detector.origin) <= 0.0 {
            return err(
                "detector.origin",
                "the detector is behind (or on) the relay wall".into(),
            );
        }
        let on_plane = |p: Vec3| (p - self.wall.center).dot(n_w).abs() < 1e-4;
        if self.capture == CaptureType::Single && !on_plane(self.laser.target) {
            return err(
                "laser.target",
                format!(
                    "the laser target {} is not on the relay wall plane",
                    self.laser.target
                ),
            );
        }
        if !on_plane(self.scan.center)
            || self.scan.axis_u.dot(n_w).abs() > 1e-4
            || self.scan.axis_v.dot(n_w).abs() > 1e-4
        {
            return err(
                "scan",
                "the scan rectangle must lie on the relay wall plane".into(),
            );
        }
        match self.laser.emission {
            LaserEmission::Power(p) if !(p.is_finite() && p >= 0.0) => {
                return err("laser.power", format!("must be finite and >= 0, got {p}"))
            }
            LaserEmission::Irradiance { irradiance, .. }
                if !(irradiance.is_finite() && irradiance >= 0.0) =>
            {
                return err(
                    "laser.irradiance",
                    format!("must be finite and >= 0, got {irradiance}"),
                )
            }
            LaserEmission::Irradiance { fov_deg, .. } if !fov_deg.is_finite() => {
                return err("laser.fov", format!("must be finite, got {fov_deg}"))
            }
            _ => {}
        }
        checks::spot_power(self, &err)?;
        if !(self.laser.spot_radius.is_finite() && self.laser.spot_radius >= 0.0) {
            return err("laser.spot_radius", "must be finite and >= 0".into());
        }
        if let EarlySurvival::Fixed(q) = self.render.rr_early_survival {
            if let Err(e) = EarlySurvival::fixed(q) {
                return err("render.rr_early_survival", e);
            }
        }
        let f = &self.film;
        if f.temporal_bins == 0 {
            return err("film.temporal_bins", "must be at least 1".into());
        }
        if !(f.bin_width_opl.is_finite() && f.bin_width_opl > 0.0) {
            return err(
                "film.bin_width_opl",
                format!("must be > 0, got {}", f.bin_width_opl),
            );
        }
        if !f.start_opl.is_finite() {
            return err("film.start_opl", "must be finite".into());
        }
        if let KernelSpec::Gaussian { sigma_opl } = f.kernel {
            if !(sigma_opl.is_finite() && sigma_opl > 0.0) {
                return err("film.sigma_opl", format!("must be > 0, got {sigma_opl}"));
            }
        }
        for (i, o) in self.objects.iter().enumerate() {
            if !(0.0..=1.0).contains(&o.albedo) {
                return err(
                    &format!("objects[{i}].albedo"),
                    format!("must be in [0, 1], got {}", o.albedo),
                );
            }
            if let Some(a) = &o.mesh.vertex_albedo {
                if a.iter().any(|v| !(0.0..=1.0).contains(v)) {
                    return err(
                        &format!("objects[{i}].vertex_albedo"),
                        "must be in [0, 1]".into(),
                    );
                }
            }
        }
        let r = &self.render;
        if r.spp == 0 {
            return err("render.spp", "must be at least 1".into());
        }
        if !(r.subdivision.is_finite() && r.subdivision > 0.0) {
            return err(
                "render.subdivision",
                format!("must be > 0, got {}", r.subdivision),
            );
        }
        if !(r.max_error.is_finite() && r.max_error > 0.0) {
            return err(
                "render.max_error",
                format!("must be > 0, got {}", r.max_error),
            );
        }
        if r.max_bounces < 3 {
            return err(
                "render.max_depth",
                "NLOS paths need at least 3 bounces".into(),
            );
        }
        checks::check(self, origin)
    }
}
