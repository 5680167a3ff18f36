//! The mosaic update per keyframe at 640×480 (depth_gap 5: ~12 k points per keyframe), into maps of 10 and 100
//! keyframes' worth of points; and at 1920×1080 (issue #19; the same field of view across: the grid step and
//! margins double there, `MosaicParams::for_size`, so ~2.25× the points — 9× before they did) into a map of 10. The camera slides along a textured wall 50 mm away, 5 mm per keyframe, so each new
//! view overlaps the last dozen keyframes, as in a colonoscopy sweep. The update should not grow with the map
//! (only overlapping keyframes are visited); beside it, the original's rule (every point of the map transformed
//! and projected for every keyframe) for contrast.
//!
//! `cargo bench -p bdis-mosaic --bench mosaic`

#![allow(clippy::expect_used)] // a benchmark on generated data: a failure is a bug to see at once

use std::hint::black_box;

use bdis_mosaic::{DepthKeyframe, Mosaic, MosaicParams, RectifiedCamera};
use criterion::{BatchSize, Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Vector3};

const STEP_MM: f64 = 5.0;

/// The camera at width `w` and height `h`: 640×480's field of view across (f = 520 at 640 px).
fn intrinsics((w, h): (u32, u32)) -> RectifiedCamera {
    let f = 520.0 * f64::from(w) / 640.0;
    let (cx, cy) = ((f64::from(w) - 1.0) / 2.0, (f64::from(h) - 1.0) / 2.0);
    RectifiedCamera { fx: f, fy: f, cx, cy, bf: 5.0 * f, width: w, height: h }
}

/// The wall's depth seen from camera `k` (at x = k · STEP_MM): 50 mm with a gentle relief in world x.
struct View {
    disparity: Vec<f32>,
    confidence: Vec<f32>,
    rgb: Vec<u8>,
}

fn view(k: u64, size: (u32, u32)) -> View {
    let cam = intrinsics(size);
    let (w, h) = size;
    let n = (w * h) as usize;
    let mut v = View { disparity: vec![f32::NAN; n], confidence: vec![0.8; n], rgb: vec![0; 3 * n] };
    for y in 0..h as usize {
        for x in 0..w as usize {
            // Intersect the ray with the wall z = 50 + 2 sin(world x / 7): a few fixed-point steps.
            let (rx, ry) = ((x as f64 - cam.cx) / cam.fx, (y as f64 - cam.cy) / cam.fy);
            let mut z = 50.0;
            for _ in 0..4 {
                let wx = k as f64 * STEP_MM + rx * z;
                z = 50.0 + 2.0 * (wx / 7.0).sin() + 0.5 * (ry * z / 5.0).cos();
            }
            let i = y * w as usize + x;
            v.disparity[i] = (cam.bf / z) as f32;
            let shade = (120.0 + 60.0 * ((x ^ y) as f64 * 0.05).sin()) as u8;
            v.rgb[3 * i..3 * i + 3].copy_from_slice(&[shade, shade / 2, shade / 3]);
        }
    }
    v
}

fn keyframe(k: u64, v: &View, size: (u32, u32)) -> DepthKeyframe<'_> {
    DepthKeyframe {
        kf_id: k,
        t_capture_ns: k,
        world_from_camera: Isometry3::translation(k as f64 * STEP_MM, 0.0, 0.0),
        intrinsics: intrinsics(size),
        disparity: &v.disparity,
        confidence: &v.confidence,
        rgb: &v.rgb,
    }
}

fn map_of(n: u64, size: (u32, u32)) -> Mosaic {
    let mut m = Mosaic::new(MosaicParams::default());
    for k in 0..n {
        let v = view(k, size);
        m.insert(&keyframe(k, &v, size)).expect("a valid keyframe");
    }
    m
}

/// The original's culling loop: every point of the map into the new camera and onto its image.
fn every_point_projected(m: &Mosaic, camera_from_world: &Isometry3<f64>, size: (u32, u32)) -> usize {
    let cam = intrinsics(size);
    let (w, h) = size;
    let mut inside = 0;
    m.for_each_world_point(|xyz, _, _| {
        let p = camera_from_world * nalgebra::Point3::from(Vector3::from(xyz.map(f64::from)));
        if p.z > 0.0 {
            let (u, v) = (cam.fx * p.x / p.z + cam.cx, cam.fy * p.y / p.z + cam.cy);
            inside += usize::from(u >= 0.0 && v >= 0.0 && u < f64::from(w) && v < f64::from(h));
        }
    });
    inside
}

fn bench(c: &mut Criterion) {
    for (size, maps) in [((640u32, 480u32), &[10u64, 100][..]), ((1920, 1080), &[10][..])] {
        bench_size(c, size, maps);
    }
}

fn bench_size(c: &mut Criterion, size: (u32, u32), maps: &[u64]) {
    let mut group = c.benchmark_group(format!("mosaic_update_{}x{}", size.0, size.1));
    if size.0 > 640 {
        group.sample_size(10);
    }
    for &n in maps {
        let map = map_of(n, size);
        let next = view(n, size);
        let report = map.clone().insert(&keyframe(n, &next, size)).expect("a valid keyframe");
        eprintln!(
            "map of {n} keyframes: {} points; the next keyframe visits {} keyframes, tests {} points",
            map.n_points(),
            report.overlapping_keyframes,
            report.tested
        );
        group.bench_function(format!("into_{n}_keyframes"), |b| {
            b.iter_batched(
                || map.clone(),
                // The map is returned so that dropping it is not timed.
                |mut m| {
                    black_box(m.insert(&keyframe(n, &next, size)).expect("a valid keyframe"));
                    m
                },
                BatchSize::LargeInput,
            )
        });
        let camera_from_world = Isometry3::translation(n as f64 * STEP_MM, 0.0, 0.0).inverse();
        group.bench_function(format!("original_rule_scan_{n}_keyframes"), |b| {
            b.iter(|| black_box(every_point_projected(&map, &camera_from_world, size)))
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(30);
    targets = bench
}
criterion_main!(benches);
