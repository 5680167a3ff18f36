//! The per-frame cost of rectification: one stereo pair remapped (both sides, RGB and grey), at 640×480 and
//! 1920×1080, single thread. The maps are built once per run and not timed here (see BENCHMARKS.md).
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use bdis_rectify::{CameraModel, RectifyMap, StereoCalibration, stereo_rectify};
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Matrix3, Vector3};
use std::hint::black_box;

fn maps(w: usize, h: usize) -> [RectifyMap; 2] {
    let f = 0.8 * w as f64;
    let camera = CameraModel {
        k: Matrix3::new(f, 0.0, w as f64 / 2.0, 0.0, f, h as f64 / 2.0, 0.0, 0.0, 1.0),
        distortion: [-0.3, 0.1, 0.001, -0.001, -0.01, 0.05, 0.01, 0.002],
    };
    let calib = StereoCalibration {
        source: "bench".into(),
        left: camera,
        right: camera,
        rotation: nalgebra::Rotation3::from_scaled_axis(Vector3::new(0.01, -0.02, 0.005)).into_inner(),
        translation: Vector3::new(-5.0, 0.1, 0.05),
        size: None,
        given: None,
    };
    let size = (w as u32, h as u32);
    let rect = stereo_rectify(&calib, size, Some(0.0));
    [
        RectifyMap::new(&calib.left, &rect.r_left, &rect.p_left, (w, h), (w, h)),
        RectifyMap::new(&calib.right, &rect.r_right, &rect.p_right, (w, h), (w, h)),
    ]
}

fn bench(c: &mut Criterion) {
    for (w, h) in [(640usize, 480usize), (1920, 1080)] {
        let [left, right] = maps(w, h);
        for channels in [3usize, 1] {
            let raw: Vec<u8> = (0..w * h * channels).map(|i| (i * 7 % 256) as u8).collect();
            let (mut a, mut b) = (vec![0u8; w * h * channels], vec![0u8; w * h * channels]);
            let name = format!("remap pair {w}x{h} {}", if channels == 3 { "rgb" } else { "grey" });
            c.bench_function(&name, |bench| {
                bench.iter(|| {
                    left.remap(black_box(&raw), channels, &mut a);
                    right.remap(black_box(&raw), channels, &mut b);
                })
            });
        }
        c.bench_function(&format!("build both maps {w}x{h}"), |bench| bench.iter(|| black_box(maps(w, h))));
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
