//! The fitted surface as the classical reconstructions (LCT, f-k) show theirs: an albedo
//! image and a depth image seen from the relay wall, one pixel per scan point.
//!
//! **What is computed.** For each scan point of the scene as fitted (`scene.scan`, `nx x
//! ny`, after any `--bin`; the sensor points of single and exhaustive captures), the ray
//! from that wall point along the wall's normal into the hidden scene, and the first
//! face of the fitted mesh it meets, either side ([`crate::recon::first_surface`], the
//! ray `recon::surface_depth_map` casts from a column's centre):
//!
//! - **depth**: the hit's distance from the wall along the normal (m);
//! - **albedo**: the fitted per-vertex albedo (the mesh's `vertex_values`) interpolated
//!   barycentrically at the hit; the fit's scalar albedo (`FitConfig::albedo`) where
//!   the mesh carries none (no stage fitted albedo). With a fitted intensity scale the
//!   albedo is relative: the scale absorbs its overall level.
//!
//! Both are NaN where the ray meets no face. The mesh is the whole fitted mesh
//! (`mesh_all.obj`): dark faces too, since albedo is what cuts a letter out of a plane.
//!
//! **Layout of `albedo.npy` and `depth.npy`.** float32, C order, shape `(ny, nx)`,
//! element `[iy, ix]` for scan point `iy · nx + ix`: the order of the measurement's
//! scan axes `(sy, sx)` (`ScanGrid::point`, `Scene::output_shape`), so `albedo[iy, ix]`
//! is the surface in front of `measured.reshape(ny, nx, T)[iy, ix]`. The arrays are in
//! scan order, not turned to any view: for Umbra's scenes (scan `axis_u` along `+x`,
//! `axis_v` along `+y`) the view from the wall is `albedo[::-1, ::-1]`; for a Stanford
//! LCT `.mat` (`axis_u` along `−y`, `axis_v` along `+x`, `io::measured`) it is
//! `albedo.T[:, ::-1]`, which shows its letters upright and readable.
//!
//! **Seen from the wall** (`albedo.png`, `reconstruction.png`): looking from the wall
//! into the hidden scene, `+y` (the wall frame's `e_v`) up and `+x` (`e_u`) to the left,
//! so a letter that faces the wall reads correctly; [`WallView`] maps the scan onto that
//! view, each scan axis along the wall axis it is closest to (a scan turned by other than
//! a quarter turn is shown turned to the nearest quarter turn).

use super::objective::hidden_object;
use crate::error::{Error, Result};
use crate::geometry::SceneGeometry;
use crate::io::plot::{labelled_maps, MapAxes, MapPanel};
use crate::recon::{first_surface, VoxelGrid, WallFrame};
use crate::scene::Scene;
use optim::checkpoint::write_atomic;
use optim::Mesh;
use std::path::{Path, PathBuf};

/// The fitted surface seen from the wall, per scan point (module doc): `[iy · nx + ix]`.
#[derive(Clone, Debug, PartialEq)]
pub struct SeenSurface {
    pub nx: usize,
    pub ny: usize,
    /// Distance from the wall along its normal to the first face (m); NaN: none.
    pub depth: Vec<f32>,
    /// Albedo at that hit; NaN: none.
    pub albedo: Vec<f32>,
}

/// The first face of `mesh` along the wall normal from each scan point of `scene`
/// (module doc); `albedo` stands where `mesh` has no per-vertex albedo. The scene's own
/// hidden objects are not looked at.
pub fn seen_surface(scene: &Scene, mesh: &Mesh, albedo: f32) -> SeenSurface {
    let fitted = Scene {
        objects: vec![hidden_object(mesh, albedo, true, Default::default())],
        ..scene.clone()
    };
    let geometry = SceneGeometry::build(&fitted);
    let frame = WallFrame::of(scene);
    let (nx, ny) = (scene.scan.nx as usize, scene.scan.ny as usize);
    let (mut depth, mut seen_albedo) = (vec![f32::NAN; nx * ny], vec![f32::NAN; nx * ny]);
    for i in 0..nx * ny {
        let q = frame.to_frame(scene.scan.point(i));
        if let Some((d, a)) = first_surface(&geometry, &frame, q.x, q.y) {
            depth[i] = d;
            seen_albedo[i] = a;
        }
    }
    SeenSurface {
        nx,
        ny,
        depth,
        albedo: seen_albedo,
    }
}

/// How the scan appears seen from the wall (module doc): `width x height` pixels, `+x`
/// to the left, `+y` up, over the scan rectangle in the wall frame.
#[derive(Clone, Debug, PartialEq)]
pub struct WallView {
    /// Pixels along the view's x and y (the scan points along the wall's `e_u`, `e_v`).
    pub width: usize,
    pub height: usize,
    /// The scan rectangle in the wall frame (m): `x_min, x_max, y_min, y_max`.
    pub extent: [f32; 4],
    nx: usize,
    ny: usize,
    /// The scan's `u` (`ix`) runs along the wall's x (else along its y).
    u_along_x: bool,
    /// `ix` grows with the wall coordinate it runs along; `iy` likewise.
    u_grows: bool,
    v_grows: bool,
}

impl WallView {
    /// The view of `scene`'s scan grid.
    pub fn of(scene: &Scene) -> WallView {
        let frame = WallFrame::of(scene);
        let s = &scene.scan;
        let along = |a: glam::Vec3| (a.dot(frame.e_u), a.dot(frame.e_v));
        let ((ux, uy), (vx, vy)) = (along(s.axis_u), along(s.axis_v));
        let u_along_x = ux.abs() >= uy.abs();
        let (nx, ny) = (s.nx as usize, s.ny as usize);
        let (lu, lv) = (s.axis_u.length(), s.axis_v.length());
        let (width, height, half_x, half_y, u_grows, v_grows) = if u_along_x {
            (nx, ny, lu / 2.0, lv / 2.0, ux >= 0.0, vy >= 0.0)
        } else {
            (ny, nx, lv / 2.0, lu / 2.0, uy >= 0.0, vx >= 0.0)
        };
        let c = frame.to_frame(s.center);
        WallView {
            width,
            height,
            extent: [c.x - half_x, c.x + half_x, c.y - half_y, c.y + half_y],
            nx,
            ny,
            u_along_x,
            u_grows,
            v_grows,
        }
    }

    /// The view's `(row, column)` (top row, left column first) of scan point `(ix, iy)`.
    pub fn pixel(&self, ix: usize, iy: usize) -> (usize, usize) {
        let ku = if self.u_grows { ix } else { self.nx - 1 - ix };
        let kv = if self.v_grows { iy } else { self.ny - 1 - iy };
        // (index along the wall's x, along its y), from their low ends
        let (kx, ky) = if self.u_along_x { (ku, kv) } else { (kv, ku) };
        (self.height - 1 - ky, self.width - 1 - kx)
    }

    /// Scan-ordered values (`[iy · nx + ix]`) as the view's image, top row first.
    pub fn show(&self, scan: &[f32]) -> Vec<f32> {
        let mut out = vec![f32::NAN; self.width * self.height];
        for iy in 0..self.ny {
            for ix in 0..self.nx {
                let (r, c) = self.pixel(ix, iy);
                out[r * self.width + c] = scan[iy * self.nx + ix];
            }
        }
        out
    }

    /// Voxels over the scan rectangle, `columns` along the wall's x and y, `nz` from
    /// depth `z_min` to `z_max`: with the view's `width x height` columns, one per scan
    /// point, each at its point (what `recon::lct` needs).
    pub fn grid(
        &self,
        columns: [usize; 2],
        z_min: f32,
        z_max: f32,
        nz: usize,
    ) -> Result<VoxelGrid> {
        let [x0, x1, y0, y1] = self.extent;
        VoxelGrid::new(
            glam::Vec3::new(x0, y0, z_min),
            glam::Vec3::new(x1, y1, z_max),
            [columns[0], columns[1], nz],
        )
    }

    /// A volume's columns (`(ix, iy)` along the wall's x and y, as [`WallView::grid`]'s)
    /// as the view's image: the last column of each row first, the top row first.
    pub fn show_columns(nx: usize, ny: usize, f: &dyn Fn(usize, usize) -> f32) -> Vec<f32> {
        (0..ny)
            .rev()
            .flat_map(|iy| (0..nx).rev().map(move |ix| (ix, iy)))
            .map(|(ix, iy)| f(ix, iy))
            .collect()
    }

    /// The axes of a panel of the view: the wall's x from high (left) to low (right),
    /// its y from high (top) to low (bottom).
    pub fn axes(&self) -> MapAxes<'static> {
        let [x0, x1, y0, y1] = self.extent;
        MapAxes {
            x: (x1, x0),
            y: (y1, y0),
            x_label: "x on the wall (m), +x to the left",
            y_label: "y (m)",
        }
    }
}

/// A `(ny, nx)` float32 array as `.npy` bytes (C order).
pub(crate) fn npy(values: &[f32], ny: usize, nx: usize, path: &Path) -> Result<Vec<u8>> {
    let arr = ndarray::ArrayView2::from_shape((ny, nx), values)
        .map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
    let mut bytes = Vec::new();
    ndarray_npy::WriteNpyExt::write_npy(&arr, &mut bytes)
        .map_err(|e| Error::Invalid(format!("{}: writing npy: {e}", path.display())))?;
    Ok(bytes)
}

/// Writes `albedo.npy` and `depth.npy` (module doc) into `out`, atomically; their paths.
pub fn write_seen_npy(out: &Path, seen: &SeenSurface) -> Result<Vec<PathBuf>> {
    [("albedo.npy", &seen.albedo), ("depth.npy", &seen.depth)]
        .into_iter()
        .map(|(name, values)| {
            let path = out.join(name);
            let bytes = npy(values, seen.ny, seen.nx, &path)?;
            write_atomic(&path, &bytes).map_err(|e| Error::io(&path, e))?;
            Ok(path)
        })
        .collect()
}

/// The largest finite value (0 if none).
pub(crate) fn finite_max(values: &[f32]) -> f32 {
    values
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0, f32::max)
}

/// The top of an albedo picture's colour scale: the 98th percentile of the finite values
/// (0 if none), so that a few outlier pixels (bright vertices at a fitted surface's rim)
/// do not darken the rest; values above it saturate.
pub(crate) fn display_max(values: &[f32]) -> f32 {
    let mut v: Vec<f32> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f32::total_cmp);
    v[((v.len() - 1) as f64 * 0.98).round() as usize]
}

/// Writes `albedo.png`: the albedo of [`seen_surface`] seen from the wall, on axes in
/// metres on the wall, with a colour bar from 0 to its 98th percentile ([`display_max`]).
pub fn write_albedo_png(path: &Path, scene: &Scene, seen: &SeenSurface) -> Result<()> {
    let view = WallView::of(scene);
    let image = view.show(&seen.albedo);
    let hi = display_max(&seen.albedo);
    let filled = seen.albedo.iter().filter(|a| a.is_finite()).count();
    labelled_maps(
        path,
        "umbra fit: the fitted albedo seen from the wall",
        &[MapPanel {
            title: &format!(
                "albedo of the first face along the wall\nnormal from each of {} x {} scan points\n({filled} hit one; black: none)",
                seen.nx, seen.ny
            ),
            width: view.width,
            height: view.height,
            values: &image,
            range: (0.0, if hi > 0.0 { hi } else { 1.0 }),
            unit: "fitted albedo (albedo.npy)",
            axes: Some(view.axes()),
        }],
        "Seen from the wall into the hidden scene: +y up, +x to\nthe left (a letter facing the wall reads correctly).\nalbedo.npy: the same values in scan order [iy, ix].",
    )
}

/// Writes `albedo.npy`, `depth.npy` (errors are the fit's) and `albedo.png` (a failure
/// to draw it is a warning) into `out`; the paths written.
pub fn write_seen(out: &Path, scene: &Scene, seen: &SeenSurface) -> Result<Vec<PathBuf>> {
    let mut files = write_seen_npy(out, seen)?;
    let png = out.join("albedo.png");
    match write_albedo_png(&png, scene, seen) {
        Ok(()) => files.push(png),
        Err(e) => eprintln!("umbra fit: warning: {} not written: {e}", png.display()),
    }
    Ok(files)
}
