//! Trajectory error: association by timestamp, SE(3) alignment (Umeyama without scale), ATE and RPE.

use bdis_core::geometry::StampedPose;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::Stats;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrajError {
    #[error("only {pairs} pose pairs matched by timestamp (within {max_dt_s} s); need at least 3")]
    TooFewPairs { pairs: usize, max_dt_s: f64 },
    #[error("the matched positions are degenerate (all on one point or line): the alignment is undefined")]
    Degenerate,
}

/// Pairs (gt index, est index) whose timestamps differ by at most `max_dt_s`, each pose used once, in time order.
pub fn associate(gt: &[StampedPose], est: &[StampedPose], max_dt_s: f64) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    let mut used = vec![false; gt.len()];
    for (j, e) in est.iter().enumerate() {
        // Nearest ground-truth time (gt sorted by time, as trajectory files are).
        let k = gt.partition_point(|g| g.t_s < e.t_s);
        let best = [k.checked_sub(1), Some(k)]
            .into_iter()
            .flatten()
            .filter(|&i| i < gt.len() && !used[i])
            .min_by(|&a, &b| (gt[a].t_s - e.t_s).abs().total_cmp(&(gt[b].t_s - e.t_s).abs()));
        if let Some(i) = best
            && (gt[i].t_s - e.t_s).abs() <= max_dt_s
        {
            used[i] = true;
            pairs.push((i, j));
        }
    }
    pairs
}

/// The rigid transform `dst_from_src` minimising Σ‖dst − (R·src + t)‖² (Umeyama 1991, no scale).
pub fn umeyama_se3(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Result<Isometry3<f64>, TrajError> {
    umeyama(src, dst).map(|fit| fit.rigid())
}

/// The similarity `dst_from_src` minimising Σ‖dst − (s·R·src + t)‖² (Umeyama 1991 with scale), as
/// (R and t, s): the point maps to `s · (R·src) + t`, so `rigid * src` is not the fit unless s = 1.
pub fn umeyama_sim3(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Result<(Isometry3<f64>, f64), TrajError> {
    umeyama(src, dst).map(|fit| fit.similarity())
}

/// One decomposition of the positions' cross-covariance, which both alignments are read from: the rotation
/// is the same with or without a scale, only the translation differs.
struct UmeyamaFit {
    r: Matrix3<f64>,
    src_mean: Vector3<f64>,
    dst_mean: Vector3<f64>,
    scale: f64,
}

impl UmeyamaFit {
    fn rotation(&self) -> UnitQuaternion<f64> {
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(self.r))
    }

    fn rigid(&self) -> Isometry3<f64> {
        Isometry3::from_parts(Translation3::from(self.dst_mean - self.r * self.src_mean), self.rotation())
    }

    fn similarity(&self) -> (Isometry3<f64>, f64) {
        let t = self.dst_mean - self.scale * (self.r * self.src_mean);
        (Isometry3::from_parts(Translation3::from(t), self.rotation()), self.scale)
    }
}

fn umeyama(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Result<UmeyamaFit, TrajError> {
    let n = src.len().min(dst.len());
    if n < 3 {
        return Err(TrajError::TooFewPairs { pairs: n, max_dt_s: f64::NAN });
    }
    let mean = |p: &[Point3<f64>]| p.iter().fold(Vector3::zeros(), |acc, q| acc + q.coords) / n as f64;
    let (ms, md) = (mean(&src[..n]), mean(&dst[..n]));
    let mut cov = Matrix3::zeros();
    let mut src_variance = 0.0;
    for (s, d) in src.iter().zip(dst) {
        cov += (d.coords - md) * (s.coords - ms).transpose();
        src_variance += (s.coords - ms).norm_squared();
    }
    cov /= n as f64;
    src_variance /= n as f64;
    let svd = cov.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else { return Err(TrajError::Degenerate) };
    // Rank < 2 leaves the rotation about the line undetermined.
    let mut sv = svd.singular_values;
    sv.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if sv[1] <= 1e-12 * sv[0].max(1e-300) {
        return Err(TrajError::Degenerate);
    }
    let mut s = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let r = u * s * v_t;
    // The scale is tr(D·S)/σ²_src; `svd` sorts the singular values in decreasing order, so the sign flip goes
    // with the last.
    let d = svd.singular_values;
    let scale = (d[0] + d[1] + s[(2, 2)] * d[2]) / src_variance;
    Ok(UmeyamaFit { r, src_mean: ms, dst_mean: md, scale })
}

/// Absolute trajectory error after alignment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Ate {
    /// Translation error statistics in the trajectory's unit.
    pub translation: Stats,
    /// `gt_from_est`: the alignment applied to the estimate.
    pub alignment_translation: [f64; 3],
    pub alignment_rotation_deg: f64,
    pub pairs: usize,
    /// The same positions under a similarity alignment (`evo_ape -as`): what is left when the estimate's
    /// scale is forgiven, and that scale.
    pub sim3: Sim3Fit,
}

/// A trajectory fitted to the ground truth with a scale as well as a rigid motion. Stereo fixes the scale, so a
/// `est_over_gt` off 1 is an error of the estimate (a biased depth, or rotation traded for translation), not
/// a freedom; it is reported to tell a scale error from drift: the SE(3) ATE of a trajectory 0.5 % too large
/// grows with the size of the path, the Sim(3) one does not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sim3Fit {
    /// How much larger the estimate is than the ground truth (1.005: 0.5 % too large).
    pub est_over_gt: f64,
    /// Translation error after the similarity alignment, in the ground truth's unit.
    pub translation: Stats,
}

/// Relative pose error over a fixed time step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Rpe {
    pub delta_s: f64,
    /// Translation drift per step, in the trajectory's unit.
    pub translation: Stats,
    /// Rotation drift per step, degrees.
    pub rotation_deg: Stats,
    /// Σ of the estimate's step lengths over Σ of the ground truth's, over the same steps: the estimate's
    /// local scale (1.005: each step 0.5 % too long). Noise lengthens a step by about σ²/(2·length), so it
    /// reads true only where steps are long against the noise (as at the default 1 s).
    pub length_ratio: f64,
}

/// Camera positions of time-matched poses: (estimate, ground truth).
type MatchedPositions = (Vec<Point3<f64>>, Vec<Point3<f64>>);

/// The camera positions of the time-matched poses `pairs` (from [`associate`] with `max_dt_s`), at least 3.
fn matched_positions(
    gt: &[StampedPose],
    est: &[StampedPose],
    pairs: &[(usize, usize)],
    max_dt_s: f64,
) -> Result<MatchedPositions, TrajError> {
    if pairs.len() < 3 {
        return Err(TrajError::TooFewPairs { pairs: pairs.len(), max_dt_s });
    }
    let src = pairs.iter().map(|&(_, j)| Point3::from(est[j].world_from_camera.translation.vector)).collect();
    let dst = pairs.iter().map(|&(i, _)| Point3::from(gt[i].world_from_camera.translation.vector)).collect();
    Ok((src, dst))
}

/// `gt_from_est`: the SE(3) alignment of `est` onto `gt` that the ATE uses (e.g. to bring a map built with the
/// estimated poses into the ground truth's frame).
pub fn align_se3(gt: &[StampedPose], est: &[StampedPose], max_dt_s: f64) -> Result<Isometry3<f64>, TrajError> {
    let (src, dst) = matched_positions(gt, est, &associate(gt, est, max_dt_s), max_dt_s)?;
    umeyama_se3(&src, &dst)
}

/// `gt_from_est` from the first pose both trajectories share: the estimate's world is where its first frame
/// was, and this puts it where the ground truth has that frame, without a fit. For a map built along a short
/// path (a hover of a few millimetres), where a fit of positions alone leaves the rotation loose and a degree
/// of it moves a map 55 mm away by a millimetre.
pub fn align_first(gt: &[StampedPose], est: &[StampedPose], max_dt_s: f64) -> Result<Isometry3<f64>, TrajError> {
    let pairs = associate(gt, est, max_dt_s);
    let Some(&(i, j)) = pairs.first() else { return Err(TrajError::TooFewPairs { pairs: 0, max_dt_s }) };
    Ok(gt[i].world_from_camera * est[j].world_from_camera.inverse())
}

/// ATE of `est` against `gt` after SE(3) alignment (`evo_ape tum gt est -a`).
pub fn ate(gt: &[StampedPose], est: &[StampedPose], max_dt_s: f64) -> Result<Ate, TrajError> {
    let (src, dst) = matched_positions(gt, est, &associate(gt, est, max_dt_s), max_dt_s)?;
    let fit = umeyama(&src, &dst)?;
    let gt_from_est = fit.rigid();
    let mut errors: Vec<f64> = src.iter().zip(&dst).map(|(s, d)| (d - gt_from_est * s).norm()).collect();
    let (rigid, scale) = fit.similarity();
    let mut sim3_errors: Vec<f64> = src
        .iter()
        .zip(&dst)
        .map(|(s, d)| (d.coords - (scale * (rigid.rotation * s.coords) + rigid.translation.vector)).norm())
        .collect();
    Ok(Ate {
        translation: Stats::of(&mut errors),
        alignment_translation: gt_from_est.translation.vector.into(),
        alignment_rotation_deg: gt_from_est.rotation.angle().to_degrees(),
        pairs: src.len(),
        sim3: Sim3Fit { est_over_gt: 1.0 / scale, translation: Stats::of(&mut sim3_errors) },
    })
}

/// A matched pose's position error after the ATE's alignment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PositionError {
    /// The estimate's time stamp, seconds.
    pub t_s: f64,
    /// In the trajectory's unit.
    pub error: f64,
}

/// The error of every matched pose of `est` after the SE(3) alignment [`ate`] uses, in the estimate's time order:
/// where along the path the ATE comes from.
pub fn position_errors(
    gt: &[StampedPose],
    est: &[StampedPose],
    max_dt_s: f64,
) -> Result<Vec<PositionError>, TrajError> {
    let pairs = associate(gt, est, max_dt_s);
    let (src, dst) = matched_positions(gt, est, &pairs, max_dt_s)?;
    let gt_from_est = umeyama_se3(&src, &dst)?;
    Ok(pairs
        .iter()
        .zip(src.iter().zip(&dst))
        .map(|(&(_, j), (s, d))| PositionError { t_s: est[j].t_s, error: (d - gt_from_est * s).norm() })
        .collect())
}

/// RPE over steps of `delta_s` seconds between matched poses (each pose paired with the first one at least
/// `delta_s` later).
pub fn rpe(gt: &[StampedPose], est: &[StampedPose], max_dt_s: f64, delta_s: f64) -> Result<Rpe, TrajError> {
    let pairs = associate(gt, est, max_dt_s);
    if pairs.len() < 3 {
        return Err(TrajError::TooFewPairs { pairs: pairs.len(), max_dt_s });
    }
    let (mut trans, mut rot) = (Vec::new(), Vec::new());
    let (mut est_length, mut gt_length) = (0.0, 0.0);
    for (a, &(ga, ea)) in pairs.iter().enumerate() {
        let t0 = est[ea].t_s;
        let Some(&(gb, eb)) = pairs[a + 1..].iter().find(|&&(_, e)| est[e].t_s - t0 >= delta_s - 1e-9) else { break };
        let gt_rel = gt[ga].world_from_camera.inverse() * gt[gb].world_from_camera;
        let est_rel = est[ea].world_from_camera.inverse() * est[eb].world_from_camera;
        let err = gt_rel.inverse() * est_rel;
        trans.push(err.translation.vector.norm());
        est_length += est_rel.translation.vector.norm();
        gt_length += gt_rel.translation.vector.norm();
        rot.push(err.rotation.angle().to_degrees());
    }
    Ok(Rpe {
        delta_s,
        translation: Stats::of(&mut trans),
        rotation_deg: Stats::of(&mut rot),
        length_ratio: est_length / gt_length,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A wavy 3-D path, one pose per 0.05 s.
    fn gt_path(n: usize) -> Vec<StampedPose> {
        (0..n)
            .map(|i| {
                let t = i as f64 * 0.05;
                StampedPose {
                    t_s: t,
                    world_from_camera: Isometry3::new(
                        Vector3::new(10.0 * t, 3.0 * (t * 1.3).sin(), 2.0 * (t * 0.7).cos()),
                        Vector3::new(0.1 * t, 0.2 * (t).sin(), 0.05),
                    ),
                }
            })
            .collect()
    }

    /// Deterministic Gaussian noise (Box–Muller over a fixed LCG).
    struct Noise(u64);
    impl Noise {
        fn uniform(&mut self) -> f64 {
            self.0 = self.0.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
            ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }
        fn gauss(&mut self) -> f64 {
            (-2.0 * self.uniform().ln()).sqrt() * (std::f64::consts::TAU * self.uniform()).cos()
        }
    }

    #[test]
    fn the_first_pose_places_an_estimate_exactly_where_a_fit_of_a_short_path_tilts_it() {
        // A hover: a few millimetres of path whose positions hardly fix a rotation, estimated with 0.3 mm of
        // noise in a frame of its own (the first camera's).
        let gt: Vec<StampedPose> = (0..90)
            .map(|i| {
                let t = i as f64 / 30.0;
                StampedPose {
                    t_s: t,
                    world_from_camera: Isometry3::new(
                        Vector3::new(2.0 * (0.6 * t).sin(), 1.5 * (0.45 * t).cos(), 15.0),
                        Vector3::new(0.05 * (0.7 * t).sin(), 0.04 * (0.5 * t).cos(), 0.0),
                    ),
                }
            })
            .collect();
        let first_inv = gt[0].world_from_camera.inverse();
        let mut noise = Noise(7);
        let est: Vec<StampedPose> = gt
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let mut pose = first_inv * p.world_from_camera;
                if i > 0 {
                    pose.translation.vector += Vector3::new(noise.gauss(), noise.gauss(), noise.gauss()) * 0.3;
                }
                StampedPose { t_s: p.t_s, world_from_camera: pose }
            })
            .collect();
        let by_first = align_first(&gt, &est, 0.01).unwrap();
        assert!((by_first.to_homogeneous() - gt[0].world_from_camera.to_homogeneous()).abs().max() < 1e-12);
        // A point of the tissue 55 mm in front of the first camera lands where it is under the first pose; the
        // fit of the noisy positions turns it by a degree or more.
        let tissue = nalgebra::Point3::new(0.0, 0.0, 55.0);
        let truth = gt[0].world_from_camera * tissue;
        let by_fit = align_se3(&gt, &est, 0.01).unwrap();
        assert!((by_first * tissue - truth).norm() < 1e-9);
        assert!((by_fit * tissue - truth).norm() > 0.5, "{}", (by_fit * tissue - truth).norm());
        assert!(align_first(&gt, &[], 0.01).is_err());
    }

    #[test]
    fn a_rigidly_moved_copy_has_zero_error_and_the_motion_is_recovered() {
        let gt = gt_path(200);
        let moved = Isometry3::new(Vector3::new(5.0, -2.0, 1.0), Vector3::new(0.3, -0.2, 0.9));
        let est: Vec<StampedPose> =
            gt.iter().map(|p| StampedPose { t_s: p.t_s, world_from_camera: moved * p.world_from_camera }).collect();
        let a = ate(&gt, &est, 0.01).unwrap();
        assert!(a.translation.rmse < 1e-9, "{a:?}");
        assert!((a.alignment_rotation_deg - moved.rotation.angle().to_degrees()).abs() < 1e-6);
        assert!((a.sim3.est_over_gt - 1.0).abs() < 1e-9 && a.sim3.translation.rmse < 1e-9, "{a:?}");
        let r = rpe(&gt, &est, 0.01, 1.0).unwrap();
        assert!(r.translation.max < 1e-9 && r.rotation_deg.max < 1e-6);
        assert!((r.length_ratio - 1.0).abs() < 1e-9);
    }

    #[test]
    fn injected_noise_of_known_rms_gives_that_ate() {
        let gt = gt_path(4000);
        let sigma = 0.05; // per axis: the expected 3-D RMS is σ·√3
        let mut noise = Noise(7);
        let est: Vec<StampedPose> = gt
            .iter()
            .map(|p| {
                let mut q = p.world_from_camera;
                q.translation.vector += Vector3::new(noise.gauss(), noise.gauss(), noise.gauss()) * sigma;
                StampedPose { t_s: p.t_s + 0.002, world_from_camera: q }
            })
            .collect();
        let a = ate(&gt, &est, 0.01).unwrap();
        let expected = sigma * 3f64.sqrt();
        assert_eq!(a.pairs, 4000);
        assert!((a.translation.rmse - expected).abs() < 0.03 * expected, "{} vs {expected}", a.translation.rmse);
        // Per pose, the same errors: in the estimate's time order, and their RMS is the ATE.
        let each = position_errors(&gt, &est, 0.01).unwrap();
        assert_eq!(each.len(), 4000);
        assert!(each.windows(2).all(|w| w[0].t_s < w[1].t_s) && each[0].t_s == est[0].t_s);
        let rms = (each.iter().map(|e| e.error * e.error).sum::<f64>() / each.len() as f64).sqrt();
        assert!((rms - a.translation.rmse).abs() < 1e-12, "{rms} vs {}", a.translation.rmse);
    }

    #[test]
    fn a_scaled_trajectory_cannot_be_aligned_away() {
        // Scaling about the centroid by s: the best rigid alignment is the identity, and the ATE RMSE is
        // |s − 1| times the RMS distance of the positions from their centroid.
        let gt = gt_path(300);
        let c = gt.iter().fold(Vector3::zeros(), |a, p| a + p.world_from_camera.translation.vector) / gt.len() as f64;
        let s = 1.1;
        let est: Vec<StampedPose> = gt
            .iter()
            .map(|p| {
                let mut q = p.world_from_camera;
                q.translation.vector = c + (q.translation.vector - c) * s;
                StampedPose { t_s: p.t_s, world_from_camera: q }
            })
            .collect();
        let rms = (gt.iter().map(|p| (p.world_from_camera.translation.vector - c).norm_squared()).sum::<f64>()
            / gt.len() as f64)
            .sqrt();
        let a = ate(&gt, &est, 0.01).unwrap();
        assert!(
            (a.translation.rmse - (s - 1.0) * rms).abs() < 1e-9 * rms,
            "{} vs {}",
            a.translation.rmse,
            (s - 1.0) * rms
        );
        assert!(a.alignment_rotation_deg < 1e-6);
        // The similarity fit takes the scale out, and says what it was; each step is s times as long.
        assert!((a.sim3.est_over_gt - s).abs() < 1e-9 && a.sim3.translation.rmse < 1e-9, "{:?}", a.sim3);
        assert!((rpe(&gt, &est, 0.01, 1.0).unwrap().length_ratio - s).abs() < 1e-9);
    }

    #[test]
    fn a_scaled_and_moved_trajectory_is_fitted_whole_by_the_similarity() {
        // Scale about another point, then a rigid motion with a turn of more than 90°: the fit must find all
        // three, and its error must be the noise's, not the scale's.
        let gt = gt_path(600);
        let moved = Isometry3::new(Vector3::new(-40.0, 7.0, 3.0), Vector3::new(0.4, 1.9, -0.7));
        let mut noise = Noise(11);
        let sigma = 0.01;
        let est: Vec<StampedPose> = gt
            .iter()
            .map(|p| {
                let mut q = p.world_from_camera;
                q.translation.vector =
                    q.translation.vector * 0.995 + Vector3::new(noise.gauss(), noise.gauss(), noise.gauss()) * sigma;
                StampedPose { t_s: p.t_s, world_from_camera: moved * q }
            })
            .collect();
        let a = ate(&gt, &est, 0.01).unwrap();
        assert!((a.sim3.est_over_gt - 0.995).abs() < 1e-4, "{:?}", a.sim3);
        assert!((a.sim3.translation.rmse - sigma * 3f64.sqrt()).abs() < 0.1 * sigma * 3f64.sqrt(), "{:?}", a.sim3);
        assert!(a.translation.rmse > 3.0 * a.sim3.translation.rmse, "{a:?}");
    }

    #[test]
    fn too_few_or_degenerate_pairs_are_errors() {
        let gt = gt_path(10);
        let late: Vec<StampedPose> = gt.iter().map(|p| StampedPose { t_s: p.t_s + 100.0, ..*p }).collect();
        assert!(matches!(ate(&gt, &late, 0.01), Err(TrajError::TooFewPairs { pairs: 0, .. })));
        let line: Vec<StampedPose> = (0..10)
            .map(|i| StampedPose { t_s: i as f64, world_from_camera: Isometry3::translation(i as f64, 0.0, 0.0) })
            .collect();
        assert_eq!(ate(&line, &line, 0.01), Err(TrajError::Degenerate));
    }
}
