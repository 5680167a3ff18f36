//! Guided matching by projection (ORB-SLAM2-STEREO.md §4). No bag of words: where ORB-SLAM2 matches under a
//! vocabulary node, we project with a pose prior (the tracker always has one, §7.3 B).

use crate::frame::{Frame, Scales};
use crate::geometry::{CameraFromWorld, RectifiedCamera};
use crate::map::{KfId, Map, MapPoint, PointId};
use crate::optim::CHI2_MONO;
use bdis_orb::{RotationBins, RotationHistogram, hamming};

pub const TH_HIGH: u32 = 100;
pub const TH_LOW: u32 = 45;
/// Lowe's ratio of descriptor matching without a pose prior (relocalisation, the loop's check; ORB-SLAM2's 0.75).
pub const PRIORLESS_RATIO: f64 = 0.75;

/// The best match of descriptor `d` among `candidates` (index, descriptor) when it is within [`TH_LOW`] and
/// under [`PRIORLESS_RATIO`] of the second best: (index, Hamming distance). The matching of relocalisation and
/// of the loop's place check and votes, where no prior narrows the candidates.
pub fn ratio_match<'a>(
    d: &[u8; 32],
    candidates: impl IntoIterator<Item = (usize, &'a [u8; 32])>,
) -> Option<(usize, u32)> {
    let ((mut best, mut at), mut second) = ((u32::MAX, usize::MAX), u32::MAX);
    for (j, c) in candidates {
        let h = hamming(d, c);
        if h < best {
            second = best;
            (best, at) = (h, j);
        } else if h < second {
            second = h;
        }
    }
    (best <= TH_LOW && f64::from(best) < PRIORLESS_RATIO * f64::from(second)).then_some((at, best))
}

/// Reusable buffers of the searches.
#[derive(Debug)]
pub struct Searcher {
    pub rotation: RotationHistogram,
    found: Vec<usize>,
    rejected: Vec<u32>,
    /// (keypoint, point, distance) of the current search.
    matches: Vec<(usize, PointId, u32)>,
}

impl Default for Searcher {
    fn default() -> Self {
        Self::with_capacity(2048)
    }
}

impl Searcher {
    /// Buffers for searches of up to `matches` matches (a frame's keypoints), grown by nothing after.
    pub fn with_capacity(matches: usize) -> Self {
        Self {
            rotation: RotationHistogram::with_capacity(RotationBins::FAITHFUL, matches),
            found: Vec::with_capacity(256),
            rejected: Vec::with_capacity(matches),
            matches: Vec::with_capacity(matches),
        }
    }
}

impl Searcher {
    /// Projects the last frame's points into `frame` (posed by prediction) and links the best matches (§5.3):
    /// radius `th·s_o`, octave window by the direction of motion, stereo gate, best ≤ TH_HIGH, rotation filter.
    #[allow(clippy::too_many_arguments)]
    pub fn from_last_frame(
        &mut self,
        cam: &RectifiedCamera,
        scales: &Scales,
        map: &Map,
        frame: &mut Frame,
        last: &Frame,
        th: f64,
    ) -> usize {
        let Some(pose) = frame.camera_from_world else { return 0 };
        let Some(last_pose) = last.camera_from_world else { return 0 };
        // The current camera centre in the last camera's frame: forward / backward motion.
        let t_lc = last_pose * (pose.inverse() * nalgebra::Point3::origin());
        let b = cam.baseline();
        let (forward, backward) = (t_lc.z > b, -t_lc.z > b);
        self.rotation.clear();
        self.matches.clear();
        let levels = scales.levels() as u8;
        for (i, p) in last.points.iter().enumerate() {
            let Some(p) = p.and_then(|p| map.resolve(p)) else { continue };
            if last.outlier[i] {
                continue;
            }
            let x = map.points[p].position;
            let pc = pose * x;
            if pc.z <= 0.0 {
                continue;
            }
            let (u, v) = cam.project(&pc);
            if !cam.in_image(u, v) {
                continue;
            }
            let o_last = last.keypoints[i].octave;
            let r = th * scales.scale[usize::from(o_last)];
            let octaves = if forward {
                o_last..=levels - 1
            } else if backward {
                0..=o_last
            } else {
                o_last.saturating_sub(1)..=(o_last + 1).min(levels - 1)
            };
            frame.grid.features_in_area(&frame.keypoints, (u as f32, v as f32), r as f32, octaves, &mut self.found);
            let u_r_pred = u - cam.bf / pc.z;
            let desc = &map.points[p].descriptor;
            let mut best = (u32::MAX, usize::MAX);
            for &j in &self.found {
                if frame.points[j].is_some() {
                    continue;
                }
                if frame.u_right[j] >= 0.0 && (u_r_pred - f64::from(frame.u_right[j])).abs() > r {
                    continue;
                }
                let d = hamming(desc, &frame.descriptors[j]);
                if d < best.0 {
                    best = (d, j);
                }
            }
            if best.0 <= TH_HIGH {
                frame.points[best.1] = Some(p);
                frame.outlier[best.1] = false;
                self.rotation.add(best.1 as u32, last.keypoints[i].angle, frame.keypoints[best.1].angle);
            }
        }
        self.drop_rotation_outliers(frame)
    }

    fn drop_rotation_outliers(&mut self, frame: &mut Frame) -> usize {
        self.rotation.rejected(&mut self.rejected);
        for &j in &self.rejected {
            frame.points[j as usize] = None;
        }
        frame.points.iter().filter(|p| p.is_some()).count()
    }

    /// Projects keyframe `kf`'s points into `frame` (posed) and links matches to keypoints without a point:
    /// radius `th·s_pred`, octaves pred ± 1, best ≤ `max_distance`, rotation filter. Points in `skip` are left
    /// out (sorted). For relocalisation (§5.7) and reference-keyframe tracking (our replacement for its BoW search).
    #[allow(clippy::too_many_arguments)]
    pub fn from_keyframe(
        &mut self,
        cam: &RectifiedCamera,
        scales: &Scales,
        map: &Map,
        frame: &mut Frame,
        kf: KfId,
        skip: &[PointId],
        th: f64,
        max_distance: u32,
    ) -> usize {
        let Some(pose) = frame.camera_from_world else { return 0 };
        let centre = pose.inverse() * nalgebra::Point3::origin();
        self.rotation.clear();
        let mut added = 0;
        let levels = scales.levels();
        for (i, p) in map.keyframes[kf].points.iter().enumerate() {
            let Some(p) = *p else { continue };
            let point = &map.points[p];
            if point.bad || skip.binary_search(&p).is_ok() {
                continue;
            }
            let pc = pose * point.position;
            if pc.z <= 0.0 {
                continue;
            }
            let (u, v) = cam.project(&pc);
            if !cam.in_image(u, v) {
                continue;
            }
            let dist = (point.position - centre).norm();
            if dist < 0.8 * point.min_dist || dist > 1.2 * point.max_dist {
                continue;
            }
            let level = scales.predict_level(dist, point.max_dist);
            let r = th * scales.scale[level];
            let octaves = level.saturating_sub(1) as u8..=(level + 1).min(levels - 1) as u8;
            frame.grid.features_in_area(&frame.keypoints, (u as f32, v as f32), r as f32, octaves, &mut self.found);
            let mut best = (u32::MAX, usize::MAX);
            for &j in &self.found {
                if frame.points[j].is_some() {
                    continue;
                }
                let d = hamming(&point.descriptor, &frame.descriptors[j]);
                if d < best.0 {
                    best = (d, j);
                }
            }
            if best.0 <= max_distance {
                frame.points[best.1] = Some(p);
                frame.outlier[best.1] = false;
                added += 1;
                self.rotation.add(best.1 as u32, map.keyframes[kf].keypoints[i].angle, frame.keypoints[best.1].angle);
            }
        }
        self.rotation.rejected(&mut self.rejected);
        for &j in &self.rejected {
            frame.points[j as usize] = None;
            added -= 1;
        }
        added
    }

    /// Matches the local points that passed the frustum test (their `cache` filled) into `frame` (§4 "local points
    /// → frame"): radius R(viewCos)·th·s_pred, octaves [pred − 1, pred], stereo gate, best ≤ TH_HIGH unless the
    /// best and the second are on the same octave and best > 0.8·second.
    pub fn local_points(&mut self, scales: &Scales, map: &Map, frame: &mut Frame, local: &[PointId], th: f64) -> usize {
        let mut added = 0;
        for &p in local {
            let point = &map.points[p];
            let c = &point.cache;
            if point.bad || !c.in_view {
                continue;
            }
            let r = if c.view_cos > 0.998 { 2.5 } else { 4.0 } * th * scales.scale[c.level];
            let octaves = c.level.saturating_sub(1) as u8..=c.level as u8;
            frame.grid.features_in_area(&frame.keypoints, (c.u as f32, c.v as f32), r as f32, octaves, &mut self.found);
            let (mut best, mut second) = ((u32::MAX, usize::MAX), u32::MAX);
            let mut best_octave = 0u8;
            let mut second_octave = 0u8;
            for &j in &self.found {
                if frame.points[j].is_some_and(|q| map.points[q].n_obs > 0 && !map.points[q].bad) {
                    continue;
                }
                if frame.u_right[j] >= 0.0 && (c.u_right - f64::from(frame.u_right[j])).abs() > r {
                    continue;
                }
                let d = hamming(&point.descriptor, &frame.descriptors[j]);
                if d < best.0 {
                    second = best.0;
                    second_octave = best_octave;
                    best = (d, j);
                    best_octave = frame.keypoints[j].octave;
                } else if d < second {
                    second = d;
                    second_octave = frame.keypoints[j].octave;
                }
            }
            if best.0 <= TH_HIGH {
                if best_octave == second_octave && f64::from(best.0) > 0.8 * f64::from(second) {
                    continue;
                }
                frame.points[best.1] = Some(p);
                frame.outlier[best.1] = false;
                added += 1;
            }
        }
        added
    }
}

/// Where a map point appears to a camera that sees it by §5.6's frustum test: in front of it and in the image,
/// within the point's scale-invariance distances, and at under 60° from its mean viewing direction.
#[derive(Debug, Clone, Copy)]
pub struct SeenAt {
    pub u: f64,
    pub v: f64,
    /// Depth along the optical axis (for the right image's column) and distance from the camera's centre.
    pub z: f64,
    pub dist: f64,
    pub view_cos: f64,
}

/// The frustum test of §5.6 for `point` seen from `pose`; `None` when it fails.
pub fn seen_from(cam: &RectifiedCamera, point: &MapPoint, pose: &CameraFromWorld) -> Option<SeenAt> {
    let pc = pose * point.position;
    if pc.z <= 0.0 {
        return None;
    }
    let (u, v) = cam.project(&pc);
    if !cam.in_image(u, v) {
        return None;
    }
    let centre = pose.inverse() * nalgebra::Point3::origin();
    let d = point.position - centre;
    let dist = d.norm();
    if dist < 0.8 * point.min_dist || dist > 1.2 * point.max_dist {
        return None;
    }
    let view_cos = d.dot(&point.normal) / dist;
    (view_cos >= 0.5).then_some(SeenAt { u, v, z: pc.z, dist, view_cos })
}

/// The frustum test of §5.6 for the local-map search; fills the point's cache. Returns whether it is visible.
pub fn frustum_check(
    cam: &RectifiedCamera,
    scales: &Scales,
    map: &mut Map,
    p: PointId,
    pose: &CameraFromWorld,
) -> bool {
    let point = &mut map.points[p];
    point.cache.in_view = false;
    let Some(SeenAt { u, v, z, dist, view_cos }) = seen_from(cam, point, pose) else { return false };
    let level = scales.predict_level(dist, point.max_dist);
    point.cache =
        crate::map::TrackCache { in_view: true, u, v, u_right: u - cam.bf / z, level, view_cos, ..point.cache };
    true
}

/// Fuses point `p` into keyframe `kf` (§4 Fuse, th = 3). Returns whether it was fused or added.
pub fn fuse_point(map: &mut Map, cam: &RectifiedCamera, scales: &Scales, kf: KfId, p: PointId) -> bool {
    let point = &map.points[p];
    if point.bad || point.observations.contains_key(&kf) {
        return false;
    }
    let k = &map.keyframes[kf];
    let Some(seen) = map.projection_from(cam, p, &k.camera_from_world) else { return false };
    let (u, v) = (seen.u, seen.v);
    let u_r = u - cam.bf / seen.depth;
    let level = scales.predict_level(seen.distance, point.max_dist);
    let r = 3.0 * scales.scale[level];
    let mut found = Vec::new();
    k.grid.features_in_area(
        &k.keypoints,
        (u as f32, v as f32),
        r as f32,
        level.saturating_sub(1) as u8..=level as u8,
        &mut found,
    );
    let mut best = (u32::MAX, usize::MAX);
    for &j in &found {
        let kp = &k.keypoints[j];
        let inv_s2 = scales.inv_sigma2[usize::from(kp.octave)];
        let (eu, ev) = (u - f64::from(kp.x), v - f64::from(kp.y));
        let e2 = if k.is_stereo(j) {
            let er = u_r - f64::from(k.u_right[j]);
            (eu * eu + ev * ev + er * er) * inv_s2 > 7.8
        } else {
            (eu * eu + ev * ev) * inv_s2 > CHI2_MONO
        };
        if e2 {
            continue;
        }
        let d = hamming(&point.descriptor, &k.descriptors[j]);
        if d < best.0 {
            best = (d, j);
        }
    }
    if best.0 > TH_LOW {
        return false;
    }
    match map.keyframes[kf].points[best.1] {
        Some(q) if !map.points[q].bad => {
            // The point with more observations survives.
            if map.points[q].n_obs > map.points[p].n_obs {
                map.replace_point(p, q);
            } else {
                map.replace_point(q, p);
            }
        }
        _ => map.add_observation(p, kf, best.1),
    }
    true
}
