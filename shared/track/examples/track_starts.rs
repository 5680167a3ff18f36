//! Tracks a sequence offline from several start frames and scores each run against the ground truth: ATE, the
//! scale error (a Sim(3) fit) and the ATE left after it, per start and as medians. A single run cannot tell
//! ±20 % apart (the start frame alone moves the ATE by up to 2×), so figures here are medians over starts.
//! A development tool; for one run with diagnostics use `track_sequence`.
//!
//! cargo run --release -p bdis-track --example track_starts -- --help   (the usage: `USAGE` below)
//!
//! Frames are tracked with the instrument estimate, as the tracking service tracks them by default.
//! Per start it also counts the frames `Lost` and `Uncertain`; `--loops` lists the loops closed (on stderr).
//! Start K tracks frames K … K + N − 1 (N: all that are left); `--gt` defaults to `<dir>/gt/poses.tum`;
//! `--out PREFIX` writes each start's trajectory to PREFIX-K.tum.
#![allow(clippy::unwrap_used, clippy::expect_used)]
use bdis_core::geometry::StampedPose;
use std::path::{Path, PathBuf};

#[path = "common/sequence.rs"]
mod sequence;

const USAGE: &str = "usage: track_starts <dir> --starts 0,3,7,11 [--frames N] [--gt F] [--settings F] [--whole-pixel]\n    [--no-loop-closing] [--out PREFIX] [--loops] [--instrument-masks off]";

fn main() {
    let a = sequence::args(USAGE, 1);
    let dir = Path::new(&a[1]);
    let starts: Vec<usize> = sequence::value(&a, "--starts")
        .unwrap_or("0")
        .split(',')
        .map(|k| k.trim().parse().expect("--starts: K,K,..."))
        .collect();
    let frames: usize = sequence::value(&a, "--frames").map_or(usize::MAX, |n| n.parse().expect("--frames: a count"));
    let gt_path = sequence::value(&a, "--gt").map_or_else(|| dir.join("gt/poses.tum"), PathBuf::from);
    let gt = bdis_core::formats::trajectory::read_tum(&gt_path).unwrap();
    let seq = sequence::Sequence::open(dir, sequence::value(&a, "--settings").map(Path::new));
    let (mut ates, mut scales, mut sim3s) = (Vec::new(), Vec::new(), Vec::new());
    println!("start  frames  keyframes  loops  ATE          scale error  ATE after Sim(3)  lost  uncertain");
    for &k in &starts {
        let mut tracker = seq.tracker();
        let mut masker = sequence::masker(&a);
        tracker.set_refinement(!a.iter().any(|x| x == "--whole-pixel"));
        tracker.set_loop_closing(!a.iter().any(|x| x == "--no-loop-closing"));
        let end = seq.times.len().min(k.saturating_add(frames));
        let (mut keyframes, mut lost, mut uncertain) = (0, 0, 0);
        for i in k..end {
            let res = seq.track(&mut tracker, masker.as_mut(), i);
            keyframes += usize::from(res.new_keyframe.is_some());
            lost += usize::from(res.state == bdis_track::TrackingState::Lost);
            uncertain += usize::from(res.state == bdis_track::TrackingState::Uncertain);
        }
        tracker.finish();
        if a.iter().any(|x| x == "--loops") {
            eprintln!("loops closed (keyframe, old keyframe): {:?}", tracker.loops_closed());
        }
        let est: Vec<StampedPose> = tracker
            .trajectory()
            .into_iter()
            .map(|(t_ns, world_from_camera, _)| StampedPose { t_s: t_ns as f64 * 1e-9, world_from_camera })
            .collect();
        if let Some(prefix) = sequence::value(&a, "--out") {
            bdis_core::formats::trajectory::write_tum(Path::new(&format!("{prefix}-{k}.tum")), &est).unwrap();
        }
        let ate = bdis_eval::traj::ate(&gt, &est, 0.01).unwrap();
        let scale = 100.0 * (ate.sim3.est_over_gt - 1.0);
        println!(
            "{k:>5}  {:>6}  {keyframes:>9}  {:>5}  {:<11.6}  {scale:>+10.3} %  {:<16.6}  {lost:>4}  {uncertain:>9}",
            end - k,
            tracker.loops_closed().len(),
            ate.translation.rmse,
            ate.sim3.translation.rmse
        );
        ates.push(ate.translation.rmse);
        scales.push(scale);
        sim3s.push(ate.sim3.translation.rmse);
    }
    println!(
        "median over {} starts: ATE {:.6}, scale error {:+.3} %, ATE after Sim(3) {:.6}",
        starts.len(),
        bdis_eval::Stats::of(&mut ates).median,
        bdis_eval::Stats::of(&mut scales).median,
        bdis_eval::Stats::of(&mut sim3s).median
    );
}
