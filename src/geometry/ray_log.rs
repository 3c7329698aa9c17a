//! A log of the rays [`SceneGeometry`](super::SceneGeometry) traces, for the ray-throughput
//! benchmark (`umbra bench rays`): a render run inside [`record`] leaves every closest-hit
//! and shadow ray it cast, which the benchmark then replays alone, through Umbra's ray
//! functions and through a bare obvhs BVH, to show how far the renderer's rays/s is from
//! the machine's.
//!
//! Off, logging costs one thread-local test per ray: `path` on T.xml (mb, 4096 spp, 2
//! threads) ran 7.1-7.7 M samples/s without the hook and 7.6-8.0 with it, alternated on a
//! quiet machine, i.e. nothing measurable. (A first comparison, on a machine shared with a
//! test run, had suggested 15 % and put the hook behind a cargo feature; it was noise.)
//! On, only the one thread of a [`record`] pool logs, into its own buffer.

use glam::Vec3;
use std::cell::{Cell, RefCell};

/// One traced ray: `origin + t dir`, `t` in `[eps, t_max]` (`dir` unit; `t_max` infinite
/// for a closest-hit ray, the shortened segment's length for a shadow ray).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoggedRay {
    pub origin: Vec3,
    pub dir: Vec3,
    pub t_max: f32,
    /// An occlusion (any-hit) query rather than a closest hit.
    pub shadow: bool,
}

thread_local! {
    /// Set on the worker thread of a [`record`] pool only: rays other threads trace
    /// meanwhile (other tests, other renders) are not logged.
    static RECORDING: Cell<bool> = const { Cell::new(false) };
    static LOG: RefCell<Vec<LoggedRay>> = const { RefCell::new(Vec::new()) };
}

/// Logs a ray if this thread is a [`record`] pool's.
#[inline(always)]
pub(crate) fn log(origin: Vec3, dir: Vec3, t_max: f32, shadow: bool) {
    if RECORDING.with(Cell::get) {
        push(LoggedRay {
            origin,
            dir,
            t_max,
            shadow,
        });
    }
}

#[cold]
#[inline(never)]
fn push(ray: LoggedRay) {
    LOG.with(|l| l.borrow_mut().push(ray));
}

/// Runs `f` in a rayon pool of one thread that logs its rays; returns `f`'s result and
/// the rays, in the order traced.
pub fn record<T: Send>(f: impl FnOnce() -> T + Send) -> crate::Result<(T, Vec<LoggedRay>)> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .start_handler(|_| RECORDING.with(|r| r.set(true)))
        .build()
        .map_err(|e| crate::Error::Invalid(format!("ray log: thread pool: {e}")))?;
    let out = pool.install(f);
    let rays = pool.install(|| LOG.with(|l| std::mem::take(&mut *l.borrow_mut())));
    Ok((out, rays))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_only_inside_record() {
        let t_max = |rays: &[LoggedRay]| -> Vec<f32> { rays.iter().map(|r| r.t_max).collect() };
        log(Vec3::ZERO, Vec3::X, -1.0, true);
        let ((), rays) = record(|| {
            log(Vec3::ZERO, Vec3::Y, -2.0, false);
            log(Vec3::ONE, Vec3::Z, -3.0, true);
        })
        .unwrap();
        log(Vec3::ZERO, Vec3::X, -1.0, true);
        assert_eq!(t_max(&rays), [-2.0, -3.0]);
        assert!(!rays[0].shadow && rays[1].shadow);
        let ((), none) = record(|| ()).unwrap();
        assert!(none.is_empty());
    }
}
