#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Issue #18's first "Done when", through the real processes: the same colon flight rendered rectified, and
//! rendered through raw rigs — `mild` (barrel distortion, cameras turned by up to 0.5°, focal lengths and
//! principal points off by a few pixels) and `strong` (a wide lens's 8-coefficient rational distortion, turned
//! by up to 1.5°) — then rectified from the rig's `calib.yaml` (by `bdis-slam rectify` for `mild`; by `run`
//! itself, given the raw calibration as its settings, for `strong`), builds a map within
//! 10 % of the rectified render's map error (mean distance to the mesh) and tracks within 1.5× its ATE.
//!
//! Why 1.5× and not the 10 % for the ATE: one run of this tracker moves by ±20 % with the start frame
//! alone (BENCHMARKS.md, issue #16), so a 10 % bound on single runs would fail by chance. The rectification
//! itself is checked to 0.01 px against a direct render of the rectified cameras
//! (`shared/synth/tests/raw_lens.rs`); the ATE over 8 start frames is in BENCHMARKS.md (raw input).
//!
//! The `strong` rig's frames also go in as a raw video (one lossless file per view) with the raw calibration:
//! acquisition then rectifies every frame as it reads it, held to the same bars.
//!
//! Bouguet's rectified frame is not the renderer's (it splits the cameras' rotation its own way), so the
//! rectified cameras are turned against the rendered ones by a constant rotation; their centres are the
//! same, and the ATE and the map error align by the camera centres.

mod common;

use common::*;
use std::path::Path;
use std::process::Command;
use std::time::Duration;

const FRAMES: usize = 40;

fn synth(out: &Path, raw: Option<&str>) {
    let mut cmd = Command::new(bdis_slam());
    cmd.args([
        "synth",
        "--frames",
        &FRAMES.to_string(),
        "--width",
        "320",
        "--height",
        "240",
        "--focal",
        "260",
        "--out",
    ])
    .arg(out);
    if let Some(raw) = raw {
        cmd.args(["--raw", raw]);
    }
    let out = run_with_timeout(&mut cmd, Duration::from_secs(900));
    assert!(out.status.success(), "{}", text(&out.stderr));
}

/// Tracks and maps `seq` with `settings` through the processes; (ATE RMSE mm, path mm, mean map error mm).
fn run(seq: &Path, settings: &Path, gt: &Path, run_dir: &Path, tag: &str) -> (f64, f64, f64) {
    track_run(seq, settings, run_dir, tag, &[]);
    let (rmse, length) = ate(gt, run_dir);
    let score = map_score(gt, run_dir);
    let mean = score["inliers"]["mean"].as_f64().unwrap_or_else(|| panic!("no inliers.mean in {score}"));
    (rmse, length, mean)
}

#[test]
fn raw_distorted_footage_rectified_here_tracks_and_maps_as_well_as_a_rectified_render() {
    let tmp = TempDir::new("raw-input");
    let rectified = tmp.path().join("rectified");
    synth(&rectified, None);
    let (ate_ref, length, map_ref) =
        run(&rectified, &rectified.join("settings.yaml"), &rectified, &tmp.path().join("run-rectified"), "raw-ref");
    eprintln!("rendered rectified: ATE {ate_ref:.4} mm over {length:.1} mm, map error {map_ref:.4} mm");
    for rig in ["mild", "strong"] {
        let raw = tmp.path().join(format!("raw-{rig}"));
        synth(&raw, Some(rig));
        assert!(!raw.join("settings.yaml").exists(), "a raw render has no rectified settings to mistake");
        let run_dir = tmp.path().join(format!("run-{rig}"));
        let (ate, _, map) = if rig == "mild" {
            // The offline step: `bdis-slam rectify`, then a run on its output.
            let ours = tmp.path().join(format!("rectified-{rig}"));
            let out = run_with_timeout(
                Command::new(bdis_slam())
                    .args(["rectify", "--settings"])
                    .arg(raw.join("calib.yaml"))
                    .arg("--sequence")
                    .arg(&raw)
                    .arg("--out")
                    .arg(&ours),
                Duration::from_secs(300),
            );
            assert!(out.status.success(), "{}", text(&out.stderr));
            run(&ours, &ours.join("settings.yaml"), &raw, &run_dir, &format!("raw-{rig}"))
        } else {
            // `run` given the raw calibration rectifies into the run folder by itself.
            let result = run(&raw, &raw.join("calib.yaml"), &raw, &run_dir, &format!("raw-{rig}"));
            assert!(run_dir.join("sequence/settings.yaml").is_file() && run_dir.join("sequence/left/1.png").is_file());
            result
        };
        eprintln!(
            "raw `{rig}`, rectified here: ATE {ate:.4} mm ({:+.0} %), map error {map:.4} mm ({:+.0} %)",
            100.0 * (ate / ate_ref - 1.0),
            100.0 * (map / map_ref - 1.0)
        );
        assert!(ate <= 1.5 * ate_ref, "`{rig}`: ATE {ate} mm against {ate_ref} mm rendered rectified");
        assert!(map <= 1.1 * map_ref, "`{rig}`: map error {map} mm against {map_ref} mm rendered rectified");
        if rig == "strong" && have_ffmpeg() {
            // The same raw frames as a video (FFV1, lossless, a file per view) with the raw calibration:
            // acquisition rectifies every frame as it reads it, straight into shared memory, and nothing is
            // written to disk. The same pixels as the folder route up to a grey level (grey is remapped here,
            // computed from the remapped colour there), held to the same bars against the rectified render:
            // a grey level's difference moves a single run's ATE by tens of percent either way (measured:
            // 0.068 mm from the folder, 0.046 mm from the video), so the two routes are not compared run by run.
            let mut files = Vec::new();
            for side in ["left", "right"] {
                let file = tmp.path().join(format!("raw-{rig}-{side}.mkv"));
                let out = run_with_timeout(
                    Command::new("ffmpeg")
                        .args(["-v", "error", "-y", "-framerate", "30", "-i"])
                        .arg(raw.join(format!("{side}/%d.png")))
                        .args(["-c:v", "ffv1", "-pix_fmt", "bgr0"])
                        .arg(&file),
                    Duration::from_secs(120),
                );
                assert!(out.status.success(), "{}", text(&out.stderr));
                files.push(file.display().to_string());
            }
            let video = format!("video:two-files:{},{}", files[0], files[1]);
            let video_run = tmp.path().join(format!("run-{rig}-video"));
            let (ate_v, _, map_v) =
                run(Path::new(&video), &raw.join("calib.yaml"), &raw, &video_run, &format!("raw-{rig}-video"));
            eprintln!("raw `{rig}` as a video, rectified in acquisition: ATE {ate_v:.4} mm, map error {map_v:.4} mm");
            assert!(!video_run.join("sequence").exists(), "a raw video is rectified in memory, not on disk");
            assert!(
                ate_v <= 1.5 * ate_ref,
                "ATE {ate_v} mm from the raw video against {ate_ref} mm rendered rectified"
            );
            assert!(
                map_v <= 1.1 * map_ref,
                "map error {map_v} mm from the raw video against {map_ref} mm rendered rectified"
            );
        }
        if rig == "strong" {
            // The raw rig behind a live grabber (the emulated device, side by side, YUYV, 10 Hz): acquisition
            // rectifies each frame as it takes it, the rectified settings come from the calibration alone.
            let live = format!("live:emulated:side-by-side:yuyv:10hz:{}", raw.display());
            let live_run = tmp.path().join(format!("run-{rig}-live"));
            track_run(&live, &raw.join("calib.yaml"), &live_run, &format!("raw-{rig}-live"), &[]);
            assert!(live_run.join("settings.yaml").is_file() && !live_run.join("sequence").exists());
            // Poses are on the device's clock (frame k at k / 10 s): the truth is put on it to compare.
            let mut gt = bdis_core::formats::trajectory::read_tum(&raw.join("gt/poses.tum")).unwrap();
            for (k, p) in gt.iter_mut().enumerate() {
                p.t_s = k as f64 / 10.0;
            }
            let est = bdis_core::formats::trajectory::read_tum(&live_run.join("trajectory.tum")).unwrap();
            let ate_l = bdis_eval::traj::ate(&gt, &est, 1e-3).unwrap().translation.rmse;
            eprintln!("raw `{rig}` live, rectified in acquisition: ATE {ate_l:.4} mm over {} poses", est.len());
            assert_eq!(est.len(), FRAMES, "a pose for every live frame");
            assert!(ate_l <= 1.5 * ate_ref, "ATE {ate_l} mm live against {ate_ref} mm rendered rectified");
        }
    }
}
