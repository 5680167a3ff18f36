use super::*;

/// A keyframe with no features, at the world's origin (other tests of the crate build maps from it).
pub(crate) fn keyframe(id: KfId, parent: Option<KfId>, bad: bool) -> KeyFrame {
    KeyFrame {
        id,
        frame_id: id as u64,
        t_ns: 0,
        camera_from_world: Isometry3::identity(),
        keypoints: Vec::new(),
        descriptors: Vec::new(),
        u_right: Vec::new(),
        depth: Vec::new(),
        grid: FeatureGrid::new(64.0, 48.0),
        points: Vec::new(),
        aligned: Vec::new(),
        connections: BTreeMap::new(),
        ordered: Vec::new(),
        parent,
        children: BTreeSet::new(),
        bad,
        camera_from_parent: bad.then(Isometry3::identity),
        median_depth: f64::NAN,
        texture: crate::frame::ViewTexture::UNKNOWN,
        veiled: false,
    }
}

#[test]
fn a_culled_keyframe_moves_with_its_first_live_ancestor() {
    // 0 ← 1 (culled) ← 2 (culled); 0 ← 3 ← 4 (culled); 5 (culled, no parent).
    let map = Map {
        keyframes: vec![
            keyframe(0, None, false),
            keyframe(1, Some(0), true),
            keyframe(2, Some(1), true),
            keyframe(3, Some(0), false),
            keyframe(4, Some(3), true),
            keyframe(5, None, true),
        ],
        ..Default::default()
    };
    assert_eq!(map.culled_following(&[0]), vec![1, 2], "through a chain of culled parents");
    assert_eq!(map.culled_following(&[3]), vec![4]);
    assert_eq!(map.culled_following(&[0, 3]), vec![1, 2, 4]);
    assert!(map.culled_following(&[]).is_empty());
    // A live keyframe never "follows": it has its own correction when it moved.
    assert!(!map.culled_following(&[0]).contains(&3));
}

/// A keyframe with `n` stereo keypoints at octave 0, each aligned (refined, spread 0.5) as if to a point.
pub(crate) fn keyframe_with_aligned_keypoints(id: KfId, n: usize) -> KeyFrame {
    let mut k = keyframe(id, None, false);
    let kp = bdis_orb::KeyPoint { x: 100.0, y: 80.0, octave: 0, angle: 0.0, response: 1.0, size: 31.0 };
    k.keypoints = vec![kp; n];
    k.descriptors = vec![[0; 32]; n];
    k.u_right = vec![90.0; n];
    k.depth = vec![60.0; n];
    k.points = vec![None; n];
    k.aligned = vec![Some(0.5); n];
    k
}

/// A keypoint aligned to one point's anchor is no sub-pixel measurement of another point: when a point is
/// fused into another (the mapper's fusion, a loop's), or a keypoint is linked to a point it was not
/// aligned to, its observation weighs as the whole-pixel corner it is. (Kept as aligned, such observations
/// were a quarter of the aligned ones on the lit circle, with a median error of 1 px of their octave
/// against 0.3 px: BENCHMARKS, "Each measurement with its own σ".)
#[test]
fn an_observation_moved_to_another_point_is_no_longer_an_aligned_measurement() {
    let scales = Scales::new(1.2, 8, 0);
    let mut map = Map {
        keyframes: vec![keyframe_with_aligned_keypoints(0, 3), keyframe_with_aligned_keypoints(1, 3)],
        ..Default::default()
    };
    let old = map.new_point(Point3::new(0.0, 0.0, 60.0), 0, 0, &scales);
    map.add_observation(old, 1, 0);
    let duplicate = map.new_point(Point3::new(0.0, 0.0, 60.0), 1, 1, &scales);
    // The tracker set these links itself, each keypoint aligned to its own point's anchor.
    map.keyframes[0].aligned = vec![Some(1.0); 3];
    map.keyframes[1].aligned = vec![Some(0.5); 3];
    // Linking again what is linked keeps the measurement.
    map.add_observation(old, 1, 0);
    assert_eq!(map.keyframes[1].aligned[0], Some(0.5));
    // Keyframe 0 had the point at keypoint 1 unmatched (not linked): fusion links it.
    map.keyframes[0].points[1] = None;
    map.add_observation(duplicate, 0, 1);
    assert_eq!(map.keyframes[0].aligned[1], None, "a keypoint linked to a point it was not aligned to");
    // The duplicate in keyframe 1 is fused into the old point: its keypoint moves over.
    let mut moved = map.clone();
    moved.points[old].observations.remove(&1);
    moved.keyframes[1].points[0] = None;
    moved.replace_point(duplicate, old);
    assert_eq!(moved.points[old].observations.get(&1), Some(&1));
    assert_eq!(moved.keyframes[1].aligned[1], None);
    // What is not touched keeps its alignment.
    assert_eq!(moved.keyframes[1].aligned[2], Some(0.5));
    assert_eq!(moved.keyframes[0].aligned[0], Some(1.0));
}
