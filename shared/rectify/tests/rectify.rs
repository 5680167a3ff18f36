#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Properties of the rectification that need no reference implementation (the golden comparison with OpenCV
//! is `tests/rectify_golden.rs` at the top level): rectified rows line up, disparity is bf / depth, the map
//! samples the raw pixel the camera model puts the point at, and an undistorted identity rig is left alone.

use bdis_core::settings::RawSettings;
use bdis_rectify::{CameraModel, RectifyMap, StereoCalibration, stereo_rectify};
use nalgebra::{Matrix3, Point3, Rotation3, Vector3};
use std::path::Path;

fn camera(fx: f64, fy: f64, cx: f64, cy: f64, distortion: [f64; 8]) -> CameraModel {
    CameraModel { k: Matrix3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0), distortion }
}

fn rig(distortion: [f64; 8]) -> StereoCalibration {
    StereoCalibration {
        source: "test".into(),
        left: camera(520.0, 522.5, 318.2, 241.7, distortion),
        right: camera(515.3, 517.9, 325.1, 236.4, distortion),
        rotation: Rotation3::from_scaled_axis(Vector3::new(0.01, -0.02, 0.005)).into_inner(),
        translation: Vector3::new(-5.0, 0.1, 0.05),
        size: Some((640, 480)),
        given: None,
    }
}

/// The raw pixel of a left-frame point in each camera.
fn raw_pixels(calib: &StereoCalibration, x: &Point3<f64>) -> [(f64, f64); 2] {
    let right = calib.rotation * x.coords + calib.translation;
    [
        calib.left.project_normalised(x.x / x.z, x.y / x.z),
        calib.right.project_normalised(right.x / right.z, right.y / right.z),
    ]
}

#[test]
fn rectified_rows_line_up_and_disparity_is_bf_over_depth() {
    let calib = rig([-0.12, 0.05, 0.001, -0.001, -0.01, 0.02, 0.0, 0.001]);
    for alpha in [None, Some(0.0), Some(1.0)] {
        let rect = stereo_rectify(&calib, (640, 480), alpha);
        // The rectified cameras are parallel and the baseline lies along x.
        let relative = rect.r_right * calib.rotation * rect.r_left.transpose();
        assert!((relative - Matrix3::identity()).abs().max() < 1e-12);
        let t = rect.r_right * calib.translation;
        assert!(t.y.abs() < 1e-12 && t.z.abs() < 1e-12 && t.x < 0.0);
        let cam = rect.camera().unwrap();
        assert!((cam.bf - cam.fx * calib.baseline()).abs() < 1e-9);
        for x in [Point3::new(3.0, -2.0, 40.0), Point3::new(-8.0, 5.0, 25.0), Point3::new(0.5, 0.2, 120.0)] {
            let left = rect.r_left * x.coords;
            let right = rect.r_right * (calib.rotation * x.coords + calib.translation);
            let (ul, vl) = (cam.fx * left.x / left.z + cam.cx, cam.fy * left.y / left.z + cam.cy);
            let (ur, vr) = (cam.fx * right.x / right.z + cam.cx, cam.fy * right.y / right.z + cam.cy);
            assert!((vl - vr).abs() < 1e-9, "rows differ: {vl} {vr}");
            assert!(((ul - ur) - cam.bf / left.z).abs() < 1e-9, "disparity is not bf / depth");
        }
    }
}

#[test]
fn the_map_samples_where_the_camera_model_puts_the_point() {
    let calib = rig([-0.3, 0.1, 0.001, -0.001, -0.01, 0.04, 0.0, 0.001]);
    let rect = stereo_rectify(&calib, (640, 480), Some(0.0));
    let cam = rect.camera().unwrap();
    for (x, y) in [(10.0, 12.0), (320.0, 240.0), (600.0, 455.0)] {
        // The left-frame point at depth 50 seen at rectified pixel (x, y) of the left image.
        let z = 50.0;
        let rectified = Vector3::new((x - cam.cx) / cam.fx * z, (y - cam.cy) / cam.fy * z, z);
        let point = Point3::from(rect.r_left.transpose() * rectified);
        let expected = raw_pixels(&calib, &point)[0];
        let sampled = RectifyMap::exact(&calib.left, &rect.r_left, &rect.p_left, x, y);
        assert!((sampled.0 - expected.0).abs() < 1e-9 && (sampled.1 - expected.1).abs() < 1e-9);
    }
}

#[test]
fn an_undistorted_identity_rig_is_copied_pixel_for_pixel() {
    let mut calib = rig([0.0; 8]);
    calib.right = calib.left;
    calib.rotation = Matrix3::identity();
    calib.translation = Vector3::new(-4.0, 0.0, 0.0);
    let (w, h) = (64usize, 48usize);
    let rect = stereo_rectify(&calib, (w as u32, h as u32), None);
    // Same focal in both axes is needed for a copy: use the rectified projection itself as the raw camera.
    let mut identity = calib.left;
    identity.k = rect.p_left.fixed_view::<3, 3>(0, 0).into_owned();
    let map = RectifyMap::new(&identity, &rect.r_left, &rect.p_left, (w, h), (w, h));
    let raw: Vec<u8> = (0..w * h * 3).map(|i| (i * 37 % 251) as u8).collect();
    let mut out = vec![0u8; w * h * 3];
    map.remap(&raw, 3, &mut out);
    assert_eq!(out, raw);
}

#[test]
fn remap_is_bilinear_within_one_level_and_black_outside() {
    // A horizontal ramp shifted by a third of a pixel: the bilinear value is exact to the 1/32 step.
    let (w, h) = (40usize, 30usize);
    let k = Matrix3::new(100.0, 0.0, 20.0, 0.0, 100.0, 15.0, 0.0, 0.0, 1.0);
    let camera = CameraModel { k, distortion: [0.0; 8] };
    let mut p = nalgebra::Matrix3x4::zeros();
    p.fixed_view_mut::<3, 3>(0, 0).copy_from(&k);
    p[(0, 2)] = 20.0 - 1.0 / 3.0;
    let map = RectifyMap::new(&camera, &Matrix3::identity(), &p, (w, h), (w, h));
    let raw: Vec<u8> = (0..h).flat_map(|_| (0..w).map(|x| (x * 6) as u8)).collect();
    let mut out = vec![0u8; w * h];
    map.remap(&raw, 1, &mut out);
    for x in 1..w - 1 {
        let expected = (x as f64 + 1.0 / 3.0) * 6.0;
        assert!((f64::from(out[5 * w + x]) - expected).abs() <= 1.0, "x {x}: {} vs {expected}", out[5 * w + x]);
    }
    // The last column samples beyond the raw image: black.
    assert_eq!(out[5 * w + w - 1], 0);
}

fn parse(text: &str) -> Result<StereoCalibration, String> {
    let raw = RawSettings::parse_opencv_yaml(text, Path::new("calib.yaml")).map_err(|e| e.to_string())?;
    StereoCalibration::from_raw(&raw).map_err(|e| e.to_string())
}

const M: &str = "   rows: 3\n   cols: 3\n   dt: d\n";

#[test]
fn bad_calibrations_name_the_file_line_and_field() {
    let k = format!("M1: !!opencv-matrix\n{M}   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\n");
    let k2 = k.replace("M1", "M2");
    let t = "T: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: d\n   data: [ -5., 0., 0. ]\n";
    let good_r = format!("R: !!opencv-matrix\n{M}   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]\n");
    let ok = parse(&format!("%YAML:1.0\n{k}{k2}{good_r}{t}")).unwrap();
    assert!(ok.distortion_free());
    let bad_r = format!("R: !!opencv-matrix\n{M}   data: [ 1., 0.2, 0., 0., 1., 0., 0., 0., 1. ]\n");
    let e = parse(&format!("%YAML:1.0\n{k}{k2}{bad_r}{t}")).unwrap_err();
    assert!(e.contains("calib.yaml:") && e.contains("`R`") && e.contains("not a rotation"), "{e}");
    let bad_k = k.replace("500., 0., 320.", "-500., 0., 320.");
    let e = parse(&format!("%YAML:1.0\n{bad_k}{k2}{good_r}{t}")).unwrap_err();
    assert!(e.contains("`M1`") && e.contains("focal lengths must be > 0"), "{e}");
    let e = parse(&format!("%YAML:1.0\n{k}{k2}{good_r}")).unwrap_err();
    assert!(e.contains("missing required key `T`"), "{e}");
    let d = "D1: !!opencv-matrix\n   rows: 1\n   cols: 6\n   dt: d\n   data: [ 0., 0., 0., 0., 0., 0. ]\n";
    let e = parse(&format!("%YAML:1.0\n{k}{d}{k2}{good_r}{t}")).unwrap_err();
    assert!(e.contains("`D1`") && e.contains("expected a 1×4"), "{e}");
    let e = parse("%YAML:1.0\nCamera.fx: 500\n").unwrap_err();
    assert!(e.contains("not a stereo calibration"), "{e}");
}
