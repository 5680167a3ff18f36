//! Frame-to-frame tracking (§5.3–§5.4): the motion model's projection search, tracking against the reference
//! keyframe, pose-only optimisation of the current frame and dropping its outliers.

use super::*;

impl Tracker {
    /// Replaces the constant-velocity prediction for the next frame with `next_from_last`, the camera's motion
    /// from the last frame to the next (an external sensor, such as a robot arm's kinematics, can give one).
    /// The prediction only seeds the search: the frame is still checked by appearance, so a wrong prior is
    /// rejected rather than followed (`TrackingQuality::prior_rejected`). Under a veil it poses the frame the
    /// images cannot ([`Self::coast`]). No effect before tracking has a velocity (the first frames, after a
    /// loss).
    pub fn set_motion_prior(&mut self, next_from_last: Isometry3<f64>) {
        if self.velocity.is_some() {
            self.velocity = Some(next_from_last);
            self.external_prior = true;
        }
    }

    /// The motion model's prediction of the current frame's pose, if tracking has a velocity.
    fn predicted_pose(&self) -> Option<CameraFromWorld> {
        Some(self.velocity? * self.last.camera_from_world?)
    }

    /// A frame seen through a veil (smoke) that the images could not pose, or posed from a few matches that
    /// nothing confirms ([`Doubt::Unconfirmed`]), is posed by the motion model instead, `Uncertain`, with no
    /// match kept: the haze takes the texture away for a second or two, and the scope goes on moving as it
    /// was. Losing the frame instead would leave only relocalisation, which finds known places only, while the
    /// scope may have moved on into new tissue by the time the veil lifts.
    /// Returns whether the frame was coasted.
    pub(super) fn coast(&mut self) -> bool {
        // The veil lasts at most `MAX_VEIL_S`, and so does coasting.
        self.veil.is_down() && self.state.is_tracked() && self.seed_from_prediction()
    }

    /// Seeds the current frame with the motion model's prediction when the frames before it were coasted
    /// ([`Self::coast`]): they hold no matches for the motion model's search, so the local map (the keyframes
    /// tracked before the veil) is searched from the prediction, and it decides.
    ///
    /// Under a veil the prediction is dead reckoning ([`Self::dead_reckoned`]): the motion over the last
    /// frames soundly measured, carried on from the last of them, not the last step times the last pose. The
    /// step of a frame tracked through thickening haze can be off by degrees, and a second of coasting
    /// multiplies it (a colon at 20 mm/s under the sheet: 41° off after 20 coasted frames, 7.5° so). An
    /// external motion prior is the exception: it knows the scope's motion, which the veil does not hide.
    pub(super) fn seed_from_prediction(&mut self) -> bool {
        let pose = if self.external_prior {
            let Some(pose) = self.predicted_pose() else { return false };
            pose
        } else {
            self.dead_reckoned(self.current.t_ns)
        };
        self.current.camera_from_world = Some(pose);
        self.current.points.iter_mut().for_each(|p| *p = None);
        self.current.outlier.iter_mut().for_each(|o| *o = false);
        true
    }

    pub(super) fn replace_last_frame_points(&mut self) {
        for p in self.last.points.iter_mut() {
            if let Some(q) = *p {
                *p = self.map.resolve(q);
            }
        }
    }

    /// Pose-only optimisation of the current frame against its linked points; writes pose and outlier flags.
    pub(super) fn optimise_current(&mut self) -> usize {
        self.opt_points.clear();
        self.opt_obs.clear();
        self.opt_index.clear();
        for (i, p) in self.current.points.iter().enumerate() {
            let Some(p) = *p else { continue };
            let point = &self.map.points[p];
            if point.bad {
                continue;
            }
            let kp = &self.current.keypoints[i];
            self.opt_points.push(point.position);
            self.opt_obs.push(Observation {
                u: f64::from(kp.x),
                v: f64::from(kp.y),
                u_right: (self.current.u_right[i] >= 0.0).then(|| f64::from(self.current.u_right[i])),
                inv_sigma2: self.scales.information(kp.octave, self.current.aligned[i], self.map.refined_sigma),
            });
            self.opt_index.push(i);
        }
        self.opt_outlier.clear();
        self.opt_outlier.resize(self.opt_index.len(), false);
        let Some(mut pose) = self.current.camera_from_world else { return 0 };
        let inliers =
            self.optimizer.optimize(&self.cam, &mut pose, &self.opt_points, &self.opt_obs, &mut self.opt_outlier);
        if self.opt_index.len() >= 3 {
            self.current.camera_from_world = Some(pose);
        }
        for (k, &i) in self.opt_index.iter().enumerate() {
            self.current.outlier[i] = self.opt_outlier[k];
        }
        inliers
    }

    /// Unlinks the outliers of the last optimisation; returns the inliers linked to points with observations.
    pub(super) fn drop_outliers(&mut self) -> usize {
        let mut good = 0;
        for i in 0..self.current.len() {
            let Some(p) = self.current.points[i] else { continue };
            if self.current.outlier[i] {
                self.current.points[i] = None;
                self.current.outlier[i] = false;
                self.map.points[p].cache.in_view = false;
                self.map.points[p].cache.last_seen_frame = Some(self.current.id);
            } else if self.map.points[p].n_obs > 0 {
                good += 1;
            }
        }
        good
    }

    /// The last frame's pose from its reference keyframe's current pose (bundle adjustment may have moved it).
    pub(super) fn update_last_frame(&mut self) {
        if let Some((r, rel)) = self.last_from_reference {
            self.last.camera_from_world = Some(rel * self.map.keyframe_pose(r));
        }
    }

    /// §5.3.
    pub(super) fn track_motion_model(&mut self) -> bool {
        self.update_last_frame();
        let (Some(v), Some(last_pose)) = (self.velocity, self.last.camera_from_world) else { return false };
        self.current.camera_from_world = Some(v * last_pose);
        self.current.points.fill(None);
        let mut n =
            self.searcher.from_last_frame(&self.cam, &self.scales, &self.map, &mut self.current, &self.last, 7.0);
        if n < 20 {
            self.current.points.fill(None);
            n = self.searcher.from_last_frame(&self.cam, &self.scales, &self.map, &mut self.current, &self.last, 14.0);
        }
        if n < 20 {
            return false;
        }
        self.optimise_current();
        self.drop_outliers() >= 10
    }

    /// §5.4 by guided projection from the last pose into the reference keyframe's points: the fallback when
    /// matching by appearance ([`Self::appearance_consensus`]) found too few distinctive matches.
    pub(super) fn track_reference_keyframe(&mut self) -> bool {
        self.update_last_frame();
        let Some(r) = self.reference_kf else { return false };
        let Some(last_pose) = self.last.camera_from_world else { return false };
        self.current.camera_from_world = Some(last_pose);
        self.current.points.fill(None);
        let n =
            self.searcher.from_keyframe(&self.cam, &self.scales, &self.map, &mut self.current, r, &[], 15.0, TH_HIGH);
        if n < 15 {
            return false;
        }
        self.optimise_current();
        self.drop_outliers() >= 10
    }
}
