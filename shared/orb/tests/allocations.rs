#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! A warmed-up extraction, stereo match, grid and rotation filter allocate nothing.

use bdis_orb::{
    FeatureGrid, Features, OrbExtractor, OrbParams, RotationBins, RotationHistogram, StereoFeatures, StereoMatcher,
};

#[global_allocator]
static GLOBAL: bdis_testkit::CountingAllocator = bdis_testkit::CountingAllocator;

#[test]
fn a_warmed_up_stereo_frame_allocates_nothing() {
    let (w, h) = (640usize, 480usize);
    // Smooth texture with corners: sums of sines, never black.
    let tex = |x: f32, y: f32| {
        (128.0 + 60.0 * (x * 0.11).sin() * (y * 0.09).cos() + 50.0 * ((x - y) * 0.05).sin().signum()) as u8
    };
    let left: Vec<u8> = (0..w * h).map(|i| tex((i % w) as f32, (i / w) as f32).max(1)).collect();
    let right: Vec<u8> = (0..w * h).map(|i| tex((i % w) as f32 + 7.0, (i / w) as f32).max(1)).collect();
    let params = OrbParams { n_features: 1000, ..OrbParams::default() };
    let (mut el, mut er) = (OrbExtractor::new(params, w, h).unwrap(), OrbExtractor::new(params, w, h).unwrap());
    let scales = el.scales().to_vec();
    let mut m = StereoMatcher::new();
    let (mut fl, mut fr, mut st) = (Features::default(), Features::default(), StereoFeatures::default());
    let (mut grid, mut histogram) =
        (FeatureGrid::new(w as f32, h as f32), RotationHistogram::new(RotationBins::FAITHFUL));
    let (mut found, mut rejected) = (Vec::with_capacity(4096), Vec::with_capacity(4096));
    let mut frame = |el: &mut OrbExtractor, er: &mut OrbExtractor| {
        el.extract(&left, &mut fl).unwrap();
        er.extract(&right, &mut fr).unwrap();
        m.match_features(&fl, &fr, &el.levels, &er.levels, &scales, 500.0, 2500.0, &mut st);
        // What the tracker does next: bin the right image's features, search around each left one, filter by
        // rotation.
        grid.build(&fr.keypoints);
        histogram.clear();
        for (i, k) in fl.keypoints.iter().enumerate() {
            grid.features_in_area(&fr.keypoints, (k.x, k.y), 15.0, 0..=7, &mut found);
            if let Some(&j) = found.first() {
                histogram.add(i as u32, k.angle, fr.keypoints[j].angle);
            }
        }
        histogram.rejected(&mut rejected);
    };
    frame(&mut el, &mut er);
    frame(&mut el, &mut er);
    let before = bdis_testkit::allocations();
    frame(&mut el, &mut er);
    let after = bdis_testkit::allocations();
    assert_eq!(after - before, 0, "{} allocations in a warmed-up frame", after - before);
    assert!(
        fl.keypoints.len() > 100 && st.matched() > 20,
        "{} keypoints, {} matched",
        fl.keypoints.len(),
        st.matched()
    );
}
