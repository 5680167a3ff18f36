#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Detection from a coarser pyramid level (`ORBextractor.firstLevel`, what HD footage gets automatically): the
//! tracker holds the same flight with every frame `Ok` and an error of
//! the same order as detection from level 0 — the octaves' σ and the searches' predicted levels follow the
//! detection levels.

mod common;

use bdis_track::{RectifiedCamera, Tracker, TrackerSettings, TrackingState};
use nalgebra::Isometry3;

const STEP_NS: u64 = 33_333_333;
const FRAMES: usize = 24;

fn truth(i: usize) -> Isometry3<f64> {
    let colon = bdis_synth::colon::Colon::default();
    let at = |k: usize| colon.forward_pose(k as f64 / 30.0, 20.0);
    at(0).inverse() * at(i)
}

/// RMS position error (mm) over the flight, and the path's length.
fn track(frames: &[(Vec<u8>, Vec<u8>)], orb: bdis_orb::OrbParams, first: usize) -> (f64, f64) {
    let cam = RectifiedCamera { fx: 520.0, fy: 520.0, cx: 319.5, cy: 239.5, bf: 2600.0, width: 640, height: 480 };
    let mut tracker = Tracker::new(cam, TrackerSettings { th_depth: 20.0, fps: 30.0, orb }).unwrap();
    let (mut sum2, mut path) = (0.0, 0.0);
    for (i, (l, r)) in frames.iter().enumerate() {
        let result = tracker.track(i as u64 * STEP_NS, l, r).unwrap();
        assert_eq!(result.state, TrackingState::Ok, "first level {first}, frame {i}: {:?}", result.quality);
        let pose = result.camera_from_world.expect("an Ok frame has a pose");
        let error = (pose.inverse().translation.vector - truth(i).translation.vector).norm();
        sum2 += error * error;
        if i > 0 {
            path += (truth(i).translation.vector - truth(i - 1).translation.vector).norm();
        }
    }
    tracker.finish();
    ((sum2 / frames.len() as f64).sqrt(), path)
}

#[test]
fn detection_from_level_2_tracks_the_flight_as_level_0_does() {
    // 640×480 (f = 520, 5 mm baseline): at 320×240 the third level (222×167) is too small to give the 500
    // features initialisation waits for; 1080p's fifth level is 926×521.
    let rig = RectifiedCamera { width: 640, height: 480, fx: 520.0, fy: 520.0, cx: 320.0, cy: 240.0, bf: 2600.0 };
    let colon = bdis_synth::colon::Colon::default();
    let shading = bdis_synth::render::Shading::default();
    let frames: Vec<_> = (0..FRAMES)
        .map(|i| {
            let pair = bdis_synth::render::render(
                &colon,
                &rig,
                &shading,
                &colon.forward_pose(i as f64 / 30.0, 20.0),
                i as u64,
            );
            (common::grey(&pair.left), common::grey(&pair.right))
        })
        .collect();
    let base = bdis_orb::OrbParams { n_features: 1000, ini_th_fast: 20, min_th_fast: 7, ..Default::default() };
    let (level0, path) = track(&frames, bdis_orb::OrbParams { first_level: Some(0), ..base }, 0);
    // The same 8-level pyramid, searched from its third level (444×333).
    let (level2, _) = track(&frames, bdis_orb::OrbParams { n_levels: 6, first_level: Some(2), ..base }, 2);
    eprintln!("RMS position error over {path:.1} mm: level 0 {level0:.4} mm, level 2 {level2:.4} mm");
    assert!(level2 <= 0.001 * path, "level 2: {level2} mm over {path} mm");
    assert!(level2 <= 4.0 * level0.max(0.001), "level 2 {level2} mm against level 0 {level0} mm");
}
