//! The per-frame cost of a live source's conversion: one side-by-side device image (both views) into the
//! packed frame — left grey + RGB, right grey — as acquisition does it, for each pixel format a grabber
//! delivers, at 640×480 and 1920×1080 per view, single thread. The image is a procedural tissue-like texture
//! (smooth colour with fine detail), the same for every format; MJPEG is encoded at quality 90, as UVC
//! devices commonly send.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::hint::black_box;
use std::mem::MaybeUninit;

use bdis_source::live::convert::{Converter, DeviceFormat, PixelFormat, View, nv12_of_rgb, yuyv_of_rgb};
use criterion::{Criterion, criterion_group, criterion_main};

fn texture(w: u32, h: u32) -> Vec<u8> {
    let mut rgb = Vec::with_capacity((3 * w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let (fx, fy) = (x as f32, y as f32);
            let smooth = (fx * 0.011).sin() * (fy * 0.017).cos();
            let fine = ((x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)) >> 13 & 31) as f32;
            let v = 120.0 + 60.0 * smooth + fine;
            rgb.extend_from_slice(&[(v + 40.0) as u8, (v * 0.6) as u8, (v * 0.5) as u8]);
        }
    }
    rgb
}

fn bench(c: &mut Criterion) {
    for (w, h) in [(640u32, 480u32), (1920, 1080)] {
        let (dw, dh) = (2 * w, h);
        let rgb = texture(dw, dh);
        let n = (w * h) as usize;
        let mut payload = vec![MaybeUninit::new(0u8); 5 * n];
        let left = View { x: 0, y: 0, width: w, height: h };
        let right = View { x: w, y: 0, width: w, height: h };
        for pixel in PixelFormat::ALL {
            let mut data = Vec::new();
            match pixel {
                PixelFormat::Yuyv => yuyv_of_rgb(&rgb, dw, dh, &mut data),
                PixelFormat::Nv12 => nv12_of_rgb(&rgb, dw, dh, &mut data),
                PixelFormat::Mjpeg => image::codecs::jpeg::JpegEncoder::new_with_quality(&mut data, 90)
                    .encode(&rgb, dw, dh, image::ExtendedColorType::Rgb8)
                    .unwrap(),
            }
            let format = DeviceFormat::packed(dw, dh, pixel);
            let mut converter = Converter::new();
            c.bench_function(&format!("live {} pair {w}x{h}", pixel.name()), |b| {
                b.iter(|| {
                    let (left_gray, rest) = payload.split_at_mut(n);
                    let (right_gray, left_rgb) = rest.split_at_mut(n);
                    let decoded = converter.decode(black_box(&data), &format).unwrap();
                    decoded.view_into(left, left_gray, Some(left_rgb));
                    decoded.view_into(right, right_gray, None);
                })
            });
        }
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
