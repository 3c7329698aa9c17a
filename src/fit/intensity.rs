//! The intensity model of a fit: the measurement `M` against a render `H` after the best
//! non-negative scale `s` and background `b`,
//!
//! `L = min_{s ≥ 0, b ≥ 0} ‖s H + b − M‖²_U / ‖M‖²_U`,
//!
//! `U` the fitted bins. Real data have an unknown scale (laser power, detector
//! efficiency; with it the object's albedo is not identifiable, so `s` absorbs both and
//! per-vertex albedo carries only relative variations) and light no hidden surface
//! explains: dark counts and ambient light (a constant, about half of `‖M‖` in the LCT
//! `diffuse_s` capture) and, in a confocal capture rectified to the wall, the direct
//! light's tail (the same at every scan point: one value per bin). `(s, b)` is the exact
//! non-negative least-squares solution ([`Intensity::fit`]); `s = 1` or `b = 0` when held.
//! Since `(s, b)` minimise `L` for the current render, by the envelope theorem (which
//! holds at the active constraints too) `dL/dH = 2 s (s H + b − M) / ‖M‖²` on `U`, 0
//! elsewhere ([`intensity_l2`]).

/// The background term of the intensity model: light in the measurement that no hidden
/// surface explains.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Background {
    /// `b = 0`.
    None,
    /// One constant `b ≥ 0` for every bin and scan point (dark counts, ambient light).
    Constant,
    /// One `b_t ≥ 0` per time bin, shared by all scan points: anything the same at every
    /// scan point, e.g. the tail of the direct light and the wall's own response in a
    /// confocal capture rectified to the wall, or a time-varying ambient floor.
    PerBin,
    /// A real capture's background per scan point: a floor per scan point and the
    /// direct return's tail scaled by each point's direct counts, with a gain field and a
    /// calibrated detector response ([`super::capture`], which replaces this module's
    /// closed form: a fit with it never comes here).
    PerPoint,
}

impl std::str::FromStr for Background {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "none" | "false" => Ok(Background::None),
            "constant" | "true" => Ok(Background::Constant),
            "per-bin" => Ok(Background::PerBin),
            "per-point" => Ok(Background::PerPoint),
            other => Err(format!(
                "'{other}' is not a background model: none, constant, per-bin or per-point"
            )),
        }
    }
}

/// Which of the intensity parameters a fit estimates (the others are held at `s = 1`,
/// `b = 0`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IntensityModel {
    pub scale: bool,
    pub background: Background,
}

/// The fitted scale `s` (measurement units per render unit) and background (measurement
/// units per bin).
#[derive(Clone, Debug, PartialEq)]
pub struct Intensity {
    pub scale: f64,
    /// The background, averaged over the fitted bins (the constant, for
    /// [`Background::Constant`]).
    pub background: f64,
    /// `b_t` for every bin of a row ([`Background::PerBin`]; empty otherwise).
    pub background_bins: Vec<f64>,
}

impl Intensity {
    /// The background in bin `t` of a row.
    pub fn background_at(&self, t: usize) -> f64 {
        self.background_bins
            .get(t)
            .copied()
            .unwrap_or(self.background)
    }
}

/// Sums over a set of bins: `⟨H,H⟩, ⟨H,1⟩, ⟨H,M⟩, ⟨M,1⟩, ⟨M,M⟩, |U|`.
#[derive(Clone, Copy, Debug, Default)]
struct Moments {
    hh: f64,
    h1: f64,
    hm: f64,
    m1: f64,
    mm: f64,
    n: f64,
}

impl Moments {
    fn add(&mut self, h: f64, y: f64) {
        self.hh += h * h;
        self.h1 += h;
        self.hm += h * y;
        self.m1 += y;
        self.mm += y * y;
        self.n += 1.0;
    }

    /// `‖s H + b − M‖²` from the moments.
    fn residual(&self, s: f64, b: f64) -> f64 {
        let r = s * s * self.hh + b * b * self.n + self.mm + 2.0 * s * b * self.h1
            - 2.0 * s * self.hm
            - 2.0 * b * self.m1;
        r.max(0.0)
    }

    /// The best `b ≥ 0` for the scale `s`.
    fn best_background(&self, s: f64) -> f64 {
        if self.n > 0.0 {
            ((self.m1 - s * self.h1) / self.n).max(0.0)
        } else {
            0.0
        }
    }
}

/// The non-negative least-squares `(s, b)` for one constant background: the
/// unconstrained solution if it is feasible, else the better of the two edge solutions
/// (`b = 0` with the best `s`, `s = 0` with the best `b`; the corner `(0, 0)` lies on both
/// edges, so it is never better).
fn fit_constant(m: &Moments, fit_scale: bool) -> (f64, f64) {
    let s_only = (m.hm / m.hh).max(0.0);
    if !fit_scale || m.hh <= 0.0 {
        let s = if fit_scale { 0.0 } else { 1.0 };
        return (s, m.best_background(s));
    }
    let det = m.hh * m.n - m.h1 * m.h1;
    if det > 1e-12 * m.hh * m.n {
        let s = (m.hm * m.n - m.h1 * m.m1) / det;
        let b = (m.hh * m.m1 - m.h1 * m.hm) / det;
        if s >= 0.0 && b >= 0.0 {
            return (s, b);
        }
    }
    let b_only = m.best_background(0.0);
    if m.residual(s_only, 0.0) <= m.residual(0.0, b_only) {
        (s_only, 0.0)
    } else {
        (0.0, b_only)
    }
}

/// The non-negative least-squares `s` with one `b_t ≥ 0` per bin. With
/// `b_t(s) = max(0, (⟨M,1⟩_t − s ⟨H,1⟩_t) / n_t)` the residual is convex in `s` and its
/// half-derivative `g(s) = Σ_t s ⟨H,H⟩_t − ⟨H,M⟩_t + b_t(s) ⟨H,1⟩_t` increases with `s`;
/// its root is bracketed, bisected, then solved exactly on the bracket's active set
/// (`g` is linear where the set of positive `b_t` does not change).
fn fit_scale_per_bin(bins: &[Moments]) -> f64 {
    let g = |s: f64| -> f64 {
        bins.iter()
            .map(|m| s * m.hh - m.hm + m.best_background(s) * m.h1)
            .sum()
    };
    if g(0.0) >= 0.0 {
        return 0.0;
    }
    let (hh, hm): (f64, f64) = bins
        .iter()
        .fold((0.0, 0.0), |a, m| (a.0 + m.hh, a.1 + m.hm));
    let mut hi = if hh > 0.0 { (hm / hh).max(1e-300) } else { 1.0 };
    let mut lo = 0.0;
    for _ in 0..2000 {
        if g(hi) >= 0.0 {
            break;
        }
        (lo, hi) = (hi, hi * 2.0);
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if g(mid) < 0.0 {
            lo = mid
        } else {
            hi = mid
        }
    }
    // Exact root on the active set at the bracket's middle.
    let mid = 0.5 * (lo + hi);
    let (mut num, mut den) = (0.0, 0.0);
    for m in bins {
        num += m.hm;
        den += m.hh;
        if m.n > 0.0 && m.m1 - mid * m.h1 > 0.0 {
            num -= m.m1 * m.h1 / m.n;
            den -= m.h1 * m.h1 / m.n;
        }
    }
    let exact = if den > 0.0 { num / den } else { mid };
    if (lo..=hi).contains(&exact) {
        exact
    } else {
        mid
    }
}

impl Intensity {
    /// The non-negative least-squares intensity of the module doc, from the moments of
    /// every bin of a row (`bins[t]` sums bin `t` over the scan points).
    fn fit(bins: &[Moments], model: IntensityModel) -> Intensity {
        let total = bins.iter().fold(Moments::default(), |mut a, m| {
            a.hh += m.hh;
            a.h1 += m.h1;
            a.hm += m.hm;
            a.m1 += m.m1;
            a.mm += m.mm;
            a.n += m.n;
            a
        });
        let s_only = || {
            if model.scale && total.hh > 0.0 {
                (total.hm / total.hh).max(0.0)
            } else if model.scale {
                0.0
            } else {
                1.0
            }
        };
        match model.background {
            Background::None => Intensity {
                scale: s_only(),
                background: 0.0,
                background_bins: Vec::new(),
            },
            // Per-point backgrounds are fitted by `fit::capture` (`fit::fit` refuses the
            // one without the other), never here; the arm only completes the match.
            Background::Constant | Background::PerPoint => {
                let (scale, background) = fit_constant(&total, model.scale);
                Intensity {
                    scale,
                    background,
                    background_bins: Vec::new(),
                }
            }
            Background::PerBin => {
                let scale = if model.scale {
                    fit_scale_per_bin(bins)
                } else {
                    1.0
                };
                let background_bins: Vec<f64> =
                    bins.iter().map(|m| m.best_background(scale)).collect();
                let sum: f64 = bins
                    .iter()
                    .zip(&background_bins)
                    .map(|(m, b)| m.n * b)
                    .sum();
                Intensity {
                    scale,
                    background: sum / total.n.max(1.0),
                    background_bins,
                }
            }
        }
    }
}

/// `(loss, δH, intensity)` of the module doc over the bins `first_bin..` of every
/// `bins`-long row (`first_bin = 0`: all).
pub fn intensity_l2(
    render: &[f32],
    measured: &[f32],
    bins: usize,
    first_bin: usize,
    model: IntensityModel,
) -> (f64, Vec<f32>, Intensity) {
    let bins = bins.max(1);
    let used = |i: usize| i % bins >= first_bin;
    let mut per_bin = vec![Moments::default(); bins];
    for (i, (&h, &y)) in render.iter().zip(measured).enumerate() {
        if used(i) {
            per_bin[i % bins].add(h as f64, y as f64);
        }
    }
    let k = Intensity::fit(&per_bin, model);
    let mm: f64 = per_bin
        .iter()
        .map(|m| m.mm)
        .sum::<f64>()
        .max(f64::MIN_POSITIVE);
    let mut loss = 0.0;
    let adjoint = render
        .iter()
        .zip(measured)
        .enumerate()
        .map(|(i, (&h, &y))| {
            if !used(i) {
                return 0.0;
            }
            let r = k.scale * h as f64 + k.background_at(i % bins) - y as f64;
            loss += r * r;
            (2.0 * k.scale * r / mm) as f32
        })
        .collect();
    (loss / mm, adjoint, k)
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: IntensityModel = IntensityModel {
        scale: true,
        background: Background::Constant,
    };
    const PER_BIN: IntensityModel = IntensityModel {
        scale: true,
        background: Background::PerBin,
    };

    fn fd_check(h: &[f32], m: &[f32], bins: usize, first: usize, model: IntensityModel) {
        let (l0, adj, _) = intensity_l2(h, m, bins, first, model);
        assert!(l0 > 0.0);
        for i in 0..h.len() {
            let eps = 1e-3f32;
            let (mut hp, mut hm) = (h.to_vec(), h.to_vec());
            hp[i] += eps;
            hm[i] -= eps;
            let fd = (intensity_l2(&hp, m, bins, first, model).0
                - intensity_l2(&hm, m, bins, first, model).0)
                / (2.0 * eps as f64);
            assert!(
                (fd - adj[i] as f64).abs() < 1e-3 * fd.abs().max(1e-3),
                "{model:?} {i}: {fd} {}",
                adj[i]
            );
        }
    }

    #[test]
    fn loss_gradient_matches_finite_differences() {
        let m = [0.3f32, 1.2, 0.9, 2.5, 0.7, 0.4];
        let h = [0.1f32, 0.5, 0.2, 1.1, 0.2, 0.05];
        for scale in [true, false] {
            for background in [Background::None, Background::Constant, Background::PerBin] {
                fd_check(&h, &m, 3, 0, IntensityModel { scale, background });
                fd_check(&h, &m, 3, 1, IntensityModel { scale, background });
            }
        }
        // Masked bins have no adjoint.
        let (_, adj, _) = intensity_l2(&h, &m, 3, 1, ALL);
        assert!(adj[0] == 0.0 && adj[3] == 0.0 && adj[1] != 0.0);
    }

    #[test]
    fn recovers_scale_and_background() {
        let h = [0.0f32, 0.5, 2.0, 1.0, 0.25, 0.0, 3.0, 0.1];
        let m = h.map(|v| 4.0 * v + 0.75);
        let (l, _, k) = intensity_l2(&h, &m, 8, 0, ALL);
        assert!(l < 1e-12, "{l}");
        assert!(
            (k.scale - 4.0).abs() < 1e-5 && (k.background - 0.75).abs() < 1e-5,
            "{k:?}"
        );
        // Without a background term the same data leave a residual.
        let (l, _, k) = intensity_l2(
            &h,
            &m,
            8,
            0,
            IntensityModel {
                scale: true,
                background: Background::None,
            },
        );
        assert!(l > 1e-3 && k.background == 0.0);
        // A negative background is not allowed: the constrained optimum has b = 0.
        let m = h.map(|v| 4.0 * v - 0.2);
        let (_, _, k) = intensity_l2(&h, &m, 8, 0, ALL);
        assert_eq!(k.background, 0.0);
        assert!(k.scale > 0.0);
    }

    /// Rows of 6 bins over 5 scan points: `M = 3 H + b_t` with a decaying `b_t`.
    fn per_bin_case() -> (Vec<f32>, Vec<f32>, Vec<f64>) {
        let b = vec![0.0, 2.0, 1.0, 0.5, 0.25, 0.0];
        let mut h = Vec::new();
        let mut m = Vec::new();
        for p in 0..5 {
            for (t, bt) in b.iter().enumerate() {
                let v = ((p * 7 + t * 3) % 5) as f32 * 0.2 + if t == p { 1.0 } else { 0.0 };
                h.push(v);
                m.push(3.0 * v + *bt as f32);
            }
        }
        (h, m, b)
    }

    #[test]
    fn per_bin_background_is_recovered_exactly() {
        let (h, m, b) = per_bin_case();
        let (l, _, k) = intensity_l2(&h, &m, 6, 0, PER_BIN);
        assert!(l < 1e-12, "{l}");
        assert!((k.scale - 3.0).abs() < 1e-6, "{k:?}");
        for (t, bt) in b.iter().enumerate() {
            assert!((k.background_at(t) - bt).abs() < 1e-5, "{t}: {k:?}");
        }
        // A constant background cannot explain it.
        let (l, _, _) = intensity_l2(&h, &m, 6, 0, ALL);
        assert!(l > 1e-3, "{l}");
    }

    #[test]
    fn per_bin_fit_is_the_constrained_optimum() {
        // Bins whose best background would be negative hold b_t = 0; the loss at the fit
        // is no larger than at nearby feasible (s, b_t).
        let (h, mut m, _) = per_bin_case();
        for (i, v) in m.iter_mut().enumerate() {
            if i % 6 == 2 {
                *v -= 1.5; // pushes b_2 below zero
            }
            *v += 0.1 * ((i * 13 % 7) as f32 - 3.0); // noise
        }
        let (l, _, k) = intensity_l2(&h, &m, 6, 1, PER_BIN);
        assert_eq!(k.background_at(2), 0.0, "{k:?}");
        let loss_at = |s: f64, b: &[f64]| -> f64 {
            let mut r2 = 0.0;
            let mut mm = 0.0;
            for (i, (&h, &y)) in h.iter().zip(&m).enumerate() {
                if i % 6 >= 1 {
                    let r = s * h as f64 + b[i % 6] - y as f64;
                    r2 += r * r;
                    mm += (y as f64).powi(2);
                }
            }
            r2 / mm
        };
        let b: Vec<f64> = (0..6).map(|t| k.background_at(t)).collect();
        assert!((loss_at(k.scale, &b) - l).abs() < 1e-9);
        for ds in [-1e-3, 1e-3] {
            assert!(loss_at(k.scale + ds, &b) >= l - 1e-12);
            for t in 1..6 {
                let mut bb = b.clone();
                bb[t] = (bb[t] + ds).max(0.0);
                assert!(loss_at(k.scale, &bb) >= l - 1e-12, "bin {t}");
            }
        }
    }
}
