//! The one percentile rule of every figure bdis-slam reports (tracking.json, mosaic.json, the latency report,
//! the benchmarks, the map preview's framing): nearest rank, as the HDR histograms of the latency report give it.
//! Accuracy statistics (`bdis_eval::Stats`) keep the statistical median (the mean of the two middle values of an
//! even set), the figure papers report.

/// The `q`-quantile (0 ≤ q ≤ 1) of `values` by the nearest-rank rule: the smallest value with at least `q·n` of
/// the values at or below it (p50 of 1..=4 is 2, p99 of 100 values is the 99th smallest). Reorders `values`;
/// `None` when there are none or `q` is outside [0, 1].
pub fn percentile(values: &mut [f64], q: f64) -> Option<f64> {
    if values.is_empty() || !(0.0..=1.0).contains(&q) {
        return None;
    }
    let rank = ((q * values.len() as f64).ceil() as usize).clamp(1, values.len());
    Some(*values.select_nth_unstable_by(rank - 1, f64::total_cmp).1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank() {
        let mut v: Vec<f64> = (1..=100).rev().map(f64::from).collect();
        assert_eq!(percentile(&mut v, 0.5), Some(50.0));
        assert_eq!(percentile(&mut v, 0.99), Some(99.0));
        assert_eq!(percentile(&mut v, 1.0), Some(100.0));
        assert_eq!(percentile(&mut v, 0.0), Some(1.0));
        assert_eq!(percentile(&mut [4.0, 1.0, 3.0, 2.0], 0.5), Some(2.0));
        assert_eq!(percentile(&mut [7.0], 0.99), Some(7.0));
        assert_eq!(percentile(&mut [], 0.5), None);
        assert_eq!(percentile(&mut [1.0], 1.5), None);
    }

    #[test]
    fn matches_its_definition_by_counting() {
        let values: Vec<f64> = (0..37).map(|i| f64::from((i * 17) % 23) * 0.5).collect();
        for q in [0.01, 0.1, 0.25, 0.5, 0.9, 0.99, 1.0] {
            // The smallest value x with #{v ≤ x} ≥ q·n.
            let n = values.len() as f64;
            let by_counting = values
                .iter()
                .copied()
                .filter(|&x| values.iter().filter(|&&v| v <= x).count() as f64 >= q * n)
                .fold(f64::INFINITY, f64::min);
            assert_eq!(percentile(&mut values.clone(), q), Some(by_counting), "q = {q}");
        }
    }
}
