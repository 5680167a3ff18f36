//! The per-frame tracking state machine (ORB-SLAM2-STEREO.md §5): stereo initialisation, motion-model and
//! reference-keyframe tracking, local-map tracking, relocalisation, the keyframe decision and creation.

use crate::frame::{Frame, FrameBuilder, Scales};
use crate::geometry::{CameraFromWorld, StereoCamera};
use crate::map::{KeyFrame, KfId, Map, PointId};
use crate::mapper::{LocalMapper, MapperReport};
use crate::optim::{Observation, PoseOptimizer};
use crate::refine::{Aligner, Anchor, Unrefined};
use crate::search::{Searcher, TH_HIGH, TH_LOW, frustum_check};
use bdis_orb::{OrbError, OrbParams, hamming};
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion};
use std::collections::BTreeSet;

/// Frames after a relocalisation during which no keyframe is made.
pub const RELOCALISATION_HOLDOFF_FRAMES: u64 = 5;

#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    #[error(transparent)]
    Orb(#[from] OrbError),
}

/// Settings of the tracker, from the ORB-SLAM2 keys (`ThDepth`, `Camera.fps`, `ORBextractor.*`).
#[derive(Debug, Clone, Copy)]
pub struct TrackerSettings {
    /// Close/far limit in baselines.
    pub th_depth: f64,
    pub fps: f64,
    pub orb: OrbParams,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrackingState {
    NotInitialized,
    Ok,
    Lost,
}

/// What one frame gave.
#[derive(Debug, Clone)]
pub struct FrameResult {
    pub frame_id: u64,
    pub t_ns: u64,
    pub state: TrackingState,
    pub camera_from_world: Option<CameraFromWorld>,
    pub inliers: usize,
    pub new_keyframe: Option<KfId>,
    pub mapper: Option<MapperReport>,
    /// The frame relocalised.
    pub relocalised: bool,
}

/// Per frame, for the trajectory: the pose relative to the reference keyframe (rebuilt with the keyframe's
/// final pose, §5.1 step 7).
#[derive(Debug, Clone, Copy)]
struct FrameRecord {
    t_ns: u64,
    reference: KfId,
    camera_from_reference: Isometry3<f64>,
    lost: bool,
}

#[derive(Debug)]
pub struct Tracker {
    cam: StereoCamera,
    scales: Scales,
    settings: TrackerSettings,
    builder: FrameBuilder,
    pub map: Map,
    mapper: LocalMapper,
    state: TrackingState,
    current: Frame,
    last: Frame,
    velocity: Option<Isometry3<f64>>,
    /// The velocity when tracking was last OK: lost frames are extrapolated with it in the trajectory.
    lost_velocity: Option<Isometry3<f64>>,
    reference_kf: Option<KfId>,
    last_kf_frame: u64,
    last_reloc_frame: Option<u64>,
    local_kfs: Vec<KfId>,
    local_points: Vec<PointId>,
    /// Per keyframe id: votes of the current frame's points, and the frame that last included it locally.
    kf_votes: Vec<u32>,
    kf_stamp: Vec<u64>,
    voters: Vec<KfId>,
    searcher: Searcher,
    optimizer: PoseOptimizer,
    opt_points: Vec<Point3<f64>>,
    opt_obs: Vec<Observation>,
    opt_index: Vec<usize>,
    opt_outlier: Vec<bool>,
    records: Vec<FrameRecord>,
    /// The last frame's pose relative to its reference keyframe.
    last_from_reference: Option<(KfId, Isometry3<f64>)>,
    ransac_state: u64,
    /// Sub-pixel measurements by patch alignment ([`crate::refine`]); on unless switched off.
    refine: bool,
    aligner: Aligner,
    /// Keypoints of the current frame whose points get an anchor once the frame's pose is final.
    to_anchor: Vec<usize>,
    /// Per keypoint of the current frame that may get a new point: its anchor (cut once, for the disparity
    /// and then for the point) and whether its right-image match was refined.
    new_point_anchors: Vec<Option<(Anchor, bool)>>,
    residual_scratch: Vec<f64>,
}

impl Tracker {
    /// Where local bundle adjustment runs: a worker thread (the default; results applied at the next keyframe)
    /// or inline in the caller's thread (applied at once: a single-core target, or measuring its cost per
    /// keyframe). Set before the first frame.
    pub fn set_ba_mode(&mut self, mode: crate::mapper::BaMode) {
        self.mapper = LocalMapper::new(mode);
    }

    /// Whether matched keypoints are moved to sub-pixel positions by patch alignment before local-map pose
    /// optimisation ([`crate::refine`]; on by default). Off gives ORB-SLAM2's whole-pixel measurements.
    pub fn set_refinement(&mut self, on: bool) {
        self.refine = on;
    }

    pub fn new(cam: StereoCamera, settings: TrackerSettings) -> Result<Self, TrackError> {
        let builder = FrameBuilder::new(cam, settings.orb)?;
        let scales = builder.scales().clone();
        Ok(Self {
            cam,
            scales,
            settings,
            builder,
            map: Map::default(),
            mapper: LocalMapper::default(),
            state: TrackingState::NotInitialized,
            current: Frame::empty(&cam),
            last: Frame::empty(&cam),
            velocity: None,
            lost_velocity: None,
            reference_kf: None,
            last_kf_frame: 0,
            last_reloc_frame: None,
            // Capacities of a large local map, so that a warmed-up frame does not grow them (they still grow,
            // amortised, past these sizes).
            local_kfs: Vec::with_capacity(128),
            local_points: Vec::with_capacity(1 << 15),
            kf_votes: Vec::with_capacity(1 << 12),
            kf_stamp: Vec::with_capacity(1 << 12),
            voters: Vec::with_capacity(1 << 10),
            searcher: Searcher::default(),
            optimizer: PoseOptimizer::default(),
            opt_points: Vec::with_capacity(1 << 12),
            opt_obs: Vec::with_capacity(1 << 12),
            opt_index: Vec::with_capacity(1 << 12),
            opt_outlier: Vec::with_capacity(1 << 12),
            // An hour at 30 fps before the trajectory record grows.
            records: Vec::with_capacity(1 << 17),
            last_from_reference: None,
            ransac_state: 0x005e_ed0f_7ac4,
            refine: true,
            aligner: Aligner::default(),
            to_anchor: Vec::with_capacity(1 << 12),
            new_point_anchors: Vec::with_capacity(1 << 12),
            residual_scratch: Vec::with_capacity(1 << 12),
        })
    }

    pub fn state(&self) -> TrackingState {
        self.state
    }

    pub fn camera(&self) -> &StereoCamera {
        &self.cam
    }

    fn max_frames(&self) -> u64 {
        self.settings.fps.round().max(1.0) as u64
    }

    fn close_depth(&self) -> f64 {
        self.settings.th_depth * self.cam.baseline()
    }

    /// Tracks one grey stereo pair.
    pub fn track(&mut self, t_ns: u64, left: &[u8], right: &[u8]) -> Result<FrameResult, TrackError> {
        self.builder.build(t_ns, left, right, &mut self.current)?;
        let mut result = FrameResult {
            frame_id: self.current.id,
            t_ns,
            state: self.state,
            camera_from_world: None,
            inliers: 0,
            new_keyframe: None,
            mapper: None,
            relocalised: false,
        };
        if self.state == TrackingState::NotInitialized {
            if self.current.len() > 500 {
                self.initialise(&mut result);
            }
            self.finish_frame(&mut result);
            return Ok(result);
        }
        let mut ok = if self.state == TrackingState::Ok {
            self.replace_last_frame_points();
            let recently_relocalised = self.last_reloc_frame.is_some_and(|r| self.current.id < r + 2);
            if self.velocity.is_none() || recently_relocalised {
                self.track_reference_keyframe()
            } else {
                self.track_motion_model() || self.track_reference_keyframe()
            }
        } else {
            let r = self.relocalise();
            result.relocalised = r;
            r
        };
        if ok {
            ok = self.track_local_map(&mut result);
        }
        self.state = if ok { TrackingState::Ok } else { TrackingState::Lost };
        if ok {
            let pose = self.current.camera_from_world.unwrap_or_else(Isometry3::identity);
            if let Some(last_pose) = self.last.camera_from_world {
                self.velocity = Some(pose * last_pose.inverse());
            }
            if self.need_keyframe(result.inliers) {
                self.create_keyframe(&mut result);
            }
            // Outlier links go after the keyframe decision (§5.1 step 5).
            for i in 0..self.current.len() {
                if self.current.outlier[i] {
                    self.current.points[i] = None;
                    self.current.outlier[i] = false;
                }
            }
        } else {
            if self.velocity.is_some() {
                self.lost_velocity = self.velocity;
            }
            self.velocity = None;
        }
        self.finish_frame(&mut result);
        Ok(result)
    }

    fn finish_frame(&mut self, result: &mut FrameResult) {
        result.state = self.state;
        let tracked = self.state == TrackingState::Ok;
        if tracked {
            result.camera_from_world = self.current.camera_from_world;
        }
        // The trajectory record: relative to the reference keyframe; when lost, the last relative pose again.
        if let (Some(r), Some(pose)) = (self.reference_kf, self.current.camera_from_world.filter(|_| tracked)) {
            let rel = pose * self.map.keyframes[r].camera_from_world.inverse();
            self.records.push(FrameRecord { t_ns: result.t_ns, reference: r, camera_from_reference: rel, lost: false });
            self.last_from_reference = Some((r, rel));
        } else if let Some((r, rel)) = self.last_from_reference {
            // While lost, the best guess is the last motion continued (ORB-SLAM2 repeats the last pose); it also
            // puts the relocalisation's search near where the camera went.
            let rel = self.lost_velocity.map_or(rel, |v| v * rel);
            self.records.push(FrameRecord { t_ns: result.t_ns, reference: r, camera_from_reference: rel, lost: true });
            self.last_from_reference = Some((r, rel));
        }
        self.last.copy_from(&self.current);
        if !tracked {
            self.last.camera_from_world = None;
        }
    }

    /// §5.2.
    fn initialise(&mut self, result: &mut FrameResult) {
        self.refine_new_disparities();
        self.current.camera_from_world = Some(Isometry3::identity());
        let kf = self.map.add_keyframe(KeyFrame::from_frame(0, &self.current, Isometry3::identity()));
        for i in 0..self.current.len() {
            if self.current.depth[i] > 0.0
                && let Some(x) = self.current.unproject_world(&self.cam, i)
            {
                let p = self.map.new_point(x, kf, i, &self.scales);
                self.current.points[i] = Some(p);
                self.anchor_new_point(p, i, kf, Isometry3::identity());
            }
        }
        self.reference_kf = Some(kf);
        self.last_kf_frame = self.current.id;
        self.local_kfs.clear();
        self.local_kfs.push(kf);
        self.local_points.clear();
        self.local_points.extend(self.map.keyframes[kf].points.iter().flatten().copied());
        self.state = TrackingState::Ok;
        result.new_keyframe = Some(kf);
        result.inliers = self.local_points.len();
    }

    fn replace_last_frame_points(&mut self) {
        for p in self.last.points.iter_mut() {
            if let Some(q) = *p {
                *p = self.map.resolve(q);
            }
        }
    }

    /// Pose-only optimisation of the current frame against its linked points; writes pose and outlier flags.
    fn optimise_current(&mut self) -> usize {
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
                inv_sigma2: self.scales.information(kp.octave, self.current.refined[i], self.map.refined_sigma),
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
    fn drop_outliers(&mut self) -> usize {
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
    fn update_last_frame(&mut self) {
        if let Some((r, rel)) = self.last_from_reference {
            self.last.camera_from_world = Some(rel * self.map.keyframe_pose(r));
        }
    }

    /// §5.3.
    fn track_motion_model(&mut self) -> bool {
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

    /// §5.4, with guided projection from the last pose instead of the vocabulary (§7.3 B).
    fn track_reference_keyframe(&mut self) -> bool {
        self.update_last_frame();
        let Some(r) = self.reference_kf else { return false };
        let Some(last_pose) = self.last.camera_from_world else { return false };
        self.current.camera_from_world = Some(last_pose);
        self.current.points.fill(None);
        let n = self.searcher.from_keyframe(
            &self.cam,
            &self.scales,
            &self.map,
            &mut self.current,
            r,
            &BTreeSet::new(),
            15.0,
            TH_HIGH,
        );
        if n < 15 {
            return false;
        }
        self.optimise_current();
        self.drop_outliers() >= 10
    }

    /// §5.6.
    fn track_local_map(&mut self, result: &mut FrameResult) -> bool {
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
            let th = if self.last_reloc_frame.is_some_and(|r| frame_id < r + 2) { 5.0 } else { 1.0 };
            self.searcher.local_points(&self.scales, &self.map, &mut self.current, &self.local_points, th);
        }
        self.refine_measurements(&pose);
        self.optimise_current();
        self.anchor_new_inliers();
        // Both read the χ² of the optimisation, made with the σ before this frame's update.
        self.reclassify_refined();
        self.update_refined_sigma();
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
        let needed = if self.last_reloc_frame.is_some_and(|r| frame_id < r + self.max_frames()) { 50 } else { 30 };
        inliers >= needed
    }

    /// Moves every matched keypoint whose point has an anchor to where the anchor's patch fits best
    /// ([`crate::refine`]) and its right-image match to where the same template fits along the row (failing
    /// that, by the same shift); notes in `to_anchor` the keypoints whose points need an anchor (none yet, or
    /// the view moved too far from it).
    fn refine_measurements(&mut self, pose: &CameraFromWorld) {
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
                    self.current.refined[i] = true;
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
    }

    /// Re-estimates the σ of refined measurements from this frame's residuals (median, so outliers do not
    /// count) and moves the map's running value a tenth of the way to it: the alignment's precision depends
    /// on the images (texture, noise, lighting), so it is measured rather than assumed.
    fn update_refined_sigma(&mut self) {
        let mut scaled = std::mem::take(&mut self.residual_scratch);
        scaled.clear();
        let sigma = self.map.refined_sigma;
        for (k, &i) in self.opt_index.iter().enumerate() {
            if !self.current.refined[i] {
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
    fn reclassify_refined(&mut self) {
        let sigma2 = self.map.refined_sigma * self.map.refined_sigma;
        for (k, &i) in self.opt_index.iter().enumerate() {
            if !self.current.refined[i] {
                continue;
            }
            let chi2 = self.optimizer.chi2()[k] * sigma2;
            let gate = if self.current.u_right[i] >= 0.0 { crate::optim::CHI2_STEREO } else { crate::optim::CHI2_MONO };
            self.current.outlier[i] = chi2.is_nan() || chi2 > gate;
        }
    }

    /// Anchors the points noted by [`Self::refine_measurements`] that are inliers of the final pose, at their
    /// keypoints in this frame.
    fn anchor_new_inliers(&mut self) {
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
            self.map.points[p].anchor = Anchor::cut(&levels[octave], scale, f64::from(kp.x), f64::from(kp.y), pose);
        }
    }

    /// Refines the right-image match of every stereo keypoint of the current frame without a point, by
    /// aligning its own patch along the right image's row: the depth new points are made with.
    fn refine_new_disparities(&mut self) {
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
    fn anchor_new_point(&mut self, p: PointId, i: usize, kf: KfId, pose: CameraFromWorld) {
        let Some((mut anchor, refined)) = self.new_point_anchors.get_mut(i).and_then(Option::take) else { return };
        anchor.camera_from_world = pose;
        self.map.points[p].anchor = Some(anchor);
        self.current.refined[i] = refined;
        self.map.keyframes[kf].refined[i] = refined;
    }

    /// The local keyframes (§5.6 step 1), with buffers indexed by keyframe id that only grow with the map.
    fn update_local_keyframes(&mut self) {
        let n = self.map.keyframes.len();
        if self.kf_votes.len() < n {
            self.kf_votes.resize(n, 0);
            self.kf_stamp.resize(n, u64::MAX);
        }
        self.voters.clear();
        for i in 0..self.current.len() {
            let Some(p) = self.current.points[i] else { continue };
            if self.map.points[p].bad {
                self.current.points[i] = None;
                continue;
            }
            for &k in self.map.points[p].observations.keys() {
                if self.kf_votes[k] == 0 {
                    self.voters.push(k);
                }
                self.kf_votes[k] += 1;
            }
        }
        if self.voters.is_empty() {
            return;
        }
        self.voters.sort_unstable();
        let stamp = self.current.id;
        let (map, local, marks) = (&self.map, &mut self.local_kfs, &mut self.kf_stamp);
        local.clear();
        for &k in &self.voters {
            if !map.keyframes[k].bad {
                local.push(k);
                marks[k] = stamp;
            }
        }
        // Neighbours of the voters (the intended behaviour: adding a parent does not end the walk, §10.1 #7).
        let voters = local.len();
        for idx in 0..voters {
            if local.len() > 80 {
                break;
            }
            let kf = &map.keyframes[local[idx]];
            let fresh = |k: &KfId| marks[*k] != stamp && !map.keyframes[*k].bad;
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

    fn update_local_points(&mut self) {
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

    /// §5.8 with a mapper that runs inline (always idle, never stopped).
    fn need_keyframe(&self, inliers: usize) -> bool {
        let n_kfs = self.map.n_good_keyframes() as u64;
        let frame_id = self.current.id;
        // ORB-SLAM2 makes no keyframe for maxFrames (= fps) frames after a relocalisation. Moving forward through
        // a colon, the old keyframes run out of view within that second and tracking is lost again (seen on the
        // synthetic colon); a few frames of hold-off are enough to keep a doubtful pose out of the map.
        if self.last_reloc_frame.is_some_and(|r| frame_id < r + RELOCALISATION_HOLDOFF_FRAMES) {
            return false;
        }
        let Some(r) = self.reference_kf else { return false };
        let min_obs = if n_kfs <= 2 { 2 } else { 3 };
        let n_ref = self.map.keyframes[r]
            .points
            .iter()
            .flatten()
            .filter(|&&p| !self.map.points[p].bad && self.map.points[p].n_obs >= min_obs)
            .count() as f64;
        let close = self.close_depth();
        let (mut tracked_close, mut untracked_close) = (0, 0);
        for i in 0..self.current.len() {
            let z = f64::from(self.current.depth[i]);
            if z > 0.0 && z < close {
                if self.current.points[i].is_some() && !self.current.outlier[i] {
                    tracked_close += 1;
                } else {
                    untracked_close += 1;
                }
            }
        }
        let need_close = tracked_close < 100 && untracked_close > 70;
        let th_ref_ratio = if n_kfs < 2 { 0.4 } else { 0.75 };
        let inliers = inliers as f64;
        let overdue = frame_id >= self.last_kf_frame + self.max_frames();
        let mapper_free = true; // the mapper runs inline, so it is always idle (minFrames = 0)
        let weak = inliers < 0.25 * n_ref || need_close;
        let content = inliers > 15.0 && (inliers < th_ref_ratio * n_ref || need_close);
        (overdue || mapper_free || weak) && content
    }

    /// §5.9, then local mapping on the new keyframe.
    fn create_keyframe(&mut self, result: &mut FrameResult) {
        let Some(pose) = self.current.camera_from_world else { return };
        self.refine_new_disparities();
        let kf = self.map.add_keyframe(KeyFrame::from_frame(0, &self.current, pose));
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
            if !has_point && let Some(x) = self.current.unproject_world(&self.cam, i) {
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
        self.reference_kf = Some(kf);
        self.last_kf_frame = self.current.id;
        let report = self.mapper.process(&mut self.map, kf, &self.cam, &self.scales, self.settings.th_depth);
        // The keyframe's pose may have moved in bundle adjustment: the frame follows it.
        let kf_pose = self.map.keyframes[kf].camera_from_world;
        self.current.camera_from_world = Some(kf_pose);
        result.new_keyframe = Some(kf);
        result.mapper = Some(report);
    }

    /// §5.7 without a vocabulary (§7.3 B): candidate keyframes by brute-force descriptor votes, a 3-point
    /// RANSAC on the frame's stereo points (each keypoint with a depth is a 3-D point, so absolute orientation
    /// replaces PnP), then pose optimisation and guided search as in ORB-SLAM2.
    fn relocalise(&mut self) -> bool {
        let n = self.current.len();
        if n == 0 {
            return false;
        }
        // Candidates (§7.3 B): the camera is most likely near where it was last seen, so the last reference
        // keyframe, its covisibles and the keyframes nearest to the last pose; when the last pose is unknown or
        // those fail, every keyframe. Each is ranked by descriptor votes (a frame keypoint whose best match among
        // the keyframe's points passes TH_LOW and the ratio test).
        let mut near: Vec<KfId> = Vec::new();
        if let Some(r) = self.reference_kf.filter(|&r| !self.map.keyframes[r].bad) {
            near.push(r);
            near.extend(self.map.keyframes[r].best_covisibles(5));
        }
        if let Some((r, rel)) = self.last_from_reference {
            let last_centre = (rel * self.map.keyframe_pose(r)).inverse() * Point3::origin();
            let mut by_distance: Vec<(f64, KfId)> =
                self.map.good_keyframes().map(|k| ((k.centre() - last_centre).norm(), k.id)).collect();
            by_distance.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            near.extend(by_distance.iter().take(5).map(|(_, k)| *k));
        }
        let mut seen = BTreeSet::new();
        near.retain(|k| seen.insert(*k) && !self.map.keyframes[*k].bad);
        let mut scored: Vec<(usize, KfId)> =
            near.iter().map(|&k| (self.votes(k), k)).filter(|(v, _)| *v >= 15).collect();
        scored.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        for &(_, kf) in scored.iter().take(5) {
            if self.relocalise_against(kf) {
                self.last_reloc_frame = Some(self.current.id);
                self.reference_kf = Some(kf);
                return true;
            }
        }
        false
    }

    /// Frame keypoints whose best match among keyframe `kf`'s points is ≤ TH_LOW and < 0.75 of the second best.
    fn votes(&self, kf: KfId) -> usize {
        let descs: Vec<&[u8; 32]> = self.map.keyframes[kf]
            .points
            .iter()
            .flatten()
            .filter(|&&p| !self.map.points[p].bad)
            .map(|&p| &self.map.points[p].descriptor)
            .collect();
        self.current
            .descriptors
            .iter()
            .filter(|d| {
                let (mut best, mut second) = (u32::MAX, u32::MAX);
                for p in &descs {
                    let h = hamming(d, p);
                    if h < best {
                        second = best;
                        best = h;
                    } else if h < second {
                        second = h;
                    }
                }
                best <= TH_LOW && f64::from(best) < 0.75 * f64::from(second)
            })
            .count()
    }

    fn relocalise_against(&mut self, kf: KfId) -> bool {
        // Matches: best descriptor (≤ TH_LOW, ratio 0.75) among the keyframe's points for each frame keypoint.
        let mut pairs: Vec<(usize, PointId)> = Vec::new();
        let points: Vec<PointId> =
            self.map.keyframes[kf].points.iter().flatten().copied().filter(|&p| !self.map.points[p].bad).collect();
        let mut used = BTreeSet::new();
        for i in 0..self.current.len() {
            let (mut best, mut second) = ((u32::MAX, usize::MAX), u32::MAX);
            for &p in &points {
                let d = hamming(&self.current.descriptors[i], &self.map.points[p].descriptor);
                if d < best.0 {
                    second = best.0;
                    best = (d, p);
                } else if d < second {
                    second = d;
                }
            }
            if best.0 <= TH_LOW && f64::from(best.0) < 0.75 * f64::from(second) && used.insert(best.1) {
                pairs.push((i, best.1));
            }
        }
        let stereo: Vec<(usize, PointId, Point3<f64>)> = pairs
            .iter()
            .filter_map(|&(i, p)| {
                let z = self.current.depth[i];
                (z > 0.0).then(|| {
                    let k = &self.current.keypoints[i];
                    (i, p, self.cam.unproject(f64::from(k.x), f64::from(k.y), f64::from(z)))
                })
            })
            .collect();
        if stereo.len() < 15 {
            return false;
        }
        // RANSAC: 3 correspondences → camera_from_world by absolute orientation; inliers by reprojection.
        let mut best: (usize, Option<CameraFromWorld>) = (0, None);
        for _ in 0..300 {
            let mut pick = [0usize; 3];
            for slot in pick.iter_mut() {
                self.ransac_state =
                    self.ransac_state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
                *slot = (self.ransac_state >> 33) as usize % stereo.len();
            }
            if pick[0] == pick[1] || pick[1] == pick[2] || pick[0] == pick[2] {
                continue;
            }
            let src: Vec<Point3<f64>> = pick.iter().map(|&k| self.map.points[stereo[k].1].position).collect();
            let dst: Vec<Point3<f64>> = pick.iter().map(|&k| stereo[k].2).collect();
            let Some(t) = rigid_fit(&src, &dst) else { continue };
            let inliers = stereo
                .iter()
                .filter(|(i, p, _)| {
                    let pc = t * self.map.points[*p].position;
                    if pc.z <= 0.0 {
                        return false;
                    }
                    let (u, v) = self.cam.project(&pc);
                    let k = &self.current.keypoints[*i];
                    let e2 = (u - f64::from(k.x)).powi(2) + (v - f64::from(k.y)).powi(2);
                    e2 < 5.991 / self.scales.inv_sigma2[usize::from(k.octave)]
                })
                .count();
            if inliers > best.0 {
                best = (inliers, Some(t));
            }
        }
        let (count, Some(pose)) = best else { return false };
        if count < 10 {
            return false;
        }
        self.current.camera_from_world = Some(pose);
        self.current.points.fill(None);
        self.current.outlier.fill(false);
        for &(i, p) in &pairs {
            self.current.points[i] = Some(p);
        }
        let mut good = self.optimise_current();
        if good < 10 {
            return false;
        }
        self.drop_outliers();
        if good < 50 {
            let found: BTreeSet<PointId> = self.current.points.iter().flatten().copied().collect();
            let added = self.searcher.from_keyframe(
                &self.cam,
                &self.scales,
                &self.map,
                &mut self.current,
                kf,
                &found,
                10.0,
                100,
            );
            if good + added >= 50 {
                good = self.optimise_current();
                self.drop_outliers();
            }
        }
        good >= 50
    }

    /// Waits for the local bundle adjustment still running and applies it (call before reading the final map or
    /// trajectory).
    pub fn finish(&mut self) -> MapperReport {
        let mut report = MapperReport::default();
        self.mapper.finish_ba(&mut self.map, &self.scales, &mut report);
        report
    }

    /// The trajectory so far: (t_ns, world_from_camera, lost) per frame, from each frame's reference keyframe as
    /// it is now (so bundle adjustment's corrections reach every frame).
    pub fn trajectory(&self) -> Vec<(u64, Isometry3<f64>, bool)> {
        self.records
            .iter()
            .map(|r| {
                let camera_from_world = r.camera_from_reference * self.map.keyframe_pose(r.reference);
                (r.t_ns, camera_from_world.inverse(), r.lost)
            })
            .collect()
    }

    /// (t_ns, world_from_camera) of every keyframe still in the map.
    pub fn keyframe_trajectory(&self) -> Vec<(u64, Isometry3<f64>)> {
        self.map.good_keyframes().map(|k| (k.t_ns, k.camera_from_world.inverse())).collect()
    }
}

/// The rigid motion `dst_from_src` that best maps `src` onto `dst` (Horn/Umeyama without scale); `None` for
/// degenerate (collinear) sets.
pub fn rigid_fit(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Option<Isometry3<f64>> {
    let n = src.len() as f64;
    let (cs, cd) = (
        src.iter().fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords) / n,
        dst.iter().fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords) / n,
    );
    let mut cov = Matrix3::zeros();
    for (s, d) in src.iter().zip(dst) {
        cov += (d.coords - cd) * (s.coords - cs).transpose();
    }
    let svd = cov.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let sv = svd.singular_values;
    if sv[1] < 1e-9 * sv[0].max(1e-30) {
        return None;
    }
    let mut s = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let r = u * s * v_t;
    let rotation = UnitQuaternion::from_matrix(&r);
    let t = cd - rotation * cs;
    Some(Isometry3::from_parts(Translation3::from(t), rotation))
}
