//! The `tri3` adjoint kernel (issue 19): the forward kernel's structure run backwards, so
//! the gradient costs about what the render does.
//!
//! For each block of eight sub-triangles ([`super::tri3_kernel`]) and each measurement:
//! 1. the forward pass's own [`TriBlock::pulses`] gives the eight pulses (`f32` lanes; the
//!    physics is written there once), visibility as in the render;
//! 2. the pulse stage in reverse: box, [`reverse_lanes`] (the block's bin window, `δH`
//!    read once per edge for all lanes, adjoint moments, `pulse_grad` in lanes); Gaussian,
//!    and the few lanes the box lanes leave (a piece narrower than `NARROW`, a window wider
//!    than `MAX_WINDOW`), [`Film::triangle_bins_reverse`] in `f64`, as the render splats
//!    Gaussian pulses in `f64`;
//! 3. [`TriBlock::reverse`]: `∂L/∂` of each sub-triangle's corners, corner `ρ/π`, normal,
//!    plane offset and area, accumulated per sub-triangle over all measurements ([`BlockGrad`]).
//!
//! Blocks are the outer loop (each block's sums run over the measurements in order, so the
//! result is the same for any thread count) and measurements the inner one. Once, at the
//! end, the normal, plane offset and area are chained to the sub-triangle's corners, and the
//! corners (affine in the original triangle's, by fixed barycentrics) to the original
//! triangle's corners and albedos.
//!
//! The `f64` dual-number model ([`super::tri3_exact`]) is the oracle this is tested against
//! (`tests/tri3_adjoint.rs`).

use super::mc3::TRI_PARAMS;
use super::tri3::{Tri3Mesh, WINDOW_MIN_BINS};
use super::tri3_kernel::{self, BlockGrad, PulseBlock, TriBlock, W};
use super::{MeasurementCtx, Progress};
use crate::film::{reverse_lanes, Film};
use crate::scene::{KernelSpec, Visibility};
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::FRAC_1_PI;
use std::sync::atomic::Ordering;

/// Blocks per work item: few enough that the measurements' frames stay warm, enough
/// items to balance two to a few dozen threads.
const BLOCKS_PER_TASK: usize = 4;

/// `Σ_m Σ_b adjoint[m, b] ∂H[m, b]/∂θ` for every original triangle's local parameters
/// (corners, corner albedos; [`TRI_PARAMS`]), for the measurements `ctxs` (one per
/// measurement, in order). `None` if cancelled through `progress`.
pub fn gradient(
    mesh: &Tri3Mesh,
    parents: usize,
    ctxs: &[MeasurementCtx],
    film: &Film,
    visibility: Visibility,
    adjoint: &[f32],
    progress: Option<&Progress>,
) -> Option<Vec<[f64; TRI_PARAMS]>> {
    let tasks: Vec<&[TriBlock]> = mesh.blocks.chunks(BLOCKS_PER_TASK).collect();
    let sums: Vec<Vec<BlockGrad>> = tasks
        .par_iter()
        .enumerate()
        .map(|(t, blocks)| {
            let first = t * BLOCKS_PER_TASK;
            task(
                mesh, first, blocks, ctxs, film, visibility, adjoint, progress,
            )
        })
        .collect();
    if progress.is_some_and(|p| p.cancel.load(Ordering::Relaxed)) {
        return None;
    }
    let mut out = vec![[0.0; TRI_PARAMS]; parents];
    for (b, acc) in sums.iter().flatten().enumerate() {
        for j in 0..W {
            let k = b * W + j;
            if k < mesh.len() {
                chain(mesh, k, acc, j, &mut out[mesh.parent[k] as usize]);
            }
        }
    }
    Some(out)
}

/// Blocks `first ..` of the mesh (`blocks`) over every measurement.
#[allow(clippy::too_many_arguments)]
fn task(
    mesh: &Tri3Mesh,
    first: usize,
    blocks: &[TriBlock],
    ctxs: &[MeasurementCtx],
    film: &Film,
    visibility: Visibility,
    adjoint: &[f32],
    progress: Option<&Progress>,
) -> Vec<BlockGrad> {
    let mut acc = vec![BlockGrad::default(); blocks.len()];
    let subs = (first * W..((first + blocks.len()) * W).min(mesh.len())).collect::<Vec<_>>();
    // `centroid` visibility: a cache over this task's original triangles only.
    let mut parents: Vec<u32> = subs.iter().map(|&k| mesh.parent[k]).collect();
    parents.sort_unstable();
    parents.dedup();
    let slot = |k: usize| parents.binary_search(&mesh.parent[k]).unwrap_or(0);
    let mut seen = vec![0u8; parents.len()];
    let gaussian = matches!(film.kernel, KernelSpec::Gaussian { .. });
    let bins = film.bins;
    let mut pulses = PulseBlock::default();
    let mut g = [[0.0f32; W]; 7];
    for (m, ctx) in ctxs.iter().enumerate() {
        if let Some(p) = progress {
            if p.cancel.load(Ordering::Relaxed) {
                break;
            }
            p.work_done.fetch_add(subs.len() as u64, Ordering::Relaxed);
        }
        let scale = ctx.power * ctx.f_wall * ctx.f_wall;
        if !ctx.legs_visible || scale == 0.0 {
            continue;
        }
        let adj = &adjoint[m * bins..(m + 1) * bins];
        let mut frame = tri3_kernel::frame(ctx, film);
        // As the render: long films get bins relative to the reach of the mesh, so the
        // lanes' bin numbers stay exact in f32.
        let (origin, window) = if !gaussian && bins as u64 > WINDOW_MIN_BINS {
            let (origin, len) = mesh.reach(&frame, bins);
            frame.offset = (f64::from(frame.offset) - origin as f64 * film.width) as f32;
            frame.lo = (f64::from(frame.lo) - origin as f64) as f32;
            frame.hi = (f64::from(frame.hi) - origin as f64) as f32;
            (origin, len)
        } else {
            (0, bins)
        };
        seen.iter_mut().for_each(|s| *s = 0);
        for (b, block) in blocks.iter().enumerate() {
            if frame.confocal() {
                block.pulses::<true>(&frame, &mut pulses);
            } else {
                block.pulses::<false>(&frame, &mut pulses);
            }
            let base = (first + b) * W;
            if visibility != Visibility::None {
                for j in 0..W {
                    let k = base + j;
                    if pulses.lanes.live()[j]
                        && !mesh.visible_at(k, ctx, visibility, &mut seen, slot(k))
                    {
                        pulses.lanes.kill(j);
                    }
                }
            }
            if !pulses.lanes.live().iter().any(|&l| l) {
                continue;
            }
            let (mut sorted, fallback) = if gaussian {
                ([[0.0; W]; 7], *pulses.lanes.live())
            } else {
                let lg = reverse_lanes(
                    &pulses.lanes,
                    &pulses.w,
                    &pulses.area,
                    &adj[origin..origin + window],
                    window,
                );
                (lg.g, lg.fallback)
            };
            for j in (0..W).filter(|&j| fallback[j]) {
                let opl = pulses
                    .lanes
                    .t()
                    .map(|t| film.start + (origin as f64 + t[j] as f64) * film.width);
                let w = pulses.w.map(|w| w[j] as f64);
                let gj =
                    film.triangle_bins_reverse(opl, w, pulses.area[j] as f64, |b| adj[b] as f64);
                for (s, v) in gj.into_iter().enumerate() {
                    // Per m of OPL to per bin.
                    let v = if s < 3 { v * film.width } else { v };
                    sorted[s][j] = v as f32;
                }
            }
            // Sorted slots to corners, and the measurement's scale.
            for j in 0..W {
                for s in 0..3 {
                    let i = pulses.order[s][j] as usize;
                    g[i][j] = sorted[s][j] * scale;
                    g[3 + i][j] = sorted[3 + s][j] * scale;
                }
                g[6][j] = sorted[6][j] * scale;
            }
            if frame.confocal() {
                block.reverse::<true>(&frame, &g, &mut acc[b]);
            } else {
                block.reverse::<false>(&frame, &g, &mut acc[b]);
            }
        }
    }
    acc
}

/// Sub-triangle `k` (lane `j` of `acc`): its normal, plane offset and area chained to its
/// corners, its corners and corner `ρ/π` to its original triangle's (`out`).
fn chain(mesh: &Tri3Mesh, k: usize, acc: &BlockGrad, j: usize, out: &mut [f64; TRI_PARAMS]) {
    let v = mesh.tris[k].map(|i| mesh.vertices[i as usize].as_dvec3());
    let mut g_v: [DVec3; 3] =
        std::array::from_fn(|i| DVec3::from_array(acc.corner[i].map(|a| a[j])));
    let mut g_n = DVec3::from_array(acc.normal.map(|a| a[j]));
    let (e1, e2) = (v[1] - v[0], v[2] - v[0]);
    let cross = e1.cross(e2);
    let len = cross.length();
    if len == 0.0 {
        return;
    }
    let n = cross / len;
    // The plane offset n·c, c the centroid.
    let g_plane = acc.plane[j];
    g_n += (v[0] + v[1] + v[2]) / 3.0 * g_plane;
    for g in &mut g_v {
        *g += n * (g_plane / 3.0);
    }
    // n = c/|c| and A = |c|/2, c = e1 × e2.
    let g_cross = (g_n - n * n.dot(g_n)) / len + n * (0.5 * acc.area[j]);
    let (g_e1, g_e2) = (e2.cross(g_cross), g_cross.cross(e1));
    g_v[1] += g_e1;
    g_v[2] += g_e2;
    g_v[0] -= g_e1 + g_e2;
    for (i, [b1, b2]) in mesh.corner_bary[k].into_iter().enumerate() {
        let beta = [1.0 - b1 as f64 - b2 as f64, b1 as f64, b2 as f64];
        for (c, b) in beta.into_iter().enumerate() {
            for axis in 0..3 {
                out[3 * c + axis] += b * g_v[i][axis];
            }
            out[9 + c] += b * acc.brdf[i][j] * FRAC_1_PI;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::SceneGeometry;
    use crate::transport::tri3_reverse::{self, ParentGeom};

    /// The lane reverse and the chain to the original triangle, pair by pair, against the
    /// `f64` hand reverse (`tri3_reverse`, itself checked against dual numbers), for the
    /// same `∂L/∂(τ, w, A)`, on the default scene: one-sided, two-sided, retroreflective.
    #[test]
    fn lane_reverse_matches_the_f64_reverse_per_pair() {
        let mut scene = crate::scene::default::default_scene().unwrap();
        for variant in 0..3 {
            match variant {
                1 => scene.objects[0].two_sided = !scene.objects[0].two_sided,
                2 => scene.objects[0].reflectance = crate::scene::Reflectance::Retroreflective,
                _ => {}
            }
            let geom = SceneGeometry::build(&scene);
            let sub = crate::transport::RenderOptions::from_scene(&scene).subdivision;
            let mesh = Tri3Mesh::build(&scene, &geom, sub);
            let film = Film::new(&scene.film);
            let (mut worst, mut pairs) = (0.0f64, 0);
            for m in [0, 37, 500, 1023] {
                let ctx = MeasurementCtx::new(&scene, &geom, &film, m);
                let frame = tri3_kernel::frame(&ctx, &film);
                for k in 0..mesh.len() {
                    let p = mesh.parent[k] as usize;
                    let parent = ParentGeom::new(&geom.hidden[p]);
                    let Some(pair) = tri3_reverse::forward(&mesh, k, &parent, &ctx) else {
                        continue;
                    };
                    pairs += 1;
                    let gk: [f32; 7] = std::array::from_fn(|i| ((i * 7 + k) % 5) as f32 - 2.0);
                    // The oracle takes τ in m.
                    let mut g64 = gk.map(f64::from);
                    (0..3).for_each(|i| g64[i] /= film.width);
                    let mut want = [0.0; TRI_PARAMS];
                    tri3_reverse::reverse(&pair, &parent, &ctx, &g64, &mut want);
                    let (b, j) = (k / W, k % W);
                    let mut g = [[0.0f32; W]; 7];
                    (0..7).for_each(|i| g[i][j] = gk[i]);
                    let mut acc = BlockGrad::default();
                    mesh.blocks[b].reverse::<true>(&frame, &g, &mut acc);
                    let mut got = [0.0; TRI_PARAMS];
                    chain(&mesh, k, &acc, j, &mut got);
                    let scale = want.iter().fold(1e-300f64, |m, g| m.max(g.abs()));
                    for (a, b) in got.iter().zip(want) {
                        worst = worst.max((a - b).abs() / scale);
                    }
                }
            }
            println!("variant {variant}: {pairs} pairs, worst {worst:e}");
            assert!(pairs > 100, "variant {variant}: {pairs} pairs");
            assert!(worst < 1e-4, "variant {variant}: worst {worst:e}");
        }
    }
}
