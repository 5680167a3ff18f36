//! Per frame, what the written trajectory is rebuilt from once the map has settled: the frame's pose relative to
//! the keyframes whose points it was tracked on.

use super::{Tracker, bridge};
use crate::map::{KfId, Map};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// How many keyframes a frame's written pose follows.
pub(super) const ANCHORS: usize = 3;

/// A keyframe a frame's written pose follows: its id, how many of the frame's inlier points it observes, and
/// the frame's pose relative to it when the frame was tracked.
#[derive(Debug, Clone, Copy)]
pub(super) struct Anchor {
    pub kf: KfId,
    pub shared_points: u32,
    pub camera_from_kf: Isometry3<f64>,
}

/// Per frame, for the trajectory (§5.1 step 7, widened): ORB-SLAM2 rebuilds a frame's pose from its reference
/// keyframe's final pose alone. When bundle adjustment later moves that one keyframe against its neighbours (a
/// keyframe made in haze, whose own pose the haze had shifted), every frame referred to it moves with it though
/// it was located on the points of several. Here the frame follows each keyframe whose points it was tracked
/// on, in proportion to the points it shares with it: where the keyframes moved together, the same pose as
/// ORB-SLAM2's.
#[derive(Debug, Clone, Copy)]
pub(super) struct FrameRecord {
    pub t_ns: u64,
    /// The reference keyframe first; unused slots share no point.
    pub anchors: [Anchor; ANCHORS],
    /// How the frame was seen, for the veil's bridge ([`bridge::View`]).
    pub view: bridge::View,
}

impl FrameRecord {
    /// The frame's world_from_camera from its keyframes' current poses: their shared-point-weighted mean, taken
    /// as small motions from the reference keyframe's (they differ by what bundle adjustment moved since).
    pub fn world_from_camera(&self, map: &Map) -> Isometry3<f64> {
        let via = |a: &Anchor| a.camera_from_kf * map.keyframe_pose(a.kf);
        let base = via(&self.anchors[0]);
        // The reference's own motion from `base` is none: it weighs in the total only (and alone, it gives
        // `base` to the bit).
        let (mut axis, mut shift, mut others) = (Vector3::zeros(), Vector3::zeros(), 0.0);
        for a in self.anchors[1..].iter().filter(|a| a.shared_points > 0) {
            let w = f64::from(a.shared_points);
            let delta = via(a) * base.inverse();
            axis += delta.rotation.scaled_axis() * w;
            shift += delta.translation.vector * w;
            others += w;
        }
        if others == 0.0 {
            return base.inverse();
        }
        let total = others + f64::from(self.anchors[0].shared_points);
        let mean =
            Isometry3::from_parts(Translation3::from(shift / total), UnitQuaternion::from_scaled_axis(axis / total));
        (mean * base).inverse()
    }

    /// The same record carried on by `motion` (a lost frame: the last motion continued).
    pub fn moved(&self, t_ns: u64, motion: Isometry3<f64>) -> Self {
        let mut r = *self;
        r.t_ns = t_ns;
        r.view = bridge::View::Lost;
        for a in &mut r.anchors {
            a.camera_from_kf = motion * a.camera_from_kf;
        }
        r
    }
}

impl Tracker {
    /// The anchors of the current frame (posed at `camera_from_world`): the reference keyframe, then the
    /// keyframes observing most of its inlier points. Allocates nothing once the vote buffers have grown.
    pub(super) fn anchors(&mut self, reference: KfId, camera_from_world: Isometry3<f64>) -> [Anchor; ANCHORS] {
        self.vote_keyframes(true);
        let relative = |k: KfId| camera_from_world * self.map.keyframes[k].camera_from_world.inverse();
        let none = Anchor { kf: reference, shared_points: 0, camera_from_kf: relative(reference) };
        let mut anchors = [none; ANCHORS];
        anchors[0].shared_points = self.kf_votes[reference].max(1);
        let own = self.map.keyframes[reference].frame_id == self.current.id;
        // The best-voted others, ties to the older keyframe (deterministic).
        for slot in (1..ANCHORS).filter(|_| !own) {
            let votes = &self.kf_votes;
            let taken = |k: KfId| anchors[..slot].iter().any(|a| a.kf == k && a.shared_points > 0);
            let best = self
                .voters
                .iter()
                .copied()
                .filter(|&k| !self.map.keyframes[k].bad && !taken(k))
                .max_by_key(|&k| (votes[k], std::cmp::Reverse(k)));
            let Some(k) = best else { break };
            anchors[slot] = Anchor { kf: k, shared_points: votes[k], camera_from_kf: relative(k) };
        }
        for &k in &self.voters {
            self.kf_votes[k] = 0;
        }
        anchors
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::tests::keyframe;
    use nalgebra::Point3;

    fn centre(world_from_camera: Isometry3<f64>) -> Point3<f64> {
        world_from_camera * Point3::origin()
    }

    #[test]
    fn a_frame_follows_its_keyframes_in_proportion_to_the_points_it_shares_with_them() {
        // The frame was tracked 1 m ahead (+z) of keyframes 0 and 1, both at the origin then; it shares 300
        // points with keyframe 0, 100 with keyframe 1.
        let mut map = Map { keyframes: vec![keyframe(0, None, false), keyframe(1, None, false)], ..Default::default() };
        let camera_from_kf = Isometry3::translation(0.0, 0.0, -1.0);
        let anchor = |kf, shared_points| Anchor { kf, shared_points, camera_from_kf };
        let record =
            FrameRecord { t_ns: 0, anchors: [anchor(0, 300), anchor(1, 100), anchor(0, 0)], view: bridge::View::Clear };
        assert!((centre(record.world_from_camera(&map)) - Point3::new(0.0, 0.0, 1.0)).norm() < 1e-12);
        // Bundle adjustment moves keyframe 1 by 4 cm sideways: a quarter of that moves the frame.
        map.keyframes[1].camera_from_world = Isometry3::translation(-0.04, 0.0, 0.0);
        assert!((centre(record.world_from_camera(&map)) - Point3::new(0.01, 0.0, 1.0)).norm() < 1e-12);
        // ... or turns it: the frame turns by a quarter of the angle.
        let turn = UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.02, 0.0));
        map.keyframes[1].camera_from_world = Isometry3::from_parts(Translation3::identity(), turn);
        let turned = record.world_from_camera(&map).rotation.scaled_axis();
        assert!((turned - Vector3::new(0.0, -0.005, 0.0)).norm() < 1e-12, "{turned}");
        // Sharing points with its reference alone, exactly ORB-SLAM2's re-expression through that keyframe.
        let alone = FrameRecord { anchors: [anchor(1, 1), anchor(0, 0), anchor(0, 0)], ..record };
        assert_eq!(alone.world_from_camera(&map), (camera_from_kf * map.keyframe_pose(1)).inverse());
    }
}
