//! The map's rule for when pose corrections apply is `bdis_mosaic::pending` (the viewer's replica of the map
//! follows the same rule); here, the bridge from the corrections topic's records and to telemetry's rejections.

use bdis_ipc::KeyframePose;
use bdis_ipc::validate::{Reason, Rejection};
use bdis_mosaic::pending::{Correction, Refusal, RefusalKind};
use nalgebra::Isometry3;

/// A record of the corrections topic, checked (its pose is `pose`).
pub fn correction(record: &KeyframePose, pose: Isometry3<f64>) -> Correction {
    Correction { kf_id: record.kf_id, generation: record.generation, world_from_camera: Some(pose) }
}

/// A correction the map did not take, as telemetry reports it.
pub fn rejection(refusal: Refusal) -> Rejection {
    let (reason, id) = match refusal.kind {
        RefusalKind::Late => (Reason::StaleId, refusal.generation),
        RefusalKind::UnknownKeyframe => (Reason::UnknownKeyframe, refusal.kf_id),
        RefusalKind::Pose => (Reason::Pose, refusal.kf_id),
    };
    Rejection::new(reason, id, refusal.detail)
}
