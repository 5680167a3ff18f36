//! The viewer node: its ports (poses, corrections, depth, telemetry), the HTTP thread, and the loop that turns
//! what arrives into the page's messages. The map is a replica of the mosaic's, built by `bdis_mosaic` under the
//! mosaic service's rule from the same topics — exact per keyframe, which the mosaic's world-coordinate
//! snapshots are not — and at the end the mosaic's written map.bin has the last word. The page's state is
//! `bdis_viewer::live`; the browsers are `bdis_viewer::hub`; the loop is `bdis_node::serve`.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use bdis_ipc::track::tracking_state;
use bdis_ipc::validate;
use bdis_ipc::{Ipc, TelemetryKind, TelemetryPublisher, Topic};
use bdis_mosaic::pending::{Correction, PendingCorrections};
use bdis_mosaic::{DepthKeyframe, Mosaic, MosaicParams};
use bdis_node::Flow;
use bdis_viewer::PathPose;
use bdis_viewer::health::{Beat, BeatKind, Health};
use bdis_viewer::live::{LiveMap, Update, image_update};
use iceoryx2::prelude::*;
use tungstenite::Message;

#[derive(Debug)]
pub struct Config {
    pub listen: String,
    pub image_width: usize,
    pub image_period: Duration,
    /// The mosaic's parameters (the launcher gives the viewer the mosaic's `--map-param`s): the replica is the
    /// same map.
    pub map_params: MosaicParams,
    pub run_dir: Option<PathBuf>,
    pub name: String,
    pub ipc_prefix: String,
}

/// How often the processes' health goes to the page.
const HEALTH_PERIOD: Duration = Duration::from_secs(1);
/// After the depth stream ends: how long to wait for the mosaic to write its last map.
const LAST_MAP_PATIENCE: Duration = Duration::from_secs(15);

fn message(update: Update) -> Message {
    match update {
        Update::Binary(bytes) => Message::binary(bytes),
        Update::Text(text) => Message::text(text),
    }
}

fn state_name(state: u32) -> &'static str {
    match state {
        tracking_state::OK => "ok",
        tracking_state::UNCERTAIN => "uncertain",
        tracking_state::LOST => "lost",
        _ => "unknown",
    }
}

pub fn run(config: Config) -> Result<()> {
    let Config { listen, image_width, image_period, map_params, run_dir, name, ipc_prefix } = config;
    // The address first: a port that is taken or an address that is not one is refused before shared memory is
    // touched.
    let (server, addr) = bdis_viewer::bind(&listen)?;
    let ipc = Ipc::open(&name, &ipc_prefix)?;
    let depth = ipc.depth()?;
    let depth_subscriber = ipc.depth_subscriber(&depth)?;
    let depth_events = ipc.listener(&ipc.events(Topic::Depth)?)?;
    let poses = ipc.poses()?;
    let pose_subscriber = poses.subscriber_builder().create().context("create the poses subscriber")?;
    let pose_events = ipc.listener(&ipc.events(Topic::Poses)?)?;
    let corrections = ipc.corrections()?;
    let correction_subscriber =
        corrections.subscriber_builder().create().context("create the corrections subscriber")?;
    let correction_events = ipc.listener(&ipc.events(Topic::Corrections)?)?;
    let telemetry_service = ipc.telemetry()?;
    let health_subscriber = ipc.telemetry_subscriber(&telemetry_service)?;

    let (mut hub, doorbell) = bdis_viewer::hub::hub();
    let run_name = run_dir
        .as_ref()
        .and_then(|d| d.file_name())
        .map_or_else(|| ipc_prefix.clone(), |n| n.to_string_lossy().into_owned());
    let site = bdis_viewer::Site::live(&run_name, doorbell);
    std::thread::Builder::new()
        .name("viewer-http".into())
        .spawn(move || site.serve(&server))
        .context("start the HTTP thread")?;
    tracing::info!("viewer at http://{addr}/");

    let mut telemetry = TelemetryPublisher::new(&ipc, &name, Some(Topic::Depth), None)?;
    let started = Instant::now();
    let mut live = LiveMap::default();
    let mut replica = Mosaic::new(map_params);
    let mut pending = PendingCorrections::default();
    let mut newest_kf_id: Option<u64> = None;
    let mut health = Health::default();
    let mut last_image: Option<Instant> = None;
    let mut last_health = Instant::now();
    let mut depth_ended: Option<Instant> = None;
    let mut mosaic_done = false;
    let mut stream = validate::StreamGuard::default();
    let mut updates = Vec::new();
    telemetry.ready();

    let wake_on = [&depth_events, &pose_events, &correction_events];
    let served = bdis_node::serve(&wake_on, &mut telemetry, |_| -> Result<Flow> {
        hub.admit(|| live.replay().into_iter().map(message).collect());

        let mut path = Vec::new();
        while let Some(sample) = pose_subscriber.receive().context("receive a pose")? {
            let record = *sample.payload();
            if record.state == tracking_state::END_OF_STREAM {
                continue;
            }
            if let Ok(Some(pose)) = validate::pose_record(&record) {
                let q = pose.rotation.quaternion().coords;
                path.push(PathPose {
                    t_s: record.t_source_ns as f64 / 1e9,
                    position: pose.translation.vector.into(),
                    orientation_xyzw: [q.x, q.y, q.z, q.w],
                    state: state_name(record.state).into(),
                });
            }
        }
        if let Some(update) = live.poses(path) {
            hub.broadcast(message(update));
        }

        // Corrections first: those a keyframe was made after were sent before it (the mosaic's order).
        receive_corrections(&correction_subscriber, &mut pending)?;
        while let Some(sample) = depth_subscriber.receive().context("receive a depth keyframe")? {
            let header = *sample.user_header();
            if header.is_end_of_stream() {
                if stream.end_of_stream(header.frame_seq, "depth").is_ok() {
                    depth_ended.get_or_insert_with(Instant::now);
                }
                continue;
            }
            let Ok((view, Some(pose))) = validate::depth(sample.user_header(), sample.payload()) else { continue };
            stream.taken(header.meta.kf_id, header.frame_seq, sample.origin());
            if replica.contains(header.meta.kf_id) {
                continue;
            }
            receive_corrections(&correction_subscriber, &mut pending)?;
            newest_kf_id = newest_kf_id.max(Some(header.meta.kf_id));
            pending.apply_up_to(header.meta.corrections_generation, newest_kf_id, &mut replica, |_| {});
            let keyframe = DepthKeyframe {
                kf_id: header.meta.kf_id,
                t_capture_ns: header.t_capture_ns,
                world_from_camera: pose,
                intrinsics: header.meta.intrinsics.camera(header.width, header.height),
                disparity: view.disparity,
                confidence: view.confidence,
                rgb: view.rgb,
            };
            if let Err(e) = replica.insert(&keyframe) {
                tracing::warn!("{e}");
            }
            if last_image.is_none_or(|t| t.elapsed() >= image_period)
                && let Some(update) =
                    image_update(header.width as usize, header.height as usize, view.rgb, view.disparity, image_width)
            {
                hub.broadcast(message(update));
                last_image = Some(Instant::now());
            }
        }
        updates.clear();
        live.sync(&replica, &mut updates);
        for update in updates.drain(..) {
            hub.broadcast(message(update));
        }

        while let Some(record) = health_subscriber.receive().context("receive telemetry")? {
            let r = *record.payload();
            let kind = match r.kind() {
                Some(TelemetryKind::Ready) => BeatKind::Ready,
                Some(TelemetryKind::Message) => BeatKind::Message { processing_ns: r.processing_ns() },
                Some(TelemetryKind::Finished) => BeatKind::Finished,
                Some(TelemetryKind::Failed) => BeatKind::Failed,
                Some(TelemetryKind::Heartbeat | TelemetryKind::Rejected) | None => BeatKind::Heartbeat,
            };
            if r.process() == "mosaic" && matches!(kind, BeatKind::Finished | BeatKind::Failed) {
                mosaic_done = true;
            }
            health.record(
                Beat { process: r.process(), pid: r.pid, kind, cpu_time_ns: r.cpu_time_ns },
                started.elapsed().as_secs_f64(),
            );
        }

        if last_health.elapsed() >= HEALTH_PERIOD {
            let update = health.report(last_health.elapsed().as_secs_f64());
            hub.broadcast(message(update));
            last_health = Instant::now();
        }
        let waited_enough = depth_ended.is_some_and(|t| t.elapsed() >= LAST_MAP_PATIENCE);
        Ok(if depth_ended.is_some() && (mosaic_done || waited_enough) { Flow::Finished } else { Flow::Continue })
    });
    // Finished or stopped: either way the page gets the run's last map below.
    let failure = served.err();
    // The last corrections (the tracker's final adjustment), then the mosaic's last map — what map.ply holds —
    // which the replica should equal: the page ends on exactly the run's map either way.
    if let Err(e) = receive_corrections(&correction_subscriber, &mut pending) {
        tracing::warn!("{e:#}");
    }
    pending.apply_up_to(u64::MAX, newest_kf_id, &mut replica, |_| {});
    // As the mosaic does before writing the map.
    replica.realign();
    updates.clear();
    live.sync(&replica, &mut updates);
    for update in updates.drain(..) {
        hub.broadcast(message(update));
    }
    let written = run_dir.map(|d| d.join("map.bin")).filter(|f| f.exists()).map(|f| bdis_mosaic::load(&f));
    match written {
        Some(Ok(last_map)) => {
            live.sync(&last_map, &mut updates);
            // Nothing, when the replica is the mosaic's map (it is built the same way from the same topics).
            if !updates.is_empty() {
                tracing::warn!(
                    "the mosaic's written map differs from the replica: {} messages to the page",
                    updates.len()
                );
            }
            for update in updates.drain(..) {
                hub.broadcast(message(update));
            }
        }
        Some(Err(e)) => tracing::warn!("the last map: {e}"),
        None => {}
    }
    hub.broadcast(message(health.report(last_health.elapsed().as_secs_f64())));
    tracing::info!(
        "viewer done: {} keyframes, {} points shown; {} browsers dropped, {} bytes queued",
        live.keyframes_shown(),
        live.points_shown(),
        hub.dropped,
        hub.bytes_queued
    );
    hub.close(Duration::from_secs(3));
    match failure {
        None => {
            telemetry.finished();
            Ok(())
        }
        Some(e) => {
            telemetry.failed();
            Err(e)
        }
    }
}

type CorrectionSubscriber = iceoryx2::port::subscriber::Subscriber<ipc::Service, bdis_ipc::KeyframePose, ()>;

/// Queues every well-formed correction waiting (the mosaic reports the others; the viewer only follows).
fn receive_corrections(subscriber: &CorrectionSubscriber, pending: &mut PendingCorrections) -> Result<()> {
    while let Some(sample) = subscriber.receive().context("receive a pose correction")? {
        let record = sample.payload();
        if let Ok(pose) = validate::correction(record) {
            let _ = pending.push(Correction {
                kf_id: record.kf_id,
                generation: record.generation,
                world_from_camera: Some(pose),
            });
        }
    }
    Ok(())
}
