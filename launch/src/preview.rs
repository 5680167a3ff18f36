//! The picture a person looks at after dense stereo: the left image beside its colour-mapped disparity.

/// Left RGB (`3·w·h` bytes) beside the colour-mapped `disparity` (`w·h`, NaN = no answer, drawn black).
pub fn disparity_beside_image(left_rgb: &[u8], disparity: &[f32], w: u32, h: u32) -> image::RgbImage {
    let mut colours = Vec::new();
    bdis_stereo::preview::colorize(disparity, &mut colours);
    let mut both = image::RgbImage::new(2 * w, h);
    for y in 0..h {
        for x in 0..w {
            let k = 3 * (y * w + x) as usize;
            both.put_pixel(x, y, image::Rgb([left_rgb[k], left_rgb[k + 1], left_rgb[k + 2]]));
            both.put_pixel(w + x, y, image::Rgb([colours[k], colours[k + 1], colours[k + 2]]));
        }
    }
    both
}
