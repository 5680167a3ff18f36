//! The mosaic node: its ports (depth keyframes, pose corrections, snapshot requests), the wake-up handling, the
//! checkpoints and the results written at the end. The map itself is `bdis_mosaic`; the loop is
//! `bdis_node::serve`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use bdis_ipc::map::{MapPoint, MapQuery, MapSnapshotHeader};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::validate::{self, StreamGuard};
use bdis_ipc::{Ipc, KeyframePose, TelemetryPublisher, Topic, event_id, monotonic_ns};
use bdis_mosaic::{DepthKeyframe, Mosaic, MosaicSummary};
use bdis_node::{Ended, Flow};
use iceoryx2::prelude::*;

use bdis_mosaic::pending::PendingCorrections;

/// The map to start from and what to do with it.
#[derive(Debug)]
pub struct Config {
    pub mosaic: Mosaic,
    pub out_dir: PathBuf,
    /// Save map.bin after every this many new keyframes (0 = only at the end).
    pub save_every: u64,
    pub preview_width: u32,
    pub name: String,
    pub ipc_prefix: String,
}

type CorrectionSubscriber = iceoryx2::port::subscriber::Subscriber<ipc::Service, KeyframePose, ()>;

/// The service's two input streams, and what it knows of the depth stream (for its end).
struct Input {
    depth: iceoryx2::port::subscriber::Subscriber<ipc::Service, [u8], bdis_ipc::DepthHeader>,
    corrections: CorrectionSubscriber,
    stream: StreamGuard,
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
    /// Points the overlap rule removed when it ran again after corrections moved keyframes (a loop's second
    /// surface).
    realigned_removed: u64,
    /// Per keyframe: the mosaic update (removal and lifting), ms, and how many earlier keyframes it visited.
    update_ms: Vec<f64>,
    overlapping: Vec<usize>,
    highest_kf_id: Option<u64>,
}

pub fn run(config: Config) -> Result<()> {
    let Config { mut mosaic, out_dir, save_every, preview_width, name, ipc_prefix } = config;
    let ipc = Ipc::open(&name, &ipc_prefix)?;
    let depth = ipc.depth()?;
    let depth_subscriber = ipc.depth_subscriber(&depth)?;
    let depth_events = ipc.listener(&ipc.events(Topic::Depth)?)?;
    let corrections = ipc.corrections()?;
    let correction_subscriber =
        corrections.subscriber_builder().create().context("create the corrections subscriber")?;
    let correction_events = ipc.listener(&ipc.events(Topic::Corrections)?)?;
    let snapshots = ipc.map_snapshot()?;
    // Room for 32 k points (640 kB) to start with; the segment grows by powers of two with the map. The pool
    // holds a response for each request that can be in flight, so a large start would reserve (virtually) that
    // many times the size in /dev/shm.
    let server = bdis_ipc::map::map_server(&snapshots, 32_768)?;
    let snapshot_service_events = ipc.map_snapshot_events()?;
    let snapshot_requests = ipc.listener(&snapshot_service_events)?;
    let snapshot_responses = ipc.notifier(&snapshot_service_events)?;
    let mut telemetry = TelemetryPublisher::new(&ipc, &name, Some(Topic::Depth), None)?;

    let mut input =
        Input { depth: depth_subscriber, corrections: correction_subscriber, stream: StreamGuard::default() };
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
    let wake_on = [&depth_events, &correction_events, &snapshot_requests];
    let served = bdis_node::serve(&wake_on, &mut telemetry, |telemetry| -> Result<Flow> {
        // Corrections first: those a keyframe was made after were sent before it.
        receive_corrections(&input.corrections, &mut pending, telemetry)?;
        end_of_stream = take_depth(&mut input, &mut mosaic, &mut pending, &mut counters, telemetry)?;
        counters.snapshots += answer_snapshots(&server, &snapshot_responses, &mosaic, &counters)?;
        if save_every > 0 && counters.inserted >= checkpointed + save_every && !end_of_stream {
            // A checkpoint: everything made so far survives a crash of this process. (At the end of the stream
            // the map is written whole below.) A failed checkpoint is reported and tried again N keyframes
            // later, not at every wake-up.
            if let Err(e) = bdis_mosaic::save(&mosaic, &out_dir.join("map.bin")) {
                tracing::warn!("checkpoint: {e}");
            }
            checkpointed = counters.inserted;
        }
        if end_of_stream {
            tracing::info!("end of stream after {} keyframes", counters.inserted);
            return Ok(Flow::Finished);
        }
        Ok(Flow::Continue)
    });
    let failure = match served {
        Ok(Ended::Finished) => None,
        Ok(Ended::StopRequested) => {
            tracing::info!("stop requested after {} keyframes", counters.inserted);
            None
        }
        Err(e) => Some(e),
    };
    // Corrections sent before the end of the stream (the tracker's last bundle adjustment) are applied before
    // the map is written; the map so far is written even when something failed.
    if let Err(e) = receive_corrections(&input.corrections, &mut pending, &mut telemetry) {
        tracing::warn!("{e:#}");
    }
    counters.corrections += pending.apply_up_to(u64::MAX, counters.highest_kf_id, &mut mosaic, |r| {
        telemetry.rejected(Topic::Corrections, &crate::pending::rejection(r))
    });
    // The last corrections can move keyframes as a loop's did: the map written is the corrected one, one surface
    // where the passes meet.
    count_realigned(&mut counters, mosaic.realign());
    let written = write_results(&mosaic, &counters, &out_dir, preview_width, end_of_stream);
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

/// Queues every pose correction waiting that is well formed and not late (see [`PendingCorrections::push`]).
fn receive_corrections(
    subscriber: &CorrectionSubscriber,
    pending: &mut PendingCorrections,
    telemetry: &mut TelemetryPublisher,
) -> Result<()> {
    while let Some(sample) = subscriber.receive().context("receive a pose correction")? {
        let record = sample.payload();
        let checked = validate::correction(record)
            .and_then(|pose| pending.push(crate::pending::correction(record, pose)).map_err(crate::pending::rejection));
        if let Err(rejection) = checked {
            telemetry.rejected(Topic::Corrections, &rejection);
        }
    }
    Ok(())
}

/// Takes every depth keyframe waiting; returns whether the end of the stream came.
fn take_depth(
    input: &mut Input,
    mosaic: &mut Mosaic,
    pending: &mut PendingCorrections,
    counters: &mut Counters,
    telemetry: &mut TelemetryPublisher,
) -> Result<bool> {
    loop {
        let Some(sample) = input.depth.receive().context("receive a depth keyframe")? else { return Ok(false) };
        let t_receive_ns = monotonic_ns();
        let header = *sample.user_header();
        if header.is_end_of_stream() {
            match input.stream.end_of_stream(header.frame_seq, "depth") {
                Ok(()) => return Ok(true),
                Err(rejection) => {
                    telemetry.rejected(Topic::Depth, &rejection);
                    continue;
                }
            }
        }
        let (view, pose) = match validate::depth(sample.user_header(), sample.payload()) {
            Ok((view, Some(pose))) => (view, pose),
            Ok((_, None)) => {
                // Well formed, but a keyframe made from frames without a tracker has no place in a map.
                tracing::warn!(
                    "depth keyframe {} has no pose (the stereo service reads frames, not the tracker's keyframes): skipped",
                    header.meta.kf_id
                );
                counters.malformed += 1;
                continue;
            }
            Err(rejection) => {
                // Refused and counted: the map so far is not lost over it.
                telemetry.rejected(Topic::Depth, &rejection);
                counters.malformed += 1;
                continue;
            }
        };
        let keyframe = DepthKeyframe {
            kf_id: header.meta.kf_id,
            t_capture_ns: header.t_capture_ns,
            world_from_camera: pose,
            intrinsics: header.meta.intrinsics.camera(header.width, header.height),
            disparity: view.disparity,
            confidence: view.confidence,
            rgb: view.rgb,
        };
        // A keyframe the map has (a replacement stereo instance redoes some) changes nothing, not even which
        // corrections are applied when.
        if mosaic.contains(header.meta.kf_id) {
            counters.duplicates += 1;
            continue;
        }
        // Corrections this keyframe was made after were sent before it, so they are in the queue by now.
        receive_corrections(&input.corrections, pending, telemetry)?;
        let newest = counters.highest_kf_id.max(Some(header.meta.kf_id));
        counters.corrections += pending.apply_up_to(header.meta.corrections_generation, newest, mosaic, |r| {
            telemetry.rejected(Topic::Corrections, &crate::pending::rejection(r))
        });
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
        let origin = sample.origin();
        drop(sample);
        input.stream.taken(header.meta.kf_id, header.frame_seq, origin);
        if report.duplicate {
            counters.duplicates += 1;
            continue;
        }
        counters.inserted += 1;
        counters.removed += report.removed as u64;
        count_realigned(counters, report.realigned);
        counters.kept_occluded += report.kept_occluded as u64;
        counters.update_ms.push((t_done_ns - start) as f64 / 1e6);
        counters.overlapping.push(report.overlapping_keyframes);
        counters.highest_kf_id = counters.highest_kf_id.max(Some(header.meta.kf_id));
        tracing::info!(
            "keyframe {}: +{} points ({} seen through before), {} replaced, {} kept behind, {} keyframes overlapped, \
             {:.2} ms; map {} points",
            header.meta.kf_id,
            report.added,
            report.seen_through,
            report.removed,
            report.kept_occluded,
            report.overlapping_keyframes,
            (t_done_ns - start) as f64 / 1e6,
            mosaic.n_points()
        );
        telemetry.message(
            MessageTiming {
                frame_seq: header.meta.kf_id,
                t_capture_ns: header.t_capture_ns,
                t_upstream_publish_ns: header.t_publish_ns,
                t_receive_ns,
                t_done_ns,
            },
            0,
        );
    }
}

fn count_realigned(counters: &mut Counters, realigned: bdis_mosaic::Realigned) {
    if realigned.keyframes_moved > 0 {
        tracing::info!(
            "corrections moved {} keyframes: the overlap rule again removed {} points seen again and {} seen through",
            realigned.keyframes_moved,
            realigned.removed,
            realigned.seen_through
        );
    }
    counters.realigned_removed += (realigned.removed + realigned.seen_through) as u64;
}

fn answer_snapshots(
    server: &iceoryx2::port::server::Server<ipc::Service, MapQuery, (), [MapPoint], MapSnapshotHeader>,
    responses: &iceoryx2::port::notifier::Notifier<ipc::Service>,
    mosaic: &Mosaic,
    counters: &Counters,
) -> Result<u64> {
    let mut answered = 0;
    loop {
        let Some(request) = server.receive().context("receive a snapshot request")? else { break };
        let query = *request.payload();
        let total = mosaic.n_points();
        let stride = match query.max_points {
            0 => 1,
            max => total.div_ceil(max as usize).max(1),
        };
        let count = total.div_ceil(stride);
        let mut loan =
            request.loan_slice_uninit(count).with_context(|| format!("loan a snapshot of {count} points"))?;
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
        response.send().context("send a snapshot")?;
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
    let mut pick = |q: f64| bdis_core::stats::percentile(&mut update_ms, q);
    // Keyframe ids are consecutive from the tracker: a gap is a keyframe the stereo service never delivered.
    let missing = counters.highest_kf_id.map_or(0, |h| (h + 1).saturating_sub(mosaic.n_keyframes() as u64));
    let summary = MosaicSummary {
        schema: MosaicSummary::SCHEMA.to_string(),
        end_of_stream,
        keyframes_inserted: counters.inserted,
        keyframes_in_map: mosaic.n_keyframes() as u64,
        keyframes_missing: missing,
        duplicates: counters.duplicates,
        malformed: counters.malformed,
        corrections_applied: counters.corrections,
        snapshots_served: counters.snapshots,
        points: mosaic.n_points() as u64,
        points_replaced: counters.removed,
        points_kept_behind: counters.kept_occluded,
        points_removed_realigned: counters.realigned_removed,
        update_ms_p50: pick(0.5),
        update_ms_p99: pick(0.99),
        overlapping_keyframes_max: counters.overlapping.iter().max().map(|&n| n as u64),
        params: mosaic.params,
        map_ply: outputs.ply.clone(),
        map_png: outputs.png.clone(),
        map_bin: outputs.bin.clone(),
    };
    summary.write(&dir.join("mosaic.json"))?;
    tracing::info!(
        "{} keyframes, {} points; update p50 {:.2} ms; {}",
        counters.inserted,
        mosaic.n_points(),
        pick(0.5).unwrap_or(0.0),
        outputs.ply.display()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use bdis_ipc::{DepthHeader, KeyframeMeta, StereoIntrinsics};
    use bdis_mosaic::MosaicParams;

    /// The node as a whole, in process, over real shared memory: two depth keyframes of a plane, a pose
    /// correction the second was made after, a sample without a pose, then the end of the stream. The map has both
    /// keyframes, the correction applied before the second was inserted, the bad sample counted, and its files
    /// written.
    #[test]
    #[allow(clippy::unwrap_used, clippy::expect_used)]
    fn depth_keyframes_and_corrections_in_a_map_out_over_shared_memory() {
        let prefix = format!("bmnode{}_", std::process::id());
        let out_dir = std::env::temp_dir().join(format!("bdis-mosaic-node-{}", std::process::id()));
        std::fs::create_dir_all(&out_dir).unwrap();
        let config = Config {
            mosaic: Mosaic::new(MosaicParams::default()),
            out_dir: out_dir.clone(),
            save_every: 0,
            preview_width: 128,
            name: "mosaic".into(),
            ipc_prefix: prefix.clone(),
        };
        let ipc = Ipc::open("node-test", &prefix).unwrap();
        let ready = bdis_ipc::ReadyWatch::open(&ipc).unwrap();
        let (w, h) = (64u32, 48u32);
        let depth = ipc.depth().unwrap();
        let depth_publisher = ipc.depth_publisher(&depth, DepthHeader::payload_len(w, h)).unwrap();
        let depth_events = ipc.notifier(&ipc.events(Topic::Depth).unwrap()).unwrap();
        let corrections = ipc.corrections().unwrap();
        let correction_publisher = corrections.publisher_builder().create().unwrap();
        let correction_events = ipc.notifier(&ipc.events(Topic::Corrections).unwrap()).unwrap();

        let node = std::thread::spawn(move || run(config));
        let deadline = || std::time::Instant::now() + std::time::Duration::from_secs(20);
        assert!(ready.wait("mosaic", deadline()).unwrap(), "the node reports ready");

        // A plane 50 mm in front of each keyframe (disparity 20 px with bf = 1000).
        let intrinsics = StereoIntrinsics { fx: 50.0, fy: 50.0, cx: 31.5, cy: 23.5, bf: 1000.0 };
        let n = (w * h) as usize;
        let send_depth = |meta: KeyframeMeta| {
            let mut header =
                DepthHeader { meta, frame_seq: meta.kf_id, algorithm: DepthHeader::BDIS, ..Default::default() };
            header.set_layout(w, h);
            let mut loan = depth_publisher.loan_slice_uninit(DepthHeader::payload_len(w, h)).unwrap();
            let payload = loan.payload_mut();
            let (payload, rgb) = payload.split_at_mut(8 * n);
            let written = bdis_node::copy_floats_into(payload, &[vec![20.0f32; n], vec![1.0f32; n]].concat())
                + bdis_node::copy_into(rgb, &vec![150u8; 3 * n]);
            assert_eq!(written, DepthHeader::payload_len(w, h));
            // SAFETY: every byte was written just above.
            let mut sample = unsafe { loan.assume_init() };
            *sample.user_header_mut() = header;
            sample.send().unwrap();
            bdis_ipc::notify(&depth_events, event_id::NEW_SAMPLE).unwrap();
        };
        let pose = |x: f64| [x, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0];
        send_depth(KeyframeMeta { kf_id: 0, world_from_camera: pose(0.0), intrinsics, corrections_generation: 0 });
        // Bundle adjustment moves keyframe 0 by 2 mm (generation 1); keyframe 1 is made after that.
        let correction = KeyframePose { kf_id: 0, world_from_camera: pose(2.0), generation: 1, culled: 0, reserved: 0 };
        correction_publisher.send_copy(correction).unwrap();
        bdis_ipc::notify(&correction_events, event_id::NEW_SAMPLE).unwrap();
        send_depth(KeyframeMeta { kf_id: 1, world_from_camera: pose(5.0), intrinsics, corrections_generation: 1 });
        // Keyframes picked from frames have no pose: not a keyframe of this map.
        send_depth(KeyframeMeta { kf_id: 2, world_from_camera: [0.0; 7], intrinsics, corrections_generation: 1 });
        bdis_node::send_end_of_stream(
            &depth_publisher,
            DepthHeader { frame_seq: 3, flags: DepthHeader::END_OF_STREAM, ..Default::default() },
        )
        .unwrap();
        bdis_ipc::notify(&depth_events, event_id::END_OF_STREAM).unwrap();
        node.join().unwrap().unwrap();

        let summary = MosaicSummary::read(&out_dir.join("mosaic.json")).unwrap();
        assert!(summary.end_of_stream);
        assert_eq!((summary.keyframes_inserted, summary.keyframes_in_map), (2, 2), "{summary:?}");
        assert_eq!((summary.malformed, summary.corrections_applied, summary.keyframes_missing), (1, 1, 0));
        assert!(summary.points > 0, "{summary:?}");
        assert!(out_dir.join("map.ply").is_file() && out_dir.join("map.bin").is_file());
        let map = bdis_mosaic::load(&out_dir.join("map.bin")).unwrap();
        let x = |kf_id: u64| map.keyframes().find(|k| k.kf_id == kf_id).unwrap().world_from_camera.translation.x;
        assert_eq!((x(0), x(1)), (2.0, 5.0), "the correction moved keyframe 0, and only it");

        drop((depth_publisher, correction_publisher, depth, corrections, ready, ipc));
        let _ = std::fs::remove_dir_all(&out_dir);
        bdis_ipc::remove_run_files(&prefix);
    }
}
