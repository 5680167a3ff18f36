//! The raw stereo calibration and its OpenCV FileStorage YAML readers (the other layouts are in
//! `formats.rs`):
//! - the SCARED layout (`M1 D1 M2 D2 R T`, optional `width`/`height` or `imageSize`), which needs rectifying;
//! - ORB-SLAM2 settings with `LEFT.K/D/R/P` and `RIGHT.*` blocks, which carry their rectification with them.

use bdis_core::settings::{RawSettings, SettingsError};
use nalgebra::{Matrix3, Matrix3x4, Vector3};
use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    #[error(transparent)]
    Settings(#[from] SettingsError),
    #[error("{path}: not a stereo calibration this reader knows: {why}")]
    Format { path: PathBuf, why: String },
    #[error(
        "{path}: this calibration gives no usable rectification (non-finite or zero focal length or baseline): check the cameras' focal lengths and distortion, and T"
    )]
    Unusable { path: PathBuf },
}

/// A pinhole camera with OpenCV's distortion: `k` the intrinsic matrix (fx, skew, cx; fy, cy), `distortion`
/// k1 k2 p1 p2 k3 k4 k5 k6 (the rational model; the plain 5-coefficient model has k4 = k5 = k6 = 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraModel {
    pub k: Matrix3<f64>,
    pub distortion: [f64; 8],
}

impl CameraModel {
    /// Normalised, distorted image coordinates of the normalised undistorted point (x, y).
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3, k4, k5, k6] = self.distortion;
        let r2 = x * x + y * y;
        let radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)));
        (
            x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
        )
    }

    /// Pixel of the normalised undistorted point (x, y).
    pub fn project_normalised(&self, x: f64, y: f64) -> (f64, f64) {
        let (xd, yd) = self.distort(x, y);
        let k = &self.k;
        (k[(0, 0)] * xd + k[(0, 1)] * yd + k[(0, 2)], k[(1, 1)] * yd + k[(1, 2)])
    }

    /// The normalised undistorted point of pixel (u, v), solved to convergence (Newton's method on the
    /// distortion, from the undistorted guess); `None` where it does not converge (beyond the lens's field).
    pub fn undistort(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let k = &self.k;
        let yd = (v - k[(1, 2)]) / k[(1, 1)];
        let xd = (u - k[(0, 2)] - k[(0, 1)] * yd) / k[(0, 0)];
        let (mut x, mut y) = (xd, yd);
        const STEP: f64 = 1e-7;
        for _ in 0..50 {
            let (fx, fy) = self.distort(x, y);
            let (ex, ey) = (fx - xd, fy - yd);
            if ex.abs().max(ey.abs()) < 1e-13 {
                return Some((x, y));
            }
            let (ax, ay) = self.distort(x + STEP, y);
            let (bx, by) = self.distort(x, y + STEP);
            let (j00, j10, j01, j11) = ((ax - fx) / STEP, (ay - fy) / STEP, (bx - fx) / STEP, (by - fy) / STEP);
            let det = j00 * j11 - j01 * j10;
            if !det.is_finite() || det.abs() < 1e-12 {
                return None;
            }
            x -= (j11 * ex - j01 * ey) / det;
            y -= (-j10 * ex + j00 * ey) / det;
        }
        let (fx, fy) = self.distort(x, y);
        ((fx - xd).abs().max((fy - yd).abs()) < 1e-9).then_some((x, y))
    }

    /// The normalised undistorted point of pixel (u, v), by OpenCV's fixed-point iteration with its default
    /// of five steps. Five steps do not converge where the distortion is strong (at the corners of a wide
    /// lens the iteration even diverges if continued), but `stereoRectify` places the rectified principal
    /// point and scale with exactly these five steps, and a calibration must rectify the same here as there.
    pub fn undistort_opencv(&self, u: f64, v: f64) -> (f64, f64) {
        let [k1, k2, p1, p2, k3, k4, k5, k6] = self.distortion;
        let k = &self.k;
        let y0 = (v - k[(1, 2)]) / k[(1, 1)];
        let x0 = (u - k[(0, 2)] - k[(0, 1)] * y0) / k[(0, 0)];
        let (mut x, mut y) = (x0, y0);
        for _ in 0..5 {
            let r2 = x * x + y * y;
            let inverse_radial = (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))) / (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)));
            let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            x = (x0 - dx) * inverse_radial;
            y = (y0 - dy) * inverse_radial;
        }
        (x, y)
    }
}

/// What a stereo calibration file says.
#[derive(Debug, Clone, PartialEq)]
pub struct StereoCalibration {
    pub source: PathBuf,
    pub left: CameraModel,
    pub right: CameraModel,
    /// `X_right = rotation · X_left + translation`, in the calibration's unit of length.
    pub rotation: Matrix3<f64>,
    pub translation: Vector3<f64>,
    /// The image size the calibration was made at, when the file gives it.
    pub size: Option<(u32, u32)>,
    /// The rectification the file carries (ORB-SLAM2's `LEFT.R/P`, `RIGHT.R/P`), used as given.
    pub given: Option<GivenRectification>,
}

/// A rectification written in the file: per side the rotation into the rectified frame and the projection.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GivenRectification {
    pub r_left: Matrix3<f64>,
    pub r_right: Matrix3<f64>,
    pub p_left: Matrix3x4<f64>,
    pub p_right: Matrix3x4<f64>,
}

struct Fields<'a> {
    raw: &'a RawSettings,
}

impl Fields<'_> {
    fn matrix(&self, key: &'static str, shapes: &[(usize, usize)]) -> Result<Option<Vec<f64>>, SettingsError> {
        let Some(bdis_core::settings::MatrixEntry { rows, cols, data, line }) = self.raw.matrix(key)? else {
            return Ok(None);
        };
        if !shapes.contains(&(rows, cols)) {
            let expected: Vec<String> = shapes.iter().map(|(r, c)| format!("{r}×{c}")).collect();
            return Err(SettingsError::value(
                &self.raw.path,
                line,
                key,
                format!("expected a {} matrix, found {rows}×{cols}", expected.join(" or ")),
            ));
        }
        Ok(Some(data.to_vec()))
    }

    fn required(&self, key: &'static str, shapes: &[(usize, usize)]) -> Result<Vec<f64>, SettingsError> {
        self.matrix(key, shapes)?.ok_or_else(|| SettingsError::Missing { path: self.raw.path.clone(), key })
    }

    fn line(&self, key: &str) -> Option<usize> {
        self.raw.entries.get(key).and_then(|e| e.line)
    }

    fn camera(&self, k_key: &'static str, d_key: &'static str) -> Result<CameraModel, SettingsError> {
        let k = Matrix3::from_row_slice(&self.required(k_key, &[(3, 3)])?);
        let (fx, fy) = (k[(0, 0)], k[(1, 1)]);
        if !(fx > 0.0 && fy > 0.0) {
            let why = format!("focal lengths must be > 0, found fx {fx}, fy {fy}");
            return Err(SettingsError::value(&self.raw.path, self.line(k_key), k_key, why));
        }
        if k[(1, 0)] != 0.0 || k[(2, 0)] != 0.0 || k[(2, 1)] != 0.0 || k[(2, 2)] != 1.0 {
            let why = "not an intrinsic matrix: the lower rows must be [0 fy cy; 0 0 1]";
            return Err(SettingsError::value(&self.raw.path, self.line(k_key), k_key, why));
        }
        let shapes: Vec<(usize, usize)> = [4, 5, 8].iter().flat_map(|&n| [(1, n), (n, 1)]).collect();
        let d = self.matrix(d_key, &shapes)?.unwrap_or_default();
        let mut distortion = [0.0; 8];
        distortion[..d.len()].copy_from_slice(&d);
        Ok(CameraModel { k, distortion })
    }

    fn rotation(&self, key: &'static str) -> Result<Option<Matrix3<f64>>, SettingsError> {
        let Some(data) = self.matrix(key, &[(3, 3)])? else { return Ok(None) };
        let r = Matrix3::from_row_slice(&data);
        let off = (r.transpose() * r - Matrix3::identity()).abs().max();
        if off > 1e-6 || (r.determinant() - 1.0).abs() > 1e-6 {
            let why = format!("not a rotation (RᵀR differs from I by {off:.2e}, det {:.6})", r.determinant());
            return Err(SettingsError::value(&self.raw.path, self.line(key), key, why));
        }
        Ok(Some(r))
    }

    fn size(&self, w_key: &'static str, h_key: &'static str) -> Result<Option<(u32, u32)>, SettingsError> {
        let dim = |key: &'static str| -> Result<Option<u32>, SettingsError> {
            let Some((v, line)) = self.raw.number(key)? else { return Ok(None) };
            if v.fract() != 0.0 || v < 1.0 || v > f64::from(u32::MAX) {
                return Err(SettingsError::value(
                    &self.raw.path,
                    line,
                    key,
                    format!("must be a whole number ≥ 1, found {v}"),
                ));
            }
            Ok(Some(v as u32))
        };
        match (dim(w_key)?, dim(h_key)?) {
            (Some(w), Some(h)) => Ok(Some((w, h))),
            (None, None) => Ok(None),
            _ => Err(SettingsError::value(
                &self.raw.path,
                self.line(w_key).or(self.line(h_key)),
                w_key,
                "give the width and the height together",
            )),
        }
    }
}

impl StereoCalibration {
    pub fn from_raw(raw: &RawSettings) -> Result<Self, CalibrationError> {
        let f = Fields { raw };
        let has = |k: &str| raw.entries.contains_key(k);
        if has("M1") || has("M2") {
            let left = f.camera("M1", "D1")?;
            let right = f.camera("M2", "D2")?;
            let rotation = f.rotation("R")?.ok_or(SettingsError::Missing { path: raw.path.clone(), key: "R" })?;
            let translation = Vector3::from_column_slice(&f.required("T", &[(3, 1), (1, 3)])?);
            if translation.norm() <= 0.0 {
                let why = "the baseline is zero";
                return Err(SettingsError::value(&raw.path, f.line("T"), "T", why).into());
            }
            let size = match f.matrix("imageSize", &[(1, 2), (2, 1)])? {
                Some(v) => Some((v[0] as u32, v[1] as u32)),
                None => f.size("width", "height")?,
            };
            return Ok(Self { source: raw.path.clone(), left, right, rotation, translation, size, given: None });
        }
        if has("LEFT.K") || has("RIGHT.K") {
            let left = f.camera("LEFT.K", "LEFT.D")?;
            let right = f.camera("RIGHT.K", "RIGHT.D")?;
            let need_rotation = |key: &'static str| -> Result<Matrix3<f64>, CalibrationError> {
                Ok(f.rotation(key)?.ok_or(SettingsError::Missing { path: raw.path.clone(), key })?)
            };
            let (r_left, r_right) = (need_rotation("LEFT.R")?, need_rotation("RIGHT.R")?);
            let p_left = Matrix3x4::from_row_slice(&f.required("LEFT.P", &[(3, 4)])?);
            let p_right = Matrix3x4::from_row_slice(&f.required("RIGHT.P", &[(3, 4)])?);
            // The rectified frames differ by a translation along x only: X_rect_right = X_rect_left + (tx, 0, 0)
            // with P_right[0][3] = fx·tx. Back in the raw frames: R = r_rightᵀ·r_left, T = r_rightᵀ·(tx, 0, 0).
            let fx = p_right[(0, 0)];
            if fx <= 0.0 {
                let why = format!("the rectified fx must be > 0, found {fx}");
                return Err(SettingsError::value(&raw.path, f.line("RIGHT.P"), "RIGHT.P", why).into());
            }
            let t_rect = Vector3::new(p_right[(0, 3)] / fx, 0.0, 0.0);
            let rotation = r_right.transpose() * r_left;
            let translation = r_right.transpose() * t_rect;
            let size = match f.size("LEFT.width", "LEFT.height")? {
                Some(s) => Some(s),
                None => f.size("Camera.width", "Camera.height")?,
            };
            let given = Some(GivenRectification { r_left, r_right, p_left, p_right });
            return Ok(Self { source: raw.path.clone(), left, right, rotation, translation, size, given });
        }
        Err(CalibrationError::Format {
            path: raw.path.clone(),
            why: "expected `M1 D1 M2 D2 R T` (OpenCV stereoCalibrate) or `LEFT.K/D/R/P` and `RIGHT.*` (ORB-SLAM2)"
                .into(),
        })
    }

    /// The baseline in the calibration's unit of length.
    pub fn baseline(&self) -> f64 {
        self.translation.norm()
    }

    /// Neither camera has distortion.
    pub fn distortion_free(&self) -> bool {
        self.left.distortion.iter().chain(&self.right.distortion).all(|v| *v == 0.0)
    }
}
