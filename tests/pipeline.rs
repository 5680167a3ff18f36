#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! End to end: `bdis-slam run` starts acquisition and the probe as real processes over real iceoryx2.

mod common;

use std::process::Command;
use std::time::Duration;

use bdis_slam::probe::{ProbeSummary, fnv1a64};
use common::*;

fn probe_summary(run_dir: &std::path::Path) -> ProbeSummary {
    let text =
        std::fs::read_to_string(run_dir.join("probe.json")).expect("the probe writes probe.json into the run folder");
    serde_json::from_str(&text).unwrap()
}

/// The hop row of the printed latency table: `acquisition→probe (frames)  msgs  p50 µs …`.
fn hop_p50_us(stdout: &str) -> f64 {
    let row = stdout
        .lines()
        .find(|l| l.starts_with("acquisition→probe (frames)"))
        .unwrap_or_else(|| panic!("no acquisition→probe row in:\n{stdout}"));
    let header = stdout.lines().find(|l| l.starts_with("hop (topic)")).expect("hop table header");
    assert!(header.contains("p50 µs"), "{header}");
    row.split_whitespace().nth(3).unwrap().parse().unwrap()
}

#[test]
fn streams_every_hamlyn6_frame_in_order_and_reads_it_in_place() {
    let Some(set6) = data_set("6") else { return };
    let tmp = TempDir::new("set6");
    let run_dir = tmp.path().join("run");
    let prefix = prefix("set6");
    let settings = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("launch/settings/hamlyn6.yaml");
    let out = run_with_timeout(
        Command::new(bdis_slam())
            .args(["run", "--sequence"])
            .arg(&set6)
            .arg("--settings")
            .arg(&settings)
            .args(["--checksums", "--ipc-prefix", &prefix, "--out"])
            .arg(&run_dir),
        Duration::from_secs(120),
    );
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "run failed\nstdout:\n{stdout}\nstderr:\n{}", text(&out.stderr));

    // Every frame, in order, intact: the probe's checksums of the pixels it read in shared memory equal those
    // of the PNGs decoded here by the image crate (an independent decoder, not our acquisition code).
    let mut names: Vec<u32> = std::fs::read_dir(set6.join("left"))
        .unwrap()
        .map(|e| e.unwrap().path().file_stem().unwrap().to_str().unwrap().parse().unwrap())
        .collect();
    names.sort();
    let summary = probe_summary(&run_dir);
    assert_eq!(summary.frames_received, 25);
    assert_eq!(summary.source_indices, names, "frames arrive in sequence order");
    assert_eq!((summary.frames_missing, summary.out_of_order, summary.malformed), (0, 0, 0));
    assert!(summary.end_of_stream);
    assert_eq!((summary.width, summary.height), (640, 480));
    let expected: Vec<String> = names
        .iter()
        .map(|n| {
            format!("{:016x}", fnv1a64(image::open(set6.join(format!("left/{n}.png"))).unwrap().to_rgb8().as_raw()))
        })
        .collect();
    assert_eq!(summary.left_rgb_fnv1a64, expected);

    // Zero copy: the pixels the probe read lie in a mapping of this run's shared-memory file.
    assert!(summary.payload_in_shared_memory);
    let mapping = summary.payload_mapping.expect("payload mapping");
    assert!(mapping.starts_with(&format!("/dev/shm/{prefix}")), "{mapping}");

    // The printed table gives the acquisition→probe hop in microseconds; latency.json has the same figures.
    let p50 = hop_p50_us(&stdout);
    assert!(p50 > 0.0 && p50 < 1_000_000.0, "{p50}");
    let latency: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("latency.json")).unwrap()).unwrap();
    let hop = &latency["hops"][0];
    assert_eq!((hop["from"].as_str(), hop["to"].as_str()), (Some("acquisition"), Some("probe")));
    assert_eq!(hop["latency_us"]["count"].as_u64(), Some(25));
    for p in latency["processes"].as_array().unwrap() {
        assert_eq!(p["messages"].as_u64(), Some(25), "{p}");
        assert!(p["processing_us"]["p99"].as_f64().unwrap() >= p["processing_us"]["p50"].as_f64().unwrap());
    }
    assert!(run_dir.join("logs/acquisition.log").is_file() && run_dir.join("logs/probe.log").is_file());
    assert!(run_dir.join("launch.toml").is_file());
    // The same figures drawn: a bar for the hop.
    let plot = std::fs::read_to_string(run_dir.join("latency.svg")).unwrap();
    assert!(plot.starts_with("<svg") && plot.contains("acquisition→probe (frames)"), "{plot}");
    assert_no_leftovers(&prefix);
}

#[test]
fn the_bundled_launch_file_runs_the_same_pipeline() {
    if data_set("6").is_none() {
        return;
    }
    let tmp = TempDir::new("launch");
    let prefix = prefix("launch");
    let launch = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("launch/hamlyn6.toml");
    let out = run_with_timeout(
        Command::new(bdis_slam()).arg("run").arg(&launch).args(["--ipc-prefix", &prefix, "--out"]).arg(tmp.path()),
        Duration::from_secs(120),
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let summary = probe_summary(tmp.path());
    assert_eq!((summary.frames_received, summary.frames_missing), (25, 0));
    assert_eq!(std::fs::read_to_string(tmp.path().join("launch.toml")).unwrap().matches("[[service]]").count(), 2);
    assert_no_leftovers(&prefix);
}

#[test]
fn sigterm_stops_the_pipeline_upstream_first_and_keeps_what_it_produced() {
    let tmp = TempDir::new("sigterm");
    let seq = tmp.path().join("seq");
    write_sequence(&seq, 60, 64, 48, 3);
    let prefix = prefix("sigterm");
    let run_dir = tmp.path().join("run");
    let mut child = Command::new(bdis_slam())
        .args(["run", "--sequence"])
        .arg(&seq)
        .args(["--pacing", "20hz", "--ipc-prefix", &prefix, "--out"])
        .arg(&run_dir)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Wait until frames flow (the probe's log shows a status line), then ask the launcher to stop.
    let log = run_dir.join("logs/probe.log");
    let start = std::time::Instant::now();
    while !std::fs::read_to_string(&log).unwrap_or_default().contains("frames:") {
        assert!(start.elapsed() < Duration::from_secs(30), "no frames flowed");
        std::thread::sleep(Duration::from_millis(50));
    }
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130), "a stop request ends the run with 130");
    let summary = probe_summary(&run_dir);
    assert!(summary.end_of_stream, "acquisition was stopped first and still sent end of stream");
    assert!(summary.frames_received >= 1 && summary.frames_received < 60, "{}", summary.frames_received);
    assert_eq!(summary.frames_missing, 0);
    let latency: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("latency.json")).unwrap()).unwrap();
    assert_eq!(latency["stop_requested"], serde_json::json!(true));
    assert!(latency["services"].as_array().unwrap().iter().all(|s| s["exit"] == "ok"), "{latency}");
    assert_no_leftovers(&prefix);
}

#[test]
fn the_demo_renders_a_sequence_and_runs_the_pipeline_over_it() {
    let tmp = TempDir::new("demo");
    let out = run_with_timeout(
        Command::new(bdis_slam()).args(["demo", "--frames", "12", "--out"]).arg(tmp.path()),
        Duration::from_secs(120),
    );
    let stdout = text(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", text(&out.stderr));
    assert!(stdout.contains("frames      12 rendered, 12 published by acquisition, 12 tracked"), "{stdout}");
    assert!(stdout.contains("acquisition→tracking (frames) p50"), "{stdout}");
    assert!(stdout.contains("tracking→stereo (keyframes) p50"), "{stdout}");
    for preview in ["preview.png", "depth-preview.png"] {
        let img = image::open(tmp.path().join(preview)).unwrap();
        assert_eq!((img.width(), img.height()), (1280, 480));
    }
    // The tracker chose the keyframes; every one of them reached the dense stereo and its consumer.
    let keyframes = bdis_core::formats::trajectory::read_tum(&tmp.path().join("keyframes.tum")).unwrap();
    let depth: bdis_slam::probe::DepthSummary =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("probe.json")).unwrap()).unwrap();
    assert!(keyframes.len() >= 2, "{} keyframes", keyframes.len());
    assert_eq!(depth.keyframe_ids.len(), keyframes.len());
    assert_eq!(depth.keyframe_ids[0], 0);
    assert!(depth.end_of_stream && depth.payload_in_shared_memory);
    assert!(depth.mean_density > 0.5, "most of the colon wall is matched: {}", depth.mean_density);
    let trajectory = bdis_core::formats::trajectory::read_tum(&tmp.path().join("trajectory.tum")).unwrap();
    assert_eq!(trajectory.len(), 12, "a pose for every frame");
    assert!(stdout.contains("tracking    ") && stdout.contains("ATE RMSE"), "{stdout}");
}

#[test]
fn hamlyn6_through_the_stereo_service() {
    if data_set("6").is_none() {
        return;
    }
    let tmp = TempDir::new("h6stereo");
    let prefix = prefix("h6st");
    let launch = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("launch/hamlyn6-stereo.toml");
    let out = run_with_timeout(
        Command::new(bdis_slam()).arg("run").arg(&launch).args(["--ipc-prefix", &prefix, "--out"]).arg(tmp.path()),
        Duration::from_secs(120),
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let depth: bdis_slam::probe::DepthSummary =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("probe.json")).unwrap()).unwrap();
    assert_eq!(depth.keyframe_ids, vec![0, 5, 10, 15, 20]);
    assert_eq!(depth.duplicates, 0);
    assert!(depth.end_of_stream && depth.payload_in_shared_memory);
    // The in-vivo frames have a black border; BDIS answers most of the rest.
    assert!(depth.mean_density > 0.6, "density {}", depth.mean_density);
    let stdout = text(&out.stdout);
    assert!(stdout.contains("acquisition→stereo (frames)") && stdout.contains("stereo→probe (depth)"), "{stdout}");
    assert_no_leftovers(&prefix);
}
