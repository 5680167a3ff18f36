//! The overlap rule again after corrections (issue #17). The rule — a newer view replaces the earlier points it
//! sees again, and an earlier view's free space removes newer points it saw through — runs when a keyframe is
//! inserted, with the poses of that moment. A loop correction then moves one pass over the tissue onto the
//! other: points that looked occluded (behind the newer surface, so kept) now agree with it, and the corrected
//! map would keep two surfaces where the passes overlap. So every keyframe remembers the pose the rule last ran
//! at; when corrections have moved one far enough to change the rule's answers, the rule runs again between it
//! and every keyframe it overlaps, with the current poses.

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use crate::{Frustum, Mosaic, MosaicParams};

/// What the overlap rule says about an earlier point that projects onto a new view's depth `z_new`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Verdict {
    /// Behind the new surface by more than the tolerance: hidden by it, not contradicted. Kept.
    Occluded,
    /// Agrees with the new surface but was seen from closer (less depth error). Kept; the new view adds nothing
    /// in its cell.
    SeenCloser,
    /// Replaced by the new surface: it agrees with it (and may be folded into it) or lies in front of it.
    Replaced { agrees: bool },
}

/// The depth test of the overlap rule: the tolerance is a share of the depth plus the depth error of a disparity
/// error in either view, so it means the same in millimetres and in metres.
#[derive(Debug, Clone, Copy)]
pub(crate) struct DepthTest {
    depth_share: f32,
    disp_tol: f32,
    bf: f32,
    keep_closer: f32,
}

impl DepthTest {
    /// `p`: the parameters at the new view's size ([`MosaicParams::for_size`]); `bf` of the new view.
    pub(crate) fn new(p: &MosaicParams, bf: f64) -> Self {
        Self {
            depth_share: p.depth_tolerance_ratio as f32,
            disp_tol: p.disparity_tolerance_px as f32,
            bf: bf as f32,
            keep_closer: p.keep_closer_ratio,
        }
    }

    /// `z_in_new`: the earlier point's depth in the new view; `z_own`: its depth in the view it came from.
    pub(crate) fn verdict(&self, z_in_new: f32, z_new: f32, z_own: f32) -> Verdict {
        let tolerance = self.depth_share * z_new.max(z_own) + self.disp_tol * (z_new * z_new + z_own * z_own) / self.bf;
        if z_in_new > z_new + tolerance {
            return Verdict::Occluded;
        }
        let agrees = (z_in_new - z_new).abs() <= tolerance;
        if agrees && z_own < self.keep_closer * z_new {
            return Verdict::SeenCloser;
        }
        Verdict::Replaced { agrees }
    }
}

/// What re-running the overlap rule did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Realigned {
    /// Keyframes that corrections had moved far enough for the rule to run again.
    pub keyframes_moved: usize,
    /// Earlier points a newer overlapping view now replaces (the second surface of a corrected loop).
    pub removed: usize,
    /// Newer points an earlier overlapping view now sees through.
    pub seen_through: usize,
}

/// How far, in pixels of the keyframe's own image, going from pose `placed` to `current` moves the corners of its
/// points' bounds (their displacement seen from the keyframe at their depth).
fn shift_px(placed: &Isometry3<f64>, current: &Isometry3<f64>, lo: [f32; 3], hi: [f32; 3], fx: f64) -> f64 {
    let placed_from_current = placed.inverse() * current;
    let mut worst = 0.0f64;
    for corner in 0..8 {
        let pick = |k: usize| f64::from(if corner & (1 << k) == 0 { lo[k] } else { hi[k] });
        let c = Point3::new(pick(0), pick(1), pick(2));
        // Points have positive depth; a corner at or behind the camera bounds nothing seen.
        if c.z <= 0.0 {
            continue;
        }
        worst = worst.max(fx * (placed_from_current * c - c).norm() / c.z);
    }
    worst
}

impl Mosaic {
    /// Runs the overlap rule again between every keyframe that corrections moved by more than
    /// `disparity_tolerance_px` (in its own image) since the rule last ran on it and every keyframe it overlaps,
    /// with the current poses: the older of each pair loses the points the newer one now sees again, the newer
    /// loses those the older saw through. Points are removed, never fused (the newer view's point of the cell was
    /// made already). Deterministic: pairs in id order. Cheap when nothing moved (one bounds check per keyframe);
    /// [`Mosaic::insert`] calls it first, and whoever applies the last corrections of a run calls it before
    /// writing the map.
    pub fn realign(&mut self) -> Realigned {
        let mut report = Realigned::default();
        self.moved.clear();
        for kf in self.keyframes.values() {
            // A keyframe restored from a saved map has no view kept (the map was realigned when it was written).
            let Some(seen) = self.seen.get(&kf.kf_id) else { continue };
            let placed = &seen.ruled_at;
            if kf.points.is_empty() || *placed == kf.world_from_camera {
                continue;
            }
            let p = self.params.for_size(kf.intrinsics.width as usize, kf.intrinsics.height as usize);
            let shift = shift_px(placed, &kf.world_from_camera, kf.bounds_min, kf.bounds_max, kf.intrinsics.fx);
            if shift > p.disparity_tolerance_px {
                self.moved.push(kf.kf_id);
            }
        }
        if self.moved.is_empty() {
            return report;
        }
        report.keyframes_moved = self.moved.len();
        self.ids.clear();
        self.ids.extend(self.keyframes.keys().copied());
        // Every pair with a moved keyframe in it, by newer then older id: a moved newer one against every older
        // keyframe, any other against the moved older ones only (`moved` is in id order) — so the work grows with
        // what moved times the map, as an insertion's does, not with the map squared.
        for newer_at in 1..self.ids.len() {
            let newer = self.ids[newer_at];
            if self.moved.binary_search(&newer).is_ok() {
                for older_at in 0..newer_at {
                    self.realign_pair(self.ids[older_at], newer, &mut report);
                }
            } else {
                for moved_at in 0..self.moved.len() {
                    let older = self.moved[moved_at];
                    if older >= newer {
                        break;
                    }
                    self.realign_pair(older, newer, &mut report);
                }
            }
        }
        for &kf_id in &self.moved {
            if let (Some(kf), Some(seen)) = (self.keyframes.get(&kf_id), self.seen.get_mut(&kf_id)) {
                seen.ruled_at = kf.world_from_camera;
            }
        }
        report
    }

    /// The overlap rule between keyframes `older` and `newer` with their current poses.
    fn realign_pair(&mut self, older: u64, newer: u64, report: &mut Realigned) {
        let (Some(new_kf), Some(old_kf)) = (self.keyframes.get(&newer), self.keyframes.get(&older)) else { return };
        let Some((centre_world, radius)) = old_kf.bounding_sphere_world() else { return };
        let camera_from_world = new_kf.world_from_camera.inverse();
        if !Frustum::new(&new_kf.intrinsics).may_contain(&(camera_from_world * centre_world), radius) {
            return;
        }
        let (world_from_new, world_from_old) = (new_kf.world_from_camera, old_kf.world_from_camera);
        let k_new = new_kf.intrinsics;
        let k_old = old_kf.intrinsics;
        // The older points the newer view sees again.
        if let (Some(seen_new), Some(old_kf)) = (self.seen.get(&newer), self.keyframes.get_mut(&older)) {
            let p = self.params.for_size(k_new.width as usize, k_new.height as usize);
            let test = DepthTest::new(&p, k_new.bf);
            let new_from_old = camera_from_world * world_from_old;
            let rotation: Matrix3<f32> = new_from_old.rotation.to_rotation_matrix().matrix().cast();
            let translation: Vector3<f32> = new_from_old.translation.vector.cast();
            let (fx, fy, cx, cy) = (k_new.fx as f32, k_new.fy as f32, k_new.cx as f32, k_new.cy as f32);
            let before = old_kf.points.len();
            old_kf.points.retain(|pt| {
                let q = rotation * Vector3::from(pt.xyz) + translation;
                if q.z <= 0.0 {
                    return true;
                }
                // The nearest of the four samples around it: an earlier point by a depth edge is judged against the
                // surface in front, so it is kept unless it agrees with that or lies in front of it.
                let z_new = seen_new.nearest_of_four(fx * q.x / q.z + cx, fy * q.y / q.z + cy);
                !z_new.is_finite() || !matches!(test.verdict(q.z, z_new, pt.xyz[2]), Verdict::Replaced { .. })
            });
            let removed = before - old_kf.points.len();
            if removed > 0 {
                old_kf.update_bounds();
                report.removed += removed;
            }
        }
        // The newer points the older view saw through.
        let carve_px = self.params.for_size(k_old.width as usize, k_old.height as usize).carve_disparity_px;
        if carve_px > 0.0
            && let (Some(seen_old), Some(new_kf)) = (self.seen.get(&older), self.keyframes.get_mut(&newer))
        {
            let carved =
                seen_old.carve(&mut new_kf.points, |pt| pt.xyz, &world_from_new, &world_from_old, &k_old, carve_px);
            if carved > 0 {
                new_kf.update_bounds();
                report.seen_through += carved;
            }
        }
    }
}
