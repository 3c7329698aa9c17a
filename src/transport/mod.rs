//! Light transport: the estimators of DESIGN §3 and the parallel driver that runs them
//! over all measurements.
//!
//! Estimators do not write to a film. For each sample they emit [`Contribution`]s
//! (OPL, weight, bounce count, the path's vertices) to a [`Sink`]. The primal sink
//! splats them through the temporal kernel; the adjoint sink (gradients) reads the
//! adjoint histogram through the same kernel. One sampling routine serves both.
//!
//! Determinism: sample `i` of measurement `m` draws its numbers from
//! `Sampler::new(seed, m, i)`; samples are grouped in fixed blocks of [`BLOCK_SPP`]
//! whose histograms are summed in block order, so the output does not depend on the
//! number of threads.

pub mod auto;
pub mod budget;
pub mod gate;
pub(crate) mod lanes;
pub mod mc3;
pub mod mc3_lanes;
pub mod path;
pub mod path_lanes;
mod path_replay;
pub(crate) mod path_step;
pub mod render;
pub mod roulette;
pub mod silence;
pub mod tri3;
pub mod tri3_adjoint;
pub mod tri3_exact;
pub mod tri3_kernel;
pub mod tri3_physics;

pub use render::{render, Progress, RenderOptions, Renderer, Transient};

use crate::film::Film;
use crate::geometry::{point_shadow, SceneGeometry};
use crate::rng::{Reserved, Sampler, StreamSeeds};
use crate::scene::{Model, Scene};
use glam::Vec3;
use std::f32::consts::FRAC_1_PI;
use std::sync::OnceLock;

/// Samples per block of work (the unit of parallelism and of progress).
pub const BLOCK_SPP: u32 = 1024;

/// One path's contribution to a measurement: radiance `weight` arriving at OPL `opl`.
#[derive(Clone, Copy, Debug)]
pub struct Contribution {
    /// Optical path length (m), legs to the laser and detector included if requested.
    pub opl: f32,
    /// Monte Carlo weight (radiance, already divided by the sampling pdf).
    pub weight: f32,
    /// Scattering events from the laser spot to the sensor point inclusive (3 = one
    /// hidden bounce).
    pub bounces: u32,
}

/// Derivatives of a contribution's weight and OPL with respect to the local parameters
/// of one hidden triangle it depends on (`mc3::TRI_PARAMS`: corners, then albedos).
#[derive(Clone, Copy, Debug)]
pub struct HiddenGrad {
    /// Flat hidden-triangle index.
    pub flat: u32,
    pub weight: [f32; mc3::TRI_PARAMS],
    /// (m per parameter unit)
    pub opl: [f32; mc3::TRI_PARAMS],
}

/// Receives contributions.
pub trait Sink {
    /// An adjoint sink: the estimators then call [`Sink::add_grad`] instead of
    /// [`Sink::add`], with the derivatives (the primal pass compiles without them).
    const ADJOINT: bool = false;

    fn add(&mut self, c: &Contribution);

    /// Adjoint pass: `c` and the derivatives of its weight and OPL.
    fn add_grad(&mut self, c: &Contribution, _grads: &[HiddenGrad]) {
        self.add(c)
    }
}

/// The primal sink: splats weights into a histogram.
pub struct HistogramSink<'a> {
    pub film: &'a Film,
    pub hist: &'a mut [f64],
}

impl Sink for HistogramSink<'_> {
    #[inline]
    fn add(&mut self, c: &Contribution) {
        self.film.splat(c.opl, c.weight, self.hist);
    }
}

/// Everything a sample of one measurement needs: its wall points, the laser's power,
/// radiometric constants and the scene's surfaces.
pub struct MeasurementCtx<'a> {
    pub scene: &'a Scene,
    pub geom: &'a SceneGeometry,
    /// Centre of the laser spot on the wall.
    pub x_l: Vec3,
    /// Sensor point on the wall.
    pub x_s: Vec3,
    pub n_w: Vec3,
    /// Whether the visible legs are clear: the laser reaches `x_l` and the detector sees
    /// `x_s` (both lines tested against the hidden objects unless the scene's
    /// `render.visible_legs` is off; a finite spot is tested along its central ray).
    pub legs_visible: bool,
    /// Power `P(x_l)` delivered to the spot (DESIGN §2), times the visible legs'
    /// visibility: 0 for a blocked measurement, so every model records nothing for it
    /// and its gradient is zero.
    pub power: f32,
    /// Wall BRDF `ρ_w / π`.
    pub f_wall: f32,
    /// OPL of the detector leg `|x_s - detector|` if counted, else 0.
    pub opl_sensor_leg: f32,
    /// OPL range that can reach the film (kernel support included): paths outside skip
    /// their visibility rays.
    pub opl_min: f32,
    pub opl_max: f32,
    /// `2 d_w`, `d_w` the hidden geometry's gap to the wall plane
    /// ([`SceneGeometry::wall_gap`]), and a floor (m) on the laser leg's OPL: what
    /// [`MeasurementCtx::past_film`] bounds the rest of a path with.
    wall_gap2: f32,
    laser_leg_floor: f32,
    /// `path`: survival of the Russian roulette before `rr_bounces`: the scene's fixed
    /// `render.rr_early_survival`, or what [`roulette`]'s pilot chose for the render
    /// ([`render::Renderer::measurement`]); 1 (none) for `auto` elsewhere.
    pub rr_early_survival: f32,
    /// Bit `t` set: a segment from hidden triangle `t` to the spot centre `x_l` needs no
    /// hidden-geometry shadow test ([`SceneGeometry::clear_toward`]); worked out on first
    /// use, so models that never ask (tri3) do not pay for it.
    spot_clear: OnceLock<u64>,
    /// The same toward the sensor point `x_s`.
    sensor_clear: OnceLock<u64>,
}

impl<'a> MeasurementCtx<'a> {
    pub fn new(scene: &'a Scene, geom: &'a SceneGeometry, film: &Film, m: usize) -> Self {
        let (x_l, x_s) = scene.measurement_points(m);
        let n_w = geom.wall_normal;
        let margin = match film.kernel {
            crate::scene::KernelSpec::Box => 0.0,
            crate::scene::KernelSpec::Gaussian { sigma_opl } => {
                crate::film::GAUSS_CUTOFF * sigma_opl as f64
            }
        };
        let legs_visible = !scene.render.visible_legs
            || !(geom.occluded(scene.laser.origin, x_l)
                || geom.occluded(x_s, scene.detector.origin));
        MeasurementCtx {
            scene,
            geom,
            x_l,
            x_s,
            n_w,
            legs_visible,
            power: if legs_visible {
                scene.laser.power_at(x_l, n_w)
            } else {
                0.0
            },
            f_wall: scene.wall.albedo * FRAC_1_PI,
            opl_sensor_leg: if scene.account_first_and_last_bounces {
                (x_s - scene.detector.origin).length()
            } else {
                0.0
            },
            opl_min: (film.start - margin) as f32,
            opl_max: (film.end() + margin) as f32,
            wall_gap2: 2.0 * geom.wall_gap,
            rr_early_survival: match scene.render.rr_early_survival {
                crate::scene::EarlySurvival::Fixed(q) => q,
                crate::scene::EarlySurvival::Auto => 1.0,
            },
            laser_leg_floor: if scene.account_first_and_last_bounces {
                ((x_l - scene.laser.origin).length() - scene.laser.spot_radius).max(0.0)
            } else {
                0.0
            },
            spot_clear: OnceLock::new(),
            sensor_clear: OnceLock::new(),
        }
    }

    /// Whether the segment `a`–`b`, one end on hidden triangle `flat`, is blocked:
    /// [`SceneGeometry::occluded_touching`]'s answer. Where the other end is the spot
    /// centre `x_l` or the sensor point `x_s` and no hidden triangle can shadow `flat`
    /// toward it ([`SceneGeometry::clear_toward`], one bit set per measurement), only the
    /// wall is tested: the same answer without the hidden-geometry query.
    #[inline]
    pub fn occluded_touching(&self, a: Vec3, b: Vec3, flat: u32) -> bool {
        if (flat as usize) < point_shadow::MAX_TRIANGLES {
            let clear = |end: Vec3| {
                let mask = if end == self.x_l {
                    &self.spot_clear
                } else if end == self.x_s {
                    &self.sensor_clear
                } else {
                    return false;
                };
                (*mask.get_or_init(|| self.geom.clear_toward(end)) >> flat) & 1 == 1
            };
            if clear(b) || clear(a) {
                return self.geom.occluded_by_wall(a, b);
            }
        }
        self.geom.occluded_touching(a, b, flat)
    }

    /// Whether every contribution a path can still make from vertex `x` (OPL `opl`
    /// walked to it, `x` on the wall if `on_wall`, `wall_only` if its next vertex can only
    /// be a wall point, `path_step::Onward::WallOnly`) lands at or past `opl_max`, so the
    /// walk can stop there: the film is the same, the work after it is not done. The
    /// rest of the path is at least `|x − x_l| − r` long (triangle inequality, `r` the
    /// spot's radius). From a wall point, whose next vertex is hidden and at least `d_w`
    /// in front of the wall's plane, it is at least `√((|x − x_l| − r)² + (2 d_w)²)`
    /// (the shortest bounce off the plane `d_w` out). From a hidden point `h` in front of
    /// the wall whose next vertex is a wall point, with a point spot (a path closes only
    /// by NEE from a hidden vertex), it is at least `h + 2 d_w`: to the wall, out to the
    /// hidden geometry again, and back. A finite spot can close the path at that wall
    /// point, so it keeps the first bound. A relative margin of `1e-5` keeps the test
    /// clear of `f32` rounding in the summed OPL.
    #[inline]
    pub fn past_film(&self, opl: f32, x: Vec3, on_wall: bool, wall_only: bool) -> bool {
        let r = self.scene.laser.spot_radius;
        let d = ((x - self.x_l).length() - r).max(0.0);
        let rest = if on_wall {
            (d * d + self.wall_gap2 * self.wall_gap2).sqrt()
        } else if wall_only && r == 0.0 {
            d.max(self.n_w.dot(x - self.x_l) + self.wall_gap2)
        } else {
            d
        };
        (opl + rest + self.laser_leg_floor) * (1.0 - 1e-5) >= self.opl_max
    }

    /// `P (ρ_w/π)²`: the constant factor of every three-bounce contribution (the laser's
    /// power on the spot and the wall's BRDF at both wall points).
    pub fn three_bounce_constant(&self) -> f32 {
        self.power * self.f_wall * self.f_wall
    }

    /// OPL of the laser leg `|laser - x_l|` if counted, else 0.
    pub fn opl_laser_leg(&self, x_l: Vec3) -> f32 {
        self.laser_leg(x_l.to_array())
    }

    /// The laser leg's length (m) to a spot point in any number type (a continuation
    /// that lands on a finite spot moves with the path in the adjoint pass); 0 unless the
    /// scene accounts the first and last bounces.
    pub fn laser_leg<R: crate::adjoint::dual::Real>(&self, p: [R; 3]) -> R {
        use crate::adjoint::dual;
        if self.scene.account_first_and_last_bounces {
            dual::length(dual::sub(dual::constant(self.scene.laser.origin), p))
        } else {
            R::c(0.0)
        }
    }
}

/// Runs samples `range` of measurement `m` with the model's sampling routine (the
/// caller's path scratch: its counters are what the adjoint reads).
pub fn run_samples<S: Sink>(
    model: Model,
    ctx: &MeasurementCtx,
    seed: u64,
    m: u64,
    range: std::ops::Range<u32>,
    sink: &mut S,
    scratch: &mut path::PathScratch,
) {
    // Every NLOS path has a hidden vertex: without hidden triangles none exists (and the
    // area distribution they would be picked from is empty).
    if ctx.scene.total_hidden_triangles() == 0 {
        return;
    }
    let seeds = StreamSeeds::new(seed, m);
    // Eight samples at a time: the scalar routines' contributions (and derivatives), in
    // the same order (`tests/lanes.rs`).
    match model {
        Model::Mc3 => mc3_lanes::run(ctx, &seeds, range, sink),
        Model::Path => path_lanes::run(ctx, &seeds, range, scratch, sink),
        Model::Tri3 | Model::Auto => unreachable!("not a Monte Carlo model"),
    }
}

/// A point of the laser spot: its centre, or a uniform point of the lit disk from the
/// pair set aside as `u` (read only for a disk).
#[inline]
pub fn sample_spot(ctx: &MeasurementCtx, sampler: &Sampler, u: Reserved) -> Vec3 {
    if ctx.scene.laser.spot_radius > 0.0 {
        spot_point(ctx, sampler.get_2d(u))
    } else {
        ctx.x_l
    }
}

/// The point of a finite laser spot at `u` (uniform on the lit disk).
#[inline]
pub fn spot_point(ctx: &MeasurementCtx, u: [f32; 2]) -> Vec3 {
    let r = ctx.scene.laser.spot_radius;
    crate::geometry::sampling::uniform_disk(ctx.x_l, ctx.n_w, r, u)
}
