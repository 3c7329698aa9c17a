//! The reverse of the box splat ([`super::box_pulse`]) for eight pulses at once: the
//! `tri3` adjoint kernel's pulse stage (issue 19).
//!
//! As in [`super::pulse_reverse`] (module doc there): `Σ_b δH_b H_b = Σ_k α_k G(k)` over
//! the bin edges `k` (bin units), `α_k = δH_{k−1} − δH_k`, and its gradient needs only the
//! adjoint moments `L_n = Σ α_k z^n` over edges in `(t0, t1]` (`z = k − t0`),
//! `U_n = Σ α_k y^n` over `(t1, t2)` (`y = t2 − k`) and `T = Σ α_k` over `[t2, ∞)`, then
//! [`pulse_grad`], eight lanes at once. `z` and `y` are exact in `f32` past the film's first
//! two bins (an integer edge minus a corner within a factor two of it, Sterbenz).
//!
//! Lanes the forward splats otherwise (a piece narrower than `NARROW`, folded into the
//! point mass `D`), and pulses spanning more than `MAX_EDGES` bin edges, are left to the
//! caller's `f64` path (`Film::triangle_bins_reverse`).

use super::box_pulse::{PulseLanes, LANES, NARROW};
use super::pulse_reverse::{pulse_grad, Moments};
use wide::{f32x8, i32x8, CmpGt, CmpLe, CmpLt};

/// Per lane: `∂/∂(t0, t1, t2, w0, w1, w2, A)` of `Σ_b δH_b H_b` in the sorted slots
/// (`t` in bins), and the lanes left to the caller (`fallback`). Dead lanes hold 0.
pub struct LaneGrad {
    pub g: [[f32; LANES]; 7],
    pub fallback: [bool; LANES],
}

/// Pulses spanning more bin edges than this are left to the caller: the moments' powers
/// of `z` (up to `MAX_EDGES³`) cancel in `f32` (at 45 edges the area slot is 2e-4 off).
const MAX_EDGES: i32 = 16;

/// The reverse of [`super::splat_lanes`] for pulses `p` (times in bins from row `base`)
/// with sorted corner weights `w` and areas `area`, given `adj[b] = δH_b` for the `bins`
/// bins the splat writes.
///
/// Each lane walks only the edges inside its own pulse, `t0 < k < t2` (one to three for
/// the sub-triangles `tri3` makes; the eight lanes step together, as the forward's
/// scatter splat): `α_k = δH_{k−1} − δH_k` from the histogram, and the sum of `α` over the
/// edges at or past `t2` telescopes to `δH_{⌈t2⌉−1}` (bins outside the film count 0).
pub fn reverse_lanes(
    p: &PulseLanes,
    w: &[[f32; LANES]; 3],
    area: &[f32; LANES],
    adj: &[f32],
    base: i64,
    bins: usize,
) -> LaneGrad {
    let t = p.t();
    // Rows of the histogram (edge `k` of the pulses' own bins is row `k + base`).
    let at = |row: i32| {
        if row >= 0 && (row as usize) < bins {
            adj[row as usize]
        } else {
            0.0
        }
    };
    let mut out = LaneGrad {
        g: [[0.0; LANES]; 7],
        fallback: [false; LANES],
    };
    // A block whose base is this far off has no pulse on the film (none is live).
    let Ok(base) = i32::try_from(base) else {
        out.fallback = *p.live();
        return out;
    };
    // Per lane: the pulse's inner edges `lo ..= hi`, and T. Lanes that the f32 splat
    // treats otherwise (a piece folded into the point mass) or that span too many edges
    // go to the caller; the rest get a harmless pulse where they are not proper.
    let (zero, one) = (f32x8::ZERO, f32x8::ONE);
    let [t0, t1, t2] = t.map(f32x8::new);
    let live = f32x8::new(p.live().map(|l| if l { 1.0 } else { 0.0 })).cmp_gt(zero);
    let al = f32x8::new(*area);
    // Clamped to the film's edges, `−base ..= bins − base` in the pulses' own bins
    // (NaN-free: dead lanes hold 0, live ones are finite, `PulseLanes::set`; whole
    // numbers, exact in f32 within 2^24 bins of the film).
    let (film_lo, film_hi) = (
        (-i64::from(base)) as f32,
        (bins as i64 - i64::from(base)) as f32,
    );
    let first = (t0.floor() + one)
        .fast_max(f32x8::splat(film_lo))
        .fast_min(f32x8::splat(film_hi + 1.0));
    let last = (t2.ceil() - one)
        .fast_max(f32x8::splat(film_lo - 1.0))
        .fast_min(f32x8::splat(film_hi));
    let proper = live
        & (t1 - t0).fast_min(t2 - t1).cmp_gt(f32x8::splat(NARROW))
        & al.cmp_gt(zero)
        & (last - first).cmp_lt(f32x8::splat(MAX_EDGES as f32));
    let (proper_at, live_at) = (proper.move_mask(), live.move_mask());
    for (j, f) in out.fallback.iter_mut().enumerate() {
        *f = (live_at & !proper_at) >> j & 1 == 1;
    }
    if proper_at == 0 {
        return out;
    }
    // As rows (within `-1 ..= bins + 1`).
    let shift = i32x8::splat(base);
    let (first, last) = (
        (first.round_int() + shift).to_array(),
        (last.round_int() + shift).to_array(),
    );
    // Lanes that are not proper walk no edge and read nothing.
    let lo: [i32; LANES] =
        std::array::from_fn(|j| if proper_at >> j & 1 == 1 { first[j] } else { 0 });
    let hi: [i32; LANES] =
        std::array::from_fn(|j| if proper_at >> j & 1 == 1 { last[j] } else { -1 });
    // δH_{⌈t2⌉−1}, which is δH_last (0 past the film's last bin).
    let top = f32x8::new(hi.map(at)) & proper;
    let (t0, t1, t2) = (
        proper.blend(t0, zero),
        proper.blend(t1, one),
        proper.blend(t2, f32x8::splat(2.0)),
    );
    let wl = w.map(|w| f32x8::new(w) & proper);
    let al = proper.blend(al, one);
    let lanes = |f: [f32; LANES]| f32x8::new(f);
    let mut m = Moments {
        lower: [zero; 4],
        upper: [zero; 4],
        top,
    };
    let steps = (0..LANES).map(|j| hi[j] + 1 - lo[j]).max().unwrap_or(0);
    let mut prev: [f32; LANES] = std::array::from_fn(|j| at(lo[j] - 1));
    for step in 0..steps {
        let k: [i32; LANES] = std::array::from_fn(|j| lo[j] + step);
        let next: [f32; LANES] = std::array::from_fn(|j| at(k[j]));
        // Lanes past their last inner edge add nothing.
        let alpha: [f32; LANES] = std::array::from_fn(|j| {
            if k[j] <= hi[j] {
                prev[j] - next[j]
            } else {
                0.0
            }
        });
        prev = next;
        // The edge in the pulses' own bins.
        let x = (i32x8::new(k) - shift).round_float();
        let a = lanes(alpha);
        let lower = x.cmp_le(t1);
        add_powers(&mut m.lower, a & lower, x - t0);
        add_powers(&mut m.upper, a & !lower, t2 - x);
    }
    out.g = pulse_grad([t0, t1, t2], wl, al, &m).map(|g| (g & proper).to_array());
    out
}

/// `acc[n] += α z^n`, `n = 0..3`, with `α` already masked to the piece.
#[inline(always)]
fn add_powers(acc: &mut [f32x8; 4], alpha: f32x8, z: f32x8) {
    let az = alpha * z;
    let az2 = az * z;
    acc[0] += alpha;
    acc[1] += az;
    acc[2] += az2;
    acc[3] += az2 * z;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::film::{BoxPulse, Film};
    use crate::scene::{FilmSpec, KernelSpec};

    /// Against the `f64` reverse (`Film::triangle_bins_reverse`, itself checked against
    /// dual numbers) on a film of unit bins: blocks of overlapping pulses, with a dead lane,
    /// a lane cut at the film's start, a near-tie lane (left to the caller) and a window too
    /// wide for the lanes.
    #[test]
    fn matches_the_f64_reverse() {
        let bins = 256;
        let film = Film::new(&FilmSpec {
            temporal_bins: bins as u32,
            bin_width_opl: 1.0,
            start_opl: 0.0,
            kernel: KernelSpec::Box,
        });
        let adj: Vec<f32> = (0..bins)
            .map(|b| ((b * 7 % 11) as f32 - 5.0) * 0.1)
            .collect();
        // Spread 1: pulses of one to three bins; 4: up to 13 bins; 30: up to 120 bins,
        // beyond the lanes' MAX_EDGES; one past the film's end.
        for spread in [1.0f32, 4.0, 30.0] {
            let mut lanes = PulseLanes::default();
            let (mut w, mut area) = ([[0.0f32; LANES]; 3], [0.0f32; LANES]);
            let mut pulses = Vec::new();
            for j in 0..LANES {
                let s = j as f32;
                let mut t = [2.2 + 0.7 * s, 4.9 + 0.3 * s, 3.4 + 1.1 * s].map(|t| t * spread);
                if j == 2 {
                    t = [-1.3, 0.4, 1.7];
                }
                if j == 4 {
                    t = [10.0, 10.0 + 2e-6, 11.5];
                }
                if j == 5 {
                    t = [254.3, 255.1, 257.7];
                }
                let p = BoxPulse::new(t, [1.0, 0.5 + 0.1 * s, 2.0], 0.1 + 0.01 * s);
                lanes.set(j, &p, j != 6);
                for (w, pw) in w.iter_mut().zip(p.w) {
                    w[j] = pw;
                }
                area[j] = 0.1 + 0.01 * s;
                pulses.push(p);
            }
            let got = reverse_lanes(&lanes, &w, &area, &adj, 0, bins);
            assert!(got.fallback[4] && !got.fallback[6], "{:?}", got.fallback);
            let fell = got.fallback.iter().filter(|&&f| f).count();
            assert_eq!(fell > 1, spread > 4.0, "{:?}", got.fallback);
            for (j, p) in pulses.iter().enumerate() {
                if j == 6 || got.fallback[j] {
                    assert!((0..7).all(|i| got.g[i][j] == 0.0), "lane {j}");
                    continue;
                }
                let want = film.triangle_bins_reverse(
                    p.t.map(f64::from),
                    p.w.map(f64::from),
                    area[j] as f64,
                    |b| adj[b] as f64,
                );
                let scale = want.iter().fold(1e-30f64, |m, g| m.max(g.abs()));
                for (i, (got, want)) in got.g.iter().map(|g| g[j]).zip(want).enumerate() {
                    let err = (got as f64 - want).abs() / scale;
                    assert!(
                        err < 2e-5,
                        "spread {spread} lane {j} slot {i}: {got} vs {want} ({err:e})"
                    );
                }
            }
        }
    }
}
