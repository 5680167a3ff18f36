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
//! * the unused parts are not written: the right and vertical gradients, `usefbcon`, the other cost functions.

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
    residual: Vec<f32>,
    /// Per patch of the current level: result and reference point.
    patches: Vec<(usize, usize, PatchResult, f32)>,
    /// Speckle filter scratch.
    labels: Vec<u32>,
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
        let border = p + (params.num_window as f64 * params.unit_disturb).ceil() as usize + 2;
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
            residual: vec![0.0; p * p],
            patches: Vec::new(),
            labels: Vec::new(),
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
            self.pad_x = (padded_w - w) / 2;
            self.pad_y = (padded_h - h) / 2;
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
        self.stack = Vec::with_capacity(finest.w * finest.h);
        self.members = Vec::with_capacity(finest.w * finest.h);
        Ok(())
    }

    /// Computes disparity and confidence for a rectified pair, into `out` (its buffers are reused).
    pub fn compute_into(&mut self, left: GrayImage<'_>, right: GrayImage<'_>, out: &mut DisparityMap) -> Result<(), MatchError> {
        if (left.width, left.height) != (right.width, right.height) {
            return Err(MatchError::SizeMismatch { lw: left.width, lh: left.height, rw: right.width, rh: right.height });
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
            l0.left.fill(0.0);
            l0.right.fill(0.0);
            for y in 0..left.height {
                let dst = (y + pad_y + border) * l0.stride + pad_x + border;
                let src = y * left.width;
                for x in 0..left.width {
                    l0.left[dst + x] = f32::from(left.data[src + x]);
                    l0.right[dst + x] = f32::from(right.data[src + x]);
                }
            }
        }
        for s in 1..self.levels.len() {
            let (coarser, finer) = {
                let (a, b) = self.levels.split_at_mut(s);
                (&mut b[0], &a[s - 1])
            };
            coarser.left.fill(0.0);
            coarser.right.fill(0.0);
            for y in 0..coarser.h {
                for x in 0..coarser.w {
                    let dst = (y + border) * coarser.stride + x + border;
                    let src = (2 * y + border) * finer.stride + 2 * x + border;
                    let img = &finer.left;
                    let (a, b, c, d) = (img[src], img[src + 1], img[src + finer.stride], img[src + finer.stride + 1]);
                    coarser.left[dst] = if a == 0.0 || b == 0.0 || c == 0.0 || d == 0.0 { 0.0 } else { 0.25 * (a + b + c + d) };
                    let img = &finer.right;
                    let (a, b, c, d) = (img[src], img[src + 1], img[src + finer.stride], img[src + finer.stride + 1]);
                    let n = u8::from(a != 0.0) + u8::from(b != 0.0) + u8::from(c != 0.0) + u8::from(d != 0.0);
                    coarser.right[dst] = if n == 0 { 0.0 } else { (a + b + c + d) / f32::from(n) };
                }
            }
        }
        for level in &mut self.levels {
            level.left_ix.fill(0.0);
            level.right_ok.fill(0);
            for y in 0..level.h {
                let row = (y + border) * level.stride + border;
                for x in 1..level.w.saturating_sub(1) {
                    let i = row + x;
                    let (a, b) = (level.left[i - 1], level.left[i + 1]);
                    level.left_ix[i] = if a == 0.0 || b == 0.0 { 0.0 } else { b - a };
                }
            }
            // right_ok over the whole bordered area: border pixels are 0 and so never usable.
            let n = level.right.len();
            for i in 0..n - level.stride {
                level.right_ok[i] = u8::from(level.right[i] != 0.0 && level.right[i + level.stride] != 0.0);
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

    /// Normalised residual `r = S_u − T` of the patch at `q` shifted by `u` (§4). Returns the number of valid
    /// entries, Σ|r| and Σr², or `None` when the shifted patch leaves the level's bounds.
    fn residual_at(&mut self, level: usize, qx: usize, qy: usize, u: f32) -> Option<(usize, f32, f32)> {
        let p = self.params.patch_size as usize;
        let half = (p / 2) as f32;
        let l = &self.levels[level];
        let x_pos = qx as f32 + u;
        if !(x_pos >= -half && x_pos <= l.w as f32 + half - 2.0) {
            return None;
        }
        // All samples of a patch share the fractional part: x = x_pos − p/2 + a for integer a.
        let x0 = x_pos - half;
        let c0 = (x0 + 1e-5).ceil() - 1.0;
        let frac = x0 - c0;
        let c0 = c0 as isize;
        let border = self.border as isize;
        let stride = l.stride as isize;
        let y0 = qy as isize - half as isize;
        let mut sum = 0.0f32;
        let mut n = 0usize;
        // First pass: samples (0 = invalid) into the residual buffer, and their mean.
        for b in 0..p {
            let row = (y0 + b as isize + border) * stride + border;
            for a in 0..p {
                let i = (row + c0 + a as isize) as usize;
                let v = if l.right_ok[i] != 0 && l.right_ok[i + 1] != 0 {
                    l.right[i] * (1.0 - frac) + l.right[i + 1] * frac
                } else {
                    0.0
                };
                self.residual[b * p + a] = v;
                if v > 0.0 {
                    sum += v;
                    n += 1;
                }
            }
        }
        let mean = if n > 0 { sum / n as f32 } else { 0.0 };
        let mut valid = 0usize;
        let mut abs_sum = 0.0f32;
        let mut sq_sum = 0.0f32;
        for k in 0..p * p {
            let sv = self.residual[k];
            let sn = if sv > 0.0 { sv - mean } else { 0.0 };
            let t = self.template[k];
            let r = if sn != 0.0 && t != 0.0 {
                valid += 1;
                sn - t
            } else {
                0.0
            };
            self.residual[k] = r;
            abs_sum += r.abs();
            sq_sum += r * r;
        }
        Some((valid, abs_sum, sq_sum))
    }

    /// Loads the template (mean-normalised left samples) and gradients of the patch at `q`; returns the Hessian.
    fn load_template(&mut self, level: usize, qx: usize, qy: usize) -> f32 {
        let p = self.params.patch_size as usize;
        let half = p / 2;
        let l = &self.levels[level];
        let (border, stride) = (self.border, l.stride);
        let mut sum = 0.0f32;
        let mut n = 0usize;
        for b in 0..p {
            let row = (qy + b + border - half) * stride + border + qx - half;
            for a in 0..p {
                let v = l.left[row + a];
                self.template[b * p + a] = v;
                self.grad[b * p + a] = l.left_ix[row + a];
                if v != 0.0 {
                    sum += v;
                    n += 1;
                }
            }
        }
        let mean = if n > 0 { sum / n as f32 } else { 0.0 };
        let mut hessian = 0.0f32;
        for k in 0..p * p {
            if self.template[k] > 0.0 {
                self.template[k] -= mean;
            }
            hessian += self.grad[k] * self.grad[k];
        }
        if hessian == 0.0 { 1e-10 } else { hessian }
    }

    /// §4 search from `u0`, then §6.1 confidence.
    fn search_patch(&mut self, level: usize, qx: usize, qy: usize, u0: f32) -> PatchResult {
        let prm = self.params;
        let p = prm.patch_size as usize;
        let pp = (p * p) as f32;
        let failed = PatchResult { u: u0, b: 0.0, var: f32::NAN };
        let hessian = self.load_template(level, qx, qy);
        let Some((_, abs0, _)) = self.residual_at(level, qx, qy, u0) else {
            return failed;
        };
        let mut u = u0;
        let mut mares = abs0 / pp;
        let mut first_step_sq = 0.0f32;
        let outlier = (p / 2) as f32;
        let mut t = 0u32;
        loop {
            t += 1;
            let mut num = 0.0f32;
            for k in 0..p * p {
                num += self.grad[k] * self.residual[k];
            }
            let delta = num / hessian;
            if t == 1 {
                first_step_sq = delta * delta;
            }
            let candidate = (u - delta).min(0.0);
            if (candidate - u0).abs() > outlier {
                u = u0;
                break;
            }
            let Some((_, abs_sum, _)) = self.residual_at(level, qx, qy, candidate) else {
                u = u0;
                break;
            };
            u = candidate;
            let mares_prev = mares;
            mares = abs_sum / pp;
            let keep_going = t < prm.maxiter
                && f64::from(mares) > prm.minimgerr
                && (t < prm.miniter || f64::from(delta * delta) >= prm.mindprate * prm.mindprate * f64::from(first_step_sq))
                && (t < prm.miniter || f64::from(mares) <= prm.mindrrate * f64::from(mares_prev));
            if !keep_going {
                break;
            }
        }
        // §6.1 confidence at the final position.
        let min_valid = (prm.ratio_patch_valid * (p * p) as f64).ceil() as usize;
        let Some((n0, _, sq0)) = self.residual_at(level, qx, qy, u) else {
            return failed;
        };
        if n0 == 0 || n0 < min_valid {
            return failed;
        }
        if prm.algorithm == Algorithm::Dis {
            return PatchResult { u, b: 1.0, var: f32::NAN };
        }
        let e0 = sq0 / n0 as f32;
        let centre = (-0.5f32).exp();
        let mut total = centre;
        let w = prm.num_window as i32;
        let delta = prm.unit_disturb as f32;
        let mut log_scores = [0f32; 33];
        for k in (-w..=w).filter(|&k| k != 0) {
            let Some((n, _, sq)) = self.residual_at(level, qx, qy, u + k as f32 * delta) else {
                return failed;
            };
            if n == 0 || n < min_valid {
                return failed;
            }
            let ek = sq / n as f32;
            // The optimum must be a strict minimum against every probed neighbour.
            if ek <= e0 {
                return failed;
            }
            let y = if e0 > 0.0 { -ek / (2.0 * e0) } else { f32::NEG_INFINITY };
            log_scores[(k + w) as usize] = y;
            total += y.exp();
        }
        log_scores[w as usize] = -0.5;
        let b = centre / total;
        let var = if prm.variance { variance_fit(&log_scores[..(2 * w + 1) as usize], total.ln(), delta, p) } else { f32::NAN };
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
        level.num.fill(0.0);
        level.den.fill(0.0);
        level.prob_sum.fill(0.0);
        level.count.fill(0);
        if want_var {
            level.var_num.fill(0.0);
        }
        for &(qx, qy, r, prob) in &self.patches {
            for b in 0..p {
                let y = qy as isize + b as isize - half as isize;
                if y < 0 || y >= lh as isize {
                    continue;
                }
                for a in 0..p {
                    let x = qx as isize + a as isize - half as isize;
                    if x < 0 || x >= lw as isize {
                        continue;
                    }
                    let k = y as usize * lw + x as usize;
                    let wgt = if bayesian { prob * self.gauss[b * p + a] } else { 1.0 };
                    level.num[k] += wgt * r.u;
                    level.den[k] += wgt;
                    level.prob_sum[k] += prob;
                    level.count[k] += 1;
                    if want_var {
                        level.var_num[k] += wgt * wgt * r.var;
                    }
                }
            }
        }
        for k in 0..lw * lh {
            if level.count[k] > 0 && level.den[k] > 0.0 {
                level.flow[k] = level.num[k] / level.den[k];
                level.prob[k] = level.prob_sum[k] / f32::from(level.count[k]);
            } else {
                level.flow[k] = f32::NAN;
                level.prob[k] = 0.0;
            }
        }
    }

    /// §6.4: 4-connected segments of similar flow with ≤ 4^(lv_f − s) pixels are removed.
    fn remove_speckles(&mut self, s: usize) {
        let max_small = 4usize.pow(self.params.lv_f - s as u32);
        let level = &mut self.levels[s];
        let (lw, lh) = (level.w, level.h);
        let labels = &mut self.labels[..lw * lh];
        labels.fill(0);
        let mut next = 1u32;
        for seed in 0..lw * lh {
            if labels[seed] != 0 || !level.flow[seed].is_finite() {
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
                    if labels[n] == 0 && level.flow[n].is_finite() && (level.flow[n] - f).abs() <= SPECKLE_DIFF {
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
        // OpenCV INTER_LINEAR: source coordinate (x + 0.5)/f − 0.5, clamped at the borders.
        let tap = |x: usize, n: usize| -> (usize, usize, f32) {
            let sx = (x as f32 + 0.5) / factor - 0.5;
            if sx <= 0.0 {
                return (0, 0, 0.0);
            }
            let x0 = sx.floor() as usize;
            if x0 + 1 >= n {
                return (n - 1, n - 1, 0.0);
            }
            (x0, x0 + 1, sx - x0 as f32)
        };
        for y in 0..h {
            let (y0, y1, fy) = tap(y + self.pad_y, level.h);
            for x in 0..w {
                let (x0, x1, fx) = tap(x + self.pad_x, level.w);
                let idx = [(y0, x0, (1.0 - fx) * (1.0 - fy)), (y0, x1, fx * (1.0 - fy)), (y1, x0, (1.0 - fx) * fy), (y1, x1, fx * fy)];
                let mut flow = 0.0f32;
                let mut prob = 0.0f32;
                for &(yy, xx, wgt) in &idx {
                    let k = yy * level.w + xx;
                    flow += wgt * level.flow[k];
                    prob += wgt * level.prob[k];
                }
                let d = -flow * factor;
                let k = y * w + x;
                let valid = d.is_finite() && d > 0.0;
                out.disparity[k] = if valid { d } else { f32::NAN };
                out.confidence[k] = if valid { prob.clamp(0.0, 1.0) } else { 0.0 };
                if let Some(var) = out.variance.as_mut() {
                    var[k] = if valid { self.pixel_variance(lv_l, &idx) * factor * factor } else { f32::NAN };
                }
            }
        }
    }

    /// Fused variance Σw²·var / (Σw)² at the nearest level pixel of the stencil.
    fn pixel_variance(&self, s: usize, idx: &[(usize, usize, f32); 4]) -> f32 {
        let level = &self.levels[s];
        let (yy, xx, _) = idx.iter().copied().fold((0, 0, -1.0f32), |best, t| if t.2 > best.2 { t } else { best });
        let k = yy * level.w + xx;
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
