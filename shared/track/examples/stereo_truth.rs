//! Scores the feature stereo matcher against a render's ground-truth depth: per frame, every left keypoint with
//! a stereo depth is compared with `gt/depth/<n>.pfm` at its pixel. Reports how many matches there are, the share
//! that are gross (depth off by more than `--gross` of the true depth, 10 % by default: a wrong right keypoint,
//! not a sub-pixel miss), and the nearest gross matches, which are the ones that weigh most in a pose.
//!
//! cargo run --release -p bdis-track --example stereo_truth -- --help   (the usage: `USAGE` below)
#![allow(clippy::unwrap_used, clippy::expect_used)]
use std::path::Path;

#[path = "common/sequence.rs"]
mod sequence;

const USAGE: &str = "usage: stereo_truth <dir> [--frames N] [--every K] [--gross F]";

fn main() {
    let a = sequence::args(USAGE, 1);
    let dir = Path::new(&a[1]);
    let seq = sequence::Sequence::open(dir, None);
    let frames: usize = sequence::value(&a, "--frames").map_or(seq.times.len(), |n| n.parse().unwrap());
    let every: usize = sequence::value(&a, "--every").map_or(1, |n| n.parse().unwrap());
    let gross: f32 = sequence::value(&a, "--gross").map_or(0.1, |n| n.parse().unwrap());
    let cam = seq.settings.camera.rectified(seq.width as u32, seq.height as u32).unwrap();
    let params = bdis_orb::OrbParams::from_settings(&seq.settings.orb);
    let mut frame = bdis_track::frame::Frame::empty(&cam);
    let mut builder = bdis_track::frame::FrameBuilder::new(cam, params).unwrap();
    let (mut matched, mut wrong, mut keypoints) = (0usize, 0usize, 0usize);
    let mut worst: Vec<(f32, f32, usize, f32)> = Vec::new();
    for i in (0..frames.min(seq.times.len())).step_by(every) {
        let (l, r) = seq.pair(i);
        builder.build(0, &l, &r, None, &mut frame).unwrap();
        let stem = seq.lefts[i].file_stem().unwrap().to_str().unwrap();
        let gt = bdis_core::formats::pfm::read(&dir.join(format!("gt/depth/{stem}.pfm"))).unwrap();
        keypoints += frame.keypoints.len();
        for (k, &z) in frame.keypoints.iter().zip(&frame.depth) {
            if z <= 0.0 {
                continue;
            }
            let z_true = gt.data[k.y.round() as usize * seq.width + k.x.round() as usize];
            if !z_true.is_finite() {
                continue;
            }
            matched += 1;
            if (z - z_true).abs() > gross * z_true {
                wrong += 1;
                worst.push((z / z_true, z, i, z_true));
            }
        }
    }
    worst.sort_by(|a, b| a.0.total_cmp(&b.0));
    println!(
        "{keypoints} keypoints, {matched} stereo matches on tissue, {wrong} gross ({:.2} %)",
        100.0 * wrong as f64 / matched.max(1) as f64
    );
    let near = worst.iter().filter(|w| w.0 < 0.5).count();
    println!("gross and nearer than half the true depth: {near}");
    for w in worst.iter().take(8) {
        println!("  frame {:>4}: depth {:.2} where the tissue is {:.2}", w.2, w.1, w.3);
    }
}
