//! [`Film::adjoint`] against finite differences of [`Film::splat`].

use super::Film;
use crate::scene::{FilmSpec, KernelSpec};

#[test]
fn adjoint_is_the_derivative_of_the_splat() {
    let film = Film::new(&FilmSpec {
        temporal_bins: 40,
        bin_width_opl: 0.01,
        start_opl: 1.0,
        kernel: KernelSpec::Gaussian { sigma_opl: 0.013 },
    });
    let adj: Vec<f32> = (0..40).map(|b| ((b * 7 % 11) as f32 - 5.0) * 0.1).collect();
    let loss = |opl: f32| {
        let mut h = vec![0.0; 40];
        film.splat(opl, 1.0, &mut h);
        h.iter().zip(&adj).map(|(h, a)| h * *a as f64).sum::<f64>()
    };
    for opl in [1.0123f32, 1.2, 1.333, 1.39] {
        let (value, slope) = film.adjoint(opl, &adj);
        assert!((value - loss(opl)).abs() < 1e-6, "{opl}");
        // Small against σ: the central difference's own error is (h/σ)²/6 relative.
        let h = 2.5e-4;
        let fd = (loss(opl + h) - loss(opl - h)) / (2.0 * h as f64);
        assert!(
            (slope - fd).abs() < 2e-3 * fd.abs().max(1.0),
            "{opl}: {slope} vs {fd}"
        );
    }
}

/// The pulse's derivatives with respect to its corner OPLs near a tie of two corners,
/// where a piece of the pulse becomes narrow.
#[test]
fn pulse_derivative_near_ties() {
    use crate::adjoint::dual::{Dual, Real};
    let film = Film::new(&FilmSpec {
        temporal_bins: 60,
        bin_width_opl: 0.01,
        start_opl: 1.0,
        kernel: KernelSpec::Gaussian { sigma_opl: 0.012 },
    });
    let adj: Vec<f64> = (0..60).map(|b| ((b * 7 % 11) as f64 - 5.0) * 0.1).collect();
    let loss = |t: [f64; 3]| {
        let mut l = 0.0;
        film.triangle_bins(t, [0.3, 0.9, 0.5], 0.01, |b, v: f64| l += adj[b] * v);
        l
    };
    for gap in [0.0, 1e-9, 1e-7, 1e-5, 1e-4, 1e-3] {
        let t = [1.2, 1.2 + gap, 1.23];
        let mut g = [0.0; 3];
        let td: [Dual<f64, 3>; 3] = std::array::from_fn(|i| Dual::var(t[i], i));
        film.triangle_bins(td, [0.3, 0.9, 0.5].map(Dual::c), Dual::c(0.01), |b, v| {
            g.iter_mut().zip(v.d).for_each(|(g, d)| *g += adj[b] * d);
        });
        for i in 0..3 {
            let h = 1e-6;
            let (mut p, mut m) = (t, t);
            p[i] += h;
            m[i] -= h;
            let fd = (loss(p) - loss(m)) / (2.0 * h);
            // The difference's own noise: f64 rounding of the loss over h = 1e-6.
            assert!(
                (g[i] - fd).abs() < 2e-4 * fd.abs(),
                "gap {gap:e} t{i}: {} vs {fd}",
                g[i]
            );
        }
    }
}
