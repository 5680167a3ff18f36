//! The matcher: image pyramid, patch grid, 1-D inverse-compositional search with coarse-to-fine propagation,
//! the Bayesian patch confidence, level likelihoods, Gaussian-weighted fusion, speckle removal, the `min_prob`
//! threshold and the upsampled output. Written from `BDIS-ALGORITHM.md`; section numbers below refer to it.
//! This file holds the types, the buffers and the driver ([`Matcher::compute_into`]); each stage is a module
//! beside it: `pyramid` (§2), `search` (§3–§6.1), `fusion` (§6.2–§6.3), `speckle` (§6.4), `upsample` (§7),
//! `consistency`, the left–right check that is not in the original (see [`Params::lr_check`]), and `halve`, the
//! pair halved before the levels count on HD (see [`Params::level_offset`]).
//!
//! Every buffer belongs to the [`Matcher`] and is reused: after the first pair of a given size, a call allocates
//! nothing.
//!
//! Deliberate deviations from the original (none of them its algorithm):
//! * the right image is masked (the original's copy-paste bug masks the left twice, so black right pixels were
//!   averaged into coarse levels as dark but "valid" texture). Black right pixels are invalid samples at every
//!   level, and a coarse right pixel is the mean of its *valid* children (invalid only when all four are). The
//!   left keeps the original rule (any invalid child makes the parent invalid): the template must lie on
//!   seen tissue, while the right only has to offer usable samples. Masking the right like the left instead
//!   spreads black borders up the pyramid and costs 8 points of density on Hamlyn 6 (80 % vs 88 %);
//! * invalid pixels are 0 from the start (the original's NaN masking followed by its repeated NaN→0 passes
//!   comes to the same thing, once);
//! * `exp` is the real exponential, not Schraudolph's −4 %/+2 % approximation;
//! * a patch whose start disparity is NaN is skipped (the original searched from NaN);
//! * an output pixel with `u ≥ 0` (zero disparity) is invalid, as in BDIS-SLAM's use of the map (`F < 0`);
//! * the variance fit runs only when asked for, and never for a degenerate candidate set;
//! * the unused parts are not written: the right and vertical gradients, `usefbcon`, the other cost functions;
//! * a fully valid patch is evaluated in one pass (see `Matcher::eval`), which cannot see a sample that is
//!   exactly equal to its patch mean (the original counts it invalid); patches touching invalid pixels, where
//!   that rule rejects flat dark areas, keep the exact two-pass evaluation;
//! * images smaller than one coarsest-level patch give an empty map rather than an error (there is nothing to
//!   search); use a smaller `lv_f` for small images;
//! * a level that keeps no pixel does not end the search: the next finer level starts again from zero
//!   disparity, as the coarsest does. In the original every finer level only refines what the coarser one
//!   found, so when the few patches of a small coarsest level all fail (at 320×240 with `lv_f` 5 the level is
//!   10×8 px, smaller than a patch) the whole map is empty: 9 of 100 frames of a rendered colon at 320×240.
//!   Where the coarsest level finds anything, nothing changes;
//! * the left–right check ([`Params::lr_check`]).

mod consistency;
mod fusion;
mod halve;
mod pyramid;
mod search;
mod speckle;
mod upsample;

use wide::f32x4;

use crate::kernels;
use crate::params::{Algorithm, ParamError, Params};
use halve::{HalvingRule, halve};

/// An 8-bit grey image, rows of `width` bytes.
#[derive(Debug, Clone, Copy)]
pub struct GrayImage<'a> {
    pub width: usize,
    pub height: usize,
    pub data: &'a [u8],
}

/// Disparity `d = x_left − x_right` (px, NaN = invalid) and confidence in [0, 1], at the input size.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DisparityMap {
    pub width: usize,
    pub height: usize,
    pub disparity: Vec<f32>,
    pub confidence: Vec<f32>,
    /// Disparity variance (px²) when asked for; NaN where invalid.
    pub variance: Option<Vec<f32>>,
}

impl DisparityMap {
    /// Fraction of pixels with a valid disparity.
    pub fn density(&self) -> f64 {
        let valid = self.disparity.iter().filter(|d| d.is_finite()).count();
        valid as f64 / self.disparity.len().max(1) as f64
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MatchError {
    #[error(transparent)]
    Params(#[from] ParamError),
    #[error("left image is {lw}×{lh}, right image is {rw}×{rh}: a stereo pair must have one size")]
    SizeMismatch { lw: usize, lh: usize, rw: usize, rh: usize },
    #[error("image is {w}×{h}: too small for {levels} pyramid levels with {patch}-px patches")]
    TooSmall { w: usize, h: usize, levels: u32, patch: u32 },
    #[error("image buffer holds {len} bytes, {w}×{h} needs {needed}")]
    Buffer { len: usize, w: usize, h: usize, needed: usize },
}

/// One pyramid level: the left and right images with a zero border (0 = invalid), the left x-gradient, the
/// right "sample is usable" mask, and the level's dense outputs.
#[derive(Debug, Default)]
struct Level {
    w: usize,
    h: usize,
    /// Row stride of the bordered images (w + 2·border).
    stride: usize,
    left: Vec<f32>,
    right: Vec<f32>,
    left_ix: Vec<f32>,
    /// 1 where the right pixel and the one below it are both valid (the bilinear validity rule reads the row
    /// below even though its weight is 0, §4).
    right_ok: Vec<u8>,
    /// Summed-area table of unusable right samples (a sample at column c needs `right_ok` at c and c+1), so
    /// "is this patch footprint fully usable" costs four reads.
    bad_sat: Vec<u32>,
    /// 1.0 where a bilinear sample starting at this column is usable, else 0.0 (for the vector kernels).
    usable: Vec<f32>,
    /// Fused flow u (≤ 0, level px; NaN invalid) and pixel probability.
    flow: Vec<f32>,
    prob: Vec<f32>,
    /// Fusion accumulators.
    num: Vec<f32>,
    den: Vec<f32>,
    prob_sum: Vec<f32>,
    count: Vec<u16>,
    /// Variance accumulators (Σ w²·var).
    var_num: Vec<f32>,
}

/// Residual statistics at one shift.
#[derive(Debug, Clone, Copy)]
struct Eval {
    n: usize,
    sum_gr: f32,
    sum_r2: f32,
    mares: f32,
}

/// The result of one patch search.
#[derive(Debug, Clone, Copy)]
struct PatchResult {
    u: f32,
    /// Bayesian centre mass b (0 = the patch failed); 1 for plain DIS.
    b: f32,
    /// Variance (level px²) when computed.
    var: f32,
}

/// Dense stereo matcher; owns and reuses every buffer.
#[derive(Debug)]
pub struct Matcher {
    params: Params,
    /// Padded full-resolution size and the padding's left/top part.
    padded_w: usize,
    padded_h: usize,
    pad_x: usize,
    pad_y: usize,
    border: usize,
    levels: Vec<Level>,
    /// Spatial weight G(a, b) of the fusion (σ_s = 4 px).
    gauss: Vec<f32>,
    template: Vec<f32>,
    grad: Vec<f32>,
    /// Row width of the padded patch arrays (p rounded up to 4), their copies, the column mask, and scratch.
    pw: usize,
    tmpl_pad: Vec<f32>,
    grad_pad: Vec<f32>,
    colmask: Vec<f32>,
    samples: Vec<f32>,
    /// Per-patch constants of the fast evaluation: template mean, Σg, Σg·T', ΣT', whether every template pixel
    /// is valid.
    tmpl_mean: f32,
    sum_g: f32,
    sum_gt: f32,
    sum_t: f32,
    tmpl_all_valid: bool,
    /// Per patch of the current level: result and reference point.
    patches: Vec<(usize, usize, PatchResult, f32)>,
    /// Bilinear taps of the output upsampling per output column and row (index, index, weight of the second).
    col_taps: Vec<(u32, u32, f32)>,
    row_taps: Vec<(u32, u32, f32)>,
    /// Speckle filter scratch.
    labels: Vec<u32>,
    next_label: u32,
    stack: Vec<usize>,
    members: Vec<usize>,
    /// The left–right check's mirrored pair (mirror of the right image as the left, and the other way) and the
    /// finest level's flow it gave, reused.
    mirrored_left: Vec<u8>,
    mirrored_right: Vec<u8>,
    reverse_flow: Vec<f32>,
    /// The input halved `offset` times ([`Params::level_offset`]), what the levels count from, and its width;
    /// with the per-column sums of the halving.
    offset: usize,
    halved_left: Vec<u8>,
    halved_right: Vec<u8>,
    halved_w: usize,
    halving_sums: Vec<(u32, u32, u32)>,
    /// The finest level's rows interpolated along x to the output's width, two at a time (§7).
    upsample_rows: upsample::RowCache,
}

/// Spatial fusion weight σ_s, hard-coded in the original (§6.3).
const SIGMA_SPATIAL: f32 = 4.0;
/// Speckle filter: neighbours within this many level pixels join a segment (§6.4).
const SPECKLE_DIFF: f32 = 1.0;

impl Matcher {
    pub fn new(params: Params) -> Result<Self, MatchError> {
        params.validate()?;
        let p = params.patch_size as usize;
        let c = p as f32 / 2.0 - 0.5;
        let gauss = (0..p * p)
            .map(|i| {
                let (a, b) = ((i % p) as f32, (i / p) as f32);
                (-((a - c).powi(2) + (b - c).powi(2)) / (2.0 * SIGMA_SPATIAL * SIGMA_SPATIAL)).exp()
            })
            .collect();
        // Samples reach p/2 beyond a patch's extreme position, the confidence probes W·δ further, and the
        // bilinear validity rule one more pixel and row: a border this wide keeps every read in bounds.
        // (+ 6: the vector kernels read whole 4-lane chunks, up to 3 samples past a row of the patch.)
        let border = p + (params.num_window as f64 * params.unit_disturb).ceil() as usize + 6;
        Ok(Self {
            params,
            padded_w: 0,
            padded_h: 0,
            pad_x: 0,
            pad_y: 0,
            border,
            levels: Vec::new(),
            gauss,
            template: vec![0.0; p * p],
            grad: vec![0.0; p * p],
            pw: p.div_ceil(4) * 4,
            tmpl_pad: vec![0.0; p * p.div_ceil(4) * 4],
            grad_pad: vec![0.0; p * p.div_ceil(4) * 4],
            colmask: (0..p.div_ceil(4) * 4).map(|j| if j < p { 1.0 } else { 0.0 }).collect(),
            samples: vec![0.0; p * p.div_ceil(4) * 4],
            tmpl_mean: 0.0,
            sum_g: 0.0,
            sum_gt: 0.0,
            sum_t: 0.0,
            tmpl_all_valid: false,
            patches: Vec::new(),
            col_taps: Vec::new(),
            row_taps: Vec::new(),
            labels: Vec::new(),
            next_label: 1,
            stack: Vec::new(),
            members: Vec::new(),
            mirrored_left: Vec::new(),
            mirrored_right: Vec::new(),
            reverse_flow: Vec::new(),
            offset: 0,
            halved_left: Vec::new(),
            halved_right: Vec::new(),
            halved_w: 0,
            halving_sums: Vec::new(),
            upsample_rows: upsample::RowCache::default(),
        })
    }

    pub fn params(&self) -> &Params {
        &self.params
    }

    /// Sizes the buffers for a `w`×`h` level 0 (the input halved [`Self::offset`] times) and an `out_w`×`out_h`
    /// output (a no-op when the sizes are unchanged).
    fn prepare(&mut self, w: usize, h: usize, out_w: usize, out_h: usize) -> Result<(), MatchError> {
        let lv_f = self.params.lv_f as usize;
        let unit = 1usize << lv_f;
        let padded_w = w.div_ceil(unit) * unit;
        let padded_h = h.div_ceil(unit) * unit;
        self.halved_w = w;
        if padded_w == self.padded_w && padded_h == self.padded_h && !self.levels.is_empty() {
            let (pad_x, pad_y) = ((padded_w - w) / 2, (padded_h - h) / 2);
            if (pad_x, pad_y, self.col_taps.len(), self.row_taps.len()) != (self.pad_x, self.pad_y, out_w, out_h) {
                self.pad_x = pad_x;
                self.pad_y = pad_y;
                self.compute_taps(out_w, out_h);
                // Another image size with the same padded size: the old pixels in the new padding must go.
                self.levels[0].left.fill(0.0);
                self.levels[0].right.fill(0.0);
            }
            return Ok(());
        }
        // The coarsest level must hold at least one patch position.
        if padded_w >> lv_f < 1 || padded_h >> lv_f < 1 || w < 2 || h < 2 {
            return Err(MatchError::TooSmall { w, h, levels: self.params.lv_f, patch: self.params.patch_size });
        }
        self.padded_w = padded_w;
        self.padded_h = padded_h;
        self.pad_x = (padded_w - w) / 2;
        self.pad_y = (padded_h - h) / 2;
        let border = self.border;
        self.levels = (0..=lv_f)
            .map(|s| {
                let (lw, lh) = (padded_w >> s, padded_h >> s);
                let stride = lw + 2 * border;
                let bordered = stride * (lh + 2 * border);
                Level {
                    w: lw,
                    h: lh,
                    stride,
                    left: vec![0.0; bordered],
                    right: vec![0.0; bordered],
                    left_ix: vec![0.0; bordered],
                    right_ok: vec![0; bordered],
                    bad_sat: vec![0; (stride + 1) * (lh + 2 * border + 1)],
                    usable: vec![0.0; bordered],
                    flow: vec![f32::NAN; lw * lh],
                    prob: vec![0.0; lw * lh],
                    num: vec![0.0; lw * lh],
                    den: vec![0.0; lw * lh],
                    prob_sum: vec![0.0; lw * lh],
                    count: vec![0; lw * lh],
                    var_num: vec![0.0; lw * lh],
                }
            })
            .collect();
        let max_patches = {
            let l = &self.levels[self.params.lv_l as usize];
            let sp = self.params.stride() as usize;
            l.w.div_ceil(sp) * l.h.div_ceil(sp)
        };
        self.patches = Vec::with_capacity(max_patches);
        let finest = &self.levels[self.params.lv_l as usize];
        self.labels = vec![0; finest.w * finest.h];
        self.next_label = 1;
        self.stack = Vec::with_capacity(finest.w * finest.h);
        self.members = Vec::with_capacity(finest.w * finest.h);
        self.compute_taps(out_w, out_h);
        Ok(())
    }

    /// Computes disparity and confidence for a rectified pair, into `out` (its buffers are reused).
    pub fn compute_into(
        &mut self,
        left: GrayImage<'_>,
        right: GrayImage<'_>,
        out: &mut DisparityMap,
    ) -> Result<(), MatchError> {
        if (left.width, left.height) != (right.width, right.height) {
            return Err(MatchError::SizeMismatch {
                lw: left.width,
                lh: left.height,
                rw: right.width,
                rh: right.height,
            });
        }
        for img in [&left, &right] {
            let needed = img.width * img.height;
            if img.data.len() < needed {
                return Err(MatchError::Buffer { len: img.data.len(), w: img.width, h: img.height, needed });
            }
        }
        let (w, h) = (left.width, left.height);
        let offset = self.params.level_offset_for(w, h) as usize;
        if offset != self.offset {
            // Another level 0: every size-dependent buffer is sized again.
            self.offset = offset;
            self.levels.clear();
        }
        // Taken out of `self` for the passes (which borrow all of it) and put back: the buffers stay reused.
        let (mut halved_left, mut halved_right) =
            (std::mem::take(&mut self.halved_left), std::mem::take(&mut self.halved_right));
        let (left, right) = if offset == 0 {
            (left, right)
        } else {
            (
                halve(left, offset, HalvingRule::AllValid, &mut self.halving_sums, &mut halved_left),
                halve(right, offset, HalvingRule::ValidMean, &mut self.halving_sums, &mut halved_right),
            )
        };
        let prepared = self.prepare(left.width, left.height, w, h);
        if prepared.is_ok() {
            let lr_check = self.params.lr_tolerance_level_px();
            if lr_check.is_some() {
                self.match_mirrored(left, right);
            }
            self.match_pass(left, right, lr_check);
            self.write_output(w, h, out);
        }
        self.halved_left = halved_left;
        self.halved_right = halved_right;
        prepared
    }

    /// One matching pass over a pair of the prepared size, from the pyramid to the finest level's flow. With
    /// `lr_check` (finest-level px), that level keeps only what the mirrored pass's flow confirms, before its
    /// speckle removal, so what the check leaves in small islands goes too.
    fn match_pass(&mut self, left: GrayImage<'_>, right: GrayImage<'_>, lr_check: Option<f32>) {
        self.build_pyramid(left, right);
        let (lv_f, lv_l) = (self.params.lv_f as usize, self.params.lv_l as usize);
        // The coarsest level is searched from zero disparity; so is a level below one that kept no pixel.
        let mut from_zero = true;
        for s in (lv_l..=lv_f).rev() {
            self.search_level(s, from_zero);
            self.fuse_level(s);
            if s == lv_l && self.params.algorithm == Algorithm::Bdis {
                let min_prob = self.params.min_prob as f32;
                let level = &mut self.levels[s];
                for (f, p) in level.flow.iter_mut().zip(level.prob.iter_mut()) {
                    if *p <= min_prob {
                        *f = f32::NAN;
                    }
                }
            }
            if s == lv_l
                && let Some(tolerance) = lr_check
            {
                self.keep_consistent(tolerance);
            }
            self.remove_speckles(s);
            from_zero = !self.levels[s].flow.iter().any(|f| f.is_finite());
        }
    }

    /// Convenience: a freshly allocated map.
    pub fn compute(&mut self, left: GrayImage<'_>, right: GrayImage<'_>) -> Result<DisparityMap, MatchError> {
        let mut out = DisparityMap::default();
        self.compute_into(left, right, &mut out)?;
        Ok(out)
    }
}

#[cfg(test)]
mod tests;
