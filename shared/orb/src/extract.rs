//! ORB extraction (ORB-SLAM2-STEREO.md §1): scale pyramid, FAST-9 per grid cell with a fallback threshold,
//! quadtree distribution, intensity-centroid orientation, rotated BRIEF on a Gaussian-smoothed level.
//! Every buffer is owned by the [`OrbExtractor`] and reused. This file holds the types and the driver
//! ([`OrbExtractor::extract`]); each stage is a module beside it: `pyramid`, `fast`, `distribute`, `describe`.

mod describe;
mod distribute;
mod fast;
mod pyramid;

use describe::{PATCH_LEN, blur_level, rotate_pattern};
pub use describe::{describe_rotated, orientation};
use distribute::Node;
use pyramid::LevelTaps;

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
    /// The pyramid level features are first detected on (`ORBextractor.firstLevel`): the `n_levels` detection
    /// levels are `first_level ..first_level + n_levels`, and the levels finer than the first are built (as the
    /// pyramid's source, and for whoever measures on them) but not searched. `None` = [`auto_first_level`]:
    /// detection on the level nearest VGA's pixels, so that HD costs about what VGA costs.
    pub first_level: Option<u32>,
}

impl Default for OrbParams {
    fn default() -> Self {
        Self { n_features: 1000, scale_factor: 1.2, n_levels: 8, ini_th_fast: 20, min_th_fast: 7, first_level: None }
    }
}

/// The first detection level for a `width`×`height` image when none is set: the pyramid level whose pixel count
/// is nearest (in ratio) the 640×480 that ORB-SLAM2's extractor settings were made for
/// (`bdis_core::scale::REFERENCE_PIXELS`; the same reference BDIS and the map scale their pixels by). Why: what
/// extraction costs grows with the pixels it searches (FAST, the blur for descriptors, the quadtree's
/// candidates), while what the tracker needs from it — ~1000 well-spread, repeatable corners, found with
/// thresholds and a budget set for VGA — does not grow with the sensor. So 1280×720 detects from level 3
/// (741×417), 1920×1080 from level 5 (772×434), 640×480 and smaller from level 0 as ORB-SLAM2 does. The images
/// are not resized: the finer levels stay in the pyramid, and the octaves keep their meaning.
pub fn auto_first_level(width: usize, height: usize, scale_factor: f64) -> u32 {
    let reference = bdis_core::scale::REFERENCE_PIXELS;
    let step = (scale_factor * scale_factor).ln();
    let ratio = width as f64 * height as f64 / reference;
    if !(ratio.is_finite() && ratio > 1.0 && step.is_finite() && step > 0.0) {
        return 0;
    }
    // Level l has ratio / s^2l of the reference's pixels: nearest in log ratio.
    (ratio.ln() / step).round().min(16.0) as u32
}

impl OrbParams {
    pub fn from_settings(s: &bdis_core::settings::OrbSettings) -> Self {
        Self {
            n_features: s.n_features,
            scale_factor: s.scale_factor,
            n_levels: s.n_levels,
            ini_th_fast: s.ini_th_fast.min(255) as u8,
            min_th_fast: s.min_th_fast.min(255) as u8,
            first_level: s.first_level,
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
    /// The first detection level ([`OrbParams::first_level`], resolved for this image size).
    first_level: usize,
    /// Features wanted per level (0 on the levels finer than the first detection level).
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
    /// A densely scored cell's scores, in rows of the level's width (`fast::DENSE_ROWS` rows; x86-64 only).
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
    cell_scores: Vec<u8>,
    corners: Vec<Corner>,
    nodes: Vec<Node>,
    next_nodes: Vec<Node>,
    members: Vec<u32>,
    next_members: Vec<u32>,
    kept: Vec<Corner>,
    width: usize,
    height: usize,
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
        let first_level = params.first_level.unwrap_or_else(|| auto_first_level(width, height, params.scale_factor));
        if first_level > 16 {
            return bad("firstLevel", format!("must be in 0..=16, found {first_level}"));
        }
        let n_pyramid = first_level + params.n_levels;
        let scales: Vec<f64> = (0..n_pyramid).map(|l| params.scale_factor.powi(l as i32)).collect();
        let sizes: Vec<(usize, usize)> = scales
            .iter()
            .map(|s| ((width as f64 / s).round() as usize, (height as f64 / s).round() as usize))
            .collect();
        if sizes.iter().any(|&(w, h)| w < 62 || h < 62) {
            return Err(OrbError::TooSmall { w: width, h: height, levels: n_pyramid, scale: params.scale_factor });
        }
        // Features per level: a geometric series (§1.2), the last level takes the remainder.
        let n = f64::from(params.n_features);
        let f = 1.0 / params.scale_factor;
        let n0 = n * (1.0 - f) / (1.0 - f.powi(params.n_levels as i32));
        let mut per_level: Vec<usize> = vec![0; first_level as usize];
        per_level.extend((0..params.n_levels as usize - 1).map(|l| (n0 * f.powi(l as i32)).round() as usize));
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
            first_level: first_level as usize,
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
            cell_scores: if cfg!(target_arch = "x86_64") { vec![0; fast::DENSE_ROWS * width] } else { Vec::new() },
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

    /// The scale of every pyramid level, the levels finer than the first detection level included.
    pub fn scales(&self) -> &[f64] {
        &self.scales
    }

    /// The finest level features are detected on: every keypoint's octave is at least this.
    pub fn first_level(&self) -> usize {
        self.first_level
    }

    /// Extracts features of a `width`×`height` grey image into `out` (its buffers are reused).
    pub fn extract(&mut self, image: &[u8], out: &mut Features) -> Result<(), OrbError> {
        self.extract_masked(image, None, out)
    }

    /// [`OrbExtractor::extract`] keeping out of `keep_out` (one byte per pixel of the image, non-zero = an
    /// instrument or anything else that must give no feature). A corner is dropped when its centre or its FAST
    /// ring (3 level pixels out) lies on the mask — a corner on a silhouette belongs to what moves, not to the
    /// tissue behind — before each level's features are distributed, so the level's budget goes to the rest.
    pub fn extract_masked(
        &mut self,
        image: &[u8],
        keep_out: Option<&[u8]>,
        out: &mut Features,
    ) -> Result<(), OrbError> {
        let (w, h) = (self.width, self.height);
        if image.len() < w * h {
            return Err(OrbError::Buffer { len: image.len(), w, h, needed: w * h });
        }
        if let Some(mask) = keep_out
            && mask.len() < w * h
        {
            return Err(OrbError::Buffer { len: mask.len(), w, h, needed: w * h });
        }
        self.build_pyramid(&image[..w * h]);
        out.keypoints.clear();
        out.descriptors.clear();
        for l in self.first_level..self.levels.len() {
            self.detect_level(l);
            if let Some(mask) = keep_out {
                let scale = self.scales[l] as f32;
                let masked = |x: f32, y: f32| {
                    let (x, y) = (level_to_image(x, scale).round(), level_to_image(y, scale).round());
                    let (x, y) = (x.clamp(0.0, (w - 1) as f32) as usize, y.clamp(0.0, (h - 1) as f32) as usize);
                    mask[y * w + x] != 0
                };
                self.corners.retain(|c| {
                    let (x, y) = (f32::from(c.x), f32::from(c.y));
                    ![(0.0, 0.0), (3.0, 0.0), (-3.0, 0.0), (0.0, 3.0), (0.0, -3.0)]
                        .iter()
                        .any(|&(dx, dy)| masked(x + dx, y + dy))
                });
            }
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
mod tests;
