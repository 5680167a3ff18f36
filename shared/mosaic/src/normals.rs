//! Surface normals of a keyframe's points, from their neighbours on the grid they were lifted from: every point
//! sits on pixel (u, v) of its keyframe with u and v multiples of the grid gap, so the points to its right and
//! below on that grid span the surface's tangent plane. No neighbour search, no fitting: one pass per keyframe.

use nalgebra::Vector3;

use crate::KeyframeCloud;

/// A neighbour further than this share of the point's own depth is across a depth edge (an occluding contour),
/// not on the same surface: a ratio, so it holds in any unit and at any distance.
const SAME_SURFACE_DEPTH_RATIO: f32 = 0.08;

/// Unit normals of `cloud`'s points in its camera frame, one per point, turned towards the camera that saw
/// them. A point with no usable neighbour gets the direction back to the camera. `gap` is the grid step the
/// points were lifted with (`MosaicParams::depth_gap_px`). `grid` is scratch the caller may reuse.
pub fn keyframe_normals(cloud: &KeyframeCloud, gap: usize, grid: &mut Vec<u32>, normals: &mut Vec<[f32; 3]>) {
    normals.clear();
    let k = &cloud.intrinsics;
    let gap = gap.max(1);
    let (gw, gh) = ((k.width as usize).div_ceil(gap), (k.height as usize).div_ceil(gap));
    const EMPTY: u32 = u32::MAX;
    grid.clear();
    grid.resize(gw * gh, EMPTY);
    let cell_of = |p: &[f32; 3]| -> Option<(usize, usize)> {
        if p[2] <= 0.0 {
            return None;
        }
        let u = (k.fx * f64::from(p[0]) / f64::from(p[2]) + k.cx).round();
        let v = (k.fy * f64::from(p[1]) / f64::from(p[2]) + k.cy).round();
        let (gu, gv) = ((u / gap as f64).round(), (v / gap as f64).round());
        (gu >= 0.0 && gv >= 0.0 && (gu as usize) < gw && (gv as usize) < gh).then_some((gu as usize, gv as usize))
    };
    for (i, p) in cloud.points.iter().enumerate() {
        if let Some((gu, gv)) = cell_of(&p.xyz) {
            grid[gv * gw + gu] = i as u32;
        }
    }
    let point = |i: u32| Vector3::from(cloud.points[i as usize].xyz);
    for p in &cloud.points {
        let here = Vector3::from(p.xyz);
        let towards_camera = -here.normalize();
        let Some((gu, gv)) = cell_of(&p.xyz) else {
            normals.push(towards_camera.into());
            continue;
        };
        // The neighbour on each side along one grid axis, if it is on the same surface.
        let neighbour = |du: isize, dv: isize| -> Option<Vector3<f32>> {
            let (u, v) = (gu as isize + du, gv as isize + dv);
            if u < 0 || v < 0 || u >= gw as isize || v >= gh as isize {
                return None;
            }
            let j = grid[v as usize * gw + u as usize];
            if j == EMPTY {
                return None;
            }
            let q = point(j);
            ((q.z - here.z).abs() <= SAME_SURFACE_DEPTH_RATIO * here.z).then_some(q)
        };
        // Central differences where both sides are there, one-sided where one is.
        let along = |a: Option<Vector3<f32>>, b: Option<Vector3<f32>>| match (a, b) {
            (Some(a), Some(b)) => Some(b - a),
            (Some(a), None) => Some(here - a),
            (None, Some(b)) => Some(b - here),
            (None, None) => None,
        };
        let tangent_u = along(neighbour(-1, 0), neighbour(1, 0));
        let tangent_v = along(neighbour(0, -1), neighbour(0, 1));
        let normal = match (tangent_u, tangent_v) {
            (Some(tu), Some(tv)) => tu.cross(&tv).try_normalize(1e-12),
            _ => None,
        };
        let normal = match normal {
            Some(n) if n.dot(&towards_camera) < 0.0 => -n,
            Some(n) => n,
            None => towards_camera,
        };
        normals.push(normal.into());
    }
}
