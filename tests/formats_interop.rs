#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Files the project writes (PFM, PLY, TUM, KITTI) read back identically by the project and by an independent
//! reader: `tests/interop/read_formats.py`, numpy only, written from the format specifications. The expected
//! values go to the Python side as JSON (serde_json, not our writers), with f32 values as their bit patterns.

mod common;

use std::process::Command;
use std::time::Duration;

use bdis_core::formats::{pfm, ply, trajectory};
use bdis_core::geometry::StampedPose;
use common::*;
use nalgebra::{Isometry3, Vector3};

#[test]
fn pfm_ply_tum_kitti_round_trip_through_us_and_numpy() {
    let tmp = TempDir::new("interop");
    let dir = tmp.path();

    // PFM: a 5×3 disparity map with invalid pixels, plus a 2×2 three-channel image.
    let (w, h) = (5usize, 3usize);
    let disparity: Vec<f32> = (0..w * h).map(|i| if i % 4 == 1 { f32::NAN } else { i as f32 * 1.25 - 3.0 }).collect();
    pfm::write_disparity(&dir.join("disparity.pfm"), w, h, &disparity).unwrap();
    let rgb: Vec<f32> = (0..12).map(|i| i as f32 / 7.0).collect();
    pfm::write(&dir.join("rgb.pfm"), 2, 2, 3, &rgb).unwrap();
    let back = pfm::read_disparity(&dir.join("disparity.pfm")).unwrap();
    for (a, b) in disparity.iter().zip(&back.data) {
        assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()));
    }
    assert_eq!(pfm::read(&dir.join("rgb.pfm")).unwrap().data, rgb);

    // PLY: coloured points with a confidence property and one triangle.
    let cloud = ply::PointCloud {
        positions: (0..7).map(|i| [i as f32 * 0.5, -(i as f32) / 3.0, 10.0 + i as f32]).collect(),
        colors: Some((0..7).map(|i| [i as u8 * 30, 255 - i as u8, 7]).collect()),
        scalars: vec![("confidence".into(), (0..7).map(|i| i as f32 / 6.0).collect())],
        faces: vec![[0, 1, 2], [2, 3, 6]],
    };
    ply::write(&dir.join("map.ply"), &cloud).unwrap();
    assert_eq!(ply::read(&dir.join("map.ply")).unwrap(), cloud);

    // Trajectories.
    let poses: Vec<StampedPose> = (0..9)
        .map(|i| {
            let a = i as f64 * 0.21;
            StampedPose {
                t_s: 1_700_000_000.0 + a,
                world_from_camera: Isometry3::new(
                    Vector3::new(a, -a * 2.0, 0.3 * a * a),
                    Vector3::new(0.2 * a, a.cos() - 1.0, 0.1),
                ),
            }
        })
        .collect();
    trajectory::write_tum(&dir.join("traj.tum"), &poses).unwrap();
    assert_eq!(trajectory::read_tum(&dir.join("traj.tum")).unwrap(), poses);
    let isos: Vec<_> = poses.iter().map(|p| p.world_from_camera).collect();
    trajectory::write_kitti(&dir.join("traj.kitti"), &isos).unwrap();
    for (a, b) in isos.iter().zip(trajectory::read_kitti(&dir.join("traj.kitti")).unwrap()) {
        assert!((a.to_homogeneous() - b.to_homogeneous()).abs().max() < 1e-14);
    }

    let bits = |v: &[f32]| {
        v.iter().map(|x| if x.is_nan() { f32::INFINITY.to_bits() } else { x.to_bits() }).collect::<Vec<u32>>()
    };
    let expected = serde_json::json!({
        "disparity": { "width": w, "height": h, "bits": bits(&disparity) },
        "rgb": { "width": 2, "height": 2, "bits": bits(&rgb) },
        "ply": {
            "xyz_bits": cloud.positions.iter().flat_map(|p| p.iter().map(|v| v.to_bits())).collect::<Vec<u32>>(),
            "rgb": cloud.colors.as_ref().unwrap().iter().flatten().copied().collect::<Vec<u8>>(),
            "confidence_bits": bits(&cloud.scalars[0].1),
            "faces": cloud.faces,
        },
        "tum": poses.iter().map(|p| {
            let t = p.world_from_camera.translation.vector;
            let q = p.world_from_camera.rotation.quaternion();
            [p.t_s, t.x, t.y, t.z, q.i, q.j, q.k, q.w]
        }).collect::<Vec<_>>(),
        "kitti": isos.iter().map(|p| { let m = p.to_homogeneous(); (0..3).flat_map(|r| (0..4).map(move |c| m[(r, c)])).collect::<Vec<f64>>() }).collect::<Vec<_>>(),
    });
    std::fs::write(dir.join("expected.json"), serde_json::to_string(&expected).unwrap()).unwrap();

    let Some(python) = python_with_numpy() else { return };
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/interop/read_formats.py");
    let out = run_with_timeout(Command::new(python).arg(&script).arg(dir), Duration::from_secs(60));
    assert!(out.status.success(), "the independent reader disagrees:\n{}{}", text(&out.stdout), text(&out.stderr));
    assert!(text(&out.stdout).contains("all formats agree"), "{}", text(&out.stdout));
}
