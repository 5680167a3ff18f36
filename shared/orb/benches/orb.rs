#![allow(clippy::expect_used)] // benchmark code: a panic is the failure report
//! Criterion benchmark: ORB extraction of both images of a 640×480 pair plus stereo matching, single thread,
//! 1000 and 2000 features requested. Inputs: `../shared/data/bdis/6` pair 1 (in-vivo, textured: ~1000 and ~2000
//! features are found) and `../shared/data/bdis/31` pair 1 (synthetic colon, dark: ~210 corners whatever is
//! requested).
//!
//! cargo bench -p bdis-orb --bench orb

use bdis_orb::{Features, OrbExtractor, OrbParams, StereoFeatures, StereoMatcher};
use criterion::{Criterion, criterion_group, criterion_main};

fn bench(c: &mut Criterion) {
    let data = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/bdis");
    let mut group = c.benchmark_group("orb-stereo-640x480");
    group.sample_size(30);
    for (set, fx, bf) in [("6", 695.877f32, 3743.1f32), ("31", 520.0, 260.0)] {
        let load = |side: &str| image::open(data.join(format!("{set}/{side}/1.png"))).map(|i| i.to_luma8().into_raw());
        let (Ok(l), Ok(r)) = (load("left"), load("right")) else {
            eprintln!("../shared/data/bdis/{set} not present: not benchmarked");
            continue;
        };
        for n in [1000u32, 2000] {
            let params = OrbParams { n_features: n, ..OrbParams::default() };
            let (mut el, mut er) = (
                OrbExtractor::new(params, 640, 480).expect("params"),
                OrbExtractor::new(params, 640, 480).expect("params"),
            );
            let scales = el.scales().to_vec();
            let mut m = StereoMatcher::new();
            let (mut fl, mut fr, mut st) = (Features::default(), Features::default(), StereoFeatures::default());
            el.extract(&l, &mut fl).expect("size");
            eprintln!("set {set}, {n} requested: {} features found", fl.keypoints.len());
            group.bench_function(format!("set{set}-{n}-features"), |b| {
                b.iter(|| {
                    el.extract(&l, &mut fl).expect("size");
                    er.extract(&r, &mut fr).expect("size");
                    m.match_features(&fl, &fr, &el.levels, &er.levels, &scales, fx, bf, &mut st);
                })
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
