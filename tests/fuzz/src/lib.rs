//! Fuzz targets: one function per parser of user-supplied files and per validator of shared-memory messages.
//! Each takes arbitrary bytes and must neither panic nor allocate without bound; where a parse succeeds it
//! also checks what the parse promises (sizes that agree, finite numbers, rigid poses), so a fuzzer finds
//! wrong answers as well as crashes.
//!
//! Two drivers call them: `tests/fuzz/libfuzzer` (cargo fuzz, coverage-guided, for long runs) and this crate's
//! `tests/smoke.rs` (stable Rust, a fixed budget of deterministic mutations of the committed corpus, in CI).

use std::path::Path;

mod ipc;

pub use ipc::{correction, depth, frame, keyframe, pose_record, telemetry};

/// A fuzz target: its name (the corpus folder) and its function.
pub type Target = (&'static str, fn(&[u8]));

/// Every target. The names are the folders of `corpus/` and the binaries of `libfuzzer/fuzz_targets/`.
pub const TARGETS: &[Target] = &[
    ("settings_yaml", settings_yaml),
    ("settings_toml", settings_toml),
    ("stereo_calibration", stereo_calibration),
    ("calibration_ini", calibration_ini),
    ("calibration_json", calibration_json),
    ("calibration_hamlyn", calibration_hamlyn),
    ("pfm", pfm),
    ("ply", ply),
    ("tum", tum),
    ("kitti_poses", kitti_poses),
    ("times", times),
    ("kitti_calib", kitti_calib),
    ("journal", journal),
    ("map_bin", map_bin),
    ("launch_file", launch_file),
    ("video_native", video_native),
    ("ipc_frame", frame),
    ("ipc_keyframe", keyframe),
    ("ipc_depth", depth),
    ("ipc_correction", correction),
    ("ipc_pose", pose_record),
    ("ipc_telemetry", telemetry),
    ("bridge_message", bridge_message),
    ("bridge_snapshot", bridge_snapshot),
];

fn path() -> &'static Path {
    Path::new("fuzz-input")
}

/// Text parsers get the bytes as a user's file would reach them: read as UTF-8, or refused before parsing.
fn text(data: &[u8]) -> Option<&str> {
    std::str::from_utf8(data).ok()
}

fn assert_rigid(p: &nalgebra::Isometry3<f64>) {
    assert!(p.translation.vector.iter().all(|v| v.is_finite()), "non-finite translation {p}");
    let q = p.rotation.quaternion();
    assert!((q.norm() - 1.0).abs() < 1e-6, "rotation not unit: {q:?}");
}

pub fn settings_yaml(data: &[u8]) {
    let Some(t) = text(data) else { return };
    if let Ok(raw) = bdis_core::settings::raw::RawSettings::parse_opencv_yaml(t, path()) {
        settings_checked(&raw);
    }
}

pub fn settings_toml(data: &[u8]) {
    let Some(t) = text(data) else { return };
    if let Ok(raw) = bdis_core::settings::raw::RawSettings::parse_toml(t, path()) {
        settings_checked(&raw);
    }
}

/// Settings that validate describe a usable camera: positive focal lengths and baseline, finite numbers.
fn settings_checked(raw: &bdis_core::settings::raw::RawSettings) {
    if let Ok(s) = bdis_core::settings::Settings::from_raw(raw) {
        let c = &s.camera;
        assert!(c.fx > 0.0 && c.fy > 0.0 && c.bf > 0.0, "accepted camera {c:?}");
        assert!(c.cx.is_finite() && c.cy.is_finite(), "accepted camera {c:?}");
    }
}

/// A stereo calibration that reads has cameras with positive focal lengths, a rotation, a baseline; and
/// rectifying it either gives finite matrices or is refused by `rectification_is_usable`.
pub fn stereo_calibration(data: &[u8]) {
    let Some(t) = text(data) else { return };
    let Ok(raw) = bdis_core::settings::raw::RawSettings::parse_opencv_yaml(t, path()) else { return };
    let Ok(calib) = bdis_rectify::StereoCalibration::from_raw(&raw) else { return };
    for cam in [&calib.left, &calib.right] {
        assert!(cam.k[(0, 0)] > 0.0 && cam.k[(1, 1)] > 0.0, "accepted camera {cam:?}");
    }
    let r = &calib.rotation;
    assert!((r.transpose() * r - nalgebra::Matrix3::identity()).abs().max() < 1e-5, "accepted rotation {r}");
    assert!(calib.translation.norm() > 0.0 && calib.translation.iter().all(|v| v.is_finite()));
    let rect = bdis_rectify::stereo_rectify(&calib, (64, 48), None);
    if bdis_rectify::rectification_is_usable(&rect) {
        assert!(rect.p_left.iter().chain(rect.p_right.iter()).all(|v| v.is_finite()));
    }
}

/// What every calibration reader promises of a calibration it accepts, and that it rectifies without panic.
fn check_calibration(calib: &bdis_rectify::StereoCalibration) {
    for cam in [&calib.left, &calib.right] {
        assert!(cam.k[(0, 0)] > 0.0 && cam.k[(1, 1)] > 0.0, "accepted camera {cam:?}");
        assert!(cam.k.iter().chain(&cam.distortion).all(|v| v.is_finite()), "accepted camera {cam:?}");
    }
    let r = &calib.rotation;
    assert!((r.transpose() * r - nalgebra::Matrix3::identity()).abs().max() < 1e-5, "accepted rotation {r}");
    assert!(calib.translation.norm() > 0.0 && calib.translation.iter().all(|v| v.is_finite()));
    let _ = bdis_rectify::stereo_rectify(calib, (64, 48), None);
}

pub fn calibration_ini(data: &[u8]) {
    let Some(t) = text(data) else { return };
    if let Ok(calib) = bdis_rectify::formats::parse_stereomis_ini(t, path()) {
        check_calibration(&calib);
    }
}

pub fn calibration_json(data: &[u8]) {
    let Some(t) = text(data) else { return };
    if let Ok(calib) = bdis_rectify::formats::parse_json(t, path()) {
        check_calibration(&calib);
    }
}

/// The three Hamlyn files, separated in the input by lines of `---`.
pub fn calibration_hamlyn(data: &[u8]) {
    let Some(t) = text(data) else { return };
    let parts: Vec<&str> = t.splitn(3, "\n---\n").collect();
    let [left, right, extrinsic] = parts[..] else { return };
    if let Ok(calib) = bdis_rectify::formats::parse_hamlyn(path(), [left, right, extrinsic]) {
        check_calibration(&calib);
    }
}

/// A video file read without ffmpeg (Y4M, Motion-JPEG AVI): indexed, then every frame it lists decoded. The
/// reader itself asserts that every indexed frame lies inside the file and has a finite time.
pub fn video_native(data: &[u8]) {
    let _ = bdis_source::video::index_and_decode(data);
}

pub fn pfm(data: &[u8]) {
    if let Ok(img) = bdis_core::formats::pfm::parse(data, path()) {
        assert_eq!(img.data.len(), img.width * img.height * img.channels, "PFM size disagrees with its data");
    }
}

pub fn ply(data: &[u8]) {
    if let Ok(cloud) = bdis_core::formats::ply::parse(data, path()) {
        if let Some(c) = &cloud.colors {
            assert_eq!(c.len(), cloud.positions.len(), "PLY colours disagree with positions");
        }
        for (name, values) in &cloud.scalars {
            assert_eq!(values.len(), cloud.positions.len(), "PLY property {name} disagrees with positions");
        }
        for f in &cloud.faces {
            assert!(f.iter().all(|&i| (i as usize) < cloud.positions.len()), "PLY face {f:?} past the vertices");
        }
    }
}

pub fn tum(data: &[u8]) {
    let Some(t) = text(data) else { return };
    if let Ok(poses) = bdis_core::formats::trajectory::parse_tum(t, path()) {
        for p in &poses {
            assert!(p.t_s.is_finite(), "non-finite time");
            assert_rigid(&p.world_from_camera);
        }
    }
}

pub fn kitti_poses(data: &[u8]) {
    let Some(t) = text(data) else { return };
    if let Ok(poses) = bdis_core::formats::trajectory::parse_kitti(t, path()) {
        poses.iter().for_each(assert_rigid);
    }
}

pub fn times(data: &[u8]) {
    let Some(t) = text(data) else { return };
    if let Ok(times) = bdis_source::source::parse_times(t, path()) {
        assert!(times.iter().all(|t| t.is_finite()), "non-finite time accepted");
        assert!(times.windows(2).all(|w| w[0] <= w[1]), "times out of order accepted");
    }
}

pub fn kitti_calib(data: &[u8]) {
    let Some(t) = text(data) else { return };
    if let Ok(c) = bdis_source::source::parse_kitti_calib(t, path()) {
        assert!(c.fx > 0.0 && c.fy > 0.0 && c.bf > 0.0 && c.cx.is_finite() && c.cy.is_finite(), "accepted {c:?}");
    }
}

pub fn journal(data: &[u8]) {
    let Some(t) = text(data) else { return };
    if let Ok(c) = bdis_track::journal::Continuation::parse(t) {
        for (_, _, p) in &c.frames {
            if let Some(p) = p {
                assert_rigid(p);
            }
        }
        c.keyframes.values().for_each(|(_, p)| assert_rigid(p));
        // What a restarted tracker does with it first.
        let _ = c.next_kf_id();
        if let Some(p) = c.last_frame_seq().and_then(|s| c.predict(s.saturating_add(3))) {
            assert_rigid(&p);
        }
    }
}

pub fn map_bin(data: &[u8]) {
    if let Ok(map) = bdis_mosaic::decode(data, path()) {
        // A map that loads can be used: its cloud built and its keyframes walked.
        let cloud = map.world_cloud();
        assert!(cloud.positions.iter().all(|p| p.iter().all(|v| v.is_finite())), "non-finite map point");
    }
}

pub fn launch_file(data: &[u8]) {
    let Some(t) = text(data) else { return };
    let _ = bdis_slam::launch_file::LaunchFile::parse(t, path());
}

/// What a bridge receiver or sender takes off the link (`bdis_bridge::wire`): one message comes out whole or as
/// an error, and a sample's header decodes only at its exact size.
pub fn bridge_message(data: &[u8]) {
    use bdis_bridge::wire::{self, Frame};
    if let Ok((_, Frame::Sample { what, header, payload })) = wire::message(data) {
        assert!(header.len() + payload.len() <= wire::MAX_FRAME_BYTES as usize);
        match what.topic {
            bdis_bridge::Carried::Depth => {
                let h = bdis_bridge::records::depth_header(header);
                assert_eq!(h.is_ok(), header.len() == bdis_bridge::records::DEPTH_HEADER_BYTES);
            }
            bdis_bridge::Carried::Corrections => {
                let c = bdis_bridge::records::correction(header);
                assert_eq!(c.is_ok(), header.len() == bdis_bridge::records::CORRECTION_BYTES);
            }
            bdis_bridge::Carried::Keyframes => {
                let k = bdis_bridge::records::keyframe_header(header);
                assert_eq!(k.is_ok(), header.len() == bdis_bridge::records::KEYFRAME_HEADER_BYTES);
            }
            bdis_bridge::Carried::Poses => {
                let p = bdis_bridge::records::pose(header);
                assert_eq!(p.is_ok(), header.len() == bdis_bridge::records::POSE_BYTES);
            }
        }
    }
}

/// What the bridge takes off the link for the map snapshot (`bdis_bridge::records`): a request, or an answer
/// whose points decode only when the bytes hold exactly the header's count of them, every coordinate finite.
pub fn bridge_snapshot(data: &[u8]) {
    use bdis_bridge::records;
    let _ = records::query(data);
    if let Ok((_, count)) = records::snapshot_header(data) {
        assert_eq!(data.len(), records::SNAPSHOT_HEADER_BYTES + count * records::MAP_POINT_BYTES);
        let mut points = vec![bdis_ipc::map::MapPoint::default(); count];
        if records::snapshot_points(data, &mut points).is_ok() {
            assert!(points.iter().all(|p| p.xyz.iter().all(|v| v.is_finite())));
        }
    }
}

/// Seeds that are easier made than committed by hand: a small `map.bin` written by the mosaic itself.
pub fn generated_seeds(target: &str) -> Vec<Vec<u8>> {
    match target {
        "map_bin" => small_map_bin().into_iter().collect(),
        "bridge_message" => bridge_messages(),
        "bridge_snapshot" => {
            let mut bytes = Vec::new();
            let header =
                bdis_ipc::map::MapSnapshotHeader { points_in_map: 2, stride: 1, keyframes: 1, ..Default::default() };
            let point =
                bdis_ipc::map::MapPoint { xyz: [1.0, 2.0, 50.0], rgb: [200, 90, 80], confidence: 255, kf_id: 0 };
            bdis_bridge::records::put_snapshot(&mut bytes, &header, &[point, point]);
            vec![bytes]
        }
        _ => Vec::new(),
    }
}

fn small_map_bin() -> Option<Vec<u8>> {
    use bdis_mosaic::{DepthKeyframe, Mosaic, MosaicParams, RectifiedCamera};
    let (w, h) = (8u32, 6u32);
    let n = (w * h) as usize;
    let disparity: Vec<f32> = (0..n).map(|i| 10.0 + (i % 7) as f32).collect();
    let confidence = vec![0.9f32; n];
    let rgb = vec![100u8; 3 * n];
    let mut mosaic = Mosaic::new(MosaicParams::default());
    let kf = DepthKeyframe {
        kf_id: 0,
        t_capture_ns: 0,
        world_from_camera: nalgebra::Isometry3::identity(),
        intrinsics: RectifiedCamera { fx: 10.0, fy: 10.0, cx: 4.0, cy: 3.0, bf: 100.0, width: w, height: h },
        disparity: &disparity,
        confidence: &confidence,
        rgb: &rgb,
    };
    mosaic.insert(&kf).ok()?;
    let dir = std::env::temp_dir().join(format!("bdis-fuzz-seed-{}", std::process::id()));
    std::fs::create_dir_all(&dir).ok()?;
    let path = dir.join("map.bin");
    bdis_mosaic::save(&mosaic, &path).ok()?;
    let bytes = std::fs::read(&path).ok();
    let _ = std::fs::remove_dir_all(&dir);
    bytes
}

/// Messages as both sides write them: a want-hello, a hello, a depth keyframe, a correction, an acknowledgement.
fn bridge_messages() -> Vec<Vec<u8>> {
    use bdis_bridge::wire::{self, SampleId};
    use bdis_bridge::{Carried, records};
    let message = |frame: &dyn Fn(&mut Vec<u8>)| {
        let mut out = Vec::new();
        wire::envelope(&mut out, 0x5eed, false);
        frame(&mut out);
        out
    };
    let mut depth = Vec::new();
    records::put_depth_header(&mut depth, &bdis_ipc::DepthHeader { width: 2, height: 1, ..Default::default() });
    let mut correction = Vec::new();
    records::put_correction(&mut correction, &bdis_ipc::KeyframePose { generation: 1, ..Default::default() });
    vec![
        message(&|o| wire::want_hello(o)),
        message(&|o| wire::hello(o, &[(Carried::Depth, Some(3)), (Carried::Corrections, None)])),
        message(&|o| wire::sample(o, SampleId { topic: Carried::Depth, id: 4, t_sent_ns: 1 }, &depth, &[0u8; 22])),
        message(&|o| {
            wire::sample(o, SampleId { topic: Carried::Corrections, id: 1 << 20, t_sent_ns: 2 }, &correction, &[])
        }),
        message(&|o| wire::ack(o, 2)),
    ]
}
