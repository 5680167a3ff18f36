//! ORB extraction (ORB-SLAM2-STEREO.md §1): scale pyramid, FAST-9 per grid cell with a fallback threshold,
//! quadtree distribution, intensity-centroid orientation, rotated BRIEF on a Gaussian-smoothed level.
//! Every buffer is owned by the [`OrbExtractor`] and reused.

use crate::pattern;
use crate::simd::multiversion;

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

/// A keypoint in level-0 pixels: the centre of pixel x of level l is at `level_to_image(x, s^l)` (see there).
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

/// Level-0 position of the centre of pixel `x` of a level at scale `s`: (x + 0.5)·s − 0.5, since each level
/// samples the one above at exactly that position (pixel centres at integers). ORB-SLAM2 uses x·s, which puts
/// keypoints of octave l up to 0.5·(s^l − 1) px (1.3 px at octave 7) towards the image origin: a bias in x and y
/// of every coarse measurement.
#[inline]
pub fn level_to_image(x: f32, s: f32) -> f32 {
    (x + 0.5) * s - 0.5
}

/// The inverse of [`level_to_image`].
#[inline]
pub fn image_to_level(u: f32, s: f32) -> f32 {
    (u + 0.5) / s - 0.5
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

/// A bilinear tap: source index, weight of the next source sample in 1/256.
type Tap = (u16, u8);

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
    blur_acc: Vec<u16>,
    /// The pyramid's vertically blended source row (plus one spare sample).
    pyramid_row: Vec<u16>,
    /// Per level: the bilinear taps from the level above.
    taps: Vec<LevelTaps>,
    /// The pattern rotated to each whole degree: 360 × 256 pairs of offsets into `patch`.
    rotated: Vec<[u16; 2]>,
    /// The neighbourhood of the keypoint being described.
    patch: Box<[u8; PATCH_LEN]>,
    scores: Vec<u8>,
    cand_ini: Vec<u8>,
    cand_min: Vec<u8>,
    hits: Vec<Corner>,
    /// A cell's candidates (indices into the level), scored together.
    batch: Vec<u32>,
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

/// Marks the pixels of row `y`, columns `x_lo..x_hi`, that may be FAST-9 corners at the thresholds `t_ini` and
/// `t_min` (1 = maybe, 0 = certainly not; the outputs are that span of the row). An arc of 9 of the 16 ring pixels
/// contains one pixel of every opposite pair (k, k + 8), so a bright corner needs, for all 8 pairs, one of the two
/// brighter than centre + t: the smallest of the 8 pair maxima must be. Dark corners likewise with the largest pair
/// minimum. Black centres are never corners. Byte min/max are single vector instructions, and the loop over
/// equal-length row slices is vectorised by the compiler; both thresholds share the loads and the reductions.
#[inline(always)]
fn candidates_row(
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

/// [`candidates_row`] for rows `y_lo..y_hi` of a level, into masks the size of the level. Not compiled for AVX2
/// as well (see `simd.rs`): with AVX2 the compiler leaves this loop scalar, and the SSE2 vectors are as fast.
#[allow(clippy::too_many_arguments)]
fn candidate_masks(
    level: &Level,
    y_lo: usize,
    y_hi: usize,
    x_lo: usize,
    x_hi: usize,
    t: (u8, u8),
    ini: &mut [u8],
    min: &mut [u8],
) {
    let w = level.w;
    for y in y_lo..y_hi {
        let span = y * w + x_lo..y * w + x_hi;
        candidates_row(&level.data, w, y, (x_lo, x_hi), t, (&mut ini[span.clone()], &mut min[span]));
    }
}

/// The taps of one pyramid step, and how far along a row they repeat every 5 outputs with 6 inputs (scale
/// factor 1.2, the default): there the gather needs no table.
#[derive(Debug, Clone, Default)]
pub(crate) struct LevelTaps {
    x: Vec<Tap>,
    y: Vec<Tap>,
    /// Outputs 0..periodic (a multiple of 5) have x0 = 6q + i and weight `weights5[i]` (x = 5q + i).
    periodic: usize,
    weights5: [u16; 5],
}

impl LevelTaps {
    fn new(x: Vec<Tap>, y: Vec<Tap>) -> Self {
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

/// Candidates scored together: the lanes of [`fast_scores`].
const SCORE_LANES: usize = 16;

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
        // Level l samples level l − 1 at (x + 0.5)·s − 0.5 with s the nominal scale factor (not the ratio of the
        // rounded sizes), so that level coordinates times s^l are level-0 coordinates; samples past the last
        // pixel take the last (replicated border).
        let axis = |src: usize, dst: usize| -> Vec<Tap> {
            let f = params.scale_factor;
            (0..dst)
                .map(|x| {
                    let sx = ((x as f64 + 0.5) * f - 0.5).max(0.0);
                    let x0 = (sx as usize).min(src - 1);
                    (x0 as u16, ((sx - x0 as f64) * 256.0).round().min(255.0) as u8)
                })
                .collect()
        };
        let taps = (0..levels.len())
            .map(|l| {
                if l == 0 {
                    LevelTaps::default()
                } else {
                    LevelTaps::new(axis(sizes[l - 1].0, sizes[l].0), axis(sizes[l - 1].1, sizes[l].1))
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
            pyramid_row: vec![0; width + 1],
            taps,
            rotated: rotate_pattern(&pattern::PATTERN),
            patch: Box::new([0; PATCH_LEN]),
            scores: vec![0; width * height],
            cand_ini: vec![0; width * height],
            cand_min: vec![0; width * height],
            hits: Vec::with_capacity(4096),
            batch: Vec::with_capacity(4096),
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
                    &mut self.patch,
                ));
                out.keypoints.push(KeyPoint {
                    x: level_to_image(f32::from(c.x), scale),
                    y: level_to_image(f32::from(c.y), scale),
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
    /// fixed point with taps computed once per size. Separable, vertical first: the two source rows of an output
    /// row are blended over their whole width (vector code), then the blended row is interpolated along x (a
    /// gather: one per output pixel). Both passes keep every bit (8.8 then 16.16 fixed point), so the result is
    /// the exact bilinear value rounded once. A pixel whose footprint touches black stays black (the view's edge
    /// must not become texture): a blended sample with a black tap is stored as 0, which real samples (≥ 256)
    /// never are.
    fn build_pyramid(&mut self, image: &[u8]) {
        self.levels[0].data.copy_from_slice(image);
        for l in 1..self.levels.len() {
            let (prev, rest) = self.levels.split_at_mut(l);
            resize_level(&prev[l - 1], &mut rest[0], &self.taps[l], &mut self.pyramid_row);
        }
    }

    /// FAST per cell with the fallback threshold and 3×3 non-maximum suppression inside the cell (§1.3).
    #[inline(never)] // a stage of its own in profiles
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
        // Candidates at both thresholds once per level on whole rows (vector code): cells then only visit
        // candidates. (On in-vivo images about half of the cells fall back to minThFAST.)
        let (ini, min) = (self.params.ini_th_fast, self.params.min_th_fast);
        let (x_lo, x_hi) = (min_x + 3, max_x - 3);
        let (cand_ini, cand_min) = (&mut self.cand_ini, &mut self.cand_min);
        candidate_masks(level, min_y + 3, max_y - 3, x_lo, x_hi, (ini, min), cand_ini, cand_min);
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

    /// Quadtree distribution keeping the strongest corner of each node (§1.4); result in `self.kept`.
    #[inline(never)] // a stage of its own in profiles
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
const PATCH_RADIUS: usize = 18;
const PATCH_SIDE: usize = 2 * PATCH_RADIUS + 1;
/// Row stride of the patch buffer, and its size (a power of two, so that a masked offset needs no bounds check).
const PATCH_STRIDE: usize = 64;
const PATCH_LEN: usize = 4096;

/// The pattern rotated to 0°, 1°, …, 359° (x' = round(x cos θ − y sin θ), y' = round(x sin θ + y cos θ)), as
/// offsets into the patch buffer ((y' + 18) · 64 + x' + 18): 360 × 256 pairs.
fn rotate_pattern(pattern: &[[(i8, i8); 2]]) -> Vec<[u16; 2]> {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A textured test level: smooth gradients, hashed noise, and a black disc corner like an endoscope's edge.
    pub(crate) fn test_level(w: usize, h: usize) -> Level {
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if x * x + y * y < 40 * 40 || (x > w - 20 && y > h - 30) {
                    return 0;
                }
                let hash = (i as u32).wrapping_mul(2_654_435_761) >> 24;
                ((x * 3 + y * 5) % 160 + (hash as usize) % 90 + 1) as u8
            })
            .collect();
        Level { w, h, data }
    }

    #[test]
    fn the_avx2_copies_give_the_portable_results_bit_for_bit() {
        let src = test_level(640, 480);
        let params = OrbParams::default();
        let ex = OrbExtractor::new(params, 640, 480).unwrap();
        // Pyramid step.
        let taps = &ex.taps[1];
        let (dw, dh) = (taps.x.len(), taps.y.len());
        let (mut a, mut b) =
            (Level { w: dw, h: dh, data: vec![0; dw * dh] }, Level { w: dw, h: dh, data: vec![1; dw * dh] });
        let mut row = vec![0u16; 641];
        resize_level(&src, &mut a, taps, &mut row);
        resize_level_portable(&src, &mut b, taps, &mut row);
        assert_eq!(a.data, b.data);
        // Blur.
        let (mut tmp, mut acc) = (vec![0u16; 640 * 480], vec![0u16; 640]);
        let (mut a, mut b) =
            (Level { w: 640, h: 480, data: vec![0; 640 * 480] }, Level { w: 640, h: 480, data: vec![1; 640 * 480] });
        blur_level(&src, &mut a, &mut tmp, &mut acc);
        blur_level_portable(&src, &mut b, &mut tmp, &mut acc);
        assert_eq!(a.data, b.data);
        // FAST scores, over every pixel of a band (partial batches included).
        let ring: [isize; 16] = CIRCLE.map(|(dx, dy)| dy as isize * 640 + dx as isize);
        let at: Vec<u32> = (100 * 640 + 20..100 * 640 + 620).collect();
        for batch in at.chunks(SCORE_LANES) {
            for t in [7u8, 20] {
                let (mut sa, mut sb) = ([0u8; SCORE_LANES], [1u8; SCORE_LANES]);
                fast_scores(&src.data, &ring, batch, t, &mut sa);
                fast_scores_portable(&src.data, &ring, batch, t, &mut sb);
                assert_eq!(sa[..batch.len()], sb[..batch.len()]);
                // And the definition, one pixel and one arc at a time.
                for (&p, &score) in batch.iter().zip(&sa) {
                    let c = i16::from(src.data[p as usize]);
                    let ring_values = ring.map(|o| src.data[(p as isize + o) as usize]);
                    let d = ring_values.map(|v| i16::from(v) - c);
                    let mut best = i16::MIN;
                    for start in 0..16 {
                        let arc = (0..9).map(|k| d[(start + k) % 16]);
                        best = best.max(arc.clone().min().unwrap()).max(arc.map(|v| -v).min().unwrap());
                    }
                    let want =
                        if ring_values.contains(&0) || best - 1 < i16::from(t) { 0 } else { (best - 1).min(255) as u8 };
                    assert_eq!(score, want, "pixel {p} threshold {t}");
                }
            }
        }
    }

    #[test]
    fn the_candidate_masks_keep_every_corner() {
        let src = test_level(640, 480);
        let ring: [isize; 16] = CIRCLE.map(|(dx, dy)| dy as isize * 640 + dx as isize);
        let (mut ini, mut min) = (vec![0u8; 640 * 480], vec![0u8; 640 * 480]);
        candidate_masks(&src, 19, 461, 19, 621, (20, 7), &mut ini, &mut min);
        let (mut corners, mut candidates) = (0, 0);
        for y in 19..461 {
            let at: Vec<u32> = (y * 640 + 19..y * 640 + 621).map(|p| p as u32).collect();
            for batch in at.chunks(SCORE_LANES) {
                for (t, mask) in [(20u8, &ini), (7, &min)] {
                    let mut scores = [0u8; SCORE_LANES];
                    fast_scores(&src.data, &ring, batch, t, &mut scores);
                    for (&p, &s) in batch.iter().zip(&scores) {
                        assert!(s == 0 || mask[p as usize] == 1, "corner at {p} (t {t}) not a candidate");
                        corners += usize::from(s > 0);
                        candidates += usize::from(mask[p as usize]);
                    }
                }
            }
        }
        // The filter must filter: far fewer candidates than pixels.
        assert!(corners > 1000 && candidates < 2 * 442 * 602 / 2, "{corners} corners, {candidates} candidates");
    }

    #[test]
    fn the_table_free_pyramid_gather_equals_the_tap_table() {
        let src = test_level(640, 480);
        let ex = OrbExtractor::new(OrbParams::default(), 640, 480).unwrap();
        let taps = &ex.taps[1];
        assert!(taps.periodic >= 500, "the 6→5 pattern should cover most of the row: {}", taps.periodic);
        let generic = LevelTaps { periodic: 0, ..taps.clone() };
        let (dw, dh) = (taps.x.len(), taps.y.len());
        let (mut a, mut b) =
            (Level { w: dw, h: dh, data: vec![0; dw * dh] }, Level { w: dw, h: dh, data: vec![1; dw * dh] });
        let mut row = vec![0u16; 641];
        resize_level(&src, &mut a, taps, &mut row);
        resize_level(&src, &mut b, &generic, &mut row);
        assert_eq!(a.data, b.data);
        // Bilinear at the nominal scale: output (x, y) is the input at ((x + 0.5)·1.2 − 0.5, …) — checked
        // against floating point away from black.
        for (x, y) in [(100usize, 100usize), (257, 311), (400, 50)] {
            let (sx, sy) = ((x as f64 + 0.5) * 1.2 - 0.5, (y as f64 + 0.5) * 1.2 - 0.5);
            let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
            let (fx, fy) = (sx - x0 as f64, sy - y0 as f64);
            let p = |x: usize, y: usize| f64::from(src.data[y * 640 + x]);
            let want = (p(x0, y0) * (1.0 - fx) + p(x0 + 1, y0) * fx) * (1.0 - fy)
                + (p(x0, y0 + 1) * (1.0 - fx) + p(x0 + 1, y0 + 1) * fx) * fy;
            assert!((f64::from(a.data[y * dw + x]) - want).abs() < 1.0, "({x}, {y})");
        }
    }
}
