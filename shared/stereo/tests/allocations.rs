#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Hot-path discipline: once warmed up on a size, the matcher allocates nothing per pair.

use bdis_stereo::{Algorithm, DisparityMap, GrayImage, Matcher, Params};

#[global_allocator]
static GLOBAL: bdis_testkit::CountingAllocator = bdis_testkit::CountingAllocator;

#[test]
fn a_warmed_up_pair_allocates_nothing() {
    let (w, h) = (640, 480);
    let tex = |x: usize, y: usize| -> u8 { (((x * 2_654_435_761) ^ (y * 40_503)) >> 6) as u8 | 1 };
    let left: Vec<u8> = (0..w * h).map(|i| tex(i % w, i / w)).collect();
    let right: Vec<u8> = (0..w * h).map(|i| tex(i % w + 5, i / w)).collect();
    for params in [
        Params::default(),
        Params::colon(),
        Params { algorithm: Algorithm::Dis, ..Params::default() },
        Params { variance: true, ..Params::colon() },
        // Without the left–right check (the defaults above run it, with its second pass and mirrored images).
        Params::colon().as_published(),
        // The pair halved first (what an HD pair gets by default), with the check and without.
        Params { level_offset: Some(1), ..Params::colon() },
        Params { level_offset: Some(2), ..Params::colon().as_published() },
    ] {
        let mut matcher = Matcher::new(params).unwrap();
        let mut out = DisparityMap::default();
        let (l, r) = (GrayImage { width: w, height: h, data: &left }, GrayImage { width: w, height: h, data: &right });
        matcher.compute_into(l, r, &mut out).unwrap();
        let before = bdis_testkit::allocations();
        matcher.compute_into(l, r, &mut out).unwrap();
        matcher.compute_into(l, r, &mut out).unwrap();
        let after = bdis_testkit::allocations();
        assert_eq!(after - before, 0, "{params:?}: {} allocations in two warmed-up pairs", after - before);
    }
}
