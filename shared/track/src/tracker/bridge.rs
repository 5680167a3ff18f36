//! The written trajectory across a veil (smoke). A frame seen through a veil is `Uncertain`: its measurements
//! are shifted by the haze blended into every patch, or there were too few to pose it and the motion model
//! coasted it. Live, that pose is the best there is and goes out flagged. Once the frames after the veil are
//! tracked again, the trajectory written at the end (which bundle adjustment's corrections also reach) bridges
//! the veil instead: the smoothest path between the clear frames on both sides, leaving each side at the
//! speed it was moving. The veiled frames' own poses are not weighed in: a veil's error is not noise that an
//! average would remove but a shift that follows the haze.

use nalgebra::{Isometry3, Translation3, Vector3};

/// The clear frames at each end of a veil whose motion gives the bridge its end velocities: long enough to
/// average a few frames' jitter, short enough to stay the motion of the moment.
const VELOCITY_WINDOW_S: f64 = 0.2;

/// Bridges every run of `veiled` frames, with the `hazy` frames just before it (the haze coming down, before
/// it was thick enough to doubt), that has a clear frame (neither veiled, hazy nor `lost`) on both sides.
/// The veil lifts only once the view is clear, so no hazy frame follows one. `t_s` are the frames' times (s),
/// `world_from_camera` their poses, rewritten in place.
pub(super) fn bridge_veils(
    t_s: &[f64],
    world_from_camera: &mut [Isometry3<f64>],
    veiled: &[bool],
    hazy: &[bool],
    lost: &[bool],
) {
    let n = t_s.len();
    let clear = |k: usize| !veiled[k] && !hazy[k] && !lost[k];
    let mut k = 0;
    while k < n {
        if !veiled[k] {
            k += 1;
            continue;
        }
        let mut start = k;
        while start > 0 && hazy[start - 1] && !veiled[start - 1] && !lost[start - 1] {
            start -= 1;
        }
        while k < n && veiled[k] {
            k += 1;
        }
        // Frames start..k are veiled; the bridge runs from start − 1 to k.
        if start == 0 || k == n || !clear(start - 1) || !clear(k) {
            continue;
        }
        let (a, b) = (start - 1, k);
        let position = |i: usize| world_from_camera[i].translation.vector;
        // The velocity on one side of the veil: the least-squares slope of position over time through the
        // clear frames within the window there (a slope through many frames, not a difference of two, so
        // the frames' own jitter does not bend the bridge).
        let velocity = |from: usize, towards_past: bool| -> Option<Vector3<f64>> {
            let mut far = from;
            loop {
                let next = if towards_past { far.checked_sub(1) } else { Some(far + 1).filter(|&j| j < n) };
                match next {
                    Some(j) if clear(j) && (t_s[j] - t_s[from]).abs() <= VELOCITY_WINDOW_S => far = j,
                    _ => break,
                }
            }
            let (lo, hi) = if towards_past { (far, from) } else { (from, far) };
            if hi - lo < 2 {
                return None;
            }
            let count = (hi - lo + 1) as f64;
            let t_mean = t_s[lo..=hi].iter().sum::<f64>() / count;
            let p_mean = (lo..=hi).map(position).sum::<Vector3<f64>>() / count;
            let (mut num, mut den) = (Vector3::zeros(), 0.0);
            for (j, &t) in (lo..=hi).zip(&t_s[lo..=hi]) {
                let dt = t - t_mean;
                num += (position(j) - p_mean) * dt;
                den += dt * dt;
            }
            (den > 0.0).then(|| num / den)
        };
        let span = t_s[b] - t_s[a];
        if span <= 0.0 {
            continue;
        }
        let chord = (position(b) - position(a)) / span;
        let (v_a, v_b) = (velocity(a, true).unwrap_or(chord), velocity(b, false).unwrap_or(chord));
        let (p_a, p_b) = (position(a), position(b));
        let (r_a, r_b) = (world_from_camera[a].rotation, world_from_camera[b].rotation);
        for i in start..k {
            let u = ((t_s[i] - t_s[a]) / span).clamp(0.0, 1.0);
            // Cubic Hermite: positions and velocities of both ends met.
            let (u2, u3) = (u * u, u * u * u);
            let p = p_a * (2.0 * u3 - 3.0 * u2 + 1.0)
                + v_a * (span * (u3 - 2.0 * u2 + u))
                + p_b * (3.0 * u2 - 2.0 * u3)
                + v_b * (span * (u3 - u2));
            let rotation = r_a.try_slerp(&r_b, u, 1e-9).unwrap_or(if u < 0.5 { r_a } else { r_b });
            world_from_camera[i] = Isometry3::from_parts(Translation3::from(p), rotation);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::UnitQuaternion;

    /// A camera moving at constant speed while turning steadily, sampled at 30 Hz.
    fn steady(k: usize) -> Isometry3<f64> {
        let t = k as f64 / 30.0;
        Isometry3::from_parts(
            Translation3::new(10.0 * t, -4.0 * t, 60.0 + 2.0 * t),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.05 * t, 0.02 * t)),
        )
    }

    #[test]
    fn a_veil_over_steady_motion_is_bridged_onto_the_motion_and_clear_frames_are_kept() {
        let n = 60;
        let t_s: Vec<f64> = (0..n).map(|k| k as f64 / 30.0).collect();
        let truth: Vec<Isometry3<f64>> = (0..n).map(steady).collect();
        let veiled: Vec<bool> = (0..n).map(|k| (20..35).contains(&k)).collect();
        // The veiled frames' poses are off by millimetres, alternately (the haze's shifts).
        let mut poses: Vec<Isometry3<f64>> = (0..n)
            .map(|k| {
                let off = if veiled[k] { if k % 2 == 0 { 1.5 } else { -1.0 } } else { 0.0 };
                Isometry3::from_parts(Translation3::new(off, 0.5 * off, 0.0), UnitQuaternion::identity()) * truth[k]
            })
            .collect();
        bridge_veils(&t_s, &mut poses, &veiled, &vec![false; n], &vec![false; n]);
        for k in 0..n {
            let error = (poses[k].translation.vector - truth[k].translation.vector).norm();
            assert!(error < 1e-9, "frame {k}: {error} mm off the steady motion");
            assert!(poses[k].rotation.angle_to(&truth[k].rotation) < 1e-9, "frame {k}");
        }
    }

    #[test]
    fn a_veil_without_a_clear_frame_on_both_sides_is_left_as_it_was() {
        let n = 20;
        let t_s: Vec<f64> = (0..n).map(|k| k as f64 / 30.0).collect();
        let original: Vec<Isometry3<f64>> =
            (0..n).map(|k| Isometry3::translation(if k % 3 == 0 { 1.0 } else { 0.0 }, 0.0, 0.0) * steady(k)).collect();
        // At the end of the sequence, and followed by a lost frame.
        for (veiled, lost) in [
            ((0..n).map(|k| k >= 15).collect::<Vec<_>>(), vec![false; n]),
            ((0..n).map(|k| (5..9).contains(&k)).collect(), (0..n).map(|k| k == 9).collect()),
            ((0..n).map(|k| k < 4).collect(), vec![false; n]),
        ] {
            let mut poses = original.clone();
            bridge_veils(&t_s, &mut poses, &veiled, &vec![false; n], &lost);
            assert_eq!(poses, original);
        }
    }
}
