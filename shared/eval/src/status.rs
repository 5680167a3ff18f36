//! Whether the tracker's `Ok` meant what it says: issue #22's honesty bar. A frame reported `Ok` must have its
//! position relative to the last keyframe within a share (1 %) of the distance travelled since that keyframe —
//! a wrong pose must be `Uncertain` or `Lost`, never `Ok`. Judged from the run's own files: the written
//! trajectory, the frame states and keyframes of `tracking-quality.csv`, and where given each keyframe's own
//! pose (`keyframes.tum`).
//!
//! Only frames that have travelled some distance since their keyframe are judged (by default four median steps
//! of the ground truth): just after a keyframe the travel is a fraction of a step, and 1 % of it is under any
//! tracker's measurement noise. Every figure is a ratio or is relative to the ground truth's own steps: no unit,
//! no image size.

use bdis_core::formats::quality::{QualityLog, ReportedState};
use bdis_core::geometry::{StampedPose, pose_nearest_in_time};
use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

/// The bar and where it is judged.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StatusBar {
    /// An `Ok` frame's position error relative to its keyframe may be at most this share of the travel since
    /// the keyframe (issue #22: 0.01).
    pub max_error_of_travel: f64,
    /// Frames are judged from this many median ground-truth steps of travel since their keyframe.
    pub min_steps: f64,
}

impl Default for StatusBar {
    fn default() -> Self {
        Self { max_error_of_travel: 0.01, min_steps: 4.0 }
    }
}

/// An `Ok` frame over the bar.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WrongOk {
    pub t_s: f64,
    /// Its keyframe's time, seconds.
    pub keyframe_t_s: f64,
    /// The true distance travelled since the keyframe, in the ground truth's unit.
    pub travelled: f64,
    /// Its position error relative to the keyframe, over `travelled`.
    pub error_of_travel: f64,
}

/// How honest a run's `Ok` was.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StatusHonesty {
    pub bar: StatusBar,
    /// The travel from which a frame is judged, in the ground truth's unit (`bar.min_steps` median steps).
    pub min_travel: f64,
    /// Frames reported `Ok`.
    pub ok_frames: usize,
    /// Of them, those judged: far enough from a keyframe, with a pose for the frame and its keyframe in both
    /// trajectories.
    pub judged: usize,
    /// The largest error over travel among the judged frames (0 when none was judged).
    pub worst_error_of_travel: f64,
    /// The judged frames over the bar, in time order.
    pub wrong_ok: Vec<WrongOk>,
    /// Every judged frame, in time order (for a plot: `eval traj --plot`).
    pub judged_frames: Vec<JudgedFrame>,
}

/// A judged `Ok` frame: its time, seconds, and its position error relative to its keyframe over the travel since.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct JudgedFrame {
    pub t_s: f64,
    pub error_of_travel: f64,
}

#[derive(Debug, thiserror::Error)]
pub enum StatusError {
    #[error("the ground truth has fewer than two poses: no step to measure travel by")]
    NoSteps,
    #[error(
        "the quality log has no `keyframe` column (written before keyframes were logged): no keyframe to judge from"
    )]
    KeyframesNotLogged,
}

/// The pose of `poses` nearest to `t_s`, if one is within `max_dt_s`.
fn pose_near(poses: &[StampedPose], t_s: f64, max_dt_s: f64) -> Option<Isometry3<f64>> {
    pose_nearest_in_time(poses, t_s, max_dt_s).map(|p| p.world_from_camera)
}

/// Judges each `Ok` frame of the run's quality log (`bdis_core::formats::quality`, in time order) against the
/// last keyframe before it: its position relative to that keyframe, from `est` and from `gt` (poses matched by
/// time within `max_dt_s`). The keyframe's estimated pose is taken from `keyframes` where it is there (the run's
/// `keyframes.tum`: the keyframe's own pose, which the frames after it were tracked against), else from `est` at
/// its time (where the written trajectory may have bridged it, if it was made under a veil).
pub fn judge_ok_frames(
    gt: &[StampedPose],
    est: &[StampedPose],
    keyframes: &[StampedPose],
    log: &QualityLog,
    max_dt_s: f64,
    bar: StatusBar,
) -> Result<StatusHonesty, StatusError> {
    if !log.logs_keyframes {
        return Err(StatusError::KeyframesNotLogged);
    }
    let frames = &log.lines;
    let mut steps: Vec<f64> = gt
        .windows(2)
        .map(|w| (w[1].world_from_camera.translation.vector - w[0].world_from_camera.translation.vector).norm())
        .collect();
    if steps.is_empty() {
        return Err(StatusError::NoSteps);
    }
    let mid = steps.len() / 2;
    let min_travel = bar.min_steps * *steps.select_nth_unstable_by(mid, f64::total_cmp).1;
    let mut honesty = StatusHonesty {
        bar,
        min_travel,
        ok_frames: frames.iter().filter(|f| f.state == ReportedState::Ok).count(),
        judged: 0,
        worst_error_of_travel: 0.0,
        wrong_ok: Vec::new(),
        judged_frames: Vec::new(),
    };
    let mut keyframe_t_s = None;
    for frame in frames {
        if frame.keyframe.is_some() {
            keyframe_t_s = Some(frame.t_source_s);
            continue;
        }
        let Some(k) = keyframe_t_s.filter(|_| frame.state == ReportedState::Ok) else { continue };
        let relative = |keyframe: Option<Isometry3<f64>>, poses: &[StampedPose]| {
            let (a, b) = (keyframe?, pose_near(poses, frame.t_source_s, max_dt_s)?);
            Some((a.inverse() * b).translation.vector)
        };
        let estimated_keyframe = pose_near(keyframes, k, max_dt_s).or_else(|| pose_near(est, k, max_dt_s));
        let (Some(truth), Some(estimate)) =
            (relative(pose_near(gt, k, max_dt_s), gt), relative(estimated_keyframe, est))
        else {
            continue;
        };
        let travelled = truth.norm();
        if travelled < min_travel {
            continue;
        }
        let error_of_travel = (estimate - truth).norm() / travelled;
        honesty.judged += 1;
        honesty.judged_frames.push(JudgedFrame { t_s: frame.t_source_s, error_of_travel });
        honesty.worst_error_of_travel = honesty.worst_error_of_travel.max(error_of_travel);
        if error_of_travel > bar.max_error_of_travel {
            honesty.wrong_ok.push(WrongOk { t_s: frame.t_source_s, keyframe_t_s: k, travelled, error_of_travel });
        }
    }
    Ok(honesty)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bdis_core::formats::quality::QualityLine;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    /// A straight path at 1 unit a frame, 30 frames a second.
    fn straight(n: usize) -> Vec<StampedPose> {
        (0..n)
            .map(|i| StampedPose {
                t_s: i as f64 / 30.0,
                world_from_camera: Isometry3::from_parts(
                    Translation3::new(i as f64, 0.0, 0.0),
                    UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.01 * i as f64),
                ),
            })
            .collect()
    }

    fn frames(n: usize, keyframes: &[usize], ok: impl Fn(usize) -> bool) -> QualityLog {
        let lines = (0..n)
            .map(|i| QualityLine {
                frame_seq: i as u64,
                t_source_s: i as f64 / 30.0,
                state: if ok(i) { ReportedState::Ok } else { ReportedState::Uncertain },
                doubt: None,
                keyframe: keyframes.iter().position(|&k| k == i).map(|k| k as u64),
            })
            .collect();
        QualityLog { lines, logs_keyframes: true }
    }

    #[test]
    fn a_wrong_ok_frame_is_found_and_a_wrong_uncertain_one_is_not() {
        let gt = straight(30);
        let mut est = gt.clone();
        // Frame 12 is 0.2 off sideways: 2.5 % of the 8 travelled since keyframe 4. Frame 20 is as far off but
        // reported Uncertain; frame 6 is off too, but only 2 from its keyframe (under four median steps).
        for (i, off) in [(12, 0.2), (20, 0.3), (6, 0.5)] {
            est[i].world_from_camera.translation.vector.z += off;
        }
        let reported = frames(30, &[0, 4, 16], |i| i != 20);
        let honesty = judge_ok_frames(&gt, &est, &[], &reported, 0.01, StatusBar::default()).unwrap();
        assert!((honesty.min_travel - 4.0).abs() < 1e-9, "{honesty:?}");
        assert_eq!(honesty.ok_frames, 29);
        assert_eq!(honesty.wrong_ok.len(), 1, "{honesty:?}");
        let wrong = honesty.wrong_ok[0];
        assert!((wrong.t_s - 12.0 / 30.0).abs() < 1e-9 && (wrong.keyframe_t_s - 4.0 / 30.0).abs() < 1e-9);
        assert!((wrong.error_of_travel - 0.025).abs() < 1e-9, "{wrong:?}");
        // Judged: frames 8–15 after keyframe 4 (4 to 11 travelled), 21–29 after keyframe 16 (the Uncertain 20
        // is not), none after keyframe 0 (frames 1–3 are under the bar's travel).
        assert_eq!(honesty.judged, 8 + 9, "{honesty:?}");
        assert_eq!(honesty.judged_frames.len(), honesty.judged);
        assert!(honesty.judged_frames.iter().any(|j| j.t_s == wrong.t_s && j.error_of_travel == wrong.error_of_travel));
    }

    /// A keyframe whose written pose was bridged (made under a veil): judged against its own pose, the frames
    /// after it are right; against the written one, they would all be off.
    #[test]
    fn the_keyframe_s_own_pose_is_used_where_it_is_given() {
        let gt = straight(30);
        let mut est = gt.clone();
        est[10].world_from_camera.translation.vector.z += 0.5;
        let reported = frames(30, &[0, 10], |_| true);
        let written = judge_ok_frames(&gt, &est, &[], &reported, 0.01, StatusBar::default()).unwrap();
        // Frames 14–29 after keyframe 10 (frame 14 at the bar's travel of four steps, counted or not by rounding).
        assert!(written.wrong_ok.len() >= 15, "{written:?}");
        assert!(written.wrong_ok.iter().all(|w| (w.keyframe_t_s - 10.0 / 30.0).abs() < 1e-9), "{written:?}");
        let keyframes = [gt[0], gt[10]];
        let own = judge_ok_frames(&gt, &est, &keyframes, &reported, 0.01, StatusBar::default()).unwrap();
        assert!(own.wrong_ok.is_empty() && own.judged == written.judged, "{own:?}");
    }

    #[test]
    fn a_right_trajectory_in_another_unit_passes_alike() {
        // The same path in metres and in millimetres, every pose 0.2 % of a step off: within the bar either way.
        for unit in [1.0, 1000.0] {
            let gt: Vec<StampedPose> = straight(40)
                .into_iter()
                .map(|mut p| {
                    p.world_from_camera.translation.vector *= unit;
                    p
                })
                .collect();
            let mut est = gt.clone();
            for (i, p) in est.iter_mut().enumerate() {
                p.world_from_camera.translation.vector.y += 0.002 * unit * if i % 2 == 0 { 1.0 } else { -1.0 };
            }
            let honesty =
                judge_ok_frames(&gt, &est, &[], &frames(40, &[0, 10, 25], |_| true), 0.01, StatusBar::default())
                    .unwrap();
            assert!(honesty.wrong_ok.is_empty(), "unit {unit}: {honesty:?}");
            assert!(honesty.judged > 20 && honesty.worst_error_of_travel < 0.01, "unit {unit}: {honesty:?}");
        }
    }

    #[test]
    fn a_log_without_keyframes_is_refused_not_judged_as_all_clear() {
        let mut log = frames(10, &[0], |_| true);
        log.logs_keyframes = false;
        let refused = judge_ok_frames(&straight(10), &straight(10), &[], &log, 0.01, StatusBar::default());
        assert!(matches!(refused, Err(StatusError::KeyframesNotLogged)), "{refused:?}");
    }
}
