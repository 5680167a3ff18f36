#![allow(clippy::expect_used)] // benchmark code: a panic is the failure report
//! Criterion benchmark: ORB extraction of both images of a 640×480 pair plus stereo matching, single thread,
//! 1000 and 2000 features requested. Inputs: `../shared/data/bdis/6` pair 1 (in-vivo, textured: ~1000 and ~2000
//! features are found) and `../shared/data/bdis/31` pair 1 (synthetic colon, dark: ~210 corners whatever is
//! requested). At 1920×1080 (issue #19): set 6's pair resized to 1920×1080 (Catmull-Rom; focal and baseline
//! scaled with it) — what the pyramid and the features cost at HD, not HD's own texture.
//!
//! cargo bench -p bdis-orb --bench orb

use bdis_orb::{Features, OrbExtractor, OrbParams, StereoFeatures, StereoMatcher};
use criterion::{Criterion, criterion_group, criterion_main};

fn bench(c: &mut Criterion) {
    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/bdis");
    for (w, h) in [(640u32, 480u32), (1920, 1080)] {
        let mut group = c.benchmark_group(format!("orb-stereo-{w}x{h}"));
        group.sample_size(if w > 640 { 10 } else { 30 });
        let sets: &[(&str, f32, f32)] =
            if w > 640 { &[("6", 695.877, 3743.1)] } else { &[("6", 695.877, 3743.1), ("31", 520.0, 260.0)] };
        for &(set, fx, bf) in sets {
            // The focal length and bf in pixels scale with the width.
            let scale = w as f32 / 640.0;
            let load = |side: &str| {
                image::open(data.join(format!("{set}/{side}/1.png"))).map(|i| {
                    // The pipeline's grey (BT.601), as the acquisition service makes it.
                    let rgb = i.to_rgb8();
                    let (iw, ih) = (rgb.width(), rgb.height());
                    let grey = bdis_core::pixel::gray_of_rgb(rgb.as_raw());
                    if iw == w && ih == h {
                        grey
                    } else {
                        let grey = image::GrayImage::from_raw(iw, ih, grey).expect("one byte per pixel");
                        image::imageops::resize(&grey, w, h, image::imageops::FilterType::CatmullRom).into_raw()
                    }
                })
            };
            let (Ok(l), Ok(r)) = (load("left"), load("right")) else {
                eprintln!("../shared/data/bdis/{set} not present: not benchmarked");
                continue;
            };
            bench_pair(&mut group, set, &l, &r, w, h, fx * scale, bf * scale);
        }
        group.finish();
    }
}

#[allow(clippy::too_many_arguments)]
fn bench_pair(
    group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    set: &str,
    l: &[u8],
    r: &[u8],
    w: u32,
    h: u32,
    fx: f32,
    bf: f32,
) {
    for n in [1000u32, 2000] {
        let params = OrbParams { n_features: n, ..OrbParams::default() };
        let (mut el, mut er) = (
            OrbExtractor::new(params, w as usize, h as usize).expect("params"),
            OrbExtractor::new(params, w as usize, h as usize).expect("params"),
        );
        let scales = el.scales().to_vec();
        let mut m = StereoMatcher::new();
        let (mut fl, mut fr, mut st) = (Features::default(), Features::default(), StereoFeatures::default());
        el.extract(l, &mut fl).expect("size");
        eprintln!("set {set} at {w}x{h}, {n} requested: {} features found", fl.keypoints.len());
        group.bench_function(format!("set{set}-{n}-features"), |b| {
            b.iter(|| {
                el.extract(l, &mut fl).expect("size");
                er.extract(r, &mut fr).expect("size");
                m.match_features(&fl, &fr, &el.levels, &er.levels, &scales, fx, bf, &mut st);
            })
        });
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
