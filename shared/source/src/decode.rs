//! Decoding a stereo pair straight into a frame payload (normally a loaned shared-memory slice).
//!
//! The decoder fills two buffers this struct owns and reuses; the payload is then written exactly once: left
//! grey, right grey, left RGB, every byte, so a `MaybeUninit` loan can be declared initialised afterwards.

use std::mem::MaybeUninit;
use std::path::{Path, PathBuf};

use bdis_core::pixel::gray_of;
use bdis_ipc::FrameLayout;
use image::{ColorType, ImageDecoder};

#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    #[error("{path}: cannot decode: {detail}")]
    Decode { path: PathBuf, detail: String },
    #[error("{path}: size {w}×{h}, expected {ew}×{eh}")]
    Size { path: PathBuf, w: u32, h: u32, ew: u32, eh: u32 },
    #[error("{path}: unsupported pixel format {color:?}")]
    Format { path: PathBuf, color: ColorType },
}

/// Decodes pairs into frame payloads; owns its decode buffers so a warmed-up frame reuses them.
#[derive(Debug, Default)]
pub struct FrameDecoder {
    left: Vec<u8>,
    right: Vec<u8>,
}

/// A decoded image in one of our buffers.
pub(crate) struct Decoded {
    pub(crate) color: ColorType,
}

/// BT.601 studio-range YUV to full-range RGB, in 8-bit fixed point (capture devices, Y4M).
#[inline]
pub(crate) fn rgb_of_yuv(y: u8, u: u8, v: u8) -> [u8; 3] {
    let c = 298 * (i32::from(y) - 16) + 128;
    let (d, e) = (i32::from(u) - 128, i32::from(v) - 128);
    let clamp = |x: i32| (x >> 8).clamp(0, 255) as u8;
    [clamp(c + 409 * e), clamp(c - 100 * d - 208 * e), clamp(c + 516 * d)]
}

pub(crate) fn decode_into(path: &Path, buf: &mut Vec<u8>, width: u32, height: u32) -> Result<Decoded, DecodeError> {
    let fail = |detail: String| DecodeError::Decode { path: path.to_path_buf(), detail };
    let decoder = image::ImageReader::open(path)
        .map_err(|e| fail(e.to_string()))?
        .with_guessed_format()
        .map_err(|e| fail(e.to_string()))?
        .into_decoder()
        .map_err(|e| fail(e.to_string()))?;
    let (w, h) = decoder.dimensions();
    if (w, h) != (width, height) {
        return Err(DecodeError::Size { path: path.to_path_buf(), w, h, ew: width, eh: height });
    }
    let color = decoder.color_type();
    if !matches!(
        color,
        ColorType::L8
            | ColorType::La8
            | ColorType::Rgb8
            | ColorType::Rgba8
            | ColorType::L16
            | ColorType::La16
            | ColorType::Rgb16
            | ColorType::Rgba16
    ) {
        return Err(DecodeError::Format { path: path.to_path_buf(), color });
    }
    let total = usize::try_from(decoder.total_bytes()).map_err(|_| fail("image too large".into()))?;
    // Grows once to the frame size and is reused after that.
    buf.resize(total, 0);
    decoder.read_image(buf).map_err(|e| fail(e.to_string()))?;
    Ok(Decoded { color })
}

/// Reads pixel `i` of a decoded buffer as 8-bit RGB (16-bit samples keep their high byte).
#[inline]
pub(crate) fn rgb_at(buf: &[u8], color: ColorType, i: usize) -> (u8, u8, u8) {
    let hi16 = |k: usize| u16::from_ne_bytes([buf[2 * k], buf[2 * k + 1]]).to_be_bytes()[0];
    match color {
        ColorType::L8 => (buf[i], buf[i], buf[i]),
        ColorType::La8 => (buf[2 * i], buf[2 * i], buf[2 * i]),
        ColorType::Rgb8 => (buf[3 * i], buf[3 * i + 1], buf[3 * i + 2]),
        ColorType::Rgba8 => (buf[4 * i], buf[4 * i + 1], buf[4 * i + 2]),
        ColorType::L16 => (hi16(i), hi16(i), hi16(i)),
        ColorType::La16 => (hi16(2 * i), hi16(2 * i), hi16(2 * i)),
        ColorType::Rgb16 => (hi16(3 * i), hi16(3 * i + 1), hi16(3 * i + 2)),
        _ => (hi16(4 * i), hi16(4 * i + 1), hi16(4 * i + 2)),
    }
}

impl FrameDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Decodes the pair and writes every byte of `layout` into `payload` (which must be `layout.payload_len()`
    /// long and packed, as [`FrameLayout::packed`] makes it). A grey source image gives R = G = B.
    pub fn decode_pair_into(
        &mut self,
        left_path: &Path,
        right_path: &Path,
        layout: &FrameLayout,
        payload: &mut [MaybeUninit<u8>],
    ) -> Result<(), DecodeError> {
        let (w, h) = (layout.width, layout.height);
        let left = decode_into(left_path, &mut self.left, w, h)?;
        let right = decode_into(right_path, &mut self.right, w, h)?;
        debug_assert_eq!(Some(*layout), FrameLayout::packed(w, h));
        let n = w as usize * h as usize;
        let (left_gray, rest) = payload.split_at_mut(n);
        let (right_gray, rgb) = rest.split_at_mut(n);
        let rgb = &mut rgb[..3 * n];
        for i in 0..n {
            let (r, g, b) = rgb_at(&self.left, left.color, i);
            left_gray[i].write(gray_of(r, g, b));
            rgb[3 * i].write(r);
            rgb[3 * i + 1].write(g);
            rgb[3 * i + 2].write(b);
            let (r, g, b) = rgb_at(&self.right, right.color, i);
            right_gray[i].write(gray_of(r, g, b));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_every_byte_of_the_payload() {
        let dir = std::env::temp_dir().join(format!("bdis-decode-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let rgb = image::RgbImage::from_fn(3, 2, |x, y| image::Rgb([x as u8 * 50, y as u8 * 100, 7]));
        let grey = image::GrayImage::from_fn(3, 2, |x, y| image::Luma([(x + 3 * y) as u8]));
        rgb.save(dir.join("l.png")).unwrap();
        grey.save(dir.join("r.png")).unwrap();
        let layout = FrameLayout::packed(3, 2).unwrap();
        let mut payload = vec![MaybeUninit::new(0xAAu8); layout.payload_len()];
        FrameDecoder::new().decode_pair_into(&dir.join("l.png"), &dir.join("r.png"), &layout, &mut payload).unwrap();
        let bytes: Vec<u8> = payload.iter().map(|b| unsafe { b.assume_init() }).collect();
        assert_eq!(&bytes[6..12], &[0, 1, 2, 3, 4, 5], "right grey copied through");
        assert_eq!(&bytes[12..15], &[0, 0, 7], "left RGB pixel (0,0)");
        assert_eq!(&bytes[27..30], &[100, 100, 7], "left RGB pixel (2,1)");
        assert_eq!(bytes[0], gray_of(0, 0, 7));
        let e = FrameDecoder::new()
            .decode_pair_into(&dir.join("l.png"), &dir.join("missing.png"), &layout, &mut payload)
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing.png: cannot decode"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
