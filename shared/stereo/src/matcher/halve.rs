//! The pair halved before the published levels count ([`Params::level_offset`]): HD footage matched with the
//! parameters' pixels.

use super::*;

/// How a halving step combines a block's pixels, 0 being "no data" (as the pyramid's levels, `pyramid.rs`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum HalvingRule {
    /// The left image: a block with any invalid pixel is invalid (the template must lie on seen tissue).
    AllValid,
    /// The right image: the mean of the block's valid pixels.
    ValidMean,
}

/// A block's grey level from the sum of its valid values, their count and its pixel count, rounded to the
/// nearest level; 0 (no data) where the rule refuses the block.
#[inline(always)]
fn block_value(total: u32, valid: u32, pixels: u32, rule: HalvingRule) -> u8 {
    let divisor = match rule {
        HalvingRule::AllValid if valid < pixels => 0,
        _ => valid,
    };
    // A mean of values ≥ 1 rounds to ≥ 1: a valid block never becomes "no data".
    (total + divisor / 2).checked_div(divisor).map_or(0, |mean| mean as u8)
}

/// `image` halved `times` times at once (2^times-pixel blocks, the last ones partial where the size is not a
/// multiple), rounded to the nearest grey level, into `out`; the image it now holds is returned.
pub(super) fn halve<'a>(
    image: GrayImage<'_>,
    times: usize,
    rule: HalvingRule,
    sums: &mut Vec<(u32, u32, u32)>,
    out: &'a mut Vec<u8>,
) -> GrayImage<'a> {
    let n = 1usize << times;
    let (w, h) = (image.width, image.height);
    let (hw, hh) = (w.div_ceil(n), h.div_ceil(n));
    out.resize(hw * hh, 0);
    for (by, out_row) in out.chunks_exact_mut(hw).enumerate() {
        let mut done = 0;
        if n == 2 && 2 * by + 1 < h {
            // The usual case (HD halved once), whole 2×2 blocks without the general loop's bookkeeping: a
            // fully valid block (nearly all of them) is a sum and a shift.
            let (top, bottom) =
                (&image.data[2 * by * w..(2 * by + 1) * w], &image.data[(2 * by + 1) * w..(2 * by + 2) * w]);
            for ((o, t), b) in out_row.iter_mut().zip(top.chunks_exact(2)).zip(bottom.chunks_exact(2)) {
                let values = [t[0], t[1], b[0], b[1]];
                let total: u32 = values.iter().map(|&v| u32::from(v)).sum();
                *o = if values.iter().all(|&v| v != 0) {
                    ((total + 2) >> 2) as u8
                } else {
                    block_value(total, values.iter().map(|&v| u32::from(v != 0)).sum(), 4, rule)
                };
            }
            done = w / 2;
        }
        if done == hw {
            continue;
        }
        // Per block of this row from `done` on: sum of valid values, valid count, pixel count.
        sums.clear();
        sums.resize(hw - done, (0, 0, 0));
        for y in by * n..((by + 1) * n).min(h) {
            for (sum, block) in sums.iter_mut().zip(image.data[y * w + done * n..(y + 1) * w].chunks(n)) {
                for &v in block {
                    sum.0 += u32::from(v);
                    sum.1 += u32::from(v != 0);
                }
                sum.2 += block.len() as u32;
            }
        }
        for (o, &(total, valid, pixels)) in out_row[done..].iter_mut().zip(sums.iter()) {
            *o = block_value(total, valid, pixels, rule);
        }
    }
    GrayImage { width: hw, height: hh, data: out }
}
