//! Losses on a transient and their adjoint histograms `δH = dLoss/dH` (DESIGN §5). The
//! gradient API takes any `δH`, so callers may bring their own loss.

use crate::error::{Error, Result};

/// A loss between a rendered transient `H` and a measured one `T` of the same shape,
/// `bins` values per measurement.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Loss {
    /// `Σ (H − T)²`.
    L2,
    /// `Σ_m ‖H_m/‖H_m‖ − T_m/‖T_m‖‖²` over measurements `m`: insensitive to each scan
    /// point's scale (unknown laser power, albedo or detector gain). A measurement with
    /// no signal (`‖·‖ = 0`) counts as zeros and passes no gradient.
    L2Normalized,
}

impl std::str::FromStr for Loss {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "l2" => Ok(Loss::L2),
            "l2-normalized" => Ok(Loss::L2Normalized),
            _ => Err(Error::Invalid(format!(
                "unknown loss '{s}': expected l2 or l2-normalized"
            ))),
        }
    }
}

impl Loss {
    /// The loss value and `δH`, in f64 sums.
    pub fn evaluate(self, render: &[f32], target: &[f32], bins: usize) -> Result<(f64, Vec<f32>)> {
        if render.len() != target.len() {
            return Err(Error::Invalid(format!(
                "target has {} values, the render {}: shapes differ",
                target.len(),
                render.len()
            )));
        }
        if let Some(i) = target.iter().position(|v| !v.is_finite()) {
            return Err(Error::Invalid(format!(
                "target has a non-finite value at flat index {i}"
            )));
        }
        let mut adjoint = vec![0.0f32; render.len()];
        let mut loss = 0.0f64;
        match self {
            Loss::L2 => {
                for ((a, &h), &t) in adjoint.iter_mut().zip(render).zip(target) {
                    let r = h as f64 - t as f64;
                    loss += r * r;
                    *a = (2.0 * r) as f32;
                }
            }
            Loss::L2Normalized => {
                let rows = render.chunks(bins).zip(target.chunks(bins));
                for ((h, t), a) in rows.zip(adjoint.chunks_mut(bins)) {
                    let norm =
                        |x: &[f32]| x.iter().map(|&v| (v as f64).powi(2)).sum::<f64>().sqrt();
                    let (nh, nt) = (norm(h), norm(t));
                    let hat = |v: f32, n: f64| if n > 0.0 { v as f64 / n } else { 0.0 };
                    let r: Vec<f64> = h
                        .iter()
                        .zip(t)
                        .map(|(&h, &t)| hat(h, nh) - hat(t, nt))
                        .collect();
                    loss += r.iter().map(|r| r * r).sum::<f64>();
                    if nh > 0.0 {
                        // d/dh of ‖ĥ − t̂‖² = (2/‖h‖)(r − ĥ (ĥ·r)).
                        let proj: f64 = h.iter().zip(&r).map(|(&h, r)| hat(h, nh) * r).sum();
                        for ((a, &h), r) in a.iter_mut().zip(h).zip(&r) {
                            *a = (2.0 / nh * (r - hat(h, nh) * proj)) as f32;
                        }
                    }
                }
            }
        }
        Ok((loss, adjoint))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adjoints_match_finite_differences() {
        let target: Vec<f32> = (0..12).map(|i| ((i * 5 % 7) as f32) * 0.3).collect();
        let render: Vec<f32> = (0..12).map(|i| ((i * 3 % 5) as f32) * 0.4 + 0.1).collect();
        for loss in [Loss::L2, Loss::L2Normalized] {
            let (_, adj) = loss.evaluate(&render, &target, 4).unwrap();
            for i in 0..12 {
                let mut p = render.clone();
                let mut m = render.clone();
                let h = 1e-3;
                p[i] += h;
                m[i] -= h;
                let fd = (loss.evaluate(&p, &target, 4).unwrap().0
                    - loss.evaluate(&m, &target, 4).unwrap().0)
                    / (2.0 * h as f64);
                assert!(
                    (adj[i] as f64 - fd).abs() < 1e-2 * fd.abs().max(0.1),
                    "{loss:?} {i}: {} vs {fd}",
                    adj[i]
                );
            }
        }
    }
}
