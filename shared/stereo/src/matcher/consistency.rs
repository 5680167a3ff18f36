//! The left–right consistency check (not in the original): the mirrored pair is matched the other way, and a
//! pixel of the finest level keeps its flow only when the right image's pixel it points at finds the same
//! disparity back.
//!
//! Mirroring both images and swapping them turns "right to left" into the same left-to-right search the matcher
//! already does, so the reverse flow comes from the same code, parameters and buffers: right column `xr` is
//! column `w − 1 − xr` of the mirrored left image, and its match in the mirrored right image lies `d` further
//! left, so a consistent pair has the same disparity both ways. The check runs on the finest searched level,
//! before its speckle removal: what it leaves in small islands is removed with the other speckles, and the
//! upsampling then treats a rejected pixel like any other invalid one.

use super::*;

/// Where the finest level sits in the full-resolution image, to follow a disparity to the mirrored reverse
/// level: its scale 2^lv_l, the padding left of the image, the image width.
#[derive(Debug, Clone, Copy)]
struct Mirror {
    scale: f32,
    pad_x: f32,
    width: usize,
    level_width: usize,
}

impl Mirror {
    /// The mirrored level's column (fractional) that the right image's pixel matched by level column `x` with
    /// disparity `d` (level px) lies on.
    fn reverse_column(&self, x: usize, d: f32) -> f32 {
        let image_x = (x as f32 + 0.5) * self.scale - 0.5 - self.pad_x;
        let mirrored_x = (self.width - 1) as f32 - (image_x - d * self.scale);
        (mirrored_x + self.pad_x + 0.5) / self.scale - 0.5
    }

    /// Whether the reverse flow `back` (one level row, flow ≤ 0 = −disparity) confirms disparity `d` at level
    /// column `x` within `tolerance` level px. The column is fractional; either neighbour may confirm it, so a
    /// true match on a depth edge is not lost to rounding. Outside the level nothing can confirm it.
    fn confirms(&self, back: &[f32], x: usize, d: f32, tolerance: f32) -> bool {
        let column = self.reverse_column(x, d);
        if !(0.0..=(self.level_width - 1) as f32).contains(&column) {
            return false;
        }
        // NaN (no reverse answer) fails both comparisons.
        let (k0, k1) = (column.floor() as usize, column.ceil() as usize);
        (d + back[k0]).abs() <= tolerance || (d + back[k1]).abs() <= tolerance
    }
}

impl Matcher {
    /// Matches the mirrored pair (mirror of the right image as the left, mirror of the left as the right) and
    /// keeps its finest level's flow for [`Self::keep_consistent`].
    pub(super) fn match_mirrored(&mut self, left: GrayImage<'_>, right: GrayImage<'_>) {
        let (w, h) = (left.width, left.height);
        // Taken out of `self` for the pass (which borrows all of it) and put back: the buffers stay reused.
        let mut mirrored_left = std::mem::take(&mut self.mirrored_left);
        let mut mirrored_right = std::mem::take(&mut self.mirrored_right);
        mirror_into(right, &mut mirrored_left);
        mirror_into(left, &mut mirrored_right);
        self.match_pass(
            GrayImage { width: w, height: h, data: &mirrored_left },
            GrayImage { width: w, height: h, data: &mirrored_right },
            None,
        );
        self.mirrored_left = mirrored_left;
        self.mirrored_right = mirrored_right;
        let finest = &self.levels[self.params.lv_l as usize].flow;
        self.reverse_flow.clear();
        self.reverse_flow.extend_from_slice(finest);
    }

    /// Invalidates every finest-level pixel whose disparity the mirrored pass does not confirm within
    /// `tolerance` level px.
    pub(super) fn keep_consistent(&mut self, tolerance: f32) {
        let s = self.params.lv_l as usize;
        let level = &mut self.levels[s];
        let mirror = Mirror {
            scale: (1usize << s) as f32,
            pad_x: self.pad_x as f32,
            width: self.halved_w,
            level_width: level.w,
        };
        for (y, (flow, prob)) in
            level.flow.chunks_exact_mut(level.w).zip(level.prob.chunks_exact_mut(level.w)).enumerate()
        {
            let back = &self.reverse_flow[y * level.w..(y + 1) * level.w];
            for x in 0..flow.len() {
                let u = flow[x];
                if u.is_finite() && !mirror.confirms(back, x, -u, tolerance) {
                    flow[x] = f32::NAN;
                    prob[x] = 0.0;
                }
            }
        }
    }
}

/// Each row of `image` reversed, into `out` (resized to the image; no allocation at an unchanged size).
fn mirror_into(image: GrayImage<'_>, out: &mut Vec<u8>) {
    let (w, h) = (image.width, image.height);
    out.resize(w * h, 0);
    for (dst, src) in out.chunks_exact_mut(w).zip(image.data[..w * h].chunks_exact(w)) {
        for (d, s) in dst.iter_mut().zip(src.iter().rev()) {
            *d = *s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const NAN: f32 = f32::NAN;

    #[test]
    fn a_disparity_is_confirmed_only_by_the_mirrored_column_it_points_at() {
        // Full resolution, no padding, 8 wide: x = 5 with d = 2 points at right column 3, mirrored 8 − 1 − 3 = 4.
        let m = Mirror { scale: 1.0, pad_x: 0.0, width: 8, level_width: 8 };
        assert_eq!(m.reverse_column(5, 2.0), 4.0);
        let mut back = [NAN; 8];
        back[4] = -2.4;
        assert!(m.confirms(&back, 5, 2.0, 0.5));
        assert!(!m.confirms(&back, 5, 2.0, 0.3), "0.4 apart");
        // x = 6, d = 2 points at mirrored column 3, which has no answer: a whole column has no second neighbour.
        assert!(!m.confirms(&back, 6, 2.0, 0.5));
        // d = 9 points left of the right image.
        assert!(!m.confirms(&back, 7, 9.0, 100.0));
    }

    #[test]
    fn a_sub_pixel_match_is_confirmed_by_either_neighbouring_column() {
        // x = 5, d = 1.5: right column 3.5, mirrored 7 − 3.5 = 3.5 → columns 3 and 4.
        let m = Mirror { scale: 1.0, pad_x: 0.0, width: 8, level_width: 8 };
        for (column, expect) in [(2, false), (3, true), (4, true), (5, false)] {
            let mut back = [NAN; 8];
            back[column] = -1.5;
            assert_eq!(m.confirms(&back, 5, 1.5, 0.25), expect, "column {column}");
        }
    }

    #[test]
    fn a_coarser_level_with_padding_maps_through_full_resolution() {
        // Level 1 of a 10-px image padded to 12 (1 px each side): level column 3 covers image x = 6.5 − 1 = 5.5;
        // d = 1 level px = 2 image px → right x 3.5 → mirrored 9 − 3.5 = 5.5 → level (5.5 + 1 + 0.5)/2 − 0.5 = 3.
        let m = Mirror { scale: 2.0, pad_x: 1.0, width: 10, level_width: 6 };
        assert_eq!(m.reverse_column(3, 1.0), 3.0);
        // Zero disparity maps a column onto its mirror image.
        assert_eq!(m.reverse_column(0, 0.0), 5.0);
    }

    #[test]
    fn mirroring_reverses_each_row_of_the_image_only() {
        let data = [1, 2, 3, 4, 5, 6, 7];
        let mut out = Vec::new();
        mirror_into(GrayImage { width: 3, height: 2, data: &data }, &mut out);
        assert_eq!(out, vec![3, 2, 1, 6, 5, 4]);
    }
}
