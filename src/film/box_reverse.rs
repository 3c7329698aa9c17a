//! The reverse of the box splat ([`super::box_pulse`]) for eight pulses at once: the
//! `tri3` adjoint kernel's pulse stage (issue 19).
//!
//! As in [`super::pulse_reverse`] (module doc there): `Σ_b δH_b H_b = Σ_k α_k G(k)` over
//! the bin edges `k` (bin units), `α_k = δH_{k−1} − δH_k`, and its gradient needs only the
//! adjoint moments `L_n = Σ α_k z^n` over edges in `(t0, t1]` (`z = k − t0`),
//! `U_n = Σ α_k y^n` over `(t1, t2)` (`y = t2 − k`) and `T = Σ α_k` over `[t2, ∞)`, then
//! [`pulse_grad`]. The eight pulses of a block share the window of bins the forward
//! splat walks ([`super::box_pulse::splat_lanes`]), so `α_k` is read once per edge for all
//! lanes, and each lane masks the edge into its pieces. `z` and `y` are exact in `f32`
//! (an integer edge minus a corner within a factor two of it).
//!
//! Lanes the forward splats otherwise (a piece narrower than `NARROW`, folded into the
//! point mass `D`), and every lane of a block whose window is wider than `MAX_WINDOW`
//! bins, are left to the caller's `f64` path (`Film::triangle_bins_reverse`).

use super::box_pulse::{window_of, PulseLanes, LANES, MAX_WINDOW, NARROW};
use super::pulse_reverse::{pulse_grad, Moments};
use wide::{f32x8, CmpGe, CmpGt, CmpLe, CmpLt};

/// Per lane: `∂/∂(t0, t1, t2, w0, w1, w2, A)` of `Σ_b δH_b H_b` in the sorted slots
/// (`t` in bins), and the lanes left to the caller (`fallback`). Dead lanes hold 0.
pub struct LaneGrad {
    pub g: [[f32; LANES]; 7],
    pub fallback: [bool; LANES],
}

/// The reverse of [`super::splat_lanes`] for pulses `p` with sorted corner weights `w`
/// and areas `area`, given `adj[b] = δH_b` for the `bins` bins the splat writes.
pub fn reverse_lanes(
    p: &PulseLanes,
    w: &[[f32; LANES]; 3],
    area: &[f32; LANES],
    adj: &[f32],
    bins: usize,
) -> LaneGrad {
    let live = *p.live();
    let mut out = LaneGrad {
        g: [[0.0; LANES]; 7],
        fallback: [false; LANES],
    };
    let Some((first, window)) = window_of(p, bins) else {
        return out;
    };
    if window > MAX_WINDOW {
        out.fallback = live;
        return out;
    }
    let t = p.t();
    // Lanes with both pieces present; the others get a harmless pulse and are zeroed.
    let mut proper = [false; LANES];
    for j in 0..LANES {
        let piece = (t[1][j] - t[0][j]).min(t[2][j] - t[1][j]);
        proper[j] = live[j] & (piece > NARROW) & (area[j] > 0.0);
        out.fallback[j] = live[j] & !proper[j];
    }
    let pick = |v: f32, j: usize, safe: f32| if proper[j] { v } else { safe };
    let lanes = |f: &dyn Fn(usize) -> f32| f32x8::new(std::array::from_fn(f));
    let [t0, t1, t2] = [0, 1, 2].map(|i| lanes(&|j| pick(t[i][j], j, i as f32)));
    let wl = [0, 1, 2].map(|i| lanes(&|j| pick(w[i][j], j, 0.0)));
    let al = lanes(&|j| pick(area[j], j, 1.0));
    let zero = f32x8::ZERO;
    let mut m = Moments {
        lower: [zero; 4],
        upper: [zero; 4],
        top: zero,
    };
    let mut prev = 0.0f32;
    let edges = adj[first..first + window].iter().chain([&0.0]);
    for (k, &next) in (first..).zip(edges) {
        let alpha = prev - next;
        prev = next;
        if alpha == 0.0 {
            continue;
        }
        let (a, x) = (f32x8::splat(alpha), f32x8::splat(k as f32));
        let lower = a & (x.cmp_gt(t0) & x.cmp_le(t1));
        let upper = a & (x.cmp_gt(t1) & x.cmp_lt(t2));
        m.top += a & x.cmp_ge(t2);
        let (z, y) = (x - t0, t2 - x);
        add_powers(&mut m.lower, lower, z);
        add_powers(&mut m.upper, upper, y);
    }
    let g = pulse_grad([t0, t1, t2], wl, al, &m).map(|g| g.to_array());
    for (slot, g) in out.g.iter_mut().zip(g) {
        for j in 0..LANES {
            slot[j] = if proper[j] { g[j] } else { 0.0 };
        }
    }
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
        let bins = 64;
        let film = Film::new(&FilmSpec {
            temporal_bins: bins as u32,
            bin_width_opl: 1.0,
            start_opl: 0.0,
            kernel: KernelSpec::Box,
        });
        let adj: Vec<f32> = (0..bins)
            .map(|b| ((b * 7 % 11) as f32 - 5.0) * 0.1)
            .collect();
        for (spread, expect_fallback) in [(1.0f32, false), (6.0, true)] {
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
                let p = BoxPulse::new(t, [1.0, 0.5 + 0.1 * s, 2.0], 0.1 + 0.01 * s);
                lanes.set(j, &p, j != 6);
                for (w, pw) in w.iter_mut().zip(p.w) {
                    w[j] = pw;
                }
                area[j] = 0.1 + 0.01 * s;
                pulses.push(p);
            }
            let got = reverse_lanes(&lanes, &w, &area, &adj, bins);
            for (j, p) in pulses.iter().enumerate() {
                let fallback = (j != 6) & (expect_fallback | (j == 4));
                assert_eq!(got.fallback[j], fallback, "lane {j}");
                if j == 6 || fallback {
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
                    assert!(err < 2e-5, "lane {j} slot {i}: {got} vs {want} ({err:e})");
                }
            }
        }
    }
}
