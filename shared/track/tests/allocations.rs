#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! A warmed-up frame that makes no keyframe allocates nothing (keyframes and new points may: they grow the map).

mod common;

// Per-thread counts: the bundle-adjustment worker allocates its problem on its own thread, off the per-frame path.
#[global_allocator]
static GLOBAL: bdis_testkit::CountingAllocator = bdis_testkit::CountingAllocator;

#[test]
fn a_warmed_up_frame_without_a_keyframe_allocates_nothing() {
    // A short rendered flight (320×240), greyed as acquisition does.
    let frames = common::colon_flight(24);
    let mut tracker = common::colon_tracker();
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

#[test]
fn a_warmed_up_instrument_estimate_allocates_nothing() {
    use bdis_track::instruments::{InstrumentMasker, InstrumentParams};
    let (w, h) = (320, 240);
    // Red tissue with a texture, a grey shaft from the left border whose position changes frame to frame (the
    // silhouette test measures both).
    let frame = |shift: usize| -> Vec<u8> {
        (0..w * h)
            .flat_map(|i| {
                let (x, y) = (i % w, i / w);
                let t = ((x * 7 + y * 13) % 40) as u8;
                if x < w / 2 && (100 + shift..140 + shift).contains(&y) { [120u8, 121, 124] } else { [160 + t, 70, 60] }
            })
            .collect()
    };
    let frames: Vec<Vec<u8>> = (0..6).map(|k| frame(5 * k)).collect();
    let mut masker = InstrumentMasker::new(InstrumentParams::default());
    masker.estimate(&frames[0], w, h);
    for rgb in &frames[1..] {
        let before = bdis_testkit::allocations();
        let found = masker.estimate(rgb, w, h);
        assert_eq!(bdis_testkit::allocations() - before, 0, "{found:?}");
        assert_eq!(found.regions, 1);
        assert!(masker.candidates()[0].edge_contrast.is_finite(), "{:?}", masker.candidates());
    }
}

#[test]
fn a_warmed_up_lost_frame_allocates_nothing() {
    // The flight is tracked, then the scope is 60 mm further on, in tissue the map does not hold: every frame is
    // lost and relocalisation votes, and may try RANSAC, over the keyframes until a segment begins. A scope lost
    // in smoke or put down spends many frames there; they must cost no more than tracked ones.
    const SEEN: usize = 20;
    /// 60 mm on (90 frames of 0.67 mm).
    const AHEAD: usize = 90;
    let mut tracker = common::colon_tracker();
    // Frames relocalisation has before a segment begins (the tracker's own count at 30 fps).
    let restart_after = (bdis_track::RESTART_AFTER_S * 30.0).ceil() as usize;
    let (mut checked, mut worst) = (0, 0);
    for k in 0..SEEN + restart_after - 1 {
        let i = if k < SEEN { k } else { k + AHEAD };
        let (left, right) = common::colon_frame(i);
        let before = bdis_testkit::allocations();
        let result = tracker.track(k as u64 * 33_333_333, &left, &right).unwrap();
        let allocations = bdis_testkit::allocations() - before;
        if k < SEEN {
            assert_eq!(result.state, bdis_track::TrackingState::Ok, "frame {k}");
        } else {
            assert_eq!(result.state, bdis_track::TrackingState::Lost, "frame {k}: new tissue, {:?}", result.quality);
            // Warm-up: the first two lost frames size the relocalisation's buffers.
            if k >= SEEN + 2 {
                checked += 1;
                worst = worst.max(allocations);
            }
            eprintln!("lost frame {k}: {allocations} allocations");
        }
    }
    tracker.finish();
    assert!(checked >= 3, "only {checked} lost frames to check");
    assert_eq!(worst, 0, "a warmed-up lost frame allocated {worst} times");
}
