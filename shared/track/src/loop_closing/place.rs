//! The places a loop can be closed to, and the check that a keyframe sees one of them again (ORB-SLAM2-STEREO.md
//! §8.1–§8.2, without a vocabulary as relocalisation does, §7.3 B).
//!
//! Candidates come from the map's geometry, not from a whole-map appearance search: the old keyframes the new
//! one looks at again by its tracked pose (see `loop_closing::revisited`). An appearance search over every
//! keyframe was tried first (descriptors hashed by a few of their bits, votes weighted by how rare a match is):
//! on the rendered tissue a descriptor finds a match within `TH_LOW` in almost every keyframe, so the true place
//! scored barely above the rest (60 against ≈ 45), and the search cost grew with the map (≈ 100 ms per keyframe
//! after 200 keyframes). A pose prior finds a loop as long as the drift is smaller than the view, which is what
//! map reuse relies on too; a vocabulary trained on tissue is the way past that (BENCHMARKS.md). The exception
//! is a detached segment, whose pose prior is a guess: its keyframes rank the older map's keyframes by
//! [`PlaceStore::votes`] (a ratio-tested match of a sample of its keypoints, not the hashed votes above) and
//! check the best few in 3-D.
//!
//! The check: the two keyframes' stereo keypoints matched by descriptor, then a 3-point RANSAC of their 3-D
//! points (both are stereo, so the loop is a rigid motion, SE(3), not Sim(3)).

use crate::frame::Scales;
use crate::geometry::{RectifiedCamera, draw_three, rigid_fit};
use crate::ids::KfId;
use crate::map::KeyFrame;
use crate::optim::CHI2_MONO;
use crate::search::ratio_match;
use nalgebra::{Isometry3, Point3};
use std::collections::BTreeMap;

/// ORB-SLAM2's thresholds of the loop's geometric check (§8.2): matches to try a solver, inliers to accept it.
pub const MIN_LOOP_MATCHES: usize = 20;
pub const MIN_LOOP_INLIERS: usize = 20;
const RANSAC_ITERATIONS: usize = 300;

/// What the index keeps of one keyframe: enough to verify a loop against it without the map.
#[derive(Debug, Clone, Default)]
pub struct PlaceEntry {
    pub descriptors: Vec<[u8; 32]>,
    /// Per keypoint: (x, y, octave).
    pub keypoints: Vec<(f32, f32, u8)>,
    /// Per keypoint: its stereo point in the keyframe's camera, when it has a depth.
    pub camera_points: Vec<Option<Point3<f64>>>,
}

impl PlaceEntry {
    /// What the index keeps of keyframe `k`: its descriptors, keypoints and stereo points.
    pub fn of_keyframe(k: &KeyFrame, cam: &RectifiedCamera) -> Self {
        Self {
            descriptors: k.descriptors.clone(),
            keypoints: k.keypoints.iter().map(|p| (p.x, p.y, p.octave)).collect(),
            camera_points: (0..k.keypoints.len())
                .map(|i| {
                    (k.depth[i] > 0.0).then(|| {
                        let p = &k.keypoints[i];
                        cam.unproject(f64::from(p.x), f64::from(p.y), f64::from(k.depth[i]))
                    })
                })
                .collect(),
        }
    }
}

/// The descriptors of `entry`'s stereo keypoints (those with a 3-D point), with their keypoint indices.
fn stereo_descriptors(entry: &PlaceEntry) -> impl Iterator<Item = (usize, &[u8; 32])> {
    entry.descriptors.iter().enumerate().filter(|&(j, _)| entry.camera_points[j].is_some())
}

/// A verified appearance match between two keyframes.
#[derive(Debug, Clone)]
pub struct PlaceMatch {
    pub candidate: KfId,
    /// The query's camera from the candidate's camera, from the inliers' 3-D points.
    pub query_from_candidate: Isometry3<f64>,
    /// (query keypoint, candidate keypoint) of the inliers.
    pub pairs: Vec<(usize, usize)>,
    /// When map reuse had already tied the query to the candidate ([`super::tied_in`]): the keyframes the query
    /// was tracked among, its side of the loop. Empty for a place found by the 3-D check.
    pub tied_side: Vec<KfId>,
}

/// What the loop worker keeps of every keyframe, by id.
#[derive(Debug)]
pub struct PlaceStore {
    entries: Vec<Option<PlaceEntry>>,
    ransac_state: u64,
}

impl Default for PlaceStore {
    fn default() -> Self {
        Self::new()
    }
}

impl PlaceStore {
    pub fn new() -> Self {
        Self { entries: Vec::new(), ransac_state: 0x0001_00bc_105e_5eed }
    }

    pub fn insert(&mut self, kf: KfId, entry: PlaceEntry) {
        if self.entries.len() <= kf {
            self.entries.resize(kf + 1, None);
        }
        self.entries[kf] = Some(entry);
    }

    /// Forgets a culled keyframe.
    pub fn remove(&mut self, kf: KfId) {
        if let Some(e) = self.entries.get_mut(kf) {
            *e = None;
        }
    }

    /// How much of `query` looks like `candidate`: of up to `sample` of the query's stereo keypoints (spread
    /// evenly over its list), those whose best match among the candidate's stereo keypoints is within `TH_LOW`
    /// and passes Lowe's ratio. A cheap ranking of many candidates before [`Self::verify`] checks the best.
    pub fn votes(&self, query: &PlaceEntry, candidate: KfId, sample: usize) -> usize {
        let Some(cand) = self.entries.get(candidate).and_then(Option::as_ref) else { return 0 };
        let stereo = query.camera_points.iter().filter(|p| p.is_some()).count();
        let stride = stereo.div_ceil(sample.max(1)).max(1);
        query
            .descriptors
            .iter()
            .zip(&query.camera_points)
            .filter(|(_, p)| p.is_some())
            .step_by(stride)
            .filter(|(d, _)| ratio_match(d, stereo_descriptors(cand)).is_some())
            .count()
    }

    /// The geometric check of a candidate (§8.2): the query's stereo keypoints matched to the candidate's by
    /// descriptor (≤ `TH_LOW`, Lowe's ratio, one to one), a 3-point RANSAC of their 3-D points, inliers by
    /// reprojection into both images at the keypoint's octave (χ² 2 DoF, 95 %), then the motion refitted to
    /// all inliers. `None` below ORB-SLAM2's 20 matches or 20 inliers.
    pub fn verify(
        &mut self,
        cam: &RectifiedCamera,
        scales: &Scales,
        query: &PlaceEntry,
        candidate: KfId,
    ) -> Option<PlaceMatch> {
        let cand = self.entries.get(candidate)?.as_ref()?;
        let mut pairs: Vec<(usize, usize)> = Vec::new();
        let mut claimed: BTreeMap<usize, (u32, usize)> = BTreeMap::new();
        for (i, d) in query.descriptors.iter().enumerate() {
            if query.camera_points[i].is_none() {
                continue;
            }
            let Some((j, distance)) = ratio_match(d, stereo_descriptors(cand)) else { continue };
            // One to one: the closer claim on a candidate keypoint wins.
            match claimed.get(&j) {
                Some(&(h, _)) if h <= distance => {}
                _ => {
                    claimed.insert(j, (distance, i));
                }
            }
        }
        for (&j, &(_, i)) in &claimed {
            pairs.push((i, j));
        }
        pairs.sort_unstable();
        if pairs.len() < MIN_LOOP_MATCHES {
            return None;
        }
        let src: Vec<Point3<f64>> = pairs.iter().filter_map(|&(_, j)| cand.camera_points[j]).collect();
        let dst: Vec<Point3<f64>> = pairs.iter().filter_map(|&(i, _)| query.camera_points[i]).collect();
        let inlier = |t: &Isometry3<f64>, k: usize| -> bool {
            let (i, j) = pairs[k];
            let gate = |pc: Point3<f64>, kp: (f32, f32, u8)| {
                if pc.z <= 0.0 {
                    return false;
                }
                let (u, v) = cam.project(&pc);
                let e2 = (u - f64::from(kp.0)).powi(2) + (v - f64::from(kp.1)).powi(2);
                e2 * scales.inv_sigma2[usize::from(kp.2)] < CHI2_MONO
            };
            gate(t * src[k], query.keypoints[i]) && gate(t.inverse() * dst[k], cand.keypoints[j])
        };
        let mut best: (usize, Option<Isometry3<f64>>) = (0, None);
        for _ in 0..RANSAC_ITERATIONS {
            let Some(pick) = draw_three(&mut self.ransac_state, pairs.len()) else { continue };
            let s: Vec<Point3<f64>> = pick.iter().map(|&k| src[k]).collect();
            let d: Vec<Point3<f64>> = pick.iter().map(|&k| dst[k]).collect();
            let Some(t) = rigid_fit(&s, &d) else { continue };
            let count = (0..pairs.len()).filter(|&k| inlier(&t, k)).count();
            if count > best.0 {
                best = (count, Some(t));
            }
        }
        let (count, Some(mut t)) = best else { return None };
        if count < MIN_LOOP_INLIERS {
            return None;
        }
        // Refit to every inlier, keep the refit when it keeps at least as many.
        let kept: Vec<usize> = (0..pairs.len()).filter(|&k| inlier(&t, k)).collect();
        let s: Vec<Point3<f64>> = kept.iter().map(|&k| src[k]).collect();
        let d: Vec<Point3<f64>> = kept.iter().map(|&k| dst[k]).collect();
        if let Some(refit) = rigid_fit(&s, &d)
            && (0..pairs.len()).filter(|&k| inlier(&refit, k)).count() >= kept.len()
        {
            t = refit;
        }
        let inliers: Vec<(usize, usize)> = (0..pairs.len()).filter(|&k| inlier(&t, k)).map(|k| pairs[k]).collect();
        (inliers.len() >= MIN_LOOP_INLIERS).then_some(PlaceMatch {
            candidate,
            query_from_candidate: t,
            pairs: inliers,
            tied_side: Vec::new(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn descriptor(seed: u64) -> [u8; 32] {
        let mut s = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15).wrapping_add(1);
        let mut d = [0u8; 32];
        for b in &mut d {
            s = s.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            *b = (s >> 56) as u8;
        }
        d
    }

    fn camera() -> RectifiedCamera {
        RectifiedCamera { width: 320, height: 240, fx: 260.0, fy: 260.0, cx: 159.5, cy: 119.5, bf: 1300.0 }
    }

    /// A keyframe seeing `points` (camera frame) with the descriptors `seeds`.
    fn entry(cam: &RectifiedCamera, points: &[Point3<f64>], seeds: &[u64]) -> PlaceEntry {
        PlaceEntry {
            descriptors: seeds.iter().map(|&s| descriptor(s)).collect(),
            keypoints: points
                .iter()
                .map(|p| {
                    let (u, v) = cam.project(p);
                    (u as f32, v as f32, 0)
                })
                .collect(),
            camera_points: points.iter().map(|p| Some(*p)).collect(),
        }
    }

    #[test]
    fn the_same_points_seen_from_elsewhere_give_the_motion_between_the_views() {
        let cam = camera();
        let scales = Scales::new(1.2, 8, 0);
        // 60 points on a wavy wall 60–70 mm in front of the old keyframe.
        let old_points: Vec<Point3<f64>> = (0..60)
            .map(|i| {
                let (x, y) = (f64::from(i % 10) * 5.0 - 22.0, f64::from(i / 10) * 5.0 - 12.0);
                Point3::new(x, y, 65.0 + 5.0 * (x * 0.2).sin())
            })
            .collect();
        let new_from_old = Isometry3::new(Vector3::new(2.0, -1.0, 1.5), Vector3::new(0.02, -0.03, 0.05));
        let new_points: Vec<Point3<f64>> = old_points.iter().map(|p| new_from_old * p).collect();
        let seeds: Vec<u64> = (0..60).collect();
        let mut store = PlaceStore::new();
        store.insert(3, entry(&cam, &old_points, &seeds));
        let query = entry(&cam, &new_points, &seeds);
        let found = store.verify(&cam, &scales, &query, 3).expect("a loop");
        assert_eq!(found.candidate, 3);
        assert!(found.pairs.len() >= 55, "{} inliers", found.pairs.len());
        let error = found.query_from_candidate.inverse() * new_from_old;
        assert!(error.translation.vector.norm() < 1e-6 && error.rotation.angle() < 1e-8, "{error}");
    }

    #[test]
    fn a_keyframe_with_other_descriptors_or_another_shape_is_no_loop() {
        let cam = camera();
        let scales = Scales::new(1.2, 8, 0);
        let points: Vec<Point3<f64>> = (0..60)
            .map(|i| Point3::new(f64::from(i % 10) * 5.0 - 22.0, f64::from(i / 10) * 5.0 - 12.0, 65.0))
            .collect();
        let seeds: Vec<u64> = (0..60).collect();
        let mut store = PlaceStore::new();
        store.insert(0, entry(&cam, &points, &seeds));
        // Other tissue: no descriptor in common.
        let other: Vec<u64> = (1000..1060).collect();
        assert!(store.verify(&cam, &scales, &entry(&cam, &points, &other), 0).is_none());
        // The same texture on another shape (the adversarial case: the descriptors match, the 3-D points do not
        // fit one rigid motion).
        let shuffled: Vec<Point3<f64>> = (0..60).map(|i| points[(i * 37) % 60]).collect();
        assert!(store.verify(&cam, &scales, &entry(&cam, &shuffled, &seeds), 0).is_none());
        // A culled keyframe is no candidate.
        store.remove(0);
        assert!(store.verify(&cam, &scales, &entry(&cam, &points, &seeds), 0).is_none());
    }
}
