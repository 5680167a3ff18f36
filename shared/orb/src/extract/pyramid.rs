//! The scale pyramid (§1.1): bilinear resizing in fixed point, with taps computed once per size.

use super::*;

/// The taps of one pyramid step, and how far along a row they repeat every 5 outputs with 6 inputs (scale
/// factor 1.2, the default): there the gather needs no table.
#[derive(Debug, Clone, Default)]
pub(crate) struct LevelTaps {
    pub(super) x: Vec<Tap>,
    pub(super) y: Vec<Tap>,
    /// Outputs 0..periodic (a multiple of 5) have x0 = 6q + i and weight `weights5[i]` (x = 5q + i).
    pub(super) periodic: usize,
    pub(super) weights5: [u16; 5],
}

impl LevelTaps {
    pub(super) fn new(x: Vec<Tap>, y: Vec<Tap>) -> Self {
        let mut weights5 = [0u16; 5];
        let mut periodic = 0;
        if x.len() >= 5 && x[..5].iter().enumerate().all(|(i, t)| usize::from(t.0) == i) {
            for (w, t) in weights5.iter_mut().zip(&x) {
                *w = u16::from(t.1);
            }
            let fits = |x_out: usize| {
                let (q, i) = (x_out / 5, x_out % 5);
                usize::from(x[x_out].0) == 6 * q + i && u16::from(x[x_out].1) == weights5[i]
            };
            while periodic + 5 <= x.len() && (periodic..periodic + 5).all(fits) {
                periodic += 5;
            }
        }
        Self { x, y, periodic, weights5 }
    }
}

multiversion! {
    /// One pyramid step (see [`OrbExtractor::build_pyramid`]): `src` resized to `dst` with the taps of that size;
    /// `blended` holds at least `src.w + 1` samples.
    fn resize_level / resize_level_portable(src: &Level, dst: &mut Level, taps: &LevelTaps, blended: &mut [u16]) {
        #[inline(always)]
        fn lerp(a: u16, b: u16, wx: u16) -> u8 {
            let (a, b, wx) = (u32::from(a), u32::from(b), u32::from(wx));
            let v = ((a * (256 - wx) + b * wx + 32768) >> 16) as u8;
            if (a != 0) & (b != 0) { v.max(1) } else { 0 }
        }
        // One spare sample past the row's end, a copy of the last, so that every tap reads x0 and x0 + 1 (at the
        // right edge x1 = x0, and the spare gives the same value).
        let blended = &mut blended[..src.w + 1];
        for (y, &(y0, wy)) in taps.y.iter().enumerate() {
            let (y0, y1) = (usize::from(y0), (usize::from(y0) + 1).min(src.h - 1));
            let (r0, r1) = (&src.data[y0 * src.w..][..src.w], &src.data[y1 * src.w..][..src.w]);
            let wy = u16::from(wy);
            for ((b, &top), &bottom) in blended.iter_mut().zip(r0).zip(r1) {
                let v = u16::from(top) * (256 - wy) + u16::from(bottom) * wy;
                // Branch-free: black taps are rare but unpredictable where they occur.
                *b = v * u16::from((top != 0) & (bottom != 0));
            }
            blended[src.w] = blended[src.w - 1];
            let out = &mut dst.data[y * dst.w..(y + 1) * dst.w];
            // The periodic part: 5 outputs from 6 inputs with fixed weights, no table.
            let w5 = taps.weights5;
            for (o, s) in out[..taps.periodic].chunks_exact_mut(5).zip(blended.chunks_exact(6)) {
                for i in 0..5 {
                    o[i] = lerp(s[i], s[i + 1], w5[i]);
                }
            }
            for (o, &(x0, wx)) in out.iter_mut().zip(&taps.x).skip(taps.periodic) {
                let pair = &blended[x0 as usize..x0 as usize + 2];
                *o = lerp(pair[0], pair[1], u16::from(wx));
            }
        }
    }
}

impl OrbExtractor {
    /// Level 0 is the image; level l is level l−1 resized bilinearly (OpenCV INTER_LINEAR, §1.1), in 8-bit
    /// fixed point with taps computed once per size. Separable, vertical first: the two source rows of an output
    /// row are blended over their whole width (vector code), then the blended row is interpolated along x (a
    /// gather: one per output pixel). Both passes keep every bit (8.8 then 16.16 fixed point), so the result is
    /// the exact bilinear value rounded once. A pixel whose footprint touches black stays black (the view's edge
    /// must not become texture): a blended sample with a black tap is stored as 0, which real samples (≥ 256)
    /// never are.
    pub(super) fn build_pyramid(&mut self, image: &[u8]) {
        self.levels[0].data.copy_from_slice(image);
        for l in 1..self.levels.len() {
            let (prev, rest) = self.levels.split_at_mut(l);
            resize_level(&prev[l - 1], &mut rest[0], &self.taps[l], &mut self.pyramid_row);
        }
    }
}
