#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Our rectification against OpenCV's (issue #18): `tests/interop/rectify_golden.py` writes calibrations with
//! cv2.FileStorage (mild and strong 8-coefficient distortion, a vertical rig, 1280×1024; alpha unset, 0, ½, 1)
//! and an ORB-SLAM2 LEFT/RIGHT file, and compares `bdis-slam calib show --json --maps` (R1 R2 P1 P2 Q, the
//! undistort–rectify maps: 0.01 px) and `bdis-slam rectify` (within one grey level of cv2.remap) with
//! opencv-python. OpenCV is a CI-only cross-check (.ci/run installs opencv-python-headless); the product has none.

mod common;

use std::process::Command;
use std::time::Duration;

use common::*;

#[test]
fn rectification_agrees_with_opencv() {
    let has_cv2 = Command::new("python3").args(["-c", "import cv2, numpy"]).output().is_ok_and(|o| o.status.success());
    if !has_cv2 {
        assert!(std::env::var_os("CI").is_none(), "CI must have python3 with opencv-python-headless (.ci/run)");
        eprintln!("skipped: python3 with cv2 (opencv-python-headless) is not available");
        return;
    }
    let tmp = TempDir::new("rectify-golden");
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/interop/rectify_golden.py");
    let out = run_with_timeout(
        Command::new("python3").arg(&script).arg(bdis_slam()).arg(tmp.path()),
        Duration::from_secs(300),
    );
    let report = format!("{}{}", text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "our rectification disagrees with OpenCV:\n{report}");
    assert!(report.contains("rectification agrees with OpenCV"), "{report}");
}
