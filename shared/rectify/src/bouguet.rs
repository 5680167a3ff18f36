//! Bouguet's stereo rectification, as OpenCV's `stereoRectify` computes it with `CALIB_ZERO_DISPARITY`:
//! each camera turns by half the relative rotation so that both look the same way, then both turn together so
//! that the baseline lies along x (or y for a vertical rig); one focal length for both (the mean of the two
//! cameras' focal lengths across the baseline); one principal point for both, placed so that the image
//! corners' mean stays at the image centre; and `alpha` scales between keeping only valid pixels (0) and
//! keeping every source pixel (1), or leaves the scale alone when it is `None` (OpenCV's −1).

use crate::calib::{CameraModel, StereoCalibration};
use bdis_core::calib::RectifiedCamera;
use nalgebra::{Matrix3, Matrix3x4, Matrix4, Rotation3, Vector3};

/// The rectification of a stereo pair, in OpenCV's terms (R1 R2 P1 P2 Q), and the rectified camera the
/// pipeline computes with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rectification {
    /// Rotation from each raw camera frame into its rectified frame.
    pub r_left: Matrix3<f64>,
    pub r_right: Matrix3<f64>,
    /// Projection of a rectified-left-frame point into each rectified image.
    pub p_left: Matrix3x4<f64>,
    pub p_right: Matrix3x4<f64>,
    /// Disparity-to-depth: (u, v, d, 1) ↦ homogeneous (X, Y, Z) in the rectified left frame.
    pub q: Matrix4<f64>,
    /// The baseline lies along y (a vertical rig): the tracker needs a horizontal one.
    pub vertical: bool,
    /// The rectified image size.
    pub size: (u32, u32),
}

impl Rectification {
    /// The rectified camera (`bf` = focal × baseline, in the calibration's unit of length); `None` for a
    /// vertical rig.
    pub fn camera(&self) -> Option<RectifiedCamera> {
        let p = &self.p_right;
        (!self.vertical).then(|| RectifiedCamera {
            fx: p[(0, 0)],
            fy: p[(1, 1)],
            cx: p[(0, 2)],
            cy: p[(1, 2)],
            bf: -p[(0, 3)],
            width: self.size.0,
            height: self.size.1,
        })
    }

    /// The rectification a file gives (ORB-SLAM2's `LEFT.R/P`, `RIGHT.R/P`), at `size`.
    pub fn given(g: &crate::calib::GivenRectification, size: (u32, u32)) -> Self {
        let (fx, cx, cy) = (g.p_left[(0, 0)], g.p_left[(0, 2)], g.p_left[(1, 2)]);
        let tx = g.p_right[(0, 3)] / g.p_right[(0, 0)];
        let vertical = g.p_right[(0, 3)] == 0.0 && g.p_right[(1, 3)] != 0.0;
        Self {
            r_left: g.r_left,
            r_right: g.r_right,
            p_left: g.p_left,
            p_right: g.p_right,
            q: disparity_to_depth(fx, cx, cy, g.p_right[(0, 2)], tx),
            vertical,
            size,
        }
    }
}

fn disparity_to_depth(f: f64, cx_left: f64, cy: f64, cx_right: f64, tx: f64) -> Matrix4<f64> {
    Matrix4::new(
        1.0,
        0.0,
        0.0,
        -cx_left, //
        0.0,
        1.0,
        0.0,
        -cy, //
        0.0,
        0.0,
        0.0,
        f, //
        0.0,
        0.0,
        -1.0 / tx,
        (cx_left - cx_right) / tx,
    )
}

/// Where the pixel (u, v) of `camera` lands in a rectified image of rotation `r`, focal `f` and principal
/// point `c` (OpenCV's `undistortPoints` with R and P).
fn rectified_pixel(camera: &CameraModel, r: &Matrix3<f64>, f: f64, c: (f64, f64), u: f64, v: f64) -> (f64, f64) {
    let (x, y) = camera.undistort_opencv(u, v);
    let p = r * Vector3::new(x, y, 1.0);
    (f * p.x / p.z + c.0, f * p.y / p.z + c.1)
}

/// Bouguet's rectification of `calib` for images of `size` (see the module's description).
pub fn stereo_rectify(calib: &StereoCalibration, size: (u32, u32), alpha: Option<f64>) -> Rectification {
    let (w, h) = (f64::from(size.0), f64::from(size.1));
    // Half the relative rotation each: the right camera turns back by half of R, the left forward by half.
    let half_back =
        Rotation3::from_scaled_axis(-Rotation3::from_matrix_unchecked(calib.rotation).scaled_axis() * 0.5).into_inner();
    let t = half_back * calib.translation;
    let along = if t.x.abs() > t.y.abs() { 0 } else { 1 };
    // Then both turn together by the smallest rotation that lays the baseline on its axis.
    let mut axis_dir = Vector3::zeros();
    axis_dir[along] = if t[along] > 0.0 { 1.0 } else { -1.0 };
    let cross = t.cross(&axis_dir);
    let onto_axis = if cross.norm() > 0.0 {
        let angle = (t[along].abs() / t.norm()).clamp(-1.0, 1.0).acos();
        Rotation3::from_scaled_axis(cross * (angle / cross.norm())).into_inner()
    } else {
        Matrix3::identity()
    };
    let r_left = onto_axis * half_back.transpose();
    let r_right = onto_axis * half_back;
    let t_rect = r_right * calib.translation;

    // One focal length: the mean of both cameras' across the baseline (fy for a horizontal rig).
    let across = 1 - along;
    let mut f = 0.5 * (calib.left.k[(across, across)] + calib.right.k[(across, across)]);
    // One principal point: where each camera's image corners are centred on average, then both averaged
    // (zero disparity at infinity).
    let corners = [(0.0, 0.0), (w - 1.0, 0.0), (0.0, h - 1.0), (w - 1.0, h - 1.0)];
    let centre_of = |camera: &CameraModel, r: &Matrix3<f64>, f: f64| {
        let (mut sx, mut sy) = (0.0, 0.0);
        for (u, v) in corners {
            let (x, y) = rectified_pixel(camera, r, f, (0.0, 0.0), u, v);
            sx += x;
            sy += y;
        }
        ((w - 1.0) * 0.5 - sx / 4.0, (h - 1.0) * 0.5 - sy / 4.0)
    };
    let (a, b) = (centre_of(&calib.left, &r_left, f), centre_of(&calib.right, &r_right, f));
    // (`alpha` below scales about this point and leaves it in place.)
    let c = ((a.0 + b.0) * 0.5, (a.1 + b.1) * 0.5);

    if let Some(alpha) = alpha {
        // Scale about the principal point between the largest rectangle of valid pixels (alpha 0) and the
        // bounding box of every source pixel (alpha 1), from a 9 × 9 grid over each source image.
        let (mut s_inner, mut s_outer) = (0.0f64, f64::INFINITY);
        for (camera, r) in [(&calib.left, &r_left), (&calib.right, &r_right)] {
            const N: usize = 9;
            let mut grid = [[(0.0, 0.0); N]; N];
            for (i, row) in grid.iter_mut().enumerate() {
                for (j, p) in row.iter_mut().enumerate() {
                    let (u, v) = (j as f64 * (w - 1.0) / (N - 1) as f64, i as f64 * (h - 1.0) / (N - 1) as f64);
                    *p = rectified_pixel(camera, r, f, c, u, v);
                }
            }
            let all = grid.iter().flatten();
            let outer_x0 = all.clone().map(|p| p.0).fold(f64::INFINITY, f64::min);
            let outer_x1 = all.clone().map(|p| p.0).fold(f64::NEG_INFINITY, f64::max);
            let outer_y0 = all.clone().map(|p| p.1).fold(f64::INFINITY, f64::min);
            let outer_y1 = all.map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
            let inner_x0 = grid.iter().map(|row| row[0].0).fold(f64::NEG_INFINITY, f64::max);
            let inner_x1 = grid.iter().map(|row| row[N - 1].0).fold(f64::INFINITY, f64::min);
            let inner_y0 = grid[0].iter().map(|p| p.1).fold(f64::NEG_INFINITY, f64::max);
            let inner_y1 = grid[N - 1].iter().map(|p| p.1).fold(f64::INFINITY, f64::min);
            let scale = |x0: f64, x1: f64, y0: f64, y1: f64| {
                [c.0 / (c.0 - x0), c.1 / (c.1 - y0), (w - 1.0 - c.0) / (x1 - c.0), (h - 1.0 - c.1) / (y1 - c.1)]
            };
            for s in scale(inner_x0, inner_x1, inner_y0, inner_y1) {
                s_inner = s_inner.max(s);
            }
            for s in scale(outer_x0, outer_x1, outer_y0, outer_y1) {
                s_outer = s_outer.min(s);
            }
        }
        let s = s_inner * (1.0 - alpha) + s_outer * alpha;
        f *= s;
    }

    let mut p_left = Matrix3x4::zeros();
    p_left[(0, 0)] = f;
    p_left[(1, 1)] = f;
    p_left[(0, 2)] = c.0;
    p_left[(1, 2)] = c.1;
    p_left[(2, 2)] = 1.0;
    let mut p_right = p_left;
    p_right[(along, 3)] = t_rect[along] * f;
    // Zero disparity at infinity: both principal points are one, so Q's last entry is 0. For a vertical rig Q
    // works on the vertical disparity with the same layout (OpenCV's convention).
    let q = disparity_to_depth(f, c.0, c.1, c.0, t_rect[along]);
    Rectification { r_left, r_right, p_left, p_right, q, vertical: along == 1, size }
}

/// A rectification the pipeline can use: every matrix finite, a positive focal length and a baseline. A
/// calibration whose distortion folds the image over itself can give neither.
pub fn rectification_is_usable(rect: &Rectification) -> bool {
    let finite = |m: &[f64]| m.iter().all(|v| v.is_finite());
    finite(rect.r_left.as_slice())
        && finite(rect.r_right.as_slice())
        && finite(rect.p_left.as_slice())
        && finite(rect.p_right.as_slice())
        && rect.p_left[(0, 0)] > 0.0
        && rect.p_left[(1, 1)] > 0.0
        && rect.p_right[(0, 3)].abs() + rect.p_right[(1, 3)].abs() > 0.0
}
