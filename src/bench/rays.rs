//! `umbra bench rays`: the path tracer's ray throughput against the machine's.
//!
//! 1. The scene is rendered as asked (median of `reps` timed renders): samples/s.
//! 2. It is rendered once more on one thread inside [`ray_log::record`]: every closest-hit
//!    and shadow ray the estimator cast, hence rays per sample.
//! 3. Those rays are replayed alone, on the same threads as the render: through Umbra's
//!    own ray functions ([`SceneGeometry::intersect`], [`SceneGeometry::occluded`]: the
//!    analytic wall, packets or the BVH), and through a bare obvhs CWBVH over every
//!    triangle including the wall's two (obvhs's raw rate, no shading, no wall plane).
//!
//! The render's *effective* rays/s (samples/s x rays/sample) against the replays' shows how
//! much of a sample's time goes to tracing: at the raw rate a render would take
//! `effective / raw` of its time in ray queries.

use crate::error::Result;
use crate::geometry::ray_log::{self, LoggedRay};
use crate::geometry::SceneGeometry;
use crate::scene::{Model, Scene};
use crate::transport::{RenderOptions, Renderer};
use obvhs::cwbvh::builder::build_cwbvh_from_tris;
use obvhs::ray::{Ray, RayHit};
use obvhs::BvhBuildParams;
use rayon::prelude::*;
use std::time::{Duration, Instant};

/// The figures of one run.
#[derive(Clone, Debug)]
pub struct RayFigures {
    pub samples: u64,
    pub closest_rays: u64,
    pub shadow_rays: u64,
    /// Median seconds of the timed renders.
    pub render_seconds: f64,
    /// Median seconds to replay every logged ray through Umbra's ray functions.
    pub umbra_replay_seconds: f64,
    /// Median seconds to replay them through a bare obvhs CWBVH.
    pub obvhs_replay_seconds: f64,
    /// Rays that hit (closest) or were blocked (shadow), in each replay. They differ where
    /// a ray lies in a triangle's plane (a shadow ray between two points of a planar
    /// object: `0/0` in both triangle tests, decided by rounding; such a ray carries zero
    /// weight, its cosines being 0) and where the two tests round differently at edges.
    pub umbra_hits: u64,
    pub obvhs_hits: u64,
    /// The same count by testing every triangle (obvhs's triangle test, no BVH): the
    /// reference for the two above, on scenes of at most [`BRUTE_FORCE_TRIANGLES`].
    pub brute_force_hits: Option<u64>,
}

/// Most samples whose rays are logged (a path casts up to ~8 rays of 28 bytes).
pub const MAX_LOGGED_SAMPLES: u64 = 1 << 24;

/// Largest scene whose rays are also tested against every triangle.
pub const BRUTE_FORCE_TRIANGLES: usize = 2048;

impl RayFigures {
    pub fn rays(&self) -> u64 {
        self.closest_rays + self.shadow_rays
    }
    pub fn samples_per_second(&self) -> f64 {
        self.samples as f64 / self.render_seconds
    }
    pub fn rays_per_sample(&self) -> f64 {
        self.rays() as f64 / self.samples as f64
    }
    /// The render's rays/s: samples/s x rays per sample.
    pub fn effective_rays_per_second(&self) -> f64 {
        self.samples_per_second() * self.rays_per_sample()
    }
    pub fn umbra_rays_per_second(&self) -> f64 {
        self.rays() as f64 / self.umbra_replay_seconds
    }
    pub fn obvhs_rays_per_second(&self) -> f64 {
        self.rays() as f64 / self.obvhs_replay_seconds
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn timed<T>(f: impl FnOnce() -> T) -> (T, Duration) {
    let t = Instant::now();
    let out = f();
    (out, t.elapsed())
}

/// Runs the three steps (module doc) on the current rayon pool.
pub fn rays(scene: &Scene, opts: &RenderOptions, reps: usize) -> Result<RayFigures> {
    if !matches!(opts.model, Model::Path | Model::Mc3) {
        return Err(crate::Error::Invalid(format!(
            "bench rays: model {:?} has no samples; use path or mc3 (render.model or -D)",
            opts.model
        )));
    }
    let samples = scene.num_measurements() as u64 * u64::from(opts.spp);
    if samples > MAX_LOGGED_SAMPLES {
        return Err(crate::Error::Invalid(format!(
            "bench rays: {samples} samples would log ~{} GB of rays; lower spp or the scan to at most {MAX_LOGGED_SAMPLES} samples",
            samples * 8 * std::mem::size_of::<LoggedRay>() as u64 / 1_000_000_000
        )));
    }
    let geom = SceneGeometry::build(scene);
    let renderer = Renderer::new(scene, &geom, opts)?;
    let mut render_s = Vec::new();
    for _ in 0..reps.max(1) {
        let (r, d) = timed(|| renderer.render(None));
        r?;
        render_s.push(d.as_secs_f64());
    }
    let (r, log) = ray_log::record(|| renderer.render(None))?;
    r?;
    let shadow = log.iter().filter(|r| r.shadow).count() as u64;
    let tris = geom.all_triangles();
    let mut build = Duration::ZERO;
    let bvh = build_cwbvh_from_tris(&tris, BvhBuildParams::medium_build(), &mut build);
    let tris: Vec<_> = bvh
        .primitive_indices
        .iter()
        .map(|&i| tris[i as usize])
        .collect();
    let bare = |r: &LoggedRay| {
        let ray = Ray::new(r.origin.into(), r.dir.into(), geom.eps, r.t_max);
        if r.shadow {
            !bvh.ray_traverse_miss(ray, |r, id| tris[id].intersect(r))
        } else {
            let mut hit = RayHit::none();
            bvh.ray_traverse(ray, &mut hit, |r, id| tris[id].intersect(r))
        }
    };
    // The two replays alternate, so that neither gets the warmer machine.
    let (mut umbra_s, mut obvhs_s) = (Vec::new(), Vec::new());
    let (mut umbra_hits, mut obvhs_hits) = (0, 0);
    for _ in 0..reps.max(1) {
        let (h, d) = timed(|| replay_umbra(&geom, &log));
        umbra_hits = h;
        umbra_s.push(d.as_secs_f64());
        let (h, d) = timed(|| chunks(&log, bare));
        obvhs_hits = h;
        obvhs_s.push(d.as_secs_f64());
    }
    let brute_force_hits = (tris.len() <= BRUTE_FORCE_TRIANGLES).then(|| {
        chunks(&log, |r| {
            let ray = Ray::new(r.origin.into(), r.dir.into(), geom.eps, r.t_max);
            tris.iter().any(|t| t.intersect(&ray) < f32::INFINITY)
        })
    });
    Ok(RayFigures {
        samples,
        closest_rays: log.len() as u64 - shadow,
        shadow_rays: shadow,
        render_seconds: median(render_s),
        umbra_replay_seconds: median(umbra_s),
        obvhs_replay_seconds: median(obvhs_s),
        umbra_hits,
        obvhs_hits,
        brute_force_hits,
    })
}

/// The logged rays through [`SceneGeometry`]'s own queries; returns the hit count.
fn replay_umbra(geom: &SceneGeometry, log: &[LoggedRay]) -> u64 {
    chunks(log, |r| {
        if r.shadow {
            // `occluded` shortens the segment by eps at both ends again.
            let b = r.origin + r.dir * (r.t_max + geom.eps);
            geom.occluded(r.origin, b)
        } else {
            geom.intersect(r.origin, r.dir).is_some()
        }
    })
}

/// `query` over the rays in parallel chunks; the number of `true`s.
fn chunks(log: &[LoggedRay], query: impl Fn(&LoggedRay) -> bool + Sync) -> u64 {
    log.par_chunks(4096)
        .map(|c| c.iter().filter(|r| query(r)).count() as u64)
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On the default scene (the extruded letter: no ray lies in a face's plane) the
    /// path tracer's rays are logged, and Umbra's ray functions, the bare BVH and the
    /// test of every triangle agree on which rays hit (to rounding at edges: 1 in 20463
    /// seen at 64 spp).
    #[test]
    fn logged_rays_replay_to_the_same_hits() {
        let scene = crate::scene::default::default_scene().unwrap();
        let opts = RenderOptions {
            spp: 4,
            ..RenderOptions::from_scene(&scene)
        };
        let f = rays(&scene, &opts, 1).unwrap();
        assert!(f.closest_rays > 0 && f.shadow_rays > 0, "{f:?}");
        // About 0.6 per sample at 4 spp: the visible legs' two shadow rays per
        // measurement (0.5) and the first steps' rays; continuations from the letter meet
        // only the wall, analytically (`SceneGeometry::intersect_wall`, not logged).
        assert!(
            f.rays_per_sample() > 0.25 && f.rays_per_sample() < 10.0,
            "{f:?}"
        );
        let brute = f.brute_force_hits.unwrap();
        assert!(brute > 0, "{f:?}");
        let tolerance = 1 + f.rays() / 10_000;
        for hits in [f.umbra_hits, f.obvhs_hits] {
            assert!(hits.abs_diff(brute) <= tolerance, "{f:?}");
        }
    }
}
