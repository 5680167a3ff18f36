#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! Criterion benchmarks of the matchers at 640×480, single thread: BDIS and plain DIS with the BDIS-SLAM
//! parameters (patch 10, overlap 0.60 → stride 3) and the synthetic-colon parameters (patch 8, overlap 0.40),
//! and each with the left–right check. At 1920×1080 (issue #19): the same pair resized to 1920×1080
//! (Catmull-Rom), BDIS with the colon parameters, with and without the check — HD's cost, not HD's texture.
//! Input: `../shared/data/bdis/31` pair 1 when present, else a rendered tissue plane (bdis-synth is not a
//! dependency here, so a procedural texture stands in).
//!
//! cargo bench -p bdis-stereo --bench matcher

use bdis_stereo::{Algorithm, DisparityMap, GrayImage, Matcher, Params};
use criterion::{Criterion, criterion_group, criterion_main};

fn pair() -> (Vec<u8>, Vec<u8>, usize, usize, &'static str) {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/bdis/31");
    if let (Ok(l), Ok(r)) = (image::open(dir.join("left/1.png")), image::open(dir.join("right/1.png"))) {
        // The pipeline's grey (BT.601), as the acquisition service makes it.
        let (l, r) = (l.to_rgb8(), r.to_rgb8());
        let (w, h) = (l.width() as usize, l.height() as usize);
        let grey = |rgb: &image::RgbImage| bdis_core::pixel::gray_of_rgb(rgb.as_raw());
        return (grey(&l), grey(&r), w, h, "set31-1");
    }
    let (w, h) = (640, 480);
    let tex = |x: f32, y: f32| -> u8 {
        (128.0 + 60.0 * (x * 0.13).sin() * (y * 0.11).cos() + 40.0 * ((x + 2.0 * y) * 0.05).sin()) as u8
    };
    let l = (0..w * h).map(|i| tex((i % w) as f32, (i / w) as f32)).collect();
    let r = (0..w * h).map(|i| tex((i % w) as f32 + 12.0, (i / w) as f32)).collect();
    (l, r, w, h, "synthetic")
}

fn bench(c: &mut Criterion) {
    let (l, r, w, h, name) = pair();
    let mut group = c.benchmark_group(format!("stereo-640x480-{name}"));
    group.sample_size(30);
    for (label, params) in [
        // As the original (and the C++ figures in BENCHMARKS.md) has them: without the left–right check.
        ("bdis-slam-params", Params::default().as_published()),
        ("bdis-colon-params", Params::colon().as_published()),
        ("dis-slam-params", Params { algorithm: Algorithm::Dis, ..Params::default() }.as_published()),
        ("dis-colon-params", Params { algorithm: Algorithm::Dis, ..Params::colon() }.as_published()),
        // As the stereo service runs them: with the check (a second, mirrored pass).
        ("bdis-colon-params-lr-checked", Params::colon()),
        ("dis-colon-params-lr-checked", Params { algorithm: Algorithm::Dis, ..Params::colon() }),
    ] {
        let mut matcher = Matcher::new(params).expect("valid parameters");
        let mut out = DisparityMap::default();
        let (left, right) = (GrayImage { width: w, height: h, data: &l }, GrayImage { width: w, height: h, data: &r });
        group
            .bench_function(label, |b| b.iter(|| matcher.compute_into(left, right, &mut out).expect("same-size pair")));
    }
    group.finish();

    let (w1, h1) = (1920usize, 1080usize);
    let resize = |data: &[u8]| {
        let img = image::GrayImage::from_raw(w as u32, h as u32, data.to_vec()).expect("the pair's size");
        image::imageops::resize(&img, w1 as u32, h1 as u32, image::imageops::FilterType::CatmullRom).into_raw()
    };
    let (l1, r1) = (resize(&l), resize(&r));
    let mut group = c.benchmark_group(format!("stereo-{w1}x{h1}-{name}-resized"));
    group.sample_size(10);
    // The default halves an HD pair once before the published levels count (`Params::level_offset`); the
    // unhalved matcher beside it for the ratio.
    let unhalved = |p: Params| Params { level_offset: Some(0), ..p };
    for (label, params) in [
        ("bdis-colon-params", Params::colon().as_published()),
        ("bdis-colon-params-lr-checked", Params::colon()),
        ("bdis-colon-params-lr-checked-unhalved", unhalved(Params::colon())),
        // What the stereo service runs with a settings file's defaults (BDIS-SLAM's: patch 10, stride 3).
        ("bdis-slam-params-lr-checked", Params::default()),
        ("bdis-slam-params-lr-checked-unhalved", unhalved(Params::default())),
    ] {
        let mut matcher = Matcher::new(params).expect("valid parameters");
        let mut out = DisparityMap::default();
        let (left, right) =
            (GrayImage { width: w1, height: h1, data: &l1 }, GrayImage { width: w1, height: h1, data: &r1 });
        group
            .bench_function(label, |b| b.iter(|| matcher.compute_into(left, right, &mut out).expect("same-size pair")));
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
