//! Matching utilities for the tracker: the frame's cell grid for area queries (ORB-SLAM2-STEREO.md §3.1) and
//! the rotation-consistency filter (§4). Hamming distance is [`crate::hamming`].
//! Both own their buffers and reuse them, so a warmed-up frame allocates nothing here.

use crate::extract::KeyPoint;
use std::ops::RangeInclusive;

/// Grid size of §3.1.
pub const GRID_COLS: usize = 64;
pub const GRID_ROWS: usize = 48;

/// A frame's keypoints binned into 64 × 48 cells over the image bounds (a counting sort: one list of keypoint
/// indices, cell by cell). Cells are found with floor, so keypoints in the last half column or row are kept
/// (ORB-SLAM2 rounds and silently drops them, §10.1 #5).
#[derive(Debug)]
pub struct FeatureGrid {
    min_x: f32,
    min_y: f32,
    /// Cells per pixel in x and y.
    inv_cell_w: f32,
    inv_cell_h: f32,
    /// `starts[c]..starts[c + 1]` is cell c's range in `indices` (c = row · 64 + col).
    starts: Vec<u32>,
    indices: Vec<u32>,
    cell_of: Vec<u32>,
}

impl Clone for FeatureGrid {
    fn clone(&self) -> Self {
        Self {
            min_x: self.min_x,
            min_y: self.min_y,
            inv_cell_w: self.inv_cell_w,
            inv_cell_h: self.inv_cell_h,
            starts: self.starts.clone(),
            indices: self.indices.clone(),
            cell_of: self.cell_of.clone(),
        }
    }

    /// Reuses this grid's buffers (a frame copied every frame must not allocate).
    fn clone_from(&mut self, other: &Self) {
        (self.min_x, self.min_y, self.inv_cell_w, self.inv_cell_h) =
            (other.min_x, other.min_y, other.inv_cell_w, other.inv_cell_h);
        self.starts.clone_from(&other.starts);
        self.indices.clone_from(&other.indices);
        self.cell_of.clone_from(&other.cell_of);
    }
}

impl FeatureGrid {
    /// A grid over `[0, width] × [0, height]` (rectified stereo has no undistortion, §1.7).
    pub fn new(width: f32, height: f32) -> Self {
        Self::with_bounds(0.0..=width, 0.0..=height)
    }

    pub fn with_bounds(x: RangeInclusive<f32>, y: RangeInclusive<f32>) -> Self {
        let (w, h) = ((x.end() - x.start()).max(1.0), (y.end() - y.start()).max(1.0));
        Self {
            min_x: *x.start(),
            min_y: *y.start(),
            inv_cell_w: GRID_COLS as f32 / w,
            inv_cell_h: GRID_ROWS as f32 / h,
            starts: vec![0; GRID_COLS * GRID_ROWS + 1],
            indices: Vec::new(),
            cell_of: Vec::new(),
        }
    }

    fn cell(&self, x: f32, y: f32) -> Option<(usize, usize)> {
        let (cx, cy) = (((x - self.min_x) * self.inv_cell_w).floor(), ((y - self.min_y) * self.inv_cell_h).floor());
        // Keypoints exactly on the far bound belong to the last cell.
        let (cx, cy) =
            (if cx == GRID_COLS as f32 { cx - 1.0 } else { cx }, if cy == GRID_ROWS as f32 { cy - 1.0 } else { cy });
        ((0.0..GRID_COLS as f32).contains(&cx) && (0.0..GRID_ROWS as f32).contains(&cy))
            .then_some((cx as usize, cy as usize))
    }

    /// Bins `keypoints` (replacing what the grid held). Keypoints outside the bounds are left out.
    pub fn build(&mut self, keypoints: &[KeyPoint]) {
        const OUT: u32 = u32::MAX;
        self.cell_of.clear();
        self.starts.fill(0);
        for kp in keypoints {
            let c = self.cell(kp.x, kp.y).map_or(OUT, |(cx, cy)| (cy * GRID_COLS + cx) as u32);
            self.cell_of.push(c);
            if c != OUT {
                self.starts[c as usize + 1] += 1;
            }
        }
        for c in 0..GRID_COLS * GRID_ROWS {
            self.starts[c + 1] += self.starts[c];
        }
        let total = self.starts[GRID_COLS * GRID_ROWS] as usize;
        self.indices.clear();
        self.indices.resize(total, 0);
        // Fill each cell from its start; `starts` is shifted by one cell meanwhile and restored after.
        for (i, &c) in self.cell_of.iter().enumerate() {
            if c != OUT {
                let slot = &mut self.starts[c as usize];
                self.indices[*slot as usize] = i as u32;
                *slot += 1;
            }
        }
        for c in (1..=GRID_COLS * GRID_ROWS).rev() {
            self.starts[c] = self.starts[c - 1];
        }
        self.starts[0] = 0;
    }

    /// Indices of the keypoints with |x − kp.x| < r, |y − kp.y| < r (a square, as in §3.1) and an octave in
    /// `octaves`, into `out` (cleared first), in cell order. `keypoints` are those given to [`Self::build`].
    pub fn features_in_area(
        &self,
        keypoints: &[KeyPoint],
        (x, y): (f32, f32),
        r: f32,
        octaves: RangeInclusive<u8>,
        out: &mut Vec<usize>,
    ) {
        out.clear();
        let col = |v: f32| ((v - self.min_x) * self.inv_cell_w).floor().clamp(0.0, GRID_COLS as f32 - 1.0) as usize;
        let row = |v: f32| ((v - self.min_y) * self.inv_cell_h).floor().clamp(0.0, GRID_ROWS as f32 - 1.0) as usize;
        if !(x.is_finite() && y.is_finite() && r.is_finite()) {
            return;
        }
        let (c0, c1, r0, r1) = (col(x - r), col(x + r), row(y - r), row(y + r));
        for cy in r0..=r1 {
            for cx in c0..=c1 {
                let c = cy * GRID_COLS + cx;
                for &i in &self.indices[self.starts[c] as usize..self.starts[c + 1] as usize] {
                    let kp = &keypoints[i as usize];
                    if (kp.x - x).abs() < r && (kp.y - y).abs() < r && octaves.contains(&kp.octave) {
                        out.push(i as usize);
                    }
                }
            }
        }
    }
}

/// How match rotations are binned by [`RotationHistogram`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RotationBins {
    /// Bin width in degrees; bins are centred on its multiples (index = round(rotation / width)).
    pub width_deg: f32,
    /// Whether the bin at 360° is the bin at 0°.
    pub wrap: bool,
}

impl RotationBins {
    /// ORB-SLAM2's behaviour (§4, §10.1 #6): 30° bins, 0° and 360° apart: 13 bins.
    pub const FAITHFUL: Self = Self { width_deg: 30.0, wrap: false };
    /// What ORB-SLAM2 meant: 30 bins of 12° round the circle.
    pub const INTENDED: Self = Self { width_deg: 12.0, wrap: true };

    fn count(&self) -> usize {
        let n = (360.0 / self.width_deg).round() as usize;
        if self.wrap { n.max(1) } else { n + 1 }
    }

    fn bin(&self, rotation_deg: f32) -> usize {
        let n = self.count();
        let b = (rotation_deg.rem_euclid(360.0) / self.width_deg).round() as usize;
        if self.wrap { b % n } else { b.min(n - 1) }
    }
}

impl Default for RotationBins {
    fn default() -> Self {
        Self::FAITHFUL
    }
}

/// Rotation-consistency filter (§4): matches vote with their keypoint angle difference; those outside the three
/// most populated bins are rejected, and the 2nd and 3rd bins count only when they hold ≥ 10 % of the 1st.
#[derive(Debug, Clone)]
pub struct RotationHistogram {
    bins: RotationBins,
    members: Vec<Vec<u32>>,
}

impl RotationHistogram {
    pub fn new(bins: RotationBins) -> Self {
        Self { bins, members: vec![Vec::new(); bins.count()] }
    }

    /// Room for `matches` votes in every bin (they usually all fall in one), so that voting allocates nothing.
    pub fn with_capacity(bins: RotationBins, matches: usize) -> Self {
        // Not `vec![Vec::with_capacity(matches); n]`: that clones the first bin, and a clone keeps the length,
        // not the capacity, so every bin but the last started empty and grew on a frame's first votes there.
        Self { bins, members: (0..bins.count()).map(|_| Vec::with_capacity(matches)).collect() }
    }

    pub fn clear(&mut self) {
        for m in &mut self.members {
            m.clear();
        }
    }

    /// Votes for match `id` with the angles (degrees) of its two keypoints.
    pub fn add(&mut self, id: u32, angle_a_deg: f32, angle_b_deg: f32) {
        let b = self.bins.bin(angle_a_deg - angle_b_deg);
        self.members[b].push(id);
    }

    /// The ids to drop, into `out` (cleared first). Ties between bins go to the lower bin.
    pub fn rejected(&self, out: &mut Vec<u32>) {
        out.clear();
        let mut top = [(0usize, usize::MAX); 3];
        for (b, m) in self.members.iter().enumerate() {
            let n = m.len();
            if n > top[0].0 {
                top = [(n, b), top[0], top[1]];
            } else if n > top[1].0 {
                top = [top[0], (n, b), top[1]];
            } else if n > top[2].0 {
                top[2] = (n, b);
            }
        }
        let first = top[0].0 as f32;
        if (top[1].0 as f32) < 0.1 * first {
            top[1].1 = usize::MAX;
            top[2].1 = usize::MAX;
        } else if (top[2].0 as f32) < 0.1 * first {
            top[2].1 = usize::MAX;
        }
        for (b, m) in self.members.iter().enumerate() {
            if !top.iter().any(|&(_, kept)| kept == b) {
                out.extend_from_slice(m);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kp(x: f32, y: f32, octave: u8) -> KeyPoint {
        KeyPoint { x, y, octave, ..KeyPoint::default() }
    }

    #[test]
    fn area_queries_equal_a_brute_force_search() {
        // Pseudo-random keypoints, plus some on the bounds and in the last half cell.
        let mut state = 12345u64;
        let mut next = |n: f32| {
            state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            (state >> 40) as f32 / (1u64 << 24) as f32 * n
        };
        let mut kps: Vec<KeyPoint> = (0..3000).map(|_| kp(next(640.0), next(480.0), (next(8.0)) as u8)).collect();
        kps.extend([kp(0.0, 0.0, 0), kp(640.0, 480.0, 0), kp(639.9, 479.9, 1), kp(635.0, 10.0, 0), kp(700.0, 10.0, 0)]);
        let mut grid = FeatureGrid::new(640.0, 480.0);
        grid.build(&kps);
        let mut got = Vec::new();
        for (x, y, r, oct) in [
            (320.0, 240.0, 15.0, 0..=7),
            (5.0, 5.0, 40.0, 0..=0),
            (638.0, 478.0, 6.0, 0..=7),
            (100.0, 400.0, 3.0, 2..=3),
        ] {
            grid.features_in_area(&kps, (x, y), r, oct.clone(), &mut got);
            got.sort_unstable();
            let want: Vec<usize> = (0..kps.len())
                .filter(|&i| (kps[i].x - x).abs() < r && (kps[i].y - y).abs() < r && oct.contains(&kps[i].octave))
                .filter(|&i| kps[i].x <= 640.0)
                .collect();
            assert_eq!(got, want, "query at ({x}, {y}) r {r}");
        }
        // The last half column is kept (ORB-SLAM2 drops it); a keypoint past the bounds is not binned.
        grid.features_in_area(&kps, (637.0, 10.0), 5.0, 0..=7, &mut got);
        assert!(got.contains(&3003));
        grid.features_in_area(&kps, (700.0, 10.0), 5.0, 0..=7, &mut got);
        assert!(got.is_empty());
    }

    #[test]
    fn the_rotation_filter_keeps_the_consistent_matches() {
        let mut h = RotationHistogram::new(RotationBins::FAITHFUL);
        // 50 matches rotated by ~10°, 8 by ~95°, 4 by ~200° (< 10 % of 50: dropped), 3 by ~300°.
        let mut id = 0;
        for (rot, n) in [(10.0f32, 50), (95.0, 8), (200.0, 4), (300.0, 3)] {
            for k in 0..n {
                h.add(id, 100.0 + rot + (k % 5) as f32, 100.0);
                id += 1;
            }
        }
        let mut rejected = Vec::new();
        h.rejected(&mut rejected);
        assert_eq!(rejected.len(), 4 + 3, "{rejected:?}");
        assert!(rejected.iter().all(|&i| i >= 58));
        // Faithful bins: 358° and 2° fall in different bins (round(358/30) = 12, round(2/30) = 0) …
        let mut h = RotationHistogram::new(RotationBins::FAITHFUL);
        for i in 0..10 {
            h.add(i, if i < 5 { 358.0 } else { 2.0 }, 0.0);
        }
        h.add(10, 180.0, 0.0);
        h.rejected(&mut rejected);
        assert_eq!(rejected, Vec::<u32>::new(), "three bins of 5, 5 and 1 are all kept");
        // … with the intended 12° bins and wrap-around they are one bin.
        let mut h = RotationHistogram::new(RotationBins::INTENDED);
        for i in 0..20 {
            h.add(i, if i % 2 == 0 { 358.0 } else { 2.0 }, 0.0);
        }
        h.add(20, 180.0, 0.0);
        h.add(21, 90.0, 0.0);
        h.rejected(&mut rejected);
        assert_eq!(rejected, vec![21, 20], "one bin of 20; 1 < 10 % of 20");
    }

    #[test]
    fn every_bin_of_a_histogram_with_capacity_has_that_capacity() {
        let h = RotationHistogram::with_capacity(RotationBins::FAITHFUL, 500);
        assert!(h.members.len() > 1 && h.members.iter().all(|m| m.capacity() >= 500));
    }
}
