//! The stereo camera: what a settings file says ([`StereoCamera`]: intrinsics, distortion, an optional image
//! size) and the checked, rectified camera of known size every stage computes with ([`RectifiedCamera`]).

use nalgebra::{Point2, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// Radial-tangential distortion (OpenCV order k1 k2 p1 p2 k3). The pipeline expects rectified images, so these
/// are all zero for the bundled sets; they are kept so a settings file round-trips.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Distortion {
    pub k1: f64,
    pub k2: f64,
    pub p1: f64,
    pub p2: f64,
    pub k3: f64,
}

impl Distortion {
    pub fn is_zero(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2, self.k3].iter().all(|v| *v == 0.0)
    }
}

/// A rectified stereo pair: the left camera's pinhole intrinsics and `bf = fx · baseline`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StereoCamera {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// `fx · baseline`, in pixels × the map unit (millimetres for endoscopes).
    pub bf: f64,
    pub distortion: Distortion,
    /// Image size in pixels when the settings give it; checked against the images.
    pub width: Option<u32>,
    pub height: Option<u32>,
}

impl StereoCamera {
    /// The stereo baseline in the map unit.
    pub fn baseline(&self) -> f64 {
        self.bf / self.fx
    }

    /// Depth of a disparity `d = x_left − x_right` (pixels); `None` when `d ≤ 0` or not finite.
    pub fn depth_from_disparity(&self, disparity_px: f64) -> Option<f64> {
        (disparity_px.is_finite() && disparity_px > 0.0).then(|| self.bf / disparity_px)
    }

    /// Projects a point in the left camera frame (x right, y down, z forward) to pixels; `None` behind the camera.
    pub fn project(&self, p: &Point3<f64>) -> Option<Point2<f64>> {
        (p.z > 0.0).then(|| Point2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
    }

    /// The point at depth `z` seen at pixel `px` in the left camera.
    pub fn unproject(&self, px: &Point2<f64>, z: f64) -> Point3<f64> {
        Point3::new((px.x - self.cx) * z / self.fx, (px.y - self.cy) * z / self.fy, z)
    }

    /// The rectified camera of a `width` × `height` image, when the images are rectified (no distortion).
    pub fn rectified(&self, width: u32, height: u32) -> Option<RectifiedCamera> {
        self.distortion.is_zero().then_some(RectifiedCamera {
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            bf: self.bf,
            width,
            height,
        })
    }
}

/// A rectified stereo camera of known image size: the left camera's pinhole intrinsics and `bf = fx · baseline`
/// (pixels × the map unit), no distortion. The one camera type of the tracker, the dense map, the renderer and
/// the messages between them (`bdis_ipc::StereoIntrinsics` is its shared-memory form).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RectifiedCamera {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    /// `fx · baseline`; depth = bf / disparity.
    pub bf: f64,
    pub width: u32,
    pub height: u32,
}

impl RectifiedCamera {
    /// The stereo baseline in the map unit.
    pub fn baseline(&self) -> f64 {
        self.bf / self.fx
    }

    /// (u, v) of a camera-frame point (z must be > 0).
    pub fn project(&self, p: &Point3<f64>) -> (f64, f64) {
        let iz = 1.0 / p.z;
        (self.fx * p.x * iz + self.cx, self.fy * p.y * iz + self.cy)
    }

    /// (u_L, v, u_R) of a camera-frame point.
    pub fn project_stereo(&self, p: &Point3<f64>) -> Vector3<f64> {
        let (u, v) = self.project(p);
        Vector3::new(u, v, u - self.bf / p.z)
    }

    /// The camera-frame point at pixel (u, v) and depth z.
    pub fn unproject(&self, u: f64, v: f64, z: f64) -> Point3<f64> {
        Point3::new((u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z)
    }

    pub fn in_image(&self, u: f64, v: f64) -> bool {
        u >= 0.0 && v >= 0.0 && u < f64::from(self.width) && v < f64::from(self.height)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_unproject_round_trip_and_depth() {
        let cam = StereoCamera {
            fx: 520.0,
            fy: 510.0,
            cx: 320.0,
            cy: 240.0,
            bf: 260.0,
            distortion: Distortion::default(),
            width: None,
            height: None,
        };
        let p = Point3::new(1.5, -2.0, 40.0);
        let px = cam.project(&p).unwrap();
        let back = cam.unproject(&px, 40.0);
        assert!((back - p).norm() < 1e-12);
        assert_eq!(cam.baseline(), 0.5);
        assert_eq!(cam.depth_from_disparity(13.0), Some(20.0));
        assert_eq!(cam.depth_from_disparity(0.0), None);
        assert_eq!(cam.depth_from_disparity(f64::NAN), None);
        assert!(cam.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
    }
}
