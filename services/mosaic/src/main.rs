//! `bdis-mosaic`: the mosaic service. Keeps the dense map (`bdis-mosaic`): takes each depth keyframe once
//! (de-duplicated by keyframe id, since a replacement stereo instance may send one again), moves keyframes'
//! points when bundle adjustment corrects their poses, answers snapshot requests so a viewer can draw the map,
//! and on stop writes `map.ply`, `map.png`, `map.bin` and `mosaic.json` into the run folder. It saves `map.bin`
//! every few keyframes too, so a crash loses little and `--load` can resume.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use bdis_ipc::map::{MapPoint, MapQuery, MapSnapshotHeader};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::track::pose_from_array;
use bdis_ipc::{DepthView, Ipc, TelemetryPublisher, Topic, event_id, monotonic_ns};
use bdis_mosaic::{DepthKeyframe, Intrinsics, Mosaic, MosaicParams};
use clap::Parser;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

/// Mosaic service: depth keyframes and pose corrections in; the dense coloured map kept, served and exported.
#[derive(Debug, Parser)]
#[command(name = "bdis-mosaic", version)]
struct Args {
    /// Folder for map.ply, map.png, map.bin, mosaic.json (default: the run folder the launcher gives, else the
    /// current folder).
    #[arg(long, env = "BDIS_RUN_DIR")]
    out: Option<PathBuf>,
    /// Start from a saved map (map.bin), e.g. to resume after this service was restarted within a run. Keyframe
    /// ids continue: a keyframe already in it is not added twice.
    #[arg(long)]
    load: Option<PathBuf>,
    /// Override a map parameter, e.g. `--map-param fusion=weighted` (repeatable; names: depth_gap_px,
    /// min_colour, min_confidence, min_disparity_px, depth_tolerance_mm, disparity_tolerance_px, keep_closer_ratio, fusion,
    /// max_weight).
    #[arg(long = "map-param", value_name = "NAME=VALUE")]
    map_params: Vec<String>,
    /// Resume from the run folder's map.bin when there is one (the checkpoint of a predecessor that crashed);
    /// the launcher gives this to a restarted instance. Without a checkpoint it starts empty.
    #[arg(long, conflicts_with = "load")]
    resume: bool,
    /// Save map.bin after every this many new keyframes (0 = only at the end).
    #[arg(long, default_value_t = 10)]
    save_every: u64,
    /// Width of the map.png preview, pixels.
    #[arg(long, default_value_t = 1024)]
    preview_width: u32,
    /// Name of this process in the run.
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "mosaic")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
}

fn main() -> ExitCode {
    bdis_ipc::process::init_logging();
    bdis_ipc::process::finish("bdis-mosaic", run(Args::parse()))
}

fn iox(what: &'static str) -> impl FnOnce(&dyn std::fmt::Debug) -> anyhow::Error {
    move |e| anyhow!("{what}: {e:?}")
}

/// What the service counts for mosaic.json.
#[derive(Debug, Default)]
struct Counters {
    inserted: u64,
    duplicates: u64,
    malformed: u64,
    corrections: u64,
    snapshots: u64,
    removed: u64,
    kept_occluded: u64,
    /// Per keyframe: the mosaic update (removal and lifting), ms, and how many earlier keyframes it visited.
    update_ms: Vec<f64>,
    overlapping: Vec<usize>,
    highest_kf_id: Option<u64>,
}

fn run(args: Args) -> Result<()> {
    let out_dir = args.out.clone().unwrap_or_else(|| PathBuf::from("."));
    let checkpoint = out_dir.join("map.bin");
    let load = match (&args.load, args.resume) {
        (Some(path), _) => Some(path.clone()),
        (None, true) if checkpoint.is_file() => Some(checkpoint),
        (None, true) => {
            tracing::info!("no checkpoint in {}: starting an empty map", out_dir.display());
            None
        }
        (None, false) => None,
    };
    let mut mosaic = match &load {
        Some(path) => {
            let mut m = bdis_mosaic::load(path)?;
            m.params.apply_overrides(&args.map_params).map_err(|e| anyhow!("--map-param {e}"))?;
            tracing::info!("resumed {} keyframes, {} points from {}", m.n_keyframes(), m.n_points(), path.display());
            m
        }
        None => {
            let mut params = MosaicParams::default();
            params.apply_overrides(&args.map_params).map_err(|e| anyhow!("--map-param {e}"))?;
            Mosaic::new(params)
        }
    };

    let ipc = Ipc::open(&args.name, &args.ipc_prefix)?;
    let depth = ipc.depth()?;
    let depth_subscriber = ipc.depth_subscriber(&depth)?;
    let depth_events = ipc.listener(&ipc.events(Topic::Depth)?)?;
    let corrections = ipc.corrections()?;
    let correction_subscriber =
        corrections.subscriber_builder().create().map_err(|e| iox("create the corrections subscriber")(&e))?;
    let correction_events = ipc.listener(&ipc.events(Topic::Corrections)?)?;
    let snapshots = ipc.map_snapshot()?;
    // Room for 32 k points (640 kB) to start with; the segment grows by powers of two with the map. The pool
    // holds a response for each request that can be in flight, so a large start would reserve (virtually) that
    // many times the size in /dev/shm.
    let server = bdis_ipc::map::map_server(&snapshots, 32_768)?;
    let snapshot_service_events = ipc.map_snapshot_events()?;
    let snapshot_requests = ipc.listener(&snapshot_service_events)?;
    let snapshot_responses = ipc.notifier(&snapshot_service_events)?;
    let mut telemetry = TelemetryPublisher::new(&ipc, &args.name, Some(Topic::Depth), None)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| iox("create a WaitSet")(&e))?;
    let _depth_guard = waitset
        .attach_deadline(&depth_events, Duration::from_secs(1))
        .map_err(|e| iox("attach the depth listener")(&e))?;
    let _corrections_guard =
        waitset.attach_notification(&correction_events).map_err(|e| iox("attach the corrections listener")(&e))?;
    let _snapshot_guard =
        waitset.attach_notification(&snapshot_requests).map_err(|e| iox("attach the snapshot listener")(&e))?;

    let mut counters = Counters::default();
    let mut pending = PendingCorrections::default();
    let mut end_of_stream = false;
    // Keyframes inserted when map.bin was last saved.
    let mut checkpointed = 0u64;
    // A resumed map tells the launcher which keyframes it has, so the stereo service redoes those after them.
    let restored = mosaic.keyframes().map(|k| k.kf_id).max();
    counters.highest_kf_id = restored;
    telemetry.ready_restored(restored);
    tracing::info!("mosaic ready ({} keyframes, {} points)", mosaic.n_keyframes(), mosaic.n_points());
    let failure = loop {
        let result = match waitset.wait_and_process_once(|_| CallbackProgression::Continue) {
            Ok(r) => r,
            Err(e) => break Some(anyhow!("wait for depth keyframes: {e:?}")),
        };
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            tracing::info!("stop requested after {} keyframes", counters.inserted);
            break None;
        }
        let _ = bdis_ipc::drain_events(&depth_events);
        let _ = bdis_ipc::drain_events(&correction_events);
        let _ = bdis_ipc::drain_events(&snapshot_requests);
        telemetry.keepalive();
        // Corrections first: those a keyframe was made after were sent before it.
        if let Err(e) = pending.receive(&correction_subscriber) {
            break Some(e);
        }
        match take_depth(
            &depth_subscriber,
            &correction_subscriber,
            &mut mosaic,
            &mut pending,
            &mut counters,
            &mut telemetry,
        ) {
            Ok(eos) => end_of_stream = eos,
            Err(e) => break Some(e),
        }
        match answer_snapshots(&server, &snapshot_responses, &mosaic, &counters) {
            Ok(n) => counters.snapshots += n,
            Err(e) => break Some(e),
        }
        if args.save_every > 0 && counters.inserted >= checkpointed + args.save_every && !end_of_stream {
            // A checkpoint: everything made so far survives a crash of this process. (At the end of the stream
            // the map is written whole below.)
            // A failed checkpoint is reported and tried again N keyframes later, not at every wake-up.
            if let Err(e) = bdis_mosaic::save(&mosaic, &out_dir.join("map.bin")) {
                tracing::warn!("checkpoint: {e}");
            }
            checkpointed = counters.inserted;
        }
        if end_of_stream {
            tracing::info!("end of stream after {} keyframes", counters.inserted);
            break None;
        }
    };
    // Corrections sent before the end of the stream (the tracker's last bundle adjustment) are applied before
    // the map is written; the map so far is written even when something failed.
    if let Err(e) = pending.receive(&correction_subscriber) {
        tracing::warn!("{e:#}");
    }
    pending.apply_up_to(u64::MAX, &mut mosaic, &mut counters);
    let written = write_results(&mosaic, &counters, &out_dir, args.preview_width, end_of_stream);
    match (failure, written) {
        (None, Ok(())) => {
            telemetry.finished();
            Ok(())
        }
        (Some(e), _) | (None, Err(e)) => {
            telemetry.failed();
            Err(e)
        }
    }
}

/// Pose corrections received but not applied yet. A depth keyframe says which correction generation the tracker
/// had reached when it made the keyframe; applying exactly those before inserting it makes the map's removal
/// decisions, and so the map, the same in every run, whatever the timing between the two topics.
#[derive(Debug, Default)]
struct PendingCorrections {
    queue: std::collections::VecDeque<bdis_ipc::KeyframePose>,
}

impl PendingCorrections {
    fn receive(
        &mut self,
        subscriber: &iceoryx2::port::subscriber::Subscriber<ipc::Service, bdis_ipc::KeyframePose, ()>,
    ) -> Result<()> {
        loop {
            match subscriber.receive() {
                Ok(Some(sample)) => self.queue.push_back(*sample.payload()),
                Ok(None) => return Ok(()),
                Err(e) => bail!("receive a pose correction: {e:?}"),
            }
        }
    }

    /// Applies the corrections up to `generation` (all of them with `u64::MAX`).
    fn apply_up_to(&mut self, generation: u64, mosaic: &mut Mosaic, counters: &mut Counters) {
        while self.queue.front().is_some_and(|c| c.generation <= generation) {
            let Some(record) = self.queue.pop_front() else { break };
            match pose_from_array(&record.world_from_camera) {
                Some(pose) => match mosaic.correct_pose(record.kf_id, pose) {
                    Ok(_) => counters.corrections += 1,
                    Err(e) => tracing::warn!("correction ignored: {e}"),
                },
                None => tracing::warn!("correction of keyframe {} ignored: not a rigid pose", record.kf_id),
            }
        }
    }
}

/// Takes every depth keyframe waiting; returns whether the end of the stream came.
fn take_depth(
    subscriber: &iceoryx2::port::subscriber::Subscriber<ipc::Service, [u8], bdis_ipc::DepthHeader>,
    corrections: &iceoryx2::port::subscriber::Subscriber<ipc::Service, bdis_ipc::KeyframePose, ()>,
    mosaic: &mut Mosaic,
    pending: &mut PendingCorrections,
    counters: &mut Counters,
    telemetry: &mut TelemetryPublisher,
) -> Result<bool> {
    loop {
        let sample = match subscriber.receive() {
            Ok(Some(s)) => s,
            Ok(None) => return Ok(false),
            Err(e) => bail!("receive a depth keyframe: {e:?}"),
        };
        let t_receive_ns = monotonic_ns();
        let header = *sample.user_header();
        if header.is_end_of_stream() {
            return Ok(true);
        }
        let view = match DepthView::new(sample.user_header(), sample.payload()) {
            Ok(v) => v,
            Err(e) => {
                // A malformed sample is reported and skipped: the map so far is not lost over it.
                tracing::warn!("{e}");
                counters.malformed += 1;
                continue;
            }
        };
        let Some(pose) = pose_from_array(&header.world_from_camera) else {
            tracing::warn!(
                "depth keyframe {} has no pose (the stereo service reads frames, not the tracker's keyframes): skipped",
                header.kf_id
            );
            counters.malformed += 1;
            continue;
        };
        let keyframe = DepthKeyframe {
            kf_id: header.kf_id,
            t_capture_ns: header.t_capture_ns,
            world_from_camera: pose,
            intrinsics: Intrinsics {
                fx: header.fx,
                fy: header.fy,
                cx: header.cx,
                cy: header.cy,
                bf: header.bf,
                width: header.width,
                height: header.height,
            },
            disparity: view.disparity,
            confidence: view.confidence,
            rgb: view.rgb,
        };
        // Corrections this keyframe was made after were sent before it, so they are in the queue by now.
        pending.receive(corrections)?;
        pending.apply_up_to(header.corrections_generation, mosaic, counters);
        let start = monotonic_ns();
        let report = match mosaic.insert(&keyframe) {
            Ok(r) => r,
            Err(e) => {
                tracing::warn!("{e}");
                counters.malformed += 1;
                continue;
            }
        };
        let t_done_ns = monotonic_ns();
        drop(sample);
        if report.duplicate {
            counters.duplicates += 1;
            continue;
        }
        counters.inserted += 1;
        counters.removed += report.removed as u64;
        counters.kept_occluded += report.kept_occluded as u64;
        counters.update_ms.push((t_done_ns - start) as f64 / 1e6);
        counters.overlapping.push(report.overlapping_keyframes);
        counters.highest_kf_id = counters.highest_kf_id.max(Some(header.kf_id));
        tracing::info!(
            "keyframe {}: +{} points, {} replaced, {} kept behind, {} keyframes overlapped, {:.2} ms; map {} points",
            header.kf_id,
            report.added,
            report.removed,
            report.kept_occluded,
            report.overlapping_keyframes,
            (t_done_ns - start) as f64 / 1e6,
            mosaic.n_points()
        );
        telemetry.message(
            MessageTiming {
                frame_seq: header.kf_id,
                t_capture_ns: header.t_capture_ns,
                t_upstream_publish_ns: header.t_publish_ns,
                t_receive_ns,
                t_done_ns,
            },
            0,
        );
    }
}

fn answer_snapshots(
    server: &iceoryx2::port::server::Server<ipc::Service, MapQuery, (), [MapPoint], MapSnapshotHeader>,
    responses: &iceoryx2::port::notifier::Notifier<ipc::Service>,
    mosaic: &Mosaic,
    counters: &Counters,
) -> Result<u64> {
    let mut answered = 0;
    loop {
        let request = match server.receive() {
            Ok(Some(r)) => r,
            Ok(None) => break,
            Err(e) => bail!("receive a snapshot request: {e:?}"),
        };
        let query = *request.payload();
        let total = mosaic.n_points();
        let stride = match query.max_points {
            0 => 1,
            max => total.div_ceil(max as usize).max(1),
        };
        let count = total.div_ceil(stride);
        let mut loan =
            request.loan_slice_uninit(count).map_err(|e| anyhow!("loan a snapshot of {count} points: {e:?}"))?;
        let slots = loan.payload_mut();
        let (mut index, mut written) = (0usize, 0usize);
        mosaic.for_each_world_point(|xyz, point, kf_id| {
            if index.is_multiple_of(stride) && written < slots.len() {
                slots[written].write(MapPoint {
                    xyz,
                    rgb: point.rgb,
                    confidence: (point.confidence.clamp(0.0, 1.0) * 255.0).round() as u8,
                    kf_id: kf_id as u32,
                });
                written += 1;
            }
            index += 1;
        });
        // Unreachable in practice (count is exactly the strided number of points); zero-fill rather than send
        // uninitialised memory.
        for slot in &mut slots[written..] {
            slot.write(MapPoint::default());
        }
        // SAFETY: every element of the slice was written above.
        let mut response = unsafe { loan.assume_init() };
        *response.user_header_mut() = MapSnapshotHeader {
            points_in_map: total as u64,
            stride: stride as u64,
            keyframes: mosaic.n_keyframes() as u64,
            keyframes_inserted: counters.inserted,
            corrections_applied: counters.corrections,
            t_publish_ns: monotonic_ns(),
        };
        response.send().map_err(|e| anyhow!("send a snapshot: {e:?}"))?;
        answered += 1;
    }
    if answered > 0 {
        bdis_ipc::notify(responses, event_id::MAP_RESPONSE)?;
    }
    Ok(answered)
}

fn write_results(
    mosaic: &Mosaic,
    counters: &Counters,
    dir: &Path,
    preview_width: u32,
    end_of_stream: bool,
) -> Result<()> {
    let outputs = bdis_mosaic::write_outputs(mosaic, dir, preview_width)?;
    let mut update_ms = counters.update_ms.clone();
    update_ms.sort_by(f64::total_cmp);
    let pick = |q: f64| update_ms.get(((update_ms.len() as f64 - 1.0) * q).round().max(0.0) as usize).copied();
    // Keyframe ids are consecutive from the tracker: a gap is a keyframe the stereo service never delivered.
    let missing = counters.highest_kf_id.map_or(0, |h| (h + 1).saturating_sub(mosaic.n_keyframes() as u64));
    let summary = serde_json::json!({
        "schema": "bdis.v1.mosaic",
        "end_of_stream": end_of_stream,
        "keyframes_inserted": counters.inserted,
        "keyframes_in_map": mosaic.n_keyframes(),
        "keyframes_missing": missing,
        "duplicates": counters.duplicates,
        "malformed": counters.malformed,
        "corrections_applied": counters.corrections,
        "snapshots_served": counters.snapshots,
        "points": mosaic.n_points(),
        "points_replaced": counters.removed,
        "points_kept_behind": counters.kept_occluded,
        "update_ms_p50": pick(0.5),
        "update_ms_p99": pick(0.99),
        "overlapping_keyframes_max": counters.overlapping.iter().max(),
        "params": mosaic.params,
        "map_ply": outputs.ply,
        "map_png": outputs.png,
        "map_bin": outputs.bin,
    });
    let path = dir.join("mosaic.json");
    std::fs::write(&path, serde_json::to_string_pretty(&summary)?)
        .with_context(|| format!("{}: cannot write", path.display()))?;
    tracing::info!(
        "{} keyframes, {} points; update p50 {:.2} ms; {}",
        counters.inserted,
        mosaic.n_points(),
        pick(0.5).unwrap_or(0.0),
        outputs.ply.display()
    );
    Ok(())
}
