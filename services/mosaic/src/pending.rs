//! Pose corrections received but not applied yet. A depth keyframe says which correction generation the tracker
//! had reached when it made the keyframe; applying exactly those before inserting it makes the map's removal
//! decisions, and so the map, the same in every run, whatever the timing between the two topics.

use std::collections::VecDeque;

use bdis_ipc::KeyframePose;
use bdis_ipc::track::pose_from_array;
use bdis_ipc::validate::{Reason, Rejection};
use bdis_mosaic::Mosaic;

#[derive(Debug, Default)]
pub struct PendingCorrections {
    queue: VecDeque<KeyframePose>,
    /// Every correction up to this generation has been applied: the tracker sent them before the keyframe
    /// that said so, so one arriving now is late (or not the tracker's).
    applied_through: u64,
}

impl PendingCorrections {
    /// A correction as it arrived (the tracker sends them in generation order).
    /// Queues a correction, or refuses it when its generation has already been applied. Only what keyframes
    /// said moves that mark, so no correction can make later ones look stale.
    pub fn push(&mut self, record: KeyframePose) -> Result<(), Rejection> {
        if record.generation <= self.applied_through {
            return Err(Rejection::new(
                Reason::StaleId,
                record.generation,
                format!(
                    "correction of keyframe {}: generation {} arrived after generation {} was applied",
                    record.kf_id, record.generation, self.applied_through
                ),
            ));
        }
        self.queue.push_back(record);
        Ok(())
    }

    /// Applies the corrections up to `generation` (all of them with `u64::MAX`); returns how many moved a
    /// keyframe's pose. A correction concerns a keyframe the tracker had made before it, so one for a keyframe
    /// after `newest_kf_id` (the keyframe about to be inserted, or the newest the map has had) never existed: it
    /// is refused through `refused`, as is one that is not a rigid pose.
    pub fn apply_up_to(
        &mut self,
        generation: u64,
        newest_kf_id: Option<u64>,
        mosaic: &mut Mosaic,
        mut refused: impl FnMut(Rejection),
    ) -> u64 {
        let mut applied = 0;
        if generation != u64::MAX {
            self.applied_through = self.applied_through.max(generation);
        }
        // In arrival order (the tracker's order), every queued correction up to `generation`: a correction from
        // the future at the front must not hold back those behind it.
        let mut kept = 0;
        for i in 0..self.queue.len() {
            let record = self.queue[i];
            if record.generation > generation {
                self.queue[kept] = record;
                kept += 1;
                continue;
            }
            if newest_kf_id.is_none_or(|newest| record.kf_id > newest) {
                refused(Rejection::new(
                    Reason::UnknownKeyframe,
                    record.kf_id,
                    format!(
                        "correction of keyframe {} (generation {}): no such keyframe was made",
                        record.kf_id, record.generation
                    ),
                ));
                continue;
            }
            let outcome = pose_from_array(&record.world_from_camera)
                .ok_or_else(|| "not a rigid pose".to_string())
                .and_then(|pose| mosaic.correct_pose(record.kf_id, pose).map_err(|e| e.to_string()));
            match outcome {
                Ok(_) => applied += 1,
                Err(why) => refused(Rejection::new(
                    Reason::Pose,
                    record.kf_id,
                    format!("correction of keyframe {}: {why}", record.kf_id),
                )),
            }
        }
        self.queue.truncate(kept);
        applied
    }

    #[cfg(test)]
    pub fn len(&self) -> usize {
        self.queue.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bdis_mosaic::{DepthKeyframe, MosaicParams, RectifiedCamera};
    use nalgebra::{Isometry3, Translation3, UnitQuaternion};

    fn correction(kf_id: u64, generation: u64, x: f64) -> KeyframePose {
        KeyframePose { kf_id, world_from_camera: [x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], generation, culled: 0, reserved: 0 }
    }

    /// A map with keyframe 0: a flat patch 50 units in front of the camera.
    fn map_with_one_keyframe() -> Mosaic {
        let (w, h) = (16u32, 12u32);
        let n = (w * h) as usize;
        let disparity = vec![20.0f32; n];
        let confidence = vec![1.0f32; n];
        let rgb = vec![128u8; 3 * n];
        let mut mosaic = Mosaic::new(MosaicParams::default());
        let kf = DepthKeyframe {
            kf_id: 0,
            t_capture_ns: 0,
            world_from_camera: Isometry3::identity(),
            intrinsics: RectifiedCamera { fx: 20.0, fy: 20.0, cx: 8.0, cy: 6.0, bf: 1000.0, width: w, height: h },
            disparity: &disparity,
            confidence: &confidence,
            rgb: &rgb,
        };
        mosaic.insert(&kf).unwrap();
        mosaic
    }

    #[test]
    fn corrections_apply_up_to_the_keyframes_generation_in_order() {
        let mut mosaic = map_with_one_keyframe();
        let mut pending = PendingCorrections::default();
        for (generation, x) in [(1, 1.0), (2, 2.0), (3, 3.0)] {
            pending.push(correction(0, generation, x)).unwrap();
        }
        assert_eq!(pending.apply_up_to(2, Some(0), &mut mosaic, |r| panic!("{r}")), 2);
        assert_eq!(pending.len(), 1, "generation 3 waits for a keyframe made after it");
        let x = mosaic.keyframes().next().unwrap().world_from_camera.translation.x;
        assert_eq!(x, 2.0, "the last applied correction wins");
        assert_eq!(pending.apply_up_to(u64::MAX, Some(0), &mut mosaic, |r| panic!("{r}")), 1);
        assert_eq!(pending.len(), 0);
    }

    #[test]
    fn a_correction_that_is_not_a_rigid_pose_is_dropped_not_applied() {
        let mut mosaic = map_with_one_keyframe();
        let mut pending = PendingCorrections::default();
        let mut bad = correction(0, 1, 0.0);
        bad.world_from_camera = [0.0; 7];
        pending.push(bad).unwrap();
        let mut nan = correction(0, 1, f64::NAN);
        nan.world_from_camera[6] = 1.0;
        pending.push(nan).unwrap();
        pending.push(correction(0, 2, 5.0)).unwrap();
        // A keyframe after the newest the map has had was never made.
        pending.push(correction(1, 2, 6.0)).unwrap();
        let mut refused = Vec::new();
        assert_eq!(pending.apply_up_to(u64::MAX, Some(0), &mut mosaic, |r| refused.push(r.reason)), 1);
        assert_eq!(refused, [Reason::Pose, Reason::Pose, Reason::UnknownKeyframe]);
        let pose = mosaic.keyframes().next().unwrap().world_from_camera;
        assert_eq!(pose, Isometry3::from_parts(Translation3::new(5.0, 0.0, 0.0), UnitQuaternion::identity()));
    }
}
