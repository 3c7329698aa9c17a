//! The renderer as the fit's objective: the hidden mesh being fitted replaces the scene's
//! hidden objects, Umbra renders it, the render goes through the detector's response
//! (jitter or measured IRF, optionally shifted: [`super::time_offset`]), and the loss
//! against the measurement `M` is the relative squared error after the best intensity
//! scale and background ([`super::intensity`]):
//!
//! `L(θ) = min_{s ≥ 0, b ≥ 0} ‖s K H(θ) + b − M‖²_U / ‖M‖²_U`,
//!
//! `U` the bins the fit uses (each row's bins from `first_bin` on). By the envelope
//! theorem the adjoint `δH = Kᵀ 2 s (s K H + b − M) / ‖M‖²` on `U` goes through
//! [`crate::adjoint::gradient`] (path replay) as any other loss.
//!
//! Monte Carlo models are seeded from the parameters (a hash of the mesh's bits), so the
//! same mesh renders the same samples (common random numbers between the cost and the
//! gradient, and an exact resume), while every new iterate sees new noise.

use super::capture::CaptureModel;
use super::intensity::{Intensity, IntensityModel};
use super::linear_fit::LinearFit;
use super::time_offset::Comparator;
use crate::adjoint;
use crate::geometry::{mesh::TriMesh, SceneGeometry};
use crate::scene::{HiddenObject, Model, Reflectance, Scene};
use crate::transport::gate::Pass;
use crate::transport::{roulette, RenderOptions, Renderer};
use glam::Vec3;
use optim::{Evaluation, Mesh, MeshObjective};

/// The fitted mesh as a hidden object.
pub fn hidden_object(
    mesh: &Mesh,
    albedo: f32,
    two_sided: bool,
    reflectance: Reflectance,
) -> HiddenObject {
    let positions = mesh
        .vertices
        .iter()
        .map(|p| Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32))
        .collect();
    let vertex_albedo = (!mesh.vertex_values.is_empty())
        .then(|| mesh.vertex_values.iter().map(|&a| a as f32).collect());
    HiddenObject {
        name: "fit".into(),
        mesh: TriMesh {
            positions,
            triangles: mesh.faces.clone(),
            vertex_albedo,
        },
        albedo,
        two_sided,
        reflectance,
    }
}

/// A 64-bit FNV-1a hash of the mesh's bits: the seed of Monte Carlo renders.
fn mesh_seed(base: u64, mesh: &Mesh) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64 ^ base;
    let mut eat = |x: u64| {
        for b in x.to_le_bytes() {
            h ^= b as u64;
            h = h.wrapping_mul(0x100_0000_01b3);
        }
    };
    for p in &mesh.vertices {
        p.iter().for_each(|c| eat(c.to_bits()));
    }
    mesh.vertex_values.iter().for_each(|a| eat(a.to_bits()));
    h
}

/// One stage's objective: the scene at the stage's resolution (its hidden objects are
/// replaced by the fitted mesh) and the measurement at the same resolution.
pub struct UmbraObjective {
    pub scene: Scene,
    pub measured: Vec<f32>,
    pub options: RenderOptions,
    pub intensity: IntensityModel,
    /// Albedo of the fitted object where it has no per-vertex albedo.
    pub albedo: f32,
    pub two_sided: bool,
    /// How the fitted surface reflects.
    pub reflectance: Reflectance,
    /// Bins before this one are left out of the loss (zeroed in render and
    /// measurement): e.g. a capture's residual direct light.
    pub first_bin: usize,
    /// Detector timing jitter `σ` (OPL, m) applied to the render after binning
    /// ([`crate::film::jitter`]); 0: none.
    pub jitter_opl: f64,
    /// The detector's measured impulse response, used instead of the jitter Gaussian.
    pub irf: Option<crate::film::irf::Irf>,
    /// Search an unknown time offset `|δ| ≤` this (OPL, m; needs `jitter_opl > 0`;
    /// [`super::time_offset`]); 0: none.
    pub time_offset_max_opl: f64,
    /// A real capture's calibrated model ([`super::capture`]): used instead of the
    /// jitter/IRF, intensity and time offset above when present.
    pub capture: Option<CaptureModel>,
}

/// The first bin of the scene's film that starts at or after `ignore_before_opl` (m),
/// 0 when nothing is ignored.
pub fn first_fitted_bin(scene: &Scene, ignore_before_opl: Option<f32>) -> usize {
    ignore_before_opl.map_or(0, |opl| {
        ((opl - scene.film.start_opl) / scene.film.bin_width_opl)
            .ceil()
            .max(0.0) as usize
    })
}

/// Refuses an `--ignore-before` OPL (m) that leaves no bin of `film`; `flag` names it.
pub fn check_ignore_before(
    film: &crate::scene::FilmSpec,
    opl: Option<f32>,
    flag: &str,
) -> crate::Result<()> {
    let end = film.start_opl + film.temporal_bins as f32 * film.bin_width_opl;
    match opl {
        Some(v) if !v.is_finite() || v >= end => Err(crate::Error::Invalid(format!(
            "{flag}: {v} m is not an optical path length before the film's end ({end} m): every bin would be ignored"
        ))),
        _ => Ok(()),
    }
}

/// Zeroes bins `..first` of every `bins`-long row.
pub fn zero_leading_bins(data: &mut [f32], bins: usize, first: usize) {
    if first == 0 || bins == 0 {
        return;
    }
    for row in data.chunks_mut(bins) {
        row[..first.min(bins)].fill(0.0);
    }
}

/// One forward evaluation: what the adjoint pass needs besides the render.
struct Forward {
    scene: Scene,
    geom: SceneGeometry,
    opts: RenderOptions,
    render: Vec<f32>,
    loss: f64,
    adjoint: Vec<f32>,
    intensity: Intensity,
    time_offset_opl: f64,
    /// The capture model's fitted nuisances (with a capture model).
    capture_fit: Option<LinearFit>,
    /// The loss at the held-out scan points (NaN: none held out, or no capture model).
    held_out: f64,
}

/// What [`UmbraObjective::render`] returns.
pub struct Rendered {
    /// The render as compared (through the detector response, unfitted bins zeroed).
    pub compared: Vec<f32>,
    /// The fitted transient: `s · compared + background`, or the capture model's `μ`.
    pub model: Vec<f32>,
    pub loss: f64,
    pub intensity: Intensity,
    /// The time offset (OPL, m): the searched `δ`, or the calibrated response's `t0`.
    pub time_offset_opl: f64,
    /// The loss at the held-out scan points (NaN: none).
    pub held_out: f64,
    /// The capture model's fitted coefficients by name (`PointBackground::coefficients`;
    /// empty without a capture model).
    pub nuisance: Vec<(String, f64)>,
    /// The capture model's floor per scan point (counts per bin, every point in the
    /// measurement's order; empty without one).
    pub floors: Vec<f64>,
}

impl UmbraObjective {
    /// How renders are compared with the measurement at this objective's resolution.
    fn comparator(&self) -> Comparator {
        let width = self.scene.film.bin_width_opl as f64;
        Comparator {
            bins: self.scene.film.temporal_bins as usize,
            first_bin: self.first_bin,
            intensity: self.intensity,
            sigma_bins: self.jitter_opl / width,
            offset_max_bins: self.time_offset_max_opl / width,
            irf: self
                .irf
                .as_ref()
                .map_or(Vec::new(), |k| k.at_width(width).taps),
        }
    }

    /// Renders `mesh` and compares it, without the gradient.
    pub fn render(&self, mesh: &Mesh) -> crate::Result<Rendered> {
        let f = self.forward(mesh)?;
        let bins = self.scene.film.temporal_bins as usize;
        let model = match (&self.capture, &f.capture_fit) {
            (Some(c), Some(fit)) => c.fitted(&f.render, fit),
            _ => f
                .render
                .iter()
                .enumerate()
                .map(|(i, &h)| {
                    let t = i % bins.max(1);
                    if t < self.first_bin {
                        0.0
                    } else {
                        (f.intensity.scale * h as f64 + f.intensity.background_at(t)) as f32
                    }
                })
                .collect(),
        };
        let nuisance = match (&self.capture, &f.capture_fit) {
            (Some(c), Some(fit)) => c.design.coefficients(fit),
            _ => Vec::new(),
        };
        Ok(Rendered {
            compared: f.render,
            model,
            loss: f.loss,
            intensity: f.intensity,
            time_offset_opl: f.time_offset_opl,
            held_out: f.held_out,
            nuisance,
            floors: f.capture_fit.map(|fit| fit.floors).unwrap_or_default(),
        })
    }

    /// `Z K_δ H` of `mesh` at a given time offset (OPL, m): the render as the loss sees
    /// it before scale and background, with no intensity or offset fitted (for a part
    /// of a fitted mesh at the whole's offset: `fit::determined`).
    pub fn response(&self, mesh: &Mesh, time_offset_opl: f64) -> crate::Result<Vec<f32>> {
        let (_, _, _, raw) = self.raw(mesh)?;
        if let Some(c) = &self.capture {
            return Ok(c.blur(&raw).0);
        }
        let shift = time_offset_opl / self.scene.film.bin_width_opl as f64;
        Ok(self.comparator().response(&raw, shift))
    }

    /// The scene with `mesh` as its hidden object, its geometry, the render options and
    /// the raw render.
    pub(super) fn raw(
        &self,
        mesh: &Mesh,
    ) -> crate::Result<(Scene, SceneGeometry, RenderOptions, Vec<f32>)> {
        let mut scene = self.scene.clone();
        scene.objects = vec![hidden_object(
            mesh,
            self.albedo,
            self.two_sided,
            self.reflectance,
        )];
        let geom = SceneGeometry::build(&scene);
        let mut opts = self.options;
        if opts.model == Model::Auto {
            opts.model = Model::Tri3;
        }
        if opts.model != Model::Tri3 {
            opts.seed = mesh_seed(self.options.seed, mesh);
        }
        // The render and the gradient play one roulette: its pilot runs once.
        let scene = roulette::resolved(&scene, &geom, &opts, Pass::Gradient)?;
        let raw = Renderer::new(&scene, &geom, &opts)?.render(None)?.data;
        Ok((scene, geom, opts, raw))
    }

    /// The scene with `mesh` as its hidden object, its render (leading bins left out)
    /// and the loss with its adjoint.
    fn forward(&self, mesh: &Mesh) -> crate::Result<Forward> {
        let (scene, geom, opts, raw) = self.raw(mesh)?;
        if let Some(capture) = &self.capture {
            let c = capture.compare(&raw, &self.measured);
            let intensity = capture.intensity(&c);
            return Ok(Forward {
                scene,
                geom,
                opts,
                render: c.blurred,
                loss: c.loss,
                adjoint: c.adjoint,
                intensity,
                time_offset_opl: capture.response.t0,
                capture_fit: Some(c.fit),
                held_out: c.held_out,
            });
        }
        let c = self.comparator().compare(&raw, &self.measured);
        let (render, loss, adjoint, intensity) = (c.fitted, c.loss, c.adjoint, c.intensity);
        let time_offset_opl = c.offset_bins * scene.film.bin_width_opl as f64;
        Ok(Forward {
            scene,
            geom,
            opts,
            render,
            loss,
            adjoint,
            intensity,
            time_offset_opl,
            capture_fit: None,
            held_out: f64::NAN,
        })
    }
}

impl MeshObjective for UmbraObjective {
    /// With a fitted intensity scale (or the capture model's gain) and a one-bounce model
    /// (`tri3`, `mc3`: the render is linear in every albedo), scaling all albedos by one
    /// factor leaves the loss unchanged. `path` carries hidden-to-hidden bounces
    /// (quadratic in albedo): not scale-free.
    fn values_scale_free(&self) -> bool {
        self.intensity.scale && matches!(self.options.model, Model::Tri3 | Model::Mc3)
    }

    /// The relay wall's box widened on every side by half the film's longest optical
    /// path, grown to hold the laser and the detector: a hidden point's path leaves the
    /// wall and returns to it, so its OPL is at least twice its distance from the wall,
    /// and a surface farther than that adds nothing to any bin. A vertex out there is a
    /// step gone wild (and `tri3`, which splits triangles into pieces of about a bin,
    /// would spend minutes on its metres-long triangles).
    fn bounds(&self) -> Option<([[f64; 3]; 2], String)> {
        let s = &self.scene;
        let w = &s.wall;
        let reach =
            s.film.start_opl as f64 + s.film.temporal_bins as f64 * s.film.bin_width_opl as f64;
        let mut b = [[f64::INFINITY; 3], [f64::NEG_INFINITY; 3]];
        let mut grow = |p: Vec3, margin: f64| {
            for k in 0..3 {
                b[0][k] = b[0][k].min(p[k] as f64 - margin);
                b[1][k] = b[1][k].max(p[k] as f64 + margin);
            }
        };
        for (u, v) in [(-0.5, -0.5), (-0.5, 0.5), (0.5, -0.5), (0.5, 0.5)] {
            grow(w.center + u * w.axis_u + v * w.axis_v, 0.5 * reach);
        }
        grow(s.laser.origin, 0.0);
        grow(s.detector.origin, 0.0);
        Some((
            b,
            format!(
                "the relay wall widened by half the film's longest path, {reach:.3} m, and the laser and detector: the measurement sees nothing beyond"
            ),
        ))
    }

    fn evaluate(&mut self, mesh: &Mesh) -> Result<Evaluation, String> {
        let f = self.forward(mesh).map_err(|e| e.to_string())?;
        let g = adjoint::gradient(&f.scene, &f.geom, &f.opts, &f.adjoint, None)
            .map_err(|e| e.to_string())?;
        let d_vertices = g.vertices.into_iter().next().unwrap_or_default();
        let d_values = if mesh.vertex_values.is_empty() {
            Vec::new()
        } else {
            g.vertex_albedo
                .into_iter()
                .next()
                .flatten()
                .unwrap_or_else(|| vec![0.0; mesh.vertices.len()])
        };
        Ok(Evaluation {
            loss: f.loss,
            d_vertices,
            d_values,
            report: {
                let mut r = vec![
                    ("scale".into(), f.intensity.scale),
                    ("background".into(), f.intensity.background),
                    ("time_offset".into(), f.time_offset_opl),
                ];
                if let Some(c) = &self.capture {
                    r.push(("held_out".into(), f.held_out));
                    r.push(("response_sigma".into(), c.response.sigma));
                }
                r
            },
        })
    }
}
