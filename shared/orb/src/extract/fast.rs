//! FAST-9 corners per cell with a fallback threshold (§1.2–§1.3): candidate masks, vectorised scores, and
//! non-maximum suppression.

use super::*;

/// Marks the pixels of row `y`, columns `x_lo..x_hi`, that may be FAST-9 corners at the thresholds `t_ini` and
/// `t_min` (1 = maybe, 0 = certainly not; the outputs are that span of the row). An arc of 9 of the 16 ring pixels
/// contains one pixel of every opposite pair (k, k + 8), so a bright corner needs, for all 8 pairs, one of the two
/// brighter than centre + t: the smallest of the 8 pair maxima must be. Dark corners likewise with the largest pair
/// minimum. Black centres are never corners. Byte min/max are single vector instructions, and the loop over
/// equal-length row slices is vectorised by the compiler; both thresholds share the loads and the reductions.
#[inline(always)]
pub(super) fn candidates_row(
    data: &[u8],
    w: usize,
    y: usize,
    (x_lo, x_hi): (usize, usize),
    t: (u8, u8),
    out: (&mut [u8], &mut [u8]),
) {
    let n = x_hi - x_lo;
    let at = |(dx, dy): (i32, i32)| {
        let start = ((y as isize + dy as isize) as usize) * w + (x_lo as isize + dx as isize) as usize;
        &data[start..start + n]
    };
    let centre = at((0, 0));
    let ring: [&[u8]; 16] = std::array::from_fn(|k| at(CIRCLE[k]));
    let (out_ini, out_min) = (&mut out.0[..n], &mut out.1[..n]);
    for i in 0..n {
        let c = centre[i];
        let (mut min_of_max, mut max_of_min) = (u8::MAX, 0u8);
        for k in 0..8 {
            let (a, b) = (ring[k][i], ring[k + 8][i]);
            min_of_max = min_of_max.min(a.max(b));
            max_of_min = max_of_min.max(a.min(b));
        }
        let maybe =
            |t: u8| u8::from(((min_of_max > c.saturating_add(t)) | (max_of_min < c.saturating_sub(t))) & (c != 0));
        out_ini[i] = maybe(t.0);
        out_min[i] = maybe(t.1);
    }
}

/// [`candidates_row`] 32 pixels at a time, for x86-64 with AVX2: byte min/max, saturating add/subtract and
/// unsigned comparisons (as "the maximum is not the other") on whole 256-bit rows, the row's last 32 pixels as
/// one more (overlapping) step; rows shorter than 32 go to the portable row. (The compiler keeps the portable
/// loop at SSE2's 16 bytes, and leaves it scalar when asked for AVX2.) Compared byte for byte with the portable
/// masks in the tests.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn candidates_row_avx2(
    data: &[u8],
    w: usize,
    y: usize,
    (x_lo, x_hi): (usize, usize),
    t: (u8, u8),
    out: (&mut [u8], &mut [u8]),
) {
    use std::arch::x86_64::*;
    let n = x_hi - x_lo;
    let (out_ini, out_min) = (&mut out.0[..n], &mut out.1[..n]);
    // The ring reaches 3 rows and 3 columns round each pixel: every read below is one the portable row makes
    // too, and the caller keeps them inside the level. Checked here, as the loads below rely on it.
    let reach = 3 * w + 3;
    assert!(y * w + x_lo >= reach && y * w + x_hi + reach <= data.len(), "the FAST ring must fit the level");
    let ring: [isize; 16] = CIRCLE.map(|(dx, dy)| dy as isize * w as isize + dx as isize);
    let (ones, one, zero) = (_mm256_set1_epi8(-1), _mm256_set1_epi8(1), _mm256_setzero_si256());
    let thresholds = (_mm256_set1_epi8(t.0 as i8), _mm256_set1_epi8(t.1 as i8));
    if n < 32 {
        candidates_row(data, w, y, (x_lo, x_hi), t, (out_ini, out_min));
        return;
    }
    // Steps of 32 from the left, and a last one ending at the row's end (overlapping the one before: the
    // same bytes written again), so no pixel goes to scalar code.
    let mut i = 0;
    loop {
        // SAFETY: pixels y·w + x_lo + i ..+ 32 end by y·w + x_hi (i + 32 ≤ n), so with any ring offset they lie
        // inside `data` (asserted above); the stores end at i + 32 ≤ n, within both output rows.
        unsafe {
            let p = data.as_ptr().add(y * w + x_lo + i);
            let c = _mm256_loadu_si256(p.cast());
            let (mut min_of_max, mut max_of_min) = (ones, zero);
            for k in 0..8 {
                let a = _mm256_loadu_si256(p.offset(ring[k]).cast());
                let b = _mm256_loadu_si256(p.offset(ring[k + 8]).cast());
                min_of_max = _mm256_min_epu8(min_of_max, _mm256_max_epu8(a, b));
                max_of_min = _mm256_max_epu8(max_of_min, _mm256_min_epu8(a, b));
            }
            let lit = _mm256_andnot_si256(_mm256_cmpeq_epi8(c, zero), ones);
            // x > y ⇔ max(x, y) ≠ y, byte by byte.
            macro_rules! greater {
                ($x:expr, $y:expr) => {{
                    let y = $y;
                    _mm256_andnot_si256(_mm256_cmpeq_epi8(_mm256_max_epu8($x, y), y), ones)
                }};
            }
            macro_rules! maybe {
                ($t:expr) => {{
                    let bright = greater!(min_of_max, _mm256_adds_epu8(c, $t));
                    let dark = greater!(_mm256_subs_epu8(c, $t), max_of_min);
                    _mm256_and_si256(_mm256_and_si256(_mm256_or_si256(bright, dark), lit), one)
                }};
            }
            _mm256_storeu_si256(out_ini.as_mut_ptr().add(i).cast(), maybe!(thresholds.0));
            _mm256_storeu_si256(out_min.as_mut_ptr().add(i).cast(), maybe!(thresholds.1));
        }
        if i + 32 == n {
            break;
        }
        i = (i + 32).min(n - 32);
    }
}

/// [`candidates_row`] for rows `y_lo..y_hi` of a level, into masks the size of the level: with AVX2 where the
/// CPU has it ([`candidates_row_avx2`]), else the portable row (SSE2's vectors on x86-64, NEON on aarch64).
#[allow(clippy::too_many_arguments)]
pub(super) fn candidate_masks(
    level: &Level,
    y_lo: usize,
    y_hi: usize,
    x_lo: usize,
    x_hi: usize,
    t: (u8, u8),
    ini: &mut [u8],
    min: &mut [u8],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2 (checked above), the function's only requirement.
        let row = |data: &[u8], w, y, xs, t, out: (&mut [u8], &mut [u8])| unsafe {
            candidates_row_avx2(data, w, y, xs, t, out)
        };
        masks_with(level, (y_lo, y_hi), (x_lo, x_hi), t, (ini, min), row);
        return;
    }
    candidate_masks_portable(level, y_lo, y_hi, x_lo, x_hi, t, ini, min);
}

/// [`candidate_masks`] with the portable row only (the parity tests' reference).
#[allow(clippy::too_many_arguments)]
pub(super) fn candidate_masks_portable(
    level: &Level,
    y_lo: usize,
    y_hi: usize,
    x_lo: usize,
    x_hi: usize,
    t: (u8, u8),
    ini: &mut [u8],
    min: &mut [u8],
) {
    masks_with(level, (y_lo, y_hi), (x_lo, x_hi), t, (ini, min), candidates_row);
}

/// `row` (a [`candidates_row`]) on rows `y_lo..y_hi` of a level, into masks the size of the level.
#[inline(always)]
fn masks_with(
    level: &Level,
    (y_lo, y_hi): (usize, usize),
    (x_lo, x_hi): (usize, usize),
    t: (u8, u8),
    (ini, min): (&mut [u8], &mut [u8]),
    row: impl Fn(&[u8], usize, usize, (usize, usize), (u8, u8), (&mut [u8], &mut [u8])),
) {
    let w = level.w;
    for y in y_lo..y_hi {
        let span = y * w + x_lo..y * w + x_hi;
        row(&level.data, w, y, (x_lo, x_hi), t, (&mut ini[span.clone()], &mut min[span]));
    }
}

/// FAST scores of the 32 pixels from index `p` of a level (`w` wide) into `out`, for x86-64 with AVX2: every
/// pixel's score as [`fast_scores`] defines it, before the threshold — the best arc's smallest difference to the
/// centre, minus 1; 0 where that is below 1 or where the ring or the centre is black. A pixel is a corner at
/// threshold t when its score here is ≥ max(t, 1), and then [`fast_scores`] gives the same number. The ring's
/// rows are contiguous, so 32 pixels take whole-vector loads where [`fast_scores`] gathers 16 bytes per
/// candidate; in saturating bytes (a difference below 0 only ever loses to one above it) the arcs are the same
/// doubling windows. Where a cell has many candidates (textured tissue at HD's first level), scoring the cell
/// densely is cheaper than gathering them. Compared with [`fast_scores`] in the tests.
///
/// # Safety
/// The CPU must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn dense_scores_avx2(data: &[u8], w: usize, ring: &[isize; 16], p: usize, out: &mut [u8]) {
    use std::arch::x86_64::*;
    // The ring (`CIRCLE` as offsets in a level `w` wide) reaches 3 rows and 3 columns round each pixel; the
    // loads below rely on this.
    let reach = 3 * w + 3;
    assert!(ring.iter().all(|o| o.unsigned_abs() <= reach), "the ring of a level {w} wide");
    assert!(p >= reach && p + 32 + reach <= data.len(), "the FAST ring must fit the level");
    assert!(out.len() >= 32, "room for 32 scores");
    let zero = _mm256_setzero_si256();
    // SAFETY: every load reads 32 bytes from p plus a ring offset (or none), inside `data` (asserted above);
    // the store writes the first 32 bytes of `out` (asserted long enough).
    unsafe {
        let at = data.as_ptr().add(p);
        let c = _mm256_loadu_si256(at.cast());
        macro_rules! ring_at {
            ($k:expr) => {
                at.offset(ring[$k]).cast::<__m256i>()
            };
        }
        let mut black = _mm256_cmpeq_epi8(c, zero);
        for &offset in ring {
            black = _mm256_or_si256(black, _mm256_cmpeq_epi8(_mm256_loadu_si256(at.offset(offset).cast()), zero));
        }
        // The best arc of 9 by doubling windows (2, 4, 8, then 8 + 1), as in `fast_scores`, for the ring's
        // differences above the centre (`bright`) or below it (`dark`). One direction at a time, the ring
        // loaded again for each, keeps the windows in registers. A macro, not a function: a helper without
        // this function's target feature would call every intrinsic.
        macro_rules! diff {
            (bright, $v:expr) => {
                _mm256_subs_epu8($v, c)
            };
            (dark, $v:expr) => {
                _mm256_subs_epu8(c, $v)
            };
        }
        macro_rules! best_arc {
            ($dir:ident) => {{
                let mut m = [zero; 16];
                for k in 0..16 {
                    m[k] = diff!($dir, _mm256_loadu_si256(ring_at!(k)));
                }
                let m2: [__m256i; 16] = [
                    _mm256_min_epu8(m[0], m[1]),
                    _mm256_min_epu8(m[1], m[2]),
                    _mm256_min_epu8(m[2], m[3]),
                    _mm256_min_epu8(m[3], m[4]),
                    _mm256_min_epu8(m[4], m[5]),
                    _mm256_min_epu8(m[5], m[6]),
                    _mm256_min_epu8(m[6], m[7]),
                    _mm256_min_epu8(m[7], m[8]),
                    _mm256_min_epu8(m[8], m[9]),
                    _mm256_min_epu8(m[9], m[10]),
                    _mm256_min_epu8(m[10], m[11]),
                    _mm256_min_epu8(m[11], m[12]),
                    _mm256_min_epu8(m[12], m[13]),
                    _mm256_min_epu8(m[13], m[14]),
                    _mm256_min_epu8(m[14], m[15]),
                    _mm256_min_epu8(m[15], m[0]),
                ];
                let mut m4 = [zero; 16];
                for k in 0..16 {
                    m4[k] = _mm256_min_epu8(m2[k], m2[(k + 2) & 15]);
                }
                let mut best = zero;
                for k in 0..16 {
                    // Window of 8 from k, and the 9th sample loaded again.
                    let m8 = _mm256_min_epu8(m4[k], m4[(k + 4) & 15]);
                    let ninth = diff!($dir, _mm256_loadu_si256(ring_at!((k + 8) & 15)));
                    best = _mm256_max_epu8(best, _mm256_min_epu8(m8, ninth));
                }
                best
            }};
        }
        let best = _mm256_max_epu8(best_arc!(bright), best_arc!(dark));
        let score = _mm256_andnot_si256(black, _mm256_subs_epu8(best, _mm256_set1_epi8(1)));
        _mm256_storeu_si256(out.as_mut_ptr().cast(), score);
    }
}

/// Rows of a cell scored densely at the most (a cell is under 60 rows: see `detect_level`).
pub(super) const DENSE_ROWS: usize = 64;

/// Candidates scored together: the lanes of [`fast_scores`].
pub(super) const SCORE_LANES: usize = 16;

multiversion! {
    /// FAST scores of up to 16 pixels (`at`: their indices into `img`): the largest t for which each is still a
    /// 9-of-16 corner, 0 where it is none at `threshold` or where its ring touches black (outside the endoscope's
    /// view). The score of an arc of 9 is its smallest difference to the centre; the best arc is found by doubling
    /// windows round the ring (2, 4, 8, then 8 + 1). The candidates are the vector lanes: the ring is gathered into
    /// 16 rows of 16 lanes, then every step is an element-wise min/max over whole rows, which the compiler turns
    /// into vector instructions (one pixel at a time it is ~300 scalar instructions).
    fn fast_scores / fast_scores_portable(
        img: &[u8],
        ring: &[isize; 16],
        at: &[u32],
        threshold: u8,
        scores: &mut [u8; SCORE_LANES],
    ) {
        type Row = [i16; SCORE_LANES];
        let mut bright: [Row; 16] = [[0; SCORE_LANES]; 16];
        let mut black: Row = [0; SCORE_LANES];
        for (j, &p) in at.iter().take(SCORE_LANES).enumerate() {
            let c = i16::from(img[p as usize]);
            for k in 0..16 {
                let v = img[(p as isize + ring[k]) as usize];
                black[j] |= i16::from(v == 0);
                bright[k][j] = i16::from(v) - c;
            }
        }
        // Plain loops over fixed-size rows (closures and array::from_fn here defeat the vectoriser).
        #[inline(always)]
        fn best_arc(d: &[Row; 16]) -> Row {
            let (mut m2, mut m4, mut m8) =
                ([[0i16; SCORE_LANES]; 16], [[0i16; SCORE_LANES]; 16], [[0i16; SCORE_LANES]; 16]);
            for k in 0..16 {
                for j in 0..SCORE_LANES {
                    m2[k][j] = d[k][j].min(d[(k + 1) & 15][j]);
                }
            }
            for k in 0..16 {
                for j in 0..SCORE_LANES {
                    m4[k][j] = m2[k][j].min(m2[(k + 2) & 15][j]);
                }
            }
            for k in 0..16 {
                for j in 0..SCORE_LANES {
                    m8[k][j] = m4[k][j].min(m4[(k + 4) & 15][j]);
                }
            }
            let mut best = [i16::MIN; SCORE_LANES];
            for k in 0..16 {
                for j in 0..SCORE_LANES {
                    best[j] = best[j].max(m8[k][j].min(d[(k + 8) & 15][j]));
                }
            }
            best
        }
        let mut dark: [Row; 16] = [[0; SCORE_LANES]; 16];
        for k in 0..16 {
            for j in 0..SCORE_LANES {
                dark[k][j] = -bright[k][j];
            }
        }
        let (b, d) = (best_arc(&bright), best_arc(&dark));
        let t = i16::from(threshold);
        for j in 0..SCORE_LANES {
            let score = b[j].max(d[j]) - 1;
            scores[j] = if score >= t && black[j] == 0 { score.min(255) as u8 } else { 0 };
        }
    }
}

impl OrbExtractor {
    /// FAST per cell with the fallback threshold and 3×3 non-maximum suppression inside the cell (§1.3).
    #[inline(never)] // a stage of its own in profiles
    pub(super) fn detect_level(&mut self, l: usize) {
        let level = &self.levels[l];
        let (w, h) = (level.w, level.h);
        let ring: [isize; 16] = CIRCLE.map(|(dx, dy)| dy as isize * w as isize + dx as isize);
        let (min_x, min_y, max_x, max_y) = (FAST_MARGIN, FAST_MARGIN, w - FAST_MARGIN, h - FAST_MARGIN);
        let (wr, hr) = (max_x - min_x, max_y - min_y);
        let n_cols = (wr / 30).max(1);
        let n_rows = (hr / 30).max(1);
        let (w_cell, h_cell) = (wr.div_ceil(n_cols), hr.div_ceil(n_rows));
        self.corners.clear();
        // Candidates at both thresholds once per level on whole rows (vector code): cells then only visit
        // candidates. (On in-vivo images about half of the cells fall back to minThFAST.)
        let (ini, min) = (self.params.ini_th_fast, self.params.min_th_fast);
        let (x_lo, x_hi) = (min_x + 3, max_x - 3);
        let (cand_ini, cand_min) = (&mut self.cand_ini, &mut self.cand_min);
        candidate_masks(level, min_y + 3, max_y - 3, x_lo, x_hi, (ini, min), cand_ini, cand_min);
        let scores = &mut self.scores[..w * h];
        // Dense scoring of a cell ([`dense_scores_avx2`]) needs AVX2 and a level at least 38 wide (32 pixels
        // and the ring's 3 on either side).
        #[cfg(target_arch = "x86_64")]
        let dense_ok = w >= 38 && std::arch::is_x86_feature_detected!("avx2");
        #[cfg(not(target_arch = "x86_64"))]
        let dense_ok = false;
        for i in 0..n_rows {
            let y_start = min_y + i * h_cell;
            if y_start >= h - 3 - FAST_MARGIN {
                continue;
            }
            let y_end = (y_start + h_cell + 6).min(max_y);
            for j in 0..n_cols {
                let x_start = min_x + j * w_cell;
                if x_start >= w - 6 - FAST_MARGIN {
                    continue;
                }
                let x_end = (x_start + w_cell + 6).min(max_x);
                // The cell's detection area: 3 px inside its window (the FAST ring must fit).
                let (ya, yb, xa, xb) = (y_start + 3, y_end.saturating_sub(3), x_start + 3, x_end.saturating_sub(3));
                if ya >= yb || xa >= xb {
                    continue;
                }
                // The cell's dense scores do not depend on the threshold: made at most once per cell.
                #[cfg(target_arch = "x86_64")]
                let mut cell_scored = false;
                for threshold in [ini, min] {
                    self.hits.clear();
                    self.batch.clear();
                    let mask = if threshold == ini { &self.cand_ini } else { &self.cand_min };
                    for y in ya..yb {
                        // Eight mask bytes (0 or 1) as one word; each set byte is visited by its lowest bit. The
                        // last word of a row may reach past xb (into the next cell's mask): those bytes are cut.
                        for c in (xa..xb).step_by(8) {
                            let at = y * w + c;
                            // In bounds: the mask spans the level and this row is ≥ 3 rows above its end.
                            let eight = &mask[at..at + 8];
                            let mut bits = u64::from_le_bytes(std::array::from_fn(|i| eight[i]));
                            if xb - c < 8 {
                                bits &= (1u64 << (8 * (xb - c))) - 1;
                            }
                            while bits != 0 {
                                let x = c + (bits.trailing_zeros() / 8) as usize;
                                bits &= bits - 1;
                                self.batch.push((y * w + x) as u32);
                            }
                        }
                    }
                    // Scoring costs ~210 instructions a candidate gathered (16 to a call), ~21 a pixel scored
                    // densely (callgrind, the abdomen at 720p): a cell with more than 1 candidate in 10 pixels is
                    // scored densely. Both give the same scores.
                    let dense = dense_ok && self.batch.len() * 10 > (yb - ya) * (xb - xa) && yb - ya <= DENSE_ROWS;
                    #[cfg(target_arch = "x86_64")]
                    if dense {
                        let start = xa.min(w - 35);
                        if !cell_scored {
                            for y in ya..yb {
                                let mut x = start;
                                loop {
                                    let out = &mut self.cell_scores[(y - ya) * w + x..][..32];
                                    // SAFETY: `dense_ok` holds only where the CPU has AVX2.
                                    unsafe { dense_scores_avx2(&level.data, w, &ring, y * w + x, out) };
                                    if x + 32 >= xb {
                                        break;
                                    }
                                    x = (x + 32).min(w - 35);
                                }
                            }
                            cell_scored = true;
                        }
                        let at_least = threshold.max(1);
                        for &p in &self.batch {
                            let (x, y) = (p as usize % w, p as usize / w);
                            let s = self.cell_scores[(y - ya) * w + x];
                            if s >= at_least {
                                scores[p as usize] = s;
                                self.hits.push(Corner { x: x as u16, y: y as u16, response: s });
                            }
                        }
                    }
                    if !dense {
                        for batch in self.batch.chunks(SCORE_LANES) {
                            let mut batch_scores = [0u8; SCORE_LANES];
                            fast_scores(&level.data, &ring, batch, threshold, &mut batch_scores);
                            for (&p, &s) in batch.iter().zip(&batch_scores) {
                                if s > 0 {
                                    scores[p as usize] = s;
                                    let (x, y) = (p as usize % w, p as usize / w);
                                    self.hits.push(Corner { x: x as u16, y: y as u16, response: s });
                                }
                            }
                        }
                    }
                    // 3×3 non-maximum suppression inside the cell, over the corners only; ties go to the first in
                    // raster order. The score map is cleared again where it was written.
                    // Outside the cell the score map is 0 (it is cleared after every cell) and the cell is ≥ 3 px
                    // inside the level, so the 8 neighbours need no bounds: an earlier neighbour (in raster order)
                    // suppresses at an equal score, a later one only at a higher score.
                    for &hit in &self.hits {
                        let (x, y, s) = (usize::from(hit.x), usize::from(hit.y), hit.response);
                        let (up, here, down) = ((y - 1) * w + x, y * w + x, (y + 1) * w + x);
                        let earlier = scores[up - 1].max(scores[up]).max(scores[up + 1]).max(scores[here - 1]);
                        let later = scores[here + 1].max(scores[down - 1]).max(scores[down]).max(scores[down + 1]);
                        if earlier < s && later <= s {
                            self.corners.push(hit);
                        }
                    }
                    for hit in &self.hits {
                        scores[usize::from(hit.y) * w + usize::from(hit.x)] = 0;
                    }
                    if !self.hits.is_empty() || threshold == self.params.min_th_fast {
                        break;
                    }
                }
            }
        }
    }
}
