#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Map reuse: a hover that circles over the abdominal wall and comes back to where it started, out of sight of
//! the start for most of the lap, finds the first keyframes' points again instead of building new ones beside
//! them.

mod common;

use bdis_track::TrackingState;

/// Frames of one lap of the renderer's `circle` path (radius 40 mm) at 40 mm/s and 30 fps: 2π·40/40·30.
const LAP_FRAMES: usize = 189;

#[test]
fn coming_back_round_a_circle_observes_the_first_points_again() {
    let rig = bdis_track::RectifiedCamera {
        width: 320,
        height: 240,
        fx: 260.0,
        fy: 260.0,
        cx: 160.0,
        cy: 120.0,
        bf: 260.0 * 5.0,
    };
    let abdomen = bdis_synth::abdomen::Abdomen::default();
    // A laparoscope's light and stand-off, as `bdis-slam synth --scene abdomen` renders it.
    let shading = bdis_synth::render::Shading { exposure_distance_mm: 65.0, ..Default::default() };
    let mut tracker = common::colon_tracker();
    let frames = LAP_FRAMES + 30;
    for i in 0..frames {
        let pose = abdomen.circle_pose(i as f64 / 30.0, 40.0);
        let pair = bdis_synth::render::render(&abdomen, &rig, &shading, &pose, i as u64);
        let (left, right) = (common::grey(&pair.left), common::grey(&pair.right));
        let result = tracker.track(i as u64 * 33_333_333, &left, &right).unwrap();
        assert!(result.state.is_tracked() || i == 0, "frame {i}: {:?}", result.state);
    }
    assert!(matches!(tracker.state(), TrackingState::Ok), "{:?}", tracker.state());
    tracker.finish();
    let map = tracker.map();
    // Points made in the first 10 frames (out of view from frame ~40 to the end of the lap), and how many of
    // them keyframes made after the lap observe.
    let early: Vec<_> = map.points.iter().filter(|p| !p.bad && map.keyframes[p.first_kf].frame_id < 10).collect();
    let found_again = early
        .iter()
        .filter(|p| p.observations.keys().any(|&k| map.keyframes[k].frame_id as usize >= LAP_FRAMES))
        .count();
    eprintln!("{} points from the first 10 frames, {found_again} observed again after the lap", early.len());
    assert!(found_again * 5 >= early.len(), "{found_again} of {} found again", early.len());
}
