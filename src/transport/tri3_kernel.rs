//! The `tri3` inner loop, eight sub-triangles per step: a structure of arrays with one
//! lane per triangle, written branch-free so the compiler emits one AVX2 instruction per
//! operation for all eight (build with `target-cpu=x86-64-v3`, as `.cargo/config.toml`
//! does).
//!
//! For one measurement (laser spot `x_l`, sensor point `x_s`, wall normal `n_w`) and a
//! triangle on the plane `n·x = d` with corners `v_i`:
//!
//! - corner OPL, in bins: `τ_i = (|x_l − v_i| + |v_i − x_s| + legs − start) / width`,
//!   computed as `τ_o + (δ_l + δ_s) / width` from the block's origin `o`
//!   ([`BlockFrame`]): `τ_o` (in `f64`, from a whole bin `base`) and the leg differences
//!   `δ = |x − v| − |x − o| = e / (|x − v| + |x − o|)` with the squared-distance excess
//!   `e = |x − v|² − |x − o|² = q·(q − 2a)`, `q = v − o`, `a = x − o`: accurate in `f32`
//!   to their own size. (Summed in `f32` from lengths of ~1 m, the
//!   times of a film's bins ~150 carry ~1e-5 bins of rounding: on sub-triangles whose
//!   pulses are 1e-3 bins wide, a percent of their width, and of the box kernel's
//!   gradient where they straddle a bin edge.)
//! - corner weight (the integrand of the `tri3` module doc at `v_i`):
//!   `w_i = (ρ_i/π) cos θ_l cos θ_s cos θ_wall,l cos θ_wall,s / (r_l² r_s²)`. On the plane,
//!   `r_l cos θ_l = n·x_l − d =: p_l` is the same for every corner (likewise `p_s`), and
//!   `r_l cos θ_wall,l = −n_w·(x_l − v_i) =: c_l`, so
//!   `w_i = (ρ_i/π) |p_l p_s| c_l c_s / (r_l² r_s²)²`, with `w_i = 0` where the corner is
//!   behind the wall (`c_l ≤ 0` or `c_s ≤ 0`) and for a triangle that does not face both
//!   wall points (`p_l, p_s > 0`, or `p_l p_s > 0` if two-sided); for a retroreflective
//!   triangle (confocal) the return leg's `|p_s| c_s / r_s⁴` is 1 (per m²), and its
//!   angular falloff `m` multiplies the weight by `cos^m θ_l = (|p_l| / r_l)^m`;
//! - the curvature shift of the pulse: `0.75 (τ(c) − mean τ_i)`, `c` the centroid;
//! - the pulse constants of [`BoxPulse`].
//!
//! The per-pair equations above live in [`super::tri3_physics`], written once over a lane
//! number type: this kernel runs them in one `f32` per lane, the adjoint
//! ([`super::tri3_adjoint`]) in eight at once.

use super::tri3_physics::{centroid, dot, KeptLegs, Legs, Plane, Wall};
use crate::film::{BoxPulse, Film, PulseLanes, LANES};
use glam::{DVec3, Vec3};

/// Triangles per block: the film's splat width, one AVX2 register of `f32`.
pub const W: usize = LANES;

type Lanes = [f32; W];

/// Eight sub-triangles, one per lane. Padding lanes repeat a real triangle with zero
/// area and albedo, so they compute finite numbers and are never live.
#[derive(Clone, Copy, Debug, Default)]
pub struct TriBlock {
    /// Corner positions from the block's origin, `v − o`, `p[corner][axis][lane]` (m).
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
    /// A retroreflector's angular falloff exponent `m` (`cos^m θ_x`), else 0.
    pub falloff: Lanes,
}

/// The measurement's constants, in the units the lanes use.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub x_l: Vec3,
    pub x_s: Vec3,
    pub n_w: Vec3,
    /// `legs − start` (m): added to the hidden-path length to get OPL from the film's start.
    pub offset: f64,
    /// 1 / bin width (1/m).
    pub inv_width: f64,
    /// Pulses entirely outside `[lo, hi)` (bins) cannot reach the film.
    pub lo: f64,
    pub hi: f64,
    /// The bins the pulses are splatted into, `0 .. bins`.
    pub bins: usize,
}

impl Frame {
    pub fn confocal(&self) -> bool {
        self.x_l == self.x_s
    }
}

/// A block's origin `o` in one measurement: what its pulse times are measured from.
#[derive(Clone, Copy, Debug, Default)]
pub struct BlockFrame {
    /// `x_l − o`, `x_s − o` (m).
    pub o_l: Vec3,
    pub o_s: Vec3,
    /// `|x_l − o|`, `|x_s − o|` (m, rounded from `f64`).
    pub r_l: f32,
    pub r_s: f32,
    /// The OPL of `o`, in bins from `base` (from `f64`).
    pub tau: f32,
    /// The frame's bin that the block's pulse times count from (negative before the
    /// film's first).
    pub base: i64,
    /// The frame's `lo`, `hi` from `base`.
    pub lo: f32,
    pub hi: f32,
}

/// [`BlockFrame`]s of a run of blocks for one measurement, structure of arrays, computed
/// together so that their `f64` arithmetic runs in vector lanes (one block at a time, in
/// scalar `f64`, it was 13 % of the render's samples).
#[derive(Clone, Debug, Default)]
pub struct BlockFrames {
    o_l: [Vec<f32>; 3],
    o_s: [Vec<f32>; 3],
    r_l: Vec<f32>,
    r_s: Vec<f32>,
    tau: Vec<f32>,
    /// Whole bins, as `f64` (converted per block: AVX2 has no packed `f64` to `i64`).
    base: Vec<f64>,
}

impl BlockFrames {
    /// The frames of the blocks with origins `(x[k], y[k], z[k])` (m).
    pub fn compute(&mut self, f: &Frame, x: &[f64], y: &[f64], z: &[f64]) {
        let n = x.len().min(y.len()).min(z.len());
        let fields = [&mut self.r_l, &mut self.r_s, &mut self.tau];
        for v in fields.into_iter().chain(&mut self.o_l).chain(&mut self.o_s) {
            v.resize(n, 0.0);
        }
        self.base.resize(n, 0.0);
        let (xl, xs) = (f.x_l.as_dvec3(), f.x_s.as_dvec3());
        let confocal = f.confocal();
        let [olx, oly, olz] = &mut self.o_l;
        let [osx, osy, osz] = &mut self.o_s;
        let (olx, oly, olz) = (&mut olx[..n], &mut oly[..n], &mut olz[..n]);
        let (osx, osy, osz) = (&mut osx[..n], &mut osy[..n], &mut osz[..n]);
        let (r_l, r_s) = (&mut self.r_l[..n], &mut self.r_s[..n]);
        let (tau, base) = (&mut self.tau[..n], &mut self.base[..n]);
        for k in 0..n {
            let o = DVec3::new(x[k], y[k], z[k]);
            let (a_l, a_s) = (xl - o, xs - o);
            let rl = a_l.length();
            let rs = if confocal { rl } else { a_s.length() };
            let t = (rl + rs + f.offset) * f.inv_width;
            // The origin's bin (times from it stay within a block's extent, small and
            // exact in f32; the splat takes them from there).
            let b = t.clamp(-1e15, 1e15).floor();
            (olx[k], oly[k], olz[k]) = (a_l.x as f32, a_l.y as f32, a_l.z as f32);
            (osx[k], osy[k], osz[k]) = (a_s.x as f32, a_s.y as f32, a_s.z as f32);
            (r_l[k], r_s[k]) = (rl as f32, rs as f32);
            (tau[k], base[k]) = ((t - b) as f32, b);
        }
    }

    /// Block `k` of the run.
    #[inline(always)]
    pub fn get(&self, f: &Frame, k: usize) -> BlockFrame {
        let at = |v: &[Vec<f32>; 3]| Vec3::new(v[0][k], v[1][k], v[2][k]);
        let base = self.base[k];
        BlockFrame {
            o_l: at(&self.o_l),
            o_s: at(&self.o_s),
            r_l: self.r_l[k],
            r_s: self.r_s[k],
            tau: self.tau[k],
            base: base as i64,
            lo: (f.lo - base) as f32,
            hi: (f.hi - base) as f32,
        }
    }
}

/// Eight pulses: the box splat's lanes, and the corner weights and areas that the
/// Gaussian splat (`f64`, one pulse at a time) reads besides.
#[derive(Clone, Copy, Debug, Default)]
pub struct PulseBlock {
    /// The times of `lanes` are in bins from the frame's bin `base` (the bin of the
    /// block's origin; negative before the film's first).
    pub base: i64,
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
    pub fn pulses<const CONFOCAL: bool>(
        &self,
        f: &Frame,
        block: &BlockFrame,
        out: &mut PulseBlock,
    ) {
        self.pulses_keeping::<CONFOCAL, false>(f, block, out, None);
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
        block: &BlockFrame,
        out: &mut PulseBlock,
        keep: Option<&mut KeptLegs>,
    ) {
        // A block without angular falloff (every Lambertian one) runs the loop without it
        // (inside the loop, the test cost the render 8 %, measured).
        if self.falloff.iter().any(|&m| m > 0.0) {
            self.lanes::<CONFOCAL, KEEP, true>(f, block, out, keep);
        } else {
            self.lanes::<CONFOCAL, KEEP, false>(f, block, out, keep);
        }
    }

    /// [`TriBlock::pulses_keeping`]'s loop over the lanes; `FALLOFF`: some lane has a
    /// retroreflector's angular falloff.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // lanes by index, as the equations
    fn lanes<const CONFOCAL: bool, const KEEP: bool, const FALLOFF: bool>(
        &self,
        f: &Frame,
        block: &BlockFrame,
        out: &mut PulseBlock,
        mut keep: Option<&mut KeptLegs>,
    ) {
        let wall = Wall::<f32>::new(f, block);
        out.base = block.base;
        for j in 0..W {
            let retro = self.retro[j] > 0.0;
            let n = [self.n[0][j], self.n[1][j], self.n[2][j]];
            let mut tau = [0.0f32; 3];
            let mut vw = [0.0f32; 3];
            for i in 0..3 {
                let q = self.corner(i, j);
                let legs = Legs::new::<CONFOCAL>(&wall, q);
                tau[i] = wall.bins::<CONFOCAL>(&legs);
                let mut k = legs.weight::<CONFOCAL>(retro);
                if FALLOFF {
                    let p_l = dot(n, wall.x_l) - self.plane[j];
                    k *= legs.falloff(p_l, self.falloff[j]);
                }
                vw[i] = self.brdf[i][j] * k;
                if let (true, Some(kept)) = (KEEP, keep.as_deref_mut()) {
                    kept.legs[i].put::<CONFOCAL>(j, &legs);
                    kept.weight[i][j] = k;
                }
            }
            let two_sided = self.two_sided[j] > 0.0;
            let g = Plane::new::<CONFOCAL>(&wall, n, self.plane[j], two_sided, retro).factor;
            let w = vw.map(|v| g * v);
            // Curvature shift: the pulse's mean moves to (1/12) Σ τ_i + (3/4) τ(c).
            let q = centroid([0, 1, 2].map(|i| self.corner(i, j)));
            let c = Legs::new::<CONFOCAL>(&wall, q);
            if let (true, Some(kept)) = (KEEP, keep.as_deref_mut()) {
                kept.legs[3].put::<CONFOCAL>(j, &c);
            }
            let tau_c = wall.bins::<CONFOCAL>(&c);
            let shift = 0.75 * (tau_c - (tau[0] + tau[1] + tau[2]) * (1.0 / 3.0));
            let (p, order) = BoxPulse::new_ordered(tau.map(|t| t + shift), w, self.area[j]);
            let live = (w[0] + w[1] + w[2] > 0.0) & (p.t[2] >= block.lo) & (p.t[0] < block.hi);
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

/// Packs sub-triangles into blocks of [`W`]: `corners` in `f64` (the sub-triangle's
/// corners from its original triangle's, the lanes store them from the block's origin).
/// Returns the blocks and their origins `o` (the mean of each block's corners, m), by
/// axis: what [`BlockFrames::compute`] reads.
#[allow(clippy::too_many_arguments)]
pub fn pack(
    corners: impl ExactSizeIterator<Item = ([DVec3; 3], [f32; 3])>,
    normal: &[Vec3],
    plane: &[f32],
    area: &[f32],
    two_sided: &[bool],
    retro: &[bool],
    falloff: &[f32],
) -> (Vec<TriBlock>, [Vec<f64>; 3]) {
    let count = corners.len();
    let corners: Vec<_> = corners.collect();
    let mut blocks = vec![TriBlock::default(); count.div_ceil(W)];
    let origin: Vec<DVec3> = corners
        .chunks(W)
        .map(|own| own.iter().flat_map(|(v, _)| v).sum::<DVec3>() / (3 * own.len()) as f64)
        .collect();
    let mut last = None;
    for (k, &(v, brdf)) in corners.iter().enumerate() {
        put(
            &mut blocks[k / W],
            origin[k / W],
            k % W,
            v,
            brdf,
            normal[k],
            plane[k],
            area[k],
            two_sided[k],
            (retro[k], falloff[k]),
        );
        last = Some((v, normal[k], plane[k]));
    }
    if let Some((v, n, d)) = last {
        for k in count..blocks.len() * W {
            put(
                &mut blocks[k / W],
                origin[k / W],
                k % W,
                v,
                [0.0; 3],
                n,
                d,
                0.0,
                false,
                (false, 0.0),
            );
        }
    }
    let by_axis = [0, 1, 2].map(|axis| origin.iter().map(|o| o[axis]).collect());
    (blocks, by_axis)
}

#[allow(clippy::too_many_arguments)]
fn put(
    b: &mut TriBlock,
    o: DVec3,
    j: usize,
    v: [DVec3; 3],
    brdf: [f32; 3],
    n: Vec3,
    plane: f32,
    area: f32,
    two_sided: bool,
    (retro, falloff): (bool, f32),
) {
    for i in 0..3 {
        for (axis, x) in (v[i] - o).to_array().into_iter().enumerate() {
            b.p[i][axis][j] = x as f32;
        }
        b.brdf[i][j] = brdf[i];
        b.n[i][j] = n[i];
    }
    b.plane[j] = plane;
    b.retro[j] = if retro { 1.0 } else { 0.0 };
    b.falloff[j] = if retro { falloff } else { 0.0 };
    b.area[j] = area;
    b.two_sided[j] = if two_sided { 1.0 } else { 0.0 };
}

/// The measurement's frame for the film `film`.
pub fn frame(ctx: &super::MeasurementCtx, film: &Film) -> Frame {
    let inv_width = 1.0 / film.width;
    let start = film.start;
    Frame {
        x_l: ctx.x_l,
        x_s: ctx.x_s,
        n_w: ctx.n_w,
        offset: f64::from(ctx.opl_laser_leg(ctx.x_l) + ctx.opl_sensor_leg) - start,
        inv_width,
        lo: (f64::from(ctx.opl_min) - start) * inv_width,
        hi: (f64::from(ctx.opl_max) - start) * inv_width,
        bins: film.bins,
    }
}
