//! Relocalisation without a vocabulary (§5.7, §7.3 B): candidate keyframes by descriptor votes, a 3-point
//! RANSAC on the frame's stereo points with an absolute-orientation fit, then pose optimisation and guided
//! search.

use super::*;

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

impl Tracker {
    /// §5.7 without a vocabulary (§7.3 B): candidate keyframes by brute-force descriptor votes, a 3-point
    /// RANSAC on the frame's stereo points (each keypoint with a depth is a 3-D point, so absolute orientation
    /// replaces PnP), then pose optimisation and guided search as in ORB-SLAM2. The candidates are the places
    /// near the last pose, and the next keyframes (at least [`SCAN_PER_FRAME`]) of a scan over the whole map.
    pub(super) fn relocalise(&mut self) -> bool {
        let n = self.current.len();
        if n == 0 {
            return false;
        }
        // Candidates (§7.3 B): the camera is most likely near where it was last seen, so the last reference
        // keyframe, its covisibles and the keyframes nearest to the last pose; then, in turn over the lost
        // frames, every other keyframe (`scan_candidates`). Each is ranked by descriptor votes (a frame keypoint
        // whose best match among the keyframe's points passes TH_LOW and the ratio test).
        let mut near: Vec<KfId> = Vec::new();
        if let Some(r) = self.reference_kf.filter(|&r| !self.map.keyframes[r].bad) {
            near.push(r);
            near.extend(self.map.keyframes[r].best_covisibles(5));
        }
        if let Some((r, rel)) = self.last_from_reference {
            let last_centre = (rel * self.map.keyframe_pose(r)).inverse() * Point3::origin();
            let mut by_distance: Vec<(f64, KfId)> =
                self.map.good_keyframes().map(|k| ((k.centre() - last_centre).norm(), k.id)).collect();
            by_distance.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            near.extend(by_distance.iter().take(5).map(|(_, k)| *k));
        }
        let mut seen = BTreeSet::new();
        near.retain(|k| seen.insert(*k) && !self.map.keyframes[*k].bad);
        self.scan_candidates(&mut near);
        let mut scored: Vec<(usize, KfId)> =
            near.iter().map(|&k| (self.votes(k), k)).filter(|(v, _)| *v >= 15).collect();
        scored.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        for &(_, kf) in scored.iter().take(5) {
            if self.relocalise_against(kf) {
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

    /// Frame keypoints whose best match among keyframe `kf`'s points is ≤ TH_LOW and < 0.75 of the second best.
    pub(super) fn votes(&self, kf: KfId) -> usize {
        let descs: Vec<&[u8; 32]> = self.map.keyframes[kf]
            .points
            .iter()
            .flatten()
            .filter(|&&p| !self.map.points[p].bad)
            .map(|&p| &self.map.points[p].descriptor)
            .collect();
        self.current
            .descriptors
            .iter()
            .filter(|d| {
                let (mut best, mut second) = (u32::MAX, u32::MAX);
                for p in &descs {
                    let h = hamming(d, p);
                    if h < best {
                        second = best;
                        best = h;
                    } else if h < second {
                        second = h;
                    }
                }
                best <= TH_LOW && f64::from(best) < 0.75 * f64::from(second)
            })
            .count()
    }

    pub(super) fn relocalise_against(&mut self, kf: KfId) -> bool {
        // Matches: best descriptor (≤ TH_LOW, ratio 0.75) among the keyframe's points for each frame keypoint.
        let mut pairs: Vec<(usize, PointId)> = Vec::new();
        let points: Vec<PointId> =
            self.map.keyframes[kf].points.iter().flatten().copied().filter(|&p| !self.map.points[p].bad).collect();
        let mut used = BTreeSet::new();
        for i in 0..self.current.len() {
            let (mut best, mut second) = ((u32::MAX, usize::MAX), u32::MAX);
            for &p in &points {
                let d = hamming(&self.current.descriptors[i], &self.map.points[p].descriptor);
                if d < best.0 {
                    second = best.0;
                    best = (d, p);
                } else if d < second {
                    second = d;
                }
            }
            if best.0 <= TH_LOW && f64::from(best.0) < 0.75 * f64::from(second) && used.insert(best.1) {
                pairs.push((i, best.1));
            }
        }
        let stereo: Vec<(usize, PointId, Point3<f64>)> = pairs
            .iter()
            .filter_map(|&(i, p)| {
                let z = self.current.depth[i];
                (z > 0.0).then(|| {
                    let k = &self.current.keypoints[i];
                    (i, p, self.cam.unproject(f64::from(k.x), f64::from(k.y), f64::from(z)))
                })
            })
            .collect();
        if stereo.len() < 15 {
            return false;
        }
        // RANSAC: 3 correspondences → camera_from_world by absolute orientation; inliers by reprojection.
        let mut best: (usize, Option<CameraFromWorld>) = (0, None);
        for _ in 0..300 {
            let Some(pick) = draw_three(&mut self.ransac_state, stereo.len()) else { continue };
            let src: Vec<Point3<f64>> = pick.iter().map(|&k| self.map.points[stereo[k].1].position).collect();
            let dst: Vec<Point3<f64>> = pick.iter().map(|&k| stereo[k].2).collect();
            let Some(t) = rigid_fit(&src, &dst) else { continue };
            let inliers = stereo
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
        for &(i, p) in &pairs {
            self.current.points[i] = Some(p);
        }
        let mut good = self.optimise_current();
        if good < 10 {
            return false;
        }
        self.drop_outliers();
        if good < PRIORLESS_INLIERS {
            let found: BTreeSet<PointId> = self.current.points.iter().flatten().copied().collect();
            let added = self.searcher.from_keyframe(
                &self.cam,
                &self.scales,
                &self.map,
                &mut self.current,
                kf,
                &found,
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
