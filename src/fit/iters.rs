//! `--iters N` over a schedule's stages.

/// `total` iterations split over stages in proportion to `weights`, each at least 1,
/// summing to `total` exactly (largest remainders); `None` if there are more stages
/// than iterations. (Rounding each share up ran `--iters 20` as 23.)
pub fn split_iters(weights: &[u64], total: u64) -> Option<Vec<u64>> {
    let n = weights.len() as u64;
    if total < n {
        return None;
    }
    // One iteration each, the rest in proportion.
    let rest = total - n;
    // Stages of no weight at all share alike.
    let weights: Vec<u64> = match weights.iter().all(|&w| w == 0) {
        true => vec![1; weights.len()],
        false => weights.to_vec(),
    };
    let sum: u128 = weights.iter().map(|&w| u128::from(w)).sum();
    let exact: Vec<(u64, u128)> = weights
        .iter()
        .map(|&w| {
            let num = u128::from(w) * u128::from(rest);
            ((num / sum) as u64, num % sum)
        })
        .collect();
    let mut out: Vec<u64> = exact.iter().map(|(q, _)| q + 1).collect();
    let short = total - out.iter().sum::<u64>();
    let mut order: Vec<usize> = (0..weights.len()).collect();
    order.sort_by(|&a, &b| exact[b].1.cmp(&exact[a].1).then(a.cmp(&b)));
    for &i in order.iter().take(short as usize) {
        out[i] += 1;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::split_iters;

    #[test]
    fn iterations_split_to_the_total_exactly() {
        for (w, total) in [
            (vec![60, 40, 100], 20),
            (vec![1, 1, 1], 20),
            (vec![7], 3),
            (vec![0, 0], 5),
            (vec![3, 1000], 2),
        ] {
            let s = split_iters(&w, total).unwrap();
            assert_eq!(s.iter().sum::<u64>(), total, "{w:?}");
            assert!(s.iter().all(|&k| k >= 1), "{s:?}");
        }
        assert_eq!(split_iters(&[60, 40, 100], 20), Some(vec![6, 4, 10]));
        assert_eq!(split_iters(&[1, 1, 1, 1], 3), None);
    }
}
