//! Trajectory files, poses `world_from_camera` of the left camera.
//!
//! * TUM: one line per pose, `t tx ty tz qx qy qz qw`, time in seconds; `#` comments.
//! * KITTI: one line per pose, the 12 values of the 3×4 `[R | t]` row by row; no times (a KITTI sequence keeps them
//!   in its own `times.txt`).
//!
//! Numbers are written in Rust's shortest round-trip form, so a file we write reads back to the same `f64`s.

use std::io::Write;
use std::path::Path;

use super::{FormatError, invalid, io_error, write_atomically};
use crate::geometry::{
    StampedPose, pose_from_rows_3x4, pose_from_translation_quaternion, pose_to_rows_3x4, quaternion_xyzw,
};

fn numbers<const N: usize>(line: &str, path: &Path, line_no: usize, what: &str) -> Result<[f64; N], FormatError> {
    let mut out = [0.0; N];
    let mut count = 0;
    for tok in line.split_whitespace() {
        if count == N {
            return Err(invalid(path, Some(line_no), format!("{what}: more than {N} values")));
        }
        out[count] =
            tok.parse().map_err(|_| invalid(path, Some(line_no), format!("{what}: `{tok}` is not a number")))?;
        count += 1;
    }
    if count != N {
        return Err(invalid(path, Some(line_no), format!("{what}: {count} values, expected {N}")));
    }
    Ok(out)
}

fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())).filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

/// Reads a TUM trajectory.
pub fn read_tum(path: &Path) -> Result<Vec<StampedPose>, FormatError> {
    let text = std::fs::read_to_string(path).map_err(io_error(path))?;
    parse_tum(&text, path)
}

pub fn parse_tum(text: &str, path: &Path) -> Result<Vec<StampedPose>, FormatError> {
    data_lines(text)
        .map(|(line_no, line)| {
            let v: [f64; 8] = numbers(line, path, line_no, "TUM pose `t tx ty tz qx qy qz qw`")?;
            if !v[0].is_finite() {
                return Err(invalid(path, Some(line_no), format!("TUM pose: time `{}` is not finite", v[0])));
            }
            let world_from_camera = pose_from_translation_quaternion([v[1], v[2], v[3]], [v[4], v[5], v[6], v[7]])
                .ok_or_else(|| invalid(path, Some(line_no), "TUM pose: non-finite value or zero quaternion"))?;
            Ok(StampedPose { t_s: v[0], world_from_camera })
        })
        .collect()
}

/// Formats one TUM line (no newline).
pub fn tum_line(pose: &StampedPose) -> String {
    let t = pose.world_from_camera.translation.vector;
    let [qx, qy, qz, qw] = quaternion_xyzw(&pose.world_from_camera);
    format!("{} {} {} {} {} {} {} {}", pose.t_s, t.x, t.y, t.z, qx, qy, qz, qw)
}

/// Writes a TUM trajectory (atomically: the old file stays until the new one is complete).
pub fn write_tum(path: &Path, poses: &[StampedPose]) -> Result<(), FormatError> {
    write_atomically(path, |w| {
        writeln!(w, "# timestamp tx ty tz qx qy qz qw (world_from_camera of the left camera)")?;
        for p in poses {
            writeln!(w, "{}", tum_line(p))?;
        }
        Ok(())
    })
}

/// Reads a KITTI trajectory; times are the line indices unless the caller pairs them with a `times.txt`.
pub fn read_kitti(path: &Path) -> Result<Vec<nalgebra::Isometry3<f64>>, FormatError> {
    let text = std::fs::read_to_string(path).map_err(io_error(path))?;
    parse_kitti(&text, path)
}

pub fn parse_kitti(text: &str, path: &Path) -> Result<Vec<nalgebra::Isometry3<f64>>, FormatError> {
    data_lines(text)
        .map(|(line_no, line)| {
            let v: [f64; 12] = numbers(line, path, line_no, "KITTI pose (3×4 row-major)")?;
            pose_from_rows_3x4(&v)
                .ok_or_else(|| invalid(path, Some(line_no), "KITTI pose: rotation is not orthonormal or not finite"))
        })
        .collect()
}

pub fn write_kitti(path: &Path, poses: &[nalgebra::Isometry3<f64>]) -> Result<(), FormatError> {
    write_atomically(path, |w| {
        for p in poses {
            let v = pose_to_rows_3x4(p);
            let line: Vec<String> = v.iter().map(|x| x.to_string()).collect();
            writeln!(w, "{}", line.join(" "))?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Isometry3, Vector3};

    fn poses() -> Vec<StampedPose> {
        (0..20)
            .map(|i| {
                let a = i as f64 * 0.1;
                StampedPose {
                    t_s: 1.0 + a / 3.0,
                    world_from_camera: Isometry3::new(Vector3::new(a, a * a, -a), Vector3::new(0.1 * a, a.sin(), 0.0)),
                }
            })
            .collect()
    }

    #[test]
    fn tum_round_trips_bit_exactly() {
        let dir = std::env::temp_dir().join(format!("bdis-tum-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.txt");
        write_tum(&path, &poses()).unwrap();
        assert_eq!(read_tum(&path).unwrap(), poses());
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text.lines().nth(1).unwrap(), "1 0 0 -0 0 0 0 1");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn kitti_round_trips_and_rewrites_identically() {
        let dir = std::env::temp_dir().join(format!("bdis-kitti-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (a, b) = (dir.join("a.txt"), dir.join("b.txt"));
        let p: Vec<_> = poses().iter().map(|p| p.world_from_camera).collect();
        write_kitti(&a, &p).unwrap();
        let back = read_kitti(&a).unwrap();
        for (x, y) in p.iter().zip(&back) {
            assert!((x.to_homogeneous() - y.to_homogeneous()).abs().max() < 1e-14);
        }
        write_kitti(&b, &back).unwrap();
        let back2 = read_kitti(&b).unwrap();
        assert!(back.iter().zip(&back2).all(|(x, y)| (x.to_homogeneous() - y.to_homogeneous()).abs().max() < 1e-15));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_lines_name_file_and_line() {
        let e = parse_tum("# c\n1 2 3\n", Path::new("g.txt")).unwrap_err().to_string();
        assert_eq!(e, "g.txt:2: TUM pose `t tx ty tz qx qy qz qw`: 3 values, expected 8");
        let e = parse_kitti("1 0 0 0 0 1 0 0 0 0 1 x\n", Path::new("k.txt")).unwrap_err().to_string();
        assert_eq!(e, "k.txt:1: KITTI pose (3×4 row-major): `x` is not a number");
    }
}
