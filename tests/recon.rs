//! Filtered backprojection (`umbra::recon`) on transients Umbra renders of known planes,
//! and on the real Stanford LCT capture `data_diffuse_s.mat`.

mod common;
use common::*;
use std::path::PathBuf;
use umbra::recon::*;
use umbra::scene::{Model, Scene};

const BIN: f32 = 0.01;

/// A 20 cm square at depth 0.5 m (tilted about y by `tilt_deg`: depth `0.5 + tan · x`),
/// facing the wall, scanned 16 x 16 over 0.8 m.
fn patch_scene(capture: &str, tilt_deg: f32) -> Scene {
    let (h, z0, s) = (0.1f32, 0.5f32, tilt_deg.to_radians().tan());
    let v = |x: f32, y: f32| format!("v {x} {y} {}\n", z0 + s * x);
    let obj = [v(-h, -h), v(h, -h), v(h, h), v(-h, h)].concat() + "f 1 4 3 2\n";
    let toml = format!(
        r#"
capture_type = "{capture}"
[wall]
size = [2.0, 2.0]
[laser]
origin = [0.3, -0.4, 1.0]
target = [0.2, -0.1, 0.0]
[scan]
resolution = [16, 16]
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

fn grid(s: &Scene) -> VoxelGrid {
    VoxelGrid::over_scan(s, 0.3, 0.7, [32, 32, 80]).unwrap()
}

fn reconstruct(s: &Scene, threshold: f32) -> (Volume, DepthMap) {
    let t = render(s, Model::Tri3, 1, 0);
    let v = backproject(s, &t.data, &grid(s), Filter::DepthLaplacian).unwrap();
    let d = depth_map(&v, threshold).unwrap();
    (v, d)
}

fn show(d: &DepthMap) {
    for iy in (0..d.ny).rev() {
        let row: String = (0..d.nx)
            .map(|ix| {
                let z = d.at(ix, iy);
                if z.is_finite() {
                    format!("{:3.0}", z * 100.0)
                } else {
                    "  .".into()
                }
            })
            .collect();
        eprintln!("{row}");
    }
}

fn show_i(d: &DepthMap) {
    let m = d.intensity.iter().cloned().fold(0.0f32, f32::max);
    for iy in (0..d.ny).rev() {
        let row: String = (0..d.nx)
            .map(|ix| {
                let v = d.intensity[iy * d.nx + ix] / m;
                format!("{:2.0}", (v * 10.0).clamp(-1.0, 9.0))
            })
            .collect();
        eprintln!("{row}");
    }
}

#[test]
fn explore_i() {
    for (cap, tilt) in [("confocal", 0.0), ("confocal", 20.0), ("single", 20.0)] {
        let s = patch_scene(cap, tilt);
        let t = render(&s, Model::Tri3, 1, 0);
        for filter in [Filter::None, Filter::DepthLaplacian] {
            for falloff in [Falloff::None, Falloff::Compensate] {
                let v = backproject_with(
                    &s,
                    &t.data,
                    &grid(&s),
                    &BackprojectOptions { filter, falloff, time_sigma_opl: 0.0 },
                )
                .unwrap();
                let d = depth_map(&v, 0.0).unwrap();
                eprintln!("{cap} {tilt} {filter:?} {falloff:?}");
                show_i(&d);
            }
        }
    }
}

#[test]
fn explore_q() {
    for kernel in [0.0f32, 0.01, 0.02] {
        for (cap, tilt) in [
            ("confocal", 0.0),
            ("confocal", 20.0),
            ("single", 0.0),
            ("single", 20.0),
        ] {
            let s = patch_scene(cap, tilt);
            let t = render(&s, Model::Tri3, 1, 0);
            let g = grid(&s);
            let tan = tilt.to_radians().tan();
            for filter in [Filter::None, Filter::DepthLaplacian] {
                for falloff in [Falloff::None, Falloff::Compensate] {
                    let v =
                        backproject_with(&s, &t.data, &g, &BackprojectOptions { filter, falloff, time_sigma_opl: kernel })
                            .unwrap();
                    let d = depth_map(&v, 0.0).unwrap();
                    let m = d.intensity.iter().cloned().fold(0.0f32, f32::max);
                    let (mut min_in, mut max_out, mut err) = (1.0f32, 0.0f32, 0.0f32);
                    let (mut sx, mut sz, mut sxx, mut sxz, mut n) = (0.0, 0.0, 0.0, 0.0, 0.0);
                    for iy in 0..32 {
                        for ix in 0..32 {
                            let c = g.center(ix, iy, 0);
                            let i = d.intensity[iy * 32 + ix] / m;
                            let out = c.x.abs().max(c.y.abs());
                            if out < 0.1 {
                                min_in = min_in.min(i);
                                let z = d.at(ix, iy);
                                err = err.max((z - 0.5 - tan * c.x).abs());
                                sx += c.x;
                                sz += z;
                                sxx += c.x * c.x;
                                sxz += c.x * z;
                                n += 1.0;
                            }
                            if out > 0.15 {
                                max_out = max_out.max(i);
                            }
                        }
                    }
                    let slope = (n * sxz - sx * sz) / (n * sxx - sx * sx);
                    eprintln!("{kernel:?} {cap} {tilt} {filter:?} {falloff:?}: min in {min_in:.2} max out {max_out:.2} depth err {:.1} mm slope {slope:.3} vs {tan:.3}", err*1000.0);
                }
            }
        }
    }
}

#[test]
fn explore_flat() {
    for cap in ["confocal", "single"] {
        let s = patch_scene(cap, 0.0);
        let (_, d) = reconstruct(&s, 0.3);
        eprintln!("{cap}");
        show(&d);
    }
    let s = patch_scene("confocal", 20.0);
    let (_, d) = reconstruct(&s, 0.3);
    show(&d);
}

fn data_dir() -> PathBuf {
    if let Ok(d) = std::env::var("UMBRA_LCT_DIR") {
        return PathBuf::from(d);
    }
    let beside = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data/lct");
    if beside.is_dir() {
        return beside;
    }
    PathBuf::from("/work/shared/data/lct")
}

#[test]
fn explore_lct() {
    use umbra::io::lct::read_lct;
    let t0 = std::time::Instant::now();
    let c = read_lct(&data_dir().join("data_diffuse_s.mat")).unwrap();
    eprintln!("read {:?} width {} shape {:?}", t0.elapsed(), c.width, c.transient.shape);
    let mut s = lct_scene(&c).unwrap();
    let mut data = c.transient.data.clone();
    zero_bins_before(&mut data, 2048, 600);
    let (film, data) = downsample_time(&s.film, &data, 8).unwrap();
    s.film = film;
    for (name, falloff, dims) in [("none", Falloff::None, [32, 32, 64]), ("comp", Falloff::Compensate, [32, 32, 64]), ("comp64", Falloff::Compensate, [64, 64, 128])] {
        let g = VoxelGrid::over_scan(&s, 0.1, 1.1, dims).unwrap();
        let t = std::time::Instant::now();
        let v = backproject_with(&s, &data, &g, &BackprojectOptions { filter: Filter::DepthLaplacian, falloff, time_sigma_opl: 0.0 }).unwrap();
        eprintln!("{name}: backprojection {:?}", t.elapsed());
        write_volume_png(&std::env::temp_dir().join(format!("lct_{name}.png")), &v).unwrap();
        let d = depth_map(&v, 0.3).unwrap();
        write_depth_png(&std::env::temp_dir().join(format!("lct_{name}_depth.png")), &d).unwrap();
        let mut z: Vec<f32> = d.depth.iter().cloned().filter(|z| z.is_finite()).collect();
        z.sort_by(f32::total_cmp);
        eprintln!("{name}: {} filled, depth quantiles {:?}", z.len(), [0.05, 0.25, 0.5, 0.75, 0.95].map(|q| z[((z.len() - 1) as f32 * q) as usize]));
        show(&d);
    }
}

/// Timing of the reference case (confocal 64 x 64 scan, 64³ voxels); run with
/// `cargo test --release --test recon -- --ignored --nocapture`.
#[test]
#[ignore]
fn timing_confocal_64_scan_64_cubed() {
    for bins in [256usize, 2048] {
        let s = confocal_scene(0.35, 64, 64, bins, 2.4 / bins as f32).unwrap();
        let data: Vec<f32> = (0..64 * 64 * bins)
            .map(|i| ((i as u64).wrapping_mul(2654435761) % 1000) as f32)
            .collect();
        let g = VoxelGrid::over_scan(&s, 0.2, 1.0, [64, 64, 64]).unwrap();
        for filter in [Filter::None, Filter::DepthLaplacian] {
            let t = std::time::Instant::now();
            let v = backproject(&s, &data, &g, filter).unwrap();
            let secs = t.elapsed().as_secs_f64();
            eprintln!(
                "{bins} bins, {filter:?}: {secs:.2} s ({:.0} M voxel-measurement pairs/s), sum {}",
                (g.len() * 4096) as f64 / secs / 1e6,
                v.data.iter().map(|&x| x as f64).sum::<f64>()
            );
        }
    }
}
