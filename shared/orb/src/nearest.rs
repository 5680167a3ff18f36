//! Hamming distances from one descriptor to many, for matching by appearance (brute force, no prior): the
//! tracker compares every stereo keypoint of a frame with every point of a keyframe, ~10⁶ distances a frame.
//!
//! The x86-64 baseline has no `popcnt` instruction, so `count_ones` becomes a dozen bit-twiddling instructions
//! per word; nearly every x86-64 CPU of the last 15 years has `popcnt` (and AVX2, with which the loop below is
//! vectorised). The loop is compiled for the baseline and with those features and chosen at run time; aarch64
//! counts bits with NEON in its baseline. The copies are compared bit for bit in the tests below.

/// Words of a 256-bit descriptor.
fn words(d: &[u8; 32]) -> [u64; 4] {
    let mut w = [0u64; 4];
    for (k, word) in w.iter_mut().enumerate() {
        let mut b = [0u8; 8];
        b.copy_from_slice(&d[8 * k..8 * k + 8]);
        *word = u64::from_le_bytes(b);
    }
    w
}

#[inline(always)]
fn distances_portable(query: &[u8; 32], candidates: &[[u8; 32]], out: &mut [u32]) {
    let q = words(query);
    for (c, o) in candidates.iter().zip(out.iter_mut()) {
        let w = words(c);
        *o = (q[0] ^ w[0]).count_ones()
            + (q[1] ^ w[1]).count_ones()
            + (q[2] ^ w[2]).count_ones()
            + (q[3] ^ w[3]).count_ones();
    }
}

/// `out[k]` = Hamming distance from `query` to `candidates[k]` (`out` at least as long as `candidates`).
pub fn hamming_distances(query: &[u8; 32], candidates: &[[u8; 32]], out: &mut [u32]) {
    #[cfg(target_arch = "x86_64")]
    {
        #[target_feature(enable = "avx2,popcnt")]
        fn fast(query: &[u8; 32], candidates: &[[u8; 32]], out: &mut [u32]) {
            distances_portable(query, candidates, out);
        }
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("popcnt") {
            // SAFETY: the CPU has AVX2 and POPCNT (checked on the line above), the only requirement of `fast`,
            // which is the portable loop compiled with those features.
            unsafe { fast(query, candidates, out) };
            return;
        }
    }
    distances_portable(query, candidates, out);
}

/// The nearest and the second-nearest distance in `distances` and the index of the nearest (first on ties);
/// `(u32::MAX, usize::MAX, u32::MAX)` when empty.
pub fn nearest_two(distances: &[u32]) -> (u32, usize, u32) {
    let (mut best, mut at, mut second) = (u32::MAX, usize::MAX, u32::MAX);
    for (k, &d) in distances.iter().enumerate() {
        if d < best {
            second = best;
            best = d;
            at = k;
        } else if d < second {
            second = d;
        }
    }
    (best, at, second)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hamming;

    fn descriptors(n: usize, seed: u64) -> Vec<[u8; 32]> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                let mut d = [0u8; 32];
                for b in d.iter_mut() {
                    s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                    *b = (s >> 56) as u8;
                }
                d
            })
            .collect()
    }

    #[test]
    fn every_copy_gives_the_distances_of_hamming() {
        let c = descriptors(1001, 7);
        let q = descriptors(5, 9);
        let (mut fast, mut portable) = (vec![0u32; c.len()], vec![0u32; c.len()]);
        for q in &q {
            hamming_distances(q, &c, &mut fast);
            distances_portable(q, &c, &mut portable);
            assert_eq!(fast, portable);
            for (k, d) in c.iter().enumerate() {
                assert_eq!(fast[k], hamming(q, d));
            }
        }
        hamming_distances(&q[0], &[], &mut fast);
        assert_eq!(hamming_distances(&c[3], &c[3..4], &mut fast[..1]), ());
        assert_eq!(fast[0], 0);
    }

    #[test]
    fn nearest_two_keeps_the_first_of_equal_distances() {
        assert_eq!(nearest_two(&[7, 3, 9, 3, 4]), (3, 1, 3));
        assert_eq!(nearest_two(&[5]), (5, 0, u32::MAX));
        assert_eq!(nearest_two(&[]), (u32::MAX, usize::MAX, u32::MAX));
    }
}
