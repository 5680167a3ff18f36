//! The per-frame tracking state machine (ORB-SLAM2-STEREO.md §5): stereo initialisation, motion-model and
//! reference-keyframe tracking, local-map tracking, relocalisation, the keyframe decision and creation. This
//! file holds the state and the machine ([`Tracker::track`]); each of ORB-SLAM2's stages is a module beside it:
//! `motion` (§5.3–§5.4), `local_map` (§5.6), `measurements` (sub-pixel, ours), `keyframe` (§5.8–§5.9) and
//! `relocalise` (§5.7).

mod appearance;
mod bridge;
mod keyframe;
mod local_map;
mod measurements;
mod motion;
mod quality;
mod record;
mod relocalise;
mod segment;

use crate::geometry::draw_three;
pub use crate::geometry::rigid_fit;
pub use appearance::AppearanceFix;
pub use quality::{Doubt, PoseMethod, TrackingQuality};
use record::FrameRecord;
pub use segment::RESTART_AFTER_S;

use crate::frame::{Frame, FrameBuilder, Scales};
use crate::geometry::{CameraFromWorld, RectifiedCamera};
use crate::map::{KeyFrame, KfId, Map, PointId};
use crate::mapper::{LocalMapper, MapperReport};
use crate::optim::{Observation, PoseOptimizer};
use crate::refine::{Aligner, Anchor, Unrefined};
use crate::search::{Searcher, TH_HIGH, frustum_check};
use bdis_orb::{OrbError, OrbParams};
use nalgebra::{Isometry3, Point3};

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
    /// Tracked, but the images do not support the pose well enough to trust it ([`TrackingQuality::doubt`]
    /// says why): the pose is published and recorded; a keyframe is made from it only for the doubts that
    /// allow one (`Tracker::track`).
    Uncertain,
    Lost,
}

impl TrackingState {
    /// Whether the frame has a pose (`Ok` or `Uncertain`).
    pub fn is_tracked(self) -> bool {
        matches!(self, Self::Ok | Self::Uncertain)
    }
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
    /// The frame began a new map segment ([`Tracker::restart`]).
    pub new_segment: bool,
    pub quality: TrackingQuality,
}

#[derive(Debug)]
pub struct Tracker {
    cam: RectifiedCamera,
    scales: Scales,
    settings: TrackerSettings,
    builder: FrameBuilder,
    map: Map,
    mapper: LocalMapper,
    state: TrackingState,
    current: Frame,
    last: Frame,
    velocity: Option<Isometry3<f64>>,
    /// The velocity when tracking was last OK: lost frames are extrapolated with it in the trajectory.
    lost_velocity: Option<Isometry3<f64>>,
    reference_kf: Option<KfId>,
    last_kf_frame: u64,
    /// The position σ (relative to the depth) of the first frame after the last keyframe: how well the map
    /// held a frame when it was fresh ([`keyframe::KeyframeEvidence::sigma_after_keyframe`]).
    sigma_after_keyframe: f64,
    last_reloc_frame: Option<u64>,
    /// Where relocalisation's scan of the whole map goes on from on the next lost frame (at least
    /// [`relocalise::SCAN_PER_FRAME`] keyframes a frame).
    reloc_scan_next: KfId,
    local_kfs: Vec<KfId>,
    local_points: Vec<PointId>,
    /// Per keyframe id: votes of the current frame's points, and the frame that last included it locally.
    kf_votes: Vec<u32>,
    kf_stamp: Vec<u64>,
    voters: Vec<KfId>,
    /// Keyframes that look where the current frame looks without sharing a point with it: (closeness, id).
    in_view: Vec<(f64, KfId)>,
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
    appearance: appearance::AppearanceScratch,
    reloc: relocalise::RelocScratch,
    /// How far the last applied local bundle adjustment moved its keyframe, over that keyframe's median depth
    /// ([`MapperReport::ba_moved_rel`]): the map the frames are tracked against, still moving by that much.
    map_moved_rel: f64,
    /// Whether the current frame is seen through a veil ([`Self::judge_veil`]).
    veil: quality::Veil,
    /// The current frame's texture over the clearest view of its place's, measure by measure (NaN without a
    /// reference).
    texture_ratio: crate::frame::ViewTexture,
    /// That clearest view of the place: what a keyframe made under a veil records as its own, so that the place
    /// stays judged against its clear view however many veiled keyframes follow.
    place_texture: crate::frame::ViewTexture,
    /// The last keyframe made in a clear view: what a keyframe made under a veil takes its new points from
    /// ([`Self::seen_in_clear_view`]).
    clear_view: keyframe::ClearView,
    /// Whether the last frame was posed by the motion model alone through a veil ([`Self::coast`]).
    last_coasted: bool,
    /// Whether `velocity` is an external motion prior for the current frame ([`Self::set_motion_prior`]).
    external_prior: bool,
    reckoning: segment::ReckoningScratch,
    /// Frames since the last tracked one that had the features to begin a map from and that relocalisation
    /// could not place.
    unplaced_frames: u64,
    /// Set while tracking on a segment begun by [`Self::restart`] that is not yet tied back.
    detached: Option<segment::Detachment>,
    /// Inliers of the last tracked frame (not coasted): what a frame of the same view keeps most of.
    confirmed_inliers: usize,
    /// The last frame's doubt: what a pose predicted from it may inherit ([`Doubt::UnconfirmedPrior`]).
    last_doubt: Option<Doubt>,
}

impl Tracker {
    /// Where local bundle adjustment runs: a worker thread (the default; results applied at the next keyframe)
    /// or inline in the caller's thread (applied at once: a single-core target, or measuring its cost per
    /// keyframe). Set before the first frame.
    pub fn set_ba_mode(&mut self, mode: crate::mapper::BaMode) {
        let (loop_closing, start) = (self.mapper.loop_closing(), self.mapper.worker_start());
        self.mapper = LocalMapper::new(mode);
        self.mapper.set_worker_start(start);
        self.mapper.set_loop_closing(loop_closing);
    }

    /// What every background thread of the tracker (local bundle adjustment, loop closing) runs first: the
    /// owning process's say in how they are scheduled ([`crate::workers::WorkerStart`]). Set before the first
    /// keyframe.
    pub fn set_worker_start(&mut self, start: crate::workers::WorkerStart) {
        self.mapper.set_worker_start(Some(start));
    }

    /// Whether matched keypoints are moved to sub-pixel positions by patch alignment before local-map pose
    /// optimisation ([`crate::refine`]; on by default). Off gives ORB-SLAM2's whole-pixel measurements.
    pub fn set_refinement(&mut self, on: bool) {
        self.refine = on;
    }

    pub fn new(cam: RectifiedCamera, settings: TrackerSettings) -> Result<Self, TrackError> {
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
            current: Frame::with_capacity(&cam, 2 * settings.orb.n_features as usize),
            last: Frame::with_capacity(&cam, 2 * settings.orb.n_features as usize),
            velocity: None,
            lost_velocity: None,
            reference_kf: None,
            last_kf_frame: 0,
            sigma_after_keyframe: f64::NAN,
            last_reloc_frame: None,
            reloc_scan_next: 0,
            // Capacities of a large local map, so that a warmed-up frame does not grow them (they still grow,
            // amortised, past these sizes).
            local_kfs: Vec::with_capacity(128),
            local_points: Vec::with_capacity(1 << 15),
            kf_votes: Vec::with_capacity(1 << 12),
            kf_stamp: Vec::with_capacity(1 << 12),
            voters: Vec::with_capacity(1 << 10),
            in_view: Vec::with_capacity(1 << 12),
            searcher: Searcher::with_capacity(2 * settings.orb.n_features as usize),
            optimizer: PoseOptimizer::for_tracking(1 << 12),
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
            appearance: appearance::AppearanceScratch::with_capacity(settings.orb.n_features as usize),
            reloc: relocalise::RelocScratch::with_capacity(settings.orb.n_features as usize),
            map_moved_rel: 0.0,
            veil: quality::Veil::Clear,
            texture_ratio: crate::frame::ViewTexture::UNKNOWN,
            place_texture: crate::frame::ViewTexture::UNKNOWN,
            clear_view: keyframe::ClearView::default(),
            last_coasted: false,
            external_prior: false,
            reckoning: segment::ReckoningScratch::default(),
            unplaced_frames: 0,
            detached: None,
            confirmed_inliers: 0,
            last_doubt: None,
        })
    }

    pub fn state(&self) -> TrackingState {
        self.state
    }

    /// The map, read-only: the tracker and its local mapping are its one owner.
    pub fn map(&self) -> &Map {
        &self.map
    }

    pub fn camera(&self) -> &RectifiedCamera {
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
        self.track_masked(t_ns, left, right, None)
    }

    /// Tracks one grey stereo pair with no feature from `keep_out` (one byte per left pixel, non-zero =
    /// instruments): what moves on its own gives neither the pose nor map points.
    pub fn track_masked(
        &mut self,
        t_ns: u64,
        left: &[u8],
        right: &[u8],
        keep_out: Option<&[u8]>,
    ) -> Result<FrameResult, TrackError> {
        self.builder.build(t_ns, left, right, keep_out, &mut self.current)?;
        let mut result = FrameResult {
            frame_id: self.current.id,
            t_ns,
            state: self.state,
            camera_from_world: None,
            inliers: 0,
            new_keyframe: None,
            mapper: None,
            relocalised: false,
            new_segment: false,
            quality: TrackingQuality::default(),
        };
        if self.state == TrackingState::NotInitialized {
            if self.enough_to_begin(keep_out) {
                self.initialise(&mut result);
                result.quality.method = PoseMethod::Initialisation;
            }
            self.finish_frame(&mut result);
            return Ok(result);
        }
        self.judge_veil();
        let mut ok = if self.state.is_tracked() {
            self.track_from_last_frame(&mut result.quality)
        } else {
            let r = self.relocalise();
            result.relocalised = r;
            result.quality.method = PoseMethod::Relocalisation;
            if !r && !self.veil.is_down() && self.enough_to_begin(keep_out) {
                self.unplaced_frames += 1;
                if self.unplaced_frames >= self.restart_after_frames() {
                    self.restart(&mut result);
                    self.finish_frame(&mut result);
                    return Ok(result);
                }
            }
            r
        };
        // After frames coasted through a veil the last frame holds no matches to start from: the local map is
        // searched from the prediction instead.
        if !ok && self.last_coasted && self.state.is_tracked() {
            ok = self.seed_from_prediction();
            result.quality.method = PoseMethod::Prediction;
        }
        if ok {
            ok = self.track_local_map(&mut result);
        }
        let mut coasting = !ok && self.coast();
        ok |= coasting;
        let mut doubt = if coasting {
            Some(Doubt::LowContrast)
        } else if ok {
            result.quality.inliers = result.inliers as u32;
            match self.assess(&mut result.quality) {
                None | Some(Doubt::MapMoving) if self.still_detached() => Some(Doubt::Detached),
                doubt => doubt,
            }
        } else {
            Some(Doubt::FewInliers)
        };
        // Under a veil it is the haze, not a cut, that takes most of the last frame's points away: a pose
        // nothing confirms there is coasted like one the images could not give (smoke that hangs in the cavity
        // leaves a few dim matches where a sheet riding with the scope left none).
        if doubt == Some(Doubt::Unconfirmed) && self.coast() {
            coasting = true;
            doubt = Some(Doubt::LowContrast);
            // The measures were of the pose given up; what appearance found stands.
            let q = &result.quality;
            result.quality = TrackingQuality {
                appearance_matches: q.appearance_matches,
                appearance_consensus: q.appearance_consensus,
                prior_rejected: q.prior_rejected,
                ..TrackingQuality::default()
            };
        }
        if coasting {
            result.quality.method = PoseMethod::Prediction;
            result.inliers = 0;
        }
        self.last_coasted = coasting;
        result.quality.inliers = result.inliers as u32;
        result.quality.doubt = doubt;
        self.last_doubt = doubt;
        // A pose nothing confirms, on a view that lost most of the last one's points, is no pose.
        ok &= doubt != Some(Doubt::Unconfirmed);
        if ok && !coasting {
            self.confirmed_inliers = result.inliers;
        }
        self.state = match (ok, doubt) {
            (false, _) => TrackingState::Lost,
            (true, None) => TrackingState::Ok,
            (true, Some(_)) => TrackingState::Uncertain,
        };
        if ok {
            let pose = self.current.camera_from_world.unwrap_or_else(Isometry3::identity);
            if let Some(last_pose) = self.last.camera_from_world {
                self.velocity = Some(pose * last_pose.inverse());
            }
            // A keyframe fixes map points and the dense map at its pose: only from a pose the images support,
            // save the doubts that keep keyframes (`Doubt::keeps_keyframes`), and a veiled view posed on the map
            // (not coasted): a scope that moves on under smoke otherwise leaves its map behind and is lost when
            // the smoke clears; such a keyframe takes new points only where the last clear keyframe saw the same
            // tissue (`create_keyframe`), so the smoke itself never enters the map.
            let supported = self.state == TrackingState::Ok
                || doubt.is_some_and(Doubt::keeps_keyframes)
                || (doubt == Some(Doubt::LowContrast) && !coasting);
            if self.current.id == self.last_kf_frame + 1 {
                self.sigma_after_keyframe = result.quality.position_sigma_rel;
            }
            // Only a pose the images support says how well the map holds the frame.
            let sigma_now = if self.state == TrackingState::Ok { result.quality.position_sigma_rel } else { f64::NAN };
            if supported && self.need_keyframe(result.inliers, sigma_now) {
                self.create_keyframe(&mut result);
            }
            self.unplaced_frames = 0;
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

    /// The first pose of a frame while tracking (§5.1 step 2): the motion model, checked against matching by
    /// appearance; appearance alone when there is no velocity (the start, after relocalisation) or the motion
    /// model fails or disagrees with it.
    fn track_from_last_frame(&mut self, quality: &mut TrackingQuality) -> bool {
        self.replace_last_frame_points();
        let recently_relocalised = self.last_reloc_frame.is_some_and(|r| self.current.id < r + 2);
        // The estimate with no prior, computed first so it can check the prior's.
        let fix = self.reference_kf.and_then(|r| self.appearance_consensus(r));
        if let Some(f) = fix {
            quality.appearance_matches = f.matches as u32;
            quality.appearance_consensus = f.consensus as u32;
        }
        if self.velocity.is_some() && !recently_relocalised && self.track_motion_model() {
            let agrees = match (fix, self.current.camera_from_world) {
                // No consensus to compare with (NaN) is no disagreement.
                (Some(_), Some(pose)) => {
                    let agreement = self.appearance_agreement(&pose);
                    agreement.is_nan() || agreement >= quality::PRIOR_AGREEMENT
                }
                _ => true,
            };
            if agrees {
                quality.method = PoseMethod::MotionModel;
                return true;
            }
            quality.prior_rejected = true;
        }
        if let Some(f) = fix
            && self.adopt_appearance(f).is_some()
        {
            quality.method = PoseMethod::Appearance;
            return true;
        }
        quality.method = PoseMethod::ReferenceProjection;
        self.track_reference_keyframe()
    }

    fn finish_frame(&mut self, result: &mut FrameResult) {
        result.state = self.state;
        let tracked = self.state.is_tracked();
        if tracked {
            result.camera_from_world = self.current.camera_from_world;
        }
        // The trajectory record: relative to the reference keyframe; when lost, the last relative pose again.
        if let (Some(r), Some(pose)) = (self.reference_kf, self.current.camera_from_world.filter(|_| tracked)) {
            let rel = pose * self.map.keyframes[r].camera_from_world.inverse();
            let view = match result.quality.doubt {
                Some(Doubt::LowContrast) if self.last_coasted => bridge::View::Coasted,
                Some(Doubt::LowContrast) => bridge::View::Veiled,
                // A map still settling doubts the live pose, not the written one (the keyframes' final poses
                // re-express it); a detached segment's frames are right relative to each other, which is what a
                // bridge takes from its ends.
                Some(Doubt::MapMoving | Doubt::Detached) | None if !self.haze_seen() => bridge::View::Clear,
                Some(Doubt::MapMoving | Doubt::Detached | Doubt::Hazy) | None => bridge::View::Hazy,
                Some(_) => bridge::View::Doubted,
            };
            let anchors = self.anchors(r, pose);
            self.records.push(FrameRecord { t_ns: result.t_ns, anchors, view });
            self.last_from_reference = Some((r, rel));
        } else if let (Some((r, rel)), Some(last)) = (self.last_from_reference, self.records.last()) {
            // While lost, the best guess is the last motion continued (ORB-SLAM2 repeats the last pose); it also
            // puts the relocalisation's search near where the camera went.
            let motion = self.lost_velocity.unwrap_or_else(Isometry3::identity);
            let record = last.moved(result.t_ns, motion);
            self.records.push(record);
            self.last_from_reference = Some((r, motion * rel));
        }
        self.last.copy_from(&self.current);
        self.external_prior = false;
        if !tracked {
            self.last.camera_from_world = None;
        }
    }

    /// Whether the current frame has the features a map can begin from: ORB-SLAM2 waits for 500; with fewer
    /// requested, for half of them; over the part of the image that may give features (a mask takes its share
    /// of the image away, not of the density).
    fn enough_to_begin(&self, keep_out: Option<&[u8]>) -> bool {
        let open = keep_out.map_or(1.0, |mask| {
            let n = (self.cam.width * self.cam.height) as usize;
            mask[..n.min(mask.len())].iter().filter(|&&m| m == 0).count() as f64 / n.max(1) as f64
        });
        let wanted = 500.min(self.settings.orb.n_features as usize / 2) as f64 * open;
        self.current.len() as f64 > wanted
    }

    /// §5.2.
    fn initialise(&mut self, result: &mut FrameResult) {
        let kf = self.begin_map_at(Isometry3::identity());
        self.state = TrackingState::Ok;
        self.last_doubt = None;
        result.new_keyframe = Some(kf);
        result.inliers = self.local_points.len();
    }

    /// Makes the current frame a keyframe at `pose` with a point for every stereo keypoint, and the whole local
    /// map: how a map begins, from one stereo frame.
    fn begin_map_at(&mut self, pose: Isometry3<f64>) -> KfId {
        self.refine_new_disparities();
        self.current.camera_from_world = Some(pose);
        let kf = self.map.add_keyframe(KeyFrame::from_frame(0, &self.current, pose));
        for i in 0..self.current.len() {
            if self.current.depth[i] > 0.0
                && let Some(x) = self.current.unproject_world(&self.cam, i)
            {
                let p = self.map.new_point(x, kf, i, &self.scales);
                self.current.points[i] = Some(p);
                self.anchor_new_point(p, i, kf, pose);
            }
        }
        self.reference_kf = Some(kf);
        self.last_kf_frame = self.current.id;
        self.local_kfs.clear();
        self.local_kfs.push(kf);
        self.local_points.clear();
        self.local_points.extend(self.map.keyframes[kf].points.iter().flatten().copied());
        kf
    }

    /// Waits for the local bundle adjustment still running and applies it (call before reading the final map or
    /// trajectory).
    pub fn finish(&mut self) -> MapperReport {
        let mut report = MapperReport::default();
        self.mapper.finish_ba(&mut self.map, &self.scales, &mut report);
        self.mapper.finish_loops(&mut self.map, &self.cam, &self.scales, &mut report);
        report
    }

    /// Loop closing on (the default) or off (ORB-SLAM2-STEREO.md §8). Set before the first frame. Either way map
    /// reuse ties a revisit in as soon as the view overlaps old keyframes; on, the mapper also recognises the
    /// revisit as a loop, fuses the two passes' duplicated points, corrects a drift beyond noise with the pose
    /// graph and re-solves the whole map by a global bundle adjustment (see BENCHMARKS.md for what each gives).
    pub fn set_loop_closing(&mut self, on: bool) {
        self.mapper.set_loop_closing(on);
    }

    /// The loops closed so far: (keyframe that recognised the place, old keyframe).
    pub fn loops_closed(&self) -> &[(KfId, KfId)] {
        self.mapper.loops_closed()
    }

    /// The trajectory so far: (t_ns, world_from_camera, lost) per frame, from the keyframes it was tracked on as
    /// they are now ([`FrameRecord::world_from_camera`]: bundle adjustment's corrections reach every frame), with
    /// every veil and every run of lost frames that clear frames enclose bridged from them ([`bridge`]).
    pub fn trajectory(&self) -> Vec<(u64, Isometry3<f64>, bool)> {
        let mut poses: Vec<Isometry3<f64>> = self.records.iter().map(|r| r.world_from_camera(&self.map)).collect();
        let t_s: Vec<f64> = self.records.iter().map(|r| r.t_ns as f64 * 1e-9).collect();
        let views: Vec<bridge::View> = self.records.iter().map(|r| r.view).collect();
        bridge::bridge_veils(&t_s, &mut poses, &views);
        bridge::bridge_hazes(&t_s, &mut poses, &views);
        bridge::bridge_losses(&t_s, &mut poses, &views);
        self.records.iter().zip(poses).map(|(r, pose)| (r.t_ns, pose, r.view == bridge::View::Lost)).collect()
    }

    /// (t_ns, world_from_camera) of every keyframe still in the map.
    pub fn keyframe_trajectory(&self) -> Vec<(u64, Isometry3<f64>)> {
        self.map.good_keyframes().map(|k| (k.t_ns, k.camera_from_world.inverse())).collect()
    }
}
