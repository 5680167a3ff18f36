//! Poses and their conventions.
//!
//! A pose is the rigid transform `world_from_camera` of the **left** camera (maps camera coordinates to world
//! coordinates), stored as `nalgebra::Isometry3<f64>`. Transforms are named `a_from_b`.

use nalgebra::{Isometry3, Matrix3, Quaternion, Rotation3, Translation3, UnitQuaternion};

/// `world_from_camera` of the left camera.
pub type Pose = Isometry3<f64>;

/// A pose with its timestamp in seconds (as in trajectory files).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StampedPose {
    pub t_s: f64,
    pub world_from_camera: Pose,
}

/// The pose of `poses` (sorted by time, as trajectory files are) nearest in time to `t_s`, if one is within
/// `max_dt_s` of it.
pub fn pose_nearest_in_time(poses: &[StampedPose], t_s: f64, max_dt_s: f64) -> Option<&StampedPose> {
    let after = poses.partition_point(|p| p.t_s < t_s);
    [after.checked_sub(1), Some(after)]
        .into_iter()
        .flatten()
        .filter_map(|i| poses.get(i))
        .filter(|p| (p.t_s - t_s).abs() <= max_dt_s)
        .min_by(|a, b| (a.t_s - t_s).abs().total_cmp(&(b.t_s - t_s).abs()))
}

/// Builds a pose from a translation and a quaternion given as (qx, qy, qz, qw), the TUM order. A quaternion that
/// is unit to 1e-12 is taken as it is, so a file written by us reads back bit-identically; one that is merely
/// close to unit is normalised; a zero or non-finite one is `None`.
pub fn pose_from_translation_quaternion(t: [f64; 3], q_xyzw: [f64; 4]) -> Option<Pose> {
    if !t.iter().chain(q_xyzw.iter()).all(|v| v.is_finite()) {
        return None;
    }
    let q = Quaternion::new(q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]);
    let norm = q.norm();
    // Written so that a NaN norm is rejected too.
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    if !(norm > 1e-6 && norm.is_finite()) {
        return None;
    }
    let rotation =
        if (norm - 1.0).abs() <= 1e-12 { UnitQuaternion::new_unchecked(q) } else { UnitQuaternion::from_quaternion(q) };
    Some(Isometry3::from_parts(Translation3::new(t[0], t[1], t[2]), rotation))
}

/// (qx, qy, qz, qw) of a pose's rotation.
pub fn quaternion_xyzw(pose: &Pose) -> [f64; 4] {
    let q = pose.rotation.quaternion();
    [q.i, q.j, q.k, q.w]
}

/// The 3×4 row-major `[R | t]` of a pose (KITTI order).
pub fn pose_to_rows_3x4(pose: &Pose) -> [f64; 12] {
    let r = pose.rotation.to_rotation_matrix();
    let m = r.matrix();
    let t = pose.translation.vector;
    [m[(0, 0)], m[(0, 1)], m[(0, 2)], t.x, m[(1, 0)], m[(1, 1)], m[(1, 2)], t.y, m[(2, 0)], m[(2, 1)], m[(2, 2)], t.z]
}

/// A pose from a 3×4 row-major `[R | t]`. The rotation part must be orthonormal to 1e-6 (it is re-orthonormalised
/// exactly); otherwise `None`.
pub fn pose_from_rows_3x4(v: &[f64; 12]) -> Option<Pose> {
    if !v.iter().all(|x| x.is_finite()) {
        return None;
    }
    let m = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
    if (m.transpose() * m - Matrix3::identity()).abs().max() > 1e-6 || m.determinant() < 0.0 {
        return None;
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
    Some(Isometry3::from_parts(Translation3::new(v[3], v[7], v[11]), rotation))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Vector3};

    #[test]
    fn world_from_camera_maps_the_optical_centre_to_the_translation() {
        let pose = Isometry3::new(Vector3::new(1.0, 2.0, 3.0), Vector3::new(0.1, -0.2, 0.3));
        assert!((pose * Point3::origin() - Point3::new(1.0, 2.0, 3.0)).norm() < 1e-15);
    }

    #[test]
    fn quaternion_and_matrix_round_trips() {
        for i in 0..50 {
            let a = i as f64 * 0.37;
            let pose = Isometry3::new(Vector3::new(a, -2.0 * a, 0.5), Vector3::new(a.sin(), a.cos() * 0.5, 0.2 * a));
            let back =
                pose_from_translation_quaternion(pose.translation.vector.into(), quaternion_xyzw(&pose)).unwrap();
            assert_eq!(back, pose);
            let back = pose_from_rows_3x4(&pose_to_rows_3x4(&pose)).unwrap();
            assert!((back.to_homogeneous() - pose.to_homogeneous()).abs().max() < 1e-12);
        }
        assert!(pose_from_translation_quaternion([0.0; 3], [0.0; 4]).is_none());
        assert!(pose_from_rows_3x4(&[2.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]).is_none());
    }

    #[test]
    fn the_nearest_pose_in_time_is_found_only_within_the_tolerance() {
        let poses: Vec<StampedPose> = [0.0, 0.1, 0.2, 0.4]
            .into_iter()
            .map(|t_s| StampedPose { t_s, world_from_camera: Isometry3::translation(t_s, 0.0, 0.0) })
            .collect();
        let near = |t_s: f64, max_dt_s: f64| pose_nearest_in_time(&poses, t_s, max_dt_s).map(|p| p.t_s);
        assert_eq!(near(0.14, 0.05), Some(0.1));
        assert_eq!(near(0.16, 0.05), Some(0.2));
        assert_eq!(near(0.3, 0.05), None, "no pose within 0.05 s of 0.3 s");
        assert_eq!(near(-0.01, 0.05), Some(0.0));
        assert_eq!(near(0.45, 0.05), Some(0.4));
        assert_eq!(near(0.5, 0.05), None);
        assert_eq!(pose_nearest_in_time(&[], 0.0, 1.0), None);
    }
}
