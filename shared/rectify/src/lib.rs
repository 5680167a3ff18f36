//! Stereo rectification written here, without OpenCV (issue #18): what a raw stereo calibration says
//! ([`StereoCalibration`]: two pinhole cameras with up to 8-coefficient rational distortion, and the right
//! camera's pose relative to the left), Bouguet's rectification as OpenCV's `stereoRectify` computes it
//! ([`stereo_rectify`], `CALIB_ZERO_DISPARITY`, `alpha`), the undistort–rectify map of each camera computed
//! once ([`RectifyMap`]), and a bilinear remap in fixed point that writes straight into the caller's buffer.
//!
//! Conventions are OpenCV's, so that calibrations from OpenCV-based tools mean the same here: a camera-frame
//! point `X_right = R · X_left + T`; distortion coefficients in the order k1 k2 p1 p2 k3 k4 k5 k6; pixel centres
//! at integer coordinates.

pub mod bouguet;
pub mod calib;
pub mod formats;
pub mod remap;

pub use bouguet::{Rectification, rectification_is_usable, stereo_rectify};
pub use calib::{CalibrationError, CameraModel, StereoCalibration};
pub use remap::{OutByte, RectifyMap};
