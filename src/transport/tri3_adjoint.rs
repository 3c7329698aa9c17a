//! The `tri3` adjoint kernel (issue 19): the forward kernel's structure run backwards, so
//! the gradient costs about what the render does.
//!
//! For each block of eight sub-triangles ([`super::tri3_kernel`]) and each measurement:
//! 1. the forward pass's own per-lane loop ([`TriBlock::pulses_keeping`]) gives the eight
//!    pulses, the sort's permutation, and keeps the legs and corner weights it computed;
//!    visibility as in the render;
//! 2. the pulse stage in reverse: box, [`reverse_lanes`] (each lane walks its own pulse's
//!    inner bin edges, adjoint moments, `pulse_grad` in lanes); Gaussian, and the few lanes
//!    the box lanes leave (a piece narrower than `NARROW`, a pulse over more than
//!    `MAX_EDGES` edges), [`Film::triangle_bins_reverse`] in `f64`, as the render splats
//!    Gaussian pulses in `f64`;
//! 3. `reverse`: the per-pair physics ([`super::tri3_physics`], the forward's equations:
//!    its kept legs, the plane factor here in `f32x8`) in reverse, `∂L/∂` of each sub-triangle's corners, corner `ρ/π`,
//!    normal, plane offset and area, accumulated per sub-triangle over all measurements
//!    ([`BlockGrad`]).
//!
//! Blocks are the outer loop (each block's sums run over the measurements in order, so the
//! result is the same for any thread count) and measurements the inner one. Once, at the
//! end, the normal, plane offset and area are chained to the sub-triangle's corners, and the
//! corners (affine in the original triangle's, by fixed barycentrics) to the original
//! triangle's corners and albedos.
//!
//! The `f64` dual-number model ([`super::tri3_exact`]) is the oracle this is tested against
//! (per pair below; the whole gradient in `tests/gradients.rs`).

use super::mc3::TRI_PARAMS;
use super::tri3::{Tri3Mesh, UNKNOWN};
use super::tri3_kernel::{BlockFrames, PulseBlock, TriBlock, W};
use super::tri3_physics::{KeptLegs, Plane, Wall};
use super::{MeasurementCtx, Progress};
use crate::film::{reverse_lanes, Film};
use crate::scene::{KernelSpec, Visibility};
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::FRAC_1_PI;
use std::sync::atomic::{AtomicU8, Ordering};
use wide::{f32x8, CmpEq, CmpGt, CmpLt};

/// Blocks per work item: few enough that the measurements' frames stay warm, enough
/// items to balance two to a few dozen threads, and enough that each measurement's block
/// frames are computed in full vector lanes (10k sheet, box: 8 is 7 % faster than 4, 16
/// no faster than 8; measured).
const BLOCKS_PER_TASK: usize = 8;

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
    let seen = SeenCache::new(mesh, ctxs.len(), visibility, SHARED_SEEN_MAX);
    gradient_with(
        mesh, parents, ctxs, film, visibility, &seen, adjoint, progress,
    )
}

/// [`gradient`] with the given visibility cache.
#[allow(clippy::too_many_arguments)]
fn gradient_with(
    mesh: &Tri3Mesh,
    parents: usize,
    ctxs: &[MeasurementCtx],
    film: &Film,
    visibility: Visibility,
    seen: &SeenCache,
    adjoint: &[f32],
    progress: Option<&Progress>,
) -> Option<Vec<[f64; TRI_PARAMS]>> {
    // A Gaussian far wider than the bins: the render bins the pulses into its cells, so
    // the pulses' adjoint is the cells' ([`Film::cells`]).
    let cells = film.cells();
    let cell_adjoint;
    let (film, adjoint) = match &cells {
        Some(c) => {
            cell_adjoint = cells_adjoint(mesh, ctxs, film, c, adjoint);
            (c, &cell_adjoint[..])
        }
        None => (film, adjoint),
    };
    let tasks: Vec<&[TriBlock]> = mesh.blocks.chunks(BLOCKS_PER_TASK).collect();
    let sums: Vec<Vec<BlockGrad>> = tasks
        .par_iter()
        .enumerate()
        .map(|(t, blocks)| {
            let first = t * BLOCKS_PER_TASK;
            task(
                mesh, first, blocks, ctxs, film, visibility, seen, adjoint, progress,
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

/// `∂L/∂` of every cell of `cells` the mesh reaches, per measurement (`cells.bins` each),
/// from the film's adjoint: the transpose of the render's blur.
fn cells_adjoint(
    mesh: &Tri3Mesh,
    ctxs: &[MeasurementCtx],
    film: &Film,
    cells: &Film,
    adjoint: &[f32],
) -> Vec<f32> {
    let mut out = vec![0.0f32; ctxs.len() * cells.bins];
    out.par_chunks_mut(cells.bins)
        .zip(ctxs.par_iter())
        .enumerate()
        .for_each(|(m, (o, ctx))| {
            let (_, first, len) = mesh.frame(ctx, cells);
            let adj = &adjoint[m * film.bins..(m + 1) * film.bins];
            film.cells_adjoint(cells, first, adj, &mut o[first..first + len]);
        });
    out
}

/// `centroid` visibility of every original triangle from every measurement, filled on
/// first use and shared by all work items, so each ray is traced once, as in the render
/// (a work item's blocks mix original triangles: with a cache of its own, the default
/// scene's 18 items traced 146 rays per measurement for 72 triangles). `None` for the
/// other modes, or where it would exceed `max` entries ([`SHARED_SEEN_MAX`]; then each
/// item keeps its own).
struct SeenCache {
    parents: usize,
    seen: Option<Vec<AtomicU8>>,
}

/// Entries (bytes) the shared visibility cache may take: 16 MiB.
const SHARED_SEEN_MAX: usize = 1 << 24;

impl SeenCache {
    fn new(mesh: &Tri3Mesh, measurements: usize, visibility: Visibility, max: usize) -> Self {
        let parents = mesh.parent_centroid.len();
        let n = measurements.saturating_mul(parents);
        let seen = (visibility == Visibility::Centroid && n <= max)
            .then(|| (0..n).map(|_| AtomicU8::new(UNKNOWN)).collect());
        SeenCache { parents, seen }
    }

    /// Measurement `m`'s entries, one per original triangle.
    fn measurement(&self, m: usize) -> Option<&[AtomicU8]> {
        let p = self.parents;
        self.seen.as_deref().map(|s| &s[m * p..(m + 1) * p])
    }
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
    shared: &SeenCache,
    adjoint: &[f32],
    progress: Option<&Progress>,
) -> Vec<BlockGrad> {
    let mut acc = vec![BlockGrad::default(); blocks.len()];
    let mut sums = vec![BlockSum::default(); blocks.len()];
    let subs = (first * W..((first + blocks.len()) * W).min(mesh.len())).collect::<Vec<_>>();
    // `centroid` visibility without the shared cache: one over this item's original
    // triangles only.
    let mut parents: Vec<u32> = subs.iter().map(|&k| mesh.parent[k]).collect();
    parents.sort_unstable();
    parents.dedup();
    let slot = |k: usize| parents.binary_search(&mesh.parent[k]).unwrap_or(0);
    let own: Vec<AtomicU8> = (0..parents.len()).map(|_| AtomicU8::new(UNKNOWN)).collect();
    let gaussian = matches!(film.kernel, KernelSpec::Gaussian { .. });
    let bins = film.bins;
    let mut pulses = PulseBlock::default();
    let mut kept = KeptLegs::default();
    let mut frames = BlockFrames::default();
    for (m, ctx) in ctxs.iter().enumerate() {
        if m % FLUSH == 0 {
            acc.iter_mut().zip(&mut sums).for_each(|(a, s)| a.flush(s));
        }
        if let Some(p) = progress {
            if p.cancel.load(Ordering::Relaxed) {
                break;
            }
            p.work_done.fetch_add(subs.len() as u64, Ordering::Relaxed);
        }
        let scale = ctx.three_bounce_constant();
        if !ctx.legs_visible || scale == 0.0 {
            continue;
        }
        let adj = &adjoint[m * bins..(m + 1) * bins];
        // As the render: long films get bins relative to the reach of the mesh.
        let (frame, origin, window) = mesh.frame(ctx, film);
        let seen = shared.measurement(m);
        if seen.is_none() {
            own.iter().for_each(|s| s.store(UNKNOWN, Ordering::Relaxed));
        }
        let entry = |k: usize| match seen {
            Some(s) => s.get(mesh.parent[k] as usize),
            None => own.get(slot(k)),
        };
        mesh.block_frames(&frame, first..first + blocks.len(), &mut frames);
        for (b, block) in blocks.iter().enumerate() {
            let here = frames.get(&frame, b);
            if frame.confocal() {
                block.pulses_keeping::<true, true>(&frame, &here, &mut pulses, Some(&mut kept));
            } else {
                block.pulses_keeping::<false, true>(&frame, &here, &mut pulses, Some(&mut kept));
            }
            if visibility != Visibility::None {
                mesh.cull(first + b, ctx, visibility, &mut pulses.lanes, entry);
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
                    pulses.base,
                    window,
                );
                (lg.g, lg.fallback)
            };
            for j in (0..W).filter(|&j| fallback[j]) {
                let opl = pulses.lanes.t().map(|t| {
                    let bin = (origin as i64 + pulses.base) as f64 + t[j] as f64;
                    film.start + bin * film.width
                });
                let w = pulses.w.map(|w| w[j] as f64);
                let gj =
                    film.triangle_bins_reverse(opl, w, pulses.area[j] as f64, |b| adj[b] as f64);
                for (s, v) in gj.into_iter().enumerate() {
                    // Per m of OPL to per bin.
                    let v = if s < 3 { v * film.width } else { v };
                    sorted[s][j] = v as f32;
                }
            }
            let order = &pulses.order;
            let wall = Wall::<f32x8>::new(&frame, &here);
            if frame.confocal() {
                reverse::<true>(block, &wall, &kept, &sorted, order, scale, &mut sums[b]);
            } else {
                reverse::<false>(block, &wall, &kept, &sorted, order, scale, &mut sums[b]);
            }
        }
    }
    acc.iter_mut().zip(&mut sums).for_each(|(a, s)| a.flush(s));
    acc
}

/// `∂L/∂` of each lane's sub-triangle's own quantities, over a gradient's measurements
/// (`f64`: each is a sum over all of them).
#[derive(Clone, Copy, Debug, Default)]
pub struct BlockGrad {
    /// `corner[i][axis][lane]`.
    pub corner: [[[f64; W]; 3]; 3],
    /// Corner `ρ/π`.
    pub brdf: [[f64; W]; 3],
    pub normal: [[f64; W]; 3],
    /// The plane offset `n·v` (m).
    pub plane: [f64; W],
    pub area: [f64; W],
}

/// The reverse of [`TriBlock::pulses`] for all eight lanes at once, through the same
/// physics ([`super::tri3_physics`]: the legs and weights the forward loop `kept`, the plane
/// factor in `f32x8`): given each lane's `∂L/∂(t, w, A)` of its
/// pulse in sorted slots (`sorted`, `t` in bins), the sort's `order` and the measurement's
/// `scale`, adds `∂L/∂` of each sub-triangle's corners, corner `ρ/π`, normal, plane offset
/// and area into `acc` (the last three chained to the corners by [`chain`]). The chain
/// rule of the forward's equations, written out:
///
/// - shift: `S = Σ g_τi`, `∂L/∂τ'_i = g_τi − S/4`, `∂L/∂τ(c) = 3S/4`;
/// - `∂τ'_i/∂v_i = −(d_l/r_l + d_s/r_s)/width` (likewise the centroid, `1/3` per corner);
/// - `w_i = G (ρ_i/π) k_i` with `k_i` the legs' weight: `∂k_i/∂v_i = k_i (n_w/c_l +
///   4 d_l/r_l² + n_w/c_s + 4 d_s/r_s²)` (retroreflective: the first two, and a falloff
///   `(|p_l|/r_l)^m` in `k_i` makes the second `(4 + m) d_l/r_l²`);
/// - `G = |p_l p_s|`: `∂G/∂p_l = sgn(p_l p_s) p_s` (retroreflective `G = |p_l|`, with the
///   falloff's `m/p_l` of `k_i`: `(1 + m) sgn(p_l)`); `∂p/∂n = x`, `∂p/∂d = −1`.
#[allow(clippy::needless_range_loop)] // corners and axes by index, as the equations
fn reverse<const CONFOCAL: bool>(
    block: &TriBlock,
    wall: &Wall<f32x8>,
    kept: &KeptLegs,
    sorted: &[[f32; W]; 7],
    order: &[[f32; W]; 3],
    scale: f32,
    acc: &mut BlockSum,
) {
    let v = |a: &[f32; W]| f32x8::new(*a);
    let (zero, one) = (f32x8::ZERO, f32x8::ONE);
    // Sorted slots to corners.
    let mut g_t = [zero; 3];
    let mut g_w = [zero; 3];
    for s in 0..3 {
        let o = v(&order[s]);
        for i in 0..3 {
            let here = o.cmp_eq(f32x8::splat(i as f32));
            g_t[i] += here & v(&sorted[s]);
            g_w[i] += here & v(&sorted[3 + s]);
        }
    }
    let scale = f32x8::splat(scale);
    let (g_t, g_w, g_a) = (
        g_t.map(|g| g * scale),
        g_w.map(|g| g * scale),
        v(&sorted[6]) * scale,
    );
    let retro = v(&block.retro).cmp_gt(zero);
    let falloff = v(&block.falloff);
    let two_sided = v(&block.two_sided).cmp_gt(zero);
    let n = [0, 1, 2].map(|k| v(&block.n[k]));
    let plane = Plane::new::<CONFOCAL>(wall, n, v(&block.plane), two_sided, retro);
    let sum = g_t[0] + g_t[1] + g_t[2];
    let mut g_factor = zero;
    let mut g_v = [[zero; 3]; 3];
    for i in 0..3 {
        // The forward's legs of this corner and its weight (`pulses_keeping`).
        let legs = kept.legs[i].lanes::<CONFOCAL>();
        let g_tau = (g_t[i] - sum * f32x8::splat(0.25)) * wall.inv_width;
        let (u_l, u_s) = (one / legs.r_l, one / legs.r_s);
        let k_i = v(&kept.weight[i]);
        let brdf = v(&block.brdf[i]);
        g_factor += g_w[i] * brdf * k_i;
        let g_k = g_w[i] * plane.factor;
        acc.0[9 + i] += g_k * k_i;
        let g_kk = g_k * brdf * k_i;
        // 1/c only where the corner is in front (k_i = 0 elsewhere).
        let front = legs.front();
        let a_l = front.blend(one / legs.c_l, zero);
        // 4/r² as 4 (1/r)²: one division per leg, not two. (Confocal, the sensor leg's
        // terms are the laser leg's, which the compiler sees: `lanes::<true>`.)
        // (A retroreflector's falloff `(|p_l|/r_l)^m` adds `m d_l/r_l²`: `4 + m`.)
        let four = f32x8::splat(4.0);
        let b_l = (four + falloff) * u_l * u_l;
        let a_s = (front & !retro).blend(one / legs.c_s, zero);
        let b_s = retro.blend(zero, four * u_s * u_s);
        for k in 0..3 {
            g_v[i][k] = -(legs.d_l[k] * u_l + legs.d_s[k] * u_s) * g_tau
                + g_kk * (wall.n_w[k] * (a_l + a_s) + legs.d_l[k] * b_l + legs.d_s[k] * b_s);
        }
    }
    // The centroid's OPL, a third per corner.
    let c = kept.legs[3].lanes::<CONFOCAL>();
    let g_c = sum * f32x8::splat(0.75 / 3.0) * wall.inv_width;
    let (u_l, u_s) = (one / c.r_l, one / c.r_s);
    for i in 0..3 {
        for k in 0..3 {
            let g = g_v[i][k] - (c.d_l[k] * u_l + c.d_s[k] * u_s) * g_c;
            acc.0[3 * i + k] += g;
        }
    }
    // The plane factor G (0 where the triangle does not face the wall points).
    let sgn = |x: f32x8| x.cmp_gt(zero).blend(one, x.cmp_lt(zero).blend(-one, zero));
    let g_factor = plane.facing.blend(g_factor, zero);
    let s = sgn(plane.p_l * plane.p_s);
    // Retroreflective: `G = |p_l|`, and the corners' falloff `|p_l|^m` (in `k_i`) adds
    // `m/p_l` of `G`'s own: `(1 + m) sgn(p_l)`.
    let g_pl = retro.blend(
        g_factor * sgn(plane.p_l) * (one + falloff),
        g_factor * s * plane.p_s,
    );
    let g_ps = retro.blend(zero, g_factor * s * plane.p_l);
    for k in 0..3 {
        acc.0[12 + k] += g_pl * wall.x_l[k] + g_ps * wall.x_s[k];
    }
    acc.0[15] -= g_pl + g_ps;
    acc.0[16] += g_a;
}

/// [`BlockGrad`]'s quantities in `f32` lanes over a run of [`FLUSH`] measurements (slots:
/// corners `3 i + axis`, `ρ/π` `9 + i`, normal `12 + axis`, plane offset 15, area 16), so
/// [`reverse`] adds vectors; flushed into the `f64` sums at fixed measurement indices (the
/// result does not depend on the thread count).
#[derive(Clone, Copy)]
pub struct BlockSum([f32x8; 17]);

impl Default for BlockSum {
    fn default() -> Self {
        BlockSum([f32x8::ZERO; 17])
    }
}

/// Measurements per `f32` run: 32 terms in `f32` lose at most ~2e-6 of their sum.
const FLUSH: usize = 32;

impl BlockGrad {
    /// Adds `s` in `f64` and clears it.
    fn flush(&mut self, s: &mut BlockSum) {
        for (slot, v) in s.0.iter_mut().enumerate() {
            let target = match slot {
                0..=8 => &mut self.corner[slot / 3][slot % 3],
                9..=11 => &mut self.brdf[slot - 9],
                12..=14 => &mut self.normal[slot - 12],
                15 => &mut self.plane,
                _ => &mut self.area,
            };
            for (a, x) in target.iter_mut().zip(v.to_array()) {
                *a += f64::from(x);
            }
            *v = f32x8::ZERO;
        }
    }
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
    use crate::transport::mc3::TriParams;
    use crate::transport::tri3_exact::{pair_pulse, Parent, TriDual64};

    /// The shared visibility cache and the per-item one give the same gradient, to the
    /// bit, on a scene where one letter shadows parts of another from some scan points.
    #[test]
    fn shared_visibility_cache_changes_nothing() {
        let mut scene = crate::scene::default::default_scene().unwrap();
        let mut front = scene.objects[0].clone();
        for p in &mut front.mesh.positions {
            *p = *p * 0.6 + glam::Vec3::new(0.05, 0.1, -0.4);
        }
        scene.objects.push(front);
        let geom = SceneGeometry::build(&scene);
        let opts = crate::transport::RenderOptions::from_scene(&scene);
        assert_eq!(opts.visibility, Visibility::Centroid);
        let mesh = Tri3Mesh::build(&scene, &geom, opts.subdivision);
        let film = Film::new(&scene.film);
        let ctxs: Vec<_> = (0..scene.num_measurements())
            .map(|m| MeasurementCtx::new(&scene, &geom, &film, m))
            .collect();
        let adj: Vec<f32> = (0..ctxs.len() * film.bins)
            .map(|i| ((i * 37 % 101) as f32 - 50.0) * 1e-2)
            .collect();
        let tris = geom.hidden.len();
        let run = |max| {
            let seen = SeenCache::new(&mesh, ctxs.len(), Visibility::Centroid, max);
            let g = gradient_with(
                &mesh,
                tris,
                &ctxs,
                &film,
                Visibility::Centroid,
                &seen,
                &adj,
                None,
            );
            (g.unwrap(), seen)
        };
        let (shared, seen) = run(usize::MAX);
        let (own, none) = run(0);
        assert!(none.seen.is_none());
        let states: Vec<u8> = seen
            .seen
            .unwrap()
            .iter()
            .map(|s| s.load(Ordering::Relaxed))
            .collect();
        let hidden = states.iter().filter(|&&s| s == 2).count();
        let lit = states.iter().filter(|&&s| s == 1).count();
        println!("{lit} seen, {hidden} hidden of {} entries", states.len());
        assert!(
            hidden > 0 && lit > hidden,
            "no shadow: the test scene is broken"
        );
        assert_eq!(shared, own);
    }

    /// The lane reverse and the chain to the original triangle, pair by pair, against the
    /// dual-number model (`tri3_exact::pair_pulse`: the pulse inputs' derivatives with
    /// respect to the original triangle), for the same `∂L/∂(τ, w, A)`, on the default
    /// scene: one-sided, two-sided, retroreflective, retroreflective with angular falloff.
    #[test]
    fn lane_reverse_matches_the_dual_model_per_pair() {
        let mut scene = crate::scene::default::default_scene().unwrap();
        for variant in 0..4 {
            match variant {
                1 => scene.objects[0].two_sided = !scene.objects[0].two_sided,
                2 => scene.objects[0].reflectance = crate::scene::Reflectance::RETRO,
                3 => {
                    scene.objects[0].reflectance =
                        crate::scene::Reflectance::Retroreflective { falloff: 3.5 }
                }
                _ => {}
            }
            let geom = SceneGeometry::build(&scene);
            let sub = crate::transport::RenderOptions::from_scene(&scene).subdivision;
            let mesh = Tri3Mesh::build(&scene, &geom, sub);
            let film = Film::new(&scene.film);
            let (mut worst, mut pairs) = (0.0f64, 0);
            for m in [0, 37, 500, 1023] {
                let ctx = MeasurementCtx::new(&scene, &geom, &film, m);
                let frame = mesh.frame(&ctx, &film).0;
                for k in 0..mesh.len() {
                    let p = mesh.parent[k] as usize;
                    let parent = Parent::new(TriParams::<TriDual64>::variables(&geom.hidden[p]));
                    let Some((tau, w, area)) = pair_pulse(&mesh, k, &parent, &ctx) else {
                        continue;
                    };
                    pairs += 1;
                    let gk: [f32; 7] = std::array::from_fn(|i| ((i * 7 + k) % 5) as f32 - 2.0);
                    // The model's τ is in m, the lanes' in bins.
                    let mut want = [0.0; TRI_PARAMS];
                    for (i, input) in tau.iter().chain(&w).chain([&area]).enumerate() {
                        let g = gk[i] as f64 / if i < 3 { film.width } else { 1.0 };
                        want.iter_mut().zip(input.d).for_each(|(w, d)| *w += g * d);
                    }
                    let (b, j) = (k / W, k % W);
                    let mut g = [[0.0f32; W]; 7];
                    (0..7).for_each(|i| g[i][j] = gk[i]);
                    let (mut acc, mut sum) = (BlockGrad::default(), BlockSum::default());
                    let order = [0.0, 1.0, 2.0].map(|i| [i; W]);
                    let mut kept = KeptLegs::default();
                    let mut pulses = PulseBlock::default();
                    let block = &mesh.blocks[b];
                    let here = mesh.block_frame(&frame, b);
                    block.pulses_keeping::<true, true>(&frame, &here, &mut pulses, Some(&mut kept));
                    let wall = Wall::new(&frame, &here);
                    reverse::<true>(block, &wall, &kept, &g, &order, 1.0, &mut sum);
                    acc.flush(&mut sum);
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
