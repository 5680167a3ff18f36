//! Free space: what a keyframe saw through. A point is transient — an instrument, smoke, a bad match, depth
//! smeared across an instrument's silhouette — when a view that looked at its place saw a surface farther
//! behind it: had the point been there, that view would have seen it instead. The mosaic already removes
//! earlier points a new view sees through (its depth test); this keeps each keyframe's depth on its point grid so
//! that a new keyframe's points are tested against every earlier view of the place too.

use nalgebra::{Isometry3, Matrix3, Vector3};

use crate::RectifiedCamera;

/// A keyframe's usable depth (the map's unit; NaN = none) at its point grid: every `gap`-th row and column.
#[derive(Debug, Clone, Default)]
pub(crate) struct SeenDepth {
    /// The keyframe's pose when the overlap rule last ran with this view ([`crate::Mosaic::realign`]).
    pub(crate) ruled_at: Isometry3<f64>,
    gap: usize,
    gw: usize,
    gh: usize,
    depth: Vec<f32>,
}

impl SeenDepth {
    /// Samples a view's per-pixel usable depth (`w × h`) at its grid; the view is at `world_from_camera`.
    pub(crate) fn sample(depth: &[f32], w: usize, h: usize, gap: usize, world_from_camera: Isometry3<f64>) -> Self {
        let (gw, gh) = (w.div_ceil(gap), h.div_ceil(gap));
        let mut grid = Vec::with_capacity(gw * gh);
        for v in (0..h).step_by(gap) {
            grid.extend((0..w).step_by(gap).map(|u| depth[v * w + u]));
        }
        Self { ruled_at: world_from_camera, gap, gw, gh, depth: grid }
    }

    /// Removes from `points` (camera frame of a new view at `world_from_new`) those this view — posed at
    /// `world_from_seen` with camera `k` — saw through: all four grid samples around the point's projection
    /// have depth, and even the nearest of them is farther than the point by more than `carve_disparity_px` of
    /// disparity (the nearest of four keeps a point on a depth edge). Returns how many were removed.
    pub(crate) fn carve<T>(
        &self,
        points: &mut Vec<T>,
        xyz: impl Fn(&T) -> [f32; 3],
        world_from_new: &Isometry3<f64>,
        world_from_seen: &Isometry3<f64>,
        k: &RectifiedCamera,
        carve_disparity_px: f32,
    ) -> usize {
        if self.depth.is_empty() {
            return 0;
        }
        let seen_from_new = world_from_seen.inverse() * world_from_new;
        let rotation: Matrix3<f32> = seen_from_new.rotation.to_rotation_matrix().matrix().cast();
        let translation: Vector3<f32> = seen_from_new.translation.vector.cast();
        let (fx, fy, cx, cy, bf) = (k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32, k.bf as f32);
        let before = points.len();
        points.retain(|pt| {
            let q = rotation * Vector3::from(xyz(pt)) + translation;
            if q.z <= 0.0 {
                return true;
            }
            let nearest = self.nearest_of_four(fx * q.x / q.z + cx, fy * q.y / q.z + cy);
            if !nearest.is_finite() {
                return true;
            }
            // In the seen view's disparity: the surface it saw is farther than the point by more than the margin.
            bf / nearest >= bf / q.z - carve_disparity_px
        });
        before - points.len()
    }

    /// The nearest depth among the four grid samples around pixel (`u`, `v`); NaN unless all four have depth.
    /// The nearest of four keeps a point on a depth edge: a surface it may belong to counts.
    pub(crate) fn nearest_of_four(&self, u: f32, v: f32) -> f32 {
        let gap = self.gap as f32;
        let (gu, gv) = (u / gap, v / gap);
        if !(gu >= 0.0 && gv >= 0.0) {
            return f32::NAN;
        }
        let (u0, v0) = (gu.floor() as usize, gv.floor() as usize);
        if u0 + 1 >= self.gw || v0 + 1 >= self.gh {
            return f32::NAN;
        }
        let mut nearest = f32::INFINITY;
        for (du, dv) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let z = self.depth[(v0 + dv) * self.gw + u0 + du];
            if !z.is_finite() {
                return f32::NAN;
            }
            nearest = nearest.min(z);
        }
        nearest
    }
}
