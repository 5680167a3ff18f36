//! The tracker's journal format: one line per published pose, keyframe and pose correction, appended as they go out, so
//! a tracker restarted after a crash can continue the same trajectory and map. It is what was *published*: the
//! world frame, the keyframe ids and the correction generations other processes already hold.
//!
//! ```text
//! F <frame_seq> <t_ns> <tx ty tz qx qy qz qw>     a frame's pose (world_from_camera), or `-` when it had none
//! K <kf_id> <t_ns> <tx ty tz qx qy qz qw>         a keyframe, written just before it is published
//! C <kf_id> <generation> <tx ty tz qx qy qz qw>   a pose correction
//! ```
//!
//! A restarted tracker builds a new map, placed in the old world frame at the pose the old one's motion predicts
//! for its first frame; its keyframe ids continue after the last published one (so no downstream id is reused)
//! and its correction generations after the last sent.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};

/// What a restarted tracker continues from.
#[derive(Debug, Clone, Default)]
pub struct Continuation {
    /// Every frame the earlier instances handled, in order: (frame_seq, t_ns, world_from_camera).
    pub frames: Vec<(u64, u64, Option<Isometry3<f64>>)>,
    /// The latest known world_from_camera (and t_ns) of every published keyframe id.
    pub keyframes: BTreeMap<u64, (u64, Isometry3<f64>)>,
    /// The highest correction generation sent.
    pub generation: u64,
}

/// A line that does not parse: its number and why.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("line {line}: {why}")]
pub struct JournalError {
    pub line: usize,
    pub why: String,
}

fn pose_text(out: &mut String, p: &Isometry3<f64>) {
    let (t, q) = (p.translation.vector, p.rotation.quaternion());
    // `{}` prints the shortest text that reads back to the same f64.
    let _ = write!(out, "{} {} {} {} {} {} {}", t.x, t.y, t.z, q.i, q.j, q.k, q.w);
}

// The line writers append to a buffer the caller reuses: the tracker journals every frame.

/// Appends the `F` line of a frame.
pub fn frame_line(out: &mut String, frame_seq: u64, t_ns: u64, world_from_camera: Option<&Isometry3<f64>>) {
    let _ = write!(out, "F {frame_seq} {t_ns} ");
    match world_from_camera {
        Some(p) => pose_text(out, p),
        None => out.push('-'),
    }
    out.push('\n');
}

/// Appends the `K` line of a keyframe.
pub fn keyframe_line(out: &mut String, kf_id: u64, t_ns: u64, world_from_camera: &Isometry3<f64>) {
    let _ = write!(out, "K {kf_id} {t_ns} ");
    pose_text(out, world_from_camera);
    out.push('\n');
}

/// Appends the `C` line of a correction.
pub fn correction_line(out: &mut String, kf_id: u64, generation: u64, world_from_camera: &Isometry3<f64>) {
    let _ = write!(out, "C {kf_id} {generation} ");
    pose_text(out, world_from_camera);
    out.push('\n');
}

fn parse_pose(fields: &[&str]) -> Result<Isometry3<f64>, String> {
    let v: Vec<f64> = fields
        .iter()
        .map(|f| f.parse::<f64>().map_err(|_| format!("`{f}` is not a number")))
        .collect::<Result<_, _>>()?;
    let [tx, ty, tz, qx, qy, qz, qw] = v[..] else { return Err(format!("a pose has 7 numbers, found {}", v.len())) };
    let q = Quaternion::new(qw, qx, qy, qz);
    if !v.iter().all(|x| x.is_finite()) || (q.norm() - 1.0).abs() > 1e-6 {
        return Err("not a rigid pose".into());
    }
    // Unchecked: the numbers read back are exactly those written (checked close to unit above).
    Ok(Isometry3::from_parts(Translation3::new(tx, ty, tz), UnitQuaternion::new_unchecked(q)))
}

impl Continuation {
    /// Reads a journal. A last line cut short by the crash is ignored; any other bad line is an error.
    pub fn parse(text: &str) -> Result<Self, JournalError> {
        let mut c = Self::default();
        let lines: Vec<&str> = text.lines().collect();
        for (i, line) in lines.iter().enumerate() {
            let fields: Vec<&str> = line.split_whitespace().collect();
            let number = |k: usize| -> Result<u64, String> {
                fields.get(k).and_then(|f| f.parse().ok()).ok_or_else(|| format!("field {} is not a count", k + 1))
            };
            let parsed: Result<(), String> = (|| {
                match fields.first().copied() {
                    Some("F") => {
                        let pose = match fields.get(3..) {
                            Some(["-"]) => None,
                            Some(rest) => Some(parse_pose(rest)?),
                            None => return Err("a frame line needs a pose or `-`".into()),
                        };
                        c.frames.push((number(1)?, number(2)?, pose));
                    }
                    Some("K") => {
                        c.keyframes.insert(number(1)?, (number(2)?, parse_pose(fields.get(3..).unwrap_or(&[]))?));
                    }
                    Some("C") => {
                        let (id, generation) = (number(1)?, number(2)?);
                        let pose = parse_pose(fields.get(3..).unwrap_or(&[]))?;
                        if let Some(k) = c.keyframes.get_mut(&id) {
                            k.1 = pose;
                        }
                        c.generation = c.generation.max(generation);
                    }
                    None => {}
                    Some(other) => return Err(format!("unknown record `{other}`")),
                }
                Ok(())
            })();
            if let Err(why) = parsed {
                // The process may have died in the middle of its last line.
                if i + 1 == lines.len() && !text.ends_with('\n') {
                    break;
                }
                return Err(JournalError { line: i + 1, why });
            }
        }
        Ok(c)
    }

    /// The last frame the earlier instances handled.
    pub fn last_frame_seq(&self) -> Option<u64> {
        self.frames.last().map(|f| f.0)
    }

    /// The first keyframe id a restarted tracker may use.
    pub fn next_kf_id(&self) -> u64 {
        self.keyframes.keys().next_back().map_or(0, |k| k + 1)
    }

    /// Where frame `frame_seq` should be: the last pose moved on at the last frame-to-frame motion
    /// (constant velocity, as the tracker's own motion model).
    pub fn predict(&self, frame_seq: u64) -> Option<Isometry3<f64>> {
        let mut posed = self.frames.iter().rev().filter_map(|(s, _, p)| p.map(|p| (*s, p)));
        let (s1, p1) = posed.next()?;
        let Some((s0, p0)) = posed.next() else { return Some(p1) };
        // The motion between the last two poses (camera frame), spread evenly over the frames it covered.
        let motion = p0.inverse() * p1;
        let f = 1.0 / s1.saturating_sub(s0).max(1) as f64;
        let per_frame = Isometry3::from_parts(
            Translation3::from(motion.translation.vector * f),
            UnitQuaternion::identity().slerp(&motion.rotation, f),
        );
        let mut p = p1;
        for _ in 0..frame_seq.saturating_sub(s1).min(1000) {
            p *= per_frame;
        }
        Some(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn pose(x: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::new(Vector3::new(x, 0.5 * x, 2.0), Vector3::new(0.0, yaw, 0.0))
    }

    /// Frame i of a camera moving at a constant velocity (in its own frame).
    fn moving(i: u64) -> Isometry3<f64> {
        let v = Isometry3::new(Vector3::new(0.3, -0.1, 1.0), Vector3::new(0.01, 0.02, 0.0));
        (0..i).fold(pose(1.0, 0.2), |p, _| p * v)
    }

    #[test]
    fn round_trips_and_continues_ids_generations_and_motion() {
        let mut text = String::new();
        for i in 0..5u64 {
            frame_line(&mut text, i, 1000 * i, Some(&moving(i)));
        }
        keyframe_line(&mut text, 0, 0, &pose(0.0, 0.0));
        keyframe_line(&mut text, 1, 4000, &pose(4.0, 0.04));
        correction_line(&mut text, 0, 3, &pose(0.1, 0.0));
        frame_line(&mut text, 5, 5000, None);
        let c = Continuation::parse(&text).unwrap();
        assert_eq!(c.frames.len(), 6);
        assert_eq!(c.last_frame_seq(), Some(5));
        assert_eq!((c.next_kf_id(), c.generation), (2, 3));
        // Exactly the published numbers come back.
        assert_eq!(c.frames[3].2, Some(moving(3)));
        assert_eq!(c.keyframes[&0].1, pose(0.1, 0.0), "the correction replaced the keyframe's pose");
        // Frame 6 is two frame-steps on from frame 4 (frame 5 had no pose).
        let predicted = c.predict(6).unwrap();
        assert!((predicted.translation.vector - moving(6).translation.vector).norm() < 1e-9, "{predicted}");
        assert!(predicted.rotation.angle_to(&moving(6).rotation) < 1e-9);
    }

    #[test]
    fn a_torn_last_line_is_ignored_and_other_bad_lines_are_errors() {
        let mut good = String::new();
        frame_line(&mut good, 0, 0, Some(&pose(0.0, 0.0)));
        let torn = format!("{good}F 1 1000 0.5 0.2");
        assert_eq!(Continuation::parse(&torn).unwrap().frames.len(), 1);
        let bad = format!("{good}X 1\n{good}");
        assert_eq!(Continuation::parse(&bad).unwrap_err(), JournalError { line: 2, why: "unknown record `X`".into() });
        let not_rigid = "K 0 0 0 0 0 0 0 0 2\n";
        assert_eq!(Continuation::parse(not_rigid).unwrap_err().why, "not a rigid pose");
        assert!(Continuation::parse("").unwrap().predict(3).is_none());
    }
}
