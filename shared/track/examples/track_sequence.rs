//! Tracks a sequence folder (left/*.png, right/*.png sorted by number, times.txt, settings.yaml unless
//! `--settings F` is given) offline and writes the trajectory as TUM, with a per-frame line on standard error:
//! a development tool (the product runs the `bdis-tracking` service).
//!
//! cargo run --release -p bdis-track --example track_sequence -- --help   (the usage: `USAGE` below)
//!
//! `--online F` writes each frame's pose as the tracker gave it at the time (TUM, world_from_camera, then the
//! pose method's name): before the trajectory's re-expression through keyframes and the veils' bridges.
//! `--dump-map F` writes the finished map's keyframes and observations for `observation_truth.py` (beside this).
#![allow(clippy::unwrap_used, clippy::expect_used)]
use std::io::Write;

#[path = "common/sequence.rs"]
mod sequence;

const USAGE: &str = "usage: track_sequence <dir> <out.tum> [max frames] [--whole-pixel] [--settings F] [--verbose]\n    [--dump-map F] [--online F] [--no-loop-closing] [--instrument-masks off]";

fn main() {
    let a = sequence::args(USAGE, 2);
    let dir = std::path::Path::new(&a[1]);
    let max: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(usize::MAX);
    let settings_path = a.iter().position(|x| x == "--settings").map(|i| std::path::PathBuf::from(&a[i + 1]));
    let verbose = a.iter().any(|x| x == "--verbose");
    let seq = sequence::Sequence::open(dir, settings_path.as_deref());
    let times = &seq.times;
    let mut tracker = seq.tracker();
    let mut masker = sequence::masker(&a);
    tracker.set_refinement(!a.iter().any(|x| x == "--whole-pixel"));
    tracker.set_loop_closing(!a.iter().any(|x| x == "--no-loop-closing"));
    let online_path = a.iter().position(|x| x == "--online").map(|i| std::path::PathBuf::from(&a[i + 1]));
    let mut online: Vec<String> = Vec::new();
    let mut cpu = Vec::new();
    let mut kf_ms = Vec::new();
    let mut steps = [0.0f64; 5];
    let (mut detect_ms, mut wait_ms) = (Vec::new(), Vec::new());
    for (i, &t) in times.iter().enumerate().take(max) {
        let frame = seq.frame(i, masker.is_some());
        // Timed as the service times a frame: the instrument estimate is the tracking thread's work.
        let start = std::time::Instant::now();
        let keep_out = sequence::keep_out(masker.as_mut(), frame.left_rgb.as_ref());
        let res = tracker.track_masked((t * 1e9).round() as u64, &frame.left, &frame.right, keep_out).unwrap();
        let ms = start.elapsed().as_secs_f64() * 1e3;
        if let Some(c) = res.camera_from_world.filter(|_| online_path.is_some()) {
            let w = c.inverse();
            let (q, p) = (w.rotation.quaternion(), w.translation.vector);
            let method = res.quality.method.name();
            online.push(format!("{t:.6} {} {} {} {} {} {} {} {method}", p.x, p.y, p.z, q.i, q.j, q.k, q.w));
        }
        if let Some(m) = &res.mapper {
            for (total, step) in steps.iter_mut().zip(m.step_ms) {
                *total += step;
            }
        }
        if res.new_keyframe.is_some() {
            kf_ms.push(ms);
        } else {
            cpu.push(ms);
        }
        if let Some(m) = &res.mapper {
            detect_ms.push(m.loop_detect_ms);
            wait_ms.push(m.loop_apply_ms);
        }
        if let Some(m) = &res.mapper
            && (m.loop_closed.is_some() || m.pose_graph.is_some() || m.global_ba_keyframes > 0)
        {
            eprintln!(
                "frame {i}: loop {:?} (drift χ² {:.1}, fused {}, moved {}), pose graph {:?} ({:.1} ms on the worker), global BA {} keyframes {} points {} iterations ({:.1} ms on its thread), detection {:.1} ms, applied in {:.1} ms",
                m.loop_closed,
                m.loop_drift_chi2,
                m.fused,
                m.moved.len(),
                m.pose_graph,
                m.pose_graph_ms,
                m.global_ba_keyframes,
                m.global_ba_points,
                m.global_ba_iterations,
                m.global_ba_ms,
                m.loop_detect_ms,
                m.loop_apply_ms
            );
        }
        if verbose || i % 20 == 0 || res.state != bdis_track::TrackingState::Ok {
            let q = &res.quality;
            eprintln!(
                "frame {i}: {:?} {} {} inliers {}/{} rms {:.2} px σ_c/z {:.5} σ_r {:.3}° app {}/{} agree {:.2}{} kf {:?} {:.1} ms, map {} kfs {} points",
                res.state,
                q.method.name(),
                q.doubt.map_or("", |d| d.name()),
                q.inliers,
                q.matched,
                q.reprojection_rms_px,
                q.position_sigma_rel,
                q.rotation_sigma_deg,
                q.appearance_consensus,
                q.appearance_matches,
                q.appearance_agreement,
                if q.prior_rejected { " prior-rejected" } else { "" },
                res.new_keyframe,
                ms,
                tracker.map().n_good_keyframes(),
                tracker.map().points.iter().filter(|p| !p.bad).count()
            );
        }
    }
    tracker.finish();
    eprintln!("loops closed: {:?}", tracker.loops_closed());
    for (name, v) in
        [("place recognition (worker)", &mut detect_ms), ("loop result taken (tracking thread)", &mut wait_ms)]
    {
        v.sort_by(f64::total_cmp);
        if !v.is_empty() {
            eprintln!(
                "{name} per keyframe: median {:.1} ms, p90 {:.1} ms, max {:.1} ms",
                v[v.len() / 2],
                v[v.len() * 9 / 10],
                v[v.len() - 1]
            );
        }
    }
    eprintln!("refined measurements: σ {:.3} of their octave's", tracker.map().refined_sigma);
    cpu.sort_by(f64::total_cmp);
    kf_ms.sort_by(f64::total_cmp);
    eprintln!(
        "per frame (no keyframe): median {:.1} ms; keyframe frames: {} median {:.1} ms",
        cpu.get(cpu.len() / 2).copied().unwrap_or(0.0),
        kf_ms.len(),
        kf_ms.get(kf_ms.len() / 2).copied().unwrap_or(0.0)
    );
    let n = kf_ms.len().max(1) as f64;
    eprintln!(
        "local mapping per keyframe (mean ms, tracking thread): observations {:.1}, new points {:.1}, fusion {:.1}, waiting for BA {:.1}, snapshot + culling {:.1}",
        steps[0] / n,
        steps[1] / n,
        steps[2] / n,
        steps[3] / n,
        steps[4] / n
    );
    if let Some(i) = a.iter().position(|x| x == "--dump-map") {
        dump_map(tracker.map(), std::path::Path::new(&a[i + 1]));
    }
    if let Some(path) = &online_path {
        std::fs::write(path, online.join("\n") + "\n").unwrap();
    }
    let mut out = std::fs::File::create(&a[2]).unwrap();
    for (t_ns, pose, _lost) in tracker.trajectory() {
        let q = pose.rotation.quaternion();
        let p = pose.translation.vector;
        writeln!(out, "{:.6} {} {} {} {} {} {} {}", t_ns as f64 * 1e-9, p.x, p.y, p.z, q.i, q.j, q.k, q.w).unwrap();
    }
}

/// Every good point's observations in good keyframes, one line each:
/// `point kf t_s u v octave u_right refined first_kf x y z spread` (spread: the measurement's σ as a factor of
/// the aligned σ), and every good keyframe's estimated pose.
fn dump_map(map: &bdis_track::map::Map, path: &std::path::Path) {
    let mut out = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    for kf in map.good_keyframes() {
        let w = kf.camera_from_world.inverse();
        let q = w.rotation.quaternion();
        let p = w.translation.vector;
        writeln!(
            out,
            "K {} {:.6} {} {} {} {} {} {} {}",
            kf.id,
            kf.t_ns as f64 * 1e-9,
            p.x,
            p.y,
            p.z,
            q.i,
            q.j,
            q.k,
            q.w
        )
        .unwrap();
    }
    for pt in map.points.iter().filter(|p| !p.bad) {
        for (kf_id, &idx) in &pt.observations {
            let kf = &map.keyframes[*kf_id];
            if kf.bad {
                continue;
            }
            let kp = &kf.keypoints[idx];
            writeln!(
                out,
                "O {} {} {:.6} {} {} {} {} {} {} {} {} {} {}",
                pt.id,
                kf_id,
                kf.t_ns as f64 * 1e-9,
                kp.x,
                kp.y,
                kp.octave,
                kf.u_right[idx],
                u8::from(kf.aligned[idx].is_some()),
                pt.first_kf,
                pt.position.x,
                pt.position.y,
                pt.position.z,
                kf.aligned[idx].unwrap_or(1.0)
            )
            .unwrap();
        }
    }
}
