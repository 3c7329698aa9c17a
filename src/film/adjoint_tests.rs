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
