#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Relocalisation on its own: after the view is lost (a black frame), a view of tissue the map has seen puts the
//! tracker back on a pose that agrees with the one it tracked there before, without a motion prior.

use bdis_track::{RectifiedCamera, Tracker, TrackerSettings, TrackingState};

#[test]
fn a_lost_tracker_relocalises_on_a_view_it_has_mapped() {
    let rig = bdis_synth::RectifiedCamera {
        width: 320,
        height: 240,
        fx: 260.0,
        fy: 260.0,
        cx: 160.0,
        cy: 120.0,
        bf: 260.0 * 5.0,
    };
    let colon = bdis_synth::colon::Colon::default();
    let shading = bdis_synth::render::Shading::default();
    let grey = |img: &image::RgbImage| -> Vec<u8> {
        img.pixels()
            .map(|p| ((u32::from(p[0]) * 4899 + u32::from(p[1]) * 9617 + u32::from(p[2]) * 1868 + 8192) >> 14) as u8)
            .collect()
    };
    let frames: Vec<(Vec<u8>, Vec<u8>)> = (0..16)
        .map(|i| {
            let pose = colon.forward_pose(i as f64 / 30.0, 20.0);
            let pair = bdis_synth::render::render(&colon, &rig, &shading, &pose, i);
            (grey(&pair.left), grey(&pair.right))
        })
        .collect();
    let cam = RectifiedCamera { fx: 260.0, fy: 260.0, cx: 159.5, cy: 119.5, bf: 1300.0, width: 320, height: 240 };
    let orb = bdis_orb::OrbParams { n_features: 1000, ini_th_fast: 20, min_th_fast: 7, ..Default::default() };
    let mut tracker = Tracker::new(cam, TrackerSettings { th_depth: 20.0, fps: 30.0, orb }).unwrap();
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
