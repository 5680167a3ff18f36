#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Bad input: one clear line naming the file and the field, a non-zero exit, no panic, no shared memory left
//! behind, and whatever was already produced is kept.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use common::*;

/// Runs `bdis-slam run --sequence SEQ --settings SETTINGS` and returns (exit code, the error line, run dir).
fn run(tmp: &TempDir, seq: &Path, settings: Option<&Path>) -> (Option<i32>, String, PathBuf, String) {
    let prefix = prefix("bad");
    let run_dir = tmp.path().join("run");
    let mut cmd = Command::new(bdis_slam());
    cmd.args(["run", "--sequence"]).arg(seq);
    if let Some(s) = settings {
        cmd.arg("--settings").arg(s);
    }
    cmd.args(["--ipc-prefix", &prefix, "--out"]).arg(&run_dir);
    let out = run_with_timeout(&mut cmd, Duration::from_secs(60));
    let stderr = text(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("bdis-slam: error:")).collect();
    assert_eq!(errors.len(), 1, "exactly one error line expected:\n{stderr}");
    assert_no_leftovers(&prefix);
    (out.status.code(), errors[0].to_string(), run_dir, prefix)
}

fn good_sequence(tmp: &TempDir, n: usize) -> (PathBuf, PathBuf) {
    let seq = tmp.path().join("seq");
    write_sequence(&seq, n, 48, 32, 2);
    let settings = tmp.path().join("s.yaml");
    write_settings(&settings, 48, 32);
    (seq, settings)
}

#[test]
fn missing_folder() {
    let tmp = TempDir::new("nofolder");
    let missing = tmp.path().join("nope");
    let (code, line, run_dir, _) = run(&tmp, &missing, None);
    assert_eq!(code, Some(1));
    assert_eq!(line, format!("bdis-slam: error: {}: sequence folder not found", missing.display()));
    assert!(!run_dir.exists(), "nothing starts, so no run folder is made");
}

#[test]
fn missing_right_image() {
    let tmp = TempDir::new("noright");
    let (seq, settings) = good_sequence(&tmp, 4);
    std::fs::remove_file(seq.join("right/3.png")).unwrap();
    let (code, line, _, _) = run(&tmp, &seq, Some(&settings));
    assert_eq!(code, Some(1));
    assert!(
        line.ends_with(&format!(
            "{}: missing right image for {}",
            seq.join("right/3.png").display(),
            seq.join("left/3.png").display()
        )),
        "{line}"
    );
}

#[test]
fn unreadable_image() {
    let tmp = TempDir::new("garbage");
    let (seq, settings) = good_sequence(&tmp, 4);
    std::fs::write(seq.join("left/2.png"), b"this is not a png").unwrap();
    let (code, line, _, _) = run(&tmp, &seq, Some(&settings));
    assert_eq!(code, Some(1));
    assert!(line.contains(&format!("{}: unreadable image", seq.join("left/2.png").display())), "{line}");
}

#[test]
fn left_right_size_mismatch() {
    let tmp = TempDir::new("size");
    let (seq, settings) = good_sequence(&tmp, 3);
    image::RgbImage::new(40, 32).save(seq.join("right/2.png")).unwrap();
    let (code, line, _, _) = run(&tmp, &seq, Some(&settings));
    assert_eq!(code, Some(1));
    assert!(
        line.contains(&format!(
            "{}: size 40×32 differs from the left image {} (48×32)",
            seq.join("right/2.png").display(),
            seq.join("left/2.png").display()
        )),
        "{line}"
    );
}

#[test]
fn times_txt_shorter_or_longer_than_the_images() {
    let tmp = TempDir::new("times");
    let (seq, settings) = good_sequence(&tmp, 4);
    for (times, n) in [("0.0\n0.04\n0.08\n", 3), ("0\n1\n2\n3\n4\n", 5)] {
        std::fs::write(seq.join("times.txt"), times).unwrap();
        let (code, line, _, _) = run(&tmp, &seq, Some(&settings));
        assert_eq!(code, Some(1));
        assert!(
            line.ends_with(&format!("{}: {n} timestamps for 4 image pairs", seq.join("times.txt").display())),
            "{line}"
        );
    }
}

#[test]
fn malformed_or_incomplete_settings() {
    let tmp = TempDir::new("settings");
    let (seq, settings) = good_sequence(&tmp, 2);
    let good = std::fs::read_to_string(&settings).unwrap();
    let cases = [
        (good.replace("Camera.fx: 100.0\n", ""), "missing required key `Camera.fx`".to_string()),
        (
            good.replace("Camera.fx: 100.0", "Camera.fx: .nan"),
            ":2: `Camera.fx`: must be a finite number, found `.nan`".into(),
        ),
        (good.replace("Camera.fx: 100.0", "Camera.fx: 0"), ":2: `Camera.fx`: must be > 0, found 0".into()),
        (good.replace("Camera.bf: 500.0", "Camera.bf: -3"), ":9: `Camera.bf`: must be > 0, found -3".into()),
        (good.replace("Camera.bf: 500.0", "Camera.bf: 2055.77s"), ":9: `Camera.bf`: `2055.77s` is not a number".into()),
        (good.replace("Camera.width: 48", "Camera.width: 64"), "`Camera.width` is 64 but the images are 48".into()),
    ];
    for (text, expected) in cases {
        std::fs::write(&settings, &text).unwrap();
        let (code, line, _, _) = run(&tmp, &seq, Some(&settings));
        assert_eq!(code, Some(1));
        assert!(line.starts_with(&format!("bdis-slam: error: {}", settings.display())), "{line}");
        assert!(line.contains(&expected), "expected `{expected}` in `{line}`");
    }
}

#[test]
fn an_image_that_breaks_mid_stream_keeps_what_was_produced() {
    let tmp = TempDir::new("midstream");
    let (seq, settings) = good_sequence(&tmp, 6);
    // A valid header with truncated pixel data passes the up-front check and fails when decoded.
    let bytes = std::fs::read(seq.join("left/4.png")).unwrap();
    std::fs::write(seq.join("left/4.png"), &bytes[..bytes.len() / 2]).unwrap();
    let (code, line, run_dir, _) = run(&tmp, &seq, Some(&settings));
    assert_eq!(code, Some(1));
    assert!(line.contains("acquisition failed (exit code 1)"), "{line}");
    assert!(line.contains(&format!("{}: cannot decode", seq.join("left/4.png").display())), "{line}");
    // The three frames before it reached the consumer, which finished cleanly on end of stream.
    let summary: bdis_slam::probe::ProbeSummary =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("probe.json")).unwrap()).unwrap();
    assert_eq!(summary.frames_received, 3);
    assert!(summary.end_of_stream);
    let latency: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("latency.json")).unwrap()).unwrap();
    assert_eq!(latency["processes"][1]["messages"].as_u64(), Some(3), "{latency}");
}

#[test]
fn bad_launch_file_names_the_key() {
    let tmp = TempDir::new("launchfile");
    let launch = tmp.path().join("l.toml");
    std::fs::write(&launch, "[[service]]\nname = \"a\"\nbinary = \"bdis-acquisition\"\ncpu = 0\n").unwrap();
    let out = run_with_timeout(Command::new(bdis_slam()).arg("run").arg(&launch), Duration::from_secs(30));
    assert_eq!(out.status.code(), Some(1));
    let stderr = text(&out.stderr);
    assert!(stderr.contains(&format!("bdis-slam: error: {}:4: unknown field `cpu`", launch.display())), "{stderr}");
}
