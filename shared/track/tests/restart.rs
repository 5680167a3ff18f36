//! Lost in tissue the map does not hold: the rendered colon flight goes dark for two seconds (a covered lens, a
//! burst of smoke no contrast survives) while the scope flies on 40 mm into new tissue. Relocalisation looks for
//! known places only, so before this change the tracker stayed lost to the end. Now, once relocalisation has had
//! its chance, a new map segment begins where the motion before the loss puts the scope: tracked from there on,
//! right relative to itself, and flagged `Detached` (never `Ok`) while it is not tied back to the first map; when
//! the scope comes back to tissue of the first map, it is found again and the frames there are `Ok`.

mod common;

use bdis_track::{Doubt, PoseMethod, RESTART_AFTER_S, TrackingState};
use common::{colon_frame, colon_tracker};
use nalgebra::Isometry3;

const FPS: f64 = 30.0;
/// Frames of the flight seen before the lens goes dark, and how many frames it stays dark.
const SEEN: usize = 20;
const DARK: usize = 60;
/// Frames seen after the dark.
const AFTER: usize = 24;

#[test]
fn a_scope_lost_in_new_tissue_goes_on_detached_where_it_was_heading_until_it_finds_the_first_map() {
    let colon = bdis_synth::colon::Colon::default();
    let truth = |i: usize| colon.forward_pose(i as f64 / FPS, 20.0);
    let mut tracker = colon_tracker();
    let dark = vec![0u8; 320 * 240];
    let mut results = Vec::new();
    for i in 0..SEEN + DARK + AFTER {
        let t_ns = (i as f64 / FPS * 1e9).round() as u64;
        let result = if (SEEN..SEEN + DARK).contains(&i) {
            tracker.track(t_ns, &dark, &dark)
        } else {
            let (left, right) = colon_frame(i);
            tracker.track(t_ns, &left, &right)
        };
        match result {
            Ok(r) => results.push(r),
            Err(e) => panic!("frame {i}: {e}"),
        }
    }
    assert!(results[..SEEN].iter().all(|r| r.state == TrackingState::Ok), "the flight is tracked before the dark");
    assert!(results[SEEN..SEEN + DARK].iter().all(|r| r.state == TrackingState::Lost), "nothing to see is lost");
    // Relocalisation gets RESTART_AFTER_S of frames it could place, then the segment begins.
    let back = SEEN + DARK;
    assert!(results.iter().all(|r| !r.new_segment || r.new_keyframe.is_some()));
    let restart = results[back..].iter().position(|r| r.new_segment).map(|k| back + k);
    let Some(restart) = restart else { panic!("no new segment: {:?}", results[back..].iter().map(|r| r.state)) };
    assert_eq!(
        restart - back + 1,
        (RESTART_AFTER_S * FPS).round() as usize,
        "the segment begins when relocalisation has had its time"
    );
    let first = &results[restart];
    assert_eq!(first.state, TrackingState::Uncertain);
    assert_eq!(first.quality.doubt, Some(Doubt::Detached));
    assert_eq!(first.quality.method, PoseMethod::Prediction);
    // From there every frame is tracked, and none is `Ok`: nothing ties the segment to the first map.
    for (i, r) in results.iter().enumerate().skip(restart) {
        assert_eq!(r.state, TrackingState::Uncertain, "frame {i}: {:?}", r.quality);
        assert_eq!(r.quality.doubt, Some(Doubt::Detached), "frame {i}");
    }
    assert!(results[restart + 1..].iter().any(|r| r.new_keyframe.is_some()), "the segment grows keyframes");

    // The tracker's world is its first camera.
    let world_from_truth = truth(0).inverse();
    let truth_in_world = |i: usize| world_from_truth * truth(i);
    let written = tracker.trajectory();
    let pose = |i: usize| -> Isometry3<f64> { written[i].1 };
    // The segment is placed where the flight was heading: where the true motion of the last 0.2 s before the
    // dark, carried on (its mean twist: the camera moving on along the arc it was turning on), would put the
    // scope. The path's bend changes, so that is not where it is (4 mm off here, and 11 mm off for the straight
    // line): the dead reckoning's error is the path's, not the tracker's. Standing still or starting over at
    // the origin would be 40 mm off.
    let heading = {
        let (a, b) = (truth_in_world(SEEN - 7).inverse(), truth_in_world(SEEN - 1).inverse());
        let per_frame = bdis_track::loop_closing::log_se3(&(b * a.inverse())) / 6.0;
        let frames = (restart - (SEEN - 1)) as f64;
        (bdis_track::geometry::exp_se3(&(per_frame * frames)) * b).inverse().translation.vector
    };
    let travelled = (heading - truth_in_world(SEEN - 1).translation.vector).norm();
    let placed = (pose(restart).translation.vector - heading).norm();
    assert!(placed < 0.05 * travelled, "the segment begins {placed:.2} mm from its heading after {travelled:.1} mm");
    // Within the segment the motion is right: each frame relative to the segment's first, against the truth.
    for i in restart + 1..results.len() {
        let moved = pose(restart).inverse() * pose(i);
        let truly = truth_in_world(restart).inverse() * truth_in_world(i);
        let error = (moved.translation.vector - truly.translation.vector).norm();
        let flown = truly.translation.vector.norm();
        // The flight moves 0.67 mm a frame; tracking within the segment is as good as on the first map.
        assert!(error < 0.2 + 0.01 * flown, "frame {i}: {error:.3} mm off over {flown:.1} mm in the segment");
        assert!(moved.rotation.angle_to(&truly.rotation).to_degrees() < 0.5, "frame {i}");
    }

    // The scope is pulled back to where the flight began (frames 5–14 again): relocalisation finds the first map,
    // and the frames on it are no longer detached.
    let t_back = results.len();
    let mut again = Vec::new();
    for (k, i) in (5..15).enumerate() {
        let t_ns = ((t_back + k) as f64 / FPS * 1e9).round() as u64;
        let (left, right) = colon_frame(i);
        match tracker.track(t_ns, &left, &right) {
            Ok(r) => again.push((i, r)),
            Err(e) => panic!("frame {i} again: {e}"),
        }
    }
    let Some(found) = again.iter().position(|(_, r)| r.relocalised) else {
        panic!("the first map was not found again: {:?}", again.iter().map(|(_, r)| r.state).collect::<Vec<_>>())
    };
    for (i, r) in &again[found..] {
        assert_eq!(r.state, TrackingState::Ok, "frame {i} again: {:?}", r.quality);
        let (Some(now), Some(then)) = (r.camera_from_world, results[*i].camera_from_world) else {
            panic!("frame {i}: no pose")
        };
        let moved = (now.inverse().translation.vector - then.inverse().translation.vector).norm();
        assert!(moved < 0.5, "frame {i} again: {moved:.3} mm from where it was tracked the first time");
    }
    tracker.finish();
}

/// A cut, then the flight back: the colon flight's frames 0–29, then 75–90 (the view jumps 30 mm on: a stall or
/// a cut in a recording), then back from 90 to 0 over the tissue of both. The cut is lost and a detached
/// segment begins where the motion before it leads, 30 mm short of the truth, so on the way back the segment's
/// guessed place lies over the first map's tissue. Map reuse searched the first map's points from that guess
/// and matched some by chance; with them a "loop" was closed across the seam, the segment was taken for tied
/// back, and the frames flown back were `Ok` 30 mm off (29 of them). Now the first map's points are not searched
/// from a detached segment's guess: it stays `detached` until the loop's 3-D check, which matches by
/// appearance, finds the first map, and the correction puts it where it is.
#[test]
fn a_segment_flown_back_over_the_first_map_is_tied_back_by_appearance_not_by_chance() {
    const SEEN: usize = 30;
    const CUT_FROM: usize = 75;
    const CUT_TO: usize = 90;
    let order: Vec<usize> = (0..SEEN).chain(CUT_FROM..=CUT_TO).chain((0..=CUT_TO).rev()).collect();
    let mut frames: Vec<Option<(Vec<u8>, Vec<u8>)>> = vec![None; CUT_TO + 1];
    let mut tracker = colon_tracker();
    let colon = bdis_synth::colon::Colon::default();
    let truth = |i: usize| colon.forward_pose(i as f64 / FPS, 20.0);
    let world_from_truth = truth(0).inverse();
    let mut results = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        let (left, right) = frames[i].get_or_insert_with(|| colon_frame(i));
        let t_ns = (k as f64 / FPS * 1e9).round() as u64;
        let r = tracker.track(t_ns, left, right).unwrap_or_else(|e| panic!("frame {i}: {e}"));
        let error = r
            .camera_from_world
            .map(|p| (p.inverse().translation.vector - (world_from_truth * truth(i)).translation.vector).norm());
        results.push((i, r.state, r.quality.doubt, error));
    }
    tracker.finish();
    for &(i, state, doubt, error) in &results[SEEN..] {
        if state == TrackingState::Ok {
            let error = error.unwrap_or(f64::INFINITY);
            assert!(error < 0.5, "flight frame {i}: Ok {error:.1} mm off ({doubt:?})");
        }
    }
    assert!(results[SEEN..].iter().any(|r| r.2 == Some(Doubt::Detached)), "the cut begins a segment");
    // Back over the first map's tissue, the segment is tied back and right.
    let last = &results[results.len() - 10..];
    assert!(last.iter().all(|r| r.1 == TrackingState::Ok), "not tied back at the end: {last:?}");
}

/// A cut on a circle over the abdominal wall: 30 frames (45 mm of the lap) are missing. The segment begun after
/// it is placed where the motion before the cut leads, 45 mm from where the scope is, and the older map's places
/// its guessed pose names are not where the scope is when the lap comes back over the start. Before this change
/// the segment stayed detached to the end, and its half of the trajectory 45 mm off. Now, while detached, each
/// new keyframe is also checked against the older map's keyframes most like it, and two consecutive keyframes
/// that agree on where the segment lies tie it back: the whole segment moves onto the first map.
#[test]
fn a_segment_placed_far_off_is_found_again_by_appearance_when_the_scope_comes_back() {
    const SPEED_MM_S: f64 = 45.0;
    const SEEN: usize = 60;
    const CUT: usize = 30;
    let lap = (2.0 * std::f64::consts::PI * bdis_synth::abdomen::CIRCLE_RADIUS_MM / SPEED_MM_S * FPS).ceil() as usize;
    // The lap, the cut left out, and on past the start over the first map's tissue.
    let order: Vec<usize> = (0..SEEN).chain(SEEN + CUT..lap + SEEN / 2).collect();
    let abdomen = bdis_synth::abdomen::Abdomen::default();
    let truth = |i: usize| abdomen.circle_pose(i as f64 / FPS, SPEED_MM_S);
    let world_from_truth = truth(0).inverse();
    let mut tracker = colon_tracker();
    let mut results = Vec::new();
    let mut flown_mm = 0.0;
    for (k, &i) in order.iter().enumerate() {
        let (left, right) = common::abdomen_pair(&abdomen, &truth(i), i as u64);
        let t_ns = (k as f64 / FPS * 1e9).round() as u64;
        let r = tracker.track(t_ns, &left, &right).unwrap_or_else(|e| panic!("frame {i}: {e}"));
        if k > 0 {
            flown_mm += (truth(i).translation.vector - truth(order[k - 1]).translation.vector).norm();
        }
        let error = r
            .camera_from_world
            .map(|p| (p.inverse().translation.vector - (world_from_truth * truth(i)).translation.vector).norm());
        results.push((i, r.state, r.quality.doubt, error, flown_mm));
    }
    tracker.finish();
    let detached = results.iter().filter(|r| r.2 == Some(Doubt::Detached)).count();
    assert!(detached > 0, "the cut begins a segment");
    // Where an `Ok` frame must be: half a millimetre, and 0.5 % of the way flown for the drift it may carry.
    let within_ok_bound = |error_mm: f64, flown_mm: f64| error_mm < 0.005 * flown_mm + 0.5;
    for &(i, state, doubt, error, flown) in &results {
        if state == TrackingState::Ok {
            let error = error.unwrap_or(f64::INFINITY);
            assert!(within_ok_bound(error, flown), "frame {i}: Ok {error:.2} mm off after {flown:.0} mm ({doubt:?})");
        }
    }
    // Back over the start, the segment is tied back: none of the last frames is detached or lost, each is where
    // an `Ok` frame must be, and the last ones are `Ok`. Between, the tie-back's correction may still be settling
    // the map (`MapMoving`, an honest doubt: with the tracker's influence check the tie-back came at frame 178,
    // four frames sooner than without, and the map settled by 189), and every frame of the segment, those tracked
    // before the tie-back included, is where it was in the trajectory the run writes.
    let last = &results[results.len() - 10..];
    let tied_back = |r: &(usize, TrackingState, Option<Doubt>, Option<f64>, f64)| {
        r.2 != Some(Doubt::Detached)
            && matches!(r.1, TrackingState::Ok | TrackingState::Uncertain)
            && r.3.is_some_and(|e| within_ok_bound(e, r.4))
    };
    assert!(last.iter().all(tied_back), "not tied back at the end: {last:?}");
    assert!(last[5..].iter().all(|r| r.1 == TrackingState::Ok), "not settled at the end: {last:?}");
    let trajectory = tracker.trajectory();
    let segment_errors: Vec<f64> = results
        .iter()
        .zip(&trajectory)
        .filter(|(r, _)| r.2 == Some(Doubt::Detached))
        .map(|(r, (_, world_from_camera, _))| {
            (world_from_camera.translation.vector - (world_from_truth * truth(r.0)).translation.vector).norm()
        })
        .collect();
    let worst = segment_errors.iter().copied().fold(0.0, f64::max);
    eprintln!("{detached} detached frames, worst of them in the trajectory {worst:.2} mm");
    assert!(worst < 0.005 * flown_mm, "a detached frame is {worst:.1} mm off in the trajectory");
}
