#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Rectifying a frame allocates nothing: the maps are built once, the remap writes into the caller's buffer.

use bdis_rectify::{CameraModel, RectifyMap, StereoCalibration, stereo_rectify};
use nalgebra::{Matrix3, Vector3};

#[global_allocator]
static GLOBAL: bdis_testkit::CountingAllocator = bdis_testkit::CountingAllocator;

#[test]
fn a_rectified_pair_allocates_nothing() {
    let camera = CameraModel {
        k: Matrix3::new(520.0, 0.0, 320.0, 0.0, 520.0, 240.0, 0.0, 0.0, 1.0),
        distortion: [-0.2, 0.05, 0.001, 0.0, 0.0, 0.0, 0.0, 0.0],
    };
    let calib = StereoCalibration {
        source: "test".into(),
        left: camera,
        right: camera,
        rotation: nalgebra::Rotation3::from_scaled_axis(Vector3::new(0.0, 0.01, 0.0)).into_inner(),
        translation: Vector3::new(-5.0, 0.0, 0.0),
        size: Some((640, 480)),
        given: None,
    };
    let rect = stereo_rectify(&calib, (640, 480), None);
    let left = RectifyMap::new(&calib.left, &rect.r_left, &rect.p_left, (640, 480), (640, 480));
    let right = RectifyMap::new(&calib.right, &rect.r_right, &rect.p_right, (640, 480), (640, 480));
    let raw: Vec<u8> = (0..640 * 480 * 3).map(|i| (i * 7 % 256) as u8).collect();
    let (mut out_left, mut out_right) = (vec![0u8; 640 * 480 * 3], vec![0u8; 640 * 480 * 3]);
    let before = bdis_testkit::allocations();
    for _ in 0..3 {
        left.remap(&raw, 3, &mut out_left);
        right.remap(&raw, 3, &mut out_right);
    }
    assert_eq!(bdis_testkit::allocations(), before, "the remap allocated");
    assert!(out_left.iter().any(|v| *v != 0));
}
