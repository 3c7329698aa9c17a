//! The `tri3` inner loop, eight sub-triangles per step: a structure of arrays with one
//! lane per triangle, written branch-free so the compiler emits one AVX2 instruction per
//! operation for all eight (build with `target-cpu=x86-64-v3`, as `.cargo/config.toml`
//! does).
//!
//! For one measurement (laser spot `x_l`, sensor point `x_s`, wall normal `n_w`) and a
//! triangle on the plane `n·x = d` with corners `v_i`:
//!
//! - corner OPL, in bins: `τ_i = (|x_l − v_i| + |v_i − x_s| + legs − start) / width`;
//! - corner weight (the integrand of the `tri3` module doc at `v_i`):
//!   `w_i = (ρ_i/π) cos θ_l cos θ_s cos θ_wall,l cos θ_wall,s / (r_l² r_s²)`. On the plane,
//!   `r_l cos θ_l = n·x_l − d =: p_l` is the same for every corner (likewise `p_s`), and
//!   `r_l cos θ_wall,l = −n_w·(x_l − v_i) =: c_l`, so
//!   `w_i = (ρ_i/π) |p_l p_s| c_l c_s / (r_l² r_s²)²`, with `w_i = 0` where the corner is
//!   behind the wall (`c_l ≤ 0` or `c_s ≤ 0`) and for a triangle that does not face both
//!   wall points (`p_l, p_s > 0`, or `p_l p_s > 0` if two-sided); for a retroreflective
//!   triangle (confocal) the return leg's `|p_s| c_s / r_s⁴` is 1 (per m²);
//! - the curvature shift of the pulse: `0.75 (τ(c) − mean τ_i)`, `c` the centroid;
//! - the pulse constants of [`BoxPulse`].
//!
//! The per-pair equations above live in [`super::tri3_physics`], written once over a lane
//! number type: this kernel runs them in one `f32` per lane, the adjoint
//! ([`super::tri3_adjoint`]) in eight at once.

use super::tri3_physics::{centroid, KeptLegs, Legs, Plane, Wall};
use crate::film::{BoxPulse, Film, PulseLanes, LANES};
use glam::Vec3;

/// Triangles per block: the film's splat width, one AVX2 register of `f32`.
pub const W: usize = LANES;

type Lanes = [f32; W];

/// Eight sub-triangles, one per lane. Padding lanes repeat a real triangle with zero
/// area and albedo, so they compute finite numbers and are never live.
#[derive(Clone, Copy, Debug, Default)]
pub struct TriBlock {
    /// Corner positions, `p[corner][axis][lane]` (m).
    pub p: [[Lanes; 3]; 3],
    /// Unit normal.
    pub n: [Lanes; 3],
    /// Plane offset `n·v` (m).
    pub plane: Lanes,
    /// Area (m²).
    pub area: Lanes,
    /// `ρ/π` at each corner (1/sr).
    pub brdf: [Lanes; 3],
    /// 1 where the triangle reflects on both sides, else 0.
    pub two_sided: Lanes,
    /// 1 where the triangle is retroreflective (confocal only), else 0.
    pub retro: Lanes,
}

/// The measurement's constants, in the units the lanes use.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub x_l: Vec3,
    pub x_s: Vec3,
    pub n_w: Vec3,
    /// `legs − start` (m): added to the hidden-path length to get OPL from the film's start.
    pub offset: f32,
    /// 1 / bin width (1/m).
    pub inv_width: f32,
    /// Pulses entirely outside `[lo, hi)` (bins) cannot reach the film.
    pub lo: f32,
    pub hi: f32,
}

impl Frame {
    pub fn confocal(&self) -> bool {
        self.x_l == self.x_s
    }
}

/// Eight pulses: the box splat's lanes, and the corner weights and areas that the
/// Gaussian splat (`f64`, one pulse at a time) reads besides.
#[derive(Clone, Copy, Debug, Default)]
pub struct PulseBlock {
    pub lanes: PulseLanes,
    /// Corner weights, in the order of `lanes.t`.
    pub w: [Lanes; 3],
    pub area: Lanes,
    /// `order[s][lane]`: which corner is in sorted slot `s` (as `f32`).
    pub order: [Lanes; 3],
}

impl TriBlock {
    #[inline(always)]
    fn corner(&self, i: usize, j: usize) -> [f32; 3] {
        [self.p[i][0][j], self.p[i][1][j], self.p[i][2][j]]
    }

    /// The eight pulses of this block for one measurement. `CONFOCAL` (`x_l == x_s`)
    /// skips the second distance.
    #[inline]
    pub fn pulses<const CONFOCAL: bool>(&self, f: &Frame, out: &mut PulseBlock) {
        self.pulses_keeping::<CONFOCAL, false>(f, out, None);
    }

    /// [`TriBlock::pulses`], keeping the legs and corner weights it computes in `keep` if
    /// `KEEP` (the adjoint's reverse reads them instead of computing them again: the
    /// adjoint 4-6 % faster, measured). `KEEP` is a constant, so the render's instance has
    /// no trace of it; and `#[inline]`, not `#[inline(always)]`: forced into the render's
    /// measurement loop, this loop made the render 2.5-3.3x slower (measured).
    #[inline]
    #[allow(clippy::needless_range_loop)] // lanes by index, as the equations
    pub fn pulses_keeping<const CONFOCAL: bool, const KEEP: bool>(
        &self,
        f: &Frame,
        out: &mut PulseBlock,
        mut keep: Option<&mut KeptLegs>,
    ) {
        let wall = Wall::<f32>::new(f);
        for j in 0..W {
            let retro = self.retro[j] > 0.0;
            let mut tau = [0.0f32; 3];
            let mut vw = [0.0f32; 3];
            for i in 0..3 {
                let legs = Legs::new::<CONFOCAL>(&wall, self.corner(i, j));
                tau[i] = wall.bins(legs.r_l, legs.r_s);
                let k = legs.weight(retro);
                vw[i] = self.brdf[i][j] * k;
                if let (true, Some(kept)) = (KEEP, keep.as_deref_mut()) {
                    kept.legs[i].put(j, &legs);
                    kept.weight[i][j] = k;
                }
            }
            let n = [self.n[0][j], self.n[1][j], self.n[2][j]];
            let two_sided = self.two_sided[j] > 0.0;
            let g = Plane::new::<CONFOCAL>(&wall, n, self.plane[j], two_sided, retro).factor;
            let w = vw.map(|v| g * v);
            // Curvature shift: the pulse's mean moves to (1/12) Σ τ_i + (3/4) τ(c).
            let c = Legs::new::<CONFOCAL>(&wall, centroid([0, 1, 2].map(|i| self.corner(i, j))));
            if let (true, Some(kept)) = (KEEP, keep.as_deref_mut()) {
                kept.legs[3].put(j, &c);
            }
            let tau_c = wall.bins(c.r_l, c.r_s);
            let shift = 0.75 * (tau_c - (tau[0] + tau[1] + tau[2]) * (1.0 / 3.0));
            let (p, order) = BoxPulse::new_ordered(tau.map(|t| t + shift), w, self.area[j]);
            let live = (w[0] + w[1] + w[2] > 0.0) & (p.t[2] >= f.lo) & (p.t[0] < f.hi);
            out.lanes.set(j, &p, live);
            for i in 0..3 {
                out.w[i][j] = p.w[i];
                out.order[i][j] = order[i];
            }
            out.area[j] = self.area[j];
        }
    }
}

/// An order of the triangles with centroids `centroid` such that each run of [`W`] is a
/// compact cluster: the box splat walks the union of a block's OPL ranges (its window)
/// for all eight lanes at once, so neighbours in space make short windows. Recursive
/// splits at the median of the longest axis, at a multiple of `W`; deterministic.
/// (On the wavy-sheet benchmark the mean window falls from 13.8 bins in mesh order to
/// 9.0, against 4.3 for the longest single pulse of a block: `examples/tri3_windows.rs`.)
pub fn block_order(centroid: &[Vec3]) -> Vec<usize> {
    fn split(idx: &mut [usize], c: &[Vec3]) {
        if idx.len() <= W {
            return;
        }
        let (lo, hi) = idx.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), &k| (lo.min(c[k]), hi.max(c[k])),
        );
        let axis = (hi - lo).max_position();
        let mid = idx.len().div_ceil(W) / 2 * W;
        idx.select_nth_unstable_by(mid, |&a, &b| c[a][axis].total_cmp(&c[b][axis]));
        let (left, right) = idx.split_at_mut(mid);
        split(left, c);
        split(right, c);
    }
    let mut idx: Vec<usize> = (0..centroid.len()).collect();
    split(&mut idx, centroid);
    idx
}

/// Packs sub-triangles into blocks of [`W`].
#[allow(clippy::too_many_arguments)]
pub fn pack(
    corners: impl ExactSizeIterator<Item = ([Vec3; 3], [f32; 3])>,
    normal: &[Vec3],
    plane: &[f32],
    area: &[f32],
    two_sided: &[bool],
    retro: &[bool],
) -> Vec<TriBlock> {
    let count = corners.len();
    let mut blocks = vec![TriBlock::default(); count.div_ceil(W)];
    let mut last = None;
    for (k, (v, brdf)) in corners.enumerate() {
        put(
            &mut blocks[k / W],
            k % W,
            v,
            brdf,
            normal[k],
            plane[k],
            area[k],
            two_sided[k],
            retro[k],
        );
        last = Some((v, normal[k], plane[k]));
    }
    if let Some((v, n, d)) = last {
        for k in count..blocks.len() * W {
            put(
                &mut blocks[k / W],
                k % W,
                v,
                [0.0; 3],
                n,
                d,
                0.0,
                false,
                false,
            );
        }
    }
    blocks
}

#[allow(clippy::too_many_arguments)]
fn put(
    b: &mut TriBlock,
    j: usize,
    v: [Vec3; 3],
    brdf: [f32; 3],
    n: Vec3,
    plane: f32,
    area: f32,
    two_sided: bool,
    retro: bool,
) {
    for i in 0..3 {
        for (axis, x) in v[i].to_array().into_iter().enumerate() {
            b.p[i][axis][j] = x;
        }
        b.brdf[i][j] = brdf[i];
        b.n[i][j] = n[i];
    }
    b.plane[j] = plane;
    b.retro[j] = if retro { 1.0 } else { 0.0 };
    b.area[j] = area;
    b.two_sided[j] = if two_sided { 1.0 } else { 0.0 };
}

/// The measurement's frame for the film `film`.
pub fn frame(ctx: &super::MeasurementCtx, film: &Film) -> Frame {
    let inv_width = (1.0 / film.width) as f32;
    let start = film.start as f32;
    Frame {
        x_l: ctx.x_l,
        x_s: ctx.x_s,
        n_w: ctx.n_w,
        offset: ctx.opl_laser_leg(ctx.x_l) + ctx.opl_sensor_leg - start,
        inv_width,
        lo: (ctx.opl_min - start) * inv_width,
        hi: (ctx.opl_max - start) * inv_width,
    }
}
