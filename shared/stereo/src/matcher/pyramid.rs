//! §2: the image pyramid — masked, bordered levels, the left x-gradient and the right image's usable-sample
//! tables.

use super::*;

impl Matcher {
    /// §1–2: padded float images, 2×2-mean pyramid where any invalid (0) pixel makes its parent invalid, the
    /// left x-gradient `I(x+1) − I(x−1)` (0 where a neighbour is invalid or at the image edge), and the right
    /// validity mask.
    pub(super) fn build_pyramid(&mut self, left: GrayImage<'_>, right: GrayImage<'_>) {
        let border = self.border;
        let (pad_x, pad_y) = (self.pad_x, self.pad_y);
        {
            let l0 = &mut self.levels[0];
            // Borders and padding are never written, so they keep the zeros of their allocation (`prepare`
            // clears level 0 again when the padding moves); only the image area is overwritten.
            let w = left.width;
            for y in 0..left.height {
                let dst = (y + pad_y + border) * l0.stride + pad_x + border;
                let src = y * w;
                for (d, &v) in l0.left[dst..dst + w].iter_mut().zip(&left.data[src..src + w]) {
                    *d = f32::from(v);
                }
                for (d, &v) in l0.right[dst..dst + w].iter_mut().zip(&right.data[src..src + w]) {
                    *d = f32::from(v);
                }
            }
        }
        for s in 1..self.levels.len() {
            let (coarser, finer) = {
                let (a, b) = self.levels.split_at_mut(s);
                (&mut b[0], &a[s - 1])
            };
            let (cw, fs) = (coarser.w, finer.stride);
            for y in 0..coarser.h {
                let dst = (y + border) * coarser.stride + border;
                let src = (2 * y + border) * fs + border;
                let (top, bottom) = (&finer.left[src..src + 2 * cw], &finer.left[src + fs..src + fs + 2 * cw]);
                for ((out, t), b) in
                    coarser.left[dst..dst + cw].iter_mut().zip(top.chunks_exact(2)).zip(bottom.chunks_exact(2))
                {
                    let (a, b, c, d) = (t[0], t[1], b[0], b[1]);
                    *out = if a == 0.0 || b == 0.0 || c == 0.0 || d == 0.0 { 0.0 } else { 0.25 * (a + b + c + d) };
                }
                let (top, bottom) = (&finer.right[src..src + 2 * cw], &finer.right[src + fs..src + fs + 2 * cw]);
                for ((out, t), b) in
                    coarser.right[dst..dst + cw].iter_mut().zip(top.chunks_exact(2)).zip(bottom.chunks_exact(2))
                {
                    let (a, b, c, d) = (t[0], t[1], b[0], b[1]);
                    let n =
                        f32::from(u8::from(a != 0.0) + u8::from(b != 0.0) + u8::from(c != 0.0) + u8::from(d != 0.0));
                    *out = if n == 0.0 { 0.0 } else { (a + b + c + d) / n };
                }
            }
        }
        // Gradients, usable-sample masks and their summed-area table only where patches are searched. Borders
        // and the first/last gradient column are never written, so they stay 0 from allocation.
        let lv_l = self.params.lv_l as usize;
        for level in &mut self.levels[lv_l..] {
            for y in 0..level.h {
                let row = (y + border) * level.stride + border;
                let img = &level.left[row..row + level.w];
                let ix = &mut level.left_ix[row..row + level.w];
                for x in 1..level.w.saturating_sub(1) {
                    let (a, b) = (img[x - 1], img[x + 1]);
                    ix[x] = if a == 0.0 || b == 0.0 { 0.0 } else { b - a };
                }
            }
            let n = level.right.len();
            let stride = level.stride;
            let (upper, lower) = level.right.split_at(stride);
            let _ = upper;
            for ((ok, &v), &below) in level.right_ok[..n - stride].iter_mut().zip(&level.right[..n - stride]).zip(lower)
            {
                *ok = u8::from(v != 0.0 && below != 0.0);
            }
            let rows = n / stride;
            let w1 = stride + 1;
            for y in 0..rows {
                let mut row_sum = 0u32;
                let ok = &level.right_ok[y * stride..(y + 1) * stride];
                let (above, below) = level.bad_sat.split_at_mut((y + 1) * w1);
                let above = &above[y * w1..];
                let below = &mut below[..w1];
                let usable_row = &mut level.usable[y * stride..(y + 1) * stride];
                for x in 0..stride {
                    let usable = x + 1 < stride && ok[x] & ok[(x + 1).min(stride - 1)] != 0;
                    usable_row[x] = if usable { 1.0 } else { 0.0 };
                    row_sum += u32::from(!usable);
                    below[x + 1] = above[x + 1] + row_sum;
                }
            }
        }
    }
}
