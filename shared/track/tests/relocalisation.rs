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
