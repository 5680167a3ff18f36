//! The tracker's contracts: a pose per frame, keyframes with their stereo images, pose and intrinsics, and pose
//! corrections when bundle adjustment moves keyframes.

use crate::frame::FrameHeader;
use iceoryx2::prelude::*;

/// Tracking state of a [`PoseRecord`].
pub mod tracking_state {
    pub const NOT_INITIALIZED: u32 = 0;
    pub const OK: u32 = 1;
    pub const LOST: u32 = 2;
    /// The last record of a stream: no more poses will come.
    pub const END_OF_STREAM: u32 = 3;
}

/// One frame's pose (`bdis.v1.PoseRecord`), fixed size.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v1.PoseRecord")]
pub struct PoseRecord {
    pub frame_seq: u64,
    /// CLOCK_MONOTONIC at capture (from the frame).
    pub t_capture_ns: u64,
    /// The frame's source timestamp (sequence time), ns.
    pub t_source_ns: u64,
    /// When the tracker published this record.
    pub t_publish_ns: u64,
    /// `world_from_camera` of the left camera: translation (x, y, z), quaternion (x, y, z, w); all zero when
    /// the state is not OK.
    pub world_from_camera: [f64; 7],
    /// [`tracking_state`].
    pub state: u32,
    /// Inlier map points of the final pose optimisation.
    pub inliers: u32,
    /// The keyframe made from this frame, or `u64::MAX`.
    pub new_keyframe: u64,
    /// CPU time the tracking thread spent on this frame, ns.
    pub cpu_ns: u64,
}

/// Header of a keyframe sample (`bdis.v1.KeyframeHeader`): the frame's header (layout of the three images in
/// the payload, exactly as on the frames topic), then the keyframe's id, pose and intrinsics.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v1.KeyframeHeader")]
pub struct KeyframeHeader {
    pub frame: FrameHeader,
    pub kf_id: u64,
    /// `world_from_camera` when the keyframe was made (later corrections arrive on the corrections topic).
    pub world_from_camera: [f64; 7],
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub bf: f64,
    /// The generation of the last pose correction the tracker had sent when it sent this keyframe
    /// ([`KeyframePose::generation`]). A consumer that applies exactly the corrections up to it before using the
    /// keyframe sees the same poses in every run, however the two topics interleave.
    pub corrections_generation: u64,
}

/// A keyframe's corrected pose (`bdis.v1.KeyframePose`), fixed size.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v1.KeyframePose")]
pub struct KeyframePose {
    pub kf_id: u64,
    pub world_from_camera: [f64; 7],
    /// Counts the corrections of the run (orders them).
    pub generation: u64,
    /// 1 when the keyframe was removed from the map (its pose then follows its parent's).
    pub culled: u32,
    pub reserved: u32,
}

/// (tx, ty, tz, qx, qy, qz, qw) of a pose, the layout of every `world_from_camera` field.
pub fn pose_to_array(pose: &nalgebra::Isometry3<f64>) -> [f64; 7] {
    let t = pose.translation.vector;
    let q = pose.rotation.quaternion();
    [t.x, t.y, t.z, q.i, q.j, q.k, q.w]
}

/// The pose of a `world_from_camera` field, `None` when it is not a valid rigid transform (e.g. all zero).
pub fn pose_from_array(a: &[f64; 7]) -> Option<nalgebra::Isometry3<f64>> {
    bdis_core::geometry::pose_from_translation_quaternion([a[0], a[1], a[2]], [a[3], a[4], a[5], a[6]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_round_trip_through_the_array_layout() {
        let p =
            nalgebra::Isometry3::new(nalgebra::Vector3::new(1.0, -2.0, 3.5), nalgebra::Vector3::new(0.1, 0.2, -0.3));
        let back = pose_from_array(&pose_to_array(&p)).unwrap();
        assert!((back.translation.vector - p.translation.vector).norm() < 1e-15);
        assert!(back.rotation.angle_to(&p.rotation) < 1e-12);
        assert!(pose_from_array(&[0.0; 7]).is_none());
    }
}
