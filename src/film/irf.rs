//! A detector's measured impulse response (IRF) as a causal kernel over time bins.
//!
//! A SPAD's response to a delta pulse is a peak of a few tens of ps followed by a long
//! diffusion tail (in the LCT captures the direct return still holds 22 % of its first
//! bin 72 mm of OPL later, 3 % at 240 mm): a Gaussian jitter cannot model it, and a fit
//! that ignores it spreads the surface to explain the tail. In a confocal capture every
//! scan point sees the wall's own return at the same time, a delta at OPL 0 after
//! rectification, so the IRF is in the data ([`Irf::from_direct_return`]): the mean over
//! scan points of the leading bins, less the floor of the capture's last bins.
//!
//! The render (box bins) is convolved with it, `H'[t] = Σ_k irf[k] H[t − k]`, `Σ irf = 1`
//! (through [`super::jitter::JitterKernel::from_taps`], whose transpose is the adjoint).
//! [`Irf::taps_at`] resamples it to a coarser or finer bin width through its cumulative
//! sum, so each stage of a coarse-to-fine fit uses the IRF at its own resolution.

/// An IRF sampled in bins of `bin_width` (OPL, m), lag 0 first, normalised to 1.
#[derive(Clone, Debug, PartialEq)]
pub struct Irf {
    pub bin_width: f64,
    pub taps: Vec<f64>,
}

impl Irf {
    /// The IRF from the direct return of a capture whose rows are `bins` long (OPL 0 at
    /// bin 0, the wall's return there): the mean over rows of bins `0..len`, less the
    /// mean of the last tenth of the bins (ambient floor), clamped at 0, normalised. `None`
    /// if nothing is left above the floor.
    pub fn from_direct_return(
        data: &[f32],
        bins: usize,
        len: usize,
        bin_width: f64,
    ) -> Option<Irf> {
        if bins == 0 || len == 0 || data.len() < bins {
            return None;
        }
        let len = len.min(bins);
        let rows = data.len() / bins;
        let tail = (bins / 10).max(1);
        let mut sum = vec![0.0f64; len];
        let mut floor = 0.0;
        for row in data.chunks_exact(bins) {
            for (s, &v) in sum.iter_mut().zip(row) {
                *s += v as f64;
            }
            floor += row[bins - tail..].iter().map(|&v| v as f64).sum::<f64>() / tail as f64;
        }
        let floor = floor / rows as f64;
        let taps: Vec<f64> = sum
            .iter()
            .map(|s| (s / rows as f64 - floor).max(0.0))
            .collect();
        let total: f64 = taps.iter().sum();
        (total > 0.0 && total.is_finite()).then(|| Irf {
            bin_width,
            taps: taps.iter().map(|t| t / total).collect(),
        })
    }

    /// The taps at bin width `width`: `C((j + 1) w) − C(j w)`, `C` the cumulative sum
    /// interpolated linearly between this IRF's bin edges.
    pub fn taps_at(&self, width: f64) -> Vec<f64> {
        // cumulative[i] = Σ_{k < i} taps[k]: C at this IRF's bin edge i.
        let mut cumulative = Vec::with_capacity(self.taps.len() + 1);
        cumulative.push(0.0);
        for t in &self.taps {
            cumulative.push(cumulative.last().copied().unwrap_or(0.0) + t);
        }
        let total = *cumulative.last().unwrap_or(&0.0);
        let cdf = |x: f64| -> f64 {
            let pos = (x / self.bin_width).max(0.0);
            let whole = pos.floor() as usize;
            match (cumulative.get(whole), self.taps.get(whole)) {
                (Some(below), Some(tap)) => below + (pos - whole as f64) * tap,
                _ => total,
            }
        };
        let span = self.taps.len() as f64 * self.bin_width;
        let n = (span / width).ceil().max(1.0) as usize;
        (0..n)
            .map(|j| cdf((j + 1) as f64 * width) - cdf(j as f64 * width))
            .collect()
    }

    /// This IRF at bin width `width` (unchanged if it already is).
    pub fn at_width(&self, width: f64) -> Irf {
        if (width - self.bin_width).abs() <= 1e-12 * width {
            return self.clone();
        }
        Irf {
            bin_width: width,
            taps: self.taps_at(width),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn direct_return_less_the_floor_and_resampling_keep_the_shape() {
        // Two rows of 20 bins: an exponential tail over a floor of 3.
        let bins = 20;
        let mut data = Vec::new();
        for scale in [1.0f32, 2.0] {
            for t in 0..bins {
                data.push(3.0 + scale * 100.0 * (-(t as f32) / 2.0).exp() * (t < 12) as u8 as f32);
            }
        }
        let irf = Irf::from_direct_return(&data, bins, 8, 0.001).unwrap();
        assert_eq!(irf.taps.len(), 8);
        assert!((irf.taps.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        let r = irf.taps[1] / irf.taps[0];
        assert!((r - (-0.5f64).exp()).abs() < 1e-6, "{r}");
        // Twice the bin width: pairs summed; half: halves.
        let coarse = irf.taps_at(0.002);
        assert_eq!(coarse.len(), 4);
        assert!((coarse[0] - irf.taps[0] - irf.taps[1]).abs() < 1e-12);
        let fine = irf.taps_at(0.0005);
        assert!((fine[0] - 0.5 * irf.taps[0]).abs() < 1e-12 && fine.len() == 16);
        assert!((fine.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        // Nothing above the floor: no IRF.
        assert!(Irf::from_direct_return(&[1.0; 40], 20, 5, 0.001).is_none());
    }
}
