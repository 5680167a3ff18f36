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
    pub(super) fn write_output(&mut self, w: usize, h: usize, out: &mut DisparityMap) {
        let lv_l = self.params.lv_l as usize;
        let factor = (1usize << (lv_l + self.offset)) as f32;
        out.width = w;
        out.height = h;
        out.disparity.resize(w * h, 0.0);
        out.confidence.resize(w * h, 0.0);
        if self.params.variance {
            self.write_output_with_variance(w, h, factor, out);
            return;
        }
        out.variance = None;
        // Separable: a level row is interpolated along x once (the output has 2^(lv_l + offset) times as many
        // rows, which share it), then each output row is a blend of two such rows — plain vector code, where
        // the four-tap form cost ~70 instructions an output pixel (15 % of a 1080p keyframe's matching). The
        // same bilinear weights in another order: equal to rounding, and a NaN tap spreads as before (0·NaN is
        // NaN).
        let mut rows = std::mem::take(&mut self.upsample_rows);
        // Rows kept from the previous pair are of its flow.
        rows.forget();
        let level = &self.levels[lv_l];
        for y in 0..h {
            let (y0, y1, fy) = self.row_taps[y];
            let (top, bottom) = rows.rows(level, &self.col_taps, y0 as usize, y1 as usize);
            let disparity = &mut out.disparity[y * w..(y + 1) * w];
            let confidence = &mut out.confidence[y * w..(y + 1) * w];
            let pixels = disparity.iter_mut().zip(confidence.iter_mut());
            let above = top.flow.iter().zip(&top.prob);
            let below = bottom.flow.iter().zip(&bottom.prob);
            for ((d_out, c_out), ((&f0, &p0), (&f1, &p1))) in pixels.zip(above.zip(below)) {
                (*d_out, *c_out) = output_pixel((1.0 - fy) * f0 + fy * f1, (1.0 - fy) * p0 + fy * p1, factor);
            }
        }
        self.upsample_rows = rows;
    }

    /// [`Self::write_output`] with the per-pixel variance, which needs the four taps of each pixel.
    fn write_output_with_variance(&self, w: usize, h: usize, factor: f32, out: &mut DisparityMap) {
        let lv_l = self.params.lv_l as usize;
        let level = &self.levels[lv_l];
        let var = out.variance.get_or_insert_with(Vec::new);
        var.resize(w * h, 0.0);
        for y in 0..h {
            let (y0, y1, fy) = self.row_taps[y];
            let (r0, r1) = (y0 as usize * level.w, y1 as usize * level.w);
            for (x, &(x0, x1, fx)) in self.col_taps.iter().enumerate() {
                let (x0, x1) = (x0 as usize, x1 as usize);
                let idx = [
                    (r0 + x0, (1.0 - fx) * (1.0 - fy)),
                    (r0 + x1, fx * (1.0 - fy)),
                    (r1 + x0, (1.0 - fx) * fy),
                    (r1 + x1, fx * fy),
                ];
                let (mut flow, mut prob) = (0.0f32, 0.0f32);
                for &(k, wgt) in &idx {
                    flow += wgt * level.flow[k];
                    prob += wgt * level.prob[k];
                }
                let (d, c) = output_pixel(flow, prob, factor);
                (out.disparity[y * w + x], out.confidence[y * w + x]) = (d, c);
                var[y * w + x] = if d.is_nan() { f32::NAN } else { self.pixel_variance(lv_l, &idx) * factor * factor };
            }
        }
    }
}

/// An output pixel's disparity and confidence from its interpolated flow and probability: the flow ×factor,
/// sign turned; NaN and confidence 0 unless the disparity is positive (NaN fails the comparison).
#[inline(always)]
fn output_pixel(flow: f32, prob: f32, factor: f32) -> (f32, f32) {
    let d = -flow * factor;
    if d > 0.0 { (d, prob.clamp(0.0, 1.0)) } else { (f32::NAN, 0.0) }
}

/// One level row's flow and probability interpolated along x to the output's columns.
#[derive(Debug, Clone, Default)]
pub(super) struct Row {
    flow: Vec<f32>,
    prob: Vec<f32>,
    /// The level row it holds.
    of: Option<usize>,
}

/// The two level rows an output row blends; output rows go down the image, so each level row is made once.
#[derive(Debug, Clone, Default)]
pub(super) struct RowCache {
    slots: [Row; 2],
}

impl RowCache {
    fn forget(&mut self) {
        for slot in &mut self.slots {
            slot.of = None;
        }
    }

    /// Level rows `y0` and `y1` interpolated with `col_taps` (made where not already held).
    fn rows(&mut self, level: &Level, col_taps: &[(u32, u32, f32)], y0: usize, y1: usize) -> (&Row, &Row) {
        let held = |slots: &[Row; 2], y: usize| slots.iter().position(|r| r.of == Some(y));
        let s0 = match held(&self.slots, y0) {
            Some(s) => s,
            None => {
                // Not the slot that holds y1, which this output row needs too.
                let s = usize::from(held(&self.slots, y1) == Some(0));
                self.slots[s].fill(level, col_taps, y0);
                s
            }
        };
        let s1 = match held(&self.slots, y1) {
            Some(s) => s,
            None => {
                self.slots[1 - s0].fill(level, col_taps, y1);
                1 - s0
            }
        };
        (&self.slots[s0], &self.slots[s1])
    }
}

impl Row {
    fn fill(&mut self, level: &Level, col_taps: &[(u32, u32, f32)], y: usize) {
        let (flow, prob) = (&level.flow[y * level.w..(y + 1) * level.w], &level.prob[y * level.w..(y + 1) * level.w]);
        self.flow.clear();
        self.prob.clear();
        for &(x0, x1, fx) in col_taps {
            let (x0, x1) = (x0 as usize, x1 as usize);
            self.flow.push((1.0 - fx) * flow[x0] + fx * flow[x1]);
            self.prob.push((1.0 - fx) * prob[x0] + fx * prob[x1]);
        }
        self.of = Some(y);
    }
}
