//! A Gaussian kernel much wider than the film's bins, in two steps (for `tri3`).
//!
//! Through a Gaussian kernel of deviation `σ` a triangle pulse reaches every bin within
//! `GAUSS_CUTOFF σ` of it, and each bin costs an evaluation of the pulse's smoothed CDF:
//! on a film with bins of width `w ≪ σ`, `tri3` pays `~13 σ / w` of them per sub-triangle
//! and measurement (a fuzzed 2 x 2 x 100000 film of 0.1 µm bins under a 9 cm kernel took
//! 124 s for 16384 sub-triangles, where `mc3` took 0.05 s).
//!
//! The film is linear in the pulses, `H = ∫_bin K_σ * μ` with `μ = Σ_T μ_T` the sum of the
//! unsmoothed pulses, so the kernel can be applied once to the sum instead of once per
//! pulse: `μ` is box-binned, exactly, into *cells* of width `δ = σ / CELLS_PER_SIGMA`
//! (a box [`Film`], the ordinary box path of the model), and each cell's mass then goes
//! through the kernel as a point at the cell's centre. The mass is exact. The shape is
//! not: a pulse moves to its cell's centre, by up to `δ/2 = σ/64`, a first-order error
//! worst for a lone pulse narrower than a cell (measured below: 0.91 % of the peak bin,
//! against the bound `e^{-1/2}/64` = 0.95 %); pulses spread over several cells, as a
//! mesh's, come out to the midpoint rule's second order (0.006 %). Both are within what
//! `tri3` leaves anyway: it subdivides until a sub-triangle's curvature displacement is
//! `0.15 σ`. The cost per measurement is the pulses' box splat plus
//! `~13 σ / w` bins per *occupied cell*, however many sub-triangles share it.
//!
//! The adjoint is the same two steps transposed: `∂L/∂(cell c) = Σ_b adj_b K_b(x_c)`, then
//! the box path's adjoint with that as the cells' adjoint. Used when `σ ≥ CELLS_PER_SIGMA w`
//! (the cells no finer than the bins); below that the pulses are smoothed one by one,
//! exactly.

use super::{Film, GAUSS_CUTOFF};
use crate::scene::KernelSpec;

/// Cells per `σ` of the kernel, and the least `σ / w` that uses them.
pub const CELLS_PER_SIGMA: f64 = 32.0;

impl Film {
    /// The box film of cells the pulses are binned into before this film's Gaussian kernel
    /// (module doc), or `None` where the pulses are smoothed one by one: a box kernel, or a
    /// Gaussian narrower than `CELLS_PER_SIGMA` bins. The cells cover the film widened by
    /// the kernel's cutoff on both sides: mass beyond them reaches no bin.
    pub fn cells(&self) -> Option<Film> {
        let KernelSpec::Gaussian { sigma_opl } = self.kernel else {
            return None;
        };
        let sigma = sigma_opl as f64;
        if sigma < CELLS_PER_SIGMA * self.width {
            return None;
        }
        let delta = sigma / CELLS_PER_SIGMA;
        let reach = GAUSS_CUTOFF * sigma + delta;
        let span = self.end() - self.start + 2.0 * reach;
        Some(Film {
            bins: (span / delta).ceil() as usize,
            start: self.start - reach,
            width: delta,
            kernel: KernelSpec::Box,
        })
    }

    /// OPL (m) of the centre of cell `c` of `cells`.
    #[inline]
    fn cell_centre(cells: &Film, c: usize) -> f64 {
        cells.start + (c as f64 + 0.5) * cells.width
    }

    /// Adds the cells `first .. first + mass.len()` of `cells`, each `scale` times its
    /// mass, into `hist` (this film's bins) through the kernel, as points at their centres.
    pub fn blur_cells(
        &self,
        cells: &Film,
        first: usize,
        mass: impl IntoIterator<Item = f64>,
        scale: f64,
        hist: &mut [f64],
    ) {
        for (c, m) in mass.into_iter().enumerate() {
            if m != 0.0 {
                let x = Self::cell_centre(cells, first + c);
                self.point_bins(x, m * scale, |b, v| hist[b] += v);
            }
        }
    }

    /// The transpose of [`Film::blur_cells`]: `out[c] = Σ_b adj_b K_b(x_c)` for the cells
    /// `first .. first + out.len()` of `cells`, given this film's adjoint `adj`.
    pub fn cells_adjoint(&self, cells: &Film, first: usize, adj: &[f32], out: &mut [f32]) {
        for (c, o) in out.iter_mut().enumerate() {
            let x = Self::cell_centre(cells, first + c);
            let mut v = 0.0;
            self.point_bins(x, 1.0, |b, k| v += adj[b] as f64 * k);
            *o = v as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::FilmSpec;

    fn film(bins: u32, width: f32, sigma: f32) -> Film {
        Film::new(&FilmSpec {
            temporal_bins: bins,
            bin_width_opl: width,
            start_opl: 1.0,
            kernel: KernelSpec::Gaussian { sigma_opl: sigma },
        })
    }

    #[test]
    fn cells_only_for_kernels_wider_than_their_threshold() {
        assert!(film(100, 0.01, 0.012).cells().is_none());
        assert!(film(100, 0.001, 0.0319).cells().is_none());
        let f = film(1000, 0.001, 0.032);
        let c = f.cells().unwrap();
        assert!((c.width - 0.001).abs() < 1e-9, "{}", c.width);
        assert!(c.start < 1.0 - 6.5 * 0.032 && c.start + c.bins as f64 * c.width > f.end() + 0.208);
    }

    /// The worst bin of `pulses` through the cells against their exact one-by-one
    /// smoothing, as a fraction of the peak bin; the totals must agree to 1e-9 (the pulses
    /// lie within the film, away from its ends, so no mass is cut).
    fn worst_against_exact(f: &Film, pulses: &[([f64; 3], [f64; 3], f64)]) -> f64 {
        let cells = f.cells().unwrap();
        let mut exact = vec![0.0; f.bins];
        let mut binned = vec![0.0; cells.bins];
        for &(t, w, a) in pulses {
            f.splat_triangle(t, w, a, &mut exact);
            cells.splat_triangle(t, w, a, &mut binned);
        }
        let mut blurred = vec![0.0; f.bins];
        f.blur_cells(&cells, 0, binned.iter().copied(), 1.0, &mut blurred);
        let (se, sb) = (exact.iter().sum::<f64>(), blurred.iter().sum::<f64>());
        assert!((se - sb).abs() < 1e-9 * se, "{se} {sb}");
        let peak = exact.iter().cloned().fold(0.0, f64::max);
        let worst = exact
            .iter()
            .zip(&blurred)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        worst / peak
    }

    /// A pulse far narrower than a cell is moved to the cell's centre, up to `δ/2 = σ/64`:
    /// a first-order error, worst for a lone narrow pulse (measured: 0.91 % of the peak bin
    /// for one at a cell's edge); pulses spread over several cells, as a mesh's, come out
    /// to the midpoint rule's second order (measured: 0.006 %).
    #[test]
    fn cells_match_the_exact_smoothing_of_triangle_pulses() {
        let f = film(8000, 0.0001, 0.02);
        let cells = f.cells().unwrap();
        // A narrow pulse just past a cell's edge: the worst case.
        let e = cells.start + 400.0 * cells.width + 1e-6;
        let lone = worst_against_exact(&f, &[([e, e + 1e-5, e + 2e-5], [1.0; 3], 0.1)]);
        let spread = worst_against_exact(
            &f,
            &[
                ([1.30, 1.31, 1.37], [1.0, 0.5, 2.0], 0.3),
                ([1.35, 1.352, 1.353], [0.2, 0.1, 0.4], 1.0),
                ([1.40, 1.50, 1.42], [1.0, 1.0, 0.0], 0.5),
                ([1.2, 1.25, 1.32], [1.0, 1.0, 1.0], 0.2),
            ],
        );
        // The bound: a shift of δ/2 moves a bin by at most δ/2 max|φ'|/φ(0) / σ of the peak.
        let bound = 0.5 / CELLS_PER_SIGMA * (-0.5f64).exp();
        assert!(
            lone < bound && lone > 0.5 * bound,
            "lone {lone} bound {bound}"
        );
        assert!(spread < 2e-4, "spread {spread}");
    }

    /// `cells_adjoint` is the transpose of `blur_cells`: `<adj, B m> = <Bᵀ adj, m>`.
    #[test]
    fn cells_adjoint_is_the_transpose_of_the_blur() {
        let f = film(500, 0.001, 0.04);
        let cells = f.cells().unwrap();
        let mass: Vec<f64> = (0..cells.bins).map(|c| ((c * 7919) % 13) as f64).collect();
        let adj: Vec<f32> = (0..f.bins)
            .map(|b| ((b * 104729) % 17) as f32 - 8.0)
            .collect();
        let mut h = vec![0.0; f.bins];
        f.blur_cells(&cells, 0, mass.iter().copied(), 1.0, &mut h);
        let lhs: f64 = h.iter().zip(&adj).map(|(h, a)| h * *a as f64).sum();
        let mut g = vec![0.0; cells.bins];
        f.cells_adjoint(&cells, 0, &adj, &mut g);
        let rhs: f64 = g.iter().zip(&mass).map(|(g, m)| *g as f64 * m).sum();
        assert!((lhs - rhs).abs() < 1e-5 * lhs.abs(), "{lhs} {rhs}");
    }
}
