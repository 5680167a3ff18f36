//! The per-frame cost of reading a stereo source into the packed frame layout, as acquisition does:
//! `cargo run --release -p bdis-source --example decode_cost -- [--calibration RAW] SOURCE...` (a sequence
//! folder or a `video:` source; `decode_cost.sh` makes a set from real footage at 640×480 and 1920×1080). With
//! `--calibration`, every frame is also rectified as it is read, as acquisition does with its `--calibration`.
//!
//! Per source: the median wall time per frame on the reading thread (what a frame waits), that thread's CPU
//! per frame, and, for a video, the ffmpeg child's CPU per frame (from `getrusage(RUSAGE_CHILDREN)` once it
//! has been reaped): decoding runs in the child, on whichever core is free. Y4M and MJPEG AVI are decoded on
//! the reading thread (no child): their decoder is named after the source.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::mem::MaybeUninit;
use std::path::Path;
use std::time::Instant;

fn children_cpu_s() -> f64 {
    // SAFETY: getrusage writes the struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) };
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    s(usage.ru_utime) + s(usage.ru_stime)
}

fn main() {
    // `--calibration FILE` first: every source is also rectified as it is read (acquisition's --calibration).
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let calibration = match args.first().map(String::as_str) {
        Some("--calibration") if args.len() > 1 => {
            let file = args[1].clone();
            args.drain(..2);
            Some(bdis_rectify::StereoCalibration::load(Path::new(&file)).unwrap())
        }
        _ => None,
    };
    println!("{:<80} {:>7} {:>11} {:>13} {:>12}", "source", "frames", "wall ms p50", "thread CPU ms", "ffmpeg CPU ms");
    for source in args {
        let sequence = match bdis_source::Sequence::open(Path::new(&source)) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{e}");
                std::process::exit(1);
            }
        };
        let layout = bdis_ipc::FrameLayout::packed(sequence.width, sequence.height).unwrap();
        let mut payload = vec![MaybeUninit::new(0u8); layout.payload_len()];
        let children_before = children_cpu_s();
        let mut reader = bdis_source::FrameReader::new(&sequence);
        if let Some(calib) = &calibration {
            let raw = (sequence.width, sequence.height);
            let rect = calib.rectification(raw, None).unwrap();
            reader = reader.with_rectifier(bdis_source::Rectifier::new(calib.maps(&rect, raw)).unwrap());
        }
        reader.prepare(&sequence.frames[0]).unwrap();
        let mut wall_ms = Vec::with_capacity(sequence.len());
        let cpu_start = bdis_ipc::clock::thread_cpu_ns();
        for entry in &sequence.frames {
            let t = Instant::now();
            reader.read_into(entry, &layout, &mut payload).unwrap();
            wall_ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let thread_cpu_ms = (bdis_ipc::clock::thread_cpu_ns() - cpu_start) as f64 / 1e6 / sequence.len() as f64;
        drop(reader);
        let child_ms = (children_cpu_s() - children_before) * 1e3 / sequence.len() as f64;
        wall_ms.sort_by(f64::total_cmp);
        let decoder = sequence.video.as_ref().map_or(String::new(), |v| format!(", {}", v.decoder));
        let name = format!("{source} ({}×{}{decoder})", sequence.width, sequence.height);
        println!(
            "{:<80} {:>7} {:>11.2} {:>13.2} {:>12.2}",
            name.chars().rev().take(80).collect::<Vec<_>>().into_iter().rev().collect::<String>(),
            sequence.len(),
            wall_ms[wall_ms.len() / 2],
            thread_cpu_ms,
            child_ms
        );
    }
}
