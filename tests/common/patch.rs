//! The reconstruction tests' patch: a 20 cm square at 0.5 m, tilted or not, and the
//! check of a depth map against it (tests/recon.rs, tests/recon_wave.rs).

use super::scene;
use umbra::recon::{DepthMap, VoxelGrid};
use umbra::scene::Scene;

/// Film bin width (m of OPL); one bin is `BIN / 2` of depth in front of a scan point.
pub const BIN: f32 = 0.01;
/// Depth error allowed: 1.5 bins.
pub const DEPTH_TOL: f32 = 1.5 * BIN / 2.0;
pub const HALF: f32 = 0.1;
pub const DEPTH: f32 = 0.5;

/// A 20 cm square centred 0.5 m in front of the wall, tilted about y by `tilt_deg`
/// (depth `0.5 + tan · x`), facing the wall, scanned `n x n` over 0.8 m.
pub fn patch_scene(capture: &str, tilt_deg: f32, n: u32) -> Scene {
    let s = tilt_deg.to_radians().tan();
    let v = |x: f32, y: f32| format!("v {x} {y} {}\n", DEPTH + s * x);
    let obj = [
        v(-HALF, -HALF),
        v(HALF, -HALF),
        v(HALF, HALF),
        v(-HALF, HALF),
    ]
    .concat()
        + "f 1 4 3 2\n";
    let toml = format!(
        r#"
capture_type = "{capture}"
[wall]
size = [2.0, 2.0]
[laser]
origin = [0.3, -0.4, 1.0]
target = [0.2, -0.1, 0.0]
[scan]
resolution = [{n}, {n}]
size = [0.8, 0.8]
[film]
temporal_bins = 128
bin_width_opl = {BIN}
start_opl = 0.8
[[objects]]
file = "p.obj"
[render]
visibility = "none"
"#
    );
    scene(&toml, &[("p.obj", &obj)])
}

/// Checks a patch's depth map: columns at least 2.5 cm inside the patch are filled at
/// the right depth (every filled column over the patch is), columns more than 5 cm
/// outside are empty; returns the least-squares slope `dz/dx` over the patch.
pub fn check_patch(name: &str, g: &VoxelGrid, d: &DepthMap, tan: f32) -> f32 {
    let (mut sx, mut sz, mut sxx, mut sxz, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let mut worst = 0.0f32;
    for iy in 0..d.ny {
        for ix in 0..d.nx {
            let c = g.center(ix, iy, 0);
            let out = c.x.abs().max(c.y.abs()) - HALF;
            let z = d.at(ix, iy);
            if out < -0.025 {
                assert!(z.is_finite(), "{name}: column ({ix}, {iy}) inside is empty");
            }
            if out < 0.0 && z.is_finite() {
                worst = worst.max((z - DEPTH - tan * c.x).abs());
                (sx, sz, sxx, sxz, n) = (sx + c.x, sz + z, sxx + c.x * c.x, sxz + c.x * z, n + 1.0);
            }
            if out > 0.05 {
                assert!(
                    z.is_nan(),
                    "{name}: column ({ix}, {iy}) outside at depth {z}"
                );
            }
        }
    }
    eprintln!(
        "{name}: {} columns filled, worst depth error {:.1} mm",
        d.filled(),
        worst * 1e3
    );
    assert!(worst <= DEPTH_TOL, "{name}: depth off by {worst} m");
    (n * sxz - sx * sz) / (n * sxx - sx * sx)
}
