//! Pose corrections received but not applied yet. A depth keyframe says which correction generation the tracker
//! had reached when it made the keyframe; applying exactly those before inserting it makes the map's removal
//! decisions, and so the map, the same in every run, whatever the timing between the two topics — and the same
//! in every process that builds the map from the same topics (the mosaic service, the viewer's replica).

use std::collections::VecDeque;

use nalgebra::Isometry3;

use crate::Mosaic;

/// One correction as the tracker sent it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correction {
    pub kf_id: u64,
    /// Counts the run's corrections (orders them).
    pub generation: u64,
    /// None when what was sent is not a rigid pose.
    pub world_from_camera: Option<Isometry3<f64>>,
}

/// Why a correction was not applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RefusalKind {
    /// Its generation had been applied already when it arrived.
    Late,
    /// For a keyframe after the newest one made: no such keyframe exists.
    UnknownKeyframe,
    /// Not a rigid pose, or the map refused it.
    Pose,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Refusal {
    pub kind: RefusalKind,
    pub kf_id: u64,
    pub generation: u64,
    pub detail: String,
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.detail)
    }
}

#[derive(Debug, Default)]
pub struct PendingCorrections {
    queue: VecDeque<Correction>,
    /// Every correction up to this generation has been applied: the tracker sent them before the keyframe
    /// that said so, so one arriving now is late (or not the tracker's).
    applied_through: u64,
}

impl PendingCorrections {
    /// Queues a correction as it arrived (the tracker sends them in generation order), or refuses it when its
    /// generation has already been applied. Only what keyframes said moves that mark, so no correction can make
    /// later ones look stale.
    pub fn push(&mut self, correction: Correction) -> Result<(), Refusal> {
        if correction.generation <= self.applied_through {
            return Err(Refusal {
                kind: RefusalKind::Late,
                kf_id: correction.kf_id,
                generation: correction.generation,
                detail: format!(
                    "correction of keyframe {}: generation {} arrived after generation {} was applied",
                    correction.kf_id, correction.generation, self.applied_through
                ),
            });
        }
        self.queue.push_back(correction);
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
        mut refused: impl FnMut(Refusal),
    ) -> u64 {
        let mut applied = 0;
        if generation != u64::MAX {
            self.applied_through = self.applied_through.max(generation);
        }
        // In arrival order (the tracker's order), every queued correction up to `generation`: a correction from
        // the future at the front must not hold back those behind it.
        let mut kept = 0;
        for i in 0..self.queue.len() {
            let c = self.queue[i];
            if c.generation > generation {
                self.queue[kept] = c;
                kept += 1;
                continue;
            }
            let refusal = |kind, detail: String| Refusal { kind, kf_id: c.kf_id, generation: c.generation, detail };
            if newest_kf_id.is_none_or(|newest| c.kf_id > newest) {
                refused(refusal(
                    RefusalKind::UnknownKeyframe,
                    format!(
                        "correction of keyframe {} (generation {}): no such keyframe was made",
                        c.kf_id, c.generation
                    ),
                ));
                continue;
            }
            let outcome = c
                .world_from_camera
                .ok_or_else(|| "not a rigid pose".to_string())
                .and_then(|pose| mosaic.correct_pose(c.kf_id, pose).map_err(|e| e.to_string()));
            match outcome {
                Ok(_) => applied += 1,
                Err(why) => refused(refusal(RefusalKind::Pose, format!("correction of keyframe {}: {why}", c.kf_id))),
            }
        }
        self.queue.truncate(kept);
        applied
    }

    /// Corrections waiting for a keyframe made after them.
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{DepthKeyframe, MosaicParams};
    use bdis_core::calib::RectifiedCamera;
    use nalgebra::{Translation3, UnitQuaternion};

    fn correction(kf_id: u64, generation: u64, x: f64) -> Correction {
        Correction { kf_id, generation, world_from_camera: Some(Isometry3::translation(x, 0.0, 0.0)) }
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
        assert!(pending.is_empty());
        // Generation 2 was applied: one arriving now is late.
        assert_eq!(pending.push(correction(0, 2, 9.0)).unwrap_err().kind, RefusalKind::Late);
    }

    #[test]
    fn a_correction_that_is_not_a_rigid_pose_is_dropped_not_applied() {
        let mut mosaic = map_with_one_keyframe();
        let mut pending = PendingCorrections::default();
        pending.push(Correction { kf_id: 0, generation: 1, world_from_camera: None }).unwrap();
        pending.push(correction(0, 2, 5.0)).unwrap();
        // A keyframe after the newest the map has had was never made.
        pending.push(correction(1, 2, 6.0)).unwrap();
        let mut refused = Vec::new();
        assert_eq!(pending.apply_up_to(u64::MAX, Some(0), &mut mosaic, |r| refused.push(r.kind)), 1);
        assert_eq!(refused, [RefusalKind::Pose, RefusalKind::UnknownKeyframe]);
        let pose = mosaic.keyframes().next().unwrap().world_from_camera;
        assert_eq!(pose, Isometry3::from_parts(Translation3::new(5.0, 0.0, 0.0), UnitQuaternion::identity()));
    }
}
