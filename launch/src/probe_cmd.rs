//! `bdis-slam probe <topic>`: a consumer that reads every frame in place and reports what it saw. In a run it
//! stands where the tracker will be; by hand it watches a live pipeline.

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::{Ipc, TelemetryPublisher, Topic, event_id, monotonic_ns};
use bdis_slam::probe::FrameChecker;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

#[derive(Debug, clap::Args)]
pub struct ProbeArgs {
    /// Topic to watch: `frames`, `depth`, `poses` or `telemetry`.
    topic: String,
    /// Checksum each frame's left RGB pixels (FNV-1a 64) into the summary.
    #[arg(long)]
    checksums: bool,
    /// Where to write the JSON summary (default: `<run folder>/<name>.json` inside a run, none otherwise).
    #[arg(long)]
    summary: Option<PathBuf>,
    /// Stop after this many frames.
    #[arg(long)]
    max_frames: Option<u64>,
    /// Depth topic: write the last keyframe as a PNG (left image beside the colour-mapped disparity).
    #[arg(long)]
    preview: Option<PathBuf>,
    /// Give up when nothing arrives for this many seconds (default: wait for end of stream or Ctrl-C).
    #[arg(long)]
    idle_timeout: Option<f64>,
    /// How long a topic may have no producer (e.g. while a stereo instance is replaced) before the probe gives up.
    #[arg(long, default_value_t = 10.0)]
    producer_grace: f64,
    /// Name of this process in the run.
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "probe")]
    name: String,
    /// Shared-memory name prefix of the run to watch.
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
}

/// Prints a status line, in place on a terminal.
fn status(line: &str) {
    let mut out = std::io::stdout();
    if out.is_terminal() {
        let _ = write!(out, "\r{line}\x1b[K");
    } else {
        let _ = writeln!(out, "{line}");
    }
    let _ = out.flush();
}

pub fn probe(args: ProbeArgs) -> Result<()> {
    match Topic::parse(&args.topic) {
        Some(Topic::Frames) => probe_frames(&args),
        Some(Topic::Telemetry) => probe_telemetry(&args),
        Some(Topic::Depth) => probe_depth(&args),
        Some(Topic::Poses) => probe_poses(&args),
        Some(t @ (Topic::Keyframes | Topic::Corrections)) => {
            bail!("topic `{}` has no probe yet (watch `poses` or `depth`)", t.short_name())
        }
        None => bail!(
            "unknown topic `{}` (topics: {})",
            args.topic,
            Topic::ALL.iter().map(|t| t.short_name()).collect::<Vec<_>>().join(", ")
        ),
    }
}

fn probe_frames(args: &ProbeArgs) -> Result<()> {
    let ipc = Ipc::open(&args.name, &args.ipc_prefix)?;
    let frames = ipc.frames()?;
    let subscriber = ipc.frame_subscriber(&frames)?;
    let listener = ipc.listener(&ipc.events(Topic::Frames)?)?;
    let consumed = ipc.notifier(&ipc.frames_consumed()?)?;
    let mut telemetry = TelemetryPublisher::new(&ipc, &args.name, Some(Topic::Frames), None)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(bdis_ipc::iox("create a WaitSet"))?;
    // The deadline both paces the status line and notices a silent producer.
    let guard = waitset
        .attach_deadline(&listener, Duration::from_secs(1))
        .map_err(bdis_ipc::iox("attach the frames listener"))?;

    let mut checker = FrameChecker::new("frames", args.checksums, &args.ipc_prefix);
    telemetry.ready();
    // Ready for a frame (an on-demand acquisition waits for it).
    bdis_ipc::notify(&consumed, event_id::JOINED)?;

    let mut window_start = monotonic_ns();
    let mut window_frames = 0u64;
    let mut last_rx = monotonic_ns();
    let mut stop_requested = false;
    let mut failure: Option<anyhow::Error> = None;
    let mut end_of_stream = false;
    let mut stream: bdis_ipc::validate::StreamGuard = Default::default();
    'outer: loop {
        let mut deadline_missed = false;
        let result = waitset
            .wait_and_process_once(|id| {
                if id.has_missed_deadline(&guard) {
                    deadline_missed = true;
                }
                CallbackProgression::Continue
            })
            .map_err(bdis_ipc::iox("wait for frames"))?;
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            stop_requested = true;
            break;
        }
        let _ = bdis_ipc::drain_events(&listener);
        telemetry.keepalive();
        loop {
            let sample = match subscriber.receive() {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(e) => {
                    failure = Some(anyhow!("receive a frame: {e:?}"));
                    break 'outer;
                }
            };
            let t_receive_ns = monotonic_ns();
            last_rx = t_receive_ns;
            let header = *sample.user_header();
            if header.is_end_of_stream() {
                if let Err(rejection) = stream.end_of_stream(header.frame_seq, "frames") {
                    telemetry.rejected(Topic::Frames, &rejection);
                    continue;
                }
                checker.end_of_stream();
                end_of_stream = true;
                break 'outer;
            }
            match bdis_ipc::validate::frame(sample.user_header(), sample.payload()) {
                Ok(view) => {
                    checker.frame(&view, t_receive_ns);
                    stream.taken(header.frame_seq, header.frame_seq, sample.origin());
                }
                Err(rejection) => {
                    telemetry.rejected(Topic::Frames, &rejection);
                    checker.malformed();
                }
            }
            drop(sample);
            let t_done_ns = monotonic_ns();
            telemetry.message(
                MessageTiming {
                    frame_seq: header.frame_seq,
                    t_capture_ns: header.t_capture_ns,
                    t_upstream_publish_ns: header.t_publish_ns,
                    t_receive_ns,
                    t_done_ns,
                },
                checker.frames_missing(),
            );
            bdis_ipc::notify(&consumed, event_id::CONSUMED)?;
            window_frames += 1;
            if args.max_frames.is_some_and(|m| checker.frames_received() >= m) {
                break 'outer;
            }
        }
        let now = monotonic_ns();
        // Every second while frames flow; every 10 s while the topic is silent (keeps logs short).
        let window_ns = now - window_start;
        if (window_frames > 0 && window_ns >= 1_000_000_000) || window_ns >= 10_000_000_000 {
            status(&checker.status_line(window_frames, (now - window_start) as f64 / 1e9));
            window_start = now;
            window_frames = 0;
        }
        if deadline_missed {
            // A silent producer: reclaim dead peers, then see whether anyone still publishes.
            ipc.cleanup_dead_nodes();
            if checker.frames_received() > 0 && frames.dynamic_config().number_of_publishers() == 0 {
                failure = Some(anyhow!(
                    "the frames producer disappeared without end of stream after {} frames",
                    checker.frames_received()
                ));
                break;
            }
            if args.idle_timeout.is_some_and(|t| (now - last_rx) as f64 / 1e9 >= t) {
                failure = Some(anyhow!("no frame for {:.1} s", (now - last_rx) as f64 / 1e9));
                break;
            }
        }
    }
    if std::io::stdout().is_terminal() {
        println!();
    }

    // The summary is written whatever happened: it is what this consumer produced.
    let summary = checker.summary();
    if let Some(path) = &summary_path(args) {
        let text = serde_json::to_string_pretty(&summary).context("serialise the probe summary")?;
        std::fs::write(path, text).with_context(|| format!("{}: cannot write the probe summary", path.display()))?;
    }
    println!(
        "{}: {} frames ({}×{}), {} missing, {} out of order, end of stream: {}, zero copy: {} ({})",
        args.name,
        summary.frames_received,
        summary.width,
        summary.height,
        summary.frames_missing,
        summary.out_of_order,
        if summary.end_of_stream { "yes" } else { "no" },
        if summary.payload_in_shared_memory { "yes" } else { "no" },
        summary.payload_mapping.as_deref().unwrap_or("-"),
    );
    if let Some(h) = summary.hop_latency_us {
        println!("{}: hop latency p50 {:.1} µs, p99 {:.1} µs; rate {:.1} Hz", args.name, h.p50, h.p99, summary.rate_hz);
    }
    match failure {
        Some(e) => {
            telemetry.failed();
            Err(e)
        }
        None => {
            if stop_requested && !end_of_stream {
                tracing::info!("stop requested");
            }
            telemetry.finished();
            Ok(())
        }
    }
}

/// Where the summary goes: `--summary`, else `<run folder>/<name>.json` inside a run.
fn summary_path(args: &ProbeArgs) -> Option<PathBuf> {
    args.summary.clone().or_else(|| {
        std::env::var_os(bdis_slam::supervisor::RUN_DIR_ENV)
            .map(|d| PathBuf::from(d).join(format!("{}.json", args.name)))
    })
}

fn probe_depth(args: &ProbeArgs) -> Result<()> {
    let ipc = Ipc::open(&args.name, &args.ipc_prefix)?;
    let depth = ipc.depth()?;
    let subscriber = ipc.depth_subscriber(&depth)?;
    let listener = ipc.listener(&ipc.events(Topic::Depth)?)?;
    let mut telemetry = TelemetryPublisher::new(&ipc, &args.name, Some(Topic::Depth), None)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(bdis_ipc::iox("create a WaitSet"))?;
    let guard = waitset
        .attach_deadline(&listener, Duration::from_secs(1))
        .map_err(bdis_ipc::iox("attach the depth listener"))?;
    let mut checker = bdis_slam::probe::DepthChecker::new("depth", &args.ipc_prefix);
    let mut last: (u32, u32, Vec<f32>, Vec<u8>) = (0, 0, Vec::new(), Vec::new());
    telemetry.ready();
    let mut no_producer_since: Option<u64> = None;
    let mut last_status = monotonic_ns();
    let mut failure = None;
    let mut stream: bdis_ipc::validate::StreamGuard = Default::default();
    'outer: loop {
        let mut deadline_missed = false;
        let result = waitset
            .wait_and_process_once(|id| {
                deadline_missed |= id.has_missed_deadline(&guard);
                CallbackProgression::Continue
            })
            .map_err(bdis_ipc::iox("wait for depth"))?;
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            break;
        }
        let _ = bdis_ipc::drain_events(&listener);
        telemetry.keepalive();
        loop {
            let sample = match subscriber.receive() {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(e) => {
                    failure = Some(anyhow!("receive a depth keyframe: {e:?}"));
                    break 'outer;
                }
            };
            let t_receive_ns = monotonic_ns();
            let header = *sample.user_header();
            if header.is_end_of_stream() {
                if let Err(rejection) = stream.end_of_stream(header.frame_seq, "depth") {
                    telemetry.rejected(Topic::Depth, &rejection);
                    continue;
                }
                checker.end_of_stream();
                break 'outer;
            }
            match bdis_ipc::validate::depth(sample.user_header(), sample.payload()) {
                Ok((view, _pose)) => {
                    checker.keyframe(&view, t_receive_ns);
                    stream.taken(header.meta.kf_id, header.frame_seq, sample.origin());
                    if args.preview.is_some() {
                        // A copy only when a preview is asked for: the sample goes back to the producer now.
                        last.0 = header.width;
                        last.1 = header.height;
                        last.2.clear();
                        last.2.extend_from_slice(view.disparity);
                        last.3.clear();
                        last.3.extend_from_slice(view.rgb);
                    }
                }
                Err(rejection) => {
                    telemetry.rejected(Topic::Depth, &rejection);
                    checker.malformed();
                }
            }
            drop(sample);
            telemetry.message(
                MessageTiming {
                    frame_seq: header.meta.kf_id,
                    t_capture_ns: header.t_capture_ns,
                    t_upstream_publish_ns: header.t_publish_ns,
                    t_receive_ns,
                    t_done_ns: monotonic_ns(),
                },
                0,
            );
        }
        let now = monotonic_ns();
        if now - last_status >= 1_000_000_000 {
            status(&checker.status_line());
            last_status = now;
        }
        if deadline_missed {
            ipc.cleanup_dead_nodes();
            // A producer may be between instances (a stereo swap); give up only after the grace period.
            if checker.received() > 0 && depth.dynamic_config().number_of_publishers() == 0 {
                let since = *no_producer_since.get_or_insert(now);
                if (now - since) as f64 / 1e9 >= args.producer_grace {
                    failure = Some(anyhow!("no depth producer for {:.0} s, and no end of stream", args.producer_grace));
                    break;
                }
            } else {
                no_producer_since = None;
            }
        }
    }
    if std::io::stdout().is_terminal() {
        println!();
    }
    let summary = checker.summary();
    if let (Some(path), true) = (&args.preview, last.0 > 0) {
        bdis_slam::preview::disparity_beside_image(&last.3, &last.2, last.0, last.1)
            .save(path)
            .with_context(|| format!("{}: cannot write the preview", path.display()))?;
    }
    if let Some(path) = summary_path(args) {
        let text = serde_json::to_string_pretty(&summary).context("serialise the probe summary")?;
        std::fs::write(&path, text).with_context(|| format!("{}: cannot write the probe summary", path.display()))?;
    }
    println!(
        "{}: {} keyframes ({} duplicates), mean density {:.1} %, end of stream: {}, zero copy: {}",
        args.name,
        summary.keyframe_ids.len(),
        summary.duplicates,
        100.0 * summary.mean_density,
        if summary.end_of_stream { "yes" } else { "no" },
        if summary.payload_in_shared_memory { "yes" } else { "no" },
    );
    match failure {
        Some(e) => {
            telemetry.failed();
            Err(e)
        }
        None => {
            telemetry.finished();
            Ok(())
        }
    }
}

fn probe_telemetry(args: &ProbeArgs) -> Result<()> {
    let ipc = Ipc::open(&args.name, &args.ipc_prefix)?;
    let service = ipc.telemetry()?;
    let subscriber = ipc.telemetry_subscriber(&service)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(bdis_ipc::iox("create a WaitSet"))?;
    let _tick = waitset.attach_interval(Duration::from_secs(1)).map_err(bdis_ipc::iox("attach a tick"))?;
    let mut counts: std::collections::BTreeMap<String, u64> = Default::default();
    let mut idle_s = 0.0;
    loop {
        let result = waitset.wait_and_process_once(|_| CallbackProgression::Continue).map_err(bdis_ipc::iox("wait"))?;
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            return Ok(());
        }
        counts.clear();
        while let Ok(Some(r)) = subscriber.receive() {
            *counts.entry(r.process().to_string()).or_default() += 1;
        }
        idle_s = if counts.is_empty() { idle_s + 1.0 } else { 0.0 };
        let line: Vec<String> = counts.iter().map(|(p, n)| format!("{p} {n}/s")).collect();
        status(&format!("telemetry: {}", if line.is_empty() { "silent".to_string() } else { line.join(", ") }));
        if args.idle_timeout.is_some_and(|t| idle_s >= t) {
            bail!("no telemetry for {idle_s:.0} s");
        }
    }
}

/// What `probe poses` saw.
#[derive(Debug, Default, serde::Serialize)]
struct PoseSummary {
    records: u64,
    ok: u64,
    /// Tracked, but the tracker did not trust the pose.
    uncertain: u64,
    lost: u64,
    not_initialized: u64,
    keyframes: u64,
    /// Records refused (an undefined state, an OK pose that is not rigid).
    malformed: u64,
    end_of_stream: bool,
    frame_seqs_in_order: bool,
    last_world_from_camera: Option<[f64; 7]>,
}

fn probe_poses(args: &ProbeArgs) -> Result<()> {
    use bdis_ipc::track::tracking_state;
    let ipc = Ipc::open(&args.name, &args.ipc_prefix)?;
    let poses = ipc.poses()?;
    let subscriber = poses.subscriber_builder().create().map_err(bdis_ipc::iox("create the poses subscriber"))?;
    let listener = ipc.listener(&ipc.events(Topic::Poses)?)?;
    let mut telemetry = TelemetryPublisher::new(&ipc, &args.name, Some(Topic::Poses), None)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(bdis_ipc::iox("create a WaitSet"))?;
    let _guard = waitset
        .attach_deadline(&listener, Duration::from_secs(1))
        .map_err(bdis_ipc::iox("attach the poses listener"))?;
    telemetry.ready();
    let mut summary = PoseSummary { frame_seqs_in_order: true, ..Default::default() };
    let mut last_seq: Option<u64> = None;
    let mut last_rx = monotonic_ns();
    'outer: loop {
        let result = waitset
            .wait_and_process_once(|_| CallbackProgression::Continue)
            .map_err(bdis_ipc::iox("wait for poses"))?;
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            break;
        }
        let _ = bdis_ipc::drain_events(&listener);
        telemetry.keepalive();
        while let Some(sample) = subscriber.receive().map_err(bdis_ipc::iox("receive a pose"))? {
            let r = *sample.payload();
            last_rx = monotonic_ns();
            if r.state == tracking_state::END_OF_STREAM {
                summary.end_of_stream = true;
                break 'outer;
            }
            if let Err(rejection) = bdis_ipc::validate::pose_record(&r) {
                telemetry.rejected(Topic::Poses, &rejection);
                summary.malformed += 1;
                continue;
            }
            summary.records += 1;
            match r.state {
                tracking_state::OK => {
                    summary.ok += 1;
                    summary.last_world_from_camera = Some(r.world_from_camera);
                }
                tracking_state::UNCERTAIN => summary.uncertain += 1,
                tracking_state::LOST => summary.lost += 1,
                _ => summary.not_initialized += 1,
            }
            summary.keyframes += u64::from(r.new_keyframe != u64::MAX);
            if last_seq.is_some_and(|l| r.frame_seq <= l) {
                summary.frame_seqs_in_order = false;
            }
            last_seq = Some(r.frame_seq);
            telemetry.message(
                MessageTiming {
                    frame_seq: r.frame_seq,
                    t_capture_ns: r.t_capture_ns,
                    t_upstream_publish_ns: r.t_publish_ns,
                    t_receive_ns: last_rx,
                    t_done_ns: monotonic_ns(),
                },
                0,
            );
        }
        status(&format!(
            "poses: {} ({} ok, {} uncertain, {} lost, {} keyframes)",
            summary.records, summary.ok, summary.uncertain, summary.lost, summary.keyframes
        ));
        if args.max_frames.is_some_and(|m| summary.records >= m) {
            break;
        }
        if args.idle_timeout.is_some_and(|t| (monotonic_ns() - last_rx) as f64 / 1e9 > t) {
            break;
        }
    }
    if let Some(path) = summary_path(args) {
        let text = serde_json::to_string_pretty(&summary).context("serialise the probe summary")?;
        std::fs::write(&path, text).with_context(|| format!("{}: cannot write the probe summary", path.display()))?;
    }
    println!(
        "poses: {} records, {} ok, {} uncertain, {} lost, {} keyframes, end of stream: {}",
        summary.records,
        summary.ok,
        summary.uncertain,
        summary.lost,
        summary.keyframes,
        if summary.end_of_stream { "yes" } else { "no" }
    );
    telemetry.finished();
    Ok(())
}
