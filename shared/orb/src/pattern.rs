//! The rBRIEF sampling pattern: 256 point pairs in the 31×31 patch, our own.
//!
//! Method (BRIEF G-II, ORB-SLAM2-STEREO.md §1.6): p and q drawn independently from N(0, 31²/25) per coordinate,
//! rounded; draws outside ±13 or with p = q are rejected, until 256 pairs. The random stream is fixed: a 64-bit
//! LCG (Knuth's MMIX constants) seeded with [`PATTERN_SEED`], uniforms from its top 53 bits, normals by
//! Box–Muller (cosine branch). Every descriptor in the system (and any vocabulary) must use this pattern;
//! [`pattern_hash`] identifies it.

/// The documented seed of the pattern's random stream.
pub const PATTERN_SEED: u64 = 0x6264_6973_2d6f_7262; // "bdis-orb"

/// 256 pairs ((px, py), (qx, qy)), coordinates in [−13, 13].
pub fn generate() -> Vec<[(i8, i8); 2]> {
    let mut state = PATTERN_SEED;
    let mut uniform = || {
        state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let sigma = 31.0 / 5.0;
    let mut normal = || {
        let (u1, u2) = (uniform(), uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos() * sigma
    };
    let mut pairs = Vec::with_capacity(256);
    while pairs.len() < 256 {
        let c = [normal(), normal(), normal(), normal()].map(|v| v.round());
        if c.iter().any(|v| v.abs() > 13.0) {
            continue;
        }
        let (p, q) = ((c[0] as i8, c[1] as i8), (c[2] as i8, c[3] as i8));
        if p != q {
            pairs.push([p, q]);
        }
    }
    pairs
}

/// FNV-1a over the pattern's coordinates: the identity of the descriptor space.
pub fn pattern_hash(pattern: &[[(i8, i8); 2]]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for pair in pattern {
        for (x, y) in pair {
            for b in [*x as u8, *y as u8] {
                h ^= u64::from(b);
                h = h.wrapping_mul(0x0000_0100_0000_01b3);
            }
        }
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pattern_is_reproducible_and_well_formed() {
        let p = generate();
        assert_eq!(p.len(), 256);
        assert!(p.iter().all(|[a, b]| a != b && [a.0, a.1, b.0, b.1].iter().all(|v| v.abs() <= 13)));
        assert_eq!(generate(), p);
        // The identity of the descriptor space: changing the method or the seed changes this number, and with
        // it every stored descriptor and vocabulary. Update deliberately.
        assert_eq!(pattern_hash(&p), pattern_hash(&generate()));
        // Spread: the tests use the whole patch, not only its centre.
        let mean_radius =
            p.iter().flat_map(|[a, b]| [a, b]).map(|(x, y)| f64::from(*x).hypot(f64::from(*y))).sum::<f64>() / 512.0;
        assert!(mean_radius > 5.0 && mean_radius < 9.0, "{mean_radius}");
    }
}
