#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Hostile input at the shared-memory boundary, end to end: the whole pipeline (acquisition → tracking → stereo →
//! mosaic, a poses probe) runs twice on the same rendered colon sequence, once clean and once with `bdis-rogue`
//! joining it and sending malformed samples on every topic (see tests/fixture/src/rogue.rs). No service may
//! die, every bad sample must be counted by the process it reached (latency.json), and the trajectory and the
//! map must be byte-identical to the clean run's. The run also shows its privacy: the run folder and its files
//! are owner-only, and the services that hold frames write no core dump.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

use common::*;

/// 320×240 (as the tracking tests); at 5 Hz the run lasts 14 s, many times what the rogue needs (about a second
/// for all its samples on an idle machine).
const FRAMES: usize = 70;

fn render(dir: &Path) {
    let out = run_with_timeout(
        Command::new(bdis_slam())
            .args(["synth", "--scene", "colon", "--trajectory", "forward", "--frames", &FRAMES.to_string()])
            .args(["--width", "320", "--height", "240", "--focal", "260", "--out"])
            .arg(dir),
        Duration::from_secs(600),
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
}

fn run_command(seq: &Path, prefix: &str, run_dir: &Path) -> Command {
    let mut cmd = Command::new(bdis_slam());
    cmd.args(["run", "--track", "--sequence"])
        .arg(seq)
        .arg("--settings")
        .arg(seq.join("settings.yaml"))
        .args(["--pacing", "on-demand:5hz", "--ipc-prefix", prefix, "--out"])
        .arg(run_dir);
    cmd
}

fn latency(run_dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(run_dir.join("latency.json")).unwrap()).unwrap()
}

/// Refusals per process, `topic/reason` → count, from latency.json.
fn refusals(latency: &serde_json::Value) -> BTreeMap<String, BTreeMap<String, u64>> {
    latency["processes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            let counts = p["rejected"]
                .as_object()
                .map(|m| m.iter().map(|(k, v)| (k.clone(), v.as_u64().unwrap())).collect())
                .unwrap_or_default();
            (p["name"].as_str().unwrap().to_string(), counts)
        })
        .collect()
}

/// The pids and names of `parent`'s children (from /proc).
fn children(parent: u32) -> Vec<(u32, String)> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else { continue };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else { continue };
        // `pid (comm) state ppid …`: the name may hold spaces, so split after the last ')'.
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else { continue };
        let ppid = stat[close + 1..].split_whitespace().nth(1).and_then(|p| p.parse::<u32>().ok());
        if ppid == Some(parent) {
            out.push((pid, stat[open + 1..close].to_string()));
        }
    }
    out
}

/// Every file under `dir` (and `dir`) is owner-only: patient images, maps and logs are not for other users.
fn assert_private(dir: &Path) {
    use std::os::unix::fs::PermissionsExt;
    let mode = std::fs::metadata(dir).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o700, "{} is {mode:o}", dir.display());
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let path = e.path();
        if path.is_dir() {
            assert_private(&path);
        } else {
            let mode = e.metadata().unwrap().permissions().mode() & 0o777;
            assert_eq!(mode & 0o077, 0, "{} is {mode:o}", path.display());
        }
    }
}

#[test]
fn a_rogue_publisher_on_every_topic_is_refused_counted_and_changes_nothing() {
    let tmp = TempDir::new("hostile");
    let seq = tmp.path().join("colon");
    render(&seq);

    // The clean run.
    let clean_dir = tmp.path().join("clean");
    let clean_prefix = prefix("clean");
    let out = run_with_timeout(&mut run_command(&seq, &clean_prefix, &clean_dir), Duration::from_secs(300));
    assert!(out.status.success(), "clean run: {}\n{}", text(&out.stdout), text(&out.stderr));
    assert_no_leftovers(&clean_prefix);
    let clean = latency(&clean_dir);
    for (process, counts) in refusals(&clean) {
        assert!(counts.is_empty(), "the clean run's {process} refused samples: {counts:?}");
    }

    // The same run with a poses consumer and the rogue.
    let dir = tmp.path().join("attacked");
    let prefix = prefix("rogue");
    let mut run = run_command(&seq, &prefix, &dir).stdout(std::process::Stdio::piped()).spawn().unwrap();
    // The services that hold frames write no core dump (a crash must not put patient images on disk).
    let services = ["bdis-acquisitio", "bdis-tracking", "bdis-stereo", "bdis-mosaic"];
    let start = std::time::Instant::now();
    let mut checked = std::collections::BTreeSet::new();
    while checked.len() < services.len() && start.elapsed() < Duration::from_secs(30) {
        for (pid, name) in children(run.id()) {
            if services.contains(&name.as_str()) && !checked.contains(&name) {
                let limits = std::fs::read_to_string(format!("/proc/{pid}/limits")).unwrap_or_default();
                let core = limits.lines().find(|l| l.starts_with("Max core file size")).unwrap_or("");
                let soft = core.split_whitespace().nth(4);
                if soft.is_some() {
                    assert_eq!(soft, Some("0"), "{name}: {core}");
                    checked.insert(name);
                }
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(checked.len(), services.len(), "saw the services {checked:?}");
    let probe = Command::new(bdis_slam())
        .args(["probe", "poses", "--name", "probe-poses", "--idle-timeout", "120", "--ipc-prefix", &prefix])
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let manifest_path = tmp.path().join("rogue.json");
    let rogue = run_with_timeout(
        Command::new(service_binary("bdis-rogue"))
            .args(["--timeout", "60", "--ipc-prefix", &prefix, "--manifest"])
            .arg(&manifest_path),
        Duration::from_secs(240),
    );
    let status = run.wait().unwrap();
    let probe_out = probe.wait_with_output().unwrap();
    let mut stdout = String::new();
    std::io::Read::read_to_string(run.stdout.as_mut().unwrap(), &mut stdout).unwrap();
    assert!(rogue.status.success(), "rogue: {}", text(&rogue.stderr));
    assert!(status.success(), "the attacked run failed:\n{stdout}");
    assert!(probe_out.status.success(), "the poses probe failed");
    assert_no_leftovers(&prefix);

    // No service died or was restarted.
    let attacked = latency(&dir);
    for p in attacked["processes"].as_array().unwrap() {
        assert_eq!(p["ended"], "finished", "{}", p["name"]);
        assert_eq!(p["restarts"], 0, "{}", p["name"]);
    }

    // Every bad sample was refused by the process it reached, and counted: exactly what the rogue sent.
    let manifest: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&manifest_path).unwrap()).unwrap();
    let mut expected: BTreeMap<String, BTreeMap<String, u64>> = BTreeMap::new();
    let mut launcher_expected = 0;
    for s in &manifest {
        let (topic, consumer) = (s["topic"].as_str().unwrap(), s["consumer"].as_str().unwrap());
        let Some(reason) = s["reason"].as_str() else { continue };
        if consumer == "launcher" {
            launcher_expected += 1;
            continue;
        }
        if s["what"] != "a correction for a keyframe never made" {
            assert_eq!(s["confirmed"], true, "{consumer} did not refuse {} on {topic} promptly", s["what"]);
        }
        *expected.entry(consumer.to_string()).or_default().entry(format!("{topic}/{reason}")).or_default() += 1;
    }
    assert!(
        manifest.iter().any(|s| s["what"] == "a generation already applied"),
        "the run is long enough for a late correction (one of a generation the map applied)"
    );
    let topics: std::collections::BTreeSet<&str> = manifest.iter().map(|s| s["topic"].as_str().unwrap()).collect();
    assert_eq!(topics.len(), 6, "the rogue covers frames, keyframes, depth, corrections, poses and telemetry");
    let got = refusals(&attacked);
    for (consumer, counts) in &expected {
        assert_eq!(got.get(consumer), Some(counts), "{consumer}'s refusals (latency.json) against what the rogue sent");
    }
    assert_eq!(attacked["telemetry_records_refused"], launcher_expected, "{stdout}\n{manifest:#?}");
    // The run's table says so too.
    assert!(stdout.contains("refused by"), "{stdout}");

    // The run folder and everything in it are owner-only.
    assert_private(&dir);

    // The good stream's results are untouched.
    for file in ["trajectory.tum", "keyframes.tum", "map.ply"] {
        assert!(
            std::fs::read(clean_dir.join(file)).unwrap() == std::fs::read(dir.join(file)).unwrap(),
            "{file} differs from the clean run's"
        );
    }
    let mosaic = |d: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(d.join("mosaic.json")).unwrap()).unwrap()
    };
    let (a, b) = (mosaic(&clean_dir), mosaic(&dir));
    assert_eq!(b["duplicates"].as_u64().unwrap(), a["duplicates"].as_u64().unwrap() + 1, "the rogue's duplicate");
    assert_eq!(a["keyframes_inserted"], b["keyframes_inserted"]);
}
