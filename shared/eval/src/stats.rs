//! Summary statistics of a set of errors.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    pub count: usize,
    pub rmse: f64,
    pub mean: f64,
    pub median: f64,
    pub max: f64,
}

impl Stats {
    /// Statistics of `values` (sorted in place); all zero for an empty set.
    pub fn of(values: &mut [f64]) -> Self {
        let n = values.len();
        if n == 0 {
            return Self::default();
        }
        values.sort_by(f64::total_cmp);
        let median = if n % 2 == 1 { values[n / 2] } else { 0.5 * (values[n / 2 - 1] + values[n / 2]) };
        Self {
            count: n,
            rmse: (values.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt(),
            mean: values.iter().sum::<f64>() / n as f64,
            median,
            max: values[n - 1],
        }
    }
}
