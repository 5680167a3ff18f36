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
    /// Tracked, but the images do not support the pose well enough to trust it (`PoseRecord::doubt` says
    /// why): the pose is there, and no keyframe is made from it (unless the doubt is `MAP_MOVING`: the next
    /// keyframe's adjustment is what settles the map; `DETACHED`: its keyframes are what the new segment is
    /// tracked with; `PRIORLESS_FEW_INLIERS`: in a jerk the keyframe is what the next frames hold on to; or
    /// `LOW_CONTRAST`: a scope moving on under smoke keeps a map, with keyframes that are not published; or
    /// `HAZY`: a haze coming down, tracked as a clear view).
    pub const UNCERTAIN: u32 = 4;
}

/// Why a pose is `UNCERTAIN` or `LOST` ([`PoseRecord::doubt`]).
pub mod doubt {
    pub const NONE: u32 = 0;
    pub const FEW_INLIERS: u32 = 1;
    pub const LOW_INLIER_RATIO: u32 = 2;
    pub const ILL_CONDITIONED: u32 = 3;
    pub const APPEARANCE_DISAGREES: u32 = 4;
    pub const LOW_CONTRAST: u32 = 5;
    /// The map the frame was fitted to is still moving: the last local bundle adjustment moved its keyframe
    /// by more than 1 % of that keyframe's depth.
    pub const MAP_MOVING: u32 = 6;
    /// Tracked on a map segment begun after a loss in tissue relocalisation did not know: right relative to the
    /// segment, but the segment's place in the world is the motion before the loss carried on.
    pub const DETACHED: u32 = 7;
    /// Posed by appearance alone (no motion prior held: a jerk, a stop) on fewer than 50 inliers, the bar
    /// for a pose found without a prior.
    pub const PRIORLESS_FEW_INLIERS: u32 = 8;
    /// A frame lost because its motion-model pose kept under half the last frame's inliers and matching by
    /// appearance found nothing to confirm it: the view changed wholesale (frames dropped, a cut).
    pub const UNCONFIRMED: u32 = 9;
    /// The motion model's pose predicted from a frame doubted for its own estimate, with nothing by appearance
    /// to confirm it: the doubt carried over.
    pub const UNCONFIRMED_PRIOR: u32 = 10;
    /// The haze coming down: less texture contrast than clear footage keeps, not yet a veil. The haze shifts
    /// what it leaves; the frame is tracked as a clear one and its keyframes are published.
    pub const HAZY: u32 = 11;
    /// The highest code defined: what a consumer accepts (a new doubt moves it).
    pub const LAST: u32 = HAZY;

    /// The doubt's name as the tracker's quality log writes it (`few-inliers`, …; "" for none or an unknown
    /// code), for consumers that report it without linking the tracker.
    pub fn name(code: u32) -> &'static str {
        match code {
            FEW_INLIERS => "few-inliers",
            LOW_INLIER_RATIO => "low-inlier-ratio",
            ILL_CONDITIONED => "ill-conditioned",
            APPEARANCE_DISAGREES => "appearance-disagrees",
            LOW_CONTRAST => "low-contrast",
            MAP_MOVING => "map-moving",
            DETACHED => "detached",
            PRIORLESS_FEW_INLIERS => "priorless-few-inliers",
            UNCONFIRMED => "unconfirmed",
            UNCONFIRMED_PRIOR => "unconfirmed-prior",
            HAZY => "hazy",
            _ => "",
        }
    }
}

/// How a pose was first found ([`PoseRecord::method`]).
pub mod pose_method {
    pub const NONE: u32 = 0;
    pub const INITIALISATION: u32 = 1;
    pub const MOTION_MODEL: u32 = 2;
    pub const APPEARANCE: u32 = 3;
    pub const REFERENCE_PROJECTION: u32 = 4;
    pub const RELOCALISATION: u32 = 5;
    /// The motion model's prediction alone (a frame coasted through a veil), or as the seed of the local
    /// map's search in the frame after one.
    pub const PREDICTION: u32 = 6;
    /// The highest code defined: what a consumer accepts (a new method moves it).
    pub const LAST: u32 = PREDICTION;
}

/// One frame's pose and how well the images support it (`bdis.v2.PoseRecord`; v2 added the quality fields
/// from `matched` on and the `UNCERTAIN` state), fixed size.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v2.PoseRecord")]
pub struct PoseRecord {
    pub frame_seq: u64,
    /// CLOCK_MONOTONIC at capture (from the frame).
    pub t_capture_ns: u64,
    /// The frame's source timestamp (sequence time), ns.
    pub t_source_ns: u64,
    /// When the tracker published this record.
    pub t_publish_ns: u64,
    /// `world_from_camera` of the left camera: translation (x, y, z), quaternion (x, y, z, w); all zero when
    /// the state is neither OK nor UNCERTAIN.
    pub world_from_camera: [f64; 7],
    /// [`tracking_state`].
    pub state: u32,
    /// Inlier map points of the final pose optimisation.
    pub inliers: u32,
    /// The keyframe made from this frame and published on the keyframe topic, or `u64::MAX` (also for a
    /// keyframe made under a veil, which serves tracking only).
    pub new_keyframe: u64,
    /// CPU time the tracking thread spent on this frame, ns.
    pub cpu_ns: u64,
    /// Links to map points in the final pose optimisation (`inliers` of them held).
    pub matched: u32,
    /// [`doubt`]: why the state is not OK.
    pub doubt: u32,
    /// [`pose_method`].
    pub method: u32,
    /// 1 when the motion model's pose was replaced by the one from appearance (the prior was wrong).
    pub prior_rejected: u32,
    /// RMS of the inliers' left-image reprojection error, px (NaN without a pose).
    pub reprojection_rms_px: f64,
    /// The camera centre's standard deviation along its worst axis over the inliers' median depth (units-free).
    pub position_sigma_rel: f64,
    /// Of the matches by appearance (no prior) that agree with each other, the fraction the pose explains (NaN
    /// when not measured).
    pub appearance_agreement: f64,
}

/// The intrinsics of a rectified stereo keyframe as they travel in shared memory (`bdis.v1.StereoIntrinsics`):
/// the left camera's pinhole and `bf = fx · baseline`. The image size travels in the frame or depth layout.
/// [`bdis_core::RectifiedCamera`] is the same camera with its size.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v1.StereoIntrinsics")]
pub struct StereoIntrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// fx · baseline; depth = bf / disparity.
    pub bf: f64,
}

impl StereoIntrinsics {
    pub fn of(camera: &bdis_core::RectifiedCamera) -> Self {
        Self { fx: camera.fx, fy: camera.fy, cx: camera.cx, cy: camera.cy, bf: camera.bf }
    }

    /// The camera of a `width` × `height` image with these intrinsics.
    pub fn camera(&self, width: u32, height: u32) -> bdis_core::RectifiedCamera {
        bdis_core::RectifiedCamera { fx: self.fx, fy: self.fy, cx: self.cx, cy: self.cy, bf: self.bf, width, height }
    }
}

/// What a keyframe is, wherever it travels (`bdis.v1.KeyframeMeta`): carried by the tracker's
/// [`KeyframeHeader`] and by the stereo service's [`DepthHeader`](crate::DepthHeader), copied from one to the
/// other in one assignment.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v1.KeyframeMeta")]
pub struct KeyframeMeta {
    /// The keyframe's id in the run: consecutive from the tracker, never reused (a replacement stereo instance may
    /// publish a keyframe again; consumers de-duplicate by this id).
    pub kf_id: u64,
    /// `world_from_camera` of the left camera when the keyframe was made (later corrections arrive on the
    /// corrections topic): translation (x, y, z), quaternion (x, y, z, w). All zero (an invalid quaternion) when
    /// the pose is unknown (keyframes taken straight from acquisition's frames).
    pub world_from_camera: [f64; 7],
    pub intrinsics: StereoIntrinsics,
    /// The generation of the last pose correction the tracker had sent when it sent this keyframe
    /// ([`KeyframePose::generation`]). A consumer that applies exactly the corrections up to it before using the
    /// keyframe sees the same poses in every run, however the topics interleave. 0 without a tracker.
    pub corrections_generation: u64,
}

/// Header of a keyframe sample (`bdis.v3.KeyframeHeader`: v3 carries `bdis.v2.FrameHeader`): the frame's header (layout of the three images in
/// the payload, exactly as on the frames topic), then what the keyframe is.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v3.KeyframeHeader")]
pub struct KeyframeHeader {
    pub frame: FrameHeader,
    pub meta: KeyframeMeta,
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
