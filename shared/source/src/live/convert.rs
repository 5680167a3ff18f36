//! What capture devices deliver (YUYV, NV12, MJPEG) into the frame layout: each camera's view of the device
//! image as grey (the tracker's and the dense stereo's input) and, for the left view, RGB (the map's colour).
//!
//! YUV is read as BT.601 with studio range (16–235 luma), which is what UVC and SDI grabbers send for SD and
//! what most send for HD too. Grey is the luma stretched to full range: the same quantity `gray_of` computes
//! from RGB, without a round trip through RGB.

use std::mem::MaybeUninit;

use image::ImageDecoder;

use crate::decode::rgb_of_yuv;
use bdis_core::pixel::gray_of;

/// A pixel format a capture device delivers that bdis-slam reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelFormat {
    /// Packed 4:2:2: `Y0 U Y1 V` per two pixels.
    Yuyv,
    /// Planar 4:2:0: a luma plane, then one plane of interleaved `U V` at half size in both directions.
    Nv12,
    /// A JPEG per frame (UVC devices' compressed mode).
    Mjpeg,
}

impl PixelFormat {
    pub const ALL: [PixelFormat; 3] = [PixelFormat::Yuyv, PixelFormat::Nv12, PixelFormat::Mjpeg];

    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Nv12 => *b"NV12",
            PixelFormat::Mjpeg => *b"MJPG",
        }
    }

    pub fn from_fourcc(fourcc: [u8; 4]) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.fourcc() == fourcc)
    }

    pub fn name(self) -> &'static str {
        match self {
            PixelFormat::Yuyv => "yuyv",
            PixelFormat::Nv12 => "nv12",
            PixelFormat::Mjpeg => "mjpeg",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name().eq_ignore_ascii_case(s))
    }

    /// Columns and rows a view must start and span in multiples of (chroma is shared by 2 or 2×2 pixels).
    pub fn alignment(self) -> (u32, u32) {
        match self {
            PixelFormat::Yuyv => (2, 1),
            PixelFormat::Nv12 => (2, 2),
            PixelFormat::Mjpeg => (1, 1),
        }
    }
}

/// The images a device delivers: size, bytes per row (of the luma plane for NV12) and pixel format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceFormat {
    pub width: u32,
    pub height: u32,
    pub stride: u32,
    pub pixel: PixelFormat,
}

impl DeviceFormat {
    /// Tightly packed rows.
    pub fn packed(width: u32, height: u32, pixel: PixelFormat) -> Self {
        let stride = match pixel {
            PixelFormat::Yuyv => 2 * width,
            PixelFormat::Nv12 | PixelFormat::Mjpeg => width,
        };
        Self { width, height, stride, pixel }
    }

    /// The bytes an uncompressed frame needs (0 for MJPEG, whose frames vary).
    pub fn frame_len(&self) -> usize {
        let rows = self.stride as usize * self.height as usize;
        match self.pixel {
            PixelFormat::Yuyv => rows,
            PixelFormat::Nv12 => rows + rows / 2,
            PixelFormat::Mjpeg => 0,
        }
    }
}

/// One camera's rectangle of the device image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct View {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

#[derive(Debug, thiserror::Error)]
pub enum ConvertError {
    #[error("a {} frame of {len} bytes, {need} expected for {width}×{height}", .format.name())]
    Short { format: PixelFormat, len: usize, need: usize, width: u32, height: u32 },
    #[error("a corrupt MJPEG frame: {0}")]
    Jpeg(String),
    #[error("an MJPEG frame of {got_w}×{got_h}, the device said {width}×{height}")]
    JpegSize { got_w: u32, got_h: u32, width: u32, height: u32 },
}

/// Decodes device frames; owns the buffer a compressed frame is decoded into, reused frame after frame.
#[derive(Debug, Default)]
pub struct Converter {
    rgb: Vec<u8>,
    /// A frame completed with the standard Huffman tables, when it came without them.
    completed: Vec<u8>,
}

/// A device frame ready to be cut into views.
#[derive(Debug, Clone, Copy)]
pub struct Decoded<'a> {
    source: Source<'a>,
    height: u32,
}

#[derive(Debug, Clone, Copy)]
enum Source<'a> {
    Yuyv { data: &'a [u8], stride: usize },
    Nv12 { data: &'a [u8], stride: usize },
    Rgb { data: &'a [u8], stride: usize },
}

impl Converter {
    pub fn new() -> Self {
        Self::default()
    }

    /// Checks a frame's size (an uncompressed one) or decodes it (MJPEG), so its views can be taken.
    pub fn decode<'a>(&'a mut self, data: &'a [u8], format: &DeviceFormat) -> Result<Decoded<'a>, ConvertError> {
        let (width, height) = (format.width, format.height);
        let need = format.frame_len();
        if data.len() < need {
            return Err(ConvertError::Short { format: format.pixel, len: data.len(), need, width, height });
        }
        let stride = format.stride as usize;
        let source = match format.pixel {
            PixelFormat::Yuyv => Source::Yuyv { data, stride },
            PixelFormat::Nv12 => Source::Nv12 { data, stride },
            PixelFormat::Mjpeg => {
                let jpeg = |e: image::ImageError| ConvertError::Jpeg(e.to_string());
                // UVC devices send Motion-JPEG without Huffman tables: the standard ones are meant.
                let data = crate::jpeg::with_huffman_tables(data, &mut self.completed);
                let decoder = image::codecs::jpeg::JpegDecoder::new(std::io::Cursor::new(data)).map_err(jpeg)?;
                let (got_w, got_h) = decoder.dimensions();
                if (got_w, got_h) != (width, height) {
                    return Err(ConvertError::JpegSize { got_w, got_h, width, height });
                }
                let color = decoder.color_type();
                let bytes = usize::try_from(decoder.total_bytes()).unwrap_or(usize::MAX);
                self.rgb.resize(bytes.max(3 * width as usize * height as usize), 0);
                decoder.read_image(&mut self.rgb[..bytes]).map_err(jpeg)?;
                match color {
                    image::ColorType::Rgb8 => {}
                    // A grey JPEG: spread in place from the back, so every pixel reads before it is overwritten.
                    image::ColorType::L8 => {
                        for i in (0..width as usize * height as usize).rev() {
                            let v = self.rgb[i];
                            self.rgb[3 * i..3 * i + 3].fill(v);
                        }
                    }
                    other => return Err(ConvertError::Jpeg(format!("unsupported colour type {other:?}"))),
                }
                Source::Rgb { data: &self.rgb, stride: 3 * width as usize }
            }
        };
        Ok(Decoded { source, height })
    }
}

/// Studio-range luma to full-range grey.
#[inline]
fn gray_of_luma(y: u8) -> u8 {
    ((298 * (i32::from(y) - 16) + 128) >> 8).clamp(0, 255) as u8
}

impl Decoded<'_> {
    /// Writes `view` as grey into `gray` (`width × height` bytes) and, when asked, as RGB into `rgb` (three
    /// times that). The view lies inside the frame and is aligned to its format (`PixelFormat::alignment`):
    /// the source checks both when it opens the device.
    pub fn view_into(&self, view: View, gray: &mut [MaybeUninit<u8>], mut rgb: Option<&mut [MaybeUninit<u8>]>) {
        let (w, x0) = (view.width as usize, view.x as usize);
        for row in 0..view.height as usize {
            let y = view.y as usize + row;
            let gray_row = &mut gray[row * w..(row + 1) * w];
            let mut rgb_row = rgb.as_deref_mut().map(|rgb| &mut rgb[3 * row * w..3 * (row + 1) * w]);
            match self.source {
                Source::Yuyv { data, stride } => {
                    let src = &data[y * stride + 2 * x0..y * stride + 2 * (x0 + w)];
                    for (i, quad) in src.chunks_exact(4).enumerate() {
                        let [y0, u, y1, v] = [quad[0], quad[1], quad[2], quad[3]];
                        gray_row[2 * i].write(gray_of_luma(y0));
                        gray_row[2 * i + 1].write(gray_of_luma(y1));
                        if let Some(out) = rgb_row.as_deref_mut() {
                            for (k, luma) in [y0, y1].into_iter().enumerate() {
                                for (o, c) in
                                    out[3 * (2 * i + k)..3 * (2 * i + k) + 3].iter_mut().zip(rgb_of_yuv(luma, u, v))
                                {
                                    o.write(c);
                                }
                            }
                        }
                    }
                }
                Source::Nv12 { data, stride } => {
                    let luma = &data[y * stride + x0..y * stride + x0 + w];
                    for (o, &l) in gray_row.iter_mut().zip(luma) {
                        o.write(gray_of_luma(l));
                    }
                    if let Some(out) = rgb_row.as_deref_mut() {
                        let chroma_start = stride * self.height as usize + (y / 2) * stride + x0;
                        let chroma = &data[chroma_start..chroma_start + w];
                        for (i, &l) in luma.iter().enumerate() {
                            let (u, v) = (chroma[i & !1], chroma[(i & !1) + 1]);
                            for (o, c) in out[3 * i..3 * i + 3].iter_mut().zip(rgb_of_yuv(l, u, v)) {
                                o.write(c);
                            }
                        }
                    }
                }
                Source::Rgb { data, stride } => {
                    let src = &data[y * stride + 3 * x0..y * stride + 3 * (x0 + w)];
                    for (o, px) in gray_row.iter_mut().zip(src.chunks_exact(3)) {
                        o.write(gray_of(px[0], px[1], px[2]));
                    }
                    if let Some(out) = rgb_row {
                        for (o, &c) in out.iter_mut().zip(src) {
                            o.write(c);
                        }
                    }
                }
            }
        }
    }
}

/// RGB (tightly packed, `width × height`) to YUYV, as a device's encoder does it: BT.601 studio range, the
/// chroma of each pixel pair their mean. For the emulated device and tests.
pub fn yuyv_of_rgb(rgb: &[u8], width: u32, height: u32, out: &mut Vec<u8>) {
    out.clear();
    for px in rgb.chunks_exact(6).take(width as usize / 2 * height as usize) {
        let (a, b) = ([px[0], px[1], px[2]], [px[3], px[4], px[5]]);
        let (u, v) = chroma_of(&[a, b]);
        out.extend_from_slice(&[luma_of(a), u, luma_of(b), v]);
    }
}

/// RGB to NV12 (chroma the mean of each 2×2 block). For the emulated device and tests.
pub fn nv12_of_rgb(rgb: &[u8], width: u32, height: u32, out: &mut Vec<u8>) {
    let (w, h) = (width as usize, height as usize);
    out.clear();
    let px = |x: usize, y: usize| [rgb[3 * (y * w + x)], rgb[3 * (y * w + x) + 1], rgb[3 * (y * w + x) + 2]];
    for y in 0..h {
        for x in 0..w {
            out.push(luma_of(px(x, y)));
        }
    }
    for y in (0..h).step_by(2) {
        for x in (0..w).step_by(2) {
            let (u, v) = chroma_of(&[px(x, y), px(x + 1, y), px(x, y + 1), px(x + 1, y + 1)]);
            out.extend_from_slice(&[u, v]);
        }
    }
}

fn luma_of([r, g, b]: [u8; 3]) -> u8 {
    let (r, g, b) = (i32::from(r), i32::from(g), i32::from(b));
    (((66 * r + 129 * g + 25 * b + 128) >> 8) + 16) as u8
}

fn chroma_of(pixels: &[[u8; 3]]) -> (u8, u8) {
    let n = pixels.len() as i32;
    let sum = |k: usize| pixels.iter().map(|p| i32::from(p[k])).sum::<i32>();
    let (r, g, b) = (sum(0), sum(1), sum(2));
    let u = (((-38 * r - 74 * g + 112 * b + 128 * n) / n) >> 8) + 128;
    let v = (((112 * r - 94 * g - 18 * b + 128 * n) / n) >> 8) + 128;
    (u.clamp(0, 255) as u8, v.clamp(0, 255) as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth colour image: chroma subsampling loses little, so the round trip must come back close.
    fn image(w: u32, h: u32) -> Vec<u8> {
        let mut rgb = Vec::new();
        for y in 0..h {
            for x in 0..w {
                rgb.extend_from_slice(&[(40 + x * 3) as u8, (30 + y * 4) as u8, (200 - x - y) as u8]);
            }
        }
        rgb
    }

    fn views_of(data: &[u8], format: DeviceFormat, view: View) -> (Vec<u8>, Vec<u8>) {
        let n = (view.width * view.height) as usize;
        let (mut gray, mut rgb) = (vec![MaybeUninit::new(0); n], vec![MaybeUninit::new(0); 3 * n]);
        let mut converter = Converter::new();
        converter.decode(data, &format).unwrap().view_into(view, &mut gray, Some(&mut rgb));
        let bytes = |v: Vec<MaybeUninit<u8>>| v.into_iter().map(|b| unsafe { b.assume_init() }).collect();
        (bytes(gray), bytes(rgb))
    }

    /// Each format, encoded as a device would and converted back, gives the source's grey within a level and
    /// its colour within a few (chroma is shared by 2 or 4 pixels; JPEG is lossy) — for a view cut from the
    /// right half, as a side-by-side device delivers.
    #[test]
    #[allow(clippy::unwrap_used)]
    fn every_format_comes_back_as_the_source_grey_and_colour() {
        let (w, h) = (32u32, 12u32);
        let rgb = image(w, h);
        let view = View { x: 16, y: 2, width: 16, height: 8 };
        let expected_gray: Vec<u8> = (0..view.height)
            .flat_map(|r| (0..view.width).map(move |c| (r, c)))
            .map(|(r, c)| {
                let i = 3 * ((view.y + r) * w + view.x + c) as usize;
                gray_of(rgb[i], rgb[i + 1], rgb[i + 2])
            })
            .collect();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 98)
            .encode(&rgb, w, h, image::ExtendedColorType::Rgb8)
            .unwrap();
        let mut yuyv = Vec::new();
        yuyv_of_rgb(&rgb, w, h, &mut yuyv);
        let mut nv12 = Vec::new();
        nv12_of_rgb(&rgb, w, h, &mut nv12);
        for (pixel, data, gray_tol, rgb_tol) in
            [(PixelFormat::Yuyv, &yuyv, 1, 4), (PixelFormat::Nv12, &nv12, 1, 4), (PixelFormat::Mjpeg, &jpeg, 3, 8)]
        {
            let (gray, out_rgb) = views_of(data, DeviceFormat::packed(w, h, pixel), view);
            let worst = gray.iter().zip(&expected_gray).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
            assert!(worst <= gray_tol, "{pixel:?}: grey off by {worst}");
            let expected_rgb = (0..view.height).flat_map(|r| {
                let start = 3 * ((view.y + r) * w + view.x) as usize;
                rgb[start..start + 3 * view.width as usize].to_vec()
            });
            let worst = out_rgb.iter().zip(expected_rgb).map(|(a, b)| a.abs_diff(b)).max().unwrap();
            assert!(worst <= rgb_tol, "{pixel:?}: colour off by {worst}");
        }
    }

    #[test]
    fn short_and_corrupt_frames_are_errors_not_panics() {
        let mut converter = Converter::new();
        let format = DeviceFormat::packed(8, 4, PixelFormat::Yuyv);
        assert!(matches!(converter.decode(&[0; 10], &format), Err(ConvertError::Short { need: 64, .. })));
        let format = DeviceFormat::packed(8, 4, PixelFormat::Mjpeg);
        assert!(matches!(converter.decode(&[0xff, 0xd8, 1, 2, 3], &format), Err(ConvertError::Jpeg(_))));
        assert_eq!(PixelFormat::from_fourcc(*b"NV12"), Some(PixelFormat::Nv12));
        assert_eq!(PixelFormat::parse("MJPEG"), Some(PixelFormat::Mjpeg));
        assert_eq!(PixelFormat::from_fourcc(*b"RGB3"), None);
    }
}
