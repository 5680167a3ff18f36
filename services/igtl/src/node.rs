//! The OpenIGTLink node: the tracker's poses and the processes' telemetry in, the mosaic's map by snapshot
//! (request-response; no depth subscription, so the dense side keeps its buffers), OpenIGTLink out to every
//! receiver. Per frame: a TRANSFORM `CameraToWorld` (the left camera's pose in the map's frame, in the
//! calibration's unit) with the tracking state in its metadata, and a STRING `TrackingState` when the state
//! changes. The map: at most every `map_period`, the keyframes that changed since the last picture
//! (`bdis_igtl::map`). At the end: the mosaic's written map (what map.ply holds) and the tracker's final
//! trajectory as a polyline `Trajectory` (what trajectory.tum holds), then the connections are closed.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use bdis_igtl::map::{Change, MapMirror};
use bdis_igtl::server::{Outgoing, Receivers};
use bdis_igtl::{DeviceName, Encoder, Timestamp};
use bdis_ipc::map::{MapPoint, MapQuery, MapSnapshotHeader};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::track::{PoseRecord, doubt, tracking_state};
use bdis_ipc::{Ipc, TelemetryKind, TelemetryPublisher, Topic, event_id, validate};
use bdis_node::Flow;
use iceoryx2::prelude::*;

type PendingSnapshot =
    iceoryx2::pending_response::PendingResponse<ipc::Service, MapQuery, (), [MapPoint], MapSnapshotHeader>;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MapOut {
    PolyData,
    Points,
    Off,
}

#[derive(Debug)]
pub struct Config {
    pub listen: String,
    pub map: MapOut,
    pub map_period: Duration,
    pub run_dir: Option<PathBuf>,
    pub name: String,
    pub ipc_prefix: String,
}

/// After the poses end: how long to wait for the tracker and the mosaic to write their last files.
const LAST_FILES_PATIENCE: Duration = Duration::from_secs(8);
/// A snapshot request unanswered this long is given up (the mosaic was restarting) and asked again.
const SNAPSHOT_PATIENCE: Duration = Duration::from_secs(5);
/// At the end: how long the receivers are given to take what is queued for them.
const CLOSE_PATIENCE: Duration = Duration::from_secs(5);

/// What goes out, and what a receiver that connects now is sent first.
struct Output {
    encoder: Encoder,
    map_out: MapOut,
    scope: DeviceName,
    state_device: DeviceName,
    last_pose: Option<Outgoing>,
    last_state: Option<(u32, u32, Outgoing)>,
    mirror: MapMirror,
    changes: Vec<Change>,
    /// Reused text of the metadata values.
    frame_time: String,
    frame: String,
    /// Wall clock minus monotonic clock, ns: turns a frame's capture time into the header's time of day.
    wall_minus_monotonic_ns: i128,
}

fn state_name(state: u32) -> &'static str {
    match state {
        tracking_state::OK => "ok",
        tracking_state::UNCERTAIN => "uncertain",
        tracking_state::LOST => "lost",
        _ => "not-initialized",
    }
}

fn wall_minus_monotonic_ns() -> i128 {
    let wall = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
    wall as i128 - i128::from(bdis_ipc::clock::monotonic_ns())
}

fn outgoing(bytes: &[u8]) -> Outgoing {
    Outgoing::from(bytes)
}

impl Output {
    fn new(map_out: MapOut) -> Result<Self> {
        Ok(Self {
            encoder: Encoder::default(),
            map_out,
            scope: DeviceName::new("CameraToWorld")?,
            state_device: DeviceName::new("TrackingState")?,
            last_pose: None,
            last_state: None,
            mirror: MapMirror::default(),
            changes: Vec::new(),
            frame_time: String::with_capacity(32),
            frame: String::with_capacity(24),
            wall_minus_monotonic_ns: wall_minus_monotonic_ns(),
        })
    }

    fn wall_time(&self, t_monotonic_ns: u64) -> Timestamp {
        let wall = i128::from(t_monotonic_ns) + self.wall_minus_monotonic_ns;
        Timestamp::from_unix_ns(u64::try_from(wall).unwrap_or(0))
    }

    fn now(&self) -> Timestamp {
        self.wall_time(bdis_ipc::clock::monotonic_ns())
    }

    /// The messages of one pose record: its TRANSFORM when it has a pose, and the state when it changed.
    fn pose(&mut self, record: &PoseRecord, receivers: &mut Receivers) {
        let time = self.wall_time(record.t_capture_ns);
        let state = state_name(record.state);
        let why = if record.state == tracking_state::OK { "" } else { doubt::name(record.doubt) };
        if self.last_state.as_ref().is_none_or(|(s, d, _)| (*s, *d) != (record.state, record.doubt)) {
            let mut text = String::from(state);
            if !why.is_empty() {
                let _ = write!(text, ": {why}");
            }
            let message = outgoing(self.encoder.string(&self.state_device, time, &text, &[]));
            receivers.broadcast(message.clone());
            self.last_state = Some((record.state, record.doubt, message));
        }
        // A frame without a pose (lost, not yet initialised) has no TRANSFORM: the receiver keeps the last one,
        // whose state message now says it is stale.
        let Ok(Some(world_from_camera)) = validate::pose_record(record) else { return };
        self.frame_time.clear();
        let _ = write!(self.frame_time, "{:.9}", record.t_source_ns as f64 * 1e-9);
        self.frame.clear();
        let _ = write!(self.frame, "{}", record.frame_seq);
        let status = if record.state == tracking_state::OK { "OK" } else { "INVALID" };
        let metadata = [
            ("TransformStatus", status),
            ("TrackingState", state),
            ("Doubt", why),
            ("FrameTime", self.frame_time.as_str()),
            ("Frame", self.frame.as_str()),
        ];
        let message = outgoing(self.encoder.transform(&self.scope, time, &world_from_camera, &metadata));
        receivers.broadcast(message.clone());
        self.last_pose = Some(message);
    }

    fn block_message(&mut self, kf_id: u64, time: Timestamp) -> Option<Outgoing> {
        let device = DeviceName::new(&format!("MapKf{kf_id}")).ok()?;
        let empty = bdis_igtl::map::KeyframeBlock::default();
        let block = self.mirror.block(kf_id).unwrap_or(&empty);
        let bytes = match self.map_out {
            MapOut::PolyData => self.encoder.point_cloud(&device, time, &block.xyz, &[]),
            MapOut::Points => self.encoder.points(&device, time, device.as_str(), &block.xyz, &block.rgb, &[]),
            MapOut::Off => return None,
        };
        Some(outgoing(bytes))
    }

    /// A new picture of the map (`fill` puts every point into the mirror): the keyframes that changed go out.
    fn map_picture(&mut self, receivers: &mut Receivers, fill: impl FnOnce(&mut MapMirror)) {
        if self.map_out == MapOut::Off {
            return;
        }
        fill(&mut self.mirror);
        let mut changes = std::mem::take(&mut self.changes);
        self.mirror.commit(&mut changes);
        let time = self.now();
        for change in &changes {
            let (Change::Block(id) | Change::Gone(id)) = *change;
            if let Some(message) = self.block_message(id, time) {
                receivers.broadcast(message);
            }
        }
        self.changes = changes;
    }

    /// What a receiver that connects now is sent first: the state, the newest pose, every block of the map.
    fn replay(&mut self) -> Vec<Outgoing> {
        let mut out: Vec<Outgoing> = self.last_state.iter().map(|(_, _, m)| m.clone()).collect();
        out.extend(self.last_pose.iter().cloned());
        let time = self.now();
        let ids: Vec<u64> = self.mirror.blocks().map(|(id, _)| id).collect();
        out.extend(ids.into_iter().filter_map(|id| self.block_message(id, time)));
        out
    }

    /// The run's final trajectory (trajectory.tum) as one polyline.
    fn trajectory(&mut self, poses: &[bdis_core::geometry::StampedPose], receivers: &mut Receivers) -> Result<()> {
        let xyz: Vec<[f32; 3]> =
            poses.iter().map(|p| p.world_from_camera.translation.vector.map(|v| v as f32).into()).collect();
        let device = DeviceName::new("Trajectory")?;
        let count = poses.len().to_string();
        let time = self.now();
        let message = outgoing(self.encoder.polyline(&device, time, &xyz, &[("Poses", count.as_str())]));
        receivers.broadcast(message);
        Ok(())
    }
}

pub fn run(config: Config) -> Result<()> {
    let Config { listen, map, map_period, run_dir, name, ipc_prefix } = config;
    // The address first: a port that is taken or an address that is not one is refused before shared memory is
    // touched.
    let (listener, addr) = bdis_igtl::server::bind(&listen)?;
    let ipc = Ipc::open(&name, &ipc_prefix)?;
    let poses = ipc.poses()?;
    let pose_subscriber = poses.subscriber_builder().create().context("create the poses subscriber")?;
    let pose_events = ipc.listener(&ipc.events(Topic::Poses)?)?;
    let telemetry_service = ipc.telemetry()?;
    let health_subscriber = ipc.telemetry_subscriber(&telemetry_service)?;
    let snapshots = ipc.map_snapshot()?;
    let snapshot_client =
        snapshots.client_builder().create().map_err(|e| anyhow::anyhow!("create the snapshot client: {e:?}"))?;
    let snapshot_events = ipc.map_snapshot_events()?;
    let snapshot_request_signal = ipc.notifier(&snapshot_events)?;
    let snapshot_responses = ipc.listener(&snapshot_events)?;

    let (mut receivers, doorbell) = bdis_igtl::server::receivers();
    std::thread::Builder::new()
        .name("igtl-accept".into())
        .spawn(move || bdis_igtl::server::accept(&listener, &doorbell))
        .context("start the accepting thread")?;
    tracing::info!("OpenIGTLink at {addr}");

    let mut telemetry = TelemetryPublisher::new(&ipc, &name, Some(Topic::Poses), None)?;
    let mut output = Output::new(map)?;
    let mut pending_snapshot: Option<PendingSnapshot> = None;
    let mut last_request: Option<Instant> = None;
    let mut poses_ended: Option<Instant> = None;
    let (mut tracking_done, mut mosaic_done) = (false, false);
    telemetry.ready();

    let wake_on = [&pose_events, &snapshot_responses];
    let served = bdis_node::serve(&wake_on, &mut telemetry, |telemetry| -> Result<Flow> {
        receivers.admit(|| output.replay());

        while let Some(sample) = pose_subscriber.receive().context("receive a pose")? {
            let record = *sample.payload();
            let t_receive_ns = bdis_ipc::clock::monotonic_ns();
            if record.state == tracking_state::END_OF_STREAM {
                poses_ended.get_or_insert_with(Instant::now);
                continue;
            }
            if let Err(rejection) = validate::pose_record(&record) {
                telemetry.rejected(Topic::Poses, &rejection);
                continue;
            }
            output.pose(&record, &mut receivers);
            let timing = MessageTiming {
                frame_seq: record.frame_seq,
                t_capture_ns: record.t_capture_ns,
                t_upstream_publish_ns: record.t_publish_ns,
                t_receive_ns,
                t_done_ns: bdis_ipc::clock::monotonic_ns(),
            };
            telemetry.message(timing, 0);
        }

        while let Some(record) = health_subscriber.receive().context("receive telemetry")? {
            let r = *record.payload();
            if matches!(r.kind(), Some(TelemetryKind::Finished | TelemetryKind::Failed)) {
                match r.process() {
                    "tracking" => tracking_done = true,
                    "mosaic" => mosaic_done = true,
                    _ => {}
                }
            }
        }

        if map != MapOut::Off {
            if let Some(pending) = &pending_snapshot {
                if let Some(response) = pending.receive().context("receive a map snapshot")? {
                    let points = response.payload();
                    output.map_picture(&mut receivers, |mirror| {
                        for p in points {
                            mirror.point(u64::from(p.kf_id), p.xyz, p.rgb);
                        }
                    });
                    pending_snapshot = None;
                } else if last_request.is_some_and(|t| t.elapsed() >= SNAPSHOT_PATIENCE) {
                    pending_snapshot = None;
                }
            }
            let due = last_request.is_none_or(|t| t.elapsed() >= map_period);
            if pending_snapshot.is_none() && due && snapshots.dynamic_config().number_of_servers() > 0 {
                pending_snapshot = Some(
                    snapshot_client
                        .send_copy(MapQuery { max_points: 0, reserved: 0 })
                        .map_err(|e| anyhow::anyhow!("ask the mosaic for its map: {e:?}"))?,
                );
                bdis_ipc::notify(&snapshot_request_signal, event_id::MAP_REQUEST)?;
                last_request = Some(Instant::now());
            }
        }

        let files_written = tracking_done && (mosaic_done || map == MapOut::Off);
        let waited_enough = poses_ended.is_some_and(|t| t.elapsed() >= LAST_FILES_PATIENCE);
        Ok(if poses_ended.is_some() && (files_written || waited_enough) { Flow::Finished } else { Flow::Continue })
    });
    let failure = served.err();
    drop(pending_snapshot);

    // The run's last word, whether it finished or was stopped: the map the mosaic wrote, the final trajectory.
    receivers.admit(|| output.replay());
    if let Some(dir) = &run_dir {
        let map_file = dir.join("map.bin");
        if map != MapOut::Off && map_file.exists() {
            match bdis_mosaic::load(&map_file) {
                Ok(last_map) => output.map_picture(&mut receivers, |mirror| {
                    last_map.for_each_world_point(|xyz, point, kf_id| mirror.point(kf_id, xyz, point.rgb));
                }),
                Err(e) => tracing::warn!("the last map: {e}"),
            }
        }
        let trajectory_file = dir.join("trajectory.tum");
        if trajectory_file.exists() {
            match bdis_core::formats::trajectory::read_tum(&trajectory_file) {
                Ok(poses) => output.trajectory(&poses, &mut receivers)?,
                Err(e) => tracing::warn!("the final trajectory: {e}"),
            }
        }
    }
    tracing::info!(
        "OpenIGTLink done: {} keyframes, {} points sent; {} receivers let go, {} bytes queued",
        output.mirror.blocks().count(),
        output.mirror.points(),
        receivers.dropped,
        receivers.bytes_queued
    );
    receivers.close(CLOSE_PATIENCE);
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
