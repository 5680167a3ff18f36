//! The matcher: image pyramid, patch grid, 1-D inverse-compositional search with coarse-to-fine propagation,
//! the Bayesian patch confidence, level likelihoods, Gaussian-weighted fusion, speckle removal, the `min_prob`
//! threshold and the upsampled output. Written from `BDIS-ALGORITHM.md`; section numbers below refer to it.
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
//! * a fully valid patch is evaluated in one pass (see [`Matcher::eval`]), which cannot see a sample that is
//!   exactly equal to its patch mean (the original counts it invalid); patches touching invalid pixels, where
//!   that rule rejects flat dark areas, keep the exact two-pass evaluation;
//! * images smaller than one coarsest-level patch give an empty map rather than an error (there is nothing to
//!   search); use a smaller `lv_f` for small images.

use wide::f32x4;

use crate::kernels;
use crate::params::{Algorithm, ParamError, Params};

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
        })
    }

    pub fn params(&self) -> &Params {
        &self.params
    }

    /// Sizes the buffers for `w`×`h` inputs (a no-op when the size is unchanged).
    fn prepare(&mut self, w: usize, h: usize) -> Result<(), MatchError> {
        let lv_f = self.params.lv_f as usize;
        let unit = 1usize << lv_f;
        let padded_w = w.div_ceil(unit) * unit;
        let padded_h = h.div_ceil(unit) * unit;
        if padded_w == self.padded_w && padded_h == self.padded_h && !self.levels.is_empty() {
            let (pad_x, pad_y) = ((padded_w - w) / 2, (padded_h - h) / 2);
            if (pad_x, pad_y, self.col_taps.len(), self.row_taps.len()) != (self.pad_x, self.pad_y, w, h) {
                self.pad_x = pad_x;
                self.pad_y = pad_y;
                self.compute_taps(w, h);
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
        self.compute_taps(w, h);
        Ok(())
    }

    /// OpenCV INTER_LINEAR taps for upsampling the finest searched level by 2^lv_l: source coordinate
    /// (x + 0.5)/f − 0.5, clamped at the borders; padding offsets included.
    fn compute_taps(&mut self, w: usize, h: usize) {
        let lv_l = self.params.lv_l as usize;
        let factor = (1usize << lv_l) as f32;
        let (lw, lh) = (self.levels[lv_l].w, self.levels[lv_l].h);
        let tap = |x: usize, n: usize| -> (u32, u32, f32) {
            let sx = (x as f32 + 0.5) / factor - 0.5;
            if sx <= 0.0 {
                return (0, 0, 0.0);
            }
            let x0 = sx.floor() as usize;
            if x0 + 1 >= n {
                return ((n - 1) as u32, (n - 1) as u32, 0.0);
            }
            (x0 as u32, (x0 + 1) as u32, sx - x0 as f32)
        };
        self.col_taps.clear();
        self.col_taps.extend((0..w).map(|x| tap(x + self.pad_x, lw)));
        self.row_taps.clear();
        self.row_taps.extend((0..h).map(|y| tap(y + self.pad_y, lh)));
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
        self.prepare(w, h)?;
        self.build_pyramid(left, right);
        let (lv_f, lv_l) = (self.params.lv_f as usize, self.params.lv_l as usize);
        for s in (lv_l..=lv_f).rev() {
            self.search_level(s);
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
            self.remove_speckles(s);
        }
        self.write_output(w, h, out);
        Ok(())
    }

    /// Convenience: a freshly allocated map.
    pub fn compute(&mut self, left: GrayImage<'_>, right: GrayImage<'_>) -> Result<DisparityMap, MatchError> {
        let mut out = DisparityMap::default();
        self.compute_into(left, right, &mut out)?;
        Ok(out)
    }

    /// §1–2: padded float images, 2×2-mean pyramid where any invalid (0) pixel makes its parent invalid, the
    /// left x-gradient `I(x+1) − I(x−1)` (0 where a neighbour is invalid or at the image edge), and the right
    /// validity mask.
    fn build_pyramid(&mut self, left: GrayImage<'_>, right: GrayImage<'_>) {
        let border = self.border;
        let (pad_x, pad_y) = (self.pad_x, self.pad_y);
        {
            let l0 = &mut self.levels[0];
            // Borders and padding are never written, so they keep the zeros of their allocation (`prepare`
            // clears level 0 again when the padding moves); only the image area is overwritten.
            let w = left.width;
            for y in 0..left.height {
                let dst = (y + pad_y + border) * l0.stride + pad_x + border;
                let src = y * w;
                for (d, &v) in l0.left[dst..dst + w].iter_mut().zip(&left.data[src..src + w]) {
                    *d = f32::from(v);
                }
                for (d, &v) in l0.right[dst..dst + w].iter_mut().zip(&right.data[src..src + w]) {
                    *d = f32::from(v);
                }
            }
        }
        for s in 1..self.levels.len() {
            let (coarser, finer) = {
                let (a, b) = self.levels.split_at_mut(s);
                (&mut b[0], &a[s - 1])
            };
            let (cw, fs) = (coarser.w, finer.stride);
            for y in 0..coarser.h {
                let dst = (y + border) * coarser.stride + border;
                let src = (2 * y + border) * fs + border;
                let (top, bottom) = (&finer.left[src..src + 2 * cw], &finer.left[src + fs..src + fs + 2 * cw]);
                for ((out, t), b) in
                    coarser.left[dst..dst + cw].iter_mut().zip(top.chunks_exact(2)).zip(bottom.chunks_exact(2))
                {
                    let (a, b, c, d) = (t[0], t[1], b[0], b[1]);
                    *out = if a == 0.0 || b == 0.0 || c == 0.0 || d == 0.0 { 0.0 } else { 0.25 * (a + b + c + d) };
                }
                let (top, bottom) = (&finer.right[src..src + 2 * cw], &finer.right[src + fs..src + fs + 2 * cw]);
                for ((out, t), b) in
                    coarser.right[dst..dst + cw].iter_mut().zip(top.chunks_exact(2)).zip(bottom.chunks_exact(2))
                {
                    let (a, b, c, d) = (t[0], t[1], b[0], b[1]);
                    let n =
                        f32::from(u8::from(a != 0.0) + u8::from(b != 0.0) + u8::from(c != 0.0) + u8::from(d != 0.0));
                    *out = if n == 0.0 { 0.0 } else { (a + b + c + d) / n };
                }
            }
        }
        // Gradients, usable-sample masks and their summed-area table only where patches are searched. Borders
        // and the first/last gradient column are never written, so they stay 0 from allocation.
        let lv_l = self.params.lv_l as usize;
        for level in &mut self.levels[lv_l..] {
            for y in 0..level.h {
                let row = (y + border) * level.stride + border;
                let img = &level.left[row..row + level.w];
                let ix = &mut level.left_ix[row..row + level.w];
                for x in 1..level.w.saturating_sub(1) {
                    let (a, b) = (img[x - 1], img[x + 1]);
                    ix[x] = if a == 0.0 || b == 0.0 { 0.0 } else { b - a };
                }
            }
            let n = level.right.len();
            let stride = level.stride;
            let (upper, lower) = level.right.split_at(stride);
            let _ = upper;
            for ((ok, &v), &below) in level.right_ok[..n - stride].iter_mut().zip(&level.right[..n - stride]).zip(lower)
            {
                *ok = u8::from(v != 0.0 && below != 0.0);
            }
            let rows = n / stride;
            let w1 = stride + 1;
            for y in 0..rows {
                let mut row_sum = 0u32;
                let ok = &level.right_ok[y * stride..(y + 1) * stride];
                let (above, below) = level.bad_sat.split_at_mut((y + 1) * w1);
                let above = &above[y * w1..];
                let below = &mut below[..w1];
                let usable_row = &mut level.usable[y * stride..(y + 1) * stride];
                for x in 0..stride {
                    let usable = x + 1 < stride && ok[x] & ok[(x + 1).min(stride - 1)] != 0;
                    usable_row[x] = if usable { 1.0 } else { 0.0 };
                    row_sum += u32::from(!usable);
                    below[x + 1] = above[x + 1] + row_sum;
                }
            }
        }
    }

    /// Level likelihood L(s) = (1/s) / Σ_{t=lv_l..lv_f} 1/t (§6.2).
    fn level_likelihood(&self, s: usize) -> f32 {
        let total: f64 = (self.params.lv_l..=self.params.lv_f).map(|t| 1.0 / f64::from(t)).sum();
        ((1.0 / s as f64) / total) as f32
    }

    /// §3–6.1 for every patch of level `s`.
    fn search_level(&mut self, s: usize) {
        let sp = self.params.stride() as usize;
        let (lw, lh) = (self.levels[s].w, self.levels[s].h);
        let (nw, nh) = (lw.div_ceil(sp), lh.div_ceil(sp));
        let ow = (lw - (nw - 1) * sp) / 2;
        let oh = (lh - (nh - 1) * sp) / 2;
        let coarsest = s == self.params.lv_f as usize;
        let likelihood = self.level_likelihood(s);
        let bayesian = self.params.algorithm == Algorithm::Bdis;
        self.patches.clear();
        for j in 0..nh {
            for i in 0..nw {
                let (qx, qy) = (i * sp + ow, j * sp + oh);
                let (u0, prob0) = if coarsest {
                    (0.0f32, 0.0f32)
                } else {
                    let parent = &self.levels[s + 1];
                    let k = (qy / 2).min(parent.h - 1) * parent.w + (qx / 2).min(parent.w - 1);
                    (2.0 * parent.flow[k], parent.prob[k])
                };
                // §5: only patches whose parent found something are searched.
                if !coarsest && (u0 == 0.0 || u0.is_nan() || prob0 <= 0.0) {
                    continue;
                }
                let result = self.search_patch(s, qx, qy, u0);
                if result.b > 0.0 {
                    let prob = if bayesian {
                        if coarsest { result.b * likelihood } else { result.b * likelihood + prob0 }
                    } else {
                        1.0
                    };
                    self.patches.push((qx, qy, result, prob));
                }
            }
        }
    }

    /// Loads the template (mean-normalised left samples) and gradients of the patch at `q`, and the per-patch
    /// constants of the fast evaluation; returns the Hessian.
    fn load_template(&mut self, level: usize, qx: usize, qy: usize) -> f32 {
        let p = self.params.patch_size as usize;
        let half = p / 2;
        let l = &self.levels[level];
        let (border, stride) = (self.border, l.stride);
        let mut sum = 0.0f32;
        let mut n = 0usize;
        for b in 0..p {
            let row = (qy + b + border - half) * stride + border + qx - half;
            let (src, srcg) = (&l.left[row..row + p], &l.left_ix[row..row + p]);
            let (dst, dstg) = (&mut self.template[b * p..(b + 1) * p], &mut self.grad[b * p..(b + 1) * p]);
            dst.copy_from_slice(src);
            dstg.copy_from_slice(srcg);
            for &v in src {
                if v != 0.0 {
                    sum += v;
                    n += 1;
                }
            }
        }
        let mean = if n > 0 { sum / n as f32 } else { 0.0 };
        let (mut hessian, mut sum_g, mut sum_gt, mut sum_t) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
        let mut all_valid = n == p * p;
        for k in 0..p * p {
            let mut t = self.template[k];
            if t > 0.0 {
                t -= mean;
                self.template[k] = t;
            }
            let g = self.grad[k];
            hessian += g * g;
            sum_g += g;
            sum_gt += g * t;
            sum_t += t;
            // A template pixel equal to its mean normalises to exactly 0 and counts as invalid (§4).
            all_valid &= t != 0.0;
        }
        let pw = self.pw;
        for b in 0..p {
            self.tmpl_pad[b * pw..b * pw + p].copy_from_slice(&self.template[b * p..(b + 1) * p]);
            self.grad_pad[b * pw..b * pw + p].copy_from_slice(&self.grad[b * p..(b + 1) * p]);
        }
        self.tmpl_mean = mean;
        self.sum_g = sum_g;
        self.sum_gt = sum_gt;
        self.sum_t = sum_t;
        self.tmpl_all_valid = all_valid;
        if hessian == 0.0 { 1e-10 } else { hessian }
    }

    /// Residual statistics of the patch at `q` shifted by `u`: valid count, Σ g·r, Σ r², and mean |r| (the last
    /// only from the exact path). `None` when the shift leaves the level's bounds.
    ///
    /// Fast path, when every template pixel is valid and every right sample usable (one summed-area lookup):
    /// with s̃ = S − m_T and Ã = mean s̃, the normalised residual is r = s̃ − Ã − T', so
    /// Σ g·r = Σ g·s̃ − Ã·Σg − Σ g·T' and Σ r² = Σ (s̃ − T')² − 2Ã·Σ(s̃ − T') + n·Ã², one pass over the samples.
    /// Patches touching invalid pixels, and every evaluation when the stopping rules need the mean |r|, take the
    /// exact two-pass [`Self::residual_at`]. The one-pass form cannot see a sample exactly equal to its patch
    /// mean (invalid in the original); the only systematic case, a flat patch, is detected from the samples'
    /// range and treated as the original treats it: no valid pixel.
    fn eval(&mut self, level: usize, qx: usize, qy: usize, u: f32, want_r2: bool, exact: bool) -> Option<Eval> {
        let p = self.params.patch_size as usize;
        let half = (p / 2) as f32;
        let l = &self.levels[level];
        let x_pos = qx as f32 + u;
        if !(x_pos >= -half && x_pos <= l.w as f32 + half - 2.0) {
            return None;
        }
        let x0 = x_pos - half;
        let c0f = (x0 + 1e-5).ceil() - 1.0;
        let border = self.border as isize;
        let win = kernels::Window {
            right: &l.right,
            usable: &l.usable,
            stride: l.stride,
            row0: (qy as isize - half as isize + border) as usize,
            col: (c0f as isize + border) as usize,
            p,
            pw: self.pw,
            frac: x0 - c0f,
        };
        let footprint_usable = {
            let w1 = l.stride + 1;
            let (col, row0) = (win.col, win.row0);
            let (x1, y1) = (col + p, row0 + p);
            let sat = &l.bad_sat;
            sat[y1 * w1 + x1] + sat[row0 * w1 + col] == sat[row0 * w1 + x1] + sat[y1 * w1 + col]
        };
        if exact || !(footprint_usable && self.tmpl_all_valid) {
            // Patches touching invalid pixels (a minority), and every evaluation when the stopping rules need
            // the mean |r|, take the exact two-pass residual: samples equal to their mean (flat dark areas) count
            // as invalid exactly as in the original, which keeps textureless patches from passing the
            // confidence test.
            let e = kernels::exact::<f32x4>(&win, &self.tmpl_pad, &self.grad_pad, &self.colmask, &mut self.samples);
            return Some(Eval {
                n: e.valid as usize,
                sum_gr: e.sum_gr,
                sum_r2: e.sum_r2,
                mares: e.sum_abs / (p * p) as f32,
            });
        }
        let n = (p * p) as f32;
        if want_r2 {
            let (a_sum, e_sum) = kernels::sum_and_sq_diff::<f32x4>(&win, &self.tmpl_pad, &self.colmask, self.tmpl_mean);
            let am = a_sum / n;
            let r2 = e_sum - 2.0 * am * (a_sum - self.sum_t) + n * am * am;
            return Some(Eval { n: p * p, sum_gr: f32::NAN, sum_r2: r2.max(0.0), mares: f32::NAN });
        }
        let (a_sum, b_sum) = kernels::sum_and_dot::<f32x4>(&win, &self.grad_pad, &self.colmask, self.tmpl_mean);
        let am = a_sum / n;
        Some(Eval { n: p * p, sum_gr: b_sum - am * self.sum_g - self.sum_gt, sum_r2: f32::NAN, mares: f32::NAN })
    }

    /// §4 search from `u0`, then §6.1 confidence.
    fn search_patch(&mut self, level: usize, qx: usize, qy: usize, u0: f32) -> PatchResult {
        let prm = self.params;
        let p = prm.patch_size as usize;
        let failed = PatchResult { u: u0, b: 0.0, var: f32::NAN };
        // The stopping rules that read the mean |r| are inactive with the shipped parameters
        // (miniter = maxiter, minimgerr = 0, §4.4); only when they are active does every step take the exact path.
        let exact = prm.miniter < prm.maxiter || prm.minimgerr > 0.0;
        let hessian = self.load_template(level, qx, qy);
        let Some(first) = self.eval(level, qx, qy, u0, false, exact) else {
            return failed;
        };
        let mut u = u0;
        let mut sum_gr = first.sum_gr;
        let mut mares = first.mares;
        let mut first_step_sq = 0.0f32;
        let outlier = (p / 2) as f32;
        let mut t = 0u32;
        loop {
            t += 1;
            let delta = sum_gr / hessian;
            if t == 1 {
                first_step_sq = delta * delta;
            }
            let candidate = (u - delta).min(0.0);
            if (candidate - u0).abs() > outlier {
                u = u0;
                break;
            }
            let last = t >= prm.maxiter;
            // Without the rate tests the last step's residual only feeds the confidence, which takes its own.
            if last && !exact {
                let x_pos = qx as f32 + candidate;
                let half = (p / 2) as f32;
                u = if x_pos >= -half && x_pos <= self.levels[level].w as f32 + half - 2.0 { candidate } else { u0 };
                break;
            }
            let Some(next) = self.eval(level, qx, qy, candidate, false, exact) else {
                u = u0;
                break;
            };
            u = candidate;
            sum_gr = next.sum_gr;
            let mares_prev = mares;
            mares = next.mares;
            if exact {
                let keep_going = !last
                    && f64::from(mares) > prm.minimgerr
                    && (t < prm.miniter
                        || f64::from(delta * delta) >= prm.mindprate * prm.mindprate * f64::from(first_step_sq))
                    && (t < prm.miniter || f64::from(mares) <= prm.mindrrate * f64::from(mares_prev));
                if !keep_going {
                    break;
                }
            }
        }
        // §6.1 confidence at the final position.
        let min_valid = (prm.ratio_patch_valid * (p * p) as f64).ceil() as usize;
        let Some(centre) = self.eval(level, qx, qy, u, true, exact) else {
            return failed;
        };
        if centre.n == 0 || centre.n < min_valid {
            return failed;
        }
        if prm.algorithm == Algorithm::Dis {
            return PatchResult { u, b: 1.0, var: f32::NAN };
        }
        let e0 = centre.sum_r2 / centre.n as f32;
        let centre_score = (-0.5f32).exp();
        let mut total = centre_score;
        let w = prm.num_window as i32;
        let delta = prm.unit_disturb as f32;
        let mut log_scores = [0f32; 33];
        for k in (-w..=w).filter(|&k| k != 0) {
            let Some(probe) = self.eval(level, qx, qy, u + k as f32 * delta, true, exact) else {
                return failed;
            };
            if probe.n == 0 || probe.n < min_valid {
                return failed;
            }
            let ek = probe.sum_r2 / probe.n as f32;
            // The optimum must be a strict minimum against every probed neighbour.
            if ek <= e0 {
                return failed;
            }
            let y = if e0 > 0.0 { -ek / (2.0 * e0) } else { f32::NEG_INFINITY };
            log_scores[(k + w) as usize] = y;
            total += y.exp();
        }
        log_scores[w as usize] = -0.5;
        let b = centre_score / total;
        let var = if prm.variance {
            variance_fit(&log_scores[..(2 * w + 1) as usize], total.ln(), delta, p)
        } else {
            f32::NAN
        };
        PatchResult { u, b, var }
    }

    /// §6.3: Gaussian-weighted (BDIS) or uniform (DIS) fusion of the level's patches into per-pixel flow and
    /// probability.
    fn fuse_level(&mut self, s: usize) {
        let p = self.params.patch_size as usize;
        let half = p / 2;
        let bayesian = self.params.algorithm == Algorithm::Bdis;
        let want_var = self.params.variance && s == self.params.lv_l as usize;
        let level = &mut self.levels[s];
        let (lw, lh) = (level.w, level.h);
        // The accumulators are cleared as they are consumed below, so they start at 0 without a pass of their
        // own; with variances the finest level's weights are read again at output time, so that level is
        // cleared up front instead.
        if want_var {
            level.num.fill(0.0);
            level.den.fill(0.0);
            level.prob_sum.fill(0.0);
            level.count.fill(0);
            level.var_num.fill(0.0);
        }
        for &(qx, qy, r, prob) in &self.patches {
            // The patch covers q + (a − p/2, b − p/2), a, b < p; clip it to the level once.
            let (x_lo, x_hi) = (qx.saturating_sub(half), (qx + half).min(lw));
            let (y_lo, y_hi) = (qy.saturating_sub(half), (qy + half).min(lh));
            let (a0, b0) = (x_lo + half - qx, y_lo + half - qy);
            for (bi, y) in (y_lo..y_hi).enumerate() {
                let row = y * lw;
                let gauss = &self.gauss[(b0 + bi) * p + a0..(b0 + bi) * p + a0 + (x_hi - x_lo)];
                let range = row + x_lo..row + x_hi;
                let (num, den) = (&mut level.num[range.clone()], &mut level.den[range.clone()]);
                let (psum, count) = (&mut level.prob_sum[range.clone()], &mut level.count[range.clone()]);
                for i in 0..gauss.len() {
                    let wgt = if bayesian { prob * gauss[i] } else { 1.0 };
                    num[i] += wgt * r.u;
                    den[i] += wgt;
                    psum[i] += prob;
                    count[i] += 1;
                }
                if want_var {
                    for (i, v) in level.var_num[range].iter_mut().enumerate() {
                        let wgt = if bayesian { prob * gauss[i] } else { 1.0 };
                        *v += wgt * wgt * r.var;
                    }
                }
            }
        }
        for k in 0..lw * lh {
            let (count, den) = (level.count[k], level.den[k]);
            if count > 0 && den > 0.0 {
                level.flow[k] = level.num[k] / den;
                level.prob[k] = level.prob_sum[k] / f32::from(count);
            } else {
                level.flow[k] = f32::NAN;
                level.prob[k] = 0.0;
            }
            if !want_var {
                level.num[k] = 0.0;
                level.den[k] = 0.0;
                level.prob_sum[k] = 0.0;
                level.count[k] = 0;
            }
        }
    }

    /// §6.4: 4-connected segments of similar flow with ≤ 4^(lv_f − s) pixels are removed.
    fn remove_speckles(&mut self, s: usize) {
        let max_small = 4usize.pow(self.params.lv_f - s as u32);
        let level = &mut self.levels[s];
        let (lw, lh) = (level.w, level.h);
        let labels = &mut self.labels[..lw * lh];
        // Labels below `first` belong to earlier levels or calls and mean "not visited": no clearing pass.
        if self.next_label > u32::MAX - (lw * lh) as u32 - 1 {
            labels.fill(0);
            self.next_label = 1;
        }
        let first = self.next_label;
        let mut next = first;
        for seed in 0..lw * lh {
            if labels[seed] >= first || !level.flow[seed].is_finite() {
                continue;
            }
            self.stack.clear();
            self.members.clear();
            self.stack.push(seed);
            labels[seed] = next;
            while let Some(k) = self.stack.pop() {
                self.members.push(k);
                let f = level.flow[k];
                let (x, y) = (k % lw, k / lw);
                let mut visit = |n: usize| {
                    if labels[n] < first && level.flow[n].is_finite() && (level.flow[n] - f).abs() <= SPECKLE_DIFF {
                        labels[n] = next;
                        self.stack.push(n);
                    }
                };
                if x > 0 {
                    visit(k - 1);
                }
                if x + 1 < lw {
                    visit(k + 1);
                }
                if y > 0 {
                    visit(k - lw);
                }
                if y + 1 < lh {
                    visit(k + lw);
                }
            }
            if self.members.len() <= max_small {
                for &k in &self.members {
                    level.flow[k] = f32::NAN;
                    level.prob[k] = 0.0;
                }
            }
            next += 1;
        }
        self.next_label = next;
    }

    /// §5 end: the finest level's flow ×2^lv_l, bilinear upsampling (NaN spreads), crop, sign → disparity.
    fn write_output(&self, w: usize, h: usize, out: &mut DisparityMap) {
        let lv_l = self.params.lv_l as usize;
        let level = &self.levels[lv_l];
        let factor = (1usize << lv_l) as f32;
        out.width = w;
        out.height = h;
        out.disparity.resize(w * h, 0.0);
        out.confidence.resize(w * h, 0.0);
        let want_var = self.params.variance;
        if want_var {
            out.variance.get_or_insert_with(Vec::new).resize(w * h, 0.0);
        } else {
            out.variance = None;
        }
        for y in 0..h {
            let (y0, y1, fy) = self.row_taps[y];
            let (r0, r1) = (y0 as usize * level.w, y1 as usize * level.w);
            let disparity = &mut out.disparity[y * w..(y + 1) * w];
            let confidence = &mut out.confidence[y * w..(y + 1) * w];
            for (x, &(x0, x1, fx)) in self.col_taps.iter().enumerate() {
                let (x0, x1) = (x0 as usize, x1 as usize);
                let idx = [
                    (r0 + x0, (1.0 - fx) * (1.0 - fy)),
                    (r0 + x1, fx * (1.0 - fy)),
                    (r1 + x0, (1.0 - fx) * fy),
                    (r1 + x1, fx * fy),
                ];
                let mut flow = 0.0f32;
                let mut prob = 0.0f32;
                for &(k, wgt) in &idx {
                    flow += wgt * level.flow[k];
                    prob += wgt * level.prob[k];
                }
                let d = -flow * factor;
                // NaN fails the comparison: invalid.
                let valid = d > 0.0;
                disparity[x] = if valid { d } else { f32::NAN };
                confidence[x] = if valid { prob.clamp(0.0, 1.0) } else { 0.0 };
                if let Some(var) = out.variance.as_mut() {
                    var[y * w + x] = if valid { self.pixel_variance(lv_l, &idx) * factor * factor } else { f32::NAN };
                }
            }
        }
    }

    /// Fused variance Σw²·var / (Σw)² at the stencil's heaviest level pixel.
    fn pixel_variance(&self, s: usize, idx: &[(usize, f32); 4]) -> f32 {
        let level = &self.levels[s];
        let (k, _) = idx.iter().copied().fold((0, -1.0f32), |best, t| if t.1 > best.1 { t } else { best });
        let den = level.den[k];
        if den > 0.0 { level.var_num[k] / (den * den) } else { f32::NAN }
    }
}

/// §6.5: fit a Gaussian `log b_k = log r − x_k²/(2σ²)` to the candidates' log-probabilities (least squares in
/// closed form: it is linear in log r and 1/(2σ²)) and return σ² in level px², or the maximum `(p/2)²` when the
/// fit is degenerate. `log_scores` are the unnormalised log scores, `log_total` their log-sum.
fn variance_fit(log_scores: &[f32], log_total: f32, delta: f32, p: usize) -> f32 {
    let max_var = (p as f32 / 2.0).powi(2);
    let w = (log_scores.len() / 2) as i32;
    // Normal equations for y = α + β·x² with y = log b_k.
    let (mut s1, mut sx, mut sxx, mut sy, mut sxy) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (i, &ls) in log_scores.iter().enumerate() {
        let y = f64::from(ls - log_total);
        if !y.is_finite() {
            return max_var;
        }
        let x2 = f64::from(((i as i32 - w) as f32 * delta).powi(2));
        s1 += 1.0;
        sx += x2;
        sxx += x2 * x2;
        sy += y;
        sxy += x2 * y;
    }
    let det = s1 * sxx - sx * sx;
    if det.abs() < 1e-12 {
        return max_var;
    }
    let beta = (s1 * sxy - sx * sy) / det;
    if beta >= 0.0 {
        return max_var;
    }
    ((-1.0 / (2.0 * beta)) as f32).min(max_var)
}
