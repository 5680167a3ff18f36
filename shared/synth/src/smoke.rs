//! Surgical smoke: a haze that rises and clears over a second or two (diathermy), lowering the contrast of
//! everything behind it. It is rendered as a sheet of uneven density at a fixed depth in front of the scope,
//! drifting upwards, seen by both cameras at their own positions (so it has a disparity of its own, as real smoke
//! has); the ground truth stays the tissue's.

use crate::value_noise;

/// One smoke event of a sequence.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Smoke {
    /// When it starts to rise, how long it takes to reach its peak, stays, and takes to clear (s).
    pub start_s: f64,
    pub rise_s: f64,
    pub hold_s: f64,
    pub clear_s: f64,
    /// The share of the light from the tissue replaced by the haze's at the peak, where it is densest.
    pub peak: f64,
    /// Depth of the sheet and how fast it drifts upwards (mm, mm/s).
    pub depth_mm: f64,
    pub drift_mm_s: f64,
    pub seed: u64,
}

/// The haze of one frame (the renderer's `Shading::haze`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Haze {
    pub density: f64,
    pub depth_mm: f64,
    /// How far the sheet has drifted up (mm).
    pub drift_mm: f64,
    pub seed: u64,
}

impl Smoke {
    /// A puff starting `start_s` into the sequence, at half the working distance: up in 0.3 s, 0.5 s at its
    /// peak (80 % of the light), gone 0.8 s later.
    pub fn puff(start_s: f64, working_distance_mm: f64, seed: u64) -> Self {
        Self {
            start_s,
            rise_s: 0.3,
            hold_s: 0.5,
            clear_s: 0.8,
            peak: 0.8,
            depth_mm: 0.5 * working_distance_mm,
            drift_mm_s: 0.2 * working_distance_mm,
            seed,
        }
    }

    /// Density in [0, peak] at time `t_s` (smooth steps up and down).
    pub fn density(&self, t_s: f64) -> f64 {
        let smooth = |x: f64| {
            let x = x.clamp(0.0, 1.0);
            x * x * (3.0 - 2.0 * x)
        };
        let t = t_s - self.start_s;
        let up = smooth(t / self.rise_s);
        let down = 1.0 - smooth((t - self.rise_s - self.hold_s) / self.clear_s);
        self.peak * up.min(down)
    }

    /// The haze at `t_s`, or `None` when there is none.
    pub fn haze_at(&self, t_s: f64) -> Option<Haze> {
        let density = self.density(t_s);
        (density > 0.0).then_some(Haze {
            density,
            depth_mm: self.depth_mm,
            drift_mm: self.drift_mm_s * (t_s - self.start_s),
            seed: self.seed,
        })
    }
}

impl Haze {
    /// The share of the light replaced at the sheet's point (x, y) (mm, in the camera frame of the view).
    pub fn alpha(&self, x_mm: f64, y_mm: f64) -> f64 {
        // Billows a quarter of the depth across, with finer wisps.
        let scale = 0.25 * self.depth_mm;
        let (u, v) = (x_mm / scale, (y_mm + self.drift_mm) / scale);
        let billow =
            0.7 * value_noise(self.seed ^ 0x5EED, u, v) + 0.3 * value_noise(self.seed ^ 0xF00D, 2.3 * u, 2.3 * v);
        self.density * (0.5 + 1.2 * (billow - 0.5)).clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_puff_rises_holds_and_clears() {
        let smoke = Smoke::puff(1.0, 50.0, 3);
        assert_eq!(smoke.density(0.9), 0.0);
        assert!(smoke.haze_at(0.9).is_none());
        assert!((smoke.density(1.5) - 0.8).abs() < 1e-12, "at its peak");
        assert!(smoke.density(1.9) > 0.0 && smoke.density(1.9) < 0.8, "clearing");
        assert_eq!(smoke.density(2.7), 0.0, "gone 1.6 s after it started");
        let haze = smoke.haze_at(1.5).unwrap();
        let alphas: Vec<f64> = (0..50).map(|i| haze.alpha(f64::from(i) * 0.7, 3.0)).collect();
        let (lo, hi) = alphas.iter().fold((1.0f64, 0.0f64), |(lo, hi), &a| (lo.min(a), hi.max(a)));
        assert!(hi - lo > 0.1 && hi <= 1.0 && lo >= 0.0, "uneven: {lo}..{hi}");
    }
}
