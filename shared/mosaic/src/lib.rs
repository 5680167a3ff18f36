//! `bdis-mosaic`: the dense map of BDIS-SLAM (the paper's §2.3 and Algorithm 1), pure compute.
//!
//! Each depth keyframe is lifted to coloured points on a sparse pixel grid (every `depth_gap_px`-th row and
//! column). The points are stored **in their keyframe's own camera frame** with the keyframe's current
//! `world_from_camera`, so a pose correction from bundle adjustment moves all of a keyframe's points by changing
//! one pose (the original froze them in world coordinates at insertion).
//!
//! The mosaic rule: a new keyframe replaces the earlier points it sees again. Unlike the original, which erased
//! every earlier point that projected onto a valid new pixel, an earlier point is removed only when it agrees with
//! the new surface or lies in front of it (a depth test whose tolerance grows with the depth uncertainty of both
//! views); a point behind the new surface is occluded, not contradicted, and stays. Only keyframes whose point
//! bounds intersect the new view's frustum are visited, so the cost of a new keyframe depends on how much of the
//! map it overlaps, not on the size of the map.
//!
//! By default (the paper's future work) an agreeing earlier point is not just replaced: it is folded into the new
//! point of the same grid cell, weighted by confidence, by its offset from the new surface where it falls
//! ([`Fusion::Weighted`]), so tissue that breathes is mapped at its mean and a slope stays a slope;
//! [`Fusion::Replace`] is the paper's plain replacement.

mod carve;
mod normals;
mod params;
pub mod pending;
mod realign;
mod render;
mod store;
mod summary;

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};
use serde::{Deserialize, Serialize};

pub use normals::keyframe_normals;
pub use params::{Fusion, MosaicParams};
pub use realign::Realigned;
pub use render::{PreviewView, render_preview};
pub use store::{MOSAIC_FORMAT, Outputs, decode, load, save, write_outputs};
pub use summary::MosaicSummary;

#[derive(Debug, thiserror::Error)]
pub enum MosaicError {
    #[error("keyframe {kf_id}: {what} has {actual} values for {width}×{height} pixels")]
    WrongSize { kf_id: u64, what: &'static str, actual: usize, width: u32, height: u32 },
    #[error("keyframe {kf_id}: intrinsics: {what}")]
    BadIntrinsics { kf_id: u64, what: String },
    #[error("keyframe {kf_id}: world_from_camera is not a finite rigid pose")]
    BadPose { kf_id: u64 },
    #[error("{path}: {what}")]
    File { path: String, what: String },
}

/// The keyframe's camera: pinhole intrinsics of a rectified stereo pair, `bf` = fx · baseline (depth =
/// bf / disparity), and the image size.
pub use bdis_core::RectifiedCamera;

/// One depth keyframe as the stereo service publishes it; the slices are read in place.
#[derive(Debug, Clone, Copy)]
pub struct DepthKeyframe<'a> {
    pub kf_id: u64,
    pub t_capture_ns: u64,
    pub world_from_camera: Isometry3<f64>,
    pub intrinsics: RectifiedCamera,
    /// Pixels, positive; NaN or ≤ 0 = no answer. Row-major, width × height.
    pub disparity: &'a [f32],
    /// In [0, 1].
    pub confidence: &'a [f32],
    /// RGB, 3 bytes per pixel.
    pub rgb: &'a [u8],
}

/// A map point in its keyframe's camera frame (millimetres).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MosaicPoint {
    pub xyz: [f32; 3],
    pub rgb: [u8; 3],
    /// BDIS confidence of the pixel it came from, in [0, 1].
    pub confidence: f32,
    /// Accumulated fusion weight (the confidence when it was made; more after [`Fusion::Weighted`]).
    pub weight: f32,
}

/// One keyframe's points and the pose that places them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KeyframeCloud {
    pub kf_id: u64,
    pub t_capture_ns: u64,
    pub world_from_camera: Isometry3<f64>,
    pub intrinsics: RectifiedCamera,
    pub points: Vec<MosaicPoint>,
    /// Axis-aligned bounds of `points` in the keyframe's frame (empty when min > max).
    pub bounds_min: [f32; 3],
    pub bounds_max: [f32; 3],
}

impl KeyframeCloud {
    fn update_bounds(&mut self) {
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in &self.points {
            for k in 0..3 {
                lo[k] = lo[k].min(p.xyz[k]);
                hi[k] = hi[k].max(p.xyz[k]);
            }
        }
        self.bounds_min = lo;
        self.bounds_max = hi;
    }

    /// Centre and radius of a sphere around the points, in world coordinates.
    fn bounding_sphere_world(&self) -> Option<(Point3<f64>, f64)> {
        if self.points.is_empty() {
            return None;
        }
        let lo = Vector3::from(self.bounds_min.map(f64::from));
        let hi = Vector3::from(self.bounds_max.map(f64::from));
        let centre = Point3::from((lo + hi) * 0.5);
        Some((self.world_from_camera * centre, (hi - lo).norm() * 0.5))
    }
}

/// What one keyframe did to the map.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct InsertReport {
    /// This keyframe id was already in the map (a replacement stereo instance sent it again): nothing changed.
    pub duplicate: bool,
    pub added: usize,
    /// Earlier points replaced (or folded into new points) because the new view saw their surface.
    pub removed: usize,
    /// Earlier points that projected onto the new valid depth but lay behind it, so were kept.
    pub kept_occluded: usize,
    /// Earlier points that agreed with the new surface but had been seen from closer, so were kept (and the new
    /// view added nothing in their cells).
    pub kept_closer: usize,
    /// Earlier keyframes whose bounds intersected the new view (their points were tested).
    pub overlapping_keyframes: usize,
    /// Earlier points tested against the new view.
    pub tested: usize,
    /// New points dropped because an earlier keyframe saw through them (see `carve_disparity_px`).
    pub seen_through: usize,
    /// Before this keyframe: the overlap rule run again on keyframes that corrections had moved
    /// ([`Mosaic::realign`]).
    pub realigned: Realigned,
}

/// The whole map: keyframe clouds by id, and the newest pose correction of every keyframe seen so far (a
/// correction may arrive before the keyframe's depth does).
#[derive(Debug, Clone)]
pub struct Mosaic {
    pub params: MosaicParams,
    keyframes: BTreeMap<u64, KeyframeCloud>,
    corrections: BTreeMap<u64, Isometry3<f64>>,
    /// Reused per keyframe: the new view's valid depth per pixel (NaN = none), and the fusion accumulators per
    /// grid cell.
    depth_scratch: Vec<f32>,
    fuse_weight: Vec<f32>,
    fuse_weighted_offset: Vec<f32>,
    /// Grid cells of the new view where an earlier, closer point was kept: no new point there.
    covered: Vec<bool>,
    /// What each keyframe saw (its depth on its grid), to test later keyframes' points against.
    seen: BTreeMap<u64, carve::SeenDepth>,
    /// Reused per keyframe: the earlier keyframes the new view overlaps.
    overlapping: Vec<u64>,
    /// Reused by [`Mosaic::realign`]: the keyframes moved since, and every keyframe id in order.
    moved: Vec<u64>,
    ids: Vec<u64>,
}

pub(crate) fn check_pose(kf_id: u64, pose: &Isometry3<f64>) -> Result<(), MosaicError> {
    let q = pose.rotation.quaternion();
    let finite = pose.translation.vector.iter().chain(q.coords.iter()).all(|v| v.is_finite());
    if !finite || (q.norm() - 1.0).abs() > 1e-6 {
        return Err(MosaicError::BadPose { kf_id });
    }
    Ok(())
}

impl Mosaic {
    pub fn new(params: MosaicParams) -> Self {
        Self {
            params,
            keyframes: BTreeMap::new(),
            corrections: BTreeMap::new(),
            depth_scratch: Vec::new(),
            fuse_weight: Vec::new(),
            fuse_weighted_offset: Vec::new(),
            covered: Vec::new(),
            seen: BTreeMap::new(),
            overlapping: Vec::new(),
            moved: Vec::new(),
            ids: Vec::new(),
        }
    }

    pub fn keyframes(&self) -> impl Iterator<Item = &KeyframeCloud> {
        self.keyframes.values()
    }

    pub fn keyframe(&self, kf_id: u64) -> Option<&KeyframeCloud> {
        self.keyframes.get(&kf_id)
    }

    pub fn n_keyframes(&self) -> usize {
        self.keyframes.len()
    }

    /// Whether the map has keyframe `kf_id` (a depth keyframe with this id again is a duplicate).
    pub fn contains(&self, kf_id: u64) -> bool {
        self.keyframes.contains_key(&kf_id)
    }

    pub fn n_points(&self) -> usize {
        self.keyframes.values().map(|k| k.points.len()).sum()
    }

    /// A keyframe's pose was corrected (bundle adjustment): its points move with it. Kept for a keyframe whose
    /// depth has not arrived yet. Returns whether points moved.
    pub fn correct_pose(&mut self, kf_id: u64, world_from_camera: Isometry3<f64>) -> Result<bool, MosaicError> {
        check_pose(kf_id, &world_from_camera)?;
        self.corrections.insert(kf_id, world_from_camera);
        Ok(match self.keyframes.get_mut(&kf_id) {
            Some(kf) => {
                kf.world_from_camera = world_from_camera;
                true
            }
            None => false,
        })
    }

    /// Adds a depth keyframe: removes the earlier points its surface replaces, then lifts its own points.
    pub fn insert(&mut self, kf: &DepthKeyframe) -> Result<InsertReport, MosaicError> {
        let RectifiedCamera { fx, fy, cx, cy, bf, width, height } = kf.intrinsics;
        let (w, h) = (width as usize, height as usize);
        let n = w * h;
        let size_error = |what, actual| MosaicError::WrongSize { kf_id: kf.kf_id, what, actual, width, height };
        if kf.disparity.len() != n {
            return Err(size_error("disparity", kf.disparity.len()));
        }
        if kf.confidence.len() != n {
            return Err(size_error("confidence", kf.confidence.len()));
        }
        if kf.rgb.len() != 3 * n {
            return Err(size_error("rgb", kf.rgb.len()));
        }
        for (name, v) in [("fx", fx), ("fy", fy), ("bf", bf)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(MosaicError::BadIntrinsics { kf_id: kf.kf_id, what: format!("{name} = {v}") });
            }
        }
        if !(cx.is_finite() && cy.is_finite()) {
            return Err(MosaicError::BadIntrinsics { kf_id: kf.kf_id, what: "cx, cy not finite".into() });
        }
        if self.keyframes.contains_key(&kf.kf_id) {
            return Ok(InsertReport { duplicate: true, ..Default::default() });
        }
        // The rule below runs with the current poses; where corrections since the last keyframe moved earlier
        // keyframes relative to each other, it runs again between them first.
        let realigned = self.realign();
        // A correction that arrived before the depth is newer than the pose the keyframe was published with.
        let world_from_camera = self.corrections.get(&kf.kf_id).copied().unwrap_or(kf.world_from_camera);
        check_pose(kf.kf_id, &world_from_camera)?;
        // Pixel parameters at this keyframe's size (an HD keyframe's grid and margins are wider).
        let p = self.params.for_size(w, h);
        let gap = p.depth_gap_px.max(1);

        // The new view's usable depth, per pixel.
        self.depth_scratch.clear();
        self.depth_scratch.resize(n, f32::NAN);
        let min_disparity = p.min_disparity_px.max(f32::MIN_POSITIVE);
        for i in 0..n {
            let d = kf.disparity[i];
            let rgb = &kf.rgb[3 * i..3 * i + 3];
            let lit = rgb.iter().any(|&c| c >= p.min_colour);
            if d.is_finite() && d >= min_disparity && kf.confidence[i] >= p.min_confidence && lit {
                self.depth_scratch[i] = (bf / f64::from(d)) as f32;
            }
        }
        let (gw, gh) = (w.div_ceil(gap), h.div_ceil(gap));
        let fuse = p.fusion == Fusion::Weighted;
        self.covered.clear();
        self.covered.resize(gw * gh, false);
        if fuse {
            self.fuse_weight.clear();
            self.fuse_weight.resize(gw * gh, 0.0);
            self.fuse_weighted_offset.clear();
            self.fuse_weighted_offset.resize(gw * gh, 0.0);
        }

        let mut report = InsertReport { realigned, ..InsertReport::default() };
        let camera_from_world = world_from_camera.inverse();
        let frustum = Frustum::new(&kf.intrinsics);
        self.overlapping.clear();
        for old in self.keyframes.values_mut() {
            let Some((centre_world, radius)) = old.bounding_sphere_world() else { continue };
            if !frustum.may_contain(&(camera_from_world * centre_world), radius) {
                continue;
            }
            self.overlapping.push(old.kf_id);
            report.overlapping_keyframes += 1;
            report.tested += old.points.len();
            let new_from_old = camera_from_world * old.world_from_camera;
            let rotation: Matrix3<f32> = new_from_old.rotation.to_rotation_matrix().matrix().cast();
            let translation: Vector3<f32> = new_from_old.translation.vector.cast();
            let (fxf, fyf, cxf, cyf) = (fx as f32, fy as f32, cx as f32, cy as f32);
            let test = realign::DepthTest::new(&p, bf);
            let depth = &self.depth_scratch;
            let (fuse_weight, fuse_weighted_offset) = (&mut self.fuse_weight, &mut self.fuse_weighted_offset);
            let covered = &mut self.covered;
            let mut kept_closer = 0usize;
            let before = old.points.len();
            let mut kept_occluded = 0usize;
            old.points.retain(|pt| {
                let q = rotation * Vector3::from(pt.xyz) + translation;
                if q.z <= 0.0 {
                    return true;
                }
                let (u_exact, v_exact) = (fxf * q.x / q.z + cxf, fyf * q.y / q.z + cyf);
                let (u, v) = (u_exact.round(), v_exact.round());
                if !(u >= 0.0 && v >= 0.0 && (u as usize) < w && (v as usize) < h) {
                    return true;
                }
                let (u, v) = (u as usize, v as usize);
                let z_new = depth[v * w + u];
                if !z_new.is_finite() {
                    return true;
                }
                // The grid cell of the new view this earlier point falls in.
                let cell = ((v + gap / 2) / gap).min(gh - 1) * gw + ((u + gap / 2) / gap).min(gw - 1);
                let agrees = match test.verdict(q.z, z_new, pt.xyz[2]) {
                    realign::Verdict::Occluded => {
                        kept_occluded += 1;
                        return true;
                    }
                    realign::Verdict::SeenCloser => {
                        covered[cell] = true;
                        kept_closer += 1;
                        return true;
                    }
                    realign::Verdict::Replaced { agrees } => agrees,
                };
                if fuse && agrees {
                    fuse_weight[cell] += pt.weight;
                    // How far it lies from the new surface where it falls (not the raw depth: on a slope, a point
                    // off the cell's centre has another depth than the surface there), carried to the centre.
                    let surface = bilinear(depth, w, h, u_exact, v_exact).unwrap_or(z_new);
                    fuse_weighted_offset[cell] += pt.weight * (q.z - surface);
                }
                false
            });
            report.kept_occluded += kept_occluded;
            report.kept_closer += kept_closer;
            let removed = before - old.points.len();
            report.removed += removed;
            if removed > 0 {
                old.update_bounds();
            }
        }
        // Lift the new points: pixel centres at integer coordinates, fy for rows (the original used fx).
        let mut cloud = KeyframeCloud {
            kf_id: kf.kf_id,
            t_capture_ns: kf.t_capture_ns,
            world_from_camera,
            intrinsics: kf.intrinsics,
            points: Vec::with_capacity(gw * gh),
            bounds_min: [0.0; 3],
            bounds_max: [0.0; 3],
        };
        for v in (0..h).step_by(gap) {
            for u in (0..w).step_by(gap) {
                let i = v * w + u;
                let mut z = self.depth_scratch[i];
                if !z.is_finite() || self.covered[(v / gap) * gw + u / gap] {
                    continue;
                }
                let confidence = kf.confidence[i];
                let mut weight = confidence.max(1e-3);
                if fuse {
                    let cell = (v / gap) * gw + u / gap;
                    let w_old = self.fuse_weight[cell];
                    if w_old > 0.0 {
                        // The weighted mean of this view's depth and the earlier points', each carried to the cell's
                        // centre along this view's surface: z plus their weighted offsets from it.
                        z += self.fuse_weighted_offset[cell] / (weight + w_old);
                        weight = (weight + w_old).min(p.max_weight);
                    }
                }
                let x = (u as f64 - cx) * f64::from(z) / fx;
                let y = (v as f64 - cy) * f64::from(z) / fy;
                cloud.points.push(MosaicPoint {
                    xyz: [x as f32, y as f32, z],
                    rgb: [kf.rgb[3 * i], kf.rgb[3 * i + 1], kf.rgb[3 * i + 2]],
                    confidence,
                    weight,
                });
            }
        }
        // Free space: earlier views of the place that saw through a new point (the existing test above did the
        // converse, this view seeing through earlier points).
        if p.carve_disparity_px > 0.0 {
            for kf_id in &self.overlapping {
                if let (Some(seen), Some(old)) = (self.seen.get(kf_id), self.keyframes.get(kf_id)) {
                    report.seen_through += seen.carve(
                        &mut cloud.points,
                        |pt| pt.xyz,
                        &world_from_camera,
                        &old.world_from_camera,
                        &old.intrinsics,
                        p.carve_disparity_px,
                    );
                }
            }
        }
        self.seen.insert(kf.kf_id, carve::SeenDepth::sample(&self.depth_scratch, w, h, gap, world_from_camera));
        report.added = cloud.points.len();
        cloud.update_bounds();
        // Kept even when empty (all dark, or all replaced later): the id stays known, so a keyframe sent again is
        // recognised as a duplicate; an empty cloud costs one bounds check per new keyframe.
        self.keyframes.insert(kf.kf_id, cloud);
        Ok(report)
    }

    /// Every point in world coordinates, with its keyframe id and confidence, ready for PLY.
    pub fn world_cloud(&self) -> bdis_core::formats::ply::PointCloud {
        let n = self.n_points();
        let mut positions = Vec::with_capacity(n);
        let mut colors = Vec::with_capacity(n);
        let (mut kf_ids, mut confidence) = (Vec::with_capacity(n), Vec::with_capacity(n));
        self.for_each_world_point(|xyz, pt, kf| {
            positions.push(xyz);
            colors.push(pt.rgb);
            // A float property: exact for ids below 2^24 (16 million keyframes).
            kf_ids.push(kf as f32);
            confidence.push(pt.confidence);
        });
        bdis_core::formats::ply::PointCloud {
            positions,
            colors: Some(colors),
            scalars: vec![("keyframe_id".into(), kf_ids), ("confidence".into(), confidence)],
            faces: Vec::new(),
        }
    }

    /// Calls `f(world xyz, point, keyframe id)` for every point.
    pub fn for_each_world_point(&self, mut f: impl FnMut([f32; 3], &MosaicPoint, u64)) {
        for kf in self.keyframes.values() {
            let rotation: Matrix3<f64> = *kf.world_from_camera.rotation.to_rotation_matrix().matrix();
            let translation = kf.world_from_camera.translation.vector;
            for pt in &kf.points {
                let q = rotation * Vector3::from(pt.xyz.map(f64::from)) + translation;
                f([q.x as f32, q.y as f32, q.z as f32], pt, kf.kf_id);
            }
        }
    }

    /// Restores a saved map (see [`load`]).
    pub fn from_parts(
        params: MosaicParams,
        keyframes: Vec<KeyframeCloud>,
        corrections: Vec<(u64, Isometry3<f64>)>,
    ) -> Self {
        let mut m = Self::new(params);
        // Bounds are derived data: recomputed rather than trusted from the file.
        m.keyframes = keyframes
            .into_iter()
            .map(|mut k| {
                k.update_bounds();
                (k.kf_id, k)
            })
            .collect();
        m.corrections = corrections.into_iter().collect();
        m
    }

    pub fn corrections(&self) -> impl Iterator<Item = (u64, &Isometry3<f64>)> {
        self.corrections.iter().map(|(k, p)| (*k, p))
    }
}

/// `depth` (`w × h`, NaN = none) at sub-pixel (`u`, `v`), when the four pixels around it all have depth. A
/// position within half a pixel outside the image (a point that rounds onto its border) is taken at the border.
fn bilinear(depth: &[f32], w: usize, h: usize, u: f32, v: f32) -> Option<f32> {
    if w < 2 || h < 2 {
        return None;
    }
    let (u, v) = (u.clamp(0.0, (w - 1) as f32), v.clamp(0.0, (h - 1) as f32));
    let (u0, v0) = ((u.floor() as usize).min(w - 2), (v.floor() as usize).min(h - 2));
    let (a, b) = (u - u0 as f32, v - v0 as f32);
    let at = |x: usize, y: usize| depth[y * w + x];
    let z = (1.0 - b) * ((1.0 - a) * at(u0, v0) + a * at(u0 + 1, v0))
        + b * ((1.0 - a) * at(u0, v0 + 1) + a * at(u0 + 1, v0 + 1));
    z.is_finite().then_some(z)
}

/// The new view's frustum as four side planes through the camera centre plus z > 0, for a sphere test.
#[derive(Debug, Clone, Copy)]
struct Frustum {
    /// Inward unit normals of the left, right, top, bottom planes (camera frame).
    normals: [Vector3<f64>; 4],
}

impl Frustum {
    fn new(k: &RectifiedCamera) -> Self {
        // Image borders at -0.5 and size - 0.5 (pixel centres at integers): x/z from (−0.5 − cx)/fx to
        // (w − 0.5 − cx)/fx.
        let left = (-0.5 - k.cx) / k.fx;
        let right = (f64::from(k.width) - 0.5 - k.cx) / k.fx;
        let top = (-0.5 - k.cy) / k.fy;
        let bottom = (f64::from(k.height) - 0.5 - k.cy) / k.fy;
        Self {
            normals: [
                Vector3::new(1.0, 0.0, -left).normalize(),
                Vector3::new(-1.0, 0.0, right).normalize(),
                Vector3::new(0.0, 1.0, -top).normalize(),
                Vector3::new(0.0, -1.0, bottom).normalize(),
            ],
        }
    }

    fn may_contain(&self, centre: &Point3<f64>, radius: f64) -> bool {
        centre.z + radius > 0.0 && self.normals.iter().all(|n| n.dot(&centre.coords) >= -radius)
    }
}

#[cfg(test)]
mod tests;
