use super::*;
use crate::geometry::exp_se3;
use nalgebra::{Isometry3, Vector3};

fn cam() -> RectifiedCamera {
    RectifiedCamera { fx: 520.0, fy: 520.0, cx: 320.0, cy: 240.0, bf: 2600.0, width: 640, height: 480 }
}

#[test]
fn jacobians_match_finite_differences() {
    let cam = cam();
    let pose = Isometry3::new(Vector3::new(1.0, -2.0, 3.0), Vector3::new(0.1, 0.2, -0.3));
    let x = pose.inverse() * Point3::new(4.0, -3.0, 40.0);
    for stereo in [true, false] {
        let obs = Observation { u: 300.0, v: 200.0, u_right: stereo.then_some(250.0), inv_sigma2: 1.0 };
        let residual = |t: &CameraFromWorld, p: &Point3<f64>| residual_and_jacobian(&cam, &(t * p), &obs).0;
        let jp = pose_jacobian(&cam, &pose, &x, &obs);
        let jl = point_jacobian(&cam, &pose, &x, &obs);
        let h = 1e-6;
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = h;
            let numeric = (residual(&(exp_se3(&d) * pose), &x) - residual(&(exp_se3(&(-d)) * pose), &x)) / (2.0 * h);
            assert!(
                (numeric - jp.column(k)).norm() < 1e-4 * (1.0 + numeric.norm()),
                "pose {k}: {numeric} vs {}",
                jp.column(k)
            );
        }
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let numeric = (residual(&pose, &(x + d)) - residual(&pose, &(x - d))) / (2.0 * h);
            assert!((numeric - jl.column(k)).norm() < 1e-5 * (1.0 + numeric.norm()), "point {k}");
        }
    }
}

/// Deterministic pseudo-random numbers in [−1, 1).
fn noise(state: &mut u64) -> f64 {
    *state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
    ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

/// Five cameras moving along a tissue-like wall 40–80 mm away, 300 points.
fn scene(seed: u64) -> (Vec<CameraFromWorld>, Vec<Point3<f64>>) {
    let mut s = seed;
    let poses = (0..5)
        .map(|i| {
            let world_from_camera = Isometry3::new(
                Vector3::new(4.0 * i as f64, 0.5 * i as f64, 1.0 * i as f64),
                Vector3::new(0.02 * i as f64, -0.03 * i as f64, 0.01 * i as f64),
            );
            world_from_camera.inverse()
        })
        .collect();
    let points = (0..300)
        .map(|_| Point3::new(30.0 * noise(&mut s) + 8.0, 22.0 * noise(&mut s), 60.0 + 20.0 * noise(&mut s)))
        .collect();
    (poses, points)
}

fn observe(
    cam: &RectifiedCamera,
    poses: &[CameraFromWorld],
    points: &[Point3<f64>],
    sigma_px: f64,
    seed: u64,
) -> Vec<BaEdge> {
    let mut s = seed;
    let mut edges = Vec::new();
    for (i, t) in poses.iter().enumerate() {
        for (p, x) in points.iter().enumerate() {
            let z = cam.project_stereo(&(t * x));
            if !cam.in_image(z.x, z.y) {
                continue;
            }
            // Gaussian-ish noise: sum of uniforms.
            let mut n = || (0..6).map(|_| noise(&mut s)).sum::<f64>() / 2.0_f64.sqrt() * sigma_px;
            let (du, dv) = (n(), n());
            let obs = Observation { u: z.x + du, v: z.y + dv, u_right: Some(z.z + du + n() * 0.3), inv_sigma2: 1.0 };
            edges.push(BaEdge { pose: i, point: p, obs, octave_chi2_scale: 1.0 });
        }
    }
    edges
}

#[test]
fn pose_only_optimisation_recovers_the_pose_and_rejects_outliers() {
    let cam = cam();
    let (poses, points) = scene(1);
    let truth = poses[2];
    let mut edges = observe(&cam, &[truth], &points, 0.5, 7);
    // 15 % gross outliers.
    let n_out = edges.len() * 15 / 100;
    for e in edges.iter_mut().take(n_out) {
        e.obs.u += 40.0;
    }
    let pts: Vec<Point3<f64>> = edges.iter().map(|e| points[e.point]).collect();
    let obs: Vec<Observation> = edges.iter().map(|e| e.obs).collect();
    let mut pose = Isometry3::new(Vector3::new(1.5, -1.0, 2.0), Vector3::new(0.03, -0.02, 0.04)) * truth;
    let mut outlier = vec![false; pts.len()];
    let inliers = PoseOptimizer::default().optimize(&cam, &mut pose, &pts, &obs, &mut outlier);
    let err = pose.inverse() * truth;
    assert!(err.translation.vector.norm() < 0.05, "translation error {}", err.translation.vector.norm());
    assert!(err.rotation.angle() < 1e-3);
    assert!(outlier[..n_out].iter().all(|o| *o), "every gross outlier found");
    assert!(inliers >= (pts.len() - n_out) * 9 / 10, "{inliers} inliers of {}", pts.len() - n_out);
}

/// A hover's view: 300 points on a wall 53–57 mm away, seen at 0.5 px. Its weak direction is sideways with a
/// turn that keeps the view on the same tissue.
fn hover_view(cam: &RectifiedCamera, truth: &CameraFromWorld) -> (Vec<Point3<f64>>, Vec<Observation>) {
    let mut s = 5u64;
    let mut points = Vec::new();
    let mut observations = Vec::new();
    while points.len() < 300 {
        let in_camera = Point3::new(25.0 * noise(&mut s), 18.0 * noise(&mut s), 55.0 + 2.0 * noise(&mut s));
        let z = cam.project_stereo(&in_camera);
        if !cam.in_image(z.x, z.y) {
            continue;
        }
        let (du, dv, dr) = (0.5 * noise(&mut s), 0.5 * noise(&mut s), 0.5 * noise(&mut s));
        points.push(truth.inverse() * in_camera);
        observations.push(Observation { u: z.x + du, v: z.y + dv, u_right: Some(z.z + du + dr), inv_sigma2: 1.0 });
    }
    (points, observations)
}

/// A spurious stereo point 5 mm from the camera (a mismatch at a tenth of the scene's depth) whose images fit a
/// pose shifted along the hover's weak direction: alone it pins that direction down, so a fit follows it and
/// keeps its residual within the χ² gate. Its influence gives it away and it is left out; a true point as near
/// as that, which agrees with the others, stays.
#[test]
fn one_measurement_that_moves_the_pose_far_from_the_others_is_left_out() {
    let cam = cam();
    let truth = Isometry3::new(Vector3::new(1.0, -2.0, 3.0), Vector3::new(0.05, -0.02, 0.03));
    let (mut points, mut observations) = hover_view(&cam, &truth);
    // Sideways by `shift` mm and turned so the wall's centre stays put: the weak direction.
    let shift = 0.2;
    let off = exp_se3(&Vector6::new(0.0, shift / 55.0, 0.0, -shift, 0.0, 0.0)) * truth;
    let near = Point3::new(3.0, 1.0, 5.0);
    let seen = cam.project_stereo(&(off * (truth.inverse() * near)));
    let spurious = points.len();
    points.push(truth.inverse() * near);
    observations.push(Observation { u: seen.x, v: seen.y, u_right: Some(seen.z), inv_sigma2: 1.0 });
    let solve = |points: &[Point3<f64>], observations: &[Observation]| {
        let mut pose = truth;
        let mut outlier = vec![false; points.len()];
        PoseOptimizer::for_tracking(0).optimize(&cam, &mut pose, points, observations, &mut outlier);
        ((pose.inverse() * truth).translation.vector.norm(), outlier)
    };
    let (error, outlier) = solve(&points, &observations);
    assert!(outlier[spurious], "the spurious point was kept");
    assert!(error < 0.2 * shift, "{error} mm off, the spurious point pulls {shift} mm");
    // Loop closing's pose checks go without the influence check: there the point stays, and pulls.
    let mut pose = truth;
    let mut kept = vec![false; points.len()];
    PoseOptimizer::default().optimize(&cam, &mut pose, &points, &observations, &mut kept);
    assert!(!kept[spurious], "the default optimiser judged influence");
    // The same point where it truly is: it agrees with the others and stays.
    let true_near = cam.project_stereo(&near);
    observations[spurious] =
        Observation { u: true_near.x, v: true_near.y, u_right: Some(true_near.z), inv_sigma2: 1.0 };
    let (error, outlier) = solve(&points, &observations);
    assert!(!outlier[spurious], "a true near point was left out");
    assert!(error < 0.2 * shift, "{error} mm off");
}

#[test]
fn bundle_adjustment_converges_from_perturbed_ground_truth() {
    let cam = cam();
    let (truth_poses, truth_points) = scene(3);
    let sigma = 0.5;
    let edges = observe(&cam, &truth_poses, &truth_points, sigma, 11);
    let mut s = 99u64;
    // Perturb every pose but the first (fixed, it sets the gauge) and every point.
    let poses: Vec<CameraFromWorld> = truth_poses
        .iter()
        .enumerate()
        .map(|(i, t)| {
            if i == 0 {
                *t
            } else {
                let d = Vector6::from_fn(|k, _| if k < 3 { 0.02 } else { 2.0 } * noise(&mut s));
                exp_se3(&d) * t
            }
        })
        .collect();
    let points: Vec<Point3<f64>> =
        truth_points.iter().map(|p| p + Vector3::from_fn(|_, _| 3.0 * noise(&mut s))).collect();
    let mut problem =
        BaProblem { fixed: (0..5).map(|i| i == 0).collect(), poses, points, excluded: vec![false; edges.len()], edges };
    let report = problem.solve(&cam, 20, true, &|| false);
    problem.solve(&cam, 10, false, &|| false);
    let pose_err: f64 = problem
        .poses
        .iter()
        .zip(&truth_poses)
        .map(|(a, b)| (a.inverse() * b).translation.vector.norm())
        .fold(0.0, f64::max);
    let mut point_err: Vec<f64> = problem.points.iter().zip(&truth_points).map(|(a, b)| (a - b).norm()).collect();
    point_err.sort_by(f64::total_cmp);
    let median_point_err = point_err[point_err.len() / 2];
    eprintln!("BA: worst pose {pose_err:.4} mm, median point {median_point_err:.4} mm, {report:?}");
    // Within noise: 0.5 px at 60 mm and f 520 is ~0.06 mm laterally, ~0.7 mm in depth for one stereo pair.
    assert!(pose_err < 0.1, "worst camera position error {pose_err} mm ({report:?})");
    assert!(median_point_err < 0.4, "median point error {median_point_err} mm");
    let chi2_mean = problem.cost(&cam, &problem.poses, &problem.points, false) / problem.edges.len() as f64;
    assert!(chi2_mean < 3.0 * sigma * sigma * 1.5, "mean χ² {chi2_mean}");
}

/// The damping is in the scene's own units: the same problem in metres and in millimetres gives the same
/// adjustment, scaled. (λ·I in the calibration's units damped lengths 10⁶ times harder in millimetres; a real
/// clip scored 0.089 m in millimetres against 0.069 m in metres.)
#[test]
fn bundle_adjustment_is_the_same_in_metres_and_millimetres() {
    let solve_in = |metres_per_unit: f64| {
        let mm = cam();
        let cam = RectifiedCamera { bf: mm.bf * 1e-3 / metres_per_unit, ..mm };
        let to_unit = 1e-3 / metres_per_unit;
        let (truth_poses, truth_points) = scene(5);
        let edges = observe(&mm, &truth_poses, &truth_points, 0.5, 13);
        let mut s = 7u64;
        let poses: Vec<CameraFromWorld> = truth_poses
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let d = Vector6::from_fn(|k, _| if i == 0 { 0.0 } else if k < 3 { 0.01 } else { 1.0 } * noise(&mut s));
                let mut p = exp_se3(&d) * t;
                p.translation.vector *= to_unit;
                p
            })
            .collect();
        let points =
            truth_points.iter().map(|p| (p + Vector3::from_fn(|_, _| 2.0 * noise(&mut s))) * to_unit).collect();
        let mut problem = BaProblem {
            fixed: (0..5).map(|i| i == 0).collect(),
            poses,
            points,
            excluded: vec![false; edges.len()],
            edges,
        };
        // Few iterations, so the damping shapes the result: converged, any damping would agree.
        problem.solve(&cam, 3, true, &|| false);
        let in_mm = |x: f64| x / to_unit;
        (
            problem.poses.iter().map(|p| p.translation.vector.map(in_mm)).collect::<Vec<_>>(),
            problem.points.iter().map(|p| p.coords.map(in_mm)).collect::<Vec<_>>(),
        )
    };
    let (poses_mm, points_mm) = solve_in(1e-3);
    let (poses_m, points_m) = solve_in(1.0);
    for (a, b) in poses_mm.iter().zip(&poses_m) {
        assert!((a - b).norm() < 1e-6, "camera {a:?} mm against {b:?} from metres");
    }
    let worst = points_mm.iter().zip(&points_m).map(|(a, b)| (a - b).norm()).fold(0.0, f64::max);
    assert!(worst < 1e-6, "points differ by up to {worst} mm between the units");
}

#[test]
fn the_written_out_block_update_is_nalgebras_product_to_the_bit() {
    // Bundle adjustment's results stay byte-identical only if the block update rounds as the product it replaced.
    let mut state = 5u64;
    for _ in 0..50 {
        let a = SMatrix::<f64, 6, 3>::from_fn(|_, _| 1e3 * noise(&mut state));
        let b = SMatrix::<f64, 6, 3>::from_fn(|_, _| 1e-2 * noise(&mut state));
        let start = DMatrix::<f64>::from_fn(18, 18, |_, _| noise(&mut state));
        let (ba, bb) = (2, 1);
        let mut expected = start.clone();
        let mut view = expected.view_mut((6 * ba, 6 * bb), (6, 6));
        view -= a * b.transpose();
        let mut written_out = start.clone();
        subtract_block_product(&mut written_out, ba, bb, &a, &b);
        assert_eq!(
            written_out.as_slice().iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            expected.as_slice().iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
    }
}

/// A symmetric positive definite matrix shaped like a reduced camera system over keyframes in time order:
/// 6×6 blocks between neighbours up to `band` apart, and a few far ones (a loop's old side).
fn banded_spd(blocks: usize, band: usize, state: &mut u64) -> DMatrix<f64> {
    let n = 6 * blocks;
    let mut j = DMatrix::<f64>::zeros(n, n);
    // J·Jᵀ of a random block-sparse J is positive semidefinite; the diagonal makes it definite.
    for a in 0..blocks {
        for b in a.saturating_sub(band)..=a {
            let far_link = a > 3 * band && b == a - band && a % 7 == 0;
            let b = if far_link { a % band } else { b };
            for r in 0..6 {
                for c in 0..6 {
                    j[(6 * a + r, 6 * b + c)] = noise(state);
                }
            }
        }
    }
    let mut m = &j * j.transpose();
    for k in 0..n {
        m[(k, k)] += 0.5;
    }
    m
}

#[test]
fn the_envelope_cholesky_is_nalgebras_to_the_bit_and_refuses_what_it_refuses() {
    let mut state = 17u64;
    for (blocks, band) in [(1, 1), (5, 5), (30, 3), (40, 6)] {
        let m = banded_spd(blocks, band, &mut state);
        let rhs = DVector::<f64>::from_fn(m.nrows(), |_, _| noise(&mut state));
        let expected = m.clone().cholesky().expect("positive definite").solve(&rhs);
        let envelope = solve_by_envelope_cholesky(m, rhs).expect("positive definite");
        assert_eq!(
            envelope.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            expected.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            "{blocks} blocks, band {band}"
        );
    }
    // Indefinite, and a zero pivot: refused, as nalgebra refuses them.
    let mut indefinite = banded_spd(10, 2, &mut state);
    indefinite[(20, 20)] = -50.0;
    assert!(indefinite.clone().cholesky().is_none());
    assert!(solve_by_envelope_cholesky(indefinite, DVector::zeros(60)).is_none());
    assert!(solve_by_envelope_cholesky(DMatrix::zeros(6, 6), DVector::zeros(6)).is_none());
}
