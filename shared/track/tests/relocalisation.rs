#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Relocalisation on its own: after the view is lost (a black frame), a view of tissue the map has seen puts the
//! tracker back on a pose that agrees with the one it tracked there before, without a motion prior.

mod common;

use bdis_track::TrackingState;

#[test]
fn a_lost_tracker_relocalises_on_a_view_it_has_mapped() {
    let frames = common::colon_flight(16);
    let mut tracker = common::colon_tracker();
    let mut poses = Vec::new();
    for (i, (l, r)) in frames.iter().enumerate() {
        let result = tracker.track(i as u64 * 33_333_333, l, r).unwrap();
        assert_eq!(result.state, TrackingState::Ok, "frame {i}");
        poses.push(result.camera_from_world.unwrap());
    }
    // Nothing to see: lost.
    let black = vec![0u8; 320 * 240];
    let t = 16 * 33_333_333;
    assert_eq!(tracker.track(t, &black, &black).unwrap().state, TrackingState::Lost);
    // The view of frame 8 again (the scope pulled back half a second's travel): no motion model can predict it.
    let (l, r) = &frames[8];
    let result = tracker.track(t + 33_333_333, l, r).unwrap();
    assert!(result.relocalised, "relocalised on a mapped view");
    assert_eq!(result.state, TrackingState::Ok);
    let pose = result.camera_from_world.unwrap();
    // Local bundle adjustment may have moved the map a little since frame 8 was tracked.
    let moved = (pose.inverse().translation.vector - poses[8].inverse().translation.vector).norm();
    assert!(moved < 0.5, "relocalised {moved} mm from where frame 8 was tracked");
    assert!(pose.rotation.angle_to(&poses[8].rotation) < 0.01);
    tracker.finish();
}

/// A scope taken out (to clean the lens) and put back where the flight began, 40 mm behind where it was lost:
/// no keyframe near the last pose shows that tissue, so relocalisation must look further, over the whole map.
/// The tracker finds the first keyframes' place before it would give up and begin a new map segment (as it does
/// in tissue the map does not hold), and the frames there are `Ok` where they were tracked the first time.
#[test]
fn a_scope_put_back_where_the_flight_began_is_found_on_the_map() {
    const STEP_NS: u64 = 33_333_333;
    let mut tracker = common::colon_tracker();
    let mut poses = Vec::new();
    for i in 0..60 {
        let (l, r) = common::colon_frame(i);
        let result = tracker.track(i as u64 * STEP_NS, &l, &r).unwrap();
        assert_eq!(result.state, TrackingState::Ok, "frame {i}");
        poses.push(result.camera_from_world.unwrap());
    }
    let keyframes = tracker.keyframe_trajectory().len();
    let black = vec![0u8; 320 * 240];
    let mut t = 60 * STEP_NS;
    for _ in 0..10 {
        assert_eq!(tracker.track(t, &black, &black).unwrap().state, TrackingState::Lost);
        t += STEP_NS;
    }
    // Back at frames 3, 4, …: each lost frame scans a few more keyframes, so it may take some frames.
    let mut placed = None;
    for (i, first_pass) in poses.iter().enumerate().take(20).skip(3) {
        let (l, r) = common::colon_frame(i);
        let result = tracker.track(t, &l, &r).unwrap();
        t += STEP_NS;
        assert!(!result.new_segment, "frame {i}: a new segment begun on tissue the map holds");
        if result.state == TrackingState::Ok {
            let pose = result.camera_from_world.unwrap();
            let moved = (pose.inverse().translation.vector - first_pass.inverse().translation.vector).norm();
            eprintln!("found on frame {i} ({keyframes} keyframes), {moved:.3} mm from its first pass");
            assert!(moved < 0.5, "frame {i}: {moved:.3} mm from where it was tracked the first time");
            placed.get_or_insert(i);
        }
    }
    let placed = placed.unwrap_or_else(|| panic!("never relocalised on the first frames' place"));
    assert!(placed < 3 + 9, "relocalised only on frame {placed}");
    tracker.finish();
}
