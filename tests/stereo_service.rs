#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! The stereo service over real iceoryx2: depth keyframes for every keyframe, and a `kill -9` in the middle of
//! a run loses none of them when a new instance takes over.

mod common;

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use bdis_slam::probe::DepthSummary;
use common::*;
use iceoryx2::prelude::*;

fn spawn(bin: std::path::PathBuf, args: &[&str], prefix: &str, log: &std::path::Path) -> Child {
    let log = std::fs::File::create(log).unwrap();
    Command::new(bin)
        .args(args)
        .env(bdis_ipc::PREFIX_ENV, prefix)
        // The credit events and every frame received are in the logs a failure prints.
        .env("RUST_LOG", "info,bdis_acquisition=debug,bdis_stereo=debug")
        .stdin(Stdio::null())
        .stdout(log.try_clone().unwrap())
        .stderr(log)
        .spawn()
        .unwrap()
}

fn wait_for(what: &str, timeout: Duration, mut done: impl FnMut() -> bool) {
    let start = Instant::now();
    while !done() {
        assert!(start.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(2));
    }
}

fn wait_exit(child: &mut Child, timeout: Duration) -> std::process::ExitStatus {
    let start = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        if start.elapsed() > timeout {
            let _ = child.kill();
            panic!("a process did not finish within {timeout:?}");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_killed_stereo_instance_is_replaced_without_losing_a_keyframe() {
    let tmp = TempDir::new("stereo-kill");
    let seq = tmp.path().join("seq");
    let rig = bdis_synth::default_camera();
    let scene = bdis_synth::PlaneScene { depth_mm: 60.0, texture: bdis_synth::TissueTexture { seed: 5 } };
    let settings = bdis_synth::write_plane_sweep(&seq, &rig, &scene, 60, 30.0, 6.0, |_| {}).unwrap();
    let prefix = prefix("stkill");
    let _files = RunFiles(&prefix);
    let settings_arg = settings.to_str().unwrap();
    let probe_json = tmp.path().join("probe.json");

    let mut probe = spawn(
        bdis_slam(),
        &["probe", "depth", "--summary", probe_json.to_str().unwrap()],
        &prefix,
        &tmp.path().join("probe.log"),
    );
    // The probe must be subscribed before the first keyframe is published.
    let ipc = bdis_ipc::Ipc::open("test", &prefix).unwrap();
    let depth = ipc.depth().unwrap();
    wait_for("the probe's subscription", Duration::from_secs(20), || {
        depth.dynamic_config().number_of_subscribers() >= 1
    });

    let stereo_args = ["--settings", settings_arg, "--every", "2"];
    let log1 = tmp.path().join("stereo1.log");
    let mut stereo = spawn(service_binary("bdis-stereo"), &stereo_args, &prefix, &log1);
    let seq_arg = seq.to_str().unwrap();
    let mut acquisition = spawn(
        service_binary("bdis-acquisition"),
        &["--sequence", seq_arg, "--settings", settings_arg, "--pacing", "on-demand"],
        &prefix,
        &tmp.path().join("acquisition.log"),
    );

    // Kill the first instance in the middle of the run, after it has published a few keyframes.
    wait_for("three keyframes", Duration::from_secs(60), || {
        std::fs::read_to_string(&log1).unwrap_or_default().matches("keyframe ").count() >= 3
    });
    stereo.kill().unwrap();
    stereo.wait().unwrap();
    let done_by_first = std::fs::read_to_string(&log1).unwrap().matches("keyframe ").count();
    assert!(done_by_first < 30, "the first instance finished before it could be killed");

    let mut replacement = spawn(service_binary("bdis-stereo"), &stereo_args, &prefix, &tmp.path().join("stereo2.log"));
    assert!(wait_exit(&mut acquisition, Duration::from_secs(120)).success());
    assert!(wait_exit(&mut replacement, Duration::from_secs(60)).success());
    let probe_status = wait_exit(&mut probe, Duration::from_secs(60));
    assert!(probe_status.success(), "{}", std::fs::read_to_string(tmp.path().join("probe.log")).unwrap());

    let summary: DepthSummary = serde_json::from_str(&std::fs::read_to_string(&probe_json).unwrap()).unwrap();
    let expected: Vec<u64> = (0..60).step_by(2).collect();
    let logs = || {
        ["stereo1.log", "stereo2.log", "acquisition.log"]
            .map(|f| format!("--- {f}\n{}", std::fs::read_to_string(tmp.path().join(f)).unwrap_or_default()))
            .join("\n")
    };
    assert_eq!(summary.keyframe_ids, expected, "every keyframe id exactly once after de-duplication\n{}", logs());
    assert!(summary.end_of_stream);
    assert!(summary.duplicates <= 2, "only the keyframe in flight may be redone ({} duplicates)", summary.duplicates);
    assert!(summary.payload_in_shared_memory);
    // A tissue plane with texture everywhere: the map is dense.
    assert!(summary.mean_density > 0.5, "density {}", summary.mean_density);

    // The killed instance's resources are reclaimed; nothing of the run is left.
    drop(depth);
    drop(ipc);
    bdis_slam::run_dir::remove_leftovers(&prefix);
    assert_no_leftovers(&prefix);
}
