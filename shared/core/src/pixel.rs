//! Grey from colour, the one way every process and tool computes it.
//!
//! Acquisition greys each frame for the tracker and the stereo matcher; the tracker's instrument estimate,
//! the tests and the benchmarks grey renders the same way, so a figure measured offline is the figure the
//! pipeline would give.

/// Grey (luma) from RGB with the BT.601 weights (0.299, 0.587, 0.114) in 14-bit fixed point, rounded.
#[inline]
pub fn gray_of(r: u8, g: u8, b: u8) -> u8 {
    ((u32::from(r) * 4899 + u32::from(g) * 9617 + u32::from(b) * 1868 + 8192) >> 14) as u8
}

/// Packed RGB (3 bytes per pixel) as grey, one byte per pixel; a trailing partial pixel is ignored.
pub fn gray_of_rgb(rgb: &[u8]) -> Vec<u8> {
    rgb.chunks_exact(3).map(|p| gray_of(p[0], p[1], p[2])).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_are_bt601() {
        assert_eq!(gray_of(0, 0, 0), 0);
        assert_eq!(gray_of(255, 255, 255), 255);
        assert_eq!(gray_of(255, 0, 0), 76); // 0.299 · 255 = 76.2
        assert_eq!(gray_of(0, 255, 0), 150); // 0.587 · 255 = 149.7
        assert_eq!(gray_of(0, 0, 255), 29); // 0.114 · 255 = 29.1
    }

    #[test]
    fn every_value_is_the_exact_weights_rounded() {
        // Each 14-bit weight is within 3e-5 of its exact value: at most 0.02 of a level beyond rounding.
        for (r, g, b) in (0..=255u8).step_by(5).flat_map(|r| (0..=255u8).step_by(17).map(move |g| (r, g, 255 - g))) {
            let exact = 0.299 * f64::from(r) + 0.587 * f64::from(g) + 0.114 * f64::from(b);
            assert!((f64::from(gray_of(r, g, b)) - exact).abs() <= 0.5 + 0.02, "{r} {g} {b}: {exact}");
        }
    }

    #[test]
    fn rgb_buffers_grey_pixel_by_pixel() {
        assert_eq!(gray_of_rgb(&[255, 0, 0, 0, 255, 0, 9]), vec![76, 150]);
    }
}
