//! One score for any recovered surface, a fitted mesh or a reconstruction's depth-map
//! surface (issue 20's baselines study, `docs/BASELINES.md`), against the true hidden
//! objects of a scene:
//!
//! - **seen Chamfer** ([`super::metrics::chamfer_seen`]): both directions over the
//!   points the wall sees;
//! - **completeness**: the share of the truth's seen points within [`COMPLETE_MM`] of
//!   the candidate (a surface that is accurate where it exists but covers half the
//!   object scores 0.5);
//! - **depth error**: on [`COLUMNS`]² columns over the scan rectangle, the first hidden
//!   surface along the wall normal from each column, candidate against truth
//!   (`recon::surface_depth_map` of each), `|d_candidate − d_truth|` over the columns
//!   where both have one: mean and 90th percentile; and the share of the truth's
//!   columns the candidate fills.
//!
//! The candidate is two-sided (a reconstruction has no orientation); the truth is as
//! its scene says.

use super::metrics::{chamfer_seen, distances, mean_p90, seen_samples, Chamfer};
use super::objective::hidden_object;
use crate::error::{Error, Result};
use crate::geometry::SceneGeometry;
use crate::recon::{surface_depth_map, DepthMap, VoxelGrid, WallFrame};
use crate::scene::Scene;
use optim::Mesh;
use serde::Serialize;

/// Distance (mm) within which a true point counts as recovered.
pub const COMPLETE_MM: f64 = 10.0;
/// Columns per side of the depth-error grid.
pub const COLUMNS: usize = 64;
/// Sample points per surface for the Chamfer distance and completeness.
const SAMPLES: usize = 4000;

/// A candidate surface's score (module docs); lengths in mm.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SurfaceScore {
    pub seen_chamfer_mm: f64,
    pub seen_candidate_to_truth_mm: f64,
    pub seen_truth_to_candidate_mm: f64,
    pub seen_candidate_to_truth_p90_mm: f64,
    pub seen_truth_to_candidate_p90_mm: f64,
    /// Share of the truth's seen points within [`COMPLETE_MM`] of the candidate.
    pub completeness: f64,
    pub depth_error_mean_mm: f64,
    pub depth_error_p90_mm: f64,
    /// Share of the truth's depth-map columns the candidate also fills.
    pub columns_filled: f64,
    /// Faces of the candidate.
    pub faces: usize,
}

/// Scores `candidate` against `truth` (the hidden objects of `truth_scene` as one mesh).
pub fn score_surface(candidate: &Mesh, truth: &Mesh, truth_scene: &Scene) -> Result<SurfaceScore> {
    if candidate.faces.is_empty() {
        return Err(Error::Invalid(
            "surface score: the candidate surface has no faces".into(),
        ));
    }
    let (c, _): (Chamfer, _) = chamfer_seen(candidate, truth, truth_scene, SAMPLES);
    let two_sided = truth_scene.objects.iter().all(|o| o.two_sided);
    let (truth_seen, _) = seen_samples(truth, truth_scene, two_sided, SAMPLES);
    let near = distances(&truth_seen, candidate)
        .iter()
        .filter(|&&d| d * 1e3 <= COMPLETE_MM)
        .count();
    let completeness = near as f64 / truth_seen.len().max(1) as f64;

    let grid = VoxelGrid::over_scan(truth_scene, 0.0, 1.0, [COLUMNS, COLUMNS, 1])?;
    let dc = mesh_depth_map(truth_scene, candidate, true, &grid).depth;
    let dt = mesh_depth_map(truth_scene, truth, two_sided, &grid).depth;
    let truth_columns = dt.iter().filter(|d| d.is_finite()).count();
    let errors: Vec<f64> = dc
        .iter()
        .zip(&dt)
        .filter(|(a, b)| a.is_finite() && b.is_finite())
        .map(|(a, b)| (a - b).abs() as f64)
        .collect();
    let filled = errors.len() as f64 / truth_columns.max(1) as f64;
    let (depth_mean, depth_p90) = mean_p90(errors);
    Ok(SurfaceScore {
        seen_chamfer_mm: 1e3 * c.symmetric,
        seen_candidate_to_truth_mm: 1e3 * c.fit_to_truth,
        seen_truth_to_candidate_mm: 1e3 * c.truth_to_fit,
        seen_candidate_to_truth_p90_mm: 1e3 * c.fit_to_truth_p90,
        seen_truth_to_candidate_p90_mm: 1e3 * c.truth_to_fit_p90,
        completeness,
        depth_error_mean_mm: 1e3 * depth_mean,
        depth_error_p90_mm: 1e3 * depth_p90,
        columns_filled: filled,
        faces: candidate.faces.len(),
    })
}

/// The depth map of `mesh` (as the only hidden object of `scene`) on the columns of
/// `grid` (`recon::surface_depth_map`).
pub fn mesh_depth_map(scene: &Scene, mesh: &Mesh, two_sided: bool, grid: &VoxelGrid) -> DepthMap {
    let with_mesh = Scene {
        objects: vec![hidden_object(mesh, 1.0, two_sided, Default::default())],
        ..scene.clone()
    };
    surface_depth_map(
        &SceneGeometry::build(&with_mesh),
        grid,
        &WallFrame::of(scene),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::toml_format;
    use std::path::Path;

    fn square(z: f64, half: f64) -> Mesh {
        Mesh::new(
            vec![
                [-half, -half, z],
                [half, -half, z],
                [half, half, z],
                [-half, half, z],
            ],
            vec![[0, 2, 1], [0, 3, 2]],
        )
    }

    fn truth_scene(truth: &Mesh) -> Scene {
        let toml = "capture_type = \"confocal\"\n[wall]\nsize = [2.0, 2.0]\n[laser]\norigin = [0.0, -1.0, 1.0]\n[scan]\nresolution = [8, 8]\nsize = [0.8, 0.8]\n[film]\ntemporal_bins = 64\nbin_width_opl = 0.02\n";
        let mut s = toml_format::parse(toml, Path::new("t.toml"), &|_| unreachable!()).unwrap();
        s.objects = vec![hidden_object(truth, 0.9, true, Default::default())];
        s
    }

    #[test]
    fn a_parallel_square_scores_its_gap() {
        let truth = square(0.5, 0.2);
        let scene = truth_scene(&truth);
        let s = score_surface(&square(0.505, 0.2), &truth, &scene).unwrap();
        assert!((s.seen_chamfer_mm - 5.0).abs() < 0.01, "{s:?}");
        assert!((s.depth_error_mean_mm - 5.0).abs() < 0.01, "{s:?}");
        assert_eq!(s.completeness, 1.0);
        assert!(s.columns_filled > 0.99, "{s:?}");
        // 2 cm off: nothing within 1 cm.
        let far = score_surface(&square(0.52, 0.2), &truth, &scene).unwrap();
        assert_eq!(far.completeness, 0.0);
    }

    #[test]
    fn half_a_square_is_half_complete() {
        let truth = square(0.5, 0.2);
        let scene = truth_scene(&truth);
        let half = Mesh::new(
            vec![
                [-0.2, -0.2, 0.5],
                [0.0, -0.2, 0.5],
                [0.0, 0.2, 0.5],
                [-0.2, 0.2, 0.5],
            ],
            vec![[0, 2, 1], [0, 3, 2]],
        );
        let s = score_surface(&half, &truth, &scene).unwrap();
        assert!((s.completeness - 0.5).abs() < 0.03, "{s:?}");
        assert!((s.columns_filled - 0.5).abs() < 0.05, "{s:?}");
        assert!(s.depth_error_mean_mm < 0.01, "{s:?}");
        assert!(score_surface(&Mesh::new(vec![], vec![]), &truth, &scene).is_err());
    }
}
