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

/// Bins per step of the splat.
pub const LANES: usize = 8;

/// Pieces narrower than this (bins) are folded into the point mass `D`: the shape
/// error is below `NARROW` bins of shift.
const NARROW: f32 = 1e-5;

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
        let ([mut t0, mut t1, mut t2], [mut w0, mut w1, mut w2]) = (t, w);
        let order = |ta: &mut f32, tb: &mut f32, wa: &mut f32, wb: &mut f32| {
            let swap = *tb < *ta;
            let (t_lo, t_hi) = (select(swap, *tb, *ta), select(swap, *ta, *tb));
            let (w_lo, w_hi) = (select(swap, *wb, *wa), select(swap, *wa, *wb));
            (*ta, *tb, *wa, *wb) = (t_lo, t_hi, w_lo, w_hi);
        };
        order(&mut t0, &mut t1, &mut w0, &mut w1);
        order(&mut t1, &mut t2, &mut w1, &mut w2);
        order(&mut t0, &mut t1, &mut w0, &mut w1);
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
        p
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

/// Step `m` of [`splat_lanes`]: `G(k_j + m + 1) − G(k_j + m)` for every lane.
#[inline(always)]
fn step(
    pulses: &[BoxPulse; LANES],
    first: &[i32; LANES],
    prev: &mut [f32; LANES],
    m: i32,
) -> [f32; LANES] {
    let mut add = [0.0f32; LANES];
    for j in 0..LANES {
        let g = pulses[j].cdf((first[j] + m + 1) as f32);
        add[j] = g - prev[j];
        prev[j] = g;
    }
    add
}

/// Padding after a measurement's bins that lets [`splat_lanes`] skip its clamps and
/// bounds checks for pulses spanning fewer bins than this.
pub const SPLAT_PAD: usize = 64;

/// Adds the live ones of eight pulses into `hist[..bins]` through the box kernel.
/// `hist` holds `bins + 1` values at least (`bins + SPLAT_PAD` for the fast path): past
/// `bins` is scratch that takes dead lanes and the (exactly zero) differences past a
/// pulse's end.
///
/// Lanes stay lanes: step `m` evaluates `G` at edge `k_j + m + 1` of every pulse `j` at
/// once (`k_j` the first edge at or below the pulse) and adds `G(k_j + m + 1) − G(k_j + m)`
/// to bin `k_j + m`, so eight pulses cost their longest one's bin count in vector steps
/// plus one scalar add per lane and step. (Measured alternatives: one pulse at a time
/// with eight bins per vector is slower, as neighbouring pulses' overlapping vector
/// stores to the histogram stall on store forwarding.)
#[inline]
pub fn splat_lanes(
    pulses: &[BoxPulse; LANES],
    live: &[bool; LANES],
    bins: usize,
    hist: &mut [f32],
) {
    let last = bins as i32;
    let hist_len = hist.len();
    assert!(
        hist_len > bins,
        "splat_lanes: the histogram needs a scratch slot"
    );
    let nbins = bins as f32;
    let mut first = [last; LANES];
    let mut span = [0i32; LANES];
    for j in 0..LANES {
        let [t0, _, t2] = pulses[j].t;
        // Written to reject NaN too; then both clamp into [0, bins] and convert exactly.
        let inside = live[j] & (t2 >= 0.0) & (t0 < nbins);
        // Clamped into [0, bins] whatever t0 and t2 are (NaN included: the comparisons
        // then pick the bound), so the conversions are exact and never out of range.
        let (lo, hi) = (min(max(t0, 0.0), nbins), max(min(t2, nbins), 0.0));
        // SAFETY: lo and hi are finite and in [0, bins], which i32 represents.
        let (k, end) = unsafe { (lo.to_int_unchecked::<i32>(), hi.to_int_unchecked::<i32>()) };
        first[j] = if inside { k } else { last };
        // Past every edge at or below t2: a point mass at t1 = t2 = k lands in bin k.
        span[j] = if inside { end + 1 - k } else { 0 };
    }
    let mut steps = 0;
    for s in span {
        steps = if s > steps { s } else { steps };
    }
    let mut prev = [0.0f32; LANES];
    for j in 0..LANES {
        prev[j] = pulses[j].cdf(first[j] as f32);
    }
    if (steps as usize) < SPLAT_PAD && hist_len >= bins + SPLAT_PAD {
        // Every index first[j] + m is at most bins + steps - 1 < hist_len: lanes past
        // their pulse's end add an exact 0, dead lanes write into the padding.
        for m in 0..steps {
            let add = step(pulses, &first, &mut prev, m);
            for (j, a) in add.into_iter().enumerate() {
                let i = (first[j] + m) as usize;
                debug_assert!(i < hist_len);
                // SAFETY: first[j] <= bins and m < steps < SPLAT_PAD, so
                // i < bins + SPLAT_PAD <= hist_len (checked above).
                unsafe { *hist.get_unchecked_mut(i) += a };
            }
        }
    } else {
        for m in 0..steps {
            let add = step(pulses, &first, &mut prev, m);
            for (j, a) in add.into_iter().enumerate() {
                let bin = first[j] + m;
                hist[if bin < last { bin } else { last } as usize] += a;
            }
        }
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

    /// `pad` selects the fast path (SPLAT_PAD) or the clamped one (1).
    fn splat_all(
        pulses: &[BoxPulse; LANES],
        live: &[bool; LANES],
        bins: usize,
        pad: usize,
    ) -> Vec<f32> {
        let mut h = vec![0.0; bins + pad];
        splat_lanes(pulses, live, bins, &mut h);
        h.truncate(bins);
        h
    }

    fn splat(p: BoxPulse, bins: usize) -> Vec<f32> {
        let mut pulses = [BoxPulse::default(); LANES];
        let mut live = [false; LANES];
        // In lane 5, with garbage in the dead lanes.
        pulses[5] = p;
        live[5] = true;
        pulses[2] = BoxPulse::new([1.0, 2.0, f32::NAN], [1.0; 3], 1.0);
        let fast = splat_all(&pulses, &live, bins, SPLAT_PAD);
        assert_eq!(
            fast,
            splat_all(&pulses, &live, bins, 1),
            "fast and clamped paths differ"
        );
        fast
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
        let mut pulses = [BoxPulse::default(); LANES];
        pulses[0] = BoxPulse::new([3.3, 5.71, 4.2], [0.3, 1.1, 0.7], 0.37);
        pulses[1] = BoxPulse::new([7.0, 7.0, 7.0], [1.0; 3], 0.5);
        let mut h = vec![0.0; 41];
        splat_lanes(
            &pulses,
            &[true, true, false, false, false, false, false, false],
            40,
            &mut h,
        );
        for (b, v) in h.iter().enumerate() {
            assert_eq!(*v == 0.0, !(3..=7).contains(&b) || b == 6, "bin {b}: {v}");
        }
        assert!((h[7] - 0.5).abs() < 1e-7);
    }
}
