//! A short rendered colon flight, shared by the tracker's integration tests (`common/mod.rs`) and its unit
//! tests (included by `#[path]`), so it names only the renderer's crate.

use bdis_synth::RectifiedCamera;

/// `frames` stereo pairs of a 320×240 flight through the synthetic colon (f = 260, 5 mm baseline), greyed as
/// acquisition does (BT.601).
pub fn colon_flight(frames: usize) -> Vec<(Vec<u8>, Vec<u8>)> {
    (0..frames).map(colon_frame).collect()
}

/// The renders' rig: 320×240, f = 260, 5 mm baseline (the rays go through pixel centres, (x + 0.5, y + 0.5)).
pub fn render_rig() -> RectifiedCamera {
    RectifiedCamera { width: 320, height: 240, fx: 260.0, fy: 260.0, cx: 160.0, cy: 120.0, bf: 260.0 * 5.0 }
}

/// Frame `i` of [`colon_flight`] (at 30 frames a second, 20 mm/s).
pub fn colon_frame(i: usize) -> (Vec<u8>, Vec<u8>) {
    let colon = bdis_synth::colon::Colon::default();
    let shading = bdis_synth::render::Shading::default();
    let pose = colon.forward_pose(i as f64 / 30.0, 20.0);
    let pair = bdis_synth::render::render(&colon, &render_rig(), &shading, &pose, i as u64);
    (grey(&pair.left), grey(&pair.right))
}

/// A rendered image greyed as acquisition does (BT.601).
pub fn grey(img: &image::RgbImage) -> Vec<u8> {
    bdis_core::pixel::gray_of_rgb(img.as_raw())
}
