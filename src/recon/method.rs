//! One entry for every classical reconstruction (`umbra recon`, the baselines study):
//! the method by name, its volume, and the surface made of it the usual way, per-column
//! argmax depth where the column's peak is above a share of the volume's maximum
//! (`depth_map`), triangulated as a wall-facing height field (`depth_map_mesh`).

use super::{
    backproject_with, depth_map, depth_map_mesh, lct, phasor_field, BackprojectOptions, DepthMap,
    Filter, LctOptions, MeshOptions, PhasorOptions, Volume, VoxelGrid, WallFrame,
};
use crate::error::{Error, Result};
use crate::geometry::mesh::TriMesh;
use crate::scene::Scene;

/// A reconstruction method and its settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Method {
    /// Backprojection (Velten et al. 2012), unfiltered.
    Backprojection(BackprojectOptions),
    /// Filtered backprojection: the depth Laplacian of the backprojection.
    Filtered(BackprojectOptions),
    /// The light-cone transform (confocal).
    Lct(LctOptions),
    /// Phasor fields, backprojection form.
    Phasor(PhasorOptions),
}

impl Method {
    /// `bp`, `fbp`, `lct` or `pf` with default settings for `scene`.
    pub fn parse(name: &str, scene: &Scene) -> Result<Method> {
        Ok(match name {
            "bp" => Method::Backprojection(BackprojectOptions {
                filter: Filter::None,
                ..Default::default()
            }),
            "fbp" => Method::Filtered(BackprojectOptions::default()),
            "lct" => Method::Lct(LctOptions::default()),
            "pf" => Method::Phasor(PhasorOptions::for_scene(scene)),
            _ => {
                return Err(Error::Invalid(format!(
                    "reconstruction method '{name}' is not one of bp, fbp, lct, pf"
                )))
            }
        })
    }

    pub fn name(&self) -> &'static str {
        match self {
            Method::Backprojection(_) => "bp",
            Method::Filtered(_) => "fbp",
            Method::Lct(_) => "lct",
            Method::Phasor(_) => "pf",
        }
    }
}

/// The volume of `method` on `grid` from `data` (the scene's layout).
pub fn reconstruct(
    scene: &Scene,
    data: &[f32],
    grid: &VoxelGrid,
    method: &Method,
) -> Result<Volume> {
    match method {
        Method::Backprojection(o) => backproject_with(
            scene,
            data,
            grid,
            &BackprojectOptions {
                filter: Filter::None,
                ..*o
            },
        ),
        Method::Filtered(o) => backproject_with(
            scene,
            data,
            grid,
            &BackprojectOptions {
                filter: Filter::DepthLaplacian,
                ..*o
            },
        ),
        Method::Lct(o) => lct(scene, data, grid, o),
        Method::Phasor(o) => phasor_field(scene, data, grid, o),
    }
}

/// The depth map of `volume` (columns whose peak is at least `threshold` of the
/// volume's maximum) and its height-field surface in world space; an error if no 2 x 2
/// block of columns is filled.
pub fn volume_surface(
    volume: &Volume,
    scene: &Scene,
    threshold: f32,
) -> Result<(DepthMap, TriMesh)> {
    let depth = depth_map(volume, threshold)?;
    let mesh = depth_map_mesh(
        &depth,
        &volume.grid,
        &WallFrame::of(scene),
        &MeshOptions::default(),
    )?;
    Ok((depth, mesh))
}
