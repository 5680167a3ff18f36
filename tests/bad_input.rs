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

/// Runs `bdis-slam ARGS` and returns (exit code, its one error line).
fn one_error(args: &[&std::ffi::OsStr]) -> (Option<i32>, String) {
    let out = run_with_timeout(Command::new(bdis_slam()).args(args), Duration::from_secs(60));
    let stderr = text(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    let errors: Vec<&str> = stderr.lines().filter(|l| l.starts_with("bdis-slam: error:")).collect();
    assert_eq!(errors.len(), 1, "exactly one error line expected:\n{stderr}");
    (out.status.code(), errors[0].to_string())
}

fn calibration(r_row0: &str) -> String {
    let m = |key: &str, rows: usize, cols: usize, data: &str| {
        format!("{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {data} ]\n")
    };
    format!(
        "%YAML:1.0\nwidth: 48\nheight: 32\n{}{}{}{}{}{}",
        m("M1", 3, 3, "40., 0., 24., 0., 40., 16., 0., 0., 1."),
        m("D1", 1, 5, "-0.1, 0.01, 0., 0., 0."),
        m("M2", 3, 3, "40., 0., 24., 0., 40., 16., 0., 0., 1."),
        m("D2", 1, 5, "-0.1, 0.01, 0., 0., 0."),
        m("R", 3, 3, &format!("{r_row0}, 0., 1., 0., 0., 0., 1.")),
        m("T", 3, 1, "-5., 0., 0."),
    )
}

#[test]
fn bad_calibrations_and_a_rectification_that_breaks_mid_sequence() {
    let tmp = TempDir::new("badcalib");
    let (seq, _) = good_sequence(&tmp, 4);
    let calib = tmp.path().join("calib.yaml");
    let os = |p: &Path| p.as_os_str().to_owned();
    // R is not a rotation: the file, the line of `R` and why.
    std::fs::write(&calib, calibration("1., 0.3, 0.")).unwrap();
    let (code, line) = one_error(&["calib".as_ref(), "show".as_ref(), &os(&calib)]);
    assert_eq!(code, Some(1));
    assert!(
        line.contains(&format!("{}:", calib.display())) && line.contains("`R`") && line.contains("not a rotation"),
        "{line}"
    );
    // The calibration is for another image size than the sequence's.
    std::fs::write(&calib, calibration("1., 0., 0.").replace("width: 48", "width: 64")).unwrap();
    let out_dir = tmp.path().join("rectified");
    let args = |c: &Path| {
        vec![
            os(Path::new("rectify")),
            os(Path::new("--settings")),
            os(c),
            os(Path::new("--sequence")),
            os(&seq),
            os(Path::new("--out")),
            os(&out_dir),
        ]
    };
    let (code, line) = one_error(&args(&calib).iter().map(|s| s.as_os_str()).collect::<Vec<_>>());
    assert_eq!(code, Some(1));
    assert!(line.contains("the calibration is for 64×32 images") && line.contains("is 48×32"), "{line}");
    // An image that breaks mid-sequence: the pairs before it are kept, with their times.
    std::fs::write(&calib, calibration("1., 0., 0.")).unwrap();
    std::fs::write(seq.join("times.txt"), "0.0\n0.1\n0.2\n0.3\n").unwrap();
    // Its header is whole (the sequence check passes it), its pixel data cut short.
    let png = std::fs::read(seq.join("left/3.png")).unwrap();
    std::fs::write(seq.join("left/3.png"), &png[..png.len() / 2]).unwrap();
    let out = run_with_timeout(Command::new(bdis_slam()).args(args(&calib)), Duration::from_secs(60));
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
    let errors: Vec<String> =
        text(&out.stderr).lines().filter(|l| l.starts_with("bdis-slam: error:")).map(String::from).collect();
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(errors[0].contains("left/3.png"), "{}", errors[0]);
    assert!(out_dir.join("left/1.png").is_file() && out_dir.join("right/2.png").is_file());
    assert!(out_dir.join("settings.yaml").is_file());
    let times = std::fs::read_to_string(out_dir.join("times.txt")).unwrap();
    assert_eq!(times.lines().count(), 2, "the two pairs written keep their times:\n{times}");
}
