//! Relocalisation without a vocabulary (§5.7, §7.3 B): candidate keyframes by descriptor votes, a 3-point
//! RANSAC on the frame's stereo points with an absolute-orientation fit, then pose optimisation and guided
//! search.

use super::*;
use crate::search::ratio_match;

/// Keyframes away from the last pose whose points each lost frame also tries, in turn over the whole map: a
/// scope taken out (to clean the lens) and put back, or moved while the view was lost, can come back to any
/// place it has mapped. At least this many a frame, and more in a large map, so that one pass over it ends
/// before a new segment would begin ([`segment::RESTART_AFTER_S`](super::segment::RESTART_AFTER_S)): a
/// segment is begun only where no keyframe knows the place. Each costs a descriptor vote (every keypoint
/// against the keyframe's points, ≈ 0.4 ms at 1000 features).
pub const SCAN_PER_FRAME: usize = 6;

/// Inliers a pose found without a prior must have to be trusted (§5.7: ORB-SLAM2's bar after relocalisation,
/// and for the frames that follow it). A pose from few matches and no prior can fit them well and still be off
/// by a tenth of a step: the search that found them was centred on it.
pub const PRIORLESS_INLIERS: usize = 50;

/// Reusable buffers of relocalisation (owned by the tracker): a lost frame allocates nothing once the first one
/// has sized the lists that grow with the map (candidates by distance).
#[derive(Debug, Default)]
pub(super) struct RelocScratch {
    /// The keyframes this frame tries; the good ones by distance from the last pose; those that passed the
    /// vote, with their votes.
    candidates: Vec<KfId>,
    by_distance: Vec<(f64, KfId)>,
    scored: Vec<(usize, KfId)>,
    /// One keyframe's usable points and their descriptors (beside them, in the same order).
    points: Vec<PointId>,
    descriptors: Vec<[u8; 32]>,
    /// Per keyframe point: already matched to a frame keypoint.
    used: Vec<bool>,
    pairs: Vec<(usize, PointId)>,
    /// (frame keypoint, point, its stereo point in the camera).
    stereo: Vec<(usize, PointId, Point3<f64>)>,
    /// The points the frame is linked to, sorted: what the guided search leaves out.
    linked: Vec<PointId>,
}

impl RelocScratch {
    /// Room for keyframes and frames of `features` keypoints (twice, as the extractor may return a few more
    /// than asked).
    pub(super) fn with_capacity(features: usize) -> Self {
        let n = 2 * features.max(1);
        Self {
            points: Vec::with_capacity(n),
            descriptors: Vec::with_capacity(n),
            used: Vec::with_capacity(n),
            pairs: Vec::with_capacity(n),
            stereo: Vec::with_capacity(n),
            linked: Vec::with_capacity(n),
            ..Self::default()
        }
    }
}

impl Tracker {
    /// §5.7 without a vocabulary (§7.3 B): candidate keyframes by brute-force descriptor votes, a 3-point
    /// RANSAC on the frame's stereo points (each keypoint with a depth is a 3-D point, so absolute orientation
    /// replaces PnP), then pose optimisation and guided search as in ORB-SLAM2. The candidates are the places
    /// near the last pose, and the next keyframes (at least [`SCAN_PER_FRAME`]) of a scan over the whole map.
    pub(super) fn relocalise(&mut self) -> bool {
        if self.current.is_empty() {
            return false;
        }
        let mut scratch = std::mem::take(&mut self.reloc);
        let placed = self.relocalise_with(&mut scratch);
        self.reloc = scratch;
        placed
    }

    fn relocalise_with(&mut self, s: &mut RelocScratch) -> bool {
        // Candidates (§7.3 B): the camera is most likely near where it was last seen, so the last reference
        // keyframe, its covisibles and the keyframes nearest to the last pose; then, in turn over the lost
        // frames, every other keyframe (`scan_candidates`). Each is ranked by descriptor votes (a frame keypoint
        // whose best match among the keyframe's points passes TH_LOW and the ratio test).
        s.candidates.clear();
        if let Some(r) = self.reference_kf.filter(|&r| !self.map.keyframes[r].bad) {
            s.candidates.push(r);
            s.candidates.extend(self.map.keyframes[r].best_covisibles(5));
        }
        if let Some((r, rel)) = self.last_from_reference {
            let last_centre = (rel * self.map.keyframe_pose(r)).inverse() * Point3::origin();
            s.by_distance.clear();
            s.by_distance.extend(self.map.good_keyframes().map(|k| ((k.centre() - last_centre).norm(), k.id)));
            s.by_distance.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            s.candidates.extend(s.by_distance.iter().take(5).map(|(_, k)| *k));
        }
        // Each once, in the order first named (a handful: a scan of the kept ones is cheaper than a set).
        let mut kept = 0;
        for j in 0..s.candidates.len() {
            let k = s.candidates[j];
            if !s.candidates[..kept].contains(&k) && !self.map.keyframes[k].bad {
                s.candidates[kept] = k;
                kept += 1;
            }
        }
        s.candidates.truncate(kept);
        self.scan_candidates(&mut s.candidates);
        s.scored.clear();
        for j in 0..s.candidates.len() {
            let k = s.candidates[j];
            let votes = self.votes(k, s);
            if votes >= 15 {
                s.scored.push((votes, k));
            }
        }
        s.scored.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        for j in 0..s.scored.len().min(5) {
            let kf = s.scored[j].1;
            if self.relocalise_against(kf, s) {
                self.last_reloc_frame = Some(self.current.id);
                self.reference_kf = Some(kf);
                return true;
            }
        }
        false
    }

    /// Appends to `candidates` the next good keyframes of the scan over the whole map that are not among them
    /// already ([`SCAN_PER_FRAME`], or the map's share of a pass within the restart's wait), and moves the scan
    /// on (back to the oldest after the newest).
    fn scan_candidates(&mut self, candidates: &mut Vec<KfId>) {
        let n = self.map.keyframes.len();
        let quota = SCAN_PER_FRAME.max(self.map.n_good_keyframes().div_ceil(self.restart_after_frames() as usize));
        let mut added = 0;
        for _ in 0..n {
            if added == quota {
                break;
            }
            let k = self.reloc_scan_next % n;
            self.reloc_scan_next = (k + 1) % n;
            if !self.map.keyframes[k].bad && !candidates.contains(&k) {
                candidates.push(k);
                added += 1;
            }
        }
    }

    /// Keyframe `kf`'s usable points into `s.points`, their descriptors into `s.descriptors`.
    fn keyframe_points(&self, kf: KfId, s: &mut RelocScratch) {
        s.points.clear();
        s.descriptors.clear();
        for &p in self.map.keyframes[kf].points.iter().flatten() {
            let point = &self.map.points[p];
            if !point.bad {
                s.points.push(p);
                s.descriptors.push(point.descriptor);
            }
        }
    }

    /// Frame keypoints whose best match among keyframe `kf`'s points is ≤ TH_LOW and < 0.75 of the second best.
    fn votes(&self, kf: KfId, s: &mut RelocScratch) -> usize {
        self.keyframe_points(kf, s);
        self.current.descriptors.iter().filter(|d| ratio_match(d, s.descriptors.iter().enumerate()).is_some()).count()
    }

    fn relocalise_against(&mut self, kf: KfId, s: &mut RelocScratch) -> bool {
        // Matches: best descriptor (≤ TH_LOW, ratio 0.75) among the keyframe's points for each frame keypoint,
        // each point to one keypoint (the first that names it).
        self.keyframe_points(kf, s);
        s.used.clear();
        s.used.resize(s.points.len(), false);
        // A keyframe can hold one point at two keypoints (after a fusion): a point is used once, whichever of
        // its keypoints matched.
        s.linked.clear();
        s.linked.extend_from_slice(&s.points);
        s.linked.sort_unstable();
        let repeats = s.linked.windows(2).any(|w| w[0] == w[1]);
        s.pairs.clear();
        for (i, d) in self.current.descriptors.iter().enumerate() {
            let Some((j, _)) = ratio_match(d, s.descriptors.iter().enumerate()) else { continue };
            if s.used[j] {
                continue;
            }
            let p = s.points[j];
            if repeats {
                for (used, _) in s.used.iter_mut().zip(&s.points).filter(|(_, q)| **q == p) {
                    *used = true;
                }
            }
            s.used[j] = true;
            s.pairs.push((i, p));
        }
        s.stereo.clear();
        for &(i, p) in &s.pairs {
            let z = self.current.depth[i];
            if z > 0.0 {
                let k = &self.current.keypoints[i];
                s.stereo.push((i, p, self.cam.unproject(f64::from(k.x), f64::from(k.y), f64::from(z))));
            }
        }
        if s.stereo.len() < 15 {
            return false;
        }
        // RANSAC: 3 correspondences → camera_from_world by absolute orientation; inliers by reprojection.
        let mut best: (usize, Option<CameraFromWorld>) = (0, None);
        for _ in 0..300 {
            let Some(pick) = draw_three(&mut self.ransac_state, s.stereo.len()) else { continue };
            let src = pick.map(|k| self.map.points[s.stereo[k].1].position);
            let dst = pick.map(|k| s.stereo[k].2);
            let Some(t) = rigid_fit(&src, &dst) else { continue };
            let inliers = s
                .stereo
                .iter()
                .filter(|(i, p, _)| {
                    let pc = t * self.map.points[*p].position;
                    if pc.z <= 0.0 {
                        return false;
                    }
                    let (u, v) = self.cam.project(&pc);
                    let k = &self.current.keypoints[*i];
                    let e2 = (u - f64::from(k.x)).powi(2) + (v - f64::from(k.y)).powi(2);
                    // The reprojection gate of a monocular observation at the keypoint's octave (χ², 2 DoF, 95 %).
                    e2 < crate::optim::CHI2_MONO / self.scales.inv_sigma2[usize::from(k.octave)]
                })
                .count();
            if inliers > best.0 {
                best = (inliers, Some(t));
            }
        }
        let (count, Some(pose)) = best else { return false };
        if count < 10 {
            return false;
        }
        self.current.camera_from_world = Some(pose);
        self.current.points.fill(None);
        self.current.outlier.fill(false);
        for &(i, p) in &s.pairs {
            self.current.points[i] = Some(p);
        }
        let mut good = self.optimise_current();
        if good < 10 {
            return false;
        }
        self.drop_outliers();
        if good < PRIORLESS_INLIERS {
            s.linked.clear();
            s.linked.extend(self.current.points.iter().flatten().copied());
            s.linked.sort_unstable();
            let added = self.searcher.from_keyframe(
                &self.cam,
                &self.scales,
                &self.map,
                &mut self.current,
                kf,
                &s.linked,
                10.0,
                100,
            );
            if good + added >= PRIORLESS_INLIERS {
                good = self.optimise_current();
                self.drop_outliers();
            }
        }
        good >= PRIORLESS_INLIERS
    }
}
