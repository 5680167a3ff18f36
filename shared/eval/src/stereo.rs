//! Scoring a disparity map against ground truth: density over an evaluation region, depth errors (mean and
//! median absolute), bad-1 / bad-2 px disparity outliers. Scores pool pixels over several pairs.

/// Accumulates pixels of one or more pairs.
#[derive(Debug, Clone, Default)]
pub struct StereoScore {
    region_pixels: u64,
    valid_pixels: u64,
    depth_abs_errors: Vec<f32>,
    disparity_abs_sum: f64,
    bad1: u64,
    bad2: u64,
}

/// The summary figures.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScoreSummary {
    /// Valid estimates / pixels of the evaluation region.
    pub density: f64,
    /// Mean and median |z_est − z_gt| over valid estimates with ground truth, in the data's depth unit.
    pub depth_mae: f64,
    pub depth_median: f64,
    /// Mean |d_est − d_gt| in px.
    pub disparity_mae: f64,
    /// Fractions of valid estimates off by more than 1 and 2 px.
    pub bad1: f64,
    pub bad2: f64,
    pub region_pixels: u64,
    pub scored_pixels: u64,
}

impl StereoScore {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds one pair. `gt_depth` is the z-depth per pixel (non-finite or ≤ 0 = no ground truth), `region` says
    /// which pixels count, `bf` converts disparity to depth.
    pub fn add(&mut self, disparity: &[f32], gt_depth: &[f32], region: &[bool], bf: f32) {
        for ((&d, &z_gt), &inside) in disparity.iter().zip(gt_depth).zip(region) {
            if !inside {
                continue;
            }
            self.region_pixels += 1;
            if !d.is_finite() || d <= 0.0 {
                continue;
            }
            self.valid_pixels += 1;
            if !(z_gt.is_finite() && z_gt > 0.0) {
                continue;
            }
            let z = bf / d;
            self.depth_abs_errors.push((z - z_gt).abs());
            let d_err = (d - bf / z_gt).abs();
            self.disparity_abs_sum += f64::from(d_err);
            self.bad1 += u64::from(d_err > 1.0);
            self.bad2 += u64::from(d_err > 2.0);
        }
    }

    pub fn summary(&self) -> ScoreSummary {
        let n = self.depth_abs_errors.len();
        let mut sorted = self.depth_abs_errors.clone();
        sorted.sort_by(f32::total_cmp);
        let median = if n == 0 {
            f64::NAN
        } else if n % 2 == 1 {
            f64::from(sorted[n / 2])
        } else {
            0.5 * (f64::from(sorted[n / 2 - 1]) + f64::from(sorted[n / 2]))
        };
        let nf = n.max(1) as f64;
        ScoreSummary {
            density: self.valid_pixels as f64 / self.region_pixels.max(1) as f64,
            depth_mae: self.depth_abs_errors.iter().map(|&e| f64::from(e)).sum::<f64>() / nf,
            depth_median: median,
            disparity_mae: self.disparity_abs_sum / nf,
            bad1: self.bad1 as f64 / nf,
            bad2: self.bad2 as f64 / nf,
            region_pixels: self.region_pixels,
            scored_pixels: n as u64,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_answers() {
        let mut s = StereoScore::new();
        // bf = 100: d 10 → z 10. GT z 10 everywhere; estimates 10 (exact), 12.5 (z 8, |Δd| 2.5), NaN, outside.
        s.add(&[10.0, 12.5, f32::NAN, 10.0], &[10.0; 4], &[true, true, true, false], 100.0);
        let m = s.summary();
        assert_eq!(m.region_pixels, 3);
        assert!((m.density - 2.0 / 3.0).abs() < 1e-12);
        assert!((m.depth_mae - 1.0).abs() < 1e-6);
        assert!((m.depth_median - 1.0).abs() < 1e-6);
        assert_eq!((m.bad1, m.bad2), (0.5, 0.5));
    }
}
