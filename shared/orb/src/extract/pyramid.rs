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

/// One bilinear sample from two vertically blended samples (8.8 fixed point) and a horizontal weight (of 256):
/// the exact value rounded once; black where either tap is black, and never black otherwise.
#[inline(always)]
fn lerp(a: u16, b: u16, wx: u16) -> u8 {
    let (a, b, wx) = (u32::from(a), u32::from(b), u32::from(wx));
    let v = ((a * (256 - wx) + b * wx + 32768) >> 16) as u8;
    if (a != 0) & (b != 0) { v.max(1) } else { 0 }
}

/// The periodic part of an output row: 5 outputs from 6 blended inputs with the weights `w5`, no table.
#[inline(always)]
fn periodic_row_portable(out: &mut [u8], blended: &[u16], w5: [u16; 5]) {
    for (o, s) in out.chunks_exact_mut(5).zip(blended.chunks_exact(6)) {
        for i in 0..5 {
            o[i] = lerp(s[i], s[i + 1], w5[i]);
        }
    }
}

/// [`periodic_row_portable`] 8 outputs at a time, for x86-64 with AVX2. The gather is the cost of a pyramid
/// step (one per output pixel, ~5 instructions in scalar code; the vertical pass is plain vector code), and the
/// pyramid's steps above the first detection level are most of what HD adds to a frame. Each 128-bit lane takes 4
/// consecutive outputs: their inputs lie within 8 samples of the lane's first, so one unaligned load and one byte
/// shuffle (one of 5, by the lane's place in the 5-output period) give both taps zero-extended to 32 bits, and
/// the arithmetic is the scalar's, exactly. 40 outputs (48 inputs) make a whole period of both, so a block's
/// loads sit at fixed offsets. Compared bit for bit with the portable copy in the tests.
#[cfg(target_arch = "x86_64")]
mod gather_avx2 {
    use super::lerp;
    use std::arch::x86_64::*;

    /// Where each of a 40-output block's 8-output steps loads its two lanes, from the block's first input
    /// (output x reads from x + x / 5).
    const LANE_0: [usize; 5] = [0, 9, 19, 28, 38];
    const LANE_1: [usize; 5] = [4, 14, 24, 33, 43];

    /// The shuffles and weights of one pyramid step (its weights), made once per step.
    pub(super) struct Gather {
        a: [__m256i; 5],
        b: [__m256i; 5],
        w: [__m256i; 5],
        w5: [u16; 5],
    }

    impl Gather {
        /// # Safety
        /// The CPU must have AVX2.
        #[target_feature(enable = "avx2")]
        pub(super) unsafe fn new(w5: [u16; 5]) -> Self {
            // Per phase p (the lane's first output x has x % 5 = p): output j of the lane reads inputs d and
            // d + 1 counted from the lane's first input, with d = j + (p + j) / 5, and has weight w5[(p + j) % 5].
            let (mut shuffle_a, mut shuffle_b, mut weights) = ([[0x80u8; 16]; 5], [[0x80u8; 16]; 5], [[0i32; 4]; 5]);
            for p in 0..5 {
                for j in 0..4 {
                    let d = (j + (p + j) / 5) as u8;
                    shuffle_a[p][4 * j..4 * j + 2].copy_from_slice(&[2 * d, 2 * d + 1]);
                    shuffle_b[p][4 * j..4 * j + 2].copy_from_slice(&[2 * d + 2, 2 * d + 3]);
                    weights[p][j] = i32::from(w5[(p + j) % 5]);
                }
            }
            // SAFETY (the loads): each reads the 16 bytes of an array of 16 bytes or of 4 × i32.
            let a_of = |p: usize| unsafe { _mm_loadu_si128(shuffle_a[p].as_ptr().cast()) };
            let b_of = |p: usize| unsafe { _mm_loadu_si128(shuffle_b[p].as_ptr().cast()) };
            let w_of = |p: usize| unsafe { _mm_loadu_si128(weights[p].as_ptr().cast()) };
            // Step k of a block (outputs 8k .. 8k + 8) has lanes of phases 8k % 5 and (8k + 4) % 5.
            let lanes = |of: &dyn Fn(usize) -> __m128i, k: usize| _mm256_set_m128i(of((8 * k + 4) % 5), of(8 * k % 5));
            Self {
                a: std::array::from_fn(|k| lanes(&a_of, k)),
                b: std::array::from_fn(|k| lanes(&b_of, k)),
                w: std::array::from_fn(|k| lanes(&w_of, k)),
                w5,
            }
        }

        /// Fills `out` (its length a multiple of 5) from `blended` (at least 6/5 of that plus one).
        ///
        /// # Safety
        /// The CPU must have AVX2.
        #[target_feature(enable = "avx2")]
        pub(super) unsafe fn row(&self, out: &mut [u8], blended: &[u16]) {
            let n = out.len() / 5 * 5;
            let (zero, one, half) = (_mm256_setzero_si256(), _mm256_set1_epi32(1), _mm256_set1_epi32(32768));
            // Byte 0 of each 32-bit lane to the 128-bit lane's bytes 0..4.
            let low_bytes = _mm256_setr_epi8(
                0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, 0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1,
                -1, -1, -1, -1, -1,
            );
            // Step k of block `block`: outputs 40·block + 8k .. + 8.
            let step = |block: usize, k: usize, out: &mut [u8]| {
                // SAFETY: the callers below check that the step's loads end within `blended` (at 48·block +
                // LANE_1[k] + 8) and its store within `out` (at 40·block + 8k + 8 ≤ n).
                unsafe {
                    let from = blended.as_ptr().add(48 * block);
                    let lo = _mm_loadu_si128(from.add(LANE_0[k]).cast());
                    let hi = _mm_loadu_si128(from.add(LANE_1[k]).cast());
                    let v = _mm256_set_m128i(hi, lo);
                    let a = _mm256_shuffle_epi8(v, self.a[k]);
                    let b = _mm256_shuffle_epi8(v, self.b[k]);
                    // a·(256 − w) + b·w = a·256 + (b − a)·w, in 32 bits (at most 255·256·256).
                    let sum = _mm256_add_epi32(
                        _mm256_slli_epi32(a, 8),
                        _mm256_mullo_epi32(_mm256_sub_epi32(b, a), self.w[k]),
                    );
                    let value = _mm256_srli_epi32(_mm256_add_epi32(sum, half), 16);
                    let black = _mm256_or_si256(_mm256_cmpeq_epi32(a, zero), _mm256_cmpeq_epi32(b, zero));
                    let value =
                        _mm256_shuffle_epi8(_mm256_andnot_si256(black, _mm256_max_epu32(value, one)), low_bytes);
                    let both = _mm_unpacklo_epi32(_mm256_castsi256_si128(value), _mm256_extracti128_si256(value, 1));
                    _mm_storel_epi64(out.as_mut_ptr().add(40 * block + 8 * k).cast(), both);
                }
            };
            let fits =
                |block: usize, k: usize| 40 * block + 8 * k + 8 <= n && 48 * block + LANE_1[k] + 8 <= blended.len();
            // Whole blocks while their last step fits, then the last block's steps that fit.
            let mut block = 0;
            while fits(block, 4) {
                for k in 0..5 {
                    step(block, k, out);
                }
                block += 1;
            }
            let mut done = 40 * block;
            for k in 0..4 {
                if !fits(block, k) {
                    break;
                }
                step(block, k, out);
                done += 8;
            }
            for (x, o) in out[..n].iter_mut().enumerate().skip(done) {
                let (q, i) = (x / 5, x % 5);
                *o = lerp(blended[6 * q + i], blended[6 * q + i + 1], self.w5[i]);
            }
        }
    }
}

/// One pyramid step (see [`OrbExtractor::build_pyramid`]): `src` resized to `dst` with the taps of that size;
/// `blended` holds at least `src.w + 1` samples. `periodic_row` fills the periodic part of a row.
#[inline(always)]
fn resize_level_with(
    src: &Level,
    dst: &mut Level,
    taps: &LevelTaps,
    blended: &mut [u16],
    periodic_row: impl Fn(&mut [u8], &[u16], [u16; 5]),
) {
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
        periodic_row(&mut out[..taps.periodic], blended, taps.weights5);
        for (o, &(x0, wx)) in out.iter_mut().zip(&taps.x).skip(taps.periodic) {
            let pair = &blended[x0 as usize..x0 as usize + 2];
            *o = lerp(pair[0], pair[1], u16::from(wx));
        }
    }
}

/// [`resize_level`] in portable code only (the parity tests' reference).
pub(crate) fn resize_level_portable(src: &Level, dst: &mut Level, taps: &LevelTaps, blended: &mut [u16]) {
    resize_level_with(src, dst, taps, blended, periodic_row_portable);
}

/// One pyramid step, with AVX2 where the CPU has it (the vertical pass compiled for it, the gather written
/// for it), else [`resize_level_portable`].
#[inline(never)] // a stage of its own in profiles
pub(crate) fn resize_level(src: &Level, dst: &mut Level, taps: &LevelTaps, blended: &mut [u16]) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2")]
        fn avx2(src: &Level, dst: &mut Level, taps: &LevelTaps, blended: &mut [u16]) {
            // SAFETY (both): this function only runs where the CPU has AVX2 (checked by its caller).
            let gather = unsafe { gather_avx2::Gather::new(taps.weights5) };
            resize_level_with(src, dst, taps, blended, |o, b, _| unsafe { gather.row(o, b) });
        }
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked on the line above), the only requirement of `avx2`.
            return unsafe { avx2(src, dst, taps, blended) };
        }
    }
    resize_level_portable(src, dst, taps, blended);
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
