//! Procedural noise and the tissue texture every scene wears: value noise on a hashed lattice (2-D and 3-D) and
//! [`TissueTexture`], evaluated in surface coordinates (mm) so it sticks to the wall.

/// Hash of a lattice point, in [0, 1).
fn lattice(seed: u64, i: i64, j: i64) -> f64 {
    let mut h = seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (j as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    h = h.wrapping_mul(0xC4CE_B9FE_1A85_EC53);
    h ^= h >> 33;
    // 53 bits fit an i64, whose conversion is one instruction (a u64's is several on x86-64); the same value.
    (h >> 11) as i64 as f64 / (1u64 << 53) as f64
}

/// `x.floor()`, the same value to the bit (the sign of a zero included), without a function call: x86-64's
/// baseline has no rounding instruction, so `f64::floor` is a call into a software routine there, and every step
/// of a ray's march takes two or more (value noise). Truncation is one instruction on every target.
#[inline]
pub(crate) fn floor(x: f64) -> f64 {
    // Below 2^52 in magnitude the truncation is exact in an i64; at or above it (and for NaN) x is its own floor.
    if x.abs() < 4_503_599_627_370_496.0 {
        let truncated = x as i64 as f64;
        if truncated > x { truncated - 1.0 } else { truncated.copysign(x) }
    } else {
        x.floor()
    }
}

/// Smooth value noise in [0, 1) with lattice spacing 1.
pub(crate) fn value_noise(seed: u64, u: f64, v: f64) -> f64 {
    let (i, j) = (floor(u), floor(v));
    let (fu, fv) = (u - i, v - j);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (su, sv) = (s(fu), s(fv));
    let (i, j) = (i as i64, j as i64);
    let a = lattice(seed, i, j) * (1.0 - su) + lattice(seed, i + 1, j) * su;
    let b = lattice(seed, i, j + 1) * (1.0 - su) + lattice(seed, i + 1, j + 1) * su;
    a * (1.0 - sv) + b * sv
}

/// Smooth value noise in [0, 1) over space, lattice spacing 1 (trilinear between [`lattice`] values of one
/// seed per lattice plane).
pub(crate) fn value_noise3(seed: u64, u: f64, v: f64, w: f64) -> f64 {
    let k = floor(w);
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let sw = s(w - k);
    let plane = |k: f64| value_noise(seed ^ (k as i64 as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93), u, v);
    plane(k) * (1.0 - sw) + plane(k + 1.0) * sw
}

/// Procedural tissue: a pink-red base at several scales, dark curvilinear vessels, and smooth low-texture
/// patches. `u`, `v` are surface coordinates in millimetres.
#[derive(Debug, Clone, Copy)]
pub struct TissueTexture {
    pub seed: u64,
}

impl TissueTexture {
    /// The albedo at (u, v) with all detail (a footprint of 0).
    pub fn rgb(&self, u: f64, v: f64) -> [u8; 3] {
        self.rgb_filtered(u, v, 0.0)
    }

    /// The albedo at (u, v) for a pixel covering `footprint_mm` of surface: the fine structure (pits,
    /// capillaries) keeps its edges at least ~2 pixels wide and fades out as it shrinks below ~3 pixels, as a
    /// camera's optics would blur it; without this it aliases into noise in the distance.
    pub fn rgb_filtered(&self, u: f64, v: f64, footprint_mm: f64) -> [u8; 3] {
        let n = |scale_mm: f64, k: u64| value_noise(self.seed.wrapping_add(k), u / scale_mm, v / scale_mm);
        let base = 0.5 * n(4.0, 1) + 0.3 * n(1.5, 2) + 0.2 * n(0.5, 3);
        // Vessels: thin bands where a warped noise field crosses one level.
        let warp = n(6.0, 4);
        let band = (n(3.0, 5) + 0.3 * warp - 0.55).abs();
        let vessel = (1.0 - (band / 0.025).min(1.0)).powi(2);
        // Fine capillaries: a second, denser and fainter network of thinner bands.
        const PIT_RADIUS_MM: f64 = 0.22;
        let fade = ((PIT_RADIUS_MM / footprint_mm.max(1e-9) - 1.0) / 2.0).clamp(0.0, 1.0);
        let band2 = (n(1.1, 7) + 0.25 * n(2.5, 8) - 0.55).abs();
        let capillary = fade * (1.0 - (band2 / 0.035).min(1.0)).powi(2);
        // Crypt openings of the mucosa: small dark pits on a jittered ~1.1 mm lattice (corner-like features,
        // well localised, as real mucosa has and smooth noise has not).
        let pit = fade * self.pits(u, v, 1.1, PIT_RADIUS_MM, footprint_mm);
        // Smooth areas: flatten the fine detail where a slow field is high (hard cases for matching).
        let smooth = ((n(12.0, 6) - 0.6) / 0.2).clamp(0.0, 1.0);
        let detail = base * (1.0 - smooth) + 0.55 * smooth;
        // The fine structure darkens the albedo (multiplicatively, so it keeps its contrast in dim light).
        let fine = 1.0 - (0.35 * capillary + 0.55 * pit) * (1.0 - 0.7 * smooth);
        let r = (150.0 + 90.0 * detail - 90.0 * vessel) * fine;
        let g = (60.0 + 70.0 * detail - 40.0 * vessel) * fine;
        let b = (60.0 + 60.0 * detail - 30.0 * vessel) * fine;
        [r.clamp(0.0, 255.0) as u8, g.clamp(0.0, 255.0) as u8, b.clamp(0.0, 255.0) as u8]
    }
}

impl TissueTexture {
    /// Darkness in [0, 1] of pits of radius `radius_mm` at one jittered point per `spacing_mm` cell, with a
    /// smooth rim (band-limited for the renderer's single ray per pixel).
    fn pits(&self, u: f64, v: f64, spacing_mm: f64, radius_mm: f64, footprint_mm: f64) -> f64 {
        let (cu, cv) = (u / spacing_mm, v / spacing_mm);
        let (i0, j0) = (floor(cu) as i64, floor(cv) as i64);
        let mut nearest = f64::MAX;
        for j in j0 - 1..=j0 + 1 {
            for i in i0 - 1..=i0 + 1 {
                let (pu, pv) = (
                    i as f64 + 0.15 + 0.7 * lattice(self.seed.wrapping_add(11), i, j),
                    j as f64 + 0.15 + 0.7 * lattice(self.seed.wrapping_add(12), i, j),
                );
                nearest = nearest.min((cu - pu).hypot(cv - pv));
            }
        }
        let d = nearest * spacing_mm / radius_mm;
        // A rim 0.8 r wide, or 2 pixels where that is wider, centred on r.
        let rim = (0.8f64).max(2.0 * footprint_mm / radius_mm);
        let t = ((1.0 + 0.5 * rim - d) / rim).clamp(0.0, 1.0);
        t * t * (3.0 - 2.0 * t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_is_f64_floor_to_the_bit() {
        // Signed zeros, integers, halves, the last fractions below 2^52, the first values at and above it, the
        // extremes and NaN: where a truncation-based floor can go wrong.
        let mut values = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            2.5,
            -2.5,
            -3.0,
            1e-300,
            -1e-300,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            4_503_599_627_370_495.5,
            -4_503_599_627_370_495.5,
            4_503_599_627_370_496.0,
            -4_503_599_627_370_496.0,
            9.3e18,
            -9.3e18,
            f64::MAX,
            f64::MIN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        // And a sweep through the coordinates the scenes use (mm, and noise lattice units).
        values.extend((-20_000..20_000).map(|i| f64::from(i) * 0.012_345_678_9));
        for x in values {
            assert_eq!(floor(x).to_bits(), x.floor().to_bits(), "floor({x:e})");
        }
        assert!(floor(f64::NAN).is_nan());
    }
}
