#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! OpenIGTLink out (issue #21): a navigation workstation's view of a run, received by an independent
//! implementation (pyigtl, through tests/interop/igtl_receive.py) while the pipeline runs as processes — the
//! scope's pose for every frame the tracker posed, its state, the map keyframe by keyframe as it grows, and at
//! the end exactly the run's map.ply and trajectory.tum.

mod common;

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};

use common::{TempDir, bdis_slam, prefix, render_small_colon, text};

fn f32s(v: &serde_json::Value) -> Vec<f32> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap() as f32).collect()
}

#[test]
fn a_navigation_workstation_receives_every_pose_the_map_as_it_grows_and_the_runs_last_word() {
    if !bdis_testkit::service::python_with("pyigtl") {
        return;
    }
    let tmp = TempDir::new("igtl");
    let sequence = tmp.path().join("colon");
    render_small_colon(&sequence, 48);
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}");

    // The receiver connects as soon as the service listens (it retries until then) and reads until the service
    // closes the connection at the end of the run. The run starts once the receiver has loaded pyigtl (it says
    // "ready"), so that it connects before the first pose on any but a very busy machine.
    let received = tmp.path().join("received.json");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/interop/igtl_receive.py");
    let mut receiver = Command::new("python3")
        .arg(&script)
        .args(["--connect", &addr, "--timeout", "300", "--out"])
        .arg(&received)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let mut said_by_receiver = BufReader::new(receiver.stdout.take().unwrap());
    let mut said = String::new();
    said_by_receiver.read_line(&mut said).unwrap();
    assert_eq!(said.trim(), "ready", "the receiver did not start");
    let run_dir = tmp.path().join("run");
    let run = Command::new(bdis_slam())
        .args(["run", "--track", "--sequence"])
        .arg(&sequence)
        .arg("--settings")
        .arg(sequence.join("settings.yaml"))
        .args(["--pacing", "on-demand:10hz", "--igtl", &addr, "--ipc-prefix", &prefix("igtl"), "--out"])
        .arg(&run_dir)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    said.clear();
    said_by_receiver.read_line(&mut said).unwrap();
    assert_eq!(said.trim(), "connected", "the receiver never connected");
    let run = run.wait_with_output().unwrap();
    assert!(run.status.success(), "{}\n{}", text(&run.stdout), text(&run.stderr));
    let status = receiver.wait().unwrap();
    assert!(status.success(), "pyigtl refused what it was sent (see above)");

    let read: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&received).unwrap()).unwrap();
    let messages = read["messages"].as_array().unwrap();
    let of = |device: &'static str| messages.iter().filter(move |m| m["device"] == device);

    // A TRANSFORM for every frame the tracker posed from the moment the receiver was let in (the newest pose
    // first, then every one: a receiver that connects late misses only what came before it), in order, under the
    // frame's own time, with its state.
    let trajectory = bdis_core::formats::trajectory::read_tum(&run_dir.join("trajectory.tum")).unwrap();
    let transforms: Vec<&serde_json::Value> = of("CameraToWorld").collect();
    assert!(transforms.iter().all(|m| m["type"] == "TRANSFORM"));
    let missed = trajectory.len() - transforms.len().min(trajectory.len());
    assert!(
        transforms.len() <= trajectory.len() && missed <= trajectory.len() / 4,
        "a pose per frame from the start: {} of {}",
        transforms.len(),
        trajectory.len()
    );
    let trajectory_from_connection = &trajectory[missed..];
    let path_length: f64 = trajectory
        .windows(2)
        .map(|w| (w[1].world_from_camera.translation.vector - w[0].world_from_camera.translation.vector).norm())
        .sum();
    let mut worst_live_offset = 0f64;
    for (m, final_pose) in transforms.iter().zip(trajectory_from_connection) {
        let frame_time: f64 = m["metadata"]["FrameTime"].as_str().unwrap().parse().unwrap();
        assert!((frame_time - final_pose.t_s).abs() < 1e-6, "{frame_time} against {}", final_pose.t_s);
        let state = m["metadata"]["TrackingState"].as_str().unwrap();
        assert!(["ok", "uncertain", "lost"].contains(&state), "{state}");
        assert_eq!(m["metadata"]["TransformStatus"], if state == "ok" { "OK" } else { "INVALID" });
        // The pose as tracked, live; trajectory.tum holds it after the last bundle adjustment: close, not equal.
        let row = |r: usize| f32s(&m["matrix"][r]);
        let t = final_pose.world_from_camera.translation.vector;
        let live = nalgebra::Vector3::new(row(0)[3] as f64, row(1)[3] as f64, row(2)[3] as f64);
        worst_live_offset = worst_live_offset.max((live - t).norm());
        assert_eq!(row(3), vec![0.0, 0.0, 0.0, 1.0]);
    }
    assert!(
        worst_live_offset < 0.01 * path_length,
        "a live pose {worst_live_offset} from the final trajectory (path {path_length})"
    );
    // The state, when it changes: the tracker starts Ok on this flight.
    let states: Vec<&str> = of("TrackingState").map(|m| m["text"].as_str().unwrap()).collect();
    assert_eq!(states.first(), Some(&"ok"), "{states:?}");

    // The map, keyframe by keyframe, while the run goes: blocks arrive before the last pose, and a keyframe is
    // sent again only when it changed (far fewer messages than pictures of the map times keyframes).
    let last_pose = messages.iter().rposition(|m| m["device"] == "CameraToWorld").unwrap();
    let first_block = messages.iter().position(|m| m["device"].as_str().unwrap().starts_with("MapKf")).unwrap();
    assert!(first_block < last_pose, "the map only arrived at the end");
    // The latest block of every keyframe, in keyframe order, is exactly map.ply.
    let mut latest: std::collections::BTreeMap<u64, &serde_json::Value> = Default::default();
    for m in messages.iter().filter(|m| m["device"].as_str().unwrap().starts_with("MapKf")) {
        assert_eq!(m["type"], "POLYDATA");
        let id: u64 = m["device"].as_str().unwrap()["MapKf".len()..].parse().unwrap();
        latest.insert(id, &m["polydata"]);
    }
    let ply = bdis_core::formats::ply::read(&run_dir.join("map.ply")).unwrap();
    let mut held = Vec::new();
    for block in latest.values() {
        let n = block["points"].as_array().unwrap().len();
        if n > 0 {
            let mut cell = vec![n as u64];
            cell.extend(0..n as u64);
            assert_eq!(block["vertices"], serde_json::json!(cell), "one vertex cell of every point");
        }
        held.extend(block["points"].as_array().unwrap().iter().map(f32s));
    }
    assert_eq!(held.len(), ply.positions.len(), "points held against map.ply");
    for (a, b) in held.iter().zip(&ply.positions) {
        assert_eq!(a.as_slice(), b.as_slice());
    }
    // And the final trajectory, as a polyline through trajectory.tum's positions.
    let line = of("Trajectory").next_back().expect("the final trajectory");
    let points = line["polydata"]["points"].as_array().unwrap();
    assert_eq!(points.len(), trajectory.len());
    for (p, pose) in points.iter().zip(&trajectory) {
        let t = pose.world_from_camera.translation.vector.map(|v| v as f32);
        assert_eq!(f32s(p), vec![t.x, t.y, t.z]);
    }
    eprintln!(
        "igtl: {} messages, {} poses, {} map blocks for {} keyframes, live poses within {:.4} of the final ({:.2} path)",
        messages.len(),
        transforms.len(),
        messages.iter().filter(|m| m["device"].as_str().unwrap().starts_with("MapKf")).count(),
        latest.len(),
        worst_live_offset,
        path_length
    );
    // Every CRC was checked by pyigtl's CRC-64 as the messages arrived (the script fails otherwise).
}
