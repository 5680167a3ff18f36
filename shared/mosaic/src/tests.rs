use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::*;

const W: u32 = 160;
const H: u32 = 120;

fn intrinsics() -> RectifiedCamera {
    RectifiedCamera { fx: 130.0, fy: 130.0, cx: 79.5, cy: 59.5, bf: 650.0, width: W, height: H }
}

/// A keyframe's images from a depth function of the pixel (None = no disparity).
struct Views {
    disparity: Vec<f32>,
    confidence: Vec<f32>,
    rgb: Vec<u8>,
}

fn views(depth: impl Fn(usize, usize) -> Option<f32>, colour: [u8; 3]) -> Views {
    let k = intrinsics();
    let n = (W * H) as usize;
    let mut v = Views { disparity: vec![f32::NAN; n], confidence: vec![0.8; n], rgb: colour.repeat(n) };
    for y in 0..H as usize {
        for x in 0..W as usize {
            if let Some(z) = depth(x, y) {
                v.disparity[y * W as usize + x] = (k.bf / f64::from(z)) as f32;
            }
        }
    }
    v
}

fn keyframe(kf_id: u64, pose: Isometry3<f64>, v: &Views) -> DepthKeyframe<'_> {
    DepthKeyframe {
        kf_id,
        t_capture_ns: kf_id * 1000,
        world_from_camera: pose,
        intrinsics: intrinsics(),
        disparity: &v.disparity,
        confidence: &v.confidence,
        rgb: &v.rgb,
    }
}

fn world_points_of(m: &Mosaic, kf: u64) -> Vec<[f32; 3]> {
    let mut out = Vec::new();
    m.for_each_world_point(|p, _, k| {
        if k == kf {
            out.push(p);
        }
    });
    out
}

#[test]
fn a_plane_lifts_to_its_grid_at_the_right_places() {
    let mut m = Mosaic::new(MosaicParams::default());
    let v = views(|_, _| Some(50.0), [200, 100, 50]);
    let report = m.insert(&keyframe(0, Isometry3::identity(), &v)).unwrap();
    let expected = W.div_ceil(5) * H.div_ceil(5);
    assert_eq!(report.added, expected as usize);
    let k = intrinsics();
    let kf = m.keyframe(0).unwrap();
    for p in &kf.points {
        assert!((p.xyz[2] - 50.0).abs() < 1e-3);
        // Back-projection: the point lands on a grid pixel.
        let u = k.fx * f64::from(p.xyz[0]) / 50.0 + k.cx;
        let v = k.fy * f64::from(p.xyz[1]) / 50.0 + k.cy;
        assert!((u - u.round()).abs() < 1e-3 && (u.round() as u32).is_multiple_of(5), "u = {u}");
        assert!((v - v.round()).abs() < 1e-3 && (v.round() as u32).is_multiple_of(5), "v = {v}");
        assert_eq!(p.rgb, [200, 100, 50]);
    }
}

#[test]
fn dark_unmatched_far_and_unconfident_pixels_are_skipped() {
    let params = MosaicParams { min_confidence: 0.5, ..MosaicParams::default() };
    let mut m = Mosaic::new(params);
    // Left third: no disparity; middle third: disparity below 8 px (depth beyond bf / 8); right third: fine.
    let mut v = views(
        |x, _| {
            if x < 50 {
                None
            } else if x < 100 {
                Some(100.0)
            } else {
                Some(40.0)
            }
        },
        [90, 90, 90],
    );
    // One dark grid pixel, one with low confidence, both in the good third.
    let dark = 10 * W as usize + 120;
    v.rgb[3 * dark..3 * dark + 3].copy_from_slice(&[39, 39, 39]);
    v.confidence[20 * W as usize + 130] = 0.2;
    let report = m.insert(&keyframe(0, Isometry3::identity(), &v)).unwrap();
    let columns = (100..W).step_by(5).count();
    assert_eq!(report.added, columns * H.div_ceil(5) as usize - 2);
}

#[test]
fn a_corrected_pose_moves_the_points_already_added() {
    let mut m = Mosaic::new(MosaicParams::default());
    let v = views(|x, y| Some(40.0 + 0.05 * x as f32 + 0.02 * y as f32), [120, 80, 60]);
    let pose =
        Isometry3::from_parts(Translation3::new(1.0, 2.0, 3.0), UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3));
    m.insert(&keyframe(7, pose, &v)).unwrap();
    let before = world_points_of(&m, 7);
    // Bundle adjustment moves the keyframe by 10 mm along x and turns it a little.
    let correction =
        Isometry3::from_parts(Translation3::new(10.0, 0.0, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, 0.05));
    let corrected = correction * pose;
    assert!(m.correct_pose(7, corrected).unwrap());
    let after = world_points_of(&m, 7);
    assert_eq!(before.len(), after.len());
    for (b, a) in before.iter().zip(&after) {
        let expected = correction * nalgebra::Point3::from(Vector3::from(b.map(f64::from)));
        let moved = Vector3::from(a.map(f64::from));
        assert!((expected.coords - moved).norm() < 1e-3, "{expected} vs {moved}");
    }
}

#[test]
fn a_correction_that_arrives_before_the_depth_is_used_at_insertion() {
    let mut m = Mosaic::new(MosaicParams::default());
    let corrected = Isometry3::translation(0.0, 0.0, 5.0);
    assert!(!m.correct_pose(3, corrected).unwrap());
    let v = views(|_, _| Some(30.0), [100, 100, 100]);
    m.insert(&keyframe(3, Isometry3::identity(), &v)).unwrap();
    assert!(world_points_of(&m, 3).iter().all(|p| (p[2] - 35.0).abs() < 1e-3));
}

#[test]
fn the_same_surface_seen_again_replaces_the_earlier_points() {
    let mut m = Mosaic::new(MosaicParams::default());
    let v0 = views(|_, _| Some(50.0), [100, 100, 100]);
    // The second view, 0.3 mm off (within the depth tolerance), shifted sideways by 2 mm.
    let v1 = views(|_, _| Some(50.3), [150, 150, 150]);
    m.insert(&keyframe(0, Isometry3::identity(), &v0)).unwrap();
    let r = m.insert(&keyframe(1, Isometry3::translation(2.0, 0.0, 0.0), &v1)).unwrap();
    assert_eq!(r.overlapping_keyframes, 1);
    assert_eq!(r.kept_occluded, 0);
    // Everything keyframe 0 saw inside keyframe 1's view is replaced; the strip 1's view misses stays.
    let left = m.keyframe(0).unwrap();
    assert!(r.removed > 0 && !left.points.is_empty());
    let k = intrinsics();
    let left_edge_x = (-0.5 - k.cx) / k.fx * 50.3 + 2.0;
    assert!(left.points.iter().all(|p| f64::from(p.xyz[0]) < left_edge_x + 0.5), "only the strip outside view 1 stays");
    assert_eq!(m.n_points(), left.points.len() + r.added);
}

#[test]
fn a_surface_behind_an_occluder_is_not_erased() {
    let mut m = Mosaic::new(MosaicParams::default());
    // Keyframe 0 sees the back wall at 60 mm everywhere.
    let wall = views(|_, _| Some(60.0), [100, 100, 100]);
    m.insert(&keyframe(0, Isometry3::identity(), &wall)).unwrap();
    let wall_points = m.n_points();
    // Keyframe 1, from the same place, sees an instrument at 25 mm covering the image's centre, the wall
    // around it.
    let occluded = |x: usize, y: usize| (40..120).contains(&x) && (30..90).contains(&y);
    let with_tool = views(|x, y| Some(if occluded(x, y) { 25.0 } else { 60.0 }), [200, 200, 200]);
    let r = m.insert(&keyframe(1, Isometry3::identity(), &with_tool)).unwrap();
    // The wall behind the instrument is kept; the wall seen again around it is replaced.
    let behind = (40..120).step_by(5).count() * (30..90).step_by(5).count();
    assert_eq!(r.kept_occluded, behind);
    assert_eq!(m.keyframe(0).unwrap().points.len(), behind);
    assert!(m.keyframe(0).unwrap().points.iter().all(|p| (p.xyz[2] - 60.0).abs() < 1e-3));
    assert_eq!(r.removed, wall_points - behind);
    // The original's rule (no depth test) would have erased the wall behind the instrument too: with a huge
    // tolerance the depth test degenerates into it.
    let mut original = Mosaic::new(MosaicParams { depth_tolerance_ratio: 1e9, ..MosaicParams::default() });
    original.insert(&keyframe(0, Isometry3::identity(), &wall)).unwrap();
    original.insert(&keyframe(1, Isometry3::identity(), &with_tool)).unwrap();
    assert!(original.keyframe(0).unwrap().points.is_empty());
}

#[test]
fn points_in_front_of_the_new_surface_are_removed() {
    // Keyframe 0 saw something at 25 mm (a passing instrument, or a wrong match); keyframe 1 sees through it to
    // the wall at 60 mm: the earlier points float in free space and go.
    let mut m = Mosaic::new(MosaicParams::default());
    let blob = views(|x, y| ((40..120).contains(&x) && (30..90).contains(&y)).then_some(25.0), [200, 200, 200]);
    m.insert(&keyframe(0, Isometry3::identity(), &blob)).unwrap();
    let wall = views(|_, _| Some(60.0), [100, 100, 100]);
    let r = m.insert(&keyframe(1, Isometry3::identity(), &wall)).unwrap();
    assert!(m.keyframe(0).unwrap().points.is_empty());
    assert_eq!(r.kept_occluded, 0);
}

#[test]
fn keyframes_that_do_not_overlap_are_not_visited() {
    let mut m = Mosaic::new(MosaicParams::default());
    let v = views(|_, _| Some(50.0), [100, 100, 100]);
    m.insert(&keyframe(0, Isometry3::identity(), &v)).unwrap();
    // 500 mm to the side, and one looking the other way: neither sees keyframe 0's patch.
    let aside = m.insert(&keyframe(1, Isometry3::translation(500.0, 0.0, 0.0), &v)).unwrap();
    assert_eq!((aside.overlapping_keyframes, aside.tested, aside.removed), (0, 0, 0));
    let turned = Isometry3::from_parts(
        Translation3::identity(),
        UnitQuaternion::from_euler_angles(0.0, std::f64::consts::PI, 0.0),
    );
    let back = m.insert(&keyframe(2, turned, &v)).unwrap();
    assert_eq!((back.overlapping_keyframes, back.removed), (0, 0));
    assert_eq!(m.n_points(), 3 * back.added);
}

#[test]
fn a_keyframe_sent_twice_is_added_once() {
    let mut m = Mosaic::new(MosaicParams::default());
    let v = views(|_, _| Some(50.0), [100, 100, 100]);
    m.insert(&keyframe(4, Isometry3::identity(), &v)).unwrap();
    let n = m.n_points();
    let again = m.insert(&keyframe(4, Isometry3::identity(), &v)).unwrap();
    assert!(again.duplicate);
    assert_eq!(m.n_points(), n);
}

#[test]
fn weighted_fusion_averages_agreeing_depths() {
    assert_eq!(MosaicParams::default().fusion, Fusion::Weighted, "averaging is the default");
    let mut m = Mosaic::new(MosaicParams::default());
    let a = views(|_, _| Some(50.4), [100, 100, 100]);
    let b = views(|_, _| Some(49.6), [100, 100, 100]);
    m.insert(&keyframe(0, Isometry3::identity(), &a)).unwrap();
    let r = m.insert(&keyframe(1, Isometry3::identity(), &b)).unwrap();
    assert_eq!(r.removed, r.added);
    let fused = m.keyframe(1).unwrap();
    // Equal confidences: the mean. (50.4 and 49.6 through disparity round-trips in f32.)
    assert!(fused.points.iter().all(|p| (p.xyz[2] - 50.0).abs() < 2e-3), "{:?}", fused.points[0]);
    assert!(fused.points.iter().all(|p| (p.weight - 1.6).abs() < 1e-4));
    // Replacement keeps the newest depth instead.
    let mut plain = Mosaic::new(MosaicParams { fusion: Fusion::Replace, ..MosaicParams::default() });
    plain.insert(&keyframe(0, Isometry3::identity(), &a)).unwrap();
    plain.insert(&keyframe(1, Isometry3::identity(), &b)).unwrap();
    assert!(plain.keyframe(1).unwrap().points.iter().all(|p| (p.xyz[2] - 49.6).abs() < 2e-3));
}

/// Fusion on a slope: the earlier points fall anywhere in a cell of the new view's grid, not on its centre, so
/// their depths are not the surface's depth at the centre. Each is carried to the centre along the new view's own
/// depth (what is averaged is how far it lies from the new surface), so a tilted plane seen twice, with the second
/// view's grid a fraction of a cell off the first's, is fused onto the plane. (Averaging the raw depths put these
/// points up to 0.08 mm off it: half the depth change across 2.5 px.)
#[test]
fn fusion_on_a_slope_stays_on_the_surface() {
    let k = intrinsics();
    // The plane z = 40 + 0.2 x (world, mm), seen from a camera translated by `tx` along x.
    let plane =
        |tx: f64| move |u: usize, _: usize| Some(((40.0 + 0.2 * tx) / (1.0 - 0.2 * (u as f64 - k.cx) / k.fx)) as f32);
    // 2.5 px at 40 mm: the first view's grid points fall between the second's.
    let tx = 2.5 * 40.0 / k.fx;
    let mut m = Mosaic::new(MosaicParams::default());
    m.insert(&keyframe(0, Isometry3::identity(), &views(plane(0.0), [100, 100, 100]))).unwrap();
    let r = m.insert(&keyframe(1, Isometry3::translation(tx, 0.0, 0.0), &views(plane(tx), [100, 100, 100]))).unwrap();
    assert!(r.removed > 0, "{r:?}");
    let fused = world_points_of(&m, 1);
    let worst = fused.iter().map(|p| (f64::from(p[2]) - (40.0 + 0.2 * f64::from(p[0]))).abs()).fold(0.0, f64::max);

    assert!(worst < 0.01, "a fused point {worst} mm off the plane");
}

#[test]
fn wrong_sizes_and_bad_poses_are_errors_not_panics() {
    let mut m = Mosaic::new(MosaicParams::default());
    let v = views(|_, _| Some(50.0), [100, 100, 100]);
    let mut kf = keyframe(0, Isometry3::identity(), &v);
    kf.disparity = &v.disparity[1..];
    assert!(matches!(m.insert(&kf), Err(MosaicError::WrongSize { what: "disparity", .. })));
    let mut kf = keyframe(0, Isometry3::identity(), &v);
    kf.intrinsics.bf = 0.0;
    assert!(matches!(m.insert(&kf), Err(MosaicError::BadIntrinsics { .. })));
    let mut kf = keyframe(0, Isometry3::identity(), &v);
    kf.world_from_camera.translation.vector.x = f64::NAN;
    assert!(matches!(m.insert(&kf), Err(MosaicError::BadPose { .. })));
    assert_eq!(m.n_keyframes(), 0);
}

#[test]
fn a_saved_map_loads_back_identical_and_a_foreign_file_is_refused() {
    let dir = std::env::temp_dir().join(format!("bdis-mosaic-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut m = Mosaic::new(MosaicParams { fusion: Fusion::Weighted, ..MosaicParams::default() });
    let v = views(|x, _| Some(40.0 + x as f32 * 0.1), [10, 200, 90]);
    m.insert(&keyframe(0, Isometry3::translation(1.0, 2.0, 3.0), &v)).unwrap();
    m.correct_pose(9, Isometry3::translation(0.0, 1.0, 0.0)).unwrap();
    let path = dir.join("map.bin");
    save(&m, &path).unwrap();
    let back = load(&path).unwrap();
    assert_eq!(back.params, m.params);
    assert_eq!(back.keyframes().collect::<Vec<_>>(), m.keyframes().collect::<Vec<_>>());
    assert_eq!(back.corrections().count(), 1);
    std::fs::write(&path, b"ply\nformat ascii 1.0\n").unwrap();
    let err = load(&path).unwrap_err().to_string();
    assert!(err.contains("map.bin") && err.contains(MOSAIC_FORMAT), "{err}");
    // A map of the format before (its depth tolerance a length): named as such, not read in the wrong unit.
    let mut v1 = bincode::serde::encode_to_vec("bdis.v1.mosaic", bincode::config::standard()).unwrap();
    v1.extend_from_slice(&[0; 64]);
    std::fs::write(&path, v1).unwrap();
    let err = load(&path).unwrap_err().to_string();
    assert!(err.contains("map.bin") && err.contains("earlier bdis-slam") && err.contains("bdis-slam map"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn the_preview_shows_the_surface_shaded_from_the_scope_side_with_the_path() {
    let mut m = Mosaic::new(MosaicParams::default());
    // A tilted plane seen from two places: the path between them is drawn in.
    let v = views(|x, y| Some(40.0 + 0.02 * (x + y) as f32), [180, 60, 60]);
    m.insert(&keyframe(0, Isometry3::identity(), &v)).unwrap();
    m.insert(&keyframe(1, Isometry3::translation(2.0, 0.0, 0.0), &v)).unwrap();
    let (image, view) = render_preview(&m, 320).unwrap();
    let total = (image.width() * image.height()) as usize;
    let tissue: Vec<[u8; 3]> =
        image.pixels().map(|p| p.0).filter(|&[r, g, b]| r > 40 && r > 2 * g && g.abs_diff(b) < 12).collect();
    // The plane covers much of the frame (beside the path and the scope's frustum), in its own hue, shaded: not one flat colour.
    assert!(tissue.len() as f64 > 0.2 * total as f64, "{} of {total}", tissue.len());
    let (lo, hi) = tissue.iter().fold((255, 0), |(lo, hi), p| (lo.min(p[0]), hi.max(p[0])));
    assert!(hi - lo > 20, "red from {lo} to {hi}: no shading");
    // Seen from the cameras' side (they look along +z), raised above their axis rather than straight on.
    assert!(view.looking_along[2] > 0.6 && view.looking_along[2] < 0.99, "{:?}", view.looking_along);
    let path = image.pixels().filter(|p| p.0[0] > 200 && p.0[1] > 150 && p.0[2] < 120).count();
    assert!(path > 10, "the path between the keyframes is not drawn ({path} pixels)");
    assert!(render_preview(&Mosaic::new(MosaicParams::default()), 320).is_none());
}

#[test]
fn normals_of_a_plane_are_its_normal_turned_to_the_camera() {
    let mut m = Mosaic::new(MosaicParams::default());
    // z = 40 + 0.02 (x + y) in pixels: tilted about the diagonal.
    let v = views(|x, y| Some(40.0 + 0.02 * (x + y) as f32), [180, 60, 60]);
    m.insert(&keyframe(0, Isometry3::identity(), &v)).unwrap();
    let cloud = m.keyframe(0).unwrap();
    let (mut grid, mut normals) = (Vec::new(), Vec::new());
    crate::keyframe_normals(cloud, m.params.depth_gap_px, &mut grid, &mut normals);
    assert_eq!(normals.len(), cloud.points.len());
    // Along the image x axis the plane rises 0.02 per pixel in z while x grows z/fx per pixel, so its normal
    // leans towards -x and -y by the same amount, and faces the camera (-z).
    let inside: Vec<_> =
        normals.iter().zip(&cloud.points).filter(|(_, p)| p.xyz[0].abs() < 5.0 && p.xyz[1].abs() < 5.0).collect();
    assert!(!inside.is_empty());
    for (n, _) in inside {
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        assert!((len - 1.0).abs() < 1e-4 && n[2] < -0.5, "{n:?}");
        assert!((n[0] - n[1]).abs() < 0.02 && n[0] > 0.05, "{n:?}");
    }
}

#[test]
fn parameters_are_set_by_name_and_bad_values_say_which() {
    let mut p = MosaicParams::default();
    p.apply_overrides(&["depth_gap_px=3".into(), "fusion=weighted".into(), "min_disparity_px = 12".into()]).unwrap();
    assert_eq!((p.depth_gap_px, p.fusion, p.min_disparity_px), (3, Fusion::Weighted, 12.0));
    assert!(p.apply_overrides(&["depth_gap_px=0".into()]).unwrap_err().contains("depth_gap_px"));
    assert!(p.apply_overrides(&["fusion=blend".into()]).unwrap_err().contains("fusion"));
    assert!(p.apply_overrides(&["gap=3".into()]).unwrap_err().contains("depth_gap_px"));
    assert!(p.apply_overrides(&["min_confidence=-1".into()]).unwrap_err().contains("min_confidence"));
    // The tolerance that was a length says what it became rather than being taken in another unit.
    assert!(p.apply_overrides(&["depth_tolerance_mm=0.5".into()]).unwrap_err().contains("depth_tolerance_ratio"));
    p.apply_overrides(&["depth_tolerance_ratio=0.02".into()]).unwrap();
    assert_eq!(p.depth_tolerance_ratio, 0.02);
}

#[test]
fn a_closer_earlier_view_is_not_overwritten_by_a_distant_one() {
    // Keyframe 0 sees the wall from 30 mm; keyframe 1 backs off to 50 mm (depth error ×2.8) and sees it again.
    let near = views(|_, _| Some(30.0), [100, 100, 100]);
    let far = views(|_, _| Some(50.0), [150, 150, 150]);
    let mut m = Mosaic::new(MosaicParams::default());
    m.insert(&keyframe(0, Isometry3::identity(), &near)).unwrap();
    let n0 = m.n_points();
    let r = m.insert(&keyframe(1, Isometry3::translation(0.0, 0.0, -20.0), &far)).unwrap();
    assert_eq!((r.removed, r.kept_closer), (0, n0), "{r:?}");
    // Keyframe 1 adds only around keyframe 0's patch (its wider view of the wall), nothing on top of it.
    let k = intrinsics();
    let (half_w, half_h) = (f64::from(W) / 2.0 / k.fx * 30.0 - 1.0, f64::from(H) / 2.0 / k.fy * 30.0 - 1.0);
    let new_points = &m.keyframe(1).unwrap().points;
    let on_top =
        new_points.iter().filter(|p| f64::from(p.xyz[0]).abs() < half_w && f64::from(p.xyz[1]).abs() < half_h).count();
    assert_eq!(on_top, 0);
    assert!(new_points.len() > 400, "the wider view adds the wall around: {}", new_points.len());
    // The other way round, the closer view replaces the distant one (and with the ratio at 0, always the newest).
    let mut m = Mosaic::new(MosaicParams::default());
    m.insert(&keyframe(0, Isometry3::translation(0.0, 0.0, -20.0), &far)).unwrap();
    let r = m.insert(&keyframe(1, Isometry3::identity(), &near)).unwrap();
    assert!(r.removed > 0 && r.kept_closer == 0, "{r:?}");
    let mut m = Mosaic::new(MosaicParams { keep_closer_ratio: 0.0, ..MosaicParams::default() });
    m.insert(&keyframe(0, Isometry3::identity(), &near)).unwrap();
    let r = m.insert(&keyframe(1, Isometry3::translation(0.0, 0.0, -20.0), &far)).unwrap();
    assert_eq!((r.removed, r.kept_closer), (n0, 0));
}

#[test]
fn an_hd_keyframe_is_lifted_on_a_grid_as_wide_as_its_depth_is_fine() {
    // The same wall seen by a 1920×1080 camera of the same field of view as a 640×360 one: BDIS matched the HD
    // pair halved, so its grid is every 10th pixel and its pixel margins double — the map gets the points a
    // 960×540 depth supports (2.25× the 640×360 keyframe's, not 9×).
    let p = MosaicParams::default();
    let hd = p.for_size(1920, 1080);
    assert_eq!((hd.depth_gap_px, hd.min_disparity_px, hd.carve_disparity_px), (10, 16.0, 6.0));
    assert_eq!(hd.disparity_tolerance_px, 2.0);
    assert_eq!(p.for_size(640, 480), p, "VGA as the parameters say");
    assert_eq!(p.grid_gap(3840, 2160), 20);
    let mut m = Mosaic::new(p);
    let cam = |w: u32, h: u32, f: f64| RectifiedCamera {
        fx: f,
        fy: f,
        cx: f64::from(w) / 2.0 - 0.5,
        cy: f64::from(h) / 2.0 - 0.5,
        bf: f * 5.0,
        width: w,
        height: h,
    };
    let mut added = Vec::new();
    for (id, (w, h, f)) in [(640u32, 360u32, 520.0), (1920, 1080, 1560.0)].into_iter().enumerate() {
        let n = (w * h) as usize;
        let (disparity, confidence, rgb) =
            (vec![(f * 5.0 / 50.0) as f32; n], vec![0.8f32; n], [200u8, 100, 50].repeat(n));
        let pose = Isometry3::translation(1000.0 * id as f64, 0.0, 0.0);
        let kf = DepthKeyframe {
            kf_id: id as u64,
            t_capture_ns: 0,
            world_from_camera: pose,
            intrinsics: cam(w, h, f),
            disparity: &disparity,
            confidence: &confidence,
            rgb: &rgb,
        };
        added.push(m.insert(&kf).unwrap().added);
    }
    assert_eq!(added, vec![128 * 72, 192 * 108]);
}

/// Two passes over a flat wall at 50 mm. The second pass's keyframe was published 15 mm off along its axis (drift),
/// so the first pass's points lay far behind its surface — occluded, kept: two surfaces. A loop correction puts
/// it where it was; the overlap rule, run again, leaves one.
#[test]
fn a_correction_that_brings_two_passes_together_leaves_one_surface() {
    let mut m = Mosaic::new(MosaicParams::default());
    let wall = views(|_, _| Some(50.0), [100, 100, 100]);
    m.insert(&keyframe(0, Isometry3::identity(), &wall)).unwrap();
    let first_pass = m.n_points();
    let truth = Isometry3::translation(2.0, 0.0, 0.0);
    let drifted = Isometry3::translation(2.0, 0.0, -15.0);
    let r = m.insert(&keyframe(1, drifted, &wall)).unwrap();
    assert_eq!((r.removed, r.kept_occluded), (0, first_pass), "drifted, the first pass lies behind: {r:?}");
    let behind = |m: &Mosaic| world_points_of(m, 0).iter().filter(|p| (p[2] - 50.0).abs() < 1e-3).count();
    assert_eq!(behind(&m), first_pass);

    // A correction well under a pixel in the keyframe's image does not run the rule again.
    m.correct_pose(1, Isometry3::translation(2.0, 0.0, -14.99)).unwrap();
    assert_eq!(m.realign(), Realigned::default());

    m.correct_pose(1, truth).unwrap();
    let realigned = m.realign();
    assert_eq!(realigned.keyframes_moved, 1);
    // What keyframe 1 sees of the wall inside its grid now agrees with it and is replaced; the strip its view
    // misses stays, and so does its last grid step (each test needs the four grid samples around the point).
    let k = intrinsics();
    let kept = m.keyframe(0).unwrap();
    assert!(realigned.removed > 0 && !kept.points.is_empty(), "{realigned:?}");
    let (last_u, last_v) = (f64::from((W - 1) / 5 * 5), f64::from((H - 1) / 5 * 5));
    for p in &kept.points {
        let u = k.fx * (f64::from(p.xyz[0]) - 2.0) / 50.0 + k.cx;
        let v = k.fy * f64::from(p.xyz[1]) / 50.0 + k.cy;
        // (A hundredth of a pixel: the map projects in f32.)
        assert!(u < 0.0 || u > last_u - 0.01 || v > last_v - 0.01, "a point inside view 1's grid kept at ({u}, {v})");
    }
    assert_eq!(realigned.removed, first_pass - kept.points.len());
    assert_eq!(realigned.seen_through, 0, "one wall, nothing seen through");
    // Run again at the same poses it changes nothing; the next keyframe's insertion reports no realignment.
    assert_eq!(m.realign(), Realigned::default());
    let r = m.insert(&keyframe(2, Isometry3::translation(4.0, 0.0, 0.0), &wall)).unwrap();
    assert_eq!(r.realigned, Realigned::default());
    // Without the second run the wall would keep its first pass behind the second inside view 1.
    let mut stale = Mosaic::new(MosaicParams::default());
    stale.insert(&keyframe(0, Isometry3::identity(), &wall)).unwrap();
    stale.insert(&keyframe(1, drifted, &wall)).unwrap();
    stale.correct_pose(1, truth).unwrap();
    assert_eq!(stale.keyframe(0).unwrap().points.len(), first_pass);
}

/// The rule runs again inside [`Mosaic::insert`] when corrections applied before a keyframe moved earlier ones.
#[test]
fn a_keyframe_inserted_after_a_correction_realigns_first() {
    let mut m = Mosaic::new(MosaicParams::default());
    let wall = views(|_, _| Some(50.0), [100, 100, 100]);
    m.insert(&keyframe(0, Isometry3::identity(), &wall)).unwrap();
    m.insert(&keyframe(1, Isometry3::translation(2.0, 0.0, -15.0), &wall)).unwrap();
    m.correct_pose(1, Isometry3::translation(2.0, 0.0, 0.0)).unwrap();
    // Keyframe 2 looks elsewhere (a wall 200 mm to the side): only the realignment touches the first two.
    let r = m.insert(&keyframe(2, Isometry3::translation(200.0, 0.0, 0.0), &wall)).unwrap();
    assert_eq!(r.realigned.keyframes_moved, 1);
    assert!(r.realigned.removed > 0);
    assert_eq!(r.overlapping_keyframes, 0);
}
