#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Tracking on footage it was not tuned on, through the real processes: real car-mounted stereo
//! (`../shared/data/kitti-a`, metres, 1226×370, 1.2 m between frames, moving at the first frame) and the hard
//! cases of a motion prior rendered by our generator (a jerk at ten times the speed, a dead stop, a fast pan, a
//! low frame rate, a far background). Each is judged on its trajectory against the ground truth and on honesty:
//! a frame is `Ok` only when its pose is right.
//!
//! The synthetic cases are rendered once for the binary at 320×240 (f = 260), the smallest size that still holds
//! the property (the 640×480 figures are in BENCHMARKS.md); their pipelines run one at a time.

mod common;

use common::*;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Mutex, OnceLock};
use std::time::Duration;

use bdis_core::formats::quality::{self, QualityLog, ReportedState, read_quality_log};
use bdis_core::formats::trajectory::read_tum;
use bdis_core::geometry::StampedPose;

/// Pipelines one at a time: each pins its services to the machine's cores.
static PIPELINE: Mutex<()> = Mutex::new(());

/// Runs `run --track` on `seq` with `settings` into `tmp/tag`; returns the run folder.
fn track(tmp: &Path, seq: &Path, settings: &Path, tag: &str) -> PathBuf {
    let _one_at_a_time = PIPELINE.lock().unwrap_or_else(|e| e.into_inner());
    let run_dir = tmp.join(tag);
    let prefix = prefix(tag);
    let out = run_with_timeout(
        Command::new(bdis_slam())
            .args(["run", "--track", "--ipc-prefix", &prefix, "--sequence"])
            .arg(seq)
            .arg("--settings")
            .arg(settings)
            .arg("--out")
            .arg(&run_dir),
        Duration::from_secs(600),
    );
    assert!(out.status.success(), "{tag}: {}\n{}", text(&out.stdout), text(&out.stderr));
    assert_no_leftovers(&prefix);
    run_dir
}

/// The run's `tracking-quality.csv`, read as the viewer and `eval` read it.
fn quality_log(run_dir: &Path) -> QualityLog {
    read_quality_log(&run_dir.join(quality::FILE_NAME)).unwrap()
}

fn path_length(gt: &[StampedPose]) -> f64 {
    gt.windows(2)
        .map(|w| (w[1].world_from_camera.translation.vector - w[0].world_from_camera.translation.vector).norm())
        .sum()
}

/// The honesty bar of the issue: an `Ok` frame's position, relative to the last keyframe, is within 1 % of the
/// distance travelled since that keyframe — checked where that distance is at least `min_steps` median steps
/// (below it the 1 % is under the measurement noise of any tracker). Returns (frames checked, worst error /
/// distance).
fn ok_frames_are_right(gt: &[StampedPose], est: &[StampedPose], run_dir: &Path, min_steps: f64) -> (usize, f64) {
    use bdis_eval::status::{StatusBar, judge_ok_frames};
    let bar = StatusBar { max_error_of_travel: 0.01, min_steps };
    let honesty = judge_ok_frames(gt, est, &[], &quality_log(run_dir), 1e-4, bar).unwrap();
    if let Some(w) = honesty.wrong_ok.first() {
        panic!(
            "frame at {:.3} s: Ok with {:.2} % of the {:.3} travelled since the keyframe at {:.3} s ({} such frames)",
            w.t_s,
            100.0 * w.error_of_travel,
            w.travelled,
            w.keyframe_t_s,
            honesty.wrong_ok.len()
        );
    }
    (honesty.judged, honesty.worst_error_of_travel)
}

#[test]
fn real_car_footage_in_metres_is_tracked_to_one_percent_with_every_step_right() {
    let Some(seq) = shared_data("kitti-a") else { return };
    let tmp = TempDir::new("kitti");
    let settings = seq.join("calib.yaml");
    let first = track(tmp.path(), &seq, &settings, "kitti1");
    let gt = read_tum(&seq.join("groundtruth.txt")).unwrap();
    let est = read_tum(&first.join("trajectory.tum")).unwrap();
    assert_eq!(est.len(), gt.len(), "a pose for every frame");
    let ate = bdis_eval::traj::ate(&gt, &est, 0.01).unwrap().translation.rmse;
    let length = path_length(&gt);
    eprintln!("kitti-a: ATE {ate:.3} m over {length:.1} m = {:.3} %", 100.0 * ate / length);
    assert!(ate <= 0.01 * length, "ATE {ate:.3} m is more than 1 % of the {length:.1} m path");
    // Every frame-to-frame step within 5 % of the true one from frame 1 on (the old tracker: 0.15–0.3 m of
    // 1.2 m over the first ten frames).
    for k in 1..gt.len() {
        let step = |p: &[StampedPose]| {
            (p[k].world_from_camera.translation.vector - p[k - 1].world_from_camera.translation.vector).norm()
        };
        let (truth, estimate) = (step(&gt), step(&est));
        assert!((estimate - truth).abs() <= 0.05 * truth, "frame {k}: step {estimate:.3} m, the truth {truth:.3} m");
    }
    let rows = quality_log(&first).lines;
    assert_eq!(rows.len(), gt.len(), "a quality line per frame");
    // Footage a tracker can hold: the frames are Ok (their steps were checked above).
    let ok = rows.iter().filter(|r| r.state == ReportedState::Ok).count();
    eprintln!("kitti-a: {ok} of {} frames Ok", rows.len());
    assert!(ok >= rows.len() - 2, "only {ok} of {} frames Ok on footage that can be tracked", rows.len());
    // Deterministic: the same run again gives the same trajectory, byte for byte.
    let second = track(tmp.path(), &seq, &settings, "kitti2");
    assert_eq!(
        std::fs::read(first.join("trajectory.tum")).unwrap(),
        std::fs::read(second.join("trajectory.tum")).unwrap(),
        "two runs differ"
    );

    // Units-free: the same clip calibrated in millimetres (bf × 1000) gives the same trajectory × 1000. Only
    // floating-point rounding differs (f32 depths, RANSAC decisions at a gate), so within 0.05 % of the path.
    let mm = tmp.path().join("kitti-mm");
    std::fs::create_dir_all(&mm).unwrap();
    for side in ["left", "right"] {
        std::os::unix::fs::symlink(seq.join(side), mm.join(side)).unwrap();
    }
    std::fs::copy(seq.join("times.txt"), mm.join("times.txt")).unwrap();
    let calib = std::fs::read_to_string(&settings).unwrap();
    let bf_line = calib.lines().find(|l| l.trim_start().starts_with("Camera.bf:")).unwrap();
    let bf: f64 = bf_line.split(':').nth(1).unwrap().trim().parse().unwrap();
    std::fs::write(mm.join("calib.yaml"), calib.replace(bf_line, &format!("Camera.bf: {}", bf * 1000.0))).unwrap();
    let in_mm = track(tmp.path(), &mm, &mm.join("calib.yaml"), "kitti-mm-run");
    let est_mm = read_tum(&in_mm.join("trajectory.tum")).unwrap();
    assert_eq!(est_mm.len(), est.len());
    let worst = est
        .iter()
        .zip(&est_mm)
        .map(|(m, mm)| {
            (m.world_from_camera.translation.vector * 1000.0 - mm.world_from_camera.translation.vector).norm() / 1000.0
        })
        .fold(0.0, f64::max);
    eprintln!("kitti-a in millimetres: at most {worst:.4} m from the run in metres");
    assert!(worst <= 0.0005 * length, "in millimetres the trajectory moves {worst:.3} m from the one in metres");
}

/// A hard case: its name, the `synth` arguments, and the ATE bar (fraction of the path) at 320×240. The paths
/// are short (30–60 mm) and 320×240 tracking has a floor of ~0.05–0.1 mm, so the bars sit at about twice what is
/// measured here; the failure they guard against is an order of magnitude above (the tracker before appearance
/// matching: 5.7 mm = 10 % on the jerk, every frame `Ok`). At 640×480 each case is ≤ 0.1 % (BENCHMARKS.md).
struct Case {
    name: &'static str,
    args: &'static [&'static str],
    ate_of_path: f64,
}

const CASES: &[Case] = &[
    // A third of the way in, three frames at ten times the speed.
    Case { name: "jerk", args: &["--scene", "colon", "--motion", "jerk", "--frames", "60"], ate_of_path: 0.003 },
    // A third of the way in, a second stopped dead, then full speed at once.
    Case { name: "stop", args: &["--scene", "colon", "--motion", "stop", "--frames", "75"], ate_of_path: 0.003 },
    // The colon flight at 7.5 fps: four times the motion per frame.
    Case { name: "low-fps", args: &["--scene", "colon", "--fps", "7.5", "--frames", "30"], ate_of_path: 0.003 },
    // Swinging ±17° at up to 4° a frame over the abdominal wall (55 mm away: at 320×240 the 5 mm baseline holds
    // the pose weakly, the hover there is 0.8 % of its path).
    Case { name: "pan", args: &["--scene", "abdomen", "--trajectory", "pan", "--frames", "60"], ate_of_path: 0.006 },
    // Looking across the wall: a far background at a third of the near wall's disparity.
    Case {
        name: "oblique",
        args: &["--scene", "abdomen", "--trajectory", "oblique", "--frames", "60"],
        ate_of_path: 0.006,
    },
];

/// The rendered cases, once per test binary.
fn rendered() -> &'static (TempDir, Vec<PathBuf>) {
    static SEQUENCES: OnceLock<(TempDir, Vec<PathBuf>)> = OnceLock::new();
    SEQUENCES.get_or_init(|| {
        let tmp = TempDir::new("hard").removed_at_exit();
        let dirs = CASES
            .iter()
            .map(|case| {
                let dir = tmp.path().join(case.name);
                let out = run_with_timeout(
                    Command::new(bdis_slam())
                        .arg("synth")
                        .args(case.args)
                        .args(["--width", "320", "--height", "240", "--focal", "260", "--out"])
                        .arg(&dir),
                    Duration::from_secs(900),
                );
                assert!(out.status.success(), "{}: {}", case.name, text(&out.stderr));
                dir
            })
            .collect();
        (tmp, dirs)
    })
}

fn hard_case(name: &str) {
    let (tmp, dirs) = rendered();
    let index = CASES.iter().position(|c| c.name == name).unwrap();
    let (case, seq) = (&CASES[index], &dirs[index]);
    let run_dir = track(tmp.path(), seq, &seq.join("settings.yaml"), &format!("run-{name}"));
    let gt = read_tum(&seq.join("gt/poses.tum")).unwrap();
    let est = read_tum(&run_dir.join("trajectory.tum")).unwrap();
    assert_eq!(est.len(), gt.len(), "{name}: a pose for every frame");
    let rows = quality_log(&run_dir).lines;
    let not_ok: Vec<String> = rows
        .iter()
        .filter(|r| r.state != ReportedState::Ok)
        .map(|r| format!("{:.3} s {} {}", r.t_source_s, r.state.name(), r.doubt.as_deref().unwrap_or("")))
        .collect();
    let ate = bdis_eval::traj::ate(&gt, &est, 0.01).unwrap().translation.rmse;
    let length = path_length(&gt);
    // Honesty where it can be judged: ten median steps of travel since the keyframe.
    let (checked, worst) = ok_frames_are_right(&gt, &est, &run_dir, 10.0);
    eprintln!(
        "{name}: ATE {ate:.4} mm over {length:.1} mm = {:.3} %; not Ok: {not_ok:?}; {checked} Ok frames far from \
         their keyframe, worst {:.2} % of the travel",
        100.0 * ate / length,
        100.0 * worst
    );
    assert!(
        ate <= case.ate_of_path * length,
        "{name}: ATE {ate:.4} mm is {:.3} % of the path (bar {:.2} %)",
        100.0 * ate / length,
        100.0 * case.ate_of_path
    );
    assert!(rows.iter().all(|r| r.state != ReportedState::Lost), "{name}: lost frames: {not_ok:?}");
}

#[test]
fn a_jerk_at_ten_times_the_speed() {
    hard_case("jerk");
}

#[test]
fn a_dead_stop_and_a_restart_at_full_speed() {
    hard_case("stop");
}

#[test]
fn a_low_frame_rate() {
    hard_case("low-fps");
}

#[test]
fn a_fast_pan() {
    hard_case("pan");
}

#[test]
fn a_far_background() {
    hard_case("oblique");
}
