//! Where a tracker instance's map sits in the run's world frame, and where its keyframe ids start. The first
//! instance's map is the world; a restarted one's is anchored at its first tracked frame, where its
//! predecessor's motion says that frame is.

use nalgebra::Isometry3;

use crate::journal::Continuation;

#[derive(Debug)]
pub struct WorldFrame {
    world_from_map: Option<Isometry3<f64>>,
    /// This instance's keyframe `k` is published as `kf_offset + k`.
    pub kf_offset: u64,
}

impl WorldFrame {
    pub fn continuing(earlier: &Continuation) -> Self {
        let first = earlier.frames.is_empty();
        Self { world_from_map: first.then(Isometry3::identity), kf_offset: earlier.next_kf_id() }
    }

    /// Places a restarted tracker's map the first time it has a pose: there, `frame_seq` is where the
    /// predecessor's motion predicts it. Later calls change nothing.
    pub fn anchor(&mut self, earlier: &Continuation, frame_seq: u64, map_from_camera: &Isometry3<f64>) {
        if self.world_from_map.is_none() {
            let world_from_camera = earlier.predict(frame_seq).unwrap_or_else(Isometry3::identity);
            self.world_from_map = Some(world_from_camera * map_from_camera.inverse());
        }
    }

    pub fn to_world(&self, map_from_camera: &Isometry3<f64>) -> Isometry3<f64> {
        self.world_from_map.unwrap_or_else(Isometry3::identity) * map_from_camera
    }

    /// The id keyframe `k` of this instance's map is published with.
    pub fn kf_id(&self, k: usize) -> u64 {
        self.kf_offset + k as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn pose(x: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(Translation3::new(x, 0.0, 0.0), UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw))
    }

    #[test]
    fn the_first_instance_is_the_world() {
        let mut w = WorldFrame::continuing(&Continuation::default());
        assert_eq!((w.kf_offset, w.kf_id(3)), (0, 3));
        w.anchor(&Continuation::default(), 0, &pose(7.0, 0.3));
        assert_eq!(w.to_world(&pose(1.0, 0.1)), pose(1.0, 0.1));
    }

    #[test]
    fn a_restarted_instance_continues_where_its_predecessor_was_heading() {
        let mut text = String::new();
        crate::journal::frame_line(&mut text, 0, 0, Some(&pose(0.0, 0.0)));
        crate::journal::frame_line(&mut text, 1, 1, Some(&pose(1.0, 0.0)));
        crate::journal::keyframe_line(&mut text, 4, 1, &pose(1.0, 0.0));
        let earlier = Continuation::parse(&text).unwrap();
        let mut w = WorldFrame::continuing(&earlier);
        assert_eq!(w.kf_id(0), 5, "keyframe ids continue after the last published one");
        // The new map's first pose (anywhere in its own frame) lands where constant velocity puts frame 2.
        let first_in_map = pose(-3.0, 0.2);
        w.anchor(&earlier, 2, &first_in_map);
        let at = w.to_world(&first_in_map);
        assert!((at.translation.vector - Vector3::new(2.0, 0.0, 0.0)).norm() < 1e-9, "{at}");
        // Anchored once: a later pose does not move the frame.
        w.anchor(&earlier, 3, &pose(9.0, 0.0));
        assert!((w.to_world(&first_in_map).translation.vector - at.translation.vector).norm() < 1e-12);
    }
}
