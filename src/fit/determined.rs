//! Which parts of a fitted mesh the data determine: each part's signal against the noise
//! in the bins it lands in (issue 20; notes/low-signal-faces.md).
//!
//! A face can be lit and seen (`fit::support`) and bright, and still return so little
//! light that the measurement cannot tell it from noise: its position and albedo are then
//! wherever the start and the regulariser left them. Grazing surface at the edge of the
//! scan's view is the common case (the far side of a sphere start wrapped behind an
//! object; the sides of a sphere seen edge-on). The classical reconstructions the fit is
//! compared with drop such surface by thresholding their volume's intensity; `mesh.obj`
//! drops it by a test in the data's own units.
//!
//! The test needs the noise, so it runs on photon counts only (Poisson: `Var M_i = λ_i`,
//! estimated by the counts averaged over [`SMOOTH_BINS`] neighbouring bins, at least one
//! count; over `n²` for `n x n` averaged scan blocks). Not the residual: early in a fit,
//! or where the model is wrong, the residual is mostly misfit, and counted as noise it
//! calls true surface undetermined (a short sphere fit lost a third of its seen surface
//! that way). A render or data of unknown noise keep every face.
//!
//! The faces kept so far are cut into up to [`CLUSTERS`] clusters (k-means on their
//! centroids, farthest-point seeds: deterministic). For a cluster `c`, its own part of
//! the fitted transient is `h_c = Z K H(all) − Z K H(all but c)` at the fit's time offset
//! (the scene's visibility, so occlusion by and of the rest counts). With the fitted
//! scale `s` and the noise variance `var_i`,
//!
//! ```text
//!   SNR_c = s² |h_c|² / ( Σ_i h_ci² var_i / |h_c|² ),
//! ```
//!
//! the cluster's signal energy against the noise energy along it. Fitting noise with `k`
//! free parameters absorbs about `k` units of it; a face of a triangle mesh carries about
//! half a vertex, two parameters (three coordinates and an albedo per vertex). A cluster of
//! `n` faces whose `SNR_c` is under [`NOISE_UNITS_PER_FACE`]` · n` (twice that count, a
//! margin) says no more than the noise, and its faces are undetermined.
//!
//! Where it fails: it cannot tell undetermined surface that happens to be right (a sphere
//! start's true grazing sides, on a sphere) from undetermined surface that is wrong (the
//! same start's far side behind a bunny); it drops both. `mesh_all.obj` keeps every face.
//! The clusters' size sets what counts as one part (40 clusters on a letter-sized mesh:
//! a few centimetres).

use super::intensity::Intensity;
use super::objective::UmbraObjective;
use optim::Mesh;

/// Clusters the kept faces are cut into.
pub const CLUSTERS: usize = 40;
/// Bins the counts are averaged over (centred) for the Poisson variance.
pub const SMOOTH_BINS: usize = 9;
/// Noise units a face's parameters may absorb: a cluster of `n` faces is determined when
/// its SNR is at least this times `n`.
pub const NOISE_UNITS_PER_FACE: f64 = 4.0;
/// Lloyd iterations of the k-means.
const KMEANS_ITERS: usize = 30;

/// Per face of the fitted mesh: its cluster's SNR over [`NOISE_UNITS_PER_FACE`] times the
/// cluster's face count (below 1: undetermined); 0 for faces not tested (left out before:
/// dark or unsupported). `objective.measured` is photon counts averaged over
/// `scan_block x scan_block` scan points (1: not averaged).
pub fn face_determination(
    objective: &UmbraObjective,
    mesh: &Mesh,
    candidates: &[bool],
    fitted: &[f32],
    intensity: &Intensity,
    time_offset_opl: f64,
    scan_block: u32,
) -> crate::Result<Vec<f64>> {
    let bins = objective.scene.film.temporal_bins as usize;
    let first = objective.first_bin;
    let measured = &objective.measured;
    let faces: Vec<usize> = (0..mesh.faces.len()).filter(|&f| candidates[f]).collect();
    let mut ratio = vec![0.0; mesh.faces.len()];
    if faces.is_empty() {
        return Ok(ratio);
    }
    let s = intensity.scale;
    let var = poisson_variance(measured, bins, first, scan_block);
    let centroids: Vec<[f64; 3]> = faces
        .iter()
        .map(|&f| {
            let [a, b, c] = mesh.faces[f].map(|i| mesh.vertices[i as usize]);
            [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0)
        })
        .collect();
    let label = kmeans(&centroids, CLUSTERS.min(faces.len()));
    let clusters = label.iter().max().map_or(0, |&l| l + 1);
    for c in 0..clusters {
        let members: Vec<usize> = (0..faces.len()).filter(|&j| label[j] == c).collect();
        if members.is_empty() {
            continue;
        }
        let mut keep = vec![true; mesh.faces.len()];
        members.iter().for_each(|&j| keep[faces[j]] = false);
        let rest = objective.response(&mesh.with_faces(&keep), time_offset_opl)?;
        let (mut energy, mut noise) = (0.0, 0.0);
        for ((&h, &r), &v) in fitted.iter().zip(&rest).zip(&var) {
            let d = (h - r) as f64;
            energy += d * d;
            noise += d * d * v;
        }
        let snr = if energy <= 0.0 {
            0.0
        } else if noise <= 0.0 {
            f64::INFINITY
        } else {
            s * s * energy * energy / noise
        };
        let value = snr / (NOISE_UNITS_PER_FACE * members.len() as f64);
        members.iter().for_each(|&j| ratio[faces[j]] = value);
    }
    Ok(ratio)
}

/// Poisson variance per bin of counts averaged over `n x n` scan blocks: the mean of
/// the counts over [`SMOOTH_BINS`] bins centred on each bin of each `bins`-long row
/// (bins past a row's ends count as zero), summed over the block, at least one count,
/// over `n⁴` (`Var(Σ/n²) = λ_sum / n⁴`); 0 in the bins before `first` (not fitted).
fn poisson_variance(measured: &[f32], bins: usize, first: usize, n: u32) -> Vec<f64> {
    let half = SMOOTH_BINS / 2;
    let block = (n.max(1) as f64).powi(2);
    let mut out = vec![0.0; measured.len()];
    for (row, o) in measured.chunks(bins).zip(out.chunks_mut(bins)) {
        for (t, v) in o.iter_mut().enumerate().skip(first) {
            let (lo, hi) = (t.saturating_sub(half), (t + half + 1).min(bins));
            let mean = row[lo..hi].iter().map(|&m| m as f64).sum::<f64>() / SMOOTH_BINS as f64;
            *v = (mean * block).max(1.0) / (block * block);
        }
    }
    out
}

/// Cluster labels of `points` in `k` clusters: farthest-point seeds from the point
/// nearest the mean, then Lloyd iterations (ties to the lower index: deterministic).
fn kmeans(points: &[[f64; 3]], k: usize) -> Vec<usize> {
    let d2 = |a: &[f64; 3], b: &[f64; 3]| (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>();
    let n = points.len() as f64;
    let mean = [0, 1, 2].map(|i| points.iter().map(|p| p[i]).sum::<f64>() / n);
    let nearest = |to: &[f64; 3]| {
        (0..points.len())
            .min_by(|&a, &b| d2(&points[a], to).total_cmp(&d2(&points[b], to)))
            .unwrap_or(0)
    };
    let mut centres = vec![points[nearest(&mean)]];
    let mut gap: Vec<f64> = points.iter().map(|p| d2(p, &centres[0])).collect();
    while centres.len() < k {
        let far = (0..points.len())
            .max_by(|&a, &b| gap[a].total_cmp(&gap[b]).then(b.cmp(&a)))
            .unwrap_or(0);
        centres.push(points[far]);
        for (g, p) in gap.iter_mut().zip(points) {
            *g = g.min(d2(p, &points[far]));
        }
    }
    let mut label = vec![0; points.len()];
    for _ in 0..KMEANS_ITERS {
        for (l, p) in label.iter_mut().zip(points) {
            *l = (0..centres.len())
                .min_by(|&a, &b| d2(p, &centres[a]).total_cmp(&d2(p, &centres[b])))
                .unwrap_or(0);
        }
        for (c, centre) in centres.iter_mut().enumerate() {
            let members: Vec<&[f64; 3]> = points
                .iter()
                .zip(&label)
                .filter(|(_, &l)| l == c)
                .map(|(p, _)| p)
                .collect();
            if !members.is_empty() {
                let m = members.len() as f64;
                *centre = [0, 1, 2].map(|i| members.iter().map(|p| p[i]).sum::<f64>() / m);
            }
        }
    }
    label
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kmeans_separates_two_groups_and_is_deterministic() {
        let mut pts = Vec::new();
        for i in 0..10 {
            pts.push([i as f64 * 0.01, 0.0, 0.0]);
            pts.push([5.0 + i as f64 * 0.01, 0.0, 0.0]);
        }
        let l = kmeans(&pts, 2);
        assert!(l.iter().step_by(2).all(|&x| x == l[0]));
        assert!(l.iter().skip(1).step_by(2).all(|&x| x == l[1]));
        assert_ne!(l[0], l[1]);
        assert_eq!(l, kmeans(&pts, 2));
    }

    #[test]
    fn the_variance_is_the_smoothed_counts_of_a_block() {
        let m = [0.0, 9.0, 0.0, 0.0, 0.0, 0.0];
        // rows of 3, no averaging: 9 counts over SMOOTH_BINS, at least one count
        let v = poisson_variance(&m, 3, 0, 1);
        assert_eq!(v[0], 1.0);
        assert_eq!(v[3..], [1.0, 1.0, 1.0]);
        let v = poisson_variance(&[0.0, 90.0, 0.0], 3, 1, 2);
        assert_eq!(v[0], 0.0); // before the first fitted bin
        assert_eq!(v[1], 90.0 / SMOOTH_BINS as f64 * 4.0 / 16.0);
    }
}
