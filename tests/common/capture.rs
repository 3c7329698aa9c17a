//! Small captures with known values, for the file writers' round trips.

use glam::Vec3;
use umbra::scene::{default::default_scene, CaptureType, ScanGrid, Scene};
use umbra::transport::Transient;

/// A small non-square scene (3 x 2 scan, 7 bins) of each capture type, and a transient whose
/// every value differs.
pub fn small_capture(capture: CaptureType) -> (Scene, Transient) {
    let mut s = default_scene().unwrap();
    s.capture = capture;
    s.scan = ScanGrid {
        nx: 3,
        ny: 2,
        center: Vec3::new(0.1, -0.2, 0.0),
        axis_u: Vec3::new(0.9, 0.0, 0.0),
        axis_v: Vec3::new(0.0, 0.4, 0.0),
    };
    s.laser.target = Vec3::new(0.25, 0.3, 0.0);
    s.film.temporal_bins = 7;
    s.film.bin_width_opl = 0.003;
    s.film.start_opl = 0.85;
    s.account_first_and_last_bounces = capture == CaptureType::Confocal;
    let shape = s.output_shape();
    let n: usize = shape.iter().product();
    let data = (0..n)
        .map(|i| 0.5 + i as f32 * 1.0e-3 + (i as f32).sin())
        .collect();
    (s, Transient { data, shape })
}
