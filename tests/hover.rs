#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Issue #6's hardest bound, through the real processes: the synthetic abdomen **hovered** over (400 frames at
//! 640×480, the scope drifting a few millimetres 55 mm above the wall) is tracked to within 0.1 % of its short
//! path (26 mm, so 26 µm ATE RMSE), without loss, the same twice.
//!
//! At this distance a 5 mm-baseline scope holds the pose weakly along the rotation–sideways-translation
//! ambiguity, so the bound needs sub-pixel measurements (`shared/track/src/refine.rs`): with ORB-SLAM2's
//! whole-pixel keypoints the same run gives 0.179 mm (0.68 %). Rendering the sequence takes ~6 minutes on
//! 2 cores; it has its own test binary so that it does not share the cores with the colon test's timing
//! comparisons.

mod common;

use common::*;
use std::process::Command;
use std::time::Duration;

const FRAMES: usize = 400;

#[test]
fn the_hover_is_tracked_within_a_thousandth_of_its_path() {
    let tmp = TempDir::new("hover");
    let seq = tmp.path().join("hover");
    let out = run_with_timeout(
        Command::new(bdis_slam())
            .args(["synth", "--scene", "abdomen", "--trajectory", "hover", "--frames", &FRAMES.to_string(), "--out"])
            .arg(&seq),
        Duration::from_secs(1800),
    );
    assert!(out.status.success(), "{}", text(&out.stderr));

    let mut trajectories = Vec::new();
    for tag in ["hover-a", "hover-b"] {
        let run_dir = tmp.path().join(tag);
        track_run(&seq, &seq.join("settings.yaml"), &run_dir, tag, &[]);
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run_dir.join("tracking.json")).unwrap()).unwrap();
        assert_eq!(summary["frames"], FRAMES as u64, "{summary}");
        assert_eq!(summary["lost"], 0, "{summary}");
        let (rmse, length) = ate(&seq, &run_dir);
        eprintln!(
            "{tag}: ATE RMSE {:.1} µm over {length:.1} mm ({:.3} %); {summary}",
            1000.0 * rmse,
            100.0 * rmse / length
        );
        assert!(rmse <= 0.001 * length, "ATE {rmse} mm over a {length} mm hover");
        trajectories.push(std::fs::read(run_dir.join("trajectory.tum")).unwrap());
    }
    assert_eq!(trajectories[0], trajectories[1], "the same run twice gives the same trajectory");
}
