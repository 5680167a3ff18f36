//! ORB extraction (ORB-SLAM2-STEREO.md §1): scale pyramid, FAST-9 per grid cell with a fallback threshold,
//! quadtree distribution, intensity-centroid orientation, rotated BRIEF on a Gaussian-smoothed level.
//! Every buffer is owned by the [`OrbExtractor`] and reused.

use crate::pattern;

/// Extractor settings (`ORBextractor.*`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrbParams {
    pub n_features: u32,
    pub scale_factor: f64,
    pub n_levels: u32,
    pub ini_th_fast: u8,
    pub min_th_fast: u8,
}

impl Default for OrbParams {
    fn default() -> Self {
        Self { n_features: 1000, scale_factor: 1.2, n_levels: 8, ini_th_fast: 20, min_th_fast: 7 }
    }
}

impl OrbParams {
    pub fn from_settings(s: &bdis_core::settings::OrbSettings) -> Self {
        Self {
            n_features: s.n_features,
            scale_factor: s.scale_factor,
            n_levels: s.n_levels,
            ini_th_fast: s.ini_th_fast.min(255) as u8,
            min_th_fast: s.min_th_fast.min(255) as u8,
        }
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum OrbError {
    #[error("ORBextractor.{key}: {message}")]
    Param { key: &'static str, message: String },
    #[error("image {w}×{h} is too small for {levels} levels at scale {scale} (every level needs ≥ 62 px)")]
    TooSmall { w: usize, h: usize, levels: u32, scale: f64 },
    #[error("image buffer holds {len} bytes, {w}×{h} needs {needed}")]
    Buffer { len: usize, w: usize, h: usize, needed: usize },
}

/// A keypoint in level-0 pixels.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct KeyPoint {
    pub x: f32,
    pub y: f32,
    pub octave: u8,
    /// Degrees in [0, 360).
    pub angle: f32,
    pub response: f32,
    /// Patch diameter at level 0: 31·s^octave.
    pub size: f32,
}

/// Keypoints and their 256-bit descriptors, in the same order (level 0 first).
#[derive(Debug, Clone, Default)]
pub struct Features {
    pub keypoints: Vec<KeyPoint>,
    pub descriptors: Vec<[u8; 32]>,
}

/// An 8-bit image level.
#[derive(Debug, Clone, Default)]
pub struct Level {
    pub w: usize,
    pub h: usize,
    pub data: Vec<u8>,
}

impl Level {
    #[inline(always)]
    pub fn at(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.w + x]
    }
}

/// Half-widths of the orientation disc's rows (radius 15), symmetric under transposition.
const UMAX: [i32; 16] = [15, 15, 15, 15, 14, 14, 14, 13, 13, 12, 11, 10, 9, 8, 6, 3];
const FAST_MARGIN: usize = 16;
/// The Bresenham circle of radius 3, in order around it.
const CIRCLE: [(i32, i32); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// A bilinear tap: source index, next source index, weight of the next one in 1/256.
type Tap = (u16, u16, u8);

#[derive(Debug, Clone, Copy)]
struct Corner {
    x: u16,
    y: u16,
    response: u8,
}

/// ORB extractor for one image size.
#[derive(Debug)]
pub struct OrbExtractor {
    params: OrbParams,
    /// Features wanted per level.
    per_level: Vec<usize>,
    scales: Vec<f64>,
    pub levels: Vec<Level>,
    blurred: Vec<Level>,
    blur_tmp: Vec<u16>,
    blur_acc: Vec<u32>,
    /// Per level: bilinear taps (index, index, weight of the second in 1/256) for columns and rows.
    taps: Vec<(Vec<Tap>, Vec<Tap>)>,
    /// The pattern rotated to each whole degree: 360 × 256 pairs of (dx, dy) offsets.
    rotated: Vec<[(i8, i8); 2]>,
    scores: Vec<u8>,
    cand_ini: Vec<u8>,
    cand_min: Vec<u8>,
    hits: Vec<u32>,
    corners: Vec<Corner>,
    nodes: Vec<Node>,
    next_nodes: Vec<Node>,
    members: Vec<u32>,
    next_members: Vec<u32>,
    kept: Vec<Corner>,
    width: usize,
    height: usize,
}

/// A quadtree node: a rectangle and the range of its corners in the member list.
#[derive(Debug, Clone, Copy)]
struct Node {
    x0: f32,
    y0: f32,
    x1: f32,
    y1: f32,
    start: u32,
    count: u32,
}

/// FAST score of `p`: the largest t for which p is still a 9-of-16 corner (0 if it is none at `threshold`).
#[inline]
fn fast_score(img: &[u8], w: usize, x: usize, y: usize, ring: &[isize; 16], threshold: u8) -> u8 {
    let base = (y * w + x) as isize;
    let c = img[base as usize] as i16;
    let t = threshold as i16;
    // Quick reject on the four compass points: any 9-arc of 16 contains at least two of them.
    let (mut bright, mut dark) = (0, 0);
    for k in [0usize, 4, 8, 12] {
        let d = img[(base + ring[k]) as usize] as i16 - c;
        bright += i32::from(d > t);
        dark += i32::from(d < -t);
    }
    if bright < 2 && dark < 2 {
        return 0;
    }
    // Black pixels are outside the endoscope's view: never a corner on or next to them.
    if c == 0 {
        return 0;
    }
    let mut d = [0i16; 16];
    let (mut bright_mask, mut dark_mask) = (0u32, 0u32);
    for k in 0..16 {
        let v = img[(base + ring[k]) as usize];
        if v == 0 {
            return 0;
        }
        d[k] = v as i16 - c;
        bright_mask |= u32::from(d[k] > t) << k;
        dark_mask |= u32::from(d[k] < -t) << k;
    }
    // A corner needs 9 contiguous ring pixels on one side: test it on the bit masks (wrapped to 32 bits) before
    // computing the score, which only corners need.
    let nine = |m: u32| {
        let mut m = m | (m << 16);
        for _ in 0..8 {
            m &= m >> 1;
        }
        m & 0xffff != 0
    };
    if !nine(bright_mask) && !nine(dark_mask) {
        return 0;
    }
    // Largest over the 16 arcs of 9 of the smallest difference in the arc (bright), likewise for dark.
    let (mut best_b, mut best_d) = (i16::MIN, i16::MIN);
    for start in 0..16 {
        let (mut mn_b, mut mn_d) = (i16::MAX, i16::MAX);
        for k in 0..9 {
            let v = d[(start + k) & 15];
            mn_b = mn_b.min(v);
            mn_d = mn_d.min(-v);
        }
        best_b = best_b.max(mn_b);
        best_d = best_d.max(mn_d);
    }
    let score = best_b.max(best_d) - 1;
    if score >= t { score.min(255) as u8 } else { 0 }
}

impl OrbExtractor {
    pub fn new(params: OrbParams, width: usize, height: usize) -> Result<Self, OrbError> {
        let bad = |key, message: String| Err(OrbError::Param { key, message });
        if params.n_features == 0 {
            return bad("nFeatures", "must be ≥ 1".into());
        }
        if !(params.scale_factor.is_finite() && params.scale_factor > 1.0) {
            return bad("scaleFactor", format!("must be a number > 1, found {}", params.scale_factor));
        }
        if params.n_levels == 0 || params.n_levels > 32 {
            return bad("nLevels", format!("must be in 1..=32, found {}", params.n_levels));
        }
        if params.min_th_fast == 0 || params.ini_th_fast < params.min_th_fast {
            return bad(
                "minThFAST",
                format!("need 1 ≤ minThFAST ≤ iniThFAST, found {} and {}", params.min_th_fast, params.ini_th_fast),
            );
        }
        let scales: Vec<f64> = (0..params.n_levels).map(|l| params.scale_factor.powi(l as i32)).collect();
        let sizes: Vec<(usize, usize)> = scales
            .iter()
            .map(|s| ((width as f64 / s).round() as usize, (height as f64 / s).round() as usize))
            .collect();
        if sizes.iter().any(|&(w, h)| w < 62 || h < 62) {
            return Err(OrbError::TooSmall {
                w: width,
                h: height,
                levels: params.n_levels,
                scale: params.scale_factor,
            });
        }
        // Features per level: a geometric series (§1.2), the last level takes the remainder.
        let n = f64::from(params.n_features);
        let f = 1.0 / params.scale_factor;
        let n0 = n * (1.0 - f) / (1.0 - f.powi(params.n_levels as i32));
        let mut per_level: Vec<usize> =
            (0..params.n_levels as usize - 1).map(|l| (n0 * f.powi(l as i32)).round() as usize).collect();
        let used: usize = per_level.iter().sum();
        per_level.push((params.n_features as usize).saturating_sub(used));
        let levels: Vec<Level> = sizes.iter().map(|&(w, h)| Level { w, h, data: vec![0; w * h] }).collect();
        let axis = |src: usize, dst: usize| -> Vec<Tap> {
            let f = src as f64 / dst as f64;
            (0..dst)
                .map(|x| {
                    let sx = ((x as f64 + 0.5) * f - 0.5).max(0.0);
                    let x0 = (sx as usize).min(src - 1);
                    let x1 = (x0 + 1).min(src - 1);
                    (x0 as u16, x1 as u16, ((sx - x0 as f64) * 256.0).round().min(255.0) as u8)
                })
                .collect()
        };
        let taps = (0..levels.len())
            .map(|l| {
                if l == 0 {
                    (Vec::new(), Vec::new())
                } else {
                    (axis(sizes[l - 1].0, sizes[l].0), axis(sizes[l - 1].1, sizes[l].1))
                }
            })
            .collect();
        Ok(Self {
            params,
            per_level,
            scales,
            blurred: levels.clone(),
            levels,
            blur_tmp: vec![0; width * height],
            blur_acc: vec![0; width],
            taps,
            rotated: rotate_pattern(&pattern::generate()),
            scores: vec![0; width * height],
            cand_ini: vec![0; width * height],
            cand_min: vec![0; width * height],
            hits: Vec::with_capacity(4096),
            corners: Vec::with_capacity(8192),
            nodes: Vec::with_capacity(4096),
            next_nodes: Vec::with_capacity(4096),
            members: Vec::with_capacity(8192),
            next_members: Vec::with_capacity(8192),
            kept: Vec::with_capacity(4096),
            width,
            height,
        })
    }

    pub fn params(&self) -> &OrbParams {
        &self.params
    }

    pub fn scales(&self) -> &[f64] {
        &self.scales
    }

    /// Extracts features of a `width`×`height` grey image into `out` (its buffers are reused).
    pub fn extract(&mut self, image: &[u8], out: &mut Features) -> Result<(), OrbError> {
        let (w, h) = (self.width, self.height);
        if image.len() < w * h {
            return Err(OrbError::Buffer { len: image.len(), w, h, needed: w * h });
        }
        self.build_pyramid(&image[..w * h]);
        out.keypoints.clear();
        out.descriptors.clear();
        for l in 0..self.levels.len() {
            self.detect_level(l);
            self.distribute(l);
            blur_level(&self.levels[l], &mut self.blurred[l], &mut self.blur_tmp, &mut self.blur_acc);
            let scale = self.scales[l] as f32;
            for &c in &self.kept {
                let (x, y) = (usize::from(c.x), usize::from(c.y));
                let angle = orientation(&self.levels[l], x, y);
                // The pattern turned to the nearest whole degree (a table, instead of 512 rotations per keypoint).
                let bin = (angle.to_degrees().rem_euclid(360.0).round() as usize) % 360;
                out.descriptors.push(describe_rotated(
                    &self.blurred[l],
                    x,
                    y,
                    &self.rotated[bin * 256..(bin + 1) * 256],
                ));
                out.keypoints.push(KeyPoint {
                    x: c.x as f32 * scale,
                    y: c.y as f32 * scale,
                    octave: l as u8,
                    angle: angle.to_degrees().rem_euclid(360.0),
                    response: f32::from(c.response),
                    size: 31.0 * scale,
                });
            }
        }
        Ok(())
    }

    /// Level 0 is the image; level l is level l−1 resized bilinearly (OpenCV INTER_LINEAR, §1.1), in 8-bit
    /// fixed point with taps computed once per size.
    fn build_pyramid(&mut self, image: &[u8]) {
        self.levels[0].data.copy_from_slice(image);
        for l in 1..self.levels.len() {
            let (prev, rest) = self.levels.split_at_mut(l);
            let (src, dst) = (&prev[l - 1], &mut rest[0]);
            let (x_taps, y_taps) = (&self.taps[l].0, &self.taps[l].1);
            for (y, &(y0, y1, wy)) in y_taps.iter().enumerate() {
                let (r0, r1) = (&src.data[y0 as usize * src.w..][..src.w], &src.data[y1 as usize * src.w..][..src.w]);
                let out = &mut dst.data[y * dst.w..(y + 1) * dst.w];
                let wy = u32::from(wy);
                for (o, &(x0, x1, wx)) in out.iter_mut().zip(x_taps) {
                    let (a, b, c, d) = (r0[x0 as usize], r0[x1 as usize], r1[x0 as usize], r1[x1 as usize]);
                    let wx = u32::from(wx);
                    let top = u32::from(a) * (256 - wx) + u32::from(b) * wx;
                    let bottom = u32::from(c) * (256 - wx) + u32::from(d) * wx;
                    let v = ((top * (256 - wy) + bottom * wy + 32768) >> 16) as u8;
                    // A pixel whose footprint touches black stays black (the view's edge must not become texture).
                    *o = if a == 0 || b == 0 || c == 0 || d == 0 { 0 } else { v.max(1) };
                }
            }
        }
    }

    /// FAST per cell with the fallback threshold and 3×3 non-maximum suppression inside the cell (§1.3).
    fn detect_level(&mut self, l: usize) {
        let level = &self.levels[l];
        let (w, h) = (level.w, level.h);
        let ring: [isize; 16] = CIRCLE.map(|(dx, dy)| dy as isize * w as isize + dx as isize);
        let (min_x, min_y, max_x, max_y) = (FAST_MARGIN, FAST_MARGIN, w - FAST_MARGIN, h - FAST_MARGIN);
        let (wr, hr) = (max_x - min_x, max_y - min_y);
        let n_cols = (wr / 30).max(1);
        let n_rows = (hr / 30).max(1);
        let (w_cell, h_cell) = (wr.div_ceil(n_cols), hr.div_ceil(n_rows));
        self.corners.clear();
        // Candidates for both thresholds, once per level, on whole rows (vector code): at least two of the four
        // compass points of the ring are brighter, or two darker, than the centre by the threshold. Cells then
        // only visit candidates.
        let (ini, min) = (self.params.ini_th_fast, self.params.min_th_fast);
        let (x_lo, x_hi) = (min_x + 3, max_x - 3);
        for y in (min_y + 3)..(max_y - 3) {
            let at = |dy: isize, dx: isize| {
                let start = ((y as isize + dy) as usize) * w;
                &level.data
                    [(start as isize + x_lo as isize + dx) as usize..(start as isize + x_hi as isize + dx) as usize]
            };
            let (centre, north, south, east, west) = (at(0, 0), at(-3, 0), at(3, 0), at(0, 3), at(0, -3));
            let (mask_ini, mask_min) =
                (&mut self.cand_ini[y * w + x_lo..y * w + x_hi], &mut self.cand_min[y * w + x_lo..y * w + x_hi]);
            for i in 0..centre.len() {
                let c = centre[i];
                let (n, s, e, wv) = (north[i], south[i], east[i], west[i]);
                let test = |t: u8| {
                    let (hi, lo) = (c.saturating_add(t), c.saturating_sub(t));
                    let b = u8::from(n > hi) + u8::from(s > hi) + u8::from(e > hi) + u8::from(wv > hi);
                    let d = u8::from(n < lo) + u8::from(s < lo) + u8::from(e < lo) + u8::from(wv < lo);
                    u8::from(b >= 2 || d >= 2)
                };
                mask_ini[i] = test(ini);
                mask_min[i] = test(min);
            }
        }
        let scores = &mut self.scores[..w * h];
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
                for threshold in [self.params.ini_th_fast, self.params.min_th_fast] {
                    self.hits.clear();
                    let mask = if threshold == ini { &self.cand_ini } else { &self.cand_min };
                    for y in ya..yb {
                        let row = &mask[y * w + xa..y * w + xb];
                        // Skip eight non-candidates at a time.
                        for (ci, chunk) in row.chunks(8).enumerate() {
                            if chunk.iter().all(|&m| m == 0) {
                                continue;
                            }
                            for (k, _) in chunk.iter().enumerate().filter(|(_, m)| **m != 0) {
                                let x = xa + ci * 8 + k;
                                let s = fast_score(&level.data, w, x, y, &ring, threshold);
                                if s > 0 {
                                    scores[y * w + x] = s;
                                    self.hits.push((y * w + x) as u32);
                                }
                            }
                        }
                    }
                    // 3×3 non-maximum suppression inside the cell, over the corners only; ties go to the first in
                    // raster order. The score map is cleared again where it was written.
                    for &k in &self.hits {
                        let (x, y) = (k as usize % w, k as usize / w);
                        let s = scores[k as usize];
                        let mut is_max = true;
                        'nms: for ny in y.saturating_sub(1).max(ya)..(y + 2).min(yb) {
                            for nx in x.saturating_sub(1).max(xa)..(x + 2).min(xb) {
                                let o = scores[ny * w + nx];
                                if o > s || (o == s && (ny, nx) < (y, x)) {
                                    is_max = false;
                                    break 'nms;
                                }
                            }
                        }
                        if is_max {
                            self.corners.push(Corner { x: x as u16, y: y as u16, response: s });
                        }
                    }
                    for &k in &self.hits {
                        scores[k as usize] = 0;
                    }
                    if !self.hits.is_empty() || threshold == self.params.min_th_fast {
                        break;
                    }
                }
            }
        }
    }

    /// Quadtree distribution keeping the strongest corner of each node (§1.4); result in `self.kept`.
    fn distribute(&mut self, l: usize) {
        let want = self.per_level[l];
        self.kept.clear();
        if self.corners.is_empty() || want == 0 {
            return;
        }
        let level = &self.levels[l];
        let (x0, y0, x1, y1) =
            (FAST_MARGIN as f32, FAST_MARGIN as f32, (level.w - FAST_MARGIN) as f32, (level.h - FAST_MARGIN) as f32);
        let n_ini = (((x1 - x0) / (y1 - y0)).round() as usize).max(1);
        let strip = (x1 - x0) / n_ini as f32;
        self.nodes.clear();
        self.members.clear();
        for k in 0..n_ini {
            let (nx0, nx1) = (x0 + k as f32 * strip, x0 + (k + 1) as f32 * strip);
            let start = self.members.len() as u32;
            for (i, c) in self.corners.iter().enumerate() {
                let cx = f32::from(c.x);
                let inside = cx >= nx0 && (cx < nx1 || k == n_ini - 1);
                if inside {
                    self.members.push(i as u32);
                }
            }
            let count = self.members.len() as u32 - start;
            if count > 0 {
                self.nodes.push(Node { x0: nx0, y0, x1: nx1, y1, start, count });
            }
        }
        // Split nodes until there are enough; nodes with one corner are final.
        loop {
            let before = self.nodes.len();
            let expandable = self.nodes.iter().filter(|n| n.count > 1).count();
            if before >= want || expandable == 0 {
                break;
            }
            // Final phase: split the most populated first, stop as soon as there are enough.
            let final_phase = before + 3 * expandable > want;
            if final_phase {
                self.nodes.sort_unstable_by_key(|n| std::cmp::Reverse(n.count));
            }
            self.next_nodes.clear();
            self.next_members.clear();
            let mut total = self.nodes.len();
            for idx in 0..self.nodes.len() {
                let n = self.nodes[idx];
                if n.count == 1 || (final_phase && total >= want) {
                    let start = self.next_members.len() as u32;
                    self.next_members.extend_from_slice(&self.members[n.start as usize..(n.start + n.count) as usize]);
                    self.next_nodes.push(Node { start, ..n });
                    continue;
                }
                let (mx, my) = ((n.x0 + (n.x1 - n.x0) / 2.0).ceil(), (n.y0 + (n.y1 - n.y0) / 2.0).ceil());
                let mut children = 0;
                for q in 0..4 {
                    let (cx0, cx1) = if q % 2 == 0 { (n.x0, mx) } else { (mx, n.x1) };
                    let (cy0, cy1) = if q < 2 { (n.y0, my) } else { (my, n.y1) };
                    let start = self.next_members.len() as u32;
                    for &m in &self.members[n.start as usize..(n.start + n.count) as usize] {
                        let c = self.corners[m as usize];
                        let (cx, cy) = (f32::from(c.x), f32::from(c.y));
                        let left = cx < mx;
                        let up = cy < my;
                        if left == (q % 2 == 0) && up == (q < 2) {
                            self.next_members.push(m);
                        }
                    }
                    let count = self.next_members.len() as u32 - start;
                    if count > 0 {
                        self.next_nodes.push(Node { x0: cx0, y0: cy0, x1: cx1, y1: cy1, start, count });
                        children += 1;
                    }
                }
                total = total - 1 + children;
            }
            std::mem::swap(&mut self.nodes, &mut self.next_nodes);
            std::mem::swap(&mut self.members, &mut self.next_members);
            if self.nodes.len() == before {
                break;
            }
        }
        for n in &self.nodes {
            let best = self.members[n.start as usize..(n.start + n.count) as usize]
                .iter()
                .map(|&m| self.corners[m as usize])
                .max_by_key(|c| c.response);
            if let Some(c) = best {
                self.kept.push(c);
            }
        }
    }
}

/// Intensity-centroid angle (radians) of the disc of radius 15 around (x, y) (§1.5).
pub fn orientation(level: &Level, x: usize, y: usize) -> f32 {
    let (mut m01, mut m10) = (0i64, 0i64);
    for v in -15i32..=15 {
        let row = (y as i32 + v) as usize * level.w;
        let span = UMAX[v.unsigned_abs() as usize];
        for u in -span..=span {
            let i = i64::from(level.data[row + (x as i32 + u) as usize]);
            m10 += i64::from(u) * i;
            m01 += i64::from(v) * i;
        }
    }
    (m01 as f32).atan2(m10 as f32)
}

/// 7×7 Gaussian (σ = 2) with reflect-101 borders (§1.6), separable, in 8.8 fixed point; `tmp` holds the
/// horizontal pass. The interior runs over shifted whole-row slices (vector code); only the 3-pixel frame needs
/// the reflection.
fn blur_level(src: &Level, dst: &mut Level, tmp: &mut [u16], acc: &mut [u32]) {
    // Weights ×256, summing to exactly 256: exp(−d²/8) for d = −3..3, normalised and rounded (the centre takes
    // the rounding remainder).
    const K: [u32; 7] = [18, 34, 49, 54, 49, 34, 18];
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
        // Interior: out[x] = Σ K[k]·row[x + k − 3] for x in 3..w−3 (≤ 255·256, fits u16).
        let n = w - 6;
        let taps: [&[u8]; 7] = std::array::from_fn(|k| &row[k..k + n]);
        for (i, o) in out[3..w - 3].iter_mut().enumerate() {
            let mut acc = 0u32;
            for k in 0..7 {
                acc += K[k] * u32::from(taps[k][i]);
            }
            *o = acc as u16;
        }
        for x in (0..3).chain(w - 3..w) {
            let acc: u32 = (0..7).map(|k| K[k] * u32::from(row[reflect(x as isize + k as isize - 3, w)])).sum();
            out[x] = acc as u16;
        }
    }
    let acc = &mut acc[..w];
    for y in 0..h {
        // Row by row into an accumulator: each pass is a plain zip over two slices (vector code).
        acc.fill(32768);
        for (k, kv) in K.iter().enumerate() {
            let r = reflect(y as isize + k as isize - 3, h);
            for (a, &t) in acc.iter_mut().zip(&tmp[r * w..(r + 1) * w]) {
                *a += kv * u32::from(t);
            }
        }
        for (o, &a) in dst.data[y * w..(y + 1) * w].iter_mut().zip(acc.iter()) {
            *o = (a >> 16) as u8;
        }
    }
}

/// The pattern rotated to 0°, 1°, …, 359° (x' = round(x cos θ − y sin θ), y' = round(x sin θ + y cos θ)).
fn rotate_pattern(pattern: &[[(i8, i8); 2]]) -> Vec<[(i8, i8); 2]> {
    let mut out = Vec::with_capacity(360 * pattern.len());
    for deg in 0..360 {
        let (s, c) = (deg as f32).to_radians().sin_cos();
        let turn = |(x, y): (i8, i8)| {
            let (fx, fy) = (f32::from(x), f32::from(y));
            ((fx * c - fy * s).round() as i8, (fx * s + fy * c).round() as i8)
        };
        out.extend(pattern.iter().map(|[p, q]| [turn(*p), turn(*q)]));
    }
    out
}

/// The descriptor at (x, y) of the blurred level with an already rotated pattern.
pub fn describe_rotated(blurred: &Level, x: usize, y: usize, rotated: &[[(i8, i8); 2]]) -> [u8; 32] {
    let at = |(dx, dy): (i8, i8)| {
        blurred.data[(y as isize + dy as isize) as usize * blurred.w + (x as isize + dx as isize) as usize]
    };
    let mut d = [0u8; 32];
    for (k, [p, q]) in rotated.iter().enumerate() {
        if at(*p) < at(*q) {
            d[k / 8] |= 1 << (k % 8);
        }
    }
    d
}

/// Hamming distance of two descriptors (4 × u64 popcount).
#[inline]
pub fn hamming(a: &[u8; 32], b: &[u8; 32]) -> u32 {
    let mut dist = 0;
    for k in 0..4 {
        let mut x = [0u8; 8];
        let mut y = [0u8; 8];
        x.copy_from_slice(&a[8 * k..8 * k + 8]);
        y.copy_from_slice(&b[8 * k..8 * k + 8]);
        dist += (u64::from_le_bytes(x) ^ u64::from_le_bytes(y)).count_ones();
    }
    dist
}
