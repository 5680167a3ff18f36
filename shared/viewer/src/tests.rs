//! The live messages against a real mosaic: a keyframe's block goes to the page once; a later view that
//! replaces some of its points trims them; a pose correction moves it by one matrix.

use bdis_core::calib::RectifiedCamera;
use bdis_mosaic::{DepthKeyframe, Mosaic, MosaicParams};
use nalgebra::Isometry3;

use crate::live::{LiveMap, Update};

const W: u32 = 64;
const H: u32 = 48;

fn plane(m: &mut Mosaic, kf_id: u64, pose: Isometry3<f64>) {
    let n = (W * H) as usize;
    let k = RectifiedCamera { fx: 60.0, fy: 60.0, cx: 32.0, cy: 24.0, bf: 300.0, width: W, height: H };
    // A plane 50 units away: disparity bf / z everywhere.
    let disparity = vec![6.0f32; n];
    let confidence = vec![0.9f32; n];
    let rgb = vec![150u8; 3 * n];
    let kf = DepthKeyframe {
        kf_id,
        t_capture_ns: kf_id,
        world_from_camera: pose,
        intrinsics: k,
        disparity: &disparity,
        confidence: &confidence,
        rgb: &rgb,
    };
    m.insert(&kf).unwrap();
}

fn tags(updates: &[Update]) -> Vec<String> {
    updates
        .iter()
        .map(|u| match u {
            Update::Binary(b) => String::from_utf8_lossy(&b[..4]).into_owned(),
            Update::Text(t) => t.clone(),
        })
        .collect()
}

#[test]
fn a_keyframe_goes_to_the_page_once_then_is_trimmed_and_moved() {
    let mut m = Mosaic::new(MosaicParams { min_disparity_px: 1.0, ..Default::default() });
    let mut live = LiveMap::default();
    let mut out = Vec::new();
    plane(&mut m, 0, Isometry3::identity());
    live.sync(&m, &mut out);
    assert_eq!(tags(&out), ["BLK1"]);
    out.clear();
    live.sync(&m, &mut out);
    assert!(out.is_empty(), "nothing changed, nothing sent: {:?}", tags(&out));

    // The same surface seen again from a little to the side: keyframe 1 is new, and the part of keyframe 0 it
    // saw again leaves the page by a trim (its points are not sent again).
    plane(&mut m, 1, Isometry3::translation(5.0, 0.0, 0.0));
    live.sync(&m, &mut out);
    assert_eq!(tags(&out), ["TRM1", "BLK1"], "{:?}", tags(&out));
    let Update::Binary(trim) = &out[0] else { unreachable!() };
    let before = u32::from_le_bytes(trim[12..16].try_into().unwrap()) as usize;
    let kept: u32 = trim[16..].iter().map(|b| b.count_ones()).sum();
    assert_eq!(kept as usize, m.keyframe(0).unwrap().points.len());
    assert!((kept as usize) < before);
    assert_eq!(live.points_shown(), m.n_points());

    // A correction of keyframe 0: one matrix.
    out.clear();
    m.correct_pose(0, Isometry3::translation(0.0, 1.0, 0.0)).unwrap();
    live.sync(&m, &mut out);
    assert_eq!(tags(&out), ["COR1"]);
    let Update::Binary(moved) = &out[0] else { unreachable!() };
    let ty = f32::from_le_bytes(moved[12 + 4 * 13..12 + 4 * 14].try_into().unwrap());
    assert_eq!(ty, 1.0, "the translation's y, column-major");

    // A page that connects now is sent both blocks as they stand.
    assert_eq!(tags(&live.replay()), ["BLK1", "BLK1"]);
}
