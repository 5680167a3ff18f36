//! SE(3) helpers and the rectified stereo camera model (ORB-SLAM2-STEREO.md §3.1, §5.5).
//!
//! Poses here are `camera_from_world` (T_cw, the tracker's working convention: it maps world points into the
//! camera); trajectories leave the crate as `world_from_camera` (bdis_core::geometry::Pose).

use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3, Vector6};

/// `camera_from_world` of the left camera.
pub type CameraFromWorld = Isometry3<f64>;

/// The cross-product matrix: `skew(a)·b = a × b`.
pub fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -a.z, a.y, a.z, 0.0, -a.x, -a.y, a.x, 0.0)
}

/// exp of a twist ξ = (ω, υ) (rotation first): the rigid motion of the left-multiplicative update T ← exp(ξ)·T.
pub fn exp_se3(xi: &Vector6<f64>) -> Isometry3<f64> {
    let omega = Vector3::new(xi[0], xi[1], xi[2]);
    let upsilon = Vector3::new(xi[3], xi[4], xi[5]);
    let theta = omega.norm();
    let w = skew(&omega);
    // V = I + (1 − cos θ)/θ² [ω]× + (θ − sin θ)/θ³ [ω]×², with its series near 0.
    let (a, b) = if theta < 1e-5 {
        (0.5 - theta * theta / 24.0, 1.0 / 6.0 - theta * theta / 120.0)
    } else {
        ((1.0 - theta.cos()) / (theta * theta), (theta - theta.sin()) / (theta * theta * theta))
    };
    let v = Matrix3::identity() + w * a + w * w * b;
    Isometry3::from_parts(Translation3::from(v * upsilon), UnitQuaternion::from_scaled_axis(omega))
}

/// `exp(ξ)·T`, the left-multiplicative update, with the rotation re-normalised: nalgebra composes unit
/// quaternions without normalising, and after thousands of updates the drift (|q| ≠ 1) makes `T·T⁻¹` a scaling
/// of the translation (a 0.1 % error in every relative pose).
pub fn update(xi: &Vector6<f64>, t: &Isometry3<f64>) -> Isometry3<f64> {
    let mut u = exp_se3(xi) * t;
    u.rotation = UnitQuaternion::new_normalize(u.rotation.into_inner());
    u
}

pub use bdis_core::calib::RectifiedCamera;

/// Three indices below `n` from the tracker's deterministic generator (a 64-bit LCG); `None` when two coincide
/// (the draw is spent, as RANSAC counts it).
pub fn draw_three(state: &mut u64, n: usize) -> Option<[usize; 3]> {
    let mut pick = [0usize; 3];
    for slot in pick.iter_mut() {
        *state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
        *slot = (*state >> 33) as usize % n;
    }
    (pick[0] != pick[1] && pick[1] != pick[2] && pick[0] != pick[2]).then_some(pick)
}

/// The rigid motion `dst_from_src` that best maps `src` onto `dst` (Horn/Umeyama without scale); `None` for
/// degenerate (collinear) sets.
pub fn rigid_fit(src: &[Point3<f64>], dst: &[Point3<f64>]) -> Option<Isometry3<f64>> {
    let n = src.len() as f64;
    let (cs, cd) = (
        src.iter().fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords) / n,
        dst.iter().fold(nalgebra::Vector3::zeros(), |a, p| a + p.coords) / n,
    );
    let mut cov = Matrix3::zeros();
    for (s, d) in src.iter().zip(dst) {
        cov += (d.coords - cd) * (s.coords - cs).transpose();
    }
    let svd = cov.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let sv = svd.singular_values;
    if sv[1] < 1e-9 * sv[0].max(1e-30) {
        return None;
    }
    let mut s = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let r = u * s * v_t;
    // U·S·Vᵀ is a rotation by construction: converted directly. (`UnitQuaternion::from_matrix` iterates from
    // the identity until it converges, and for some rotations it never does: a hang seen in this fit.)
    let rotation = UnitQuaternion::from_rotation_matrix(&nalgebra::Rotation3::from_matrix_unchecked(r));
    let t = cd - rotation * cs;
    Some(Isometry3::from_parts(Translation3::from(t), rotation))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_of_small_and_large_twists_matches_integration() {
        for xi in [Vector6::new(1e-8, -2e-8, 3e-8, 0.1, 0.2, -0.3), Vector6::new(0.3, -0.5, 0.2, 1.0, -2.0, 0.5)] {
            // Integrate the constant twist in 10⁴ small steps.
            let mut t = Isometry3::identity();
            let step = exp_first_order(&(xi / 10_000.0));
            for _ in 0..10_000 {
                t = step * t;
            }
            let e = exp_se3(&xi);
            assert!((e.translation.vector - t.translation.vector).norm() < 1e-4, "{e} vs {t}");
            assert!(e.rotation.angle_to(&t.rotation) < 1e-6);
        }
    }

    fn exp_first_order(xi: &Vector6<f64>) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(xi[3], xi[4], xi[5]),
            UnitQuaternion::from_scaled_axis(Vector3::new(xi[0], xi[1], xi[2])),
        )
    }

    #[test]
    fn updates_keep_the_rotation_unit() {
        let mut t = Isometry3::identity();
        for k in 0..100_000 {
            let a = k as f64 * 0.001;
            t = update(&Vector6::new(0.01 * a.sin(), 0.02 * a.cos(), -0.01, 0.1, 0.0, 0.2), &t);
        }
        assert!((t.rotation.into_inner().norm() - 1.0).abs() < 1e-12);
        assert!((t * t.inverse()).translation.vector.norm() < 1e-9);
    }

    #[test]
    fn stereo_projection_inverts_unprojection() {
        let cam = RectifiedCamera { fx: 520.0, fy: 520.0, cx: 320.0, cy: 240.0, bf: 2600.0, width: 640, height: 480 };
        let p = cam.unproject(100.5, 300.25, 42.0);
        let z = cam.project_stereo(&p);
        assert!((z.x - 100.5).abs() < 1e-12 && (z.y - 300.25).abs() < 1e-12);
        assert!((z.x - z.z - 2600.0 / 42.0).abs() < 1e-12);
    }

    #[test]
    fn rigid_fit_recovers_a_rigid_motion_exactly() {
        let motion = Isometry3::new(Vector3::new(0.3, -1.2, 4.0), Vector3::new(0.2, -0.4, 0.9));
        let src: Vec<Point3<f64>> =
            [(0.0, 0.0, 1.0), (1.0, 0.5, 2.0), (-0.7, 2.0, 3.0), (0.4, -1.0, 5.0), (2.0, 2.0, 2.5)]
                .into_iter()
                .map(|(x, y, z)| Point3::new(x, y, z))
                .collect();
        let dst: Vec<Point3<f64>> = src.iter().map(|p| motion * p).collect();
        let fit = rigid_fit(&src, &dst).unwrap();
        assert!((fit.translation.vector - motion.translation.vector).norm() < 1e-9);
        assert!(fit.rotation.angle_to(&motion.rotation) < 1e-9);
    }

    #[test]
    fn rigid_fit_never_returns_a_reflection() {
        // Points mirrored through a plane: the best rotation is still a rotation (det +1).
        let src: Vec<Point3<f64>> = [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (1.0, 1.0, 1.0)]
            .map(|(x, y, z)| Point3::new(x, y, z))
            .into();
        let dst: Vec<Point3<f64>> = src.iter().map(|p| Point3::new(-p.x, p.y, p.z)).collect();
        let fit = rigid_fit(&src, &dst).unwrap();
        assert!((fit.rotation.to_rotation_matrix().matrix().determinant() - 1.0).abs() < 1e-9);
    }

    #[test]
    fn rigid_fit_refuses_collinear_points() {
        let src: Vec<Point3<f64>> = (0..5).map(|i| Point3::new(f64::from(i), 2.0 * f64::from(i), 0.0)).collect();
        assert!(rigid_fit(&src, &src).is_none());
    }
}
