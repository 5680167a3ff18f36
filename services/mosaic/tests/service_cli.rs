#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! The `bdis-mosaic` service binary: bad input is one line and exit 1 before shared memory is touched; a saved
//! map is resumed and, when the service is stopped, written out whole. (Its pipeline behaviour is tested end to
//! end in the workspace's tests/tracking.rs.)

use std::io::BufRead;
use std::process::{Command, Stdio};

use bdis_mosaic::{DepthKeyframe, Mosaic, MosaicParams, RectifiedCamera};
use nalgebra::Isometry3;

fn prefix() -> String {
    format!("bmoscli{}_", std::process::id())
}

fn run(args: &[&str]) -> (Option<i32>, String) {
    let out =
        Command::new(env!("CARGO_BIN_EXE_bdis-mosaic")).args(args).env("BDIS_IPC_PREFIX", prefix()).output().unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).trim().to_string())
}

fn temp_dir(tag: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("bdis-mosaic-cli-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn bad_parameters_and_files_are_one_line_and_exit_1() {
    let (code, err) = run(&["--map-param", "gap=3"]);
    assert_eq!(code, Some(1));
    assert!(err.starts_with("bdis-mosaic: error: --map-param `gap` is not a map parameter"), "{err}");
    assert!(err.contains("depth_gap_px"), "the valid names are listed: {err}");
    assert_eq!(err.lines().count(), 1, "{err}");

    let (code, err) = run(&["--map-param", "fusion=blend"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("fusion: `blend`"), "{err}");

    let (code, err) = run(&["--load", "/nonexistent/map.bin"]);
    assert_eq!(code, Some(1));
    assert!(err.contains("/nonexistent/map.bin: cannot read"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");

    let dir = temp_dir("bad");
    let foreign = dir.join("map.bin");
    std::fs::write(&foreign, b"ply\nformat ascii 1.0\nelement vertex 0\nend_header\n").unwrap();
    let (code, err) = run(&["--load", foreign.to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert!(err.contains("map.bin") && err.contains("not a bdis-slam map"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(!err.contains("panicked"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_saved_map_is_resumed_and_written_out_when_the_service_is_stopped() {
    let dir = temp_dir("resume");
    // A small map: a tilted plane seen by two keyframes.
    let (w, h) = (80u32, 60u32);
    let n = (w * h) as usize;
    let disparity: Vec<f32> = (0..n).map(|i| 40.0 + (i % w as usize) as f32 * 0.05).collect();
    let confidence = vec![0.9f32; n];
    let rgb = vec![150u8; 3 * n];
    let mut map = Mosaic::new(MosaicParams::default());
    for k in 0..2u64 {
        map.insert(&DepthKeyframe {
            kf_id: k,
            t_capture_ns: k,
            world_from_camera: Isometry3::translation(30.0 * k as f64, 0.0, 0.0),
            intrinsics: RectifiedCamera { fx: 65.0, fy: 65.0, cx: 39.5, cy: 29.5, bf: 325.0, width: w, height: h },
            disparity: &disparity,
            confidence: &confidence,
            rgb: &rgb,
        })
        .unwrap();
    }
    let saved = dir.join("saved.bin");
    bdis_mosaic::save(&map, &saved).unwrap();

    let out = dir.join("run");
    std::fs::create_dir_all(&out).unwrap();
    let run_prefix = format!("bmosres{}_", std::process::id());
    let mut child = Command::new(env!("CARGO_BIN_EXE_bdis-mosaic"))
        .args(["--load", saved.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .env("BDIS_IPC_PREFIX", &run_prefix)
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait until it says it is ready (its log line), then stop it as the launcher does.
    let mut log = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    loop {
        let mut line = String::new();
        assert!(log.read_line(&mut line).unwrap() > 0, "the service ended before it was ready:\n{seen}");
        seen += &line;
        if line.contains("mosaic ready") {
            break;
        }
    }
    assert!(seen.contains("resumed 2 keyframes"), "{seen}");
    Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut log, &mut rest).unwrap();
    let status = child.wait().unwrap();
    // iceoryx2 keeps the run's global management file after the last node (the launcher removes it after a run).
    for e in std::fs::read_dir("/dev/shm").into_iter().flatten().flatten() {
        if e.file_name().to_string_lossy().starts_with(run_prefix.as_str()) {
            let _ = std::fs::remove_file(e.path());
        }
    }
    assert!(status.success(), "{status}: {seen}{rest}");

    let cloud = bdis_core::formats::ply::read(&out.join("map.ply")).unwrap();
    assert_eq!(cloud.len(), map.n_points());
    assert!(out.join("map.png").exists());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("mosaic.json")).unwrap()).unwrap();
    assert_eq!(summary["end_of_stream"], false, "stopped, not ended: {summary}");
    assert_eq!(summary["points"], map.n_points());
    let back = bdis_mosaic::load(&out.join("map.bin")).unwrap();
    assert_eq!(back.n_points(), map.n_points());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn help_names_the_outputs() {
    let out = Command::new(env!("CARGO_BIN_EXE_bdis-mosaic")).arg("--help").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("--load") && text.contains("map.ply") && text.contains("--map-param"), "{text}");
    for name in MosaicParams::NAMES {
        assert!(text.contains(name), "--help names every map parameter; `{name}` is missing");
    }
}
