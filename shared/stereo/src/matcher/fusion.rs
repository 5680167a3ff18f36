//! §6.2–§6.3: Gaussian-weighted fusion of the patches' answers into a dense level, with the level likelihood.

use super::*;

impl Matcher {
    /// §6.3: Gaussian-weighted (BDIS) or uniform (DIS) fusion of the level's patches into per-pixel flow and
    /// probability.
    pub(super) fn fuse_level(&mut self, s: usize) {
        let p = self.params.patch_size as usize;
        let half = p / 2;
        let bayesian = self.params.algorithm == Algorithm::Bdis;
        let want_var = self.params.variance && s == self.params.lv_l as usize;
        let level = &mut self.levels[s];
        let (lw, lh) = (level.w, level.h);
        // The accumulators are cleared as they are consumed below, so they start at 0 without a pass of their
        // own; with variances the finest level's weights are read again at output time, so that level is
        // cleared up front instead.
        if want_var {
            level.num.fill(0.0);
            level.den.fill(0.0);
            level.prob_sum.fill(0.0);
            level.count.fill(0);
            level.var_num.fill(0.0);
        }
        for &(qx, qy, r, prob) in &self.patches {
            // The patch covers q + (a − p/2, b − p/2), a, b < p; clip it to the level once.
            let (x_lo, x_hi) = (qx.saturating_sub(half), (qx + half).min(lw));
            let (y_lo, y_hi) = (qy.saturating_sub(half), (qy + half).min(lh));
            let (a0, b0) = (x_lo + half - qx, y_lo + half - qy);
            for (bi, y) in (y_lo..y_hi).enumerate() {
                let row = y * lw;
                let gauss = &self.gauss[(b0 + bi) * p + a0..(b0 + bi) * p + a0 + (x_hi - x_lo)];
                let range = row + x_lo..row + x_hi;
                let (num, den) = (&mut level.num[range.clone()], &mut level.den[range.clone()]);
                let (psum, count) = (&mut level.prob_sum[range.clone()], &mut level.count[range.clone()]);
                for i in 0..gauss.len() {
                    let wgt = if bayesian { prob * gauss[i] } else { 1.0 };
                    num[i] += wgt * r.u;
                    den[i] += wgt;
                    psum[i] += prob;
                    count[i] += 1;
                }
                if want_var {
                    for (i, v) in level.var_num[range].iter_mut().enumerate() {
                        let wgt = if bayesian { prob * gauss[i] } else { 1.0 };
                        *v += wgt * wgt * r.var;
                    }
                }
            }
        }
        for k in 0..lw * lh {
            let (count, den) = (level.count[k], level.den[k]);
            if count > 0 && den > 0.0 {
                level.flow[k] = level.num[k] / den;
                level.prob[k] = level.prob_sum[k] / f32::from(count);
            } else {
                level.flow[k] = f32::NAN;
                level.prob[k] = 0.0;
            }
            if !want_var {
                level.num[k] = 0.0;
                level.den[k] = 0.0;
                level.prob_sum[k] = 0.0;
                level.count[k] = 0;
            }
        }
    }

    /// Fused variance Σw²·var / (Σw)² at the stencil's heaviest level pixel.
    pub(super) fn pixel_variance(&self, s: usize, idx: &[(usize, f32); 4]) -> f32 {
        let level = &self.levels[s];
        let (k, _) = idx.iter().copied().fold((0, -1.0f32), |best, t| if t.1 > best.1 { t } else { best });
        let den = level.den[k];
        if den > 0.0 { level.var_num[k] / (den * den) } else { f32::NAN }
    }
}
