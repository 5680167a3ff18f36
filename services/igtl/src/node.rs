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
    /// The newest record with a pose, and the newest state (state, doubt): what a receiver is sent first.
    last_pose: Option<PoseRecord>,
    /// The record at which the state (state, doubt) last changed.
    last_state: Option<PoseRecord>,
    mirror: MapMirror,
    changes: Vec<Change>,
    /// Reused text of the state message and the metadata values.
    text: String,
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
            text: String::with_capacity(64),
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

    /// The messages of one pose record: its TRANSFORM when it has a pose, and the state when it changed. With
    /// no receiver nothing is encoded (a console without a navigation system pays nothing per frame); the
    /// record is kept for a receiver that connects later.
    fn pose(&mut self, record: &PoseRecord, receivers: &mut Receivers) {
        let state_changed = self.last_state.is_none_or(|s| (s.state, s.doubt) != (record.state, record.doubt));
        if state_changed {
            self.last_state = Some(*record);
        }
        let posed = matches!(validate::pose_record(record), Ok(Some(_)));
        if posed {
            self.last_pose = Some(*record);
        }
        if receivers.watchers() == 0 {
            return;
        }
        if state_changed {
            receivers.broadcast(self.state_message(record));
        }
        if posed && let Some(message) = self.transform_message(record) {
            receivers.broadcast(message);
        }
    }

    fn state_message(&mut self, record: &PoseRecord) -> Outgoing {
        let time = self.wall_time(record.t_capture_ns);
        self.text.clear();
        self.text.push_str(state_name(record.state));
        let why = if record.state == tracking_state::OK { "" } else { doubt::name(record.doubt) };
        if !why.is_empty() {
            let _ = write!(self.text, ": {why}");
        }
        outgoing(self.encoder.string(&self.state_device, time, &self.text, &[]))
    }

    /// The TRANSFORM of a record with a pose (None without one). Each message sent is one shared buffer, the
    /// only allocation per frame.
    fn transform_message(&mut self, record: &PoseRecord) -> Option<Outgoing> {
        let Ok(Some(world_from_camera)) = validate::pose_record(record) else { return None };
        let time = self.wall_time(record.t_capture_ns);
        self.frame_time.clear();
        let _ = write!(self.frame_time, "{:.9}", record.t_source_ns as f64 * 1e-9);
        self.frame.clear();
        let _ = write!(self.frame, "{}", record.frame_seq);
        let state = state_name(record.state);
        let why = if record.state == tracking_state::OK { "" } else { doubt::name(record.doubt) };
        let status = if record.state == tracking_state::OK { "OK" } else { "INVALID" };
        let metadata = [
            ("TransformStatus", status),
            ("TrackingState", state),
            ("Doubt", why),
            ("FrameTime", self.frame_time.as_str()),
            ("Frame", self.frame.as_str()),
        ];
        Some(outgoing(self.encoder.transform(&self.scope, time, &world_from_camera, &metadata)))
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
        let mut out = Vec::new();
        if let Some(changed) = self.last_state {
            out.push(self.state_message(&changed));
        }
        if let Some(newest) = self.last_pose {
            out.extend(self.transform_message(&newest));
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[global_allocator]
    static GLOBAL: bdis_testkit::CountingAllocator = bdis_testkit::CountingAllocator;

    fn record(seq: u64, state: u32) -> PoseRecord {
        let pose = nalgebra::Isometry3::new(
            nalgebra::Vector3::new(seq as f64, 2.0, 3.0),
            nalgebra::Vector3::new(0.0, 0.01 * seq as f64, 0.0),
        );
        PoseRecord {
            frame_seq: seq,
            t_capture_ns: 1_000_000_000 + seq * 33_000_000,
            t_source_ns: seq * 33_000_000,
            world_from_camera: bdis_ipc::track::pose_to_array(&pose),
            state,
            inliers: 300,
            new_keyframe: u64::MAX,
            reprojection_rms_px: 0.8,
            position_sigma_rel: 1e-4,
            appearance_agreement: 1.0,
            ..Default::default()
        }
    }

    #[test]
    #[allow(clippy::unwrap_used)]
    fn a_warmed_up_frame_allocates_nothing_without_a_receiver_and_one_shared_buffer_with_one() {
        let mut output = Output::new(MapOut::PolyData).unwrap();
        let (mut receivers, doorbell) = bdis_igtl::server::receivers();
        for seq in 0..4 {
            output.pose(&record(seq, tracking_state::OK), &mut receivers);
        }
        let before = bdis_testkit::allocations();
        for seq in 4..40 {
            output.pose(&record(seq, tracking_state::OK), &mut receivers);
        }
        assert_eq!(bdis_testkit::allocations() - before, 0, "no receiver: nothing encoded, nothing allocated");

        let (sent_to, sent) = std::sync::mpsc::channel::<Outgoing>();
        let watcher = bdis_core::fanout::start_writer(
            "test-receiver",
            bdis_igtl::server::RECEIVER_QUEUE,
            sent_to,
            |to, m| to.send(m).map_err(|_| std::io::Error::other("gone")),
            |_| {},
        )
        .unwrap();
        doorbell.send(watcher).unwrap();
        receivers.admit(|| output.replay());
        // The newest state and pose first.
        let first: Vec<Outgoing> = (0..2).map(|_| sent.recv().unwrap()).collect();
        assert_eq!(&first[0][2..8], b"STRING");
        assert_eq!(&first[1][2..11], b"TRANSFORM");
        for seq in 40..44 {
            output.pose(&record(seq, tracking_state::OK), &mut receivers);
        }
        let before = bdis_testkit::allocations();
        for seq in 44..80 {
            output.pose(&record(seq, tracking_state::OK), &mut receivers);
        }
        assert_eq!(bdis_testkit::allocations() - before, 36, "one shared buffer per frame sent");
        // A change of state is said once, then the poses go on.
        output.pose(&record(80, tracking_state::UNCERTAIN), &mut receivers);
        // Everything broadcast reaches the receiver's writer, in order (it forwards on its own thread).
        let kinds: Vec<Vec<u8>> = (0..4 + 36 + 2)
            .map(|_| sent.recv_timeout(std::time::Duration::from_secs(10)).unwrap()[2..14].to_vec())
            .collect();
        assert_eq!(&kinds[40][..6], b"STRING");
        assert_eq!(&kinds[41][..9], b"TRANSFORM");
    }
}
