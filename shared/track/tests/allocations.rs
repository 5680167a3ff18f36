#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! A warmed-up frame that makes no keyframe allocates nothing (keyframes and new points may: they grow the map).

use bdis_track::{RectifiedCamera, Tracker, TrackerSettings};

// Per-thread counts: the bundle-adjustment worker allocates its problem on its own thread, off the per-frame path.
#[global_allocator]
static GLOBAL: bdis_testkit::CountingAllocator = bdis_testkit::CountingAllocator;

#[test]
fn a_warmed_up_frame_without_a_keyframe_allocates_nothing() {
    // A short rendered flight (320×240), greyed as acquisition does.
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
    let frames: Vec<(Vec<u8>, Vec<u8>)> = (0..24)
        .map(|i| {
            let pose = colon.forward_pose(i as f64 / 30.0, 20.0);
            let pair = bdis_synth::render::render(&colon, &rig, &shading, &pose, i);
            (grey(&pair.left), grey(&pair.right))
        })
        .collect();
    let cam = RectifiedCamera { fx: 260.0, fy: 260.0, cx: 159.5, cy: 119.5, bf: 1300.0, width: 320, height: 240 };
    let orb = bdis_orb::OrbParams { n_features: 1000, ini_th_fast: 20, min_th_fast: 7, ..Default::default() };
    let mut tracker = Tracker::new(cam, TrackerSettings { th_depth: 20.0, fps: 30.0, orb }).unwrap();
    let (mut checked, mut worst) = (0, 0);
    for (i, (l, r)) in frames.iter().enumerate() {
        let before = bdis_testkit::allocations();
        let result = tracker.track(i as u64 * 33_333_333, l, r).unwrap();
        let allocations = bdis_testkit::allocations() - before;
        assert_eq!(result.state, bdis_track::TrackingState::Ok, "frame {i}");
        // Warm-up: the first 12 frames; afterwards only frames that made no keyframe count.
        if i >= 12 && result.new_keyframe.is_none() && result.mapper.is_none() {
            checked += 1;
            worst = worst.max(allocations);
            eprintln!("frame {i}: {allocations} allocations");
        }
    }
    tracker.finish();
    assert!(checked >= 3, "only {checked} frames without a keyframe to check");
    assert_eq!(worst, 0, "a warmed-up frame allocated {worst} times");
}
