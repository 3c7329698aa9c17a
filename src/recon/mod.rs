//! Classic reconstruction from a measurement: filtered backprojection (FBP), the depth
//! map of its volume, and a wall-facing height-field mesh from that depth map.
//!
//! Backprojection (Velten et al. 2012; Arellano, Gutierrez, Jarabo 2017) gives every
//! voxel `v` the sum, over the measurements `m` with wall points `x_l`, `x_s`, of the
//! transient at the OPL a three-bounce path through `v` would have:
//!
//! `V(v) = Σ_m w_m(v) H_m(τ_m(v))`,  `τ_m(v) = |x_l − v| + |v − x_s| (+ legs_m)`,
//!
//! with `H_m(τ)` interpolated linearly between bin centres and `w_m(v)` either 1 or the
//! falloff compensation `|x_l − v|² |v − x_s|²` ([`Falloff`]). The "filtered" step is the
//! discrete Laplacian along depth, `F(v) = −∂²V/∂z²` ([`Filter`]). [`depth_map`] takes
//! the brightest voxel of each column; [`depth_map_mesh`] triangulates those depths.
//!
//! Coordinates: the grid lives in the *wall frame*, origin at the wall's centre, `x`
//! along `axis_u`, `y` along `axis_v`, `z` along the wall's normal (the height above the
//! wall). With y-tal's convention (wall centred at the origin, normal `+z`, up `+y`) the
//! wall frame is world space.
//!
//! Choices, from measurements (`tests/recon.rs`):
//!
//! - the default weight is 1: on the LCT capture `diffuse_s`, the falloff compensation
//!   lets the late-time noise (weighted by `r⁴`) outshine the letter; on noiseless
//!   renders it helps a little (dim patch edges come up);
//! - rendered histograms are sharper than any detector's: a sparse scan (16 x 16 at
//!   5 cm) of them leaves shells that the depth Laplacian sharpens to half the surface's
//!   brightness. A Gaussian of one bin along time
//!   ([`BackprojectOptions::time_sigma_opl`]) halves them;
//! - LCT data: zero the residual direct light ([`zero_bins_before`], bin 600 as the
//!   original code) and sum bins ([`downsample_time`], 8 → 9.6 mm of OPL) first: in the
//!   raw 1.2 mm bins photon noise swamps the Laplacian. The step at the zeroed bins
//!   leaves a faint sheet at ≈ 0.36 m.
//!
//! ```no_run
//! # use umbra::recon::*;
//! # fn main() -> umbra::Result<()> {
//! let c = umbra::io::lct::read_lct(std::path::Path::new("data_diffuse_s.mat"))?;
//! let mut scene = lct_scene(&c)?;
//! let mut data = c.transient.data;
//! zero_bins_before(&mut data, scene.film.temporal_bins as usize, 600);
//! let (film, data) = downsample_time(&scene.film, &data, 8)?;
//! scene.film = film;
//! let grid = VoxelGrid::over_scan(&scene, 0.2, 1.0, [64, 64, 128])?;
//! let volume = backproject(&scene, &data, &grid, Filter::DepthLaplacian)?;
//! let depth = depth_map(&volume, 0.3)?;
//! let mesh = depth_map_mesh(&depth, &grid, &WallFrame::of(&scene), &MeshOptions::default())?;
//! write_volume_png(std::path::Path::new("fbp.png"), &volume)?;
//! # let _ = mesh;
//! # Ok(())
//! # }
//! ```

mod backprojection;
mod depth;
mod image;
mod lct;
mod method;
mod phasor;
mod surfaces;

pub use backprojection::{
    backproject, backproject_with, downsample_time, subtract_floor, zero_bins_before,
};
pub use depth::{depth_map, depth_map_mesh, first_surface, surface_depth_map, DepthMap};
pub use image::{write_comparison_png, write_depth_png, write_volume_png};
pub use lct::{lct, LctOptions};
pub use method::{reconstruct, volume_surface, Method};
pub use phasor::{phasor_field, PhasorOptions};
pub use surfaces::{peak_map, peak_mesh, MeshOptions, Peak, PeakMap};

use crate::error::{Error, Result};
use crate::io::lct::LctCapture;
use crate::scene::{toml_format, Scene};
use glam::Vec3;
use std::path::Path;

/// The wall's orthonormal frame: origin at its centre, `e_u`, `e_v` in its plane,
/// `n` its normal (the side the hidden scene is on).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WallFrame {
    pub origin: Vec3,
    pub e_u: Vec3,
    pub e_v: Vec3,
    pub n: Vec3,
}

impl WallFrame {
    pub fn of(scene: &Scene) -> Self {
        let n = scene.wall.normal();
        let e_u = scene.wall.axis_u.normalize();
        // Re-orthogonalise in case the wall's axes are not exactly perpendicular.
        let e_v = n.cross(e_u).normalize();
        WallFrame {
            origin: scene.wall.center,
            e_u,
            e_v,
            n,
        }
    }
    /// World point → wall-frame coordinates.
    pub fn to_frame(&self, p: Vec3) -> Vec3 {
        let d = p - self.origin;
        Vec3::new(d.dot(self.e_u), d.dot(self.e_v), d.dot(self.n))
    }
    /// Wall-frame coordinates → world point.
    pub fn to_world(&self, q: Vec3) -> Vec3 {
        self.origin + q.x * self.e_u + q.y * self.e_v + q.z * self.n
    }
}

/// A box of voxels in the wall frame; voxel `(ix, iy, iz)` has its centre at
/// `min + (i + ½) (max − min) / dims` on each axis (cell-centred, like the scan grid).
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelGrid {
    pub min: Vec3,
    pub max: Vec3,
    /// Voxels along x, y, z (depth).
    pub dims: [usize; 3],
}

impl VoxelGrid {
    /// A checked grid: finite corners, `max > min` on every axis, at least one voxel per
    /// axis and at most 2²⁸ in all (1 GiB of `f32`).
    pub fn new(min: Vec3, max: Vec3, dims: [usize; 3]) -> Result<Self> {
        if !(min.is_finite() && max.is_finite() && max.cmpgt(min).all()) {
            return Err(Error::Invalid(format!(
                "voxel grid: corners must be finite with max > min on every axis, got min {min}, max {max}"
            )));
        }
        let n = dims
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .unwrap_or(usize::MAX);
        if dims.contains(&0) || n > 1 << 28 {
            return Err(Error::Invalid(format!(
                "voxel grid: dims must be >= 1 with at most 2^28 voxels, got {dims:?}"
            )));
        }
        Ok(VoxelGrid { min, max, dims })
    }

    /// A box over the scan rectangle with depths `[z_min, z_max]` (m from the wall).
    pub fn over_scan(scene: &Scene, z_min: f32, z_max: f32, dims: [usize; 3]) -> Result<Self> {
        let f = WallFrame::of(scene);
        let c = f.to_frame(scene.scan.center);
        let h = Vec3::new(
            0.5 * scene.scan.axis_u.length(),
            0.5 * scene.scan.axis_v.length(),
            0.0,
        );
        let (lo, hi) = (c - h, c + h);
        Self::new(
            Vec3::new(lo.x, lo.y, z_min),
            Vec3::new(hi.x, hi.y, z_max),
            dims,
        )
    }

    /// The default grid: over the scan rectangle, with the depths the film's time range
    /// can see: half the hidden path length (OPL minus the first and last legs, if the
    /// scene counts them) at the film's start and end, the start clamped at 1 mm.
    pub fn for_scene(scene: &Scene, dims: [usize; 3]) -> Result<Self> {
        let film = &scene.film;
        let (mut legs_min, mut legs_max) = (0.0f32, 0.0f32);
        if scene.account_first_and_last_bounces {
            (legs_min, legs_max) = (f32::MAX, f32::MIN);
            for m in 0..scene.num_measurements() {
                let l = legs(scene, m);
                legs_min = legs_min.min(l);
                legs_max = legs_max.max(l);
            }
        }
        let end = film.start_opl + film.temporal_bins as f32 * film.bin_width_opl;
        let z_min = (0.5 * (film.start_opl - legs_max)).max(1e-3);
        let z_max = 0.5 * (end - legs_min);
        if z_max <= z_min {
            return Err(Error::Invalid(format!(
                "the film's time range ({} to {end} m of OPL) sees no hidden depth",
                film.start_opl
            )));
        }
        Self::over_scan(scene, z_min, z_max, dims)
    }

    pub fn len(&self) -> usize {
        self.dims.iter().product()
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Voxel size on each axis (m).
    pub fn voxel_size(&self) -> Vec3 {
        let d = Vec3::new(
            self.dims[0] as f32,
            self.dims[1] as f32,
            self.dims[2] as f32,
        );
        (self.max - self.min) / d
    }
    /// Centre of voxel `(ix, iy, iz)` in the wall frame.
    pub fn center(&self, ix: usize, iy: usize, iz: usize) -> Vec3 {
        let i = Vec3::new(ix as f32, iy as f32, iz as f32) + 0.5;
        self.min + i * self.voxel_size()
    }
    /// Index of voxel `(ix, iy, iz)` in [`Volume::data`].
    pub fn index(&self, ix: usize, iy: usize, iz: usize) -> usize {
        (iy * self.dims[0] + ix) * self.dims[2] + iz
    }
}

/// First and last legs of measurement `m` (laser → `x_l`, `x_s` → detector), m.
pub(crate) fn legs(scene: &Scene, m: usize) -> f32 {
    let (x_l, x_s) = scene.measurement_points(m);
    (scene.laser.origin - x_l).length() + (x_s - scene.detector.origin).length()
}

/// A reconstructed volume: one value per voxel, layout `(y, x, z)` row-major (depth
/// fastest, so a column along depth is contiguous).
#[derive(Clone, Debug)]
pub struct Volume {
    pub grid: VoxelGrid,
    pub data: Vec<f32>,
}

impl Volume {
    /// The depth column of `(ix, iy)`.
    pub fn column(&self, ix: usize, iy: usize) -> &[f32] {
        let nz = self.grid.dims[2];
        let i = self.grid.index(ix, iy, 0);
        &self.data[i..i + nz]
    }

    /// The volume on columns `factor` x `factor` times as wide, each the mean of the
    /// columns it covers (columns left over at the high `x` or `y` edge are dropped, the
    /// grid shrunk to match): a coarser lateral sampling of the same depths.
    pub fn pooled(&self, factor: usize) -> Volume {
        let f = factor.max(1);
        let [nx, ny, nz] = self.grid.dims;
        let (cx, cy) = ((nx / f).max(1), (ny / f).max(1));
        let size = self.grid.voxel_size();
        let (fx, fy) = (f.min(nx), f.min(ny));
        let grid = VoxelGrid {
            min: self.grid.min,
            max: Vec3::new(
                self.grid.min.x + (cx * fx) as f32 * size.x,
                self.grid.min.y + (cy * fy) as f32 * size.y,
                self.grid.max.z,
            ),
            dims: [cx, cy, nz],
        };
        let mut data = vec![0.0f32; grid.len()];
        let w = 1.0 / (fx * fy) as f32;
        for iy in 0..cy * fy {
            for ix in 0..cx * fx {
                let out = grid.index(ix / fx, iy / fy, 0);
                for (o, v) in data[out..out + nz].iter_mut().zip(self.column(ix, iy)) {
                    *o += w * v;
                }
            }
        }
        Volume { grid, data }
    }
}

/// The "filtered" of FBP.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Filter {
    /// Plain backprojection.
    None,
    /// `F[z] = −(V[z−1] − 2 V[z] + V[z+1])` along depth, the edge voxels repeated past
    /// the ends: the negated second derivative, so a surface stays a positive peak.
    #[default]
    DepthLaplacian,
}

/// Weight of a measurement's sample in a voxel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Falloff {
    /// Unweighted sum, as in the classic backprojection (the default: it does not
    /// amplify the noise of late bins).
    #[default]
    None,
    /// Multiply by `|x_l − v|² |v − x_s|²`, undoing the `1/(r_l² r_s²)` falloff of a
    /// Lambertian point, so far voxels are not dimmed (cf. the `τ⁴` scaling of LCT).
    Compensate,
}

/// Backprojection settings.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct BackprojectOptions {
    pub filter: Filter,
    pub falloff: Falloff,
    /// Standard deviation (m of OPL) of a Gaussian blur of each histogram along time
    /// before backprojection; 0 = none. With [`Filter::DepthLaplacian`] this makes the
    /// filter a Laplacian of Gaussian: it tames the shells a sparse scan of sharp
    /// (noiseless, jitter-free) histograms leaves in the volume. About one bin suits
    /// rendered data; measured data already carry the detector's jitter.
    pub time_sigma_opl: f32,
}

/// A confocal scene with no hidden objects for data that come without a scene file: an
/// `nx x ny` scan at pixel centres over `[-half_width, half_width]²` on the wall `z = 0`
/// (normal `+z`, up `+y`), a film of `bins` bins of `bin_width_opl` from OPL 0, legs not
/// counted. `+y` of the scan is data row `sy = ny − 1`.
pub fn confocal_scene(
    half_width: f32,
    nx: usize,
    ny: usize,
    bins: usize,
    bin_width_opl: f32,
) -> Result<Scene> {
    let ok = |v: f32| v.is_finite() && v > 0.0;
    if !(ok(half_width) && ok(bin_width_opl)) || nx == 0 || ny == 0 || bins == 0 {
        return Err(Error::Invalid(format!(
            "confocal scene: need positive sizes, got half width {half_width}, scan {nx} x {ny}, {bins} bins of {bin_width_opl}"
        )));
    }
    let (nx, ny) = (
        u32::try_from(nx).map_err(|_| Error::Invalid("scan too large".into()))?,
        u32::try_from(ny).map_err(|_| Error::Invalid("scan too large".into()))?,
    );
    let side = 2.0 * half_width;
    let toml = format!(
        r#"
capture_type = "confocal"
[wall]
size = [{side:?}, {side:?}]
[laser]
origin = [0.0, 0.0, 1.0]
[scan]
resolution = [{nx}, {ny}]
[film]
temporal_bins = {bins}
bin_width_opl = {bin_width_opl:?}
"#
    );
    toml_format::parse(&toml, Path::new("<confocal scene>"), &|f| {
        Err(Error::scene(
            Path::new(f),
            "no meshes in a reconstruction scene",
        ))
    })
}

/// The scene of a Stanford LCT capture ([`confocal_scene`] with its width, scan and bins).
/// The capture's grid is `linspace(-width, width, N)` in the original code; pixel centres
/// differ from it by a factor `(N − 1)/N` in scale (1.6 % for N = 64), which we neglect.
pub fn lct_scene(c: &LctCapture) -> Result<Scene> {
    let &[ny, nx, bins] = c.transient.shape.as_slice() else {
        return Err(Error::Invalid(format!(
            "LCT capture has shape {:?}, expected (y, x, t)",
            c.transient.shape
        )));
    };
    // The scan grid follows the LCT code's orientation (io::measured::lct_scan_grid):
    // rect_data's first index runs along x, its second down y.
    let mut scene = confocal_scene(c.width, nx, ny, bins, c.bin_width_opl)?;
    scene.scan = crate::io::measured::lct_scan_grid(c.width, nx, ny);
    Ok(scene)
}
