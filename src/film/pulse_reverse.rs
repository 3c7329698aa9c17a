//! The reverse of [`Film::triangle_bins`]: given `δH_b` (the loss's derivative with
//! respect to each bin), `g = ∂/∂(t_0, t_1, t_2, w_0, w_1, w_2, A) Σ_b δH_b H_b` of one
//! triangle pulse, in the work of one forward splat in `f64` (issue 19) instead of seven
//! derivative slots carried through every bin.
//!
//! Both kernels splat the pulse's weighted-area function `W(t; θ)` (module doc of
//! [`super::pulse`]: 0 below `t0`, a cubic in `z = t − t0` on `[t0, t1]`, `total` minus a
//! cubic in `y = t2 − t` on `[t1, t2]`, `total` above) through a kernel, and bin `b` is a
//! difference of the result at its edges `e_b`, `e_{b+1}`. So `Σ_b δH_b H_b = Σ_k α_k C(e_k)`
//! with `α_k = δH_{k−1} − δH_k` (bins outside the splatted range count 0), and
//! `C(x) = ⟨K_x, W⟩`: box, `W(x)` itself; Gaussian, `∫ W(t) φ((x − t)/σ) dt/σ` plus the
//! `total Φ((x − t2)/σ)` beyond `t2` (by parts). Because `W` is continuous in `t` for every
//! `θ`, moving a piece's end moves no mass, and
//!
//! `∂/∂θ Σ_k α_k C(e_k) = ⟨A, ∂W/∂θ⟩`, with `A = Σ_k α_k K_{e_k}`,
//!
//! where `∂W/∂θ` is the pieces' polynomials differentiated at fixed `t`. That needs only
//! the adjoint moments of each piece, accumulated once over the edges in plain `f64`:
//! `L_n = ⟨A, z^n⟩` on `[t0, t1]`, `U_n = ⟨A, y^n⟩` on `[t1, t2]`, `T = ⟨A, 1⟩` above `t2`.
//! Then `F = ka (3 w0 L_2 + ga L_3) + total (U_0 + T) − kb (3 w2 U_2 + gb U_3)` with
//! `∂L_n/∂t0 = −n L_{n−1}`, `∂U_n/∂t2 = n U_{n−1}` (the powers' own dependence), evaluated
//! once in seven-slot duals, is `g`.
//!
//! Gaussian moments: with `u_j = (x − t_j)/σ` and `μ_m = ∫ u^m φ(u) du` between two of
//! them (antiderivatives `Φ`, `−φ`, `Φ − uφ`, `−(u² + 2)φ`), the lower piece's `z = σ (u_0 − u)`
//! and the upper's `y = σ (u − u_2)` expand binomially in `μ_0 … μ_3`.
//!
//! Pulses that the forward pass treats specially (a point pulse, a dropped piece, a piece
//! narrower than `NARROW_FOR_GAUSS σ` that it integrates by quadrature) take the dual-number
//! forward instead: rare, and then exactly the forward's derivative.

use super::normal::normal;
use super::pulse::PulseBins;
use super::Film;
use crate::adjoint::dual::Dual;

type PulseDual = Dual<f64, 7>;

/// The adjoint moments of a pulse's pieces (module doc).
#[derive(Clone, Copy, Default)]
pub struct Moments<R> {
    /// `L_n`, `n = 0..3`, on `[t0, t1]`.
    pub lower: [R; 4],
    /// `U_n`, `n = 0..3`, on `[t1, t2]`.
    pub upper: [R; 4],
    /// `T` above `t2`.
    pub top: R,
}

/// The arithmetic [`pulse_grad`] needs: `f64` here, eight `f32` lanes in the `tri3`
/// adjoint kernel (and, with `transport::tri3_physics::Lane` on top, its physics).
pub trait Arith:
    Copy
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
    + std::ops::Neg<Output = Self>
{
    /// A constant.
    fn k(v: f64) -> Self;
}

impl Arith for f64 {
    #[inline(always)]
    fn k(v: f64) -> Self {
        v
    }
}

impl Arith for f32 {
    #[inline(always)]
    fn k(v: f64) -> Self {
        v as f32
    }
}

impl Arith for wide::f32x8 {
    #[inline(always)]
    fn k(v: f64) -> Self {
        wide::f32x8::splat(v as f32)
    }
}

/// `(t, w)` sorted by `t`, with `order[s]` the input corner in sorted slot `s`.
fn sorted(t: [f64; 3], w: [f64; 3]) -> ([usize; 3], [f64; 3], [f64; 3]) {
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| t[a].total_cmp(&t[b]));
    (order, order.map(|i| t[i]), order.map(|i| w[i]))
}

/// `∂F/∂(t0, t1, t2, w0, w1, w2, A)` (sorted corners, both pieces of positive width) of
/// `F = ka (3 w0 L_2 + ga L_3) + total (U_0 + T) − kb (3 w2 U_2 + gb U_3)` (module doc),
/// written out: with `d1 = t1 − t0`, `e = t2 − t1`, `d = t2 − t0`,
/// `ka = A/(3 d1 d)`, `ga = (w1 − w0)/d1 + (w2 − w0)/d`, `kb = A/(3 e d)`,
/// `gb = (w1 − w2)/e + (w0 − w2)/d`, `total = A (w0 + w1 + w2)/3`. Generic, so the lanes
/// of the `tri3` adjoint kernel (`f32`) and the `f64` splat share it.
#[inline(always)]
pub fn pulse_grad<R: Arith>(t: [R; 3], w: [R; 3], area: R, m: &Moments<R>) -> [R; 7] {
    let ([t0, t1, t2], [w0, w1, w2]) = (t, w);
    let k = R::k;
    let one = k(1.0);
    let (i1, ie, id) = (one / (t1 - t0), one / (t2 - t1), one / (t2 - t0));
    let third = area * k(1.0 / 3.0);
    let (ka, kb) = (third * i1 * id, third * ie * id);
    let ga = (w1 - w0) * i1 + (w2 - w0) * id;
    let gb = (w1 - w2) * ie + (w0 - w2) * id;
    let ([_, l1, l2, l3], [u0, u1, u2, u3]) = (m.lower, m.upper);
    // ∂F/∂ka, ∂F/∂ga, ∂F/∂kb, ∂F/∂gb, ∂F/∂total.
    let (f_ka, f_ga) = (k(3.0) * w0 * l2 + ga * l3, ka * l3);
    let (f_kb, f_gb) = (-(k(3.0) * w2 * u2 + gb * u3), -(kb * u3));
    let f_total = u0 + m.top;
    // The powers' own dependence on t0 (z = t − t0) and t2 (y = t2 − t).
    let f_t0 = -(ka * (k(6.0) * w0 * l1 + k(3.0) * ga * l2));
    let f_t2 = -(kb * (k(6.0) * w2 * u1 + k(3.0) * gb * u2));
    let (a1, ad) = ((w1 - w0) * i1 * i1, (w2 - w0) * id * id);
    let (be, bd) = ((w1 - w2) * ie * ie, (w0 - w2) * id * id);
    let g_t0 = f_t0 + f_ka * ka * (i1 + id) + f_ga * (a1 + ad) + f_kb * kb * id + f_gb * bd;
    let g_t1 = -(f_ka * ka * i1) - f_ga * a1 + f_kb * kb * ie + f_gb * be;
    let g_t2 = f_t2 - f_ka * ka * id - f_ga * ad - f_kb * kb * (ie + id) - f_gb * (be + bd);
    let g_w0 = k(3.0) * ka * l2 - f_ga * (i1 + id) + f_gb * id + f_total * third;
    let g_w1 = f_ga * i1 + f_gb * ie + f_total * third;
    let g_w2 = f_ga * id - f_gb * (ie + id) - k(3.0) * kb * u2 + f_total * third;
    let g_a = (f_ka * ka + f_kb * kb) / area + f_total * (w0 + w1 + w2) * k(1.0 / 3.0);
    [g_t0, g_t1, g_t2, g_w0, g_w1, g_w2, g_a]
}

impl Film {
    /// `g = ∂/∂(t, w, A) Σ_b adj(b) H_b` for the pulse `triangle_bins(t, w, area)` (corner
    /// order as given; `t` in m).
    pub fn triangle_bins_reverse(
        &self,
        t: [f64; 3],
        w: [f64; 3],
        area: f64,
        adj: impl Fn(usize) -> f64,
    ) -> [f64; 7] {
        let k = self.pulse_kernel();
        let (order, ts, ws) = sorted(t, w);
        let [t0, t1, t2] = ts;
        // Pulses the forward splats otherwise (module doc), through its dual numbers.
        let dropped = |d: f64| d <= k.narrow || d == 0.0;
        if t2 - t0 <= k.point || dropped(t1 - t0) || dropped(t2 - t1) || area == 0.0 {
            let mut g = [0.0; 7];
            self.triangle_bins(
                std::array::from_fn(|i| PulseDual::var(t[i], i)),
                std::array::from_fn(|i| PulseDual::var(w[i], 3 + i)),
                PulseDual::var(area, 6),
                |b, v| {
                    let a = adj(b);
                    g.iter_mut().zip(v.d).for_each(|(g, d)| *g += a * d);
                },
            );
            return g;
        }
        let Some(bins) = self.pulse_bins(t0, t2, k.margin) else {
            return [0.0; 7];
        };
        let m = self.moments(&bins, ts, k.sigma, adj);
        let g = pulse_grad(ts, ws, area, &m);
        let mut out = [0.0; 7];
        for (s, &i) in order.iter().enumerate() {
            out[i] = g[s];
            out[3 + i] = g[3 + s];
        }
        out[6] = g[6];
        out
    }

    /// The adjoint moments over the edges `e_lo ..= e_{hi+1}` of the splatted bins.
    fn moments(
        &self,
        bins: &PulseBins,
        [t0, t1, t2]: [f64; 3],
        sigma: f64,
        adj: impl Fn(usize) -> f64,
    ) -> Moments<f64> {
        let PulseBins { lo, hi, .. } = *bins;
        let adj = &adj;
        // α_k of every edge, with its OPL (m).
        let edges = || {
            (lo..=hi + 1).scan(0.0, move |prev, k| {
                let next = if k <= hi { adj(k) } else { 0.0 };
                let alpha = *prev - next;
                *prev = next;
                Some((alpha, self.start + k as f64 * self.width))
            })
        };
        let mut m = Moments::default();
        if sigma == 0.0 {
            for (alpha, x) in edges().filter(|e| e.0 != 0.0) {
                if x <= t0 {
                } else if x <= t1 {
                    add_powers(&mut m.lower, alpha, x - t0);
                } else if x < t2 {
                    add_powers(&mut m.upper, alpha, t2 - x);
                } else {
                    m.top += alpha;
                }
            }
            return m;
        }
        let wide = [t1 - t0 >= WIDE * sigma, t2 - t1 >= WIDE * sigma];
        let inv_s = 1.0 / sigma;
        for (alpha, x) in edges().filter(|e| e.0 != 0.0) {
            let u = [x - t0, x - t1, x - t2].map(|d| d * inv_s);
            gauss_edge(&mut m, alpha, u, sigma, wide);
        }
        // Narrow pieces: 5-point Gauss–Legendre of `z^n A(t)` over the piece, `A` summed
        // over the edges at each node.
        let density = |t: f64| {
            edges()
                .filter(|e| e.0 != 0.0)
                .map(|(alpha, x)| alpha * normal((x - t) * inv_s).1)
                .sum::<f64>()
                * inv_s
        };
        if !wide[0] {
            let half = 0.5 * (t1 - t0);
            for (x, g) in GL5 {
                let z = half * (1.0 + x);
                add_powers(&mut m.lower, g * half * density(t0 + z), z);
            }
        }
        if !wide[1] {
            let half = 0.5 * (t2 - t1);
            for (x, g) in GL5 {
                let y = half * (1.0 + x);
                add_powers(&mut m.upper, g * half * density(t2 - y), y);
            }
        }
        m
    }
}

/// Pieces at least this many σ wide take the closed-form moments; narrower ones would
/// lose digits to its cancellation (terms ~ `(u/Δ)³` larger than the result, with `Φ`
/// and `φ` from a table good to 1e-13), and take quadrature instead.
const WIDE: f64 = 0.5;

/// 5-point Gauss–Legendre nodes and weights on `[−1, 1]`: on a piece at most `WIDE σ`
/// wide, the rule's error for `z^n A(t)` (`A` smooth on the scale σ) is at most 3e-10 of
/// the gradient (measured against a 40-digit reference at 0.45 σ; 1e-12 below σ/10).
const GL5: [(f64, f64); 5] = [
    (-0.906_179_845_938_664, 0.236_926_885_056_189_1),
    (-0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
    (0.0, 0.568_888_888_888_888_9),
    (0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
    (0.906_179_845_938_664, 0.236_926_885_056_189_1),
];

/// `acc[n] += α z^n`, `n = 0..3`.
#[inline(always)]
fn add_powers(acc: &mut [f64; 4], alpha: f64, z: f64) {
    let z2 = z * z;
    acc[0] += alpha;
    acc[1] += alpha * z;
    acc[2] += alpha * z2;
    acc[3] += alpha * z2 * z;
}

/// One edge's share of the Gaussian moments, `u_j = (x − t_j)/σ` (`u_0 ≥ u_1 ≥ u_2`), for
/// the pieces that are `wide` (closed form).
#[inline(always)]
fn gauss_edge(
    m: &mut Moments<f64>,
    alpha: f64,
    [u0, u1, u2]: [f64; 3],
    sigma: f64,
    wide: [bool; 2],
) {
    // ∫ u^m φ(u) du, m = 0..3, as antiderivatives at one point.
    let anti = |u: f64| {
        let (c, p) = normal(u);
        [c, -p, c - u * p, -(u * u + 2.0) * p]
    };
    let (a0, a1, a2) = (anti(u0), anti(u1), anti(u2));
    let (s2, s3) = (sigma * sigma, sigma * sigma * sigma);
    if wide[0] {
        // z = σ (u0 − u) on [u1, u0].
        let mu: [f64; 4] = std::array::from_fn(|i| a0[i] - a1[i]);
        let l = [
            mu[0],
            sigma * (u0 * mu[0] - mu[1]),
            s2 * (u0 * (u0 * mu[0] - 2.0 * mu[1]) + mu[2]),
            s3 * (u0 * (u0 * (u0 * mu[0] - 3.0 * mu[1]) + 3.0 * mu[2]) - mu[3]),
        ];
        m.lower.iter_mut().zip(l).for_each(|(m, l)| *m += alpha * l);
    }
    if wide[1] {
        // y = σ (u − u2) on [u2, u1].
        let nu: [f64; 4] = std::array::from_fn(|i| a1[i] - a2[i]);
        let u = [
            nu[0],
            sigma * (nu[1] - u2 * nu[0]),
            s2 * (nu[2] + u2 * (u2 * nu[0] - 2.0 * nu[1])),
            s3 * (nu[3] + u2 * (3.0 * nu[1] * u2 - 3.0 * nu[2] - u2 * u2 * nu[0])),
        ];
        m.upper.iter_mut().zip(u).for_each(|(m, u)| *m += alpha * u);
    }
    m.top += alpha * a2[0];
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::KernelSpec;

    use crate::film::pulse::tests::film;

    fn adj(b: usize) -> f64 {
        ((b * 7 % 11) as f64 - 5.0) * 0.1
    }

    /// The largest difference over the seven slots, relative to the largest slot of `want`.
    fn rel(got: [f64; 7], want: [f64; 7]) -> f64 {
        let scale = want.iter().fold(1e-300f64, |m, g| m.max(g.abs()));
        (0..7).map(|i| (got[i] - want[i]).abs()).fold(0.0, f64::max) / scale
    }

    /// Against the seven-slot dual forward on pulses of every shape: inside the film,
    /// cut at either end, one bin wide, points, ties. The dual forward's closed form loses
    /// digits on Gaussian pieces narrower than σ (1e-9 at 0.3 σ, up to 1.5e-4 below σ/10,
    /// against the 40-digit reference below): pieces narrower than `WIDE σ` are compared
    /// there instead.
    #[test]
    fn matches_the_dual_forward() {
        let mut cases: Vec<([f64; 3], [f64; 3], f64)> = vec![
            ([1.2031, 1.2417, 1.2244], [1.0, 1.0, 1.0], 0.3),
            ([1.2031, 1.2417, 1.2244], [0.2, 1.7, 0.9], 0.3),
            ([1.5, 1.5, 1.537], [0.5, 1.0, 2.0], 0.2),
            ([1.30, 1.3413, 1.3413], [1.0, 0.1, 0.6], 0.1),
            ([1.0004, 1.0202, 0.998], [1.0, 2.0, 0.0], 0.3),
            ([2.98, 3.05, 3.01], [1.0, 0.5, 0.7], 0.3),
            ([1.4321, 1.4321, 1.4321], [0.3, 0.2, 0.1], 0.1),
            ([1.6001, 1.6003, 1.6002], [0.3, 0.2, 0.1], 0.1),
            ([1.7, 1.7004, 1.73], [0.3, 0.2, 0.1], 0.1),
        ];
        // Pseudo-random pulses of widths from a tenth of a bin to ten bins.
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let mut rnd = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..200 {
            let c = 0.95 + 2.1 * rnd();
            let width = 0.001 * 10f64.powf(2.0 * rnd());
            let t = [c, c + width * rnd(), c + width * rnd()];
            cases.push((t, [rnd(), rnd(), rnd()], 0.05 + rnd()));
        }
        let mut compared = 0;
        for kernel in [
            KernelSpec::Box,
            KernelSpec::Gaussian { sigma_opl: 0.013 },
            KernelSpec::Gaussian { sigma_opl: 0.004 },
        ] {
            let f = film(kernel);
            let sigma = f.pulse_kernel().sigma;
            for &(t, w, area) in &cases {
                let (_, ts, _) = sorted(t, w);
                let piece = (ts[1] - ts[0]).min(ts[2] - ts[1]);
                if sigma > 0.0 && piece > 0.0 && piece < WIDE * sigma {
                    continue;
                }
                compared += 1;
                let got = f.triangle_bins_reverse(t, w, area, adj);
                let mut want = [0.0; 7];
                f.triangle_bins(
                    std::array::from_fn(|i| PulseDual::var(t[i], i)),
                    std::array::from_fn(|i| PulseDual::var(w[i], 3 + i)),
                    PulseDual::var(area, 6),
                    |b, v| want.iter_mut().zip(v.d).for_each(|(g, d)| *g += adj(b) * d),
                );
                let err = rel(got, want);
                assert!(
                    err < 1e-9,
                    "{kernel:?} {t:?} {w:?}: {got:?} vs {want:?} ({err:e})"
                );
            }
        }
        assert!(compared > 300, "{compared}");
    }

    /// Gaussian pulses with pieces of 1e-4 to 0.45 σ (the quadrature branch), against a 40-digit evaluation
    /// (mpmath quadrature and differentiation, `python/validation/pulse_reverse_reference.py`,
    /// whose output this is): both pieces narrow, one piece narrow, either order.
    #[test]
    fn narrow_gaussian_pieces_match_a_40_digit_reference() {
        #[allow(clippy::type_complexity)]
        let cases: [([f64; 3], [f64; 3], f64, [f64; 7]); 4] = [
            (
                [2.0621738718943634, 2.062725825288175, 2.062727627133973],
                [0.6178618616570651, 0.43463922657748344, 0.1202894287848445],
                0.7991742557526181,
                [
                    -0.5818126338152022,
                    -0.525198401462539,
                    -0.4223315861951884,
                    0.0034294893766357924,
                    0.003249612907699954,
                    0.003249023234306535,
                    0.004907794579706474,
                ],
            ),
            (
                [2.812673844602699, 2.812770923522122, 2.813352921193937],
                [0.3467870507935086, 0.38950297664015754, 0.7676886668254803],
                0.46258881165776783,
                [
                    -0.21753270776748154,
                    -0.22200396218377494,
                    -0.2619050962727106,
                    0.00997521517281635,
                    0.00996375243726232,
                    0.009896072799392601,
                    0.03229064179973173,
                ],
            ),
            (
                [1.4057939662622982, 1.4069237285829468, 1.4065787588827172],
                [
                    0.22112908475961357,
                    0.017923023518559233,
                    0.47578197457171134,
                ],
                0.20647656791954977,
                [
                    -0.08165145315271909,
                    -0.06357896046299226,
                    -0.10343926516851903,
                    -0.00044766745109390714,
                    -0.000545938897319501,
                    -0.0005160358072938697,
                    -0.0017159220939561978,
                ],
            ),
            (
                [1.5, 1.50585, 1.52],
                [0.3, 0.9, 0.5],
                0.25,
                [
                    -0.12650939035580624,
                    -0.1848221039285591,
                    -0.19673123579135468,
                    0.0028855162202792322,
                    0.00252864366569327,
                    0.0013174939856733046,
                    0.01520072463217746,
                ],
            ),
        ];
        let f = film(KernelSpec::Gaussian { sigma_opl: 0.013 });
        for (t, w, area, want) in cases {
            let got = f.triangle_bins_reverse(t, w, area, adj);
            // 5-point Gauss–Legendre: 3e-10 at 0.45 σ, 1e-12 below σ/10.
            let err = rel(got, want);
            assert!(err < 1e-9, "{t:?}: {got:?} vs {want:?} ({err:e})");
        }
    }
}
