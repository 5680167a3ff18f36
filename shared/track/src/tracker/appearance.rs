//! Tracking by appearance: the current frame matched to a keyframe by descriptors alone, with no pose prior
//! (what ORB-SLAM2's TrackReferenceKeyFrame does with its vocabulary, §5.4; here by brute force, §7.3 B), then a
//! pose from those matches by a 3-point RANSAC on the frame's stereo points and the pose-only optimisation.
//!
//! Why no prior: a projection search centred on a predicted pose finds the matches near the prediction, so a
//! wrong prediction (the start, when the camera is already moving; a jerk, a stop, a turn) returns a biased
//! subset — typically the far points, which barely move — and the optimised pose follows them. Matching by
//! appearance finds the same points wherever they moved to.
//!
//! Cost: every stereo keypoint of the frame against every point of the keyframe, 32-byte Hamming distances
//! (≈ 1 M for 1000 × 1000), measured in BENCHMARKS.md; the buffers are the tracker's and reused.

use super::*;
use crate::optim::{CHI2_STEREO, Observation, chi2};

/// The Lowe ratio of the brute-force matching (best < ratio · second best): ORB-SLAM2's value for tracking the
/// reference keyframe.
const RATIO: f64 = 0.8;
/// Fewest matches worth a RANSAC: three per hypothesis, and enough beyond them that a consensus means something.
const MIN_MATCHES: usize = 15;
/// RANSAC stops when a better hypothesis would be found with less than this probability.
const RANSAC_CONFIDENCE: f64 = 0.999;
const RANSAC_MAX_ITERATIONS: usize = 300;

/// Reusable buffers of appearance matching (owned by the tracker, so a warmed-up frame allocates nothing).
#[derive(Debug)]
pub(super) struct AppearanceScratch {
    /// The keyframe's usable points and, beside them, their descriptors and the keypoint they were matched at.
    points: Vec<(PointId, usize)>,
    descriptors: Vec<[u8; 32]>,
    /// Per keyframe point: the best claim (distance, frame keypoint), so each point goes to one keypoint.
    claims: Vec<(u32, u32)>,
    /// Distances from one keypoint's descriptor to every point's.
    distances: Vec<u32>,
    /// (frame keypoint, point, stereo point in the camera, the point in the world, the observation).
    matches: Vec<Match>,
    rejected: Vec<u32>,
    inlier: Vec<bool>,
    best_inlier: Vec<bool>,
}

impl AppearanceScratch {
    /// Room for a keyframe of `features` keypoints (twice, as the extractor may return a few more than asked):
    /// a keyframe with more points than the last one then grows nothing.
    pub(super) fn with_capacity(features: usize) -> Self {
        let n = 2 * features.max(1);
        Self {
            points: Vec::with_capacity(n),
            descriptors: Vec::with_capacity(n),
            claims: Vec::with_capacity(n),
            distances: Vec::with_capacity(n),
            matches: Vec::with_capacity(n),
            rejected: Vec::with_capacity(n),
            inlier: Vec::with_capacity(n),
            best_inlier: Vec::with_capacity(n),
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Match {
    keypoint: usize,
    point: PointId,
    camera: Point3<f64>,
    world: Point3<f64>,
    obs: Observation,
}

/// What appearance tracking found: the pose and its support, before and after the pose optimisation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AppearanceFix {
    /// Matches by descriptor that passed the ratio and rotation tests.
    pub matches: usize,
    /// Of them, consistent with the best RANSAC hypothesis.
    pub consensus: usize,
    /// The hypothesis (three matches' absolute orientation).
    pub pose: CameraFromWorld,
}

impl Tracker {
    /// Poses the current frame from the last [`Self::appearance_consensus`]: its hypothesis, its matches as links
    /// (the RANSAC outliers marked so the optimisation starts without them; they may come back if the refined
    /// pose explains them), then the pose-only optimisation.
    pub(super) fn adopt_appearance(&mut self, fix: AppearanceFix) -> Option<AppearanceFix> {
        self.current.points.fill(None);
        self.current.outlier.fill(false);
        self.current.camera_from_world = Some(fix.pose);
        let s = &self.appearance;
        for (m, &inlier) in s.matches.iter().zip(&s.best_inlier) {
            self.current.points[m.keypoint] = Some(m.point);
            self.current.outlier[m.keypoint] = !inlier;
        }
        self.optimise_current();
        if self.drop_outliers() >= 10 {
            return Some(fix);
        }
        // The optimisation over these few matches slid off the hypothesis and kept fewer of them than it
        // explained (a jerk's coarse-octave matches pull it): the hypothesis, with its consensus, is the better
        // start. The local map's search and its inlier count then judge it, as they judge any appearance pose.
        self.current.camera_from_world = Some(fix.pose);
        let s = &self.appearance;
        for (m, &inlier) in s.matches.iter().zip(&s.best_inlier) {
            self.current.points[m.keypoint] = inlier.then_some(m.point);
            self.current.outlier[m.keypoint] = false;
        }
        Some(fix)
    }

    /// Of the last appearance consensus, the fraction that `pose` explains too (χ² of a stereo observation at
    /// 95 %): near 1 when `pose` is where the images say the camera is, low when it is somewhere else.
    pub(super) fn appearance_agreement(&self, pose: &CameraFromWorld) -> f64 {
        let s = &self.appearance;
        let (mut consensus, mut explained) = (0usize, 0usize);
        for (m, &inlier) in s.matches.iter().zip(&s.best_inlier) {
            if inlier {
                consensus += 1;
                explained += usize::from(chi2(&self.cam, pose, &m.world, &m.obs) < CHI2_STEREO);
            }
        }
        if consensus == 0 { f64::NAN } else { explained as f64 / consensus as f64 }
    }

    /// The descriptor matches of the current frame's stereo keypoints to `kf`'s points and the best 3-point
    /// hypothesis (`appearance.best_inlier` marks its consensus). The frame is left as it was.
    pub(super) fn appearance_consensus(&mut self, kf: KfId) -> Option<AppearanceFix> {
        self.match_by_appearance(kf);
        let n = self.appearance.matches.len();
        let s = &mut self.appearance;
        s.inlier.clear();
        s.inlier.resize(n, false);
        s.best_inlier.clear();
        s.best_inlier.resize(n, false);
        if n < MIN_MATCHES {
            return None;
        }
        let mut best: (usize, Option<CameraFromWorld>) = (0, None);
        let mut needed = RANSAC_MAX_ITERATIONS;
        let mut iteration = 0;
        while iteration < needed {
            iteration += 1;
            let Some(pick) = draw_three(&mut self.ransac_state, n) else { continue };
            let src = pick.map(|k| s.matches[k].world);
            let dst = pick.map(|k| s.matches[k].camera);
            let Some(t) = rigid_fit(&src, &dst) else { continue };
            let mut count = 0;
            for (m, inlier) in s.matches.iter().zip(s.inlier.iter_mut()) {
                *inlier = chi2(&self.cam, &t, &m.world, &m.obs) < CHI2_STEREO;
                count += usize::from(*inlier);
            }
            if count > best.0 {
                best = (count, Some(t));
                s.best_inlier.copy_from_slice(&s.inlier);
                // Adaptive stopping: enough draws that an all-inlier triple would have come up.
                let w = count as f64 / n as f64;
                let p_good = w * w * w;
                needed = if p_good >= 1.0 {
                    iteration
                } else {
                    let k = (1.0 - RANSAC_CONFIDENCE).ln() / (1.0 - p_good).ln();
                    (k.ceil() as usize).clamp(iteration, RANSAC_MAX_ITERATIONS)
                };
            }
        }
        let (consensus, Some(pose)) = best else { return None };
        if consensus < 10 {
            s.best_inlier.fill(false);
            return None;
        }
        Some(AppearanceFix { matches: n, consensus, pose })
    }

    /// Fills `appearance.matches`: each stereo keypoint of the frame to its nearest point of `kf` by descriptor
    /// (≤ TH_HIGH, < RATIO of the second nearest), one keypoint per point (the nearest), then the rotation test.
    fn match_by_appearance(&mut self, kf: KfId) {
        let s = &mut self.appearance;
        s.points.clear();
        s.descriptors.clear();
        s.matches.clear();
        let keyframe = &self.map.keyframes[kf];
        for (i, p) in keyframe.points.iter().enumerate() {
            let Some(p) = *p else { continue };
            if self.map.points[p].bad {
                continue;
            }
            s.points.push((p, i));
            s.descriptors.push(self.map.points[p].descriptor);
        }
        s.claims.clear();
        s.claims.resize(s.points.len(), (u32::MAX, u32::MAX));
        if s.distances.len() < s.descriptors.len() {
            s.distances.resize(s.descriptors.len(), 0);
        }
        for i in 0..self.current.len() {
            if self.current.depth[i] <= 0.0 {
                continue;
            }
            let distances = &mut s.distances[..s.descriptors.len()];
            bdis_orb::hamming_distances(&self.current.descriptors[i], &s.descriptors, distances);
            let (best, k, second) = bdis_orb::nearest_two(distances);
            if best <= TH_HIGH && f64::from(best) < RATIO * f64::from(second) && best < s.claims[k].0 {
                s.claims[k] = (best, i as u32);
            }
        }
        self.searcher.rotation.clear();
        for (k, &(distance, i)) in s.claims.iter().enumerate() {
            if distance == u32::MAX {
                continue;
            }
            let (p, kf_keypoint) = s.points[k];
            let i = i as usize;
            let kp = &self.current.keypoints[i];
            let octave = usize::from(kp.octave);
            let obs = Observation {
                u: f64::from(kp.x),
                v: f64::from(kp.y),
                u_right: Some(f64::from(self.current.u_right[i])),
                inv_sigma2: self.scales.inv_sigma2[octave],
            };
            let camera = self.cam.unproject(obs.u, obs.v, f64::from(self.current.depth[i]));
            self.searcher.rotation.add(s.matches.len() as u32, keyframe.keypoints[kf_keypoint].angle, kp.angle);
            s.matches.push(Match { keypoint: i, point: p, camera, world: self.map.points[p].position, obs });
        }
        self.searcher.rotation.rejected(&mut s.rejected);
        if !s.rejected.is_empty() {
            s.rejected.sort_unstable();
            let mut r = 0;
            let mut k = 0;
            s.matches.retain(|_| {
                let drop = r < s.rejected.len() && s.rejected[r] as usize == k;
                r += usize::from(drop);
                k += 1;
                !drop
            });
        }
    }
}
