#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Beyond one host (issue #21): the pipeline split over two iceoryx2 systems that share no memory — two
//! shared-memory prefixes, each run by its own launcher from its own launch file, standing for two hosts — and
//! joined only by `bdis-bridge` over Zenoh (TCP) on loopback. Host A runs acquisition, tracking and the stereo service;
//! host B the mosaic. The map B writes is byte for byte the map of the same run on one host, and a `kill -9` of
//! either side of the bridge mid-run loses no keyframe once the launcher has restarted it; mid-run, host A gets
//! host B's map as a snapshot through the bridge.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

use common::{TempDir, bdis_slam, prefix, render_small_colon, text, track_run};

/// One small rendered colon flight for every test here.
fn sequence() -> &'static Path {
    static SEQUENCE: OnceLock<TempDir> = OnceLock::new();
    SEQUENCE
        .get_or_init(|| {
            let tmp = TempDir::new("bridgeseq").removed_at_exit();
            render_small_colon(&tmp.path().join("colon"), 48);
            tmp
        })
        .path()
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port()
}

/// The two placements, as launch files in launch/: the map on host B (depth crosses), or the stereo service and
/// the map on host B (keyframes cross).
#[derive(Debug, Clone, Copy)]
enum Placement {
    Map,
    StereoAndMap,
}

impl Placement {
    fn files(self) -> (PathBuf, PathBuf) {
        let launch = Path::new(env!("CARGO_MANIFEST_DIR")).join("launch");
        match self {
            Placement::Map => (launch.join("two-hosts-a.toml"), launch.join("two-hosts-b.toml")),
            Placement::StereoAndMap => (launch.join("two-hosts-stereo-a.toml"), launch.join("two-hosts-stereo-b.toml")),
        }
    }
}

/// A placement's launch files as shipped, but paced at 10 Hz (so that a kill falls mid-run on a machine of any
/// speed) and with a probe of the poses on host B.
fn paced_launch_files(dir: &Path, placement: Placement) -> (PathBuf, PathBuf) {
    let (a, b) = placement.files();
    let a_text = std::fs::read_to_string(a).unwrap().replace(r#""on-demand""#, r#""on-demand:10hz""#);
    assert!(a_text.contains("on-demand:10hz"));
    let mut b_text = std::fs::read_to_string(b).unwrap();
    b_text
        .push_str("\n[[service]]\nname = \"probe\"\nbinary = \"bdis-slam\"\nargs = [\"probe\", \"poses\"]\ncore = 1\n");
    std::fs::write(dir.join("a.toml"), a_text).unwrap();
    std::fs::write(dir.join("b.toml"), b_text).unwrap();
    (dir.join("a.toml"), dir.join("b.toml"))
}

/// Starts a launcher on `launch` under its own prefix, with the shipped launch files' variables set.
fn start(launch: &Path, tag: &str, out: &Path, port: u16) -> Child {
    let seq = sequence().join("colon");
    Command::new(bdis_slam())
        .arg("run")
        .arg(launch)
        .args(["--ipc-prefix", &prefix(tag), "--out"])
        .arg(out)
        .env("BDIS_SEQUENCE", &seq)
        .env("BDIS_SETTINGS", seq.join("settings.yaml"))
        .env("BDIS_BRIDGE_PEER", format!("127.0.0.1:{port}"))
        .env("BDIS_BRIDGE_LISTEN", format!("127.0.0.1:{port}"))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn finish(child: Child, what: &str) -> String {
    let out = child.wait_with_output().unwrap();
    let said = format!("{}\n{}", text(&out.stdout), text(&out.stderr));
    assert!(out.status.success(), "{what}:\n{said}");
    said
}

fn keyframes_in(run: &Path, file: &str, key: &str) -> u64 {
    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(run.join(file)).unwrap()).unwrap();
    summary[key].as_u64().unwrap_or_else(|| panic!("{file}: {key}: {summary}"))
}

/// Runs the split pipeline; with `kill` ("send" or "receive"), host B's map is asked for on host A once B's mosaic
/// has taken in a few keyframes, then that side of the bridge is killed with SIGKILL. Returns (A's run folder, B's run folder, what the
/// launchers said).
fn split_run(tmp: &Path, tag: &str, placement: Placement, kill: Option<&str>) -> (PathBuf, PathBuf, String) {
    let port = free_port();
    let (a_toml, b_toml) = match kill {
        None => placement.files(),
        Some(_) => paced_launch_files(tmp, placement),
    };
    let (run_a, run_b) = (tmp.join("a"), tmp.join("b"));
    let host_b = start(&b_toml, &format!("{tag}b"), &run_b, port);
    let host_a = start(&a_toml, &format!("{tag}a"), &run_a, port);
    let mut said = String::new();
    if let Some(role) = kill {
        let log = if role == "send" { run_a.join("logs/bridge.log") } else { run_b.join("logs/bridge.log") };
        let mosaic_log = run_b.join("logs/mosaic.log");
        // Wait until B's mosaic has three keyframes: the kill falls mid-run.
        let deadline = std::time::Instant::now() + Duration::from_secs(120);
        while std::fs::read_to_string(&mosaic_log).unwrap_or_default().matches("keyframe ").count() < 3 {
            assert!(std::time::Instant::now() < deadline, "the mosaic on host B never started mapping");
            std::thread::sleep(Duration::from_millis(50));
        }
        // The map made on host B, asked for on host A (the bridge carries the snapshot's request and answer).
        let snapshot = run_a.join("snapshot-from-b.ply");
        let asked = Command::new(bdis_slam())
            .args(["snapshot", "--run"])
            .arg(&run_a)
            .arg("--out")
            .arg(&snapshot)
            .output()
            .unwrap();
        let answer = text(&asked.stdout);
        assert!(asked.status.success(), "a snapshot on host A:\n{answer}{}", text(&asked.stderr));
        let points: u64 = answer.split(": ").nth(1).and_then(|a| a.split(' ').next()).unwrap().parse().unwrap();
        let keyframes: u64 = answer.split(", ").nth(1).and_then(|a| a.split(' ').next()).unwrap().parse().unwrap();
        assert!(points > 0 && keyframes >= 3, "host B's map as host A sees it: {answer}");
        said.push_str(&answer);
        let pid = pid_of(&log, if role == "send" { "bdis-bridge send" } else { "bdis-bridge receive" });
        Command::new("kill").args(["-KILL", &pid.to_string()]).status().unwrap();
        said.push_str(&format!("killed the {role} side, pid {pid}\n"));
    }
    said.push_str(&finish(host_a, "host A"));
    said.push_str(&finish(host_b, "host B"));
    (run_a, run_b, said)
}

/// The pid of the running `bdis-bridge` whose arguments hold `command`'s role and whose run folder is the one
/// `log` is in (the launcher gives each service `BDIS_RUN_DIR`).
fn pid_of(log: &Path, command: &str) -> u32 {
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else { continue };
        let Ok(cmdline) = std::fs::read(entry.path().join("cmdline")) else { continue };
        let cmdline = String::from_utf8_lossy(&cmdline).replace('\0', " ");
        let Some(binary) = cmdline.split(' ').next() else { continue };
        let run_dir = log.parent().and_then(|l| l.parent()).unwrap();
        if cmdline.contains(&command["bdis-bridge".len()..])
            && binary.ends_with("bdis-bridge")
            && std::fs::read_to_string(entry.path().join("environ"))
                .map(|e| e.contains(&run_dir.display().to_string()))
                .unwrap_or(false)
        {
            return pid;
        }
    }
    panic!("no `{command}` of {} running", log.display())
}

#[test]
fn the_map_made_on_the_far_host_is_byte_for_byte_the_single_host_map() {
    let tmp = TempDir::new("bridge");
    let seq = sequence().join("colon");
    let single = tmp.path().join("single");
    track_run(&seq, &seq.join("settings.yaml"), &single, "brone", &[]);
    let near = std::fs::read(single.join("map.ply")).unwrap();
    for (placement, tag) in [(Placement::Map, "brmap"), (Placement::StereoAndMap, "brstereo")] {
        let dir = tmp.path().join(tag);
        std::fs::create_dir_all(&dir).unwrap();
        let (run_a, run_b, said) = split_run(&dir, tag, placement, None);
        let made = keyframes_in(&run_a, "tracking.json", "keyframes_created");
        assert_eq!(keyframes_in(&run_b, "mosaic.json", "keyframes_inserted"), made, "{placement:?}: {said}");
        let far = std::fs::read(run_b.join("map.ply")).unwrap();
        assert!(
            far == near,
            "{placement:?}: host B's map.ply ({} bytes) differs from the single host's ({} bytes)",
            far.len(),
            near.len()
        );
        // Nothing crossed but what the bridge carries: host A has no map, host B no trajectory.
        assert!(!run_a.join("map.ply").exists() && !run_b.join("trajectory.tum").exists(), "{placement:?}");
    }
}

#[test]
fn a_killed_sender_or_receiver_loses_no_keyframe_once_restarted() {
    let cases = [
        (Placement::Map, "send"),
        (Placement::Map, "receive"),
        (Placement::StereoAndMap, "send"),
        (Placement::StereoAndMap, "receive"),
    ];
    for (placement, role) in cases {
        let tmp = TempDir::new(&format!("bridgekill{role}"));
        let (run_a, run_b, said) = split_run(tmp.path(), &format!("brk{role}"), placement, Some(role));
        assert!(said.contains("bridge restarted"), "{placement:?}: the launcher restarted the {role} side:\n{said}");
        let made = keyframes_in(&run_a, "tracking.json", "keyframes_created");
        let mapped = keyframes_in(&run_b, "mosaic.json", "keyframes_inserted");
        assert_eq!(mapped, made, "{placement:?}, kill -9 of the {role} side: keyframes lost\n{said}");
        // The poses crossed too, to their end, in order; a receiver that died is sent again what it had not
        // acknowledged, so none is missing then (a sender that died misses those published while it was down:
        // poses have no history to redo them from).
        let poses: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run_b.join("probe.json")).unwrap()).unwrap();
        assert_eq!(poses["end_of_stream"], true, "{placement:?}: {poses}");
        assert_eq!(poses["frame_seqs_in_order"], true, "{placement:?}: {poses}");
        if role == "receive" {
            let frames = keyframes_in(&run_a, "tracking.json", "frames");
            assert_eq!(poses["records"].as_u64(), Some(frames), "{placement:?}: {poses}");
        }
    }
}
