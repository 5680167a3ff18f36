//! A new map segment when the tracker is lost in tissue the map does not hold (ORB-SLAM2-STEREO.md §5.7 finds
//! known places only): where it is placed, and when it is tied back.

use super::{FrameResult, Tracker, TrackingState, bridge, relocalise};
use crate::map::{KfId, PointId};
use crate::tracker::quality::{Doubt, PoseMethod};
use nalgebra::Isometry3;

/// How long relocalisation gets to find a known place in frames it could have started a map from, before the
/// tracker begins a new map segment there ([`Tracker::restart`]). Relocalisation finds a place it knows in the
/// first frame that shows it clearly; every frame waited beyond that is travel dead-reckoned into the new
/// segment's place.
pub const RESTART_AFTER_S: f64 = 0.3;
/// Inliers on points made before a restart that tie the new segment back to the older map: relocalisation's
/// bar for a pose found against a keyframe's points (§5.7).
const TIED_BACK_INLIERS: usize = relocalise::PRIORLESS_INLIERS;

/// Reusable buffers of dead reckoning ([`Tracker::dead_reckoned`]): the last records' times, world poses and
/// views, over the window the motion is measured on.
#[derive(Debug, Default)]
pub(super) struct ReckoningScratch {
    t_s: Vec<f64>,
    poses: Vec<Isometry3<f64>>,
    views: Vec<bridge::View>,
}

#[derive(Debug, Clone, Copy)]
pub(super) struct Detachment {
    /// The segment's first keyframe: keyframes from it on are the segment's.
    first_keyframe: KfId,
    /// The older map the segment is tied back to: the points and keyframes with ids below these. The map before
    /// the segment, or, when the segment began while an earlier one was still detached, the map before that
    /// one (a segment is never tied to another one's guessed place).
    older_than_point: PointId,
    older_than_keyframe: KfId,
}

impl Tracker {
    /// [`RESTART_AFTER_S`] in frames at this footage's rate: the unplaced frames after which a segment begins.
    pub(super) fn restart_after_frames(&self) -> u64 {
        (RESTART_AFTER_S * self.settings.fps).ceil().max(1.0) as u64
    }

    /// Begins a new map segment at the current frame, lost for [`RESTART_AFTER_S`] in frames relocalisation could
    /// not place: the scope has gone on into tissue the map does not hold (a fast flight through smoke, a jerk
    /// into new tissue), where relocalisation, which looks for known places only, would never find it. The
    /// segment is placed where the motion at the last frame soundly measured (veiled frames included: the haze
    /// shifts them by a bounded amount, while dead reckoning's error grows with its gap), carried on, puts the
    /// camera ([`Self::dead_reckoned`]), and tied into the keyframe tree under the last reference keyframe, so
    /// that loop closing can correct it like any other keyframe. Its frames are `Uncertain`,
    /// [`Doubt::Detached`], until it is tied back to the older map.
    pub(super) fn restart(&mut self, result: &mut FrameResult) {
        let pose = self.dead_reckoned(result.t_ns);
        let before = self.reference_kf.filter(|&r| !self.map.keyframes[r].bad);
        // A failed relocalisation leaves its matches as links: they are to the old map, not to this frame.
        self.current.points.iter_mut().for_each(|p| *p = None);
        self.current.outlier.iter_mut().for_each(|o| *o = false);
        let first_point = self.map.points.len();
        let kf = self.begin_map_at(pose);
        if let Some(parent) = before {
            self.map.keyframes[kf].parent = Some(parent);
            self.map.keyframes[parent].children.insert(kf);
        }
        let (older_than_point, older_than_keyframe) =
            self.detached.map_or((first_point, kf), |earlier| (earlier.older_than_point, earlier.older_than_keyframe));
        self.detached = Some(Detachment { first_keyframe: kf, older_than_point, older_than_keyframe });
        self.mapper.segment_begun(kf);
        // The segment's first keyframe is the clearest view of its place so far.
        self.texture_ratio = crate::frame::ViewTexture { contrast: 1.0, brightness_cv: 1.0 };
        self.velocity = None;
        self.last_coasted = false;
        self.unplaced_frames = 0;
        self.state = TrackingState::Uncertain;
        self.last_doubt = Some(Doubt::Detached);
        result.new_keyframe = Some(kf);
        result.new_segment = true;
        result.inliers = self.local_points.len();
        result.quality.method = PoseMethod::Prediction;
        result.quality.doubt = Some(Doubt::Detached);
        result.quality.inliers = result.inliers as u32;
    }

    /// Where the camera is at `t_ns` if it kept the motion it had at the last frame measured in its own images
    /// ([`bridge::carried_on`]); the last tracked pose when no record was measured; the identity before any.
    /// Allocates nothing once the scratch has held a window's records.
    pub(super) fn dead_reckoned(&mut self, t_ns: u64) -> Isometry3<f64> {
        let last_tracked =
            self.last_from_reference.map_or_else(Isometry3::identity, |(r, rel)| rel * self.map.keyframe_pose(r));
        let Some(last) = self.records.iter().rposition(|r| r.view.is_sound_measurement()) else { return last_tracked };
        // The window and a frame more: enough records for the motion at the last measured one.
        let t_last = self.records[last].t_ns;
        let first = self.records[..last]
            .iter()
            .rposition(|r| t_last.saturating_sub(r.t_ns) as f64 * 1e-9 > bridge::VELOCITY_WINDOW_S)
            .unwrap_or(0);
        let s = &mut self.reckoning;
        s.t_s.clear();
        s.poses.clear();
        s.views.clear();
        for r in &self.records[first..=last] {
            s.t_s.push(r.t_ns as f64 * 1e-9);
            s.poses.push(r.world_from_camera(&self.map));
            s.views.push(r.view);
        }
        bridge::carried_on(&s.t_s, &s.poses, &s.views, t_ns as f64 * 1e-9).map_or(last_tracked, |pose| pose.inverse())
    }

    /// The first keyframe of the detached segment the tracker is on (0 when it is not detached): the local map
    /// holds only keyframes from it on, since from the segment's guessed place what older keyframes show
    /// matches only by chance.
    pub(super) fn segment_start(&self) -> KfId {
        self.detached.map_or(0, |d| d.first_keyframe)
    }

    /// Whether the frame is still on a detached segment ([`Self::restart`]); ends the detachment when a loop has
    /// closed between the segment and the older map, or the frame's pose rests on [`TIED_BACK_INLIERS`] points
    /// made before the restart (map reuse found the older map).
    pub(super) fn still_detached(&mut self) -> bool {
        let Some(d) = self.detached else { return false };
        let older = (0..self.current.len())
            .filter(|&i| !self.current.outlier[i] && self.current.points[i].is_some_and(|p| p < d.older_than_point))
            .count();
        let across = |&(a, b): &(KfId, KfId)| a.min(b) < d.older_than_keyframe && a.max(b) >= d.first_keyframe;
        if self.mapper.loops_closed().iter().any(across) || older >= TIED_BACK_INLIERS {
            self.detached = None;
        }
        self.detached.is_some()
    }
}
