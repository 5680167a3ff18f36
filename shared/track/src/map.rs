//! The map (ORB-SLAM2-STEREO.md §3.2–§3.4): keyframes, map points, covisibility graph and spanning tree, with
//! one owner. Ids are indices that are never reused; culled keyframes and bad points stay as tombstones so that
//! ids in flight (messages, trajectories) remain valid. Ordered containers keep every run deterministic.

use crate::frame::{Frame, Scales};
use crate::geometry::{CameraFromWorld, RectifiedCamera};
use bdis_orb::{FeatureGrid, KeyPoint, hamming};
use nalgebra::{Isometry3, Point3, Vector3};
use std::collections::{BTreeMap, BTreeSet};

pub use crate::ids::{KfId, PointId};

/// Covisibility weight from which a neighbour is kept in the ordered list (§3.2).
const COVIS_MIN_WEIGHT: u32 = 15;

#[derive(Debug, Clone)]
pub struct KeyFrame {
    pub id: KfId,
    pub frame_id: u64,
    pub t_ns: u64,
    pub camera_from_world: CameraFromWorld,
    pub keypoints: Vec<KeyPoint>,
    pub descriptors: Vec<[u8; 32]>,
    pub u_right: Vec<f32>,
    pub depth: Vec<f32>,
    pub grid: FeatureGrid,
    pub points: Vec<Option<PointId>>,
    /// Per keypoint: aligned to its point's anchor, and the measurement's relative σ (see [`Frame::aligned`]).
    pub aligned: Vec<Option<f32>>,
    /// All neighbours with their shared-point counts.
    pub connections: BTreeMap<KfId, u32>,
    /// Neighbours with weight ≥ 15 (or the single strongest), by descending weight then id.
    pub ordered: Vec<(KfId, u32)>,
    pub parent: Option<KfId>,
    pub children: BTreeSet<KfId>,
    pub bad: bool,
    /// Set when culled: the pose relative to the parent at that moment (to rebuild trajectories).
    pub camera_from_parent: Option<Isometry3<f64>>,
    /// Median stereo depth of its keypoints (NaN without any): how far it looks, for finding the keyframes a
    /// later frame looks at again (map reuse).
    pub median_depth: f64,
    /// What its left image shows of the texture ([`crate::frame::view_texture`]); for a veiled keyframe, its
    /// place's in clear view.
    pub texture: crate::frame::ViewTexture,
    /// Made under a veil (smoke): it serves tracking, and its images are no view to take depth from.
    pub veiled: bool,
}

impl KeyFrame {
    pub fn from_frame(id: KfId, frame: &Frame, camera_from_world: CameraFromWorld) -> Self {
        Self {
            id,
            frame_id: frame.id,
            t_ns: frame.t_ns,
            camera_from_world,
            keypoints: frame.keypoints.clone(),
            descriptors: frame.descriptors.clone(),
            u_right: frame.u_right.clone(),
            depth: frame.depth.clone(),
            grid: frame.grid.clone(),
            points: frame.points.iter().zip(&frame.outlier).map(|(p, o)| if *o { None } else { *p }).collect(),
            aligned: frame.aligned.clone(),
            connections: BTreeMap::new(),
            ordered: Vec::new(),
            parent: None,
            children: BTreeSet::new(),
            bad: false,
            camera_from_parent: None,
            median_depth: median_depth(&frame.depth),
            texture: frame.texture,
            veiled: false,
        }
    }

    /// The point it looks at: on its optical axis at its median depth (world coordinates).
    pub fn look_at(&self) -> Point3<f64> {
        self.camera_from_world.inverse() * Point3::new(0.0, 0.0, self.median_depth)
    }

    pub fn centre(&self) -> Point3<f64> {
        self.camera_from_world.inverse() * Point3::origin()
    }

    pub fn best_covisibles(&self, n: usize) -> impl Iterator<Item = KfId> + '_ {
        self.ordered.iter().take(n).map(|(k, _)| *k)
    }

    pub fn is_stereo(&self, i: usize) -> bool {
        self.u_right.get(i).is_some_and(|u| *u >= 0.0)
    }

    /// Keypoint `i` as a measurement for the optimisers (with its right-image u when it has one), weighted by
    /// `inv_sigma2`.
    pub fn observation(&self, i: usize, inv_sigma2: f64) -> crate::optim::Observation {
        let kp = &self.keypoints[i];
        crate::optim::Observation {
            u: f64::from(kp.x),
            v: f64::from(kp.y),
            u_right: self.is_stereo(i).then(|| f64::from(self.u_right[i])),
            inv_sigma2,
        }
    }
}

/// Per-frame scratch of the local-map search (§5.6), kept with the point.
#[derive(Debug, Clone, Copy, Default)]
pub struct TrackCache {
    pub in_view: bool,
    pub u: f64,
    pub v: f64,
    pub u_right: f64,
    pub level: usize,
    pub view_cos: f64,
    pub last_seen_frame: Option<u64>,
    pub local_for_frame: Option<u64>,
    pub fuse_target: Option<KfId>,
}

#[derive(Debug, Clone)]
pub struct MapPoint {
    pub id: PointId,
    pub position: Point3<f64>,
    /// Mean viewing direction (unit).
    pub normal: Vector3<f64>,
    pub min_dist: f64,
    pub max_dist: f64,
    pub descriptor: [u8; 32],
    /// Keyframe → keypoint index.
    pub observations: BTreeMap<KfId, usize>,
    /// Observation count, a stereo observation counting 2 (§3.3).
    pub n_obs: u32,
    pub ref_kf: KfId,
    pub first_kf: KfId,
    pub visible: u32,
    pub found: u32,
    pub bad: bool,
    pub replaced_by: Option<PointId>,
    pub cache: TrackCache,
    /// The patch later measurements are aligned to ([`crate::refine`]); set when the point is first measured
    /// as an inlier, and anew when the view has moved too far from it.
    pub anchor: Option<crate::refine::Anchor>,
}

impl MapPoint {
    pub fn found_ratio(&self) -> f64 {
        f64::from(self.found) / f64::from(self.visible.max(1))
    }
}

/// The map.
#[derive(Debug, Clone)]
pub struct Map {
    pub keyframes: Vec<KeyFrame>,
    pub points: Vec<MapPoint>,
    /// σ of measurements refined by patch alignment, relative to their octave's (measured by the tracker;
    /// see [`crate::refine::INITIAL_REFINED_SIGMA`]).
    pub refined_sigma: f64,
}

impl Default for Map {
    fn default() -> Self {
        Self { keyframes: Vec::new(), points: Vec::new(), refined_sigma: crate::refine::INITIAL_REFINED_SIGMA }
    }
}

impl Map {
    pub fn good_keyframes(&self) -> impl Iterator<Item = &KeyFrame> {
        self.keyframes.iter().filter(|k| !k.bad)
    }

    pub fn n_good_keyframes(&self) -> usize {
        self.good_keyframes().count()
    }

    /// Adds a keyframe (its `points` links are kept; observations are added by the caller).
    pub fn add_keyframe(&mut self, mut kf: KeyFrame) -> KfId {
        let id = self.keyframes.len();
        kf.id = id;
        self.keyframes.push(kf);
        id
    }

    /// Creates a point at `position` observed by keypoint `idx` of keyframe `kf`.
    pub fn new_point(&mut self, position: Point3<f64>, kf: KfId, idx: usize, scales: &Scales) -> PointId {
        let id = self.points.len();
        let k = &self.keyframes[kf];
        self.points.push(MapPoint {
            id,
            position,
            normal: Vector3::z(),
            min_dist: 0.0,
            max_dist: 0.0,
            descriptor: k.descriptors[idx],
            observations: BTreeMap::new(),
            n_obs: 0,
            ref_kf: kf,
            first_kf: kf,
            visible: 1,
            found: 1,
            bad: false,
            replaced_by: None,
            cache: TrackCache::default(),
            anchor: None,
        });
        self.add_observation(id, kf, idx);
        self.update_normal_and_depth(id, scales);
        id
    }

    pub fn add_observation(&mut self, p: PointId, kf: KfId, idx: usize) {
        let keyframe = &mut self.keyframes[kf];
        let stereo = keyframe.is_stereo(idx);
        if keyframe.points[idx] != Some(p) {
            // The keypoint was aligned (if at all) to another point's anchor, or is a whole-pixel corner: its
            // position is no sub-pixel measurement of this point's anchored tissue.
            keyframe.aligned[idx] = None;
        }
        keyframe.points[idx] = Some(p);
        let point = &mut self.points[p];
        if point.observations.insert(kf, idx).is_none() {
            point.n_obs += if stereo { 2 } else { 1 };
        }
    }

    /// Removes keyframe `kf`'s observation of point `p` (and the link); the point goes bad with ≤ 2 left.
    pub fn erase_observation(&mut self, p: PointId, kf: KfId) {
        let Some(idx) = self.points[p].observations.remove(&kf) else { return };
        let stereo = self.keyframes[kf].is_stereo(idx);
        if self.keyframes[kf].points[idx] == Some(p) {
            self.keyframes[kf].points[idx] = None;
        }
        let point = &mut self.points[p];
        point.n_obs = point.n_obs.saturating_sub(if stereo { 2 } else { 1 });
        if point.ref_kf == kf
            && let Some((&k, _)) = point.observations.iter().next()
        {
            point.ref_kf = k;
        }
        if point.n_obs <= 2 {
            self.set_bad_point(p);
        }
    }

    pub fn set_bad_point(&mut self, p: PointId) {
        let obs = std::mem::take(&mut self.points[p].observations);
        self.points[p].bad = true;
        self.points[p].n_obs = 0;
        for (kf, idx) in obs {
            if self.keyframes[kf].points[idx] == Some(p) {
                self.keyframes[kf].points[idx] = None;
            }
        }
    }

    /// Replaces point `p` by `by` everywhere (the one with more observations survives, decided by the caller).
    pub fn replace_point(&mut self, p: PointId, by: PointId) {
        if p == by || self.points[p].bad || self.points[by].bad {
            return;
        }
        let obs = std::mem::take(&mut self.points[p].observations);
        let (visible, found) = (self.points[p].visible, self.points[p].found);
        self.points[p].bad = true;
        self.points[p].n_obs = 0;
        self.points[p].replaced_by = Some(by);
        for (kf, idx) in obs {
            if self.points[by].observations.contains_key(&kf) {
                if self.keyframes[kf].points[idx] == Some(p) {
                    self.keyframes[kf].points[idx] = None;
                }
            } else {
                self.add_observation(by, kf, idx);
            }
        }
        self.points[by].visible += visible;
        self.points[by].found += found;
        self.compute_descriptor(by);
    }

    /// Follows `replaced_by` to the surviving point, if any.
    pub fn resolve(&self, mut p: PointId) -> Option<PointId> {
        for _ in 0..64 {
            let point = &self.points[p];
            if !point.bad {
                return Some(p);
            }
            p = point.replaced_by?;
        }
        None
    }

    /// Mean viewing direction (renormalised, §10.1 #13) and the scale-invariance distances (§3.3).
    pub fn update_normal_and_depth(&mut self, p: PointId, scales: &Scales) {
        let point = &self.points[p];
        if point.bad || point.observations.is_empty() {
            return;
        }
        let mut normal = Vector3::zeros();
        for &kf in point.observations.keys() {
            let d = point.position - self.keyframes[kf].centre();
            normal += d / d.norm().max(1e-12);
        }
        let ref_kf = &self.keyframes[point.ref_kf];
        let Some(&idx) = point.observations.get(&point.ref_kf) else { return };
        let dist = (point.position - ref_kf.centre()).norm();
        let octave = usize::from(ref_kf.keypoints[idx].octave);
        let max_dist = dist * scales.scale[octave];
        let min_dist = max_dist / scales.scale[scales.levels() - 1];
        let point = &mut self.points[p];
        point.normal = normal.try_normalize(1e-12).unwrap_or(Vector3::z());
        point.max_dist = max_dist;
        point.min_dist = min_dist;
    }

    /// The representative descriptor: the observation descriptor with the smallest median distance to the others.
    pub fn compute_descriptor(&mut self, p: PointId) {
        let point = &self.points[p];
        if point.bad {
            return;
        }
        let descs: Vec<[u8; 32]> =
            point.observations.iter().map(|(&kf, &idx)| self.keyframes[kf].descriptors[idx]).collect();
        if descs.is_empty() {
            return;
        }
        let mut best = (u32::MAX, 0);
        for (i, a) in descs.iter().enumerate() {
            let mut d: Vec<u32> = descs.iter().map(|b| hamming(a, b)).collect();
            d.sort_unstable();
            let median = d[(d.len() - 1) / 2];
            if median < best.0 {
                best = (median, i);
            }
        }
        self.points[p].descriptor = descs[best.1];
    }

    /// Recounts keyframe `kf`'s covisibility from its points, rebuilds its lists and its neighbours' links, and
    /// picks its parent the first time (§3.2).
    pub fn update_connections(&mut self, kf: KfId) {
        let mut counts: BTreeMap<KfId, u32> = BTreeMap::new();
        for p in self.keyframes[kf].points.iter().flatten() {
            let point = &self.points[*p];
            if point.bad {
                continue;
            }
            for &other in point.observations.keys() {
                if other != kf && !self.keyframes[other].bad {
                    *counts.entry(other).or_default() += 1;
                }
            }
        }
        if counts.is_empty() {
            return;
        }
        let mut ordered: Vec<(KfId, u32)> = counts.iter().map(|(&k, &w)| (k, w)).collect();
        ordered.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let strongest = ordered[0];
        let mut strong: Vec<(KfId, u32)> = ordered.iter().copied().filter(|(_, w)| *w >= COVIS_MIN_WEIGHT).collect();
        if strong.is_empty() {
            strong.push(strongest);
        }
        // Links are made symmetric for every neighbour (ORB-SLAM2 only links back the strong ones, §10.1 #21).
        for (&other, &w) in &counts {
            self.add_connection(other, kf, w);
        }
        let k = &mut self.keyframes[kf];
        k.connections = counts;
        k.ordered = strong;
        if k.parent.is_none() && kf != 0 {
            k.parent = Some(strongest.0);
            self.keyframes[strongest.0].children.insert(kf);
        }
    }

    fn add_connection(&mut self, kf: KfId, other: KfId, w: u32) {
        let k = &mut self.keyframes[kf];
        k.connections.insert(other, w);
        let mut ordered: Vec<(KfId, u32)> = k.connections.iter().map(|(&k, &w)| (k, w)).collect();
        ordered.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        let strongest = ordered[0];
        ordered.retain(|(_, w)| *w >= COVIS_MIN_WEIGHT);
        if ordered.is_empty() {
            ordered.push(strongest);
        }
        k.ordered = ordered;
    }

    /// Culls keyframe `kf` (§3.2): its observations go, its neighbours forget it, its children move to its parent.
    pub fn set_bad_keyframe(&mut self, kf: KfId) {
        if kf == 0 || self.keyframes[kf].bad {
            return;
        }
        let neighbours: Vec<KfId> = self.keyframes[kf].connections.keys().copied().collect();
        for n in neighbours {
            let k = &mut self.keyframes[n];
            k.connections.remove(&kf);
            k.ordered.retain(|(id, _)| *id != kf);
        }
        let points: Vec<PointId> = self.keyframes[kf].points.iter().flatten().copied().collect();
        for p in points {
            self.erase_observation(p, kf);
        }
        let parent = self.keyframes[kf].parent.unwrap_or(0);
        let children: Vec<KfId> = std::mem::take(&mut self.keyframes[kf].children).into_iter().collect();
        // Each child takes, among the parent and the already relinked children, its most covisible one (the
        // parent when none is covisible).
        let mut candidates = vec![parent];
        for c in children {
            let best = candidates
                .iter()
                .filter(|&&cand| !self.keyframes[cand].bad)
                .max_by_key(|&&cand| {
                    (self.keyframes[c].connections.get(&cand).copied().unwrap_or(0), std::cmp::Reverse(cand))
                })
                .copied()
                .unwrap_or(parent);
            self.keyframes[c].parent = Some(best);
            self.keyframes[best].children.insert(c);
            candidates.push(c);
        }
        self.keyframes[parent].children.remove(&kf);
        let camera_from_parent =
            self.keyframes[kf].camera_from_world * self.keyframes[parent].camera_from_world.inverse();
        let k = &mut self.keyframes[kf];
        k.camera_from_parent = Some(camera_from_parent);
        k.connections.clear();
        k.ordered.clear();
        k.bad = true;
    }

    /// The culled keyframes whose pose moved with `moved`: a culled keyframe's pose follows its first live
    /// ancestor up the parent chain ([`Map::keyframe_pose`]), so when that ancestor moved, so did it. A consumer
    /// that keeps culled keyframes (the dense map keeps their points) needs their corrections too.
    pub fn culled_following(&self, moved: &[KfId]) -> Vec<KfId> {
        let moved: std::collections::BTreeSet<KfId> = moved.iter().copied().collect();
        let keyframes = &self.keyframes;
        (0..keyframes.len())
            .filter(|&k| keyframes[k].bad)
            .filter(|&k| {
                let mut ancestor = keyframes[k].parent;
                for _ in 0..keyframes.len() {
                    match ancestor {
                        Some(a) if keyframes[a].bad => ancestor = keyframes[a].parent,
                        _ => break,
                    }
                }
                ancestor.is_some_and(|a| moved.contains(&a))
            })
            .collect()
    }

    /// The current `camera_from_world` of keyframe `kf`, following parents through culled keyframes.
    pub fn keyframe_pose(&self, mut kf: KfId) -> CameraFromWorld {
        let mut camera_from_x = Isometry3::identity();
        for _ in 0..self.keyframes.len() {
            let k = &self.keyframes[kf];
            if !k.bad {
                return camera_from_x * k.camera_from_world;
            }
            camera_from_x *= k.camera_from_parent.unwrap_or_else(Isometry3::identity);
            kf = k.parent.unwrap_or(0);
        }
        camera_from_x * self.keyframes[0].camera_from_world
    }

    /// Where `p` projects in a camera at `camera_from_world`, if it can be seen there: in front, inside the
    /// image, at a distance in its scale-invariance range (0.8·min – 1.2·max) and within 60° of its normal.
    pub fn projection_from(
        &self,
        cam: &RectifiedCamera,
        p: PointId,
        camera_from_world: &CameraFromWorld,
    ) -> Option<Projection> {
        let point = &self.points[p];
        let pc = camera_from_world * point.position;
        if pc.z <= 0.0 {
            return None;
        }
        let (u, v) = cam.project(&pc);
        if !cam.in_image(u, v) {
            return None;
        }
        let d = point.position - camera_from_world.inverse() * Point3::origin();
        let distance = d.norm();
        (distance >= 0.8 * point.min_dist && distance <= 1.2 * point.max_dist && d.dot(&point.normal) >= 0.5 * distance)
            .then_some(Projection { u, v, depth: pc.z, distance })
    }
}

/// A map point seen from a camera ([`Map::projection_from`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Projection {
    pub u: f64,
    pub v: f64,
    /// z in the camera's frame.
    pub depth: f64,
    /// From the camera's centre.
    pub distance: f64,
}

/// Median of the positive depths (−1 marks none); NaN when there is none.
fn median_depth(depth: &[f32]) -> f64 {
    let mut valid: Vec<f32> = depth.iter().copied().filter(|d| *d > 0.0).collect();
    if valid.is_empty() {
        return f64::NAN;
    }
    let mid = valid.len() / 2;
    let (_, median, _) = valid.select_nth_unstable_by(mid, f32::total_cmp);
    f64::from(*median)
}

#[cfg(test)]
pub(crate) mod tests;
