#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! A wrong motion prior is not followed: the tracker recovers the pose by appearance (matching the reference
//! keyframe with no prior), and a frame is never reported `Ok` with a pose the images do not support.

mod common;

use bdis_track::{PoseMethod, TrackingState};
use nalgebra::{Isometry3, Vector3};

const STEP_NS: u64 = 33_333_333;
/// The flight's step: 20 mm/s at 30 frames a second.
const STEP_MM: f64 = 20.0 / 30.0;

/// The renderer's camera at frame `i` relative to frame 0 (the tracker's world), as `world_from_camera`.
fn truth(i: usize) -> Isometry3<f64> {
    let colon = bdis_synth::colon::Colon::default();
    let at = |k: usize| colon.forward_pose(k as f64 / 30.0, 20.0);
    at(0).inverse() * at(i)
}

fn position_error_mm(camera_from_world: &Isometry3<f64>, i: usize) -> f64 {
    (camera_from_world.inverse().translation.vector - truth(i).translation.vector).norm()
}

#[test]
fn a_wrong_motion_prior_is_rejected_and_the_pose_recovered_by_appearance() {
    let frames = common::colon_flight(30);
    let mut tracker = common::colon_tracker();
    for (i, (l, r)) in frames.iter().enumerate().take(16) {
        let result = tracker.track(i as u64 * STEP_NS, l, r).unwrap();
        assert_eq!(result.state, TrackingState::Ok, "frame {i}");
    }
    // The true step is ~0.7 mm and a fraction of a degree; the prior says 8 mm sideways and 6° of yaw.
    let wrong = Isometry3::new(Vector3::new(8.0, -3.0, 2.0), Vector3::new(0.0, 0.1, 0.02));
    tracker.set_motion_prior(wrong);
    let (l, r) = &frames[16];
    let result = tracker.track(16 * STEP_NS, l, r).unwrap();
    assert_eq!(result.state, TrackingState::Ok, "{:?}", result.quality);
    assert_eq!(result.quality.method, PoseMethod::Appearance, "{:?}", result.quality);
    let error = position_error_mm(&result.camera_from_world.unwrap(), 16);
    assert!(error < 0.1, "recovered {error:.3} mm from the truth");

    // A jump the motion model cannot predict: frames 17–23 skipped (ten times the usual step, as in a jerk),
    // then a prior that is merely stale. Either the pose is right, or the frame does not claim to be.
    // The bar: an `Ok` pose is within 1 % of the distance travelled since the last keyframe, relative to
    // that keyframe (so the keyframe's own error does not count).
    let (kf_t_ns, world_from_kf) = *tracker.keyframe_trajectory().last().unwrap();
    let kf_frame = (kf_t_ns / STEP_NS) as usize;
    let (l, r) = &frames[24];
    let result = tracker.track(17 * STEP_NS, l, r).unwrap();
    let kf_from_camera = world_from_kf.inverse() * result.camera_from_world.unwrap().inverse();
    let true_kf_from_camera = truth(kf_frame).inverse() * truth(24);
    let travelled = true_kf_from_camera.translation.vector.norm();
    let error = (kf_from_camera.translation.vector - true_kf_from_camera.translation.vector).norm();
    eprintln!(
        "after the jump: {:?}, {error:.3} mm off over {travelled:.2} mm since keyframe at frame {kf_frame}, {:?}",
        result.state, result.quality
    );
    if result.state == TrackingState::Ok {
        assert!(error < 0.01 * travelled, "Ok with a pose {error:.3} mm off over {travelled:.2} mm");
    }
    // Tracking goes on from there, each frame within a third of a frame's travel of the truth (a tracker that
    // lost the thread, or followed the stale prior, is off by a step or more; this 320×240 flight's ATE is
    // 0.14–0.16 mm).
    for (k, (l, r)) in frames.iter().enumerate().skip(25) {
        let result = tracker.track((k as u64 - 7) * STEP_NS, l, r).unwrap();
        assert_eq!(result.state, TrackingState::Ok, "frame {k}");
        let step = (truth(k).translation.vector - truth(k - 1).translation.vector).norm();
        let error = position_error_mm(&result.camera_from_world.unwrap(), k);
        assert!(error < step / 3.0, "frame {k}: {error:.3} mm off (a step is {step:.3} mm)");
    }
    tracker.finish();
}

#[test]
fn a_right_pose_is_not_doubted() {
    // Clean footage: every frame Ok, the motion model's pose agreeing with appearance (no prior rejected).
    let frames = common::colon_flight(20);
    let mut tracker = common::colon_tracker();
    for (i, (l, r)) in frames.iter().enumerate() {
        let result = tracker.track(i as u64 * STEP_NS, l, r).unwrap();
        assert_eq!(result.state, TrackingState::Ok, "frame {i}: {:?}", result.quality);
        assert!(!result.quality.prior_rejected, "frame {i}: {:?}", result.quality);
        if i >= 2 {
            let q = &result.quality;
            assert!(q.appearance_agreement >= 0.8, "frame {i}: {q:?}");
            assert!(q.reprojection_rms_px < 2.0 && q.position_sigma_rel < 1e-3, "frame {i}: {q:?}");
        }
    }
    tracker.finish();
}

/// The renderer's jerk (`synth --motion jerk`): a third of the way in, the scope moves at four, then ten, ten and
/// seven times its speed for a frame each. The frame after the first tenfold step is posed by appearance alone
/// from few points (much of the near wall has left the view); on renders of this jerk such poses were off by
/// 0.25–1.8 mm, a tenth of the step, and reported `Ok`. A pose found without a prior is either right relative to
/// its keyframe (1 % of the travel since it) or does not claim to be; tracking is never lost, and the frames
/// after the jerk are `Ok` again.
#[test]
fn a_jerk_s_priorless_poses_are_right_or_do_not_claim_to_be() {
    // Frame indices of the flight at 30 fps: steps of 1, then 4, 10, 10, 7 frames, then 1 again.
    let mut shown: Vec<usize> = (0..20).collect();
    for step in [4, 10, 10, 7] {
        shown.push(shown[shown.len() - 1] + step);
    }
    let resumed = shown.len();
    let last = shown[resumed - 1];
    shown.extend(last + 1..last + 8);
    let mut tracker = common::colon_tracker();
    let (mut claimed_wrong, mut doubted) = (Vec::new(), Vec::new());
    for (k, &i) in shown.iter().enumerate() {
        // The keyframe the frame is tracked from: the newest one before it.
        let (kf_t_ns, world_from_kf) = tracker.keyframe_trajectory().last().copied().unwrap_or_default();
        let (l, r) = common::colon_frame(i);
        let result = tracker.track(k as u64 * STEP_NS, &l, &r).unwrap();
        assert_ne!(result.state, TrackingState::Lost, "frame {k} (flight frame {i})");
        if k > resumed {
            assert_eq!(result.state, TrackingState::Ok, "after the jerk, frame {k}: {:?}", result.quality);
        }
        if result.quality.method != PoseMethod::Appearance || k == 0 {
            continue;
        }
        let kf_flight_frame = shown[(kf_t_ns / STEP_NS) as usize];
        let kf_from_camera = world_from_kf.inverse() * result.camera_from_world.unwrap().inverse();
        let true_kf_from_camera = truth(kf_flight_frame).inverse() * truth(i);
        let travelled = true_kf_from_camera.translation.vector.norm();
        let error = (kf_from_camera.translation.vector - true_kf_from_camera.translation.vector).norm();
        let line = format!(
            "frame {k} (flight {i}): {:?} {:?}, {} inliers, {error:.3} mm off over {travelled:.2} mm since flight \
             frame {kf_flight_frame}",
            result.state, result.quality.doubt, result.inliers
        );
        eprintln!("{line}");
        // Judged from four steps of travel on: below that, 1 % of it is under this size's floor (clear frames
        // of this flight are 0.01–0.04 mm off their keyframe).
        if result.state == TrackingState::Ok && travelled > 4.0 * STEP_MM && error > 0.01 * travelled {
            claimed_wrong.push(line);
        } else if result.state == TrackingState::Uncertain {
            doubted.push(line);
        }
    }
    tracker.finish();
    assert!(claimed_wrong.is_empty(), "Ok and wrong: {claimed_wrong:?}");
    // The jerk is a real test of the doubt: some priorless pose in it needed it.
    assert!(!doubted.is_empty(), "no frame of the jerk was doubted");
}

/// A view that changes wholesale between two frames (frames dropped, a cut in a recording): the flight jumps
/// 40 mm on, into tissue the map does not hold, with nothing between. The motion model's search, centred on
/// its prediction, found 45 chance inliers there (the frame before had 215), and the frame was `Ok` 41 mm off,
/// then made a keyframe at that pose, and every frame after it rested on that keyframe's points: `Ok` and
/// 41 mm off to the end. Now a motion-model pose that appearance cannot confirm and that kept under half the
/// last frame's support is no pose: the frame is lost, relocalisation looks for the place, and a detached
/// segment begins where it finds none. No frame after the cut may claim to be where it is not.
#[test]
fn a_view_that_changes_wholesale_is_never_claimed_ok_where_it_is_not() {
    const SEEN: usize = 20;
    /// 60 frames at 0.67 mm: 40 mm on, the cut the motion model fell for.
    const SKIPPED: usize = 60;
    let mut tracker = common::colon_tracker();
    let mut after = Vec::new();
    for k in 0..SEEN + 20 {
        let i = if k < SEEN { k } else { k + SKIPPED };
        let (left, right) = common::colon_frame(i);
        let result = tracker.track(k as u64 * STEP_NS, &left, &right).unwrap();
        if k < SEEN {
            assert_eq!(result.state, TrackingState::Ok, "frame {k}");
            continue;
        }
        if result.state == TrackingState::Ok {
            let pose = result.camera_from_world.unwrap();
            // Whatever the tracker's frame now is, Ok must be right: within a tenth of the jump of the truth.
            let error = position_error_mm(&pose, i);
            assert!(error < 0.1 * SKIPPED as f64 * STEP_MM, "frame {k} (flight frame {i}) Ok {error:.1} mm off");
        }
        after.push((k, result.state, result.quality.doubt, result.new_keyframe.is_some()));
    }
    tracker.finish();
    eprintln!("{after:?}");
    // The first frame after the cut is lost for it, and makes no keyframe.
    let (_, state, doubt, keyframe) = after[0];
    assert_eq!((state, doubt), (TrackingState::Lost, Some(bdis_track::Doubt::Unconfirmed)), "{:?}", after[0]);
    assert!(!keyframe, "a keyframe at the cut: {:?}", after[0]);
}

/// The frames after a relocalisation. An oblique view over the abdominal wall (seed 2026, as `bdis-slam synth
/// --scene abdomen --trajectory oblique --seed 2026` renders it) is cut by 15 frames (10 mm), and the frame
/// where the cut falls carries nothing of the scene (sensor noise: a signal drop-out), so the tracker is lost
/// there and relocalises after it. The frame after a relocalisation has no velocity to predict with and is
/// posed by appearance on few matches, `Uncertain`; the frame after that one is predicted by the motion
/// model from that doubted pose. Before `unconfirmed-prior` such a frame was `Ok` 1.2 mm off where appearance
/// found nothing to check it against: the motion model carried the doubted pose on, by a velocity that ended
/// on it. Now a motion-model pose predicted from a doubted one is `Ok` only if appearance confirms it.
///
/// The loss used to come from the cut alone; once keyframes followed the map's information
/// (`keyframe_needed`'s halved-information rule) the tracker held a 15-frame cut, so the drop-out makes the
/// loss whatever the keyframe density. Cuts of 12–19 frames, with and without the drop-out, are in
/// BENCHMARKS.md ("The frames after a cut"): most put some `Ok` frame over 0.5 mm off, with or without that
/// rule — this test pins the relocalisation case, not every cut.
#[test]
fn a_pose_predicted_from_a_doubted_one_is_not_claimed_ok_unconfirmed() {
    const SEEN: usize = 30;
    const CUT: usize = 15;
    const SPEED_MM_S: f64 = 20.0;
    let abdomen = bdis_synth::abdomen::Abdomen {
        seed: 2026,
        texture: bdis_synth::TissueTexture { seed: 2026 },
        ..Default::default()
    };
    let truth = |i: usize| abdomen.oblique_pose(i as f64 / 30.0, SPEED_MM_S);
    let world_from_truth = truth(0).inverse();
    let mut tracker = common::colon_tracker();
    // (flight frame, state, doubt, position error, method, appearance consensus) after the cut.
    let mut after = Vec::new();
    for (k, i) in (0..SEEN).chain(SEEN + CUT..SEEN + CUT + 20).enumerate() {
        let (mut left, mut right) = common::abdomen_pair(&abdomen, &truth(i), i as u64);
        if k == SEEN {
            // The drop-out: uniform noise from a fixed xorshift, different in each eye.
            let mut x = 0x9e37_79b9_7f4a_7c15_u64;
            for (l, r) in left.iter_mut().zip(right.iter_mut()) {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                (*l, *r) = (x as u8, (x >> 8) as u8);
            }
        }
        let result = tracker.track(k as u64 * STEP_NS, &left, &right).unwrap();
        let error = result
            .camera_from_world
            .map(|p| (p.inverse().translation.vector - (world_from_truth * truth(i)).translation.vector).norm());
        if k >= SEEN {
            let q = result.quality;
            after.push((i, result.state, q.doubt, error, q.method, q.appearance_consensus));
        }
    }
    tracker.finish();
    eprintln!("{after:?}");
    assert_eq!(after[0].1, TrackingState::Lost, "the drop-out is not lost: {:?}", after[0]);
    assert!(
        after.iter().any(|a| a.4 == PoseMethod::Relocalisation && a.1 == TrackingState::Ok),
        "no frame relocalised after the drop-out: {after:?}"
    );
    // The case: a motion-model pose predicted from a pose doubted for its own estimate.
    let mut predicted_from_doubted = 0;
    for pair in after.windows(2) {
        let (before, now) = (pair[0], pair[1]);
        if now.4 == PoseMethod::MotionModel && before.2.is_some_and(bdis_track::Doubt::carries_over) {
            predicted_from_doubted += 1;
            assert!(
                now.1 != TrackingState::Ok || now.5 > 0,
                "frame {}: Ok, predicted from a doubted pose and unconfirmed by appearance: {now:?}",
                now.0
            );
        }
    }
    assert!(predicted_from_doubted > 0, "no pose was predicted from a doubted one here: the case is gone ({after:?})");
    for &(i, state, doubt, error, ..) in &after {
        if state == TrackingState::Ok {
            let error = error.unwrap_or(f64::INFINITY);
            assert!(error < 0.5, "frame {i}: Ok {error:.2} mm off ({doubt:?})");
        }
    }
    // Tracking holds on: the last frames are `Ok`.
    assert!(after[after.len() - 5..].iter().all(|a| a.1 == TrackingState::Ok), "{after:?}");
}
