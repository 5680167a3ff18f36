//! The keyframe decision (§5.8) and keyframe creation (§5.9), then local mapping on the new keyframe.

use super::*;

impl Tracker {
    /// §5.8 with a mapper that runs inline (always idle, never stopped): gathers what the rule looks at.
    /// `position_sigma_rel`: this frame's position σ over its depth (NaN when its pose is not `Ok`).
    pub(super) fn need_keyframe(&mut self, inliers: usize, position_sigma_rel: f64) -> bool {
        // Under a veil the haze takes matches away wherever the scope is: the ratio counts the reference's points
        // still in view where it counts matched ones in a clear view (only moving on takes the map out of view).
        // The close-points rule is kept (in a flight it is what calls for keyframes under the veil), but only
        // while a keyframe could add one of those close points: under a veil a new point must be tissue the
        // last clear keyframe saw (`seen_in_clear_view`). Over a hover's haze none is, and the rule, reading the
        // matches the haze took for tissue the map lacks, made a keyframe every frame that added nothing.
        let veiled = self.veil.is_down();
        let n_kfs = self.map.n_good_keyframes() as u64;
        let min_obs = if n_kfs <= 2 { 2 } else { 3 };
        let reference_points = self.reference_kf.map(|r| self.reference_points(r, min_obs).count());
        let close = self.close_depth();
        let (mut tracked_close, mut untracked_close) = (0, 0);
        // Whether one of the untracked close keypoints could become a point; checked until one is found.
        let mut addable = !veiled;
        let mut found = std::mem::take(&mut self.clear_view.near);
        for i in 0..self.current.len() {
            let z = f64::from(self.current.depth[i]);
            if z > 0.0 && z < close {
                if self.current.points[i].is_some() && !self.current.outlier[i] {
                    tracked_close += 1;
                } else {
                    untracked_close += 1;
                    addable = addable
                        || self
                            .current
                            .unproject_world(&self.cam, i)
                            .is_some_and(|x| self.seen_in_clear_view(&x, i, &mut found));
                }
            }
        }
        self.clear_view.near = found;
        // Close keypoints no keyframe could add do not call for one.
        if !addable {
            untracked_close = 0;
        }
        let inliers = match self.reference_kf {
            Some(r) if veiled => self.reference_points_in_view(r, min_obs),
            _ => inliers,
        };
        keyframe_needed(&KeyframeEvidence {
            frame_id: self.current.id,
            last_relocalisation_frame: self.last_reloc_frame,
            last_keyframe_frame: self.last_kf_frame,
            max_frames: self.max_frames(),
            keyframes_in_map: n_kfs,
            reference_points,
            inliers,
            tracked_close,
            untracked_close,
            position_sigma_rel,
            sigma_after_keyframe: self.sigma_after_keyframe,
        })
    }

    /// §5.9, then local mapping on the new keyframe.
    pub(super) fn create_keyframe(&mut self, result: &mut FrameResult) {
        let Some(pose) = self.current.camera_from_world else { return };
        self.refine_new_disparities();
        let kf = self.map.add_keyframe(KeyFrame::from_frame(0, &self.current, pose));
        // Under a veil the haze is in the keypoints' surroundings: a new point must be tissue the last clear
        // keyframe saw, and the place keeps its clear contrast.
        let veiled = self.veil.is_down();
        if veiled {
            let made = &mut self.map.keyframes[kf];
            if self.place_texture.contrast > made.texture.contrast {
                made.texture = self.place_texture;
            }
            made.veiled = true;
        } else {
            self.clear_view.kf = Some(kf);
        }
        let mut found = std::mem::take(&mut self.clear_view.near);
        // New stereo points, nearest first: every close keypoint, far ones until 100 have been covered.
        let mut by_depth: Vec<(f32, usize)> = (0..self.current.len())
            .filter(|&i| self.current.depth[i] > 0.0)
            .map(|i| (self.current.depth[i], i))
            .collect();
        by_depth.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let close = self.close_depth();
        let mut covered = 0;
        for (z, i) in by_depth {
            let has_point =
                self.current.points[i].is_some_and(|p| !self.map.points[p].bad && self.map.points[p].n_obs > 0);
            if !has_point
                && let Some(x) = self.current.unproject_world(&self.cam, i)
                && (!veiled || self.seen_in_clear_view(&x, i, &mut found))
            {
                let p = self.map.new_point(x, kf, i, &self.scales);
                self.current.points[i] = Some(p);
                self.current.outlier[i] = false;
                self.anchor_new_point(p, i, kf, pose);
            }
            covered += 1;
            if f64::from(z) > close && covered > 100 {
                break;
            }
        }
        self.clear_view.near = found;
        self.reference_kf = Some(kf);
        self.last_kf_frame = self.current.id;
        let report = self.mapper.process(&mut self.map, kf, &self.cam, &self.scales, self.settings.th_depth);
        if let Some(moved) = report.ba_moved_rel {
            self.map_moved_rel = moved;
        }
        // The keyframe's pose may have moved in bundle adjustment: the frame follows it.
        let kf_pose = self.map.keyframes[kf].camera_from_world;
        self.current.camera_from_world = Some(kf_pose);
        result.new_keyframe = Some(kf);
        result.mapper = Some(report);
    }

    /// Keyframe `r`'s good points seen by at least `min_obs` (a stereo observation counting 2).
    fn reference_points(&self, r: KfId, min_obs: u32) -> impl Iterator<Item = &crate::map::MapPoint> {
        let points = self.map.keyframes[r].points.iter().flatten().map(|&p| &self.map.points[p]);
        points.filter(move |point| !point.bad && point.n_obs >= min_obs)
    }

    /// Of [`Self::reference_points`], those the current pose still sees (§5.6's frustum test), matched or not.
    fn reference_points_in_view(&self, r: KfId, min_obs: u32) -> usize {
        let Some(pose) = self.current.camera_from_world else { return 0 };
        self.reference_points(r, min_obs)
            .filter(|point| crate::search::seen_from(&self.cam, point, &pose).is_some())
            .count()
    }

    /// Whether keypoint `i` of the current frame, put at `x` by its stereo depth, is tissue the last clear
    /// keyframe saw: that keyframe has a keypoint where `x` projects (within the χ² gate of a measurement at
    /// the octave the distance predicts), at the same disparity, with a matching descriptor.
    ///
    /// Why: a keypoint under a veil may be the smoke's own texture, or a corner the haze has moved. Smoke that
    /// hangs in the cavity was not there in the clear view, and smoke that rides with the scope was somewhere
    /// else in it (it moves with the camera, not with the scene), so neither is found; tissue is, wherever the
    /// scope has moved since. Without the check a veiled keyframe fills the map with smoke that rides with the
    /// scope, and the poses follow it (8 mm off on a 150-frame oblique view).
    fn seen_in_clear_view(&self, x: &Point3<f64>, i: usize, found: &mut Vec<usize>) -> bool {
        let Some(kf) = self.clear_view.kf.map(|k| &self.map.keyframes[k]).filter(|kf| !kf.bad) else { return false };
        let in_clear = kf.camera_from_world * x;
        let in_current = self.current.camera_from_world.map_or(in_clear, |pose| pose * x);
        if in_clear.z <= 0.0 || in_current.z <= 0.0 {
            return false;
        }
        // The clear keyframe saw the corner from its own distance: smaller from farther, at a lower octave.
        let octave = self.current.keypoints[i].octave;
        let shift = (in_current.z / in_clear.z).ln() / self.scales.factor.ln();
        let predicted = (f64::from(octave) + shift).round().clamp(0.0, (self.scales.levels() - 1) as f64) as u8;
        let (u, v) = self.cam.project(&in_clear);
        let u_right = u - self.cam.bf / in_clear.z;
        let radius = crate::optim::CHI2_MONO.sqrt() * self.scales.scale[usize::from(predicted)];
        let octaves = predicted.saturating_sub(1)..=predicted + 1;
        kf.grid.features_in_area(&kf.keypoints, (u as f32, v as f32), radius as f32, octaves, found);
        let descriptor = &self.current.descriptors[i];
        found.iter().any(|&j| {
            let right = kf.u_right[j];
            (right < 0.0 || (f64::from(right) - u_right).abs() < radius)
                && bdis_orb::hamming(descriptor, &kf.descriptors[j]) <= TH_HIGH
        })
    }
}

/// The last keyframe made in a clear view, and the gate's buffer of its keypoints near a projection
/// ([`Tracker::seen_in_clear_view`]), reused.
#[derive(Debug, Default)]
pub(super) struct ClearView {
    pub kf: Option<KfId>,
    near: Vec<usize>,
}

/// What the keyframe decision looks at.
#[derive(Debug, Clone, Copy)]
pub(super) struct KeyframeEvidence {
    pub frame_id: u64,
    pub last_relocalisation_frame: Option<u64>,
    pub last_keyframe_frame: u64,
    /// ORB-SLAM2's maxFrames (the frame rate): a keyframe is overdue after this many frames.
    pub max_frames: u64,
    pub keyframes_in_map: u64,
    /// Points of the reference keyframe seen by enough keyframes (`None`: no reference keyframe).
    pub reference_points: Option<usize>,
    /// Inliers of the current frame's pose.
    pub inliers: usize,
    /// Close stereo keypoints (depth below `th_depth` baselines) with and without a tracked map point.
    pub tracked_close: usize,
    pub untracked_close: usize,
    /// This frame's position σ over the depth of its points (NaN when its pose is not `Ok`), and the same of
    /// the first frame after the last keyframe.
    pub position_sigma_rel: f64,
    pub sigma_after_keyframe: f64,
}

/// A keyframe is due once the frame's position is held by half the information (σ larger by √2) the frame
/// right after the last keyframe had: the map under the view has thinned out however many points it still
/// tracks. Why: ORB-SLAM2's rules count points (0.75 of the reference keyframe's; under 100 tracked close
/// ones), and where corners repeat well (a blurred lens) a frame keeps those counts for ten frames while it
/// maps a fifth of what it sees; the keyframes came so far apart that local bundle adjustment moved right
/// poses 0.7 mm (BENCHMARKS.md, "A battery of renders none of this was tuned on"). The pose's own covariance
/// measures what the counts stand for, in no unit and at any image size or frame rate.
pub const INFORMATION_HALVED_SIGMA: f64 = std::f64::consts::SQRT_2;

/// §5.8: a keyframe is made when the frame still has content (> 15 inliers) but tracks clearly fewer points
/// than its reference keyframe (< 75 %, 40 % while the map has one keyframe), or when it sees many close
/// points that are not in the map; never during the hold-off after a relocalisation. The mapper runs inline
/// and is always idle, so the "overdue" and "mapper free" conditions always hold.
pub(super) fn keyframe_needed(e: &KeyframeEvidence) -> bool {
    // ORB-SLAM2 makes no keyframe for maxFrames (= fps) frames after a relocalisation. Moving forward through
    // a colon, the old keyframes run out of view within that second and tracking is lost again (seen on the
    // synthetic colon); a few frames of hold-off are enough to keep a doubtful pose out of the map.
    if e.last_relocalisation_frame.is_some_and(|r| e.frame_id < r + RELOCALISATION_HOLDOFF_FRAMES) {
        return false;
    }
    let Some(n_ref) = e.reference_points else { return false };
    let n_ref = n_ref as f64;
    let need_close = e.tracked_close < 100 && e.untracked_close > 70;
    let th_ref_ratio = if e.keyframes_in_map < 2 { 0.4 } else { 0.75 };
    let inliers = e.inliers as f64;
    let overdue = e.frame_id >= e.last_keyframe_frame + e.max_frames;
    let mapper_free = true; // the mapper runs inline, so it is always idle (minFrames = 0)
    // NaN (a pose not `Ok`, or no frame measured since the keyframe) compares false: no keyframe from it.
    let thinned = e.keyframes_in_map >= 2 && e.position_sigma_rel > INFORMATION_HALVED_SIGMA * e.sigma_after_keyframe;
    let weak = inliers < 0.25 * n_ref || need_close || thinned;
    let content = inliers > 15.0 && (inliers < th_ref_ratio * n_ref || need_close || thinned);
    (overdue || mapper_free || weak) && content
}

#[cfg(test)]
mod tests {
    use super::*;

    fn evidence() -> KeyframeEvidence {
        KeyframeEvidence {
            frame_id: 100,
            last_relocalisation_frame: None,
            last_keyframe_frame: 90,
            max_frames: 30,
            keyframes_in_map: 10,
            reference_points: Some(400),
            inliers: 350,
            tracked_close: 300,
            untracked_close: 20,
            position_sigma_rel: 1e-3,
            sigma_after_keyframe: 1e-3,
        }
    }

    #[test]
    fn a_frame_that_tracks_most_of_its_reference_makes_no_keyframe() {
        assert!(!keyframe_needed(&evidence()));
    }

    #[test]
    fn a_frame_that_tracks_under_three_quarters_of_its_reference_makes_one() {
        assert!(keyframe_needed(&KeyframeEvidence { inliers: 299, ..evidence() }));
        assert!(!keyframe_needed(&KeyframeEvidence { inliers: 300, ..evidence() }));
        // With one keyframe in the map the bar is 40 %.
        let one = KeyframeEvidence { keyframes_in_map: 1, ..evidence() };
        assert!(!keyframe_needed(&KeyframeEvidence { inliers: 161, ..one }));
        assert!(keyframe_needed(&KeyframeEvidence { inliers: 159, ..one }));
    }

    #[test]
    fn many_close_points_missing_from_the_map_make_one() {
        let e = KeyframeEvidence { tracked_close: 99, untracked_close: 71, ..evidence() };
        assert!(keyframe_needed(&e));
        assert!(!keyframe_needed(&KeyframeEvidence { untracked_close: 70, ..e }));
    }

    #[test]
    fn a_frame_held_by_half_the_information_of_the_one_after_the_keyframe_makes_one() {
        // Tracking most of its reference, but its position is determined √2 times less well.
        let thinned = KeyframeEvidence { position_sigma_rel: 1.5e-3, sigma_after_keyframe: 1e-3, ..evidence() };
        assert!(keyframe_needed(&thinned));
        assert!(!keyframe_needed(&KeyframeEvidence { position_sigma_rel: 1.4e-3, ..thinned }));
        // A pose that is not `Ok` (NaN) says nothing about the map; nor does a map of one keyframe.
        assert!(!keyframe_needed(&KeyframeEvidence { position_sigma_rel: f64::NAN, ..thinned }));
        assert!(!keyframe_needed(&KeyframeEvidence { sigma_after_keyframe: f64::NAN, ..thinned }));
        assert!(!keyframe_needed(&KeyframeEvidence { keyframes_in_map: 1, inliers: 300, ..thinned }));
    }

    #[test]
    fn too_few_inliers_or_no_reference_make_none() {
        assert!(!keyframe_needed(&KeyframeEvidence { inliers: 15, ..evidence() }));
        assert!(!keyframe_needed(&KeyframeEvidence { reference_points: None, inliers: 10, ..evidence() }));
    }

    #[test]
    fn no_keyframe_during_the_hold_off_after_a_relocalisation() {
        let weak = KeyframeEvidence { inliers: 100, ..evidence() };
        assert!(keyframe_needed(&weak));
        let just_relocalised = KeyframeEvidence { last_relocalisation_frame: Some(98), ..weak };
        assert!(!keyframe_needed(&just_relocalised));
        let later = KeyframeEvidence { last_relocalisation_frame: Some(100 - RELOCALISATION_HOLDOFF_FRAMES), ..weak };
        assert!(keyframe_needed(&later));
    }
}
