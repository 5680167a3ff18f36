//! A stereo frame: ORB features of the left image, their stereo matches and depths, the grid (§2, §3.1).

use crate::geometry::{CameraFromWorld, RectifiedCamera};
use crate::ids::PointId;
use bdis_orb::{FeatureGrid, Features, KeyPoint, OrbError, OrbExtractor, OrbParams, StereoFeatures, StereoMatcher};

/// The pyramid's scales and the information of each octave (σ⁻² = s^−2o).
#[derive(Debug, Clone, PartialEq)]
pub struct Scales {
    pub factor: f64,
    pub scale: Vec<f64>,
    pub inv_sigma2: Vec<f64>,
    /// The finest level features are detected on (`bdis_orb::OrbParams::first_level`): no keypoint has a
    /// smaller octave, so no search predicts one.
    pub first: usize,
}

impl Scales {
    /// `levels` pyramid levels of which features come from `first..levels`.
    pub fn new(factor: f64, levels: usize, first: usize) -> Self {
        let scale: Vec<f64> = (0..levels).map(|l| factor.powi(l as i32)).collect();
        let inv_sigma2 = scale.iter().map(|s| 1.0 / (s * s)).collect();
        Self { factor, scale, inv_sigma2, first: first.min(levels.saturating_sub(1)) }
    }

    pub fn levels(&self) -> usize {
        self.scale.len()
    }

    /// σ of a measurement relative to its octave's: 1 for a corner as FAST found it, `refined_sigma` · its
    /// spread for one aligned to its point's anchor (`aligned`, see [`Frame::aligned`]). The one place the
    /// weights and the χ² gates of aligned measurements come from.
    pub fn relative_sigma(aligned: Option<f32>, refined_sigma: f64) -> f64 {
        aligned.map_or(1.0, |spread| refined_sigma * f64::from(spread))
    }

    /// σ⁻² of a measurement at `octave`: (s^o · [`Self::relative_sigma`])⁻².
    pub fn information(&self, octave: u8, aligned: Option<f32>, refined_sigma: f64) -> f64 {
        let sigma = Self::relative_sigma(aligned, refined_sigma);
        self.inv_sigma2[usize::from(octave)] / (sigma * sigma)
    }

    /// The octave at which a point seen at `dist` with a scale-invariance limit `max_dist` should appear.
    pub fn predict_level(&self, dist: f64, max_dist: f64) -> usize {
        let ratio = max_dist / dist;
        let level = (ratio.ln() / self.factor.ln()).ceil();
        let level = if level.is_nan() || level < 0.0 { 0 } else { (level as usize).min(self.levels() - 1) };
        // A point seen closer than its finest detection allows still appears, on the finest detection level.
        level.max(self.first)
    }
}

/// One stereo frame. `points[i]` links keypoint i to a map point; `outlier[i]` marks links rejected by the
/// last pose optimisation.
#[derive(Debug, Clone)]
pub struct Frame {
    pub id: u64,
    pub t_ns: u64,
    pub keypoints: Vec<KeyPoint>,
    pub descriptors: Vec<[u8; 32]>,
    /// u of the right-image match (level-0 px), −1 where none.
    pub u_right: Vec<f32>,
    /// Stereo depth, −1 where none.
    pub depth: Vec<f32>,
    pub grid: FeatureGrid,
    pub points: Vec<Option<PointId>>,
    pub outlier: Vec<bool>,
    /// `Some(spread)` when keypoint i's position (and right match) was aligned to its point's anchor
    /// ([`crate::refine`]): its σ is the map's `refined_sigma` of its octave's, times `spread`, the
    /// alignment's own σ over the frame's median one (`Tracker::normalise_spreads`). `None`: the corner as
    /// FAST found it, at its octave's σ.
    pub aligned: Vec<Option<f32>>,
    pub camera_from_world: Option<CameraFromWorld>,
    /// What the left image shows of the scene's texture ([`view_texture`]): smoke, a fogged lens and blood
    /// lower its contrast; added light (a haze) narrows its brightness range with it.
    pub texture: ViewTexture,
}

/// What a view shows of its texture ([`view_texture`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewTexture {
    /// Mean absolute difference between neighbouring pixels over the mean brightness: the share of the image's
    /// light that is texture. A gain (exposure) leaves it unchanged; a veil (smoke: an added haze and the
    /// texture behind it dimmed) lowers it.
    pub contrast: f32,
    /// The brightness's standard deviation over its mean (coefficient of variation): how wide the image's range
    /// is. A gain leaves it too; a haze narrows it by the same factor as the contrast (an added light A over
    /// an image I: both are a spread over the mean, and the spread scales by (1 − α) while the mean moves
    /// towards A). Tissue with less fine texture lowers the contrast alone, and a view down a dark lumen
    /// widens the range.
    pub brightness_cv: f32,
}

impl ViewTexture {
    /// Nothing to tell (no image yet, or one without light).
    pub const UNKNOWN: Self = Self { contrast: f32::NAN, brightness_cv: f32::NAN };

    /// Each measure of this view over the same of `reference`.
    pub fn over(self, reference: Self) -> Self {
        Self {
            contrast: self.contrast / reference.contrast,
            brightness_cv: self.brightness_cv / reference.brightness_cv,
        }
    }
}

/// [`ViewTexture`] on every fourth row, away from `keep_out`. NaN for an image without light (black: a covered
/// lens, the light off): there is no share to tell, and darkness is no veil to track through.
pub fn view_texture(image: &[u8], width: usize, height: usize, keep_out: Option<&[u8]>) -> ViewTexture {
    let (mut difference, mut brightness, mut squares, mut pixels_used) = (0u64, 0u64, 0u64, 0u64);
    for y in (0..height.saturating_sub(1)).step_by(4) {
        let (row, below) = (&image[y * width..(y + 1) * width], &image[(y + 1) * width..(y + 2) * width]);
        let (pixels, right, under) = (&row[..width - 1], &row[1..], &below[..width - 1]);
        // A row's sums fit 32 bits for rows up to 16 000 pixels (255² per pixel); without a mask the loop is
        // plain vector code.
        let add = |(d, b, q, n): (u32, u32, u32, u32), p: u8, r: u8, u: u8| {
            let pw = u32::from(p);
            (d + u32::from(p.abs_diff(r)) + u32::from(p.abs_diff(u)), b + pw, q + pw * pw, n + 1)
        };
        let (row_difference, row_brightness, row_squares, row_pixels) =
            match keep_out.map(|m| &m[y * width..(y + 1) * width]) {
                None => pixels.iter().zip(right).zip(under).fold((0, 0, 0, 0), |acc, ((&p, &r), &u)| add(acc, p, r, u)),
                Some(mask) => pixels.iter().zip(right).zip(under).zip(mask.windows(2)).fold(
                    (0, 0, 0, 0),
                    |acc, (((&p, &r), &u), m)| if m[0] != 0 || m[1] != 0 { acc } else { add(acc, p, r, u) },
                ),
            };
        difference += u64::from(row_difference);
        brightness += u64::from(row_brightness);
        squares += u64::from(row_squares);
        pixels_used += u64::from(row_pixels);
    }
    if brightness == 0 {
        return ViewTexture::UNKNOWN;
    }
    let n = pixels_used as f64;
    let mean = brightness as f64 / n;
    let variance = (squares as f64 / n - mean * mean).max(0.0);
    ViewTexture { contrast: difference as f32 / brightness as f32, brightness_cv: (variance.sqrt() / mean) as f32 }
}

impl Frame {
    pub fn empty(cam: &RectifiedCamera) -> Self {
        Self {
            id: 0,
            t_ns: 0,
            keypoints: Vec::new(),
            descriptors: Vec::new(),
            u_right: Vec::new(),
            depth: Vec::new(),
            grid: FeatureGrid::new(cam.width as f32, cam.height as f32),
            points: Vec::new(),
            outlier: Vec::new(),
            aligned: Vec::new(),
            camera_from_world: None,
            texture: ViewTexture::UNKNOWN,
        }
    }

    /// An empty frame with room for `keypoints` keypoints in every per-keypoint list, so that building a frame
    /// with more keypoints than any before it (their number varies with the image) allocates nothing.
    pub fn with_capacity(cam: &RectifiedCamera, keypoints: usize) -> Self {
        let mut frame = Self::empty(cam);
        frame.keypoints.reserve(keypoints);
        frame.descriptors.reserve(keypoints);
        frame.u_right.reserve(keypoints);
        frame.depth.reserve(keypoints);
        frame.points.reserve(keypoints);
        frame.outlier.reserve(keypoints);
        frame.aligned.reserve(keypoints);
        frame
    }

    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    /// The world point of keypoint i from its stereo depth (needs a pose and a depth).
    pub fn unproject_world(&self, cam: &RectifiedCamera, i: usize) -> Option<nalgebra::Point3<f64>> {
        let z = f64::from(*self.depth.get(i)?);
        if z <= 0.0 {
            return None;
        }
        let k = &self.keypoints[i];
        let pc = cam.unproject(f64::from(k.x), f64::from(k.y), z);
        Some(self.camera_from_world?.inverse() * pc)
    }

    /// Copies another frame into this one, reusing this one's buffers.
    pub fn copy_from(&mut self, other: &Frame) {
        self.id = other.id;
        self.t_ns = other.t_ns;
        self.keypoints.clone_from(&other.keypoints);
        self.descriptors.clone_from(&other.descriptors);
        self.u_right.clone_from(&other.u_right);
        self.depth.clone_from(&other.depth);
        self.grid.clone_from(&other.grid);
        self.points.clone_from(&other.points);
        self.outlier.clone_from(&other.outlier);
        self.aligned.clone_from(&other.aligned);
        self.camera_from_world = other.camera_from_world;
        self.texture = other.texture;
    }
}

/// Builds frames from grey stereo pairs with buffers it owns.
#[derive(Debug)]
pub struct FrameBuilder {
    cam: RectifiedCamera,
    left: OrbExtractor,
    right: OrbExtractor,
    matcher: StereoMatcher,
    left_features: Features,
    right_features: Features,
    stereo: StereoFeatures,
    scales: Scales,
    next_id: u64,
}

impl FrameBuilder {
    pub fn new(cam: RectifiedCamera, params: OrbParams) -> Result<Self, OrbError> {
        let left = OrbExtractor::new(params, cam.width as usize, cam.height as usize)?;
        let right = OrbExtractor::new(params, cam.width as usize, cam.height as usize)?;
        let scales = Scales::new(params.scale_factor, left.scales().len(), left.first_level());
        Ok(Self {
            cam,
            left,
            right,
            matcher: StereoMatcher::with_capacity(2 * params.n_features as usize),
            left_features: Features::default(),
            right_features: Features::default(),
            stereo: StereoFeatures::default(),
            scales,
            next_id: 0,
        })
    }

    /// The left image's pyramid of the last frame built (level 0 is the image).
    pub fn left_levels(&self) -> &[bdis_orb::Level] {
        &self.left.levels
    }

    /// The right image's pyramid of the last frame built.
    pub fn right_levels(&self) -> &[bdis_orb::Level] {
        &self.right.levels
    }

    pub fn scales(&self) -> &Scales {
        &self.scales
    }

    /// Extracts and matches a grey pair into `frame` (its buffers reused). No left feature comes from
    /// `keep_out` (one byte per left pixel, non-zero = instruments: see [`OrbExtractor::extract_masked`]).
    pub fn build(
        &mut self,
        t_ns: u64,
        left: &[u8],
        right: &[u8],
        keep_out: Option<&[u8]>,
        frame: &mut Frame,
    ) -> Result<(), OrbError> {
        self.left.extract_masked(left, keep_out, &mut self.left_features)?;
        self.right.extract(right, &mut self.right_features)?;
        self.matcher.match_features(
            &self.left_features,
            &self.right_features,
            &self.left.levels,
            &self.right.levels,
            &self.scales.scale,
            self.cam.fx as f32,
            self.cam.bf as f32,
            &mut self.stereo,
        );
        frame.id = self.next_id;
        self.next_id += 1;
        frame.t_ns = t_ns;
        frame.keypoints.clone_from(&self.left_features.keypoints);
        frame.descriptors.clone_from(&self.left_features.descriptors);
        frame.u_right.clear();
        frame.u_right.extend(self.stereo.u_right.iter().map(|u| u.unwrap_or(-1.0)));
        frame.depth.clear();
        frame.depth.extend(self.stereo.depth.iter().map(|d| d.unwrap_or(-1.0)));
        frame.grid.build(&frame.keypoints);
        let n = frame.keypoints.len();
        frame.points.clear();
        frame.points.resize(n, None);
        frame.outlier.clear();
        frame.outlier.resize(n, false);
        frame.aligned.clear();
        frame.aligned.resize(n, None);
        frame.camera_from_world = None;
        let (w, h) = (self.cam.width as usize, self.cam.height as usize);
        frame.texture = view_texture(&left[..w * h], w, h, keep_out);
        Ok(())
    }
}

#[cfg(test)]
mod contrast_tests {
    use super::view_texture;

    fn contrast(image: &[u8], w: usize, h: usize, keep_out: Option<&[u8]>) -> f32 {
        view_texture(image, w, h, keep_out).contrast
    }

    #[test]
    fn a_gain_keeps_the_texture_contrast_and_a_veil_lowers_it() {
        let (w, h) = (64, 48);
        let texture: Vec<u8> = (0..w * h).map(|i| (60 + (i * 37 % 51) + (i / w * 13 % 29)) as u8).collect();
        let clear = contrast(&texture, w, h, None);
        let brighter: Vec<u8> = texture.iter().map(|&p| (u16::from(p) * 3 / 2) as u8).collect();
        assert!((contrast(&brighter, w, h, None) / clear - 1.0).abs() < 0.03, "an exposure change");
        // Smoke: half the light replaced by a bright haze.
        let veiled: Vec<u8> = texture.iter().map(|&p| (u16::from(p) / 2 + 100) as u8).collect();
        assert!(contrast(&veiled, w, h, None) < 0.5 * clear);
        // A masked half is left out.
        let mut half = texture.clone();
        half[..w * h / 2].fill(255);
        let mask: Vec<u8> = (0..w * h).map(|i| if i < w * h / 2 + w { 255 } else { 0 }).collect();
        let kept = contrast(&half, w, h, Some(&mask));
        assert!((kept / contrast(&texture[w * h / 2..], w, h / 2, None) - 1.0).abs() < 0.2, "{kept}");
    }

    /// The haze's mark: it narrows the brightness range by as much as it takes of the texture, where a view of
    /// plainer tissue with a dark lumen in it loses texture and widens the range.
    #[test]
    fn a_haze_narrows_the_brightness_range_with_the_texture_and_a_dark_lumen_widens_it() {
        let (w, h) = (96, 64);
        let texture = |amplitude: f64, background: &dyn Fn(usize) -> f64| -> Vec<u8> {
            (0..w * h)
                .map(|i| {
                    let fine = ((i * 37 % 51) as f64 + (i / w * 13 % 29) as f64) / 80.0 - 0.5;
                    (background(i) * (1.0 + amplitude * fine)).clamp(0.0, 255.0) as u8
                })
                .collect()
        };
        let clear = view_texture(&texture(0.8, &|_| 120.0), w, h, None);
        let brighter = view_texture(&texture(0.8, &|_| 180.0), w, h, None);
        assert!((brighter.brightness_cv / clear.brightness_cv - 1.0).abs() < 0.03, "an exposure change");
        // A haze: 40 % of the light replaced by a bright airlight.
        let hazy: Vec<u8> =
            texture(0.8, &|_| 120.0).iter().map(|&p| (0.6 * f64::from(p) + 0.4 * 200.0) as u8).collect();
        let hazy = view_texture(&hazy, w, h, None);
        let (contrast_ratio, range_ratio) = (hazy.contrast / clear.contrast, hazy.brightness_cv / clear.brightness_cv);
        assert!(contrast_ratio < 0.75 && range_ratio < 0.75, "{contrast_ratio} {range_ratio}");
        assert!((range_ratio / contrast_ratio - 1.0).abs() < 0.1, "the same factor: {contrast_ratio} {range_ratio}");
        // Plainer tissue, a third of the view down a dark lumen: less texture, a wider range.
        let lumen = view_texture(&texture(0.5, &|i| if i % w < w / 3 { 30.0 } else { 130.0 }), w, h, None);
        assert!(lumen.contrast < 0.75 * clear.contrast, "{} {}", lumen.contrast, clear.contrast);
        assert!(lumen.brightness_cv > clear.brightness_cv, "{} {}", lumen.brightness_cv, clear.brightness_cv);
    }
}
