#![allow(clippy::expect_used)] // benchmark code: a panic is the failure report
//! Criterion benchmark: tracking CPU per frame at 640×480 with 1000 features (ORB on both images, stereo
//! matching, pose, local map, keyframes with their inline local mapping), single thread. Input: the first 40
//! frames of the synthetic colon flight (`bdis-slam synth`, default rig), rendered into a temporary folder, or
//! the folder in `BDIS_BENCH_SEQUENCE` at its own size (e.g. a 1920×1080 render for issue #19; the group is
//! named by the size). One iteration tracks all 40 frames with a new tracker; the figure per
//! frame is the time divided by 40. Both measurement modes: `aligned` (the default, `refine.rs`) and
//! `whole-pixel` (ORB-SLAM2's).
//!
//! cargo bench -p bdis-track --bench tracking

use bdis_track::{Tracker, TrackerSettings};
use criterion::{Criterion, criterion_group, criterion_main};

const FRAMES: usize = 40;

fn grey(path: &std::path::Path) -> Vec<u8> {
    let img = image::open(path).expect("frame").to_rgb8();
    bdis_core::pixel::gray_of_rgb(img.as_raw())
}

fn bench(c: &mut Criterion) {
    let dir = match std::env::var_os("BDIS_BENCH_SEQUENCE") {
        Some(d) => std::path::PathBuf::from(d),
        None => {
            let dir = std::env::temp_dir().join(format!("bdis-bench-tracking-{}", std::process::id()));
            let request = bdis_synth::SceneRequest { frames: FRAMES, ..Default::default() };
            bdis_synth::write_scene(&dir, &bdis_synth::default_camera(), &request, |_| {}).expect("render");
            dir
        }
    };
    let settings = bdis_core::Settings::load(&dir.join("settings.yaml")).expect("settings");
    let (width, height) = image::image_dimensions(dir.join("left/1.png")).expect("the first frame");
    let cam = settings.camera.rectified(width, height).expect("rectified images");
    let ts = TrackerSettings {
        th_depth: settings.th_depth,
        fps: settings.fps,
        orb: bdis_orb::OrbParams { n_features: 1000, ..bdis_orb::OrbParams::from_settings(&settings.orb) },
    };
    let frames: Vec<(Vec<u8>, Vec<u8>)> = (1..=FRAMES)
        .map(|n| (grey(&dir.join(format!("left/{n}.png"))), grey(&dir.join(format!("right/{n}.png")))))
        .collect();
    let mut group = c.benchmark_group(format!("tracking-{width}x{height}"));
    group.sample_size(10);
    // The product's measurements (aligned to sub-pixel) and ORB-SLAM2's whole-pixel ones, side by side.
    for (name, aligned) in [("aligned", true), ("whole-pixel", false)] {
        group.bench_function(format!("{FRAMES}-frames-{name}"), |b| {
            b.iter(|| {
                let mut tracker = Tracker::new(cam, ts).expect("settings");
                tracker.set_refinement(aligned);
                for (i, (l, r)) in frames.iter().enumerate() {
                    tracker.track(i as u64 * 33_333_333, l, r).expect("frame");
                }
            })
        });
    }
    group.finish();
    if std::env::var_os("BDIS_BENCH_SEQUENCE").is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
