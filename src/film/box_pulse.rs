//! The triangle pulse of [`super::pulse`] through the `box` kernel, in bin units and
//! `f32`, evaluated eight bin edges at a time: the inner loop of the `tri3` model.
//!
//! With OPLs measured in bins from the film's start (`x = (τ − start) / width`, so bin
//! `k` is `[k, k + 1)`), corners sorted `t0 ≤ t1 ≤ t2`, weights `w_i` and area `A`, the
//! weighted area with OPL below `x` is, up to a constant,
//!
//! `G(x) = P(a) − Q(b) + D·[x > t1]`, with `a = max(min(x, t1) − t0, 0)`,
//! `b = max(t2 − max(x, t1), 0)`,
//!
//! `P(a) = ka a² (3 w0 + ga a)` the corner triangle at `v0` (`ka = A / (3 (t1 − t0)(t2 − t0))`,
//! `ga = (w1 − w0)/(t1 − t0) + (w2 − w0)/(t2 − t0)`), `Q(b)` the same at `v2`, and
//! `D = W − P(t1 − t0) − Q(t2 − t1)` the mass the two pieces miss: zero up to rounding for
//! a proper pulse, everything (`W = A (w0 + w1 + w2)/3`) for a pulse narrower than
//! [`NARROW`] bins, which is a point at `t1`. `G` is branch-free, so bin `k` receives
//! `G(k + 1) − G(k)` for eight pulses in a handful of vector instructions ([`splat_lanes`]);
//! only differences are used, so the constant `Q(t2 − t1)` that makes `G` the CDF is dropped.

use wide::{f32x8, CmpGt};

/// Bins per step of the splat.
pub const LANES: usize = 8;

/// Pieces narrower than this (bins) are folded into the point mass `D`: the shape
/// error is below `NARROW` bins of shift.
pub(super) const NARROW: f32 = 1e-5;

#[inline(always)]
fn min(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

#[inline(always)]
fn max(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// Branch-free `min`/`max` (no NaN handling), so lane loops vectorise.
#[inline(always)]
fn select(c: bool, a: f32, b: f32) -> f32 {
    if c {
        a
    } else {
        b
    }
}

/// A triangle pulse in bin units, ready to splat.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BoxPulse {
    /// Corner OPLs, sorted (bins from the film's start).
    pub t: [f32; 3],
    /// Corner weights, in the order of `t`.
    pub w: [f32; 3],
    /// `P(a) = a² (p0 + p1 a)`: `p0 = 3 ka w0`, `p1 = ka ga`.
    p0: f32,
    p1: f32,
    /// `Q(b) = b² (q0 + q1 b)`: `q0 = 3 kb w2`, `q1 = kb gb`.
    q0: f32,
    q1: f32,
    /// Point mass at `t1` (see the module doc).
    d: f32,
}

impl BoxPulse {
    /// The pulse of a triangle with corner OPLs `t` (bins, any order), corner weights `w`
    /// and area `area`. Branch-free, so a loop of these over lanes vectorises.
    #[inline(always)]
    pub fn new(t: [f32; 3], w: [f32; 3], area: f32) -> Self {
        Self::new_ordered(t, w, area).0
    }

    /// [`BoxPulse::new`], and which input corner went to each sorted slot (as `f32`, so
    /// the lane loops stay branch-free).
    #[inline(always)]
    pub fn new_ordered(t: [f32; 3], w: [f32; 3], area: f32) -> (Self, [f32; 3]) {
        let ([mut t0, mut t1, mut t2], [mut w0, mut w1, mut w2]) = (t, w);
        let [mut i0, mut i1, mut i2] = [0.0f32, 1.0, 2.0];
        let order = |a: (&mut f32, &mut f32, &mut f32), b: (&mut f32, &mut f32, &mut f32)| {
            let swap = *b.0 < *a.0;
            for (x, y) in [(a.0, b.0), (a.1, b.1), (a.2, b.2)] {
                let (lo, hi) = (select(swap, *y, *x), select(swap, *x, *y));
                (*x, *y) = (lo, hi);
            }
        };
        order((&mut t0, &mut w0, &mut i0), (&mut t1, &mut w1, &mut i1));
        order((&mut t1, &mut w1, &mut i1), (&mut t2, &mut w2, &mut i2));
        order((&mut t0, &mut w0, &mut i0), (&mut t1, &mut w1, &mut i1));
        let inv = |d: f32| select(d > NARROW, 1.0 / max(d, NARROW), 0.0);
        let (inv_span, inv_a, inv_b) = (inv(t2 - t0), inv(t1 - t0), inv(t2 - t1));
        let third_area = area * (1.0 / 3.0);
        let (ka, kb) = (third_area * inv_a * inv_span, third_area * inv_b * inv_span);
        let ga = (w1 - w0) * inv_a + (w2 - w0) * inv_span;
        let gb = (w1 - w2) * inv_b + (w0 - w2) * inv_span;
        let mut p = BoxPulse {
            t: [t0, t1, t2],
            w: [w0, w1, w2],
            p0: 3.0 * ka * w0,
            p1: ka * ga,
            q0: 3.0 * kb * w2,
            q1: kb * gb,
            d: 0.0,
        };
        p.d = third_area * (w0 + w1 + w2) - p.lower(t1 - t0) - p.upper(t2 - t1);
        (p, [i0, i1, i2])
    }

    /// The sorted corners, weights and the five constants, for a structure of arrays.
    #[inline(always)]
    pub fn parts(&self) -> ([f32; 3], [f32; 3], [f32; 5]) {
        (self.t, self.w, [self.p0, self.p1, self.q0, self.q1, self.d])
    }

    /// Inverse of [`BoxPulse::parts`].
    #[inline(always)]
    pub fn from_parts(t: [f32; 3], w: [f32; 3], p: [f32; 5]) -> Self {
        let [p0, p1, q0, q1, d] = p;
        BoxPulse {
            t,
            w,
            p0,
            p1,
            q0,
            q1,
            d,
        }
    }

    /// Weighted area of the corner triangle at `v0` with `τ − t0 ≤ a`.
    #[inline(always)]
    fn lower(&self, a: f32) -> f32 {
        a * a * self.p1.mul_add(a, self.p0)
    }

    /// Weighted area of the corner triangle at `v2` with `t2 − τ ≤ b`.
    #[inline(always)]
    fn upper(&self, b: f32) -> f32 {
        b * b * self.q1.mul_add(b, self.q0)
    }

    /// `G(x)` of the module doc.
    #[inline(always)]
    pub fn cdf(&self, x: f32) -> f32 {
        let [t0, t1, t2] = self.t;
        let a = max(min(x, t1) - t0, 0.0);
        let b = max(t2 - max(x, t1), 0.0);
        let step = select(x > t1, self.d, 0.0);
        self.lower(a) - self.upper(b) + step
    }
}

/// Eight pulses, structure of arrays (the fields of [`BoxPulse`], lane `j` in `[j]`):
/// what [`splat_lanes`] reads. A dead lane holds a zero pulse at 0, so it adds exact
/// zeros wherever the splat evaluates it: [`PulseLanes::set`] and [`PulseLanes::kill`],
/// the only writers, keep that so.
#[derive(Clone, Copy, Debug, Default)]
pub struct PulseLanes {
    /// Sorted corner OPLs (bins).
    t: [[f32; LANES]; 3],
    /// `p0, p1, q0, q1, d` of [`BoxPulse`].
    k: [[f32; LANES]; 5],
    /// The lane holds a pulse with weight that can reach the film.
    live: [bool; LANES],
}

impl PulseLanes {
    /// Puts `p` in lane `j`, or a zero pulse unless `live`. A pulse with a non-finite
    /// corner is dead (written so that NaN fails). Branch-free, for lane loops.
    #[inline(always)]
    pub fn set(&mut self, j: usize, p: &BoxPulse, live: bool) {
        let live = live & (p.t[0] >= f32::MIN) & (p.t[2] <= f32::MAX);
        for i in 0..3 {
            self.t[i][j] = select(live, p.t[i], 0.0);
        }
        for (k, v) in self.k.iter_mut().zip([p.p0, p.p1, p.q0, p.q1, p.d]) {
            k[j] = select(live, v, 0.0);
        }
        self.live[j] = live;
    }

    /// Makes lane `j` dead.
    pub fn kill(&mut self, j: usize) {
        self.set(j, &BoxPulse::default(), false);
    }

    /// Sorted corner OPLs (bins), `t[corner][lane]`.
    pub fn t(&self) -> &[[f32; LANES]; 3] {
        &self.t
    }

    pub fn live(&self) -> &[bool; LANES] {
        &self.live
    }
}

/// `G` of the module doc for eight lanes in explicit vectors. (Written with plain
/// lane loops, LLVM vectorises [`splat_window`]'s loop along the bins instead, with
/// every lane's constants broadcast, which is slower.)
struct LaneCdf {
    t: [f32x8; 3],
    k: [f32x8; 5],
}

impl LaneCdf {
    #[inline(always)]
    fn new(p: &PulseLanes) -> Self {
        LaneCdf {
            t: p.t.map(f32x8::new),
            k: p.k.map(f32x8::new),
        }
    }

    /// `G` of lane `j` at `x[j]`; 0 in dead lanes (a zero pulse at 0, no NaN).
    #[inline(always)]
    fn at(&self, x: f32x8) -> f32x8 {
        let [t0, t1, t2] = self.t;
        let [p0, p1, q0, q1, d] = self.k;
        let zero = f32x8::ZERO;
        let a = (x.fast_min(t1) - t0).fast_max(zero);
        let b = (t2 - x.fast_max(t1)).fast_max(zero);
        let step = x.cmp_gt(t1) & d;
        a * a * p1.mul_add(a, p0) - b * b * q1.mul_add(b, q0) + step
    }
}

/// Histogram rows: bin `b`'s value is the sum of `hist[b]` over its eight lanes
/// ([`splat_lanes`] keeps lanes apart so no two of its stores depend on each other).
pub type LaneRow = [f32; LANES];

/// Windows longer than this many bins are splatted lane by lane ([`splat_scatter`]).
pub const MAX_WINDOW: usize = 24;

/// Padding after a measurement's bins that lets [`splat_scatter`] skip its clamps and
/// bounds checks for pulses spanning fewer bins than this.
pub const SPLAT_PAD: usize = 64;

/// Adds the live ones of eight pulses into `hist[..bins]` through the box kernel; bin
/// `b` of the result is `hist[b].iter().sum()`. The pulses' times are in bins from row
/// `base` of `hist` (any whole number: negative before the first row; the `tri3` kernel
/// measures each block's times from its own origin, so they stay small and exact in `f32`).
/// `hist` holds `bins + 1` rows at least (`bins + SPLAT_PAD` for the fast path): rows past
/// `bins` are scratch.
///
/// Bin `b` receives `G(b + 1 − base) − G(b − base)` of every pulse. The eight pulses of a
/// block are neighbouring sub-triangles, so their OPL ranges overlap: over the window of
/// bins that any of them reaches, [`splat_window`] evaluates `G` at each edge for all eight
/// lanes at once and adds the differences to that bin's row with one vector add, no
/// scatter. Wider windows (blocks straddling a fold or a row of the mesh) go to
/// [`splat_scatter`], which walks each pulse's own bins.
#[inline]
pub fn splat_lanes(p: &PulseLanes, base: i64, bins: usize, hist: &mut [LaneRow]) {
    match window_of(p, base, bins) {
        Some((first, window)) if window <= MAX_WINDOW => splat_window(p, base, first, window, hist),
        Some(_) => splat_scatter(p, base, bins, hist),
        None => {}
    }
}

/// The whole bin at or below `t` (bins from `base`), as a row of the histogram: `t` is
/// finite in a live lane, and clamped first so that the conversion is exact.
#[inline(always)]
fn row_of(t: f32, base: i64) -> i64 {
    const FAR: f32 = (1 << 24) as f32;
    t.clamp(-FAR, FAR).floor() as i64 + base
}

/// The rows `first .. first + window` that the live lanes of `p` reach within
/// `[0, bins)`; `None` without a live lane.
#[inline(always)]
fn window_of(p: &PulseLanes, base: i64, bins: usize) -> Option<(usize, usize)> {
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    let mut any = false;
    for j in 0..LANES {
        let live = p.live[j];
        any |= live;
        lo = select(live, min(lo, p.t[0][j]), lo);
        hi = select(live, max(hi, p.t[2][j]), hi);
    }
    if !any || bins == 0 {
        return None;
    }
    let n = bins as i64;
    let first = row_of(lo, base).clamp(0, n);
    let last = row_of(hi, base).clamp(0, n - 1).max(first);
    Some((first as usize, (last + 1 - first).min(n - first) as usize))
}

/// Rows `first .. first + window` of every lane: one vector `G` per edge, one vector add
/// per bin.
#[inline(always)]
fn splat_window(p: &PulseLanes, base: i64, first: usize, window: usize, hist: &mut [LaneRow]) {
    let cdf = LaneCdf::new(p);
    // Edges in the pulses' own bins: whole numbers, exact in f32.
    let mut x = f32x8::splat((first as i64 - base) as f32);
    let mut prev = cdf.at(x);
    for row in &mut hist[first..first + window] {
        x += f32x8::ONE;
        let g = cdf.at(x);
        *row = (f32x8::new(*row) + (g - prev)).to_array();
        prev = g;
    }
}

/// Each lane over its own bins: step `m` evaluates `G` at edge `k_j + m + 1` of every
/// pulse `j` at once (`k_j` the first row at or below the pulse) and adds
/// `G(k_j + m + 1) − G(k_j + m)` to lane `j` of row `k_j + m`.
fn splat_scatter(p: &PulseLanes, base: i64, bins: usize, hist: &mut [LaneRow]) {
    let last = bins as i64;
    let hist_len = hist.len();
    assert!(
        hist_len > bins,
        "splat_scatter: the histogram needs a scratch row"
    );
    let mut first = [last; LANES];
    let mut span = [0i64; LANES];
    for j in 0..LANES {
        let (k0, k2) = (row_of(p.t[0][j], base), row_of(p.t[2][j], base));
        let inside = p.live[j] & (k2 >= 0) & (k0 < last);
        let (k, end) = (k0.clamp(0, last), k2.clamp(0, last));
        first[j] = if inside { k } else { last };
        // Past every edge at or below t2: a point mass at t1 = t2 = k lands in bin k.
        span[j] = if inside { end + 1 - k } else { 0 };
    }
    let steps = span.into_iter().max().unwrap_or(0);
    let cdf = LaneCdf::new(p);
    let edge = |m: i64| f32x8::new(first.map(|k| (k - base + m) as f32));
    let mut prev = cdf.at(edge(0));
    let fast = (steps as usize) < SPLAT_PAD && hist_len >= bins + SPLAT_PAD;
    for m in 0..steps {
        let g = cdf.at(edge(m + 1));
        let add = (g - prev).to_array();
        for (j, add) in add.into_iter().enumerate() {
            let bin = first[j] + m;
            if fast {
                // Lanes past their pulse's end add an exact 0, dead lanes write into the
                // padding: first[j] <= bins and m < steps < SPLAT_PAD.
                debug_assert!((bin as usize) < hist_len);
                // SAFETY: bin < bins + SPLAT_PAD <= hist_len (checked above).
                unsafe { hist.get_unchecked_mut(bin as usize)[j] += add };
            } else {
                hist[bin.min(last) as usize][j] += add;
            }
        }
        prev = g;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::Film;
    use crate::scene::{FilmSpec, KernelSpec};

    /// Against the f64 splat of `pulse.rs` (itself checked against a point cloud).
    #[test]
    fn matches_the_f64_splat() {
        let spec = FilmSpec {
            temporal_bins: 64,
            bin_width_opl: 0.01,
            start_opl: 1.0,
            kernel: KernelSpec::Box,
        };
        let film = Film::new(&spec);
        let cases: [([f64; 3], [f64; 3]); 8] = [
            ([1.2031, 1.2417, 1.2244], [1.0, 1.0, 1.0]),
            ([1.2031, 1.2417, 1.2244], [0.2, 1.7, 0.9]),
            ([1.5, 1.5, 1.537], [0.5, 1.0, 2.0]),
            ([1.30, 1.3413, 1.3413], [1.0, 0.1, 0.6]),
            ([1.0004, 1.0202, 0.998], [1.0, 2.0, 0.0]),
            ([1.3, 1.6, 1.9], [1.0, 0.5, 2.0]),
            ([1.61, 1.6334, 1.65], [0.0, 0.0, 1.0]),
            ([1.4321, 1.4321, 1.4321], [0.3, 0.2, 0.1]),
        ];
        for (t, w) in cases {
            let mut want = vec![0.0f64; 64];
            film.splat_triangle(t, w, 0.3, &mut want);
            let tb = t.map(|x| ((x - 1.0) / 0.01) as f32);
            let got = splat(BoxPulse::new(tb, w.map(|x| x as f32), 0.3), 64);
            // f32 differences of a CDF: a few ulp of the pulse's total per bin.
            let total: f64 = want.iter().sum();
            for b in 0..64 {
                assert!(
                    (got[b] as f64 - want[b]).abs() < 1e-6 * total,
                    "{t:?} {w:?} bin {b}: {} vs {}",
                    got[b],
                    want[b]
                );
            }
        }
    }

    /// The splat through each path: `(window, scatter with padding, scatter clamped)`.
    fn splat_all(pulses: &PulseLanes, bins: usize) -> [Vec<f32>; 3] {
        let sum = |h: Vec<LaneRow>| h[..bins].iter().map(|r| r.iter().sum()).collect();
        let p = *pulses;
        let mut window = vec![[0.0; LANES]; bins + 1];
        if let Some((first, n)) = window_of(&p, 0, bins) {
            splat_window(&p, 0, first, n, &mut window);
        }
        let mut fast = vec![[0.0; LANES]; bins + SPLAT_PAD];
        splat_scatter(&p, 0, bins, &mut fast);
        let mut clamped = vec![[0.0; LANES]; bins + 1];
        splat_scatter(&p, 0, bins, &mut clamped);
        // splat_lanes picks one of them.
        let mut picked = vec![[0.0; LANES]; bins + SPLAT_PAD];
        splat_lanes(pulses, 0, bins, &mut picked);
        let picked: Vec<f32> = sum(picked);
        let all = [sum(window), sum(fast), sum(clamped)];
        assert!(all.contains(&picked));
        all
    }

    fn lanes(pulses: &[BoxPulse], live: &[bool]) -> PulseLanes {
        let mut l = PulseLanes::default();
        for (j, (p, &live)) in pulses.iter().zip(live).enumerate() {
            l.set(j, p, live);
        }
        l
    }

    fn splat(p: BoxPulse, bins: usize) -> Vec<f32> {
        let mut pulses = [BoxPulse::default(); LANES];
        let mut live = [false; LANES];
        // In lane 5, with garbage in the dead lanes.
        pulses[5] = p;
        live[5] = true;
        pulses[2] = BoxPulse::new([1.0, 2.0, f32::NAN], [1.0; 3], 1.0);
        pulses[3] = BoxPulse::new([-1e30, 2.0, f32::INFINITY], [1.0; 3], 1.0);
        let [window, fast, clamped] = splat_all(&lanes(&pulses, &live), bins);
        assert_eq!(fast, clamped, "fast and clamped scatter differ");
        // One pulse: the same edges, the same differences.
        assert_eq!(window, fast, "window and scatter differ");
        window
    }

    /// Times from another base row, by whole bins, give the same bins: before the film's
    /// first row (negative base, the pulse cut there), inside it, through the window and
    /// the scatter.
    #[test]
    fn a_base_row_moves_the_times_by_whole_bins() {
        let bins = 40;
        let pulses = [
            BoxPulse::new([-1.25, 0.5, 2.125], [0.3, 1.1, 0.7], 0.37),
            BoxPulse::new([10.25, 11.5, 12.125], [1.0, 0.5, 2.0], 0.2),
            BoxPulse::new([5.0, 38.5, 45.0], [1.0; 3], 0.5),
        ];
        for live in [[true, true, false], [true, true, true]] {
            let at = |base: i64| {
                let moved: Vec<BoxPulse> = pulses
                    .iter()
                    .map(|p| BoxPulse::new(p.t.map(|t| t - base as f32), p.w, 0.3))
                    .collect();
                let mut h = vec![[0.0; LANES]; bins + SPLAT_PAD];
                splat_lanes(&lanes(&moved, &live), base, bins, &mut h);
                h[..bins]
                    .iter()
                    .map(|r| r.iter().sum())
                    .collect::<Vec<f32>>()
            };
            let want = at(0);
            assert!(want.iter().any(|&v| v > 0.0));
            for base in [-3, 4, 9] {
                assert_eq!(at(base), want, "base {base}, live {live:?}");
            }
        }
    }

    #[test]
    fn clips_at_both_ends_and_ignores_nan() {
        // Straddles the start: only the half with x >= 0 lands, all in bin 0.
        let h = splat(BoxPulse::new([-1.0, 1.0, 0.0], [1.0, 1.0, 1.0], 1.0), 4);
        assert!(
            (h[0] - 0.5).abs() < 1e-6 && h[1..].iter().all(|&v| v == 0.0),
            "{h:?}"
        );
        // Beyond the end: only bin 3, with the part before edge 4.
        let h = splat(BoxPulse::new([3.5, 9.0, 4.0], [1.0; 3], 1.0), 4);
        assert!(h[..3].iter().all(|&v| v == 0.0) && h[3] > 0.0, "{h:?}");
        let h = splat(BoxPulse::new([f32::NAN, 1.0, 2.0], [1.0; 3], 1.0), 4);
        assert!(h.iter().all(|&v| v == 0.0));
    }

    #[test]
    fn bins_outside_pulses_stay_exactly_zero() {
        // Two pulses, one a point mass on an edge: empty bins must be 0, not rounding noise.
        let pulses = [
            BoxPulse::new([3.3, 5.71, 4.2], [0.3, 1.1, 0.7], 0.37),
            BoxPulse::new([7.0, 7.0, 7.0], [1.0; 3], 0.5),
        ];
        for h in splat_all(&lanes(&pulses, &[true, true]), 40) {
            for (b, v) in h.iter().enumerate() {
                assert_eq!(*v == 0.0, !(3..=7).contains(&b) || b == 6, "bin {b}: {v}");
            }
            assert!((h[7] - 0.5).abs() < 1e-7);
        }
    }

    /// Eight overlapping pulses with a dead lane: the window and the scatter agree to
    /// rounding (they sum the same differences in another order), and both match the
    /// sum of single-pulse splats.
    #[test]
    fn window_and_scatter_agree_on_full_blocks() {
        let mut pulses = [BoxPulse::default(); LANES];
        for (j, p) in pulses.iter_mut().enumerate() {
            let s = j as f32;
            *p = BoxPulse::new(
                [10.2 + 0.7 * s, 12.9 + 0.3 * s, 11.4 + 1.1 * s],
                [1.0, 0.5 + 0.1 * s, 2.0],
                0.1 + 0.01 * s,
            );
        }
        let mut live = [true; LANES];
        live[6] = false;
        let [window, fast, clamped] = splat_all(&lanes(&pulses, &live), 48);
        assert_eq!(fast, clamped);
        let mut single = [0.0f32; 48];
        for j in (0..LANES).filter(|&j| live[j]) {
            for (s, v) in single.iter_mut().zip(splat(pulses[j], 48)) {
                *s += v;
            }
        }
        let total: f32 = single.iter().sum();
        for b in 0..48 {
            for h in [&window, &fast] {
                assert!((h[b] - single[b]).abs() <= 1e-6 * total, "bin {b}");
            }
            assert_eq!(window[b] == 0.0, single[b] == 0.0, "bin {b}");
        }
    }
}
