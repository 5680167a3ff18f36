//! Orientation by intensity centroid (§1.5), the Gaussian blur (§1.6) and the rotated BRIEF descriptor (§1.7).

use super::*;

/// Intensity-centroid angle (radians) of the disc of radius 15 around (x, y) (§1.5).
#[inline(never)] // a stage of its own in profiles
pub fn orientation(level: &Level, x: usize, y: usize) -> f32 {
    // u = −15..=15: the column weights of m10.
    const U: [i32; 31] = {
        let mut u = [0i32; 31];
        let mut k = 0;
        while k < 31 {
            u[k] = k as i32 - 15;
            k += 1;
        }
        u
    };
    let w = level.w;
    let row_at = |v: isize, span: usize| {
        let start = (y as isize + v) as usize * w + x - span;
        &level.data[start..start + 2 * span + 1]
    };
    let centre = row_at(0, 15);
    let mut m10: i32 = centre.iter().zip(&U).map(|(&i, &u)| u * i32::from(i)).sum();
    let mut m01 = 0i32;
    // Rows v and −v together: m10 takes their sum, m01 their difference.
    for (v, &span) in UMAX.iter().enumerate().skip(1) {
        let span = span as usize;
        let (below, above) = (row_at(v as isize, span), row_at(-(v as isize), span));
        let weights = &U[15 - span..=15 + span];
        let (mut sum_u, mut diff) = (0i32, 0i32);
        for ((&b, &a), &u) in below.iter().zip(above).zip(weights) {
            let (b, a) = (i32::from(b), i32::from(a));
            sum_u += u * (b + a);
            diff += b - a;
        }
        m10 += sum_u;
        m01 += v as i32 * diff;
    }
    (m01 as f32).atan2(m10 as f32)
}

multiversion! {
    /// 7×7 Gaussian (σ = 2) with reflect-101 borders (§1.6), separable, in 16-bit fixed point so that eight (SSE2,
    /// NEON) or sixteen (AVX2) pixels go through each instruction. The horizontal pass gives 8.8 fixed point (weights
    /// ×256 summing to 256: ≤ 65280, exact). The vertical pass adds the high halves of tmp·(K·256), i.e. ⌊tmp·K/256⌋,
    /// which again sums to ≤ 65280; each of the 7 truncations loses < 1/256 of an output grey level. Interiors run
    /// over shifted whole-row slices (vector code); only the 3-pixel frame needs the reflection.
    fn blur_level / blur_level_portable(src: &Level, dst: &mut Level, tmp: &mut [u16], acc: &mut [u16]) {
        // exp(−d²/8) for d = −3..3, normalised to 256 and rounded (the centre takes the rounding remainder).
        const K: [u16; 7] = [18, 34, 49, 54, 49, 34, 18];
        let (w, h) = (src.w, src.h);
        let reflect = |i: isize, n: usize| -> usize {
            let n = n as isize;
            let r = if i < 0 {
                -i
            } else if i >= n {
                2 * n - 2 - i
            } else {
                i
            };
            r.clamp(0, n - 1) as usize
        };
        let tmp = &mut tmp[..w * h];
        for y in 0..h {
            let row = &src.data[y * w..(y + 1) * w];
            let out = &mut tmp[y * w..(y + 1) * w];
            let n = w - 6;
            let taps: [&[u8]; 7] = std::array::from_fn(|k| &row[k..k + n]);
            for (i, o) in out[3..w - 3].iter_mut().enumerate() {
                let mut sum = 0u16;
                for k in 0..7 {
                    sum += K[k] * u16::from(taps[k][i]);
                }
                *o = sum;
            }
            for x in (0..3).chain(w - 3..w) {
                out[x] = (0..7).map(|k| K[k] * u16::from(row[reflect(x as isize + k as isize - 3, w)])).sum();
            }
        }
        let acc = &mut acc[..w];
        for y in 0..h {
            acc.fill(128); // rounding of the final >> 8
            for (k, &kv) in K.iter().enumerate() {
                let r = reflect(y as isize + k as isize - 3, h);
                let kv = u32::from(kv) << 8;
                for (a, &t) in acc.iter_mut().zip(&tmp[r * w..(r + 1) * w]) {
                    *a += ((u32::from(t) * kv) >> 16) as u16;
                }
            }
            for (o, &a) in dst.data[y * w..(y + 1) * w].iter_mut().zip(acc.iter()) {
                *o = (a >> 8) as u8;
            }
        }
    }
}

/// Side of the square patch a descriptor reads: the pattern lies in [−13, 13]², so rotated it stays within
/// radius 13√2 < 19 of the keypoint, which is ≥ 19 px inside the level (FAST margin 16 + ring 3).
pub(super) const PATCH_RADIUS: usize = 18;
pub(super) const PATCH_SIDE: usize = 2 * PATCH_RADIUS + 1;
/// Row stride of the patch buffer, and its size (a power of two, so that a masked offset needs no bounds check).
pub(super) const PATCH_STRIDE: usize = 64;
pub(super) const PATCH_LEN: usize = 4096;

/// The pattern rotated to 0°, 1°, …, 359° (x' = round(x cos θ − y sin θ), y' = round(x sin θ + y cos θ)), as
/// offsets into the patch buffer ((y' + 18) · 64 + x' + 18): 360 × 256 pairs.
pub(super) fn rotate_pattern(pattern: &[[(i8, i8); 2]]) -> Vec<[u16; 2]> {
    let mut out = Vec::with_capacity(360 * pattern.len());
    for deg in 0..360 {
        let (s, c) = (deg as f32).to_radians().sin_cos();
        let turn = |(x, y): (i8, i8)| {
            let (fx, fy) = (f32::from(x), f32::from(y));
            let (rx, ry) = ((fx * c - fy * s).round() as i32, (fx * s + fy * c).round() as i32);
            ((ry + PATCH_RADIUS as i32) * PATCH_STRIDE as i32 + rx + PATCH_RADIUS as i32) as u16
        };
        out.extend(pattern.iter().map(|[p, q]| [turn(*p), turn(*q)]));
    }
    out
}

/// The descriptor at (x, y) of the blurred level with an already rotated pattern. The keypoint's neighbourhood
/// is copied once into `patch` (37 row copies); the 512 reads then use fixed offsets into it.
#[inline(never)] // a stage of its own in profiles
pub fn describe_rotated(
    blurred: &Level,
    x: usize,
    y: usize,
    rotated: &[[u16; 2]],
    patch: &mut [u8; PATCH_LEN],
) -> [u8; 32] {
    for r in 0..PATCH_SIDE {
        let start = (y + r - PATCH_RADIUS) * blurred.w + x - PATCH_RADIUS;
        let row: &[u8; PATCH_SIDE] = blurred.data[start..start + PATCH_SIDE].try_into().unwrap_or(&[0; PATCH_SIDE]);
        patch[r * PATCH_STRIDE..r * PATCH_STRIDE + PATCH_SIDE].copy_from_slice(row);
    }
    let at = |o: u16| patch[usize::from(o) & (PATCH_LEN - 1)];
    // Bits gathered in registers, 64 at a time (a read-modify-write of the output byte per bit is 3× slower).
    let mut d = [0u8; 32];
    for (word, pairs) in d.chunks_exact_mut(8).zip(rotated.chunks(64)) {
        let mut bits = 0u64;
        for (j, &[p, q]) in pairs.iter().enumerate() {
            bits |= u64::from(at(p) < at(q)) << j;
        }
        word.copy_from_slice(&bits.to_le_bytes());
    }
    d
}
