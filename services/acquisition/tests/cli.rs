#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! The `bdis-acquisition` binary on its own: checks input before creating any shared memory.

use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_bdis-acquisition"))
}

#[test]
fn check_mode_summarises_a_sequence() {
    let root = std::env::temp_dir().join(format!("bdis-acq-cli-{}", std::process::id()));
    for side in ["left", "right"] {
        std::fs::create_dir_all(root.join(side)).unwrap();
        for n in 1..=2 {
            image::RgbImage::new(16, 8).save(root.join(format!("{side}/{n}.png"))).unwrap();
        }
    }
    let out = bin().arg("--sequence").arg(&root).arg("--check").output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("Plain layout, 2 stereo pairs of 16×8, timestamps: no"), "{stdout}");
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn a_missing_sequence_is_one_line_and_exit_1() {
    let out = bin().args(["--sequence", "/nonexistent/seq"]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(
        String::from_utf8_lossy(&out.stderr).trim(),
        "bdis-acquisition: error: /nonexistent/seq: sequence folder not found"
    );
}

#[test]
fn bad_pacing_is_rejected_by_the_argument_parser() {
    let out = bin().args(["--sequence", "/x", "--pacing", "fast"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&out.stderr)
            .contains("expected on-demand, on-demand:<rate>, recorded, or a rate such as 30hz")
    );
}

#[test]
fn a_synthetic_source_is_rendered_then_checked() {
    let dir = std::env::temp_dir().join(format!("bdis-acq-synth-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out =
        bin().args(["--sequence", "synthetic:abdomen:hover:2", "--check"]).env("BDIS_RUN_DIR", &dir).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("2 stereo pairs of 640×480, timestamps: 0.000–0.033 s"));
    let out = bin().args(["--sequence", "synthetic:volcano"]).env("BDIS_RUN_DIR", &dir).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(
        String::from_utf8_lossy(&out.stderr).trim(),
        "bdis-acquisition: error: `volcano` is not a scene (colon, abdomen)"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
