//! §3–§6.1: the patch grid of a level, the template, the one-pass and exact residual evaluation, and the 1-D
//! inverse-compositional search with its Bayesian confidence and variance fit.

use super::*;

impl Matcher {
    /// Level likelihood L(s) = (1/s) / Σ_{t=lv_l..lv_f} 1/t (§6.2).
    pub(super) fn level_likelihood(&self, s: usize) -> f32 {
        let total: f64 = (self.params.lv_l..=self.params.lv_f).map(|t| 1.0 / f64::from(t)).sum();
        ((1.0 / s as f64) / total) as f32
    }

    /// §3–6.1 for every patch of level `s`: from zero disparity everywhere (`from_zero`: the coarsest level, or
    /// one below a level that kept nothing), else from the coarser level's answer where it has one.
    pub(super) fn search_level(&mut self, s: usize, from_zero: bool) {
        let sp = self.params.stride() as usize;
        let (lw, lh) = (self.levels[s].w, self.levels[s].h);
        let (nw, nh) = (lw.div_ceil(sp), lh.div_ceil(sp));
        let ow = (lw - (nw - 1) * sp) / 2;
        let oh = (lh - (nh - 1) * sp) / 2;
        let likelihood = self.level_likelihood(s);
        let bayesian = self.params.algorithm == Algorithm::Bdis;
        self.patches.clear();
        for j in 0..nh {
            for i in 0..nw {
                let (qx, qy) = (i * sp + ow, j * sp + oh);
                let (u0, prob0) = if from_zero {
                    (0.0f32, 0.0f32)
                } else {
                    let parent = &self.levels[s + 1];
                    let k = (qy / 2).min(parent.h - 1) * parent.w + (qx / 2).min(parent.w - 1);
                    (2.0 * parent.flow[k], parent.prob[k])
                };
                // §5: only patches whose parent found something are searched.
                if !from_zero && (u0 == 0.0 || u0.is_nan() || prob0 <= 0.0) {
                    continue;
                }
                let result = self.search_patch(s, qx, qy, u0);
                if result.b > 0.0 {
                    let prob = if bayesian {
                        if from_zero { result.b * likelihood } else { result.b * likelihood + prob0 }
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
    pub(super) fn load_template(&mut self, level: usize, qx: usize, qy: usize) -> f32 {
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
    pub(super) fn eval(
        &mut self,
        level: usize,
        qx: usize,
        qy: usize,
        u: f32,
        want_r2: bool,
        exact: bool,
    ) -> Option<Eval> {
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
    pub(super) fn search_patch(&mut self, level: usize, qx: usize, qy: usize, u0: f32) -> PatchResult {
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
}

/// §6.5: fit a Gaussian `log b_k = log r − x_k²/(2σ²)` to the candidates' log-probabilities (least squares in
/// closed form: it is linear in log r and 1/(2σ²)) and return σ² in level px², or the maximum `(p/2)²` when the
/// fit is degenerate. `log_scores` are the unnormalised log scores, `log_total` their log-sum.
pub(super) fn variance_fit(log_scores: &[f32], log_total: f32, delta: f32, p: usize) -> f32 {
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
