//! Sub-pixel measurements (not in ORB-SLAM2): matches aligned to the patch their map point was first seen with,
//! the σ of aligned measurements measured from the residuals, new points' anchors and refined disparities.

use super::*;

/// An aligned measurement's σ relative to its frame's median one stays within a factor of two either way: the
/// fit's residual over 81 pixels tells a clean fit from a spoiled one, not a σ to better than that (it cannot
/// see the warp's own model error), and a measurement spoiled beyond 2× is left to the χ² gates and the robust
/// kernel. (Unbounded below, a flat-residual fit would outweigh a whole frame.)
const SPREAD_BOUNDS: (f64, f64) = (0.5, 2.0);
/// Fewer aligned measurements than this give no median to measure against: all keep σ_r.
const MIN_SPREADS: usize = 20;

impl Tracker {
    /// Moves every matched keypoint whose point has an anchor to where the anchor's patch fits best
    /// ([`crate::refine`]) and its right-image match to where the same template fits along the row (failing
    /// that, by the same shift); notes in `to_anchor` the keypoints whose points need an anchor (none yet, or
    /// the view moved too far from it).
    pub(super) fn refine_measurements(&mut self, pose: &CameraFromWorld) {
        self.to_anchor.clear();
        if !self.refine {
            return;
        }
        let (levels, right_levels) = (self.builder.left_levels(), self.builder.right_levels());
        for i in 0..self.current.len() {
            let Some(p) = self.current.points[i] else { continue };
            let point = &self.map.points[p];
            if point.bad {
                continue;
            }
            let Some(anchor) = &point.anchor else {
                self.to_anchor.push(i);
                continue;
            };
            let kp = &mut self.current.keypoints[i];
            let octave = usize::from(kp.octave);
            let refined = self.aligner.refine(
                &self.cam,
                &levels[octave],
                self.scales.scale[octave],
                f64::from(kp.x),
                f64::from(kp.y),
                &point.position,
                pose,
                anchor,
            );
            match refined {
                Ok((u, v)) => {
                    self.current.aligned[i] = Some(self.aligner.spread() as f32);
                    let shift = u as f32 - kp.x;
                    kp.x = u as f32;
                    kp.y = v as f32;
                    let u_right = &mut self.current.u_right[i];
                    if *u_right >= 0.0 {
                        // The same patch along the right image's row; failing that, the disparity is kept.
                        *u_right = match self.aligner.refine_right(
                            &right_levels[octave],
                            self.scales.scale[octave],
                            f64::from(*u_right + shift),
                            v,
                        ) {
                            Ok(refined) if (u - refined) > 0.0 => refined as f32,
                            _ => *u_right + shift,
                        };
                        self.current.depth[i] = (self.cam.bf / (u - f64::from(*u_right))) as f32;
                    }
                }
                Err(Unrefined::OutOfAnchor) => self.to_anchor.push(i),
                Err(Unrefined::Failed) => {}
            }
        }
        self.normalise_spreads();
    }

    /// Turns each aligned measurement's own σ (from its fit's residual and normal matrix, [`Aligner::spread`])
    /// into its σ relative to the frame's median one, within [`SPREAD_BOUNDS`]. The frame's typical σ is the
    /// map's measured `refined_sigma`; the spread only shares the weight out among the frame's measurements.
    ///
    /// Why: the scope's light changes a patch's shading between its anchor's view and a later one, and a
    /// highlight or a relief's shadow that moved leaves the fit a residual the gain and offset cannot take out;
    /// those measurements are the biased ones. With one σ for all, they weighed as much as clean fits. Relative,
    /// because the residual sees only what the fit could not explain: an absolute σ from it would trust a clean
    /// fit's noise floor far beyond what the warp's model errors allow.
    fn normalise_spreads(&mut self) {
        let mut spreads = std::mem::take(&mut self.residual_scratch);
        spreads.clear();
        spreads.extend(self.current.aligned.iter().flatten().map(|&s| f64::from(s)));
        let median = if spreads.len() >= MIN_SPREADS {
            let mid = spreads.len() / 2;
            *spreads.select_nth_unstable_by(mid, f64::total_cmp).1
        } else {
            f64::NAN
        };
        let (low, high) = SPREAD_BOUNDS;
        for spread in self.current.aligned.iter_mut().flatten() {
            let relative = f64::from(*spread) / median;
            *spread = if relative.is_finite() { relative.clamp(low, high) as f32 } else { 1.0 };
        }
        self.residual_scratch = spreads;
    }

    /// Re-estimates the σ of refined measurements from this frame's residuals (median, so outliers do not
    /// count) and moves the map's running value a tenth of the way to it: the alignment's precision depends
    /// on the images (texture, noise, lighting), so it is measured rather than assumed.
    pub(super) fn update_refined_sigma(&mut self) {
        let mut scaled = std::mem::take(&mut self.residual_scratch);
        scaled.clear();
        let sigma = self.map.refined_sigma;
        for (k, &i) in self.opt_index.iter().enumerate() {
            if self.current.aligned[i].is_none() {
                continue;
            }
            let dof = if self.current.u_right[i] >= 0.0 { 3.0 } else { 2.0 };
            // χ² in units of the octave's σ, per component: (e/s^o)²/dof = χ²·σ_r²/dof.
            let chi2 = self.optimizer.chi2()[k];
            if chi2.is_finite() {
                scaled.push((chi2 * sigma * sigma / dof).sqrt());
            }
        }
        if scaled.len() >= 20 {
            let mid = scaled.len() / 2;
            let (_, median, _) = scaled.select_nth_unstable_by(mid, f64::total_cmp);
            // The median of sqrt(χ²_k/k) for k = 2–3 is ≈ 0.87 of the σ.
            let measured = *median / 0.87;
            self.map.refined_sigma = (0.9 * sigma + 0.1 * measured)
                .clamp(crate::refine::MIN_REFINED_SIGMA, crate::refine::MAX_REFINED_SIGMA);
        }
        self.residual_scratch = scaled;
    }

    /// Refined measurements weigh by their precision in the pose, but stay linked (count as tracked, make
    /// no new point at a keyframe) by the χ² gates at their octave's σ, as whole-pixel ones do: a refined
    /// match 2σ_r off is a slightly worse measurement, not a mismatch. (Unlinking them at σ_r made a keyframe
    /// nearly every other frame, and points twice.)
    pub(super) fn reclassify_refined(&mut self) {
        for (k, &i) in self.opt_index.iter().enumerate() {
            let Some(spread) = self.current.aligned[i] else { continue };
            let sigma = Scales::relative_sigma(Some(spread), self.map.refined_sigma);
            let chi2 = self.optimizer.chi2()[k] * (sigma * sigma);
            let gate = if self.current.u_right[i] >= 0.0 { crate::optim::CHI2_STEREO } else { crate::optim::CHI2_MONO };
            self.current.outlier[i] = chi2.is_nan() || chi2 > gate;
        }
    }

    /// Anchors the points noted by [`Self::refine_measurements`] that are inliers of the final pose: a point's
    /// first anchor at its keypoint in this frame, a new one where the point projects.
    pub(super) fn anchor_new_inliers(&mut self) {
        let Some(pose) = self.current.camera_from_world else { return };
        let levels = self.builder.left_levels();
        for &i in &self.to_anchor {
            let Some(p) = self.current.points[i] else { continue };
            if self.current.outlier[i] {
                continue;
            }
            let kp = &self.current.keypoints[i];
            let octave = usize::from(kp.octave);
            let scale = self.scales.scale[octave];
            let (mut u, mut v) = (f64::from(kp.x), f64::from(kp.y));
            if self.map.points[p].anchor.is_some() {
                // Anchored anew (the view moved beyond the old anchor's patch): centred where the point
                // projects, not on the corner FAST found, so that later measurements go on following the
                // tissue the old anchor's did. The point's position was adjusted over those measurements; a
                // new corner is off that spot by its own detection error (~a pixel of its octave), which
                // would split the point's observations into two groups that bundle adjustment cannot both fit.
                let (pu, pv) = self.cam.project(&(pose * self.map.points[p].position));
                let reach = crate::refine::MAX_SHIFT * scale;
                if (pu - u).abs() <= reach && (pv - v).abs() <= reach {
                    (u, v) = (pu, pv);
                }
            }
            self.map.points[p].anchor = Anchor::cut(&levels[octave], scale, u, v, pose);
        }
    }

    /// Refines the right-image match of every stereo keypoint of the current frame without a point, by
    /// aligning its own patch along the right image's row: the depth new points are made with.
    pub(super) fn refine_new_disparities(&mut self) {
        self.new_point_anchors.clear();
        self.new_point_anchors.resize(self.current.len(), None);
        if !self.refine {
            return;
        }
        let (levels, right_levels) = (self.builder.left_levels(), self.builder.right_levels());
        for i in 0..self.current.len() {
            // The keypoints `create_keyframe` may make a point at.
            let has_point =
                self.current.points[i].is_some_and(|p| !self.map.points[p].bad && self.map.points[p].n_obs > 0);
            if self.current.u_right[i] < 0.0 || has_point {
                continue;
            }
            let kp = &self.current.keypoints[i];
            let octave = usize::from(kp.octave);
            let scale = self.scales.scale[octave];
            let (u, v) = (f64::from(kp.x), f64::from(kp.y));
            // The pose is set when a point is made here.
            let Some(anchor) = Anchor::cut(&levels[octave], scale, u, v, Isometry3::identity()) else { continue };
            let mut disparity_refined = false;
            if self.aligner.load_unwarped(&anchor).is_ok()
                && let Ok(refined) =
                    self.aligner.refine_right(&right_levels[octave], scale, f64::from(self.current.u_right[i]), v)
                && u - refined > 0.0
            {
                self.current.u_right[i] = refined as f32;
                self.current.depth[i] = (self.cam.bf / (u - refined)) as f32;
                disparity_refined = true;
            }
            self.new_point_anchors[i] = Some((anchor, disparity_refined));
        }
    }

    /// Anchors new point `p` at keypoint `i` of the current frame (keyframe `kf`), seen from `pose`, with the
    /// patch [`Self::refine_new_disparities`] cut there. The keyframe's measurement is then the anchor's centre
    /// itself, refined when its disparity was.
    pub(super) fn anchor_new_point(&mut self, p: PointId, i: usize, kf: KfId, pose: CameraFromWorld) {
        let Some((mut anchor, refined)) = self.new_point_anchors.get_mut(i).and_then(Option::take) else { return };
        anchor.camera_from_world = pose;
        self.map.points[p].anchor = Some(anchor);
        let aligned = refined.then_some(1.0);
        self.current.aligned[i] = aligned;
        self.map.keyframes[kf].aligned[i] = aligned;
    }
}
