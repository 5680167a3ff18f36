//! Tracking the local map (§5.6): the local keyframes (covisibility) and their points, projected into the frame
//! and searched, then the pose optimised against all of them.

use super::*;

/// ORB-SLAM2's bound on the local keyframes (§5.6).
const MAX_LOCAL_KEYFRAMES: usize = 80;

impl Tracker {
    /// §5.6.
    pub(super) fn track_local_map(&mut self, result: &mut FrameResult) -> bool {
        self.update_local_keyframes();
        self.update_local_points();
        let frame_id = self.current.id;
        let Some(pose) = self.current.camera_from_world else { return false };
        // Visibility: points already linked count as seen; the others go through the frustum test.
        for p in self.current.points.iter().flatten() {
            let point = &mut self.map.points[*p];
            point.visible += 1;
            point.cache.last_seen_frame = Some(frame_id);
            point.cache.in_view = false;
        }
        let mut to_match = 0;
        for k in 0..self.local_points.len() {
            let p = self.local_points[k];
            if self.map.points[p].bad || self.map.points[p].cache.last_seen_frame == Some(frame_id) {
                continue;
            }
            if frustum_check(&self.cam, &self.scales, &mut self.map, p, &pose) {
                self.map.points[p].visible += 1;
                to_match += 1;
            }
        }
        if to_match > 0 {
            // After relocalisation, when the pose came from appearance (the motion model could not predict the
            // frame) and when it is the prediction alone (after a veil), the pose is coarser and the scale may
            // have changed: search wider.
            let th = if self.last_reloc_frame.is_some_and(|r| frame_id < r + 2)
                || result.quality.method == PoseMethod::Prediction
            {
                5.0
            } else if result.quality.method == PoseMethod::Appearance {
                3.0
            } else {
                1.0
            };
            self.searcher.local_points(&self.scales, &self.map, &mut self.current, &self.local_points, th);
        }
        self.refine_measurements(&pose);
        self.optimise_current();
        self.anchor_new_inliers();
        // Both read the χ² of the optimisation, made with the σ before this frame's update.
        self.reclassify_refined();
        // A veiled frame's residuals are the haze's shifts as much as the alignment's noise: they do not set
        // the σ that clear frames are weighed by.
        if !self.veil.is_down() {
            self.update_refined_sigma();
        }
        let mut inliers = 0;
        for i in 0..self.current.len() {
            let Some(p) = self.current.points[i] else { continue };
            if !self.current.outlier[i] {
                self.map.points[p].found += 1;
                if self.map.points[p].n_obs > 0 {
                    inliers += 1;
                }
            } else if self.current.u_right[i] >= 0.0 {
                self.current.points[i] = None;
                self.current.outlier[i] = false;
            }
        }
        result.inliers = inliers;
        let needed = if self.last_reloc_frame.is_some_and(|r| frame_id < r + self.max_frames()) {
            relocalise::PRIORLESS_INLIERS
        } else {
            30
        };
        inliers >= needed
    }

    /// Per keyframe, how many of the current frame's points it observes (`kf_votes`, the voters listed in
    /// `voters`; the caller zeroes them after use). Before the local map is searched, points culled since they
    /// were matched are dropped from the frame too; with `inliers_only` (the pose is final) the count is over the
    /// pose's inliers and the frame is only read. The buffers are indexed by keyframe id and only grow with the
    /// map.
    pub(super) fn vote_keyframes(&mut self, inliers_only: bool) {
        let n = self.map.keyframes.len();
        if self.kf_votes.len() < n {
            self.kf_votes.resize(n, 0);
            self.kf_stamp.resize(n, u64::MAX);
        }
        self.voters.clear();
        for i in 0..self.current.len() {
            let Some(p) = self.current.points[i] else { continue };
            if self.map.points[p].bad {
                if !inliers_only {
                    self.current.points[i] = None;
                }
                continue;
            }
            if inliers_only && self.current.outlier[i] {
                continue;
            }
            for &k in self.map.points[p].observations.keys() {
                if self.kf_votes[k] == 0 {
                    self.voters.push(k);
                }
                self.kf_votes[k] += 1;
            }
        }
    }

    /// The local keyframes (§5.6 step 1).
    pub(super) fn update_local_keyframes(&mut self) {
        self.vote_keyframes(false);
        if self.voters.is_empty() {
            return;
        }
        self.voters.sort_unstable();
        let stamp = self.current.id;
        let segment = self.segment_start();
        let (map, local, marks) = (&self.map, &mut self.local_kfs, &mut self.kf_stamp);
        local.clear();
        for &k in &self.voters {
            if !map.keyframes[k].bad {
                local.push(k);
                marks[k] = stamp;
            }
        }
        // Neighbours of the voters (the intended behaviour: adding a parent does not end the walk, §10.1 #7).
        // On a detached segment, not the keyframes before it (`segment`, above): the segment's first keyframe
        // hangs under the last one before the loss, and from the segment's guessed place their points match
        // only by chance.
        let voters = local.len();
        for idx in 0..voters {
            if local.len() > MAX_LOCAL_KEYFRAMES {
                break;
            }
            let kf = &map.keyframes[local[idx]];
            let fresh = |k: &KfId| marks[*k] != stamp && !map.keyframes[*k].bad && *k >= segment;
            let covisible = kf.best_covisibles(10).find(|k| fresh(k));
            let child = kf.children.iter().copied().find(|k| fresh(k));
            let parent = kf.parent.filter(|k| fresh(k));
            for k in [covisible, child, parent].into_iter().flatten() {
                if marks[k] != stamp {
                    marks[k] = stamp;
                    local.push(k);
                }
            }
        }
        self.add_keyframes_in_view(stamp);
        let votes = &self.kf_votes;
        if let Some(&best) = self
            .voters
            .iter()
            .filter(|&&k| !self.map.keyframes[k].bad)
            .max_by_key(|&&k| (votes[k], std::cmp::Reverse(k)))
        {
            self.reference_kf = Some(best);
        }
        for &k in &self.voters {
            self.kf_votes[k] = 0;
        }
    }

    /// Map reuse: keyframes that look at what this frame looks at but share no point with it yet (the scope has
    /// come back to tissue mapped earlier) join the local keyframes, so their points are searched and a revisit
    /// adds observations to the old points instead of making new ones beside them. A keyframe qualifies when
    /// the point it looks at (its optical axis at its median depth) projects into this frame and its centre is
    /// within its median depth of this frame's: ratios of the scene's depth, no unit. The closest come first,
    /// up to ORB-SLAM2's 80 local keyframes; the frustum and viewing-angle test then decides point by point.
    fn add_keyframes_in_view(&mut self, stamp: u64) {
        let Some(pose) = self.current.camera_from_world else { return };
        let centre = pose.inverse() * Point3::origin();
        self.in_view.clear();
        // A detached segment's place is a guess: what the older map shows there is no evidence (a segment 30 mm
        // off was tied back on 43 chance matches this way). It is tied back by a loop's 3-D check or by
        // relocalisation, both by appearance.
        let segment = self.segment_start();
        for kf in &self.map.keyframes[segment..] {
            if kf.bad || self.kf_stamp[kf.id] == stamp || !kf.median_depth.is_finite() {
                continue;
            }
            let closeness = (kf.centre() - centre).norm() / kf.median_depth;
            if closeness > 1.0 {
                continue;
            }
            let seen = pose * kf.look_at();
            if seen.z > 0.0 && {
                let (u, v) = self.cam.project(&seen);
                self.cam.in_image(u, v)
            } {
                self.in_view.push((closeness, kf.id));
            }
        }
        self.in_view.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let room = MAX_LOCAL_KEYFRAMES.saturating_sub(self.local_kfs.len());
        for &(_, k) in self.in_view.iter().take(room) {
            self.kf_stamp[k] = stamp;
            self.local_kfs.push(k);
        }
    }

    pub(super) fn update_local_points(&mut self) {
        self.local_points.clear();
        let frame_id = self.current.id;
        for &k in &self.local_kfs {
            for p in self.map.keyframes[k].points.iter().flatten() {
                let point = &mut self.map.points[*p];
                if point.bad || point.cache.local_for_frame == Some(frame_id) {
                    continue;
                }
                point.cache.local_for_frame = Some(frame_id);
                self.local_points.push(*p);
            }
        }
    }
}
