//! A veil over the view (surgical smoke), on a rendered colon flight veiled frame by frame: each pixel is
//! blended towards the image's mean, which takes that share of the texture contrast away as a haze does.
//! The veil is doubted from when it comes down until the view is clear again, not merely less veiled (a haze
//! still coming down is doubted too, as `hazy`, though tracked as a clear view); a view that stays dim longer
//! than smoke lasts is taken as it is; a veil too thick to track through is coasted on the motion model, never
//! lost, and the written trajectory bridges it; a scope that moves on under the renderer's own smoke keeps a
//! map with keyframes flagged as veiled; a hover under it makes no keyframe that adds nothing.

mod common;

use bdis_track::{Doubt, FrameResult, PoseMethod, Tracker, TrackingState};
use common::{colon_flight, colon_tracker, colon_tracker_at, grey, render_rig};

/// `image` with `share` of its contrast taken away: blended towards its own mean brightness.
fn veiled(image: &[u8], share: f64) -> Vec<u8> {
    let mean = image.iter().map(|&p| f64::from(p)).sum::<f64>() / image.len() as f64;
    image.iter().map(|&p| ((1.0 - share) * f64::from(p) + share * mean).round() as u8).collect()
}

/// Tracks the colon flight's first `frames` pairs with each frame veiled by `veil(i)`.
fn track_veiled(tracker: &mut Tracker, frames: usize, veil: impl Fn(usize) -> f64) -> Vec<FrameResult> {
    colon_flight(frames)
        .iter()
        .enumerate()
        .map(|(i, (l, r))| {
            let share = veil(i);
            let (l, r) = (veiled(l, share), veiled(r, share));
            match tracker.track(i as u64 * 33_333_333, &l, &r) {
                Ok(result) => result,
                Err(e) => panic!("frame {i}: {e}"),
            }
        })
        .collect()
}

fn doubted_for_contrast(result: &FrameResult) -> bool {
    result.state == TrackingState::Uncertain && result.quality.doubt == Some(Doubt::LowContrast)
}

#[test]
fn a_veil_is_doubted_until_the_view_is_clear_again_and_a_thin_haze_alone_is_no_veil() {
    // 60 % of the contrast gone over frames 12–14, then 35 % over 15–17 (thinning), then clear.
    let mut tracker = colon_tracker();
    let results = track_veiled(&mut tracker, 26, |i| match i {
        12..15 => 0.6,
        15..18 => 0.35,
        _ => 0.0,
    });
    for (i, r) in results.iter().enumerate() {
        let expected = (12..18).contains(&i);
        assert_eq!(doubted_for_contrast(r), expected, "frame {i}: {:?} {:?}", r.state, r.quality);
        assert_ne!(r.state, TrackingState::Lost, "frame {i}");
    }
    // A keyframe made under the veil (the flight moves on past its map) is flagged as such: it serves tracking,
    // and its images are no view to take depth from.
    let map = tracker.map();
    for (i, r) in results.iter().enumerate() {
        if let Some(k) = r.new_keyframe {
            assert_eq!(map.keyframes[k].veiled, (12..18).contains(&i), "frame {i}");
        }
    }
    // The same 35 % with no veil before it: a haze coming down, not yet a veil. The frames are doubted for it
    // (clear footage keeps three quarters of its contrast), but tracked as clear ones are: posed on the map,
    // never coasted, and what keyframes they make are not flagged as veiled.
    let mut thin_tracker = colon_tracker();
    let thin = track_veiled(&mut thin_tracker, 18, |i| if (12..15).contains(&i) { 0.35 } else { 0.0 });
    for (i, r) in thin.iter().enumerate() {
        let hazy = r.state == TrackingState::Uncertain && r.quality.doubt == Some(Doubt::Hazy);
        assert_eq!(hazy, (12..15).contains(&i), "frame {i}: {:?} {:?}", r.state, r.quality);
        assert_ne!(r.quality.method, PoseMethod::Prediction, "frame {i} coasted");
        if let Some(k) = r.new_keyframe {
            assert!(!thin_tracker.map().keyframes[k].veiled, "frame {i}'s keyframe flagged as veiled");
        }
    }
}

#[test]
fn a_view_that_stays_dim_for_longer_than_smoke_lasts_is_taken_as_it_is() {
    // At 5 frames a second a veil lasts at most 2 s: 10 frames. From frame 10 on the view keeps 45 % of its
    // contrast for good.
    let results = track_veiled(&mut colon_tracker_at(5.0), 34, |i| if i >= 10 { 0.55 } else { 0.0 });
    for (i, r) in results.iter().enumerate() {
        assert_ne!(r.state, TrackingState::Lost, "frame {i}: {:?}", r.quality);
    }
    assert!(doubted_for_contrast(&results[10]), "the veil came down: {:?}", results[10].quality);
    // Within the longest a veil lasts, the dim view is the view: no longer doubted for its contrast.
    for (i, r) in results.iter().enumerate().skip(21) {
        assert!(!doubted_for_contrast(r), "frame {i}: {:?}", r.quality);
    }
}

#[test]
fn a_veil_too_thick_to_track_through_is_coasted_and_the_written_trajectory_bridges_it() {
    // Frames 14–19 keep 3 % of their contrast: nothing to match (no corner survives it).
    let mut tracker = colon_tracker();
    let results = track_veiled(&mut tracker, 30, |i| if (14..20).contains(&i) { 0.97 } else { 0.0 });
    for (i, r) in results.iter().enumerate() {
        assert_ne!(r.state, TrackingState::Lost, "frame {i}: {:?}", r.quality);
    }
    let coasted = (14..20).filter(|&i| results[i].quality.method == PoseMethod::Prediction).count();
    assert!(coasted >= 3, "{coasted} of the veiled frames posed by the motion model");
    assert!((14..20).all(|i| doubted_for_contrast(&results[i])));
    assert!(results[24..].iter().all(|r| r.state == TrackingState::Ok), "tracking resumed after the veil");
    // The written trajectory against the truth (the tracker's world is its first camera).
    let colon = bdis_synth::colon::Colon::default();
    let truth = |i: usize| colon.forward_pose(i as f64 / 30.0, 20.0);
    let first = truth(0).inverse();
    let written = tracker.trajectory();
    assert_eq!(written.len(), 30);
    for (i, (_, world_from_camera, _)) in written.iter().enumerate() {
        let error = (world_from_camera.translation.vector - (first * truth(i)).translation.vector).norm();
        // The flight moves 0.67 mm a frame; the clear frames are within a tenth of that.
        assert!(error < 0.2, "frame {i}: {error:.3} mm off");
    }
    // Live, a coasted frame is the motion of the frames measured before it carried on: on this steady flight,
    // as near the truth as the written one.
    for i in (14..20).filter(|&i| results[i].quality.method == PoseMethod::Prediction) {
        let live = results[i].camera_from_world.expect("a coasted frame has a pose").inverse();
        let error = (live.translation.vector - (first * truth(i)).translation.vector).norm();
        assert!(error < 0.2, "coasted frame {i}: {error:.3} mm off");
    }
}

#[test]
fn a_veil_that_thickens_at_once_is_coasted_where_its_few_matches_confirm_nothing() {
    // Half the contrast gone over frames 12–15, then 70–74 % of it over 16–21: the scope enters the thick of a
    // cloud. Where a pose keeps under half the last frame's inliers and appearance finds nothing, a cut would be
    // lost (`Doubt::Unconfirmed`); under a veil it is the haze that took them (at 72 % the frame kept 46 of
    // 141), and the frame is coasted instead: never lost, `Ok` again once clear.
    for thick in [0.70, 0.72, 0.74] {
        let results = track_veiled(&mut colon_tracker(), 30, |i| match i {
            12..16 => 0.5,
            16..22 => thick,
            _ => 0.0,
        });
        for (i, r) in results.iter().enumerate() {
            assert_ne!(r.state, TrackingState::Lost, "{thick}: frame {i}: {:?}", r.quality);
        }
        assert!((12..22).all(|i| doubted_for_contrast(&results[i])), "{thick}");
        assert!(results[24..].iter().all(|r| r.state == TrackingState::Ok), "{thick}: tracking resumed after the veil");
    }
}

/// The colon flight of [`colon_flight`] with `smoke` rendered into it.
fn smoky_colon_flight(frames: usize, smoke: &bdis_synth::smoke::Smoke) -> Vec<(Vec<u8>, Vec<u8>)> {
    let colon = bdis_synth::colon::Colon::default();
    (0..frames)
        .map(|i| {
            let t = i as f64 / 30.0;
            let shading = bdis_synth::render::Shading { haze: smoke.haze_at(t), ..Default::default() };
            let pose = colon.forward_pose(t, 20.0);
            let pair = bdis_synth::render::render(&colon, &render_rig(), &shading, &pose, i as u64);
            (grey(&pair.left), grey(&pair.right))
        })
        .collect()
}

#[test]
fn a_scope_flying_on_under_smoke_keeps_its_map_and_its_way() {
    // A second of smoke hanging in the colon over the 20 mm/s flight: the scope flies 20 mm under it, past the
    // tissue its last clear keyframe mapped. Keyframes made under the veil (flagged as such: tracking's, not
    // the dense map's) keep the map ahead of it; without them the map ran out under the smoke and the written
    // trajectory was 2.8 mm off by the time it cleared.
    let colon = bdis_synth::colon::Colon::default();
    let truth = |i: usize| colon.forward_pose(i as f64 / 30.0, 20.0);
    let frames = 70;
    let smoke = bdis_synth::smoke::Smoke {
        hold_s: 1.0,
        clear_s: 0.5,
        peak: 0.6,
        ..bdis_synth::smoke::Smoke::cavity_puff(1.0 / 3.0, colon.radius_mm, &truth(10), 7)
    };
    let mut tracker = colon_tracker();
    let results: Vec<FrameResult> = smoky_colon_flight(frames, &smoke)
        .iter()
        .enumerate()
        .map(|(i, (l, r))| match tracker.track(i as u64 * 33_333_333, l, r) {
            Ok(result) => result,
            Err(e) => panic!("frame {i}: {e}"),
        })
        .collect();
    let veiled: Vec<usize> = (0..frames).filter(|&i| doubted_for_contrast(&results[i])).collect();
    assert!(veiled.len() >= 10, "the smoke veiled {veiled:?}");
    for (i, r) in results.iter().enumerate() {
        assert_ne!(r.state, TrackingState::Lost, "frame {i}: {:?}", r.quality);
    }
    let map = tracker.map();
    let made_veiled: Vec<_> = veiled.iter().filter_map(|&i| results[i].new_keyframe).collect();
    assert!(!made_veiled.is_empty(), "no keyframe under the veil");
    assert!(made_veiled.iter().all(|&k| map.keyframes[k].veiled));
    assert!(
        results
            .iter()
            .filter(|r| !doubted_for_contrast(r))
            .filter_map(|r| r.new_keyframe)
            .all(|k| !map.keyframes[k].veiled)
    );
    let after = veiled.last().copied().unwrap_or(frames) + 1;
    assert!(results[after..].iter().all(|r| r.state == TrackingState::Ok), "tracking resumed after the veil");
    // The written trajectory, frame by frame, within the clear flight's bound.
    let first = truth(0).inverse();
    for (i, (_, world_from_camera, _)) in tracker.trajectory().iter().enumerate() {
        let error = (world_from_camera.translation.vector - (first * truth(i)).translation.vector).norm();
        assert!(error < 0.2, "frame {i}: {error:.3} mm off");
    }
}

#[test]
fn a_hover_under_smoke_makes_no_keyframe_that_adds_nothing() {
    // A laparoscope hovering over the abdominal wall while a cloud comes down, hangs and clears. The haze takes
    // the close points' matches away, which ORB-SLAM2's close-points rule reads as tissue the map lacks. But a
    // keyframe under a veil takes a new point only where the last clear keyframe saw the same tissue
    // (`create_keyframe`), and over this hover's haze none passes: each keyframe made there would cost local
    // mapping and an adjustment on the haze's shifted measurements and add nothing. It was one a frame.
    let abdomen = bdis_synth::abdomen::Abdomen::default();
    let frames = 60;
    let truth = |i: usize| abdomen.hover_pose(i as f64 / 30.0);
    let smoke = bdis_synth::smoke::Smoke {
        hold_s: 0.7,
        clear_s: 0.4,
        ..bdis_synth::smoke::Smoke::cavity_puff(0.3, 65.0, &truth(9), 5)
    };
    let mut tracker = colon_tracker();
    let mut results = Vec::with_capacity(frames);
    for i in 0..frames {
        let (left, right) = common::abdomen_pair_through(&abdomen, &truth(i), i as u64, smoke.haze_at(i as f64 / 30.0));
        match tracker.track(i as u64 * 33_333_333, &left, &right) {
            Ok(result) => results.push(result),
            Err(e) => panic!("frame {i}: {e}"),
        }
    }
    let veiled: Vec<usize> = (0..frames).filter(|&i| doubted_for_contrast(&results[i])).collect();
    assert!(veiled.len() >= 10, "the smoke veiled {veiled:?}");
    assert!(results.iter().all(|r| r.state != TrackingState::Lost));
    let map = tracker.map();
    for &i in &veiled {
        if let Some(k) = results[i].new_keyframe {
            let added = map.points.iter().filter(|p| p.first_kf == k).count();
            assert!(added > 0, "frame {i}: keyframe {k} made under the veil added no point");
        }
    }
}
