//! §7: the output — the finest level upsampled bilinearly to the full image, `min_prob` applied.

use super::*;

impl Matcher {
    /// OpenCV INTER_LINEAR taps for upsampling the finest searched level by 2^(lv_l + offset) to the input:
    /// source coordinate (x + 0.5)/f − 0.5, clamped at the borders; padding offsets (level-0 pixels, each
    /// 2^offset input pixels) included.
    pub(super) fn compute_taps(&mut self, w: usize, h: usize) {
        let lv_l = self.params.lv_l as usize;
        let factor = (1usize << (lv_l + self.offset)) as f32;
        let (pad_x, pad_y) = (self.pad_x << self.offset, self.pad_y << self.offset);
        let (lw, lh) = (self.levels[lv_l].w, self.levels[lv_l].h);
        let tap = |x: usize, n: usize| -> (u32, u32, f32) {
            let sx = (x as f32 + 0.5) / factor - 0.5;
            if sx <= 0.0 {
                return (0, 0, 0.0);
            }
            let x0 = sx.floor() as usize;
            if x0 + 1 >= n {
                return ((n - 1) as u32, (n - 1) as u32, 0.0);
            }
            (x0 as u32, (x0 + 1) as u32, sx - x0 as f32)
        };
        self.col_taps.clear();
        self.col_taps.extend((0..w).map(|x| tap(x + pad_x, lw)));
        self.row_taps.clear();
        self.row_taps.extend((0..h).map(|y| tap(y + pad_y, lh)));
    }

    /// §5 end: the finest level's flow ×2^(lv_l + offset), bilinear upsampling (NaN spreads), crop, sign →
    /// disparity in input pixels.
    pub(super) fn write_output(&self, w: usize, h: usize, out: &mut DisparityMap) {
        let lv_l = self.params.lv_l as usize;
        let level = &self.levels[lv_l];
        let factor = (1usize << (lv_l + self.offset)) as f32;
        out.width = w;
        out.height = h;
        out.disparity.resize(w * h, 0.0);
        out.confidence.resize(w * h, 0.0);
        let want_var = self.params.variance;
        if want_var {
            out.variance.get_or_insert_with(Vec::new).resize(w * h, 0.0);
        } else {
            out.variance = None;
        }
        for y in 0..h {
            let (y0, y1, fy) = self.row_taps[y];
            let (r0, r1) = (y0 as usize * level.w, y1 as usize * level.w);
            let disparity = &mut out.disparity[y * w..(y + 1) * w];
            let confidence = &mut out.confidence[y * w..(y + 1) * w];
            for (x, &(x0, x1, fx)) in self.col_taps.iter().enumerate() {
                let (x0, x1) = (x0 as usize, x1 as usize);
                let idx = [
                    (r0 + x0, (1.0 - fx) * (1.0 - fy)),
                    (r0 + x1, fx * (1.0 - fy)),
                    (r1 + x0, (1.0 - fx) * fy),
                    (r1 + x1, fx * fy),
                ];
                let mut flow = 0.0f32;
                let mut prob = 0.0f32;
                for &(k, wgt) in &idx {
                    flow += wgt * level.flow[k];
                    prob += wgt * level.prob[k];
                }
                let d = -flow * factor;
                // NaN fails the comparison: invalid.
                let valid = d > 0.0;
                disparity[x] = if valid { d } else { f32::NAN };
                confidence[x] = if valid { prob.clamp(0.0, 1.0) } else { 0.0 };
                if let Some(var) = out.variance.as_mut() {
                    var[y * w + x] = if valid { self.pixel_variance(lv_l, &idx) * factor * factor } else { f32::NAN };
                }
            }
        }
    }
}
