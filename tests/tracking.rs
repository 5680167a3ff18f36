#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Tracking through the real processes (acquisition → tracking → stereo → probe over iceoryx2) on the project's
//! synthetic colon: accuracy against the renderer's ground truth, determinism, and recovery after the view is
//! lost (black frames).
//!
//! The sequence is rendered once at 320×240 (f = 260, 5 mm baseline), 400 frames: at 640×480 rendering alone
//! would take ~10 minutes on the CI machine.

mod common;

use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use bdis_core::formats::trajectory::read_tum;

const FRAMES: usize = 400;

fn render(dir: &Path) {
    let out = run_with_timeout(
        Command::new(bdis_slam())
            .args(["synth", "--scene", "colon", "--trajectory", "forward", "--frames", &FRAMES.to_string()])
            .args(["--width", "320", "--height", "240", "--focal", "260", "--out"])
            .arg(dir),
        Duration::from_secs(900),
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
}

/// Runs the tracking pipeline on `seq`; returns the run folder.
fn track(tmp: &TempDir, seq: &Path, tag: &str) -> PathBuf {
    let run_dir = tmp.path().join(tag);
    let prefix = prefix(tag);
    let out = run_with_timeout(
        Command::new(bdis_slam())
            .args(["run", "--track", "--sequence"])
            .arg(seq)
            .arg("--settings")
            .arg(seq.join("settings.yaml"))
            .args(["--ipc-prefix", &prefix, "--out"])
            .arg(&run_dir),
        Duration::from_secs(600),
    );
    assert!(out.status.success(), "{tag}: {}\n{}", text(&out.stdout), text(&out.stderr));
    assert_no_leftovers(&prefix);
    run_dir
}

fn summary(run_dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(run_dir.join("tracking.json")).unwrap()).unwrap()
}

/// ATE RMSE (mm) of a run's trajectory, and the ground-truth path length.
fn ate(seq: &Path, run_dir: &Path) -> (f64, f64) {
    let gt = read_tum(&seq.join("gt/poses.tum")).unwrap();
    let est = read_tum(&run_dir.join("trajectory.tum")).unwrap();
    assert_eq!(est.len(), gt.len(), "a pose for every frame");
    let ate = bdis_eval::traj::ate(&gt, &est, 0.01).unwrap();
    let length: f64 = gt
        .windows(2)
        .map(|w| (w[1].world_from_camera.translation.vector - w[0].world_from_camera.translation.vector).norm())
        .sum();
    (ate.translation.rmse, length)
}

/// A black PNG of the sequence's size.
fn black(path: &Path) {
    image::RgbImage::new(320, 240).save(path).unwrap();
}

#[test]
fn tracks_the_synthetic_colon_deterministically_and_recovers_after_black_frames() {
    let tmp = TempDir::new("tracking");
    let seq = tmp.path().join("colon");
    render(&seq);

    // Clean run, twice: no loss, bounded error, byte-identical trajectories.
    let a = track(&tmp, &seq, "track-a");
    let b = track(&tmp, &seq, "track-b");
    let sa = summary(&a);
    assert_eq!(sa["frames"], FRAMES as u64);
    assert_eq!(sa["lost"], 0, "{sa}");
    let (rmse, length) = ate(&seq, &a);
    let relative = rmse / length;
    eprintln!("clean: ATE RMSE {rmse:.3} mm over {length:.1} mm ({:.3} %); {sa}", 100.0 * relative);
    // The target is 0.1 % of the path: met at 640×480 (0.03 %); at this resolution 0.11–0.12 % was
    // measured (0.31–0.33 mm). The bound catches regressions.
    assert!(relative < 0.003, "ATE {rmse} mm over {length} mm");
    assert_eq!(
        std::fs::read(a.join("trajectory.tum")).unwrap(),
        std::fs::read(b.join("trajectory.tum")).unwrap(),
        "the same run twice gives the same trajectory"
    );
    // Every keyframe went through the dense stereo.
    let keyframes = read_tum(&a.join("keyframes.tum")).unwrap();
    let depth: bdis_slam::probe::DepthSummary =
        serde_json::from_str(&std::fs::read_to_string(a.join("probe.json")).unwrap()).unwrap();
    assert_eq!(depth.keyframe_ids.len() as u64, sa["keyframes_created"].as_u64().unwrap());
    assert!(keyframes.len() >= 10);

    // Ten black frames in the middle: the tracker reports lost, relocalises when the view returns, and the
    // trajectory stays within twice the clean error.
    let dark = tmp.path().join("colon-dark");
    for side in ["left", "right"] {
        std::fs::create_dir_all(dark.join(side)).unwrap();
        for n in 1..=FRAMES {
            let (src, dst) = (seq.join(format!("{side}/{n}.png")), dark.join(format!("{side}/{n}.png")));
            if (201..=210).contains(&n) {
                black(&dst);
            } else {
                std::os::unix::fs::symlink(&src, &dst).unwrap();
            }
        }
    }
    for f in ["times.txt", "settings.yaml"] {
        std::fs::copy(seq.join(f), dark.join(f)).unwrap();
    }
    std::fs::create_dir_all(dark.join("gt")).unwrap();
    std::fs::copy(seq.join("gt/poses.tum"), dark.join("gt/poses.tum")).unwrap();
    let c = track(&tmp, &dark, "track-dark");
    let sc = summary(&c);
    let (rmse_dark, _) = ate(&dark, &c);
    eprintln!("with 10 black frames: ATE RMSE {rmse_dark:.3} mm; {sc}");
    assert!(sc["lost"].as_u64().unwrap() >= 10, "{sc}");
    assert!(sc["relocalisations"].as_u64().unwrap() >= 1, "{sc}");
    assert!(sc["lost"].as_u64().unwrap() <= 20, "back on track within 10 frames of the view returning: {sc}");
    assert!(rmse_dark <= 2.0 * rmse, "ATE {rmse_dark} mm with black frames vs {rmse} mm without");
}
