//! Parameters in pixels on images of any size. BDIS-SLAM's pixel parameters (BDIS's patch size and levels, the
//! map's `depth_gap`, its disparity margins) were made for 640×480-class footage; on HD footage the same
//! numbers would look at 2–3× finer detail than they were meant to, at the square of the cost. An HD image is
//! therefore treated as a halved one for them: [`reference_halvings`] says how many times, and a pixel
//! parameter scales by `2^halvings` — so the depth's own resolution and the map's grid keep the same relation at
//! every size.

/// The image size those pixel parameters are in the pixels of (BDIS-SLAM's settings files are for 640×480-class
/// footage, as the Hamlyn sets are).
pub const REFERENCE_PIXELS: f64 = 640.0 * 480.0;

/// How many halvings bring a `width`×`height` image's side closest (in ratio) to [`REFERENCE_PIXELS`]'s: 640×480
/// and smaller 0; 1280×720 and 1920×1080 1; 3840×2160 2.
pub fn reference_halvings(width: usize, height: usize) -> u32 {
    let ratio = (width as f64 * height as f64 / REFERENCE_PIXELS).sqrt();
    if ratio.is_finite() && ratio > 1.0 { ratio.log2().round().min(8.0) as u32 } else { 0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hd_is_halved_once_4k_twice_and_vga_never() {
        for ((w, h), k) in [
            ((320, 240), 0),
            ((640, 480), 0),
            ((720, 576), 0),
            ((1280, 720), 1),
            ((1280, 1024), 1),
            ((1920, 1080), 1),
            ((3840, 2160), 2),
            ((0, 0), 0),
        ] {
            assert_eq!(reference_halvings(w, h), k, "{w}×{h}");
        }
    }
}
