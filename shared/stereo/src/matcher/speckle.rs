//! §6.4: speckle removal — small connected segments of similar disparity are dropped.

use super::*;

impl Matcher {
    /// §6.4: 4-connected segments of similar flow with ≤ 4^(lv_f − s) pixels are removed.
    pub(super) fn remove_speckles(&mut self, s: usize) {
        let max_small = 4usize.pow(self.params.lv_f - s as u32);
        let level = &mut self.levels[s];
        let (lw, lh) = (level.w, level.h);
        let labels = &mut self.labels[..lw * lh];
        // Labels below `first` belong to earlier levels or calls and mean "not visited": no clearing pass.
        if self.next_label > u32::MAX - (lw * lh) as u32 - 1 {
            labels.fill(0);
            self.next_label = 1;
        }
        let first = self.next_label;
        let mut next = first;
        for seed in 0..lw * lh {
            if labels[seed] >= first || !level.flow[seed].is_finite() {
                continue;
            }
            self.stack.clear();
            self.members.clear();
            self.stack.push(seed);
            labels[seed] = next;
            while let Some(k) = self.stack.pop() {
                self.members.push(k);
                let f = level.flow[k];
                let (x, y) = (k % lw, k / lw);
                let mut visit = |n: usize| {
                    if labels[n] < first && level.flow[n].is_finite() && (level.flow[n] - f).abs() <= SPECKLE_DIFF {
                        labels[n] = next;
                        self.stack.push(n);
                    }
                };
                if x > 0 {
                    visit(k - 1);
                }
                if x + 1 < lw {
                    visit(k + 1);
                }
                if y > 0 {
                    visit(k - lw);
                }
                if y + 1 < lh {
                    visit(k + lw);
                }
            }
            if self.members.len() <= max_small {
                for &k in &self.members {
                    level.flow[k] = f32::NAN;
                    level.prob[k] = 0.0;
                }
            }
            next += 1;
        }
        self.next_label = next;
    }
}
