//! A log of the rays [`SceneGeometry`](super::SceneGeometry) traces, for the ray-throughput
//! benchmark (`umbra bench rays`): a render run inside [`record`] leaves every closest-hit
//! and shadow ray it cast, which the benchmark then replays alone, through Umbra's ray
//! functions and through a bare obvhs BVH, to show how far the renderer's rays/s is from
//! the machine's.
//!
//! Compiled in with the `ray-log` feature only: as a relaxed atomic load and a not-taken
//! branch per ray, always present, it made `path` on the T letter 15 % slower (4.4 against
//! 5.4 M samples/s, 2 threads, old and new binary alternated). Without the feature [`log`]
//! is empty and [`record`] logs nothing. On, each ray takes a lock: recording is for a
//! benchmark's one-thread pass only.

use glam::Vec3;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

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

static RECORDING: AtomicBool = AtomicBool::new(false);
static LOG: Mutex<Vec<LoggedRay>> = Mutex::new(Vec::new());
/// Serialises [`record`] calls (one log for the process).
static SESSION: Mutex<()> = Mutex::new(());

/// Whether this build can log rays (the `ray-log` feature).
pub const ENABLED: bool = cfg!(feature = "ray-log");

/// Logs a ray if a [`record`] is running (a no-op without the `ray-log` feature).
#[inline(always)]
pub(crate) fn log(origin: Vec3, dir: Vec3, t_max: f32, shadow: bool) {
    if ENABLED && RECORDING.load(Ordering::Relaxed) {
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
    LOG.lock().unwrap_or_else(|e| e.into_inner()).push(ray);
}

/// Runs `f` with logging on; returns its result and the rays traced meanwhile by every
/// thread (in the order they were traced when `f` runs on one thread).
pub fn record<T>(f: impl FnOnce() -> T) -> (T, Vec<LoggedRay>) {
    let _session = SESSION.lock().unwrap_or_else(|e| e.into_inner());
    LOG.lock().unwrap_or_else(|e| e.into_inner()).clear();
    RECORDING.store(true, Ordering::SeqCst);
    let out = f();
    RECORDING.store(false, Ordering::SeqCst);
    let rays = std::mem::take(&mut *LOG.lock().unwrap_or_else(|e| e.into_inner()));
    (out, rays)
}

#[cfg(all(test, feature = "ray-log"))]
mod tests {
    use super::*;

    #[test]
    fn records_only_inside_record() {
        // Other tests may trace rays while this one records: the rays here are told
        // apart by their (impossible) t_max.
        let mine = |rays: &[LoggedRay]| -> Vec<f32> {
            rays.iter().map(|r| r.t_max).filter(|t| *t < 0.0).collect()
        };
        log(Vec3::ZERO, Vec3::X, -1.0, true);
        let ((), rays) = record(|| {
            log(Vec3::ZERO, Vec3::Y, -2.0, false);
            log(Vec3::ONE, Vec3::Z, -3.0, true);
        });
        log(Vec3::ZERO, Vec3::X, -1.0, true);
        assert_eq!(mine(&rays), [-2.0, -3.0]);
        let ((), none) = record(|| ());
        assert!(mine(&none).is_empty());
    }
}
