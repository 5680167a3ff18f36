//! A short rendered colon flight for the tracker's tests: the camera, ORB settings and grey stereo pairs as
//! acquisition delivers them.
#![allow(dead_code)]

use bdis_track::{RectifiedCamera, Tracker, TrackerSettings};

// The flight is rendered by a file the crate's own unit tests include too (`#[path]`): it names no crate but
// the renderer's.
mod flight;
#[allow(unused_imports)] // each test binary uses its own part of this module
pub use flight::{colon_flight, colon_frame, grey, render_rig};

/// A tracker for [`colon_flight`] and the other 320×240 renders with f = 260 (pixel centres at half-pixel offsets, as the settings the renderer writes).
pub fn colon_tracker() -> Tracker {
    colon_tracker_at(30.0)
}

/// [`colon_tracker`] told the frames come at `fps` (what its time spans, a keyframe's or a veil's, count in).
pub fn colon_tracker_at(fps: f64) -> Tracker {
    let cam = RectifiedCamera { fx: 260.0, fy: 260.0, cx: 159.5, cy: 119.5, bf: 1300.0, width: 320, height: 240 };
    let orb = bdis_orb::OrbParams { n_features: 1000, ini_th_fast: 20, min_th_fast: 7, ..Default::default() };
    match Tracker::new(cam, TrackerSettings { th_depth: 20.0, fps, orb }) {
        Ok(t) => t,
        Err(e) => panic!("tracker: {e}"),
    }
}

/// A grey stereo pair of the abdominal wall `abdomen` seen from `world_from_camera` with [`render_rig`], lit by a
/// laparoscope's light as `bdis-slam synth --scene abdomen` renders it.
pub fn abdomen_pair(
    abdomen: &bdis_synth::abdomen::Abdomen,
    world_from_camera: &nalgebra::Isometry3<f64>,
    noise_seed: u64,
) -> (Vec<u8>, Vec<u8>) {
    abdomen_pair_through(abdomen, world_from_camera, noise_seed, None)
}

/// [`abdomen_pair`] seen through `haze` (the renderer's smoke at that moment, if any).
pub fn abdomen_pair_through(
    abdomen: &bdis_synth::abdomen::Abdomen,
    world_from_camera: &nalgebra::Isometry3<f64>,
    noise_seed: u64,
    haze: Option<bdis_synth::smoke::Haze>,
) -> (Vec<u8>, Vec<u8>) {
    let shading = bdis_synth::render::Shading { exposure_distance_mm: 65.0, haze, ..Default::default() };
    let pair = bdis_synth::render::render(abdomen, &render_rig(), &shading, world_from_camera, noise_seed);
    (grey(&pair.left), grey(&pair.right))
}
