#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! A warmed-up keyframe update allocates only the new keyframe's own storage (its points, and the depth it saw on
//! its grid, kept for the free-space test of later keyframes): the per-pixel depth image, the fusion
//! accumulators, the covered-cell flags and the list of overlapping keyframes are buffers the map reuses; removal
//! works in place.

use bdis_mosaic::{DepthKeyframe, Fusion, Mosaic, MosaicParams, RectifiedCamera};
use nalgebra::Isometry3;

#[global_allocator]
static GLOBAL: bdis_testkit::CountingAllocator = bdis_testkit::CountingAllocator;

const W: u32 = 320;
const H: u32 = 240;

#[test]
fn a_warmed_up_keyframe_allocates_only_its_own_points() {
    let k = RectifiedCamera { fx: 260.0, fy: 260.0, cx: 159.5, cy: 119.5, bf: 1300.0, width: W, height: H };
    let n = (W * H) as usize;
    let disparity: Vec<f32> = (0..n).map(|i| 30.0 + (i % W as usize) as f32 * 0.02).collect();
    let confidence = vec![0.8f32; n];
    let rgb = vec![120u8; 3 * n];
    for fusion in [Fusion::Replace, Fusion::Weighted] {
        let mut map = Mosaic::new(MosaicParams { fusion, ..MosaicParams::default() });
        let keyframe = |id: u64| DepthKeyframe {
            kf_id: id,
            t_capture_ns: id,
            // Sliding sideways 3 mm per keyframe: each view overlaps the previous ones and replaces points.
            world_from_camera: Isometry3::translation(3.0 * id as f64, 0.0, 0.0),
            intrinsics: k,
            disparity: &disparity,
            confidence: &confidence,
            rgb: &rgb,
        };
        for id in 0..5 {
            map.insert(&keyframe(id)).unwrap();
        }
        for id in 5..10 {
            let (a0, b0) = (bdis_testkit::allocations(), bdis_testkit::bytes());
            let report = map.insert(&keyframe(id)).unwrap();
            let (allocations, bytes) = (bdis_testkit::allocations() - a0, bdis_testkit::bytes() - b0);
            assert!(report.removed > 0 && report.added > 0, "{report:?}");
            // The new keyframe's point vector and seen depth, and at most one node of each keyframe index.
            assert!(allocations <= 4, "{fusion:?}, keyframe {id}: {allocations} allocations");
            let cells = (W.div_ceil(5) * H.div_ceil(5)) as usize;
            let points_bytes = cells * size_of::<bdis_mosaic::MosaicPoint>();
            assert!(
                bytes <= points_bytes + cells * size_of::<f32>() + 4096,
                "{fusion:?}, keyframe {id}: {bytes} bytes for {points_bytes} of points"
            );
        }
    }
}
