//! bdis-slam's message contracts over iceoryx2 0.10: headers, service names and QoS (in one place), wake-ups,
//! telemetry records, and the per-run name prefix that keeps parallel runs apart.
//!
//! Rules this crate enforces (DESIGN.md, IPC-NOTES.md):
//! * pixels travel as `[u8]` slice payloads loaned from shared memory and written once by their producer; a
//!   `#[repr(C)]` versioned user header carries layout and times;
//! * every process opens every service through the functions here, so the QoS a service is created with is the
//!   same whoever creates it first;
//! * safe overflow stays on: a slow consumer loses old samples, it never blocks a producer;
//! * consumers wake through an event service of the same name and a WaitSet, never by polling.

use std::fmt::Debug;
use std::time::Duration;

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;

pub mod clock;
pub mod control;
pub mod depth;
pub mod frame;
pub mod map;
pub mod process;
pub mod shm;
pub mod telemetry;
pub mod track;

pub use clock::monotonic_ns;
pub use depth::{DepthHeader, DepthView};
pub use frame::{FrameHeader, FrameLayout, FrameView};
pub use map::{MapPoint, MapQuery, MapSnapshotHeader};
pub use telemetry::{TelemetryKind, TelemetryPublisher, TelemetryRecord};
pub use track::{KeyframeHeader, KeyframePose, PoseRecord};

/// The environment variable through which the launcher hands each child its run's name prefix.
pub const PREFIX_ENV: &str = "BDIS_IPC_PREFIX";
/// The prefix used when none is given (a user starting services by hand).
pub const DEFAULT_PREFIX: &str = "bdis_";

/// Event ids used on every event service of the pipeline.
pub mod event_id {
    /// A new sample was sent.
    pub const NEW_SAMPLE: usize = 1;
    /// The producer finished its stream: no more samples will come.
    pub const END_OF_STREAM: usize = 2;
    /// A notifier's process died (sent by iceoryx2's dead-node cleanup).
    pub const NOTIFIER_DEAD: usize = 3;
    /// A consumer released a frame (on-demand pacing).
    pub const CONSUMED: usize = 4;
    /// A consumer started and is ready for a frame; frames an earlier instance may have died with are sent
    /// again (on-demand pacing).
    pub const JOINED: usize = 5;
    /// A client sent a map snapshot request.
    pub const MAP_REQUEST: usize = 6;
    /// The map's owner answered a snapshot request.
    pub const MAP_RESPONSE: usize = 7;
    /// A tool sent the launcher a control request (swap a service).
    pub const CONTROL_REQUEST: usize = 8;
    /// The launcher answered a control request.
    pub const CONTROL_RESPONSE: usize = 9;
    pub const MAX: usize = 9;
}

/// The topics of the pipeline. Their names, payloads and QoS are defined here and nowhere else.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Topic {
    /// Stereo frames from acquisition: `[u8]` = left grey, right grey, left RGB; header [`FrameHeader`].
    Frames,
    /// Pipeline telemetry: fixed-size [`TelemetryRecord`]s from every process to the launcher.
    Telemetry,
    /// Depth keyframes from stereo: `[u8]` = disparity f32, confidence f32, left RGB; header [`DepthHeader`].
    Depth,
    /// A pose per frame from tracking: fixed-size [`PoseRecord`]s.
    Poses,
    /// Keyframes from tracking: `[u8]` = left grey, right grey, left RGB (as frames); header [`KeyframeHeader`].
    Keyframes,
    /// Keyframe pose corrections from tracking's bundle adjustment: fixed-size [`KeyframePose`]s.
    Corrections,
}

impl Topic {
    pub const ALL: [Topic; 6] =
        [Topic::Frames, Topic::Telemetry, Topic::Depth, Topic::Poses, Topic::Keyframes, Topic::Corrections];

    /// The short name users type (`bdis-slam probe frames`).
    pub fn short_name(self) -> &'static str {
        match self {
            Topic::Frames => "frames",
            Topic::Telemetry => "telemetry",
            Topic::Depth => "depth",
            Topic::Poses => "poses",
            Topic::Keyframes => "keyframes",
            Topic::Corrections => "corrections",
        }
    }

    /// The iceoryx2 service name (the run prefix is applied to files by iceoryx2's `global.prefix`).
    pub fn service_name(self) -> &'static str {
        match self {
            Topic::Frames => "bdis/v1/frames",
            Topic::Telemetry => "bdis/v1/telemetry",
            Topic::Depth => "bdis/v1/depth",
            Topic::Poses => "bdis/v1/poses",
            Topic::Keyframes => "bdis/v1/keyframes",
            Topic::Corrections => "bdis/v1/corrections",
        }
    }

    pub fn parse(name: &str) -> Option<Topic> {
        Topic::ALL.into_iter().find(|t| t.short_name() == name || t.service_name() == name)
    }
}

/// Everything that can fail while talking to iceoryx2. The detail is iceoryx2's own error, kept as text because
/// its error types differ per call and callers only report them.
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    #[error("invalid name `{name}`: {detail}")]
    Name { name: String, detail: String },
    #[error("{context}: {detail}")]
    Iceoryx { context: String, detail: String },
    #[error("{topic}: {detail}")]
    Contract { topic: &'static str, detail: String },
}

/// Wraps an iceoryx2 error with what was being done.
pub fn iox<E: Debug>(context: impl Into<String>) -> impl FnOnce(E) -> IpcError {
    let context = context.into();
    move |e| IpcError::Iceoryx { context, detail: format!("{e:?}") }
}

/// The iceoryx2 configuration for one run: its file-name prefix isolates the run's shared memory from any
/// other run on the machine (parallel tests, a second pipeline).
pub fn config_for_prefix(prefix: &str) -> Result<Config, IpcError> {
    let mut config = Config::default();
    config.global.prefix = FileName::new(prefix.as_bytes())
        .map_err(|e| IpcError::Name { name: prefix.to_string(), detail: format!("{e:?}") })?;
    Ok(config)
}

/// The run prefix from the environment, or the default.
pub fn prefix_from_env() -> String {
    std::env::var(PREFIX_ENV).ok().filter(|p| !p.is_empty()).unwrap_or_else(|| DEFAULT_PREFIX.to_string())
}

/// One process's connection to the run: its iceoryx2 node and the run's configuration.
#[derive(Debug)]
pub struct Ipc {
    pub node: Node<ipc::Service>,
    pub prefix: String,
}

/// The pub/sub side of a topic, with its same-named event service for wake-ups.
pub type FramesService = PubSubFactory<ipc::Service, [u8], FrameHeader>;
pub type TelemetryService = PubSubFactory<ipc::Service, TelemetryRecord, ()>;
pub type DepthService = PubSubFactory<ipc::Service, [u8], DepthHeader>;
pub type PosesService = PubSubFactory<ipc::Service, PoseRecord, ()>;
pub type KeyframesService = PubSubFactory<ipc::Service, [u8], KeyframeHeader>;
pub type CorrectionsService = PubSubFactory<ipc::Service, KeyframePose, ()>;
pub type Events = EventFactory<ipc::Service>;

/// QoS of every topic. Sizing (IPC-NOTES §2): samples per publisher segment =
/// subscribers · (buffer + borrowed) + history + loaned; frames: 4 · (2 + 2) + 0 + 1 = 17 frames of 5·W·H bytes
/// (26 MB at 640×480); depth: 3 · (4 + 2) + 0 + 1 = 19 keyframes of 11·W·H bytes (64 MB at 640×480). tmpfs backs
/// only the pages that are touched.
pub mod qos {
    pub const FRAMES_MAX_PUBLISHERS: usize = 2;
    pub const FRAMES_MAX_SUBSCRIBERS: usize = 4;
    pub const FRAMES_BUFFER: usize = 2;
    pub const FRAMES_BORROWED: usize = 2;
    pub const DEPTH_MAX_PUBLISHERS: usize = 2;
    pub const DEPTH_MAX_SUBSCRIBERS: usize = 3;
    pub const DEPTH_BUFFER: usize = 4;
    pub const DEPTH_BORROWED: usize = 2;
    pub const MAX_NODES: usize = 32;
    pub const TELEMETRY_MAX_PUBLISHERS: usize = 16;
    /// Keyframes: 3 · (16 + 2) + 16 + 1 = 71 samples of 5·W·H bytes (109 MB of address space at 640×480; tmpfs
    /// backs only the pages written). A subscriber receives at most its buffer size of history, so the buffer
    /// is as deep as the history: a replacement stereo instance gets all 16 last keyframes.
    pub const KEYFRAMES_MAX_PUBLISHERS: usize = 2;
    pub const KEYFRAMES_MAX_SUBSCRIBERS: usize = 3;
    pub const KEYFRAMES_BUFFER: usize = 16;
    pub const KEYFRAMES_BORROWED: usize = 2;
    /// Poses and corrections are small; their buffers hold seconds of them.
    pub const POSES_MAX_SUBSCRIBERS: usize = 4;
    pub const POSES_BUFFER: usize = 256;
    pub const CORRECTIONS_BUFFER: usize = 1024;
    pub const TELEMETRY_MAX_SUBSCRIBERS: usize = 3;
    /// Records are drained by the launcher every [`TELEMETRY_DRAIN_PERIOD`](super::TELEMETRY_DRAIN_PERIOD); the
    /// buffer holds seconds of them at pipeline rates.
    pub const TELEMETRY_BUFFER: usize = 512;
    /// Standby instances waiting for the launcher's activation (at most one per swappable service at a time).
    pub const ACTIVATION_MAX_SUBSCRIBERS: usize = 4;
    pub const ACTIVATION_BUFFER: usize = 4;
    /// The last keyframes stay in the publisher's history: a stereo instance that joins late (a swap, a
    /// restart after a crash, a replay for a restarted mosaic) receives them and redoes those its downstream
    /// does not have yet. 16 covers a mosaic's checkpoint interval (4) plus its restart (~0.2 s) at the
    /// highest keyframe rate seen (14 per second at 320×240). iceoryx2 delivers at most the subscriber's buffer
    /// size of history: [`KEYFRAMES_BUFFER`] matches it.
    pub const KEYFRAMES_HISTORY: usize = 16;
}

/// How often the launcher drains telemetry. Message records are not individually signalled (that would add a
/// wake-up syscall per frame to every process's hot path); lifecycle records are.
pub const TELEMETRY_DRAIN_PERIOD: Duration = Duration::from_millis(100);

impl Ipc {
    /// Creates this process's node for the run with `prefix`. Creating a node also reclaims the resources of
    /// dead nodes of the run (iceoryx2's default), so a restarted process does not inherit a crashed one's slots.
    pub fn open(node_name: &str, prefix: &str) -> Result<Self, IpcError> {
        let config = config_for_prefix(prefix)?;
        let name = NodeName::new(node_name)
            .map_err(|e| IpcError::Name { name: node_name.to_string(), detail: format!("{e:?}") })?;
        let node = NodeBuilder::new()
            .name(&name)
            .config(&config)
            .create::<ipc::Service>()
            .map_err(iox(format!("create iceoryx2 node `{node_name}` (prefix `{prefix}`)")))?;
        restrict_global_management(prefix);
        Ok(Self { node, prefix: prefix.to_string() })
    }

    fn service_name(topic: Topic) -> Result<ServiceName, IpcError> {
        let name = topic.service_name();
        ServiceName::new(name).map_err(|e| IpcError::Name { name: name.to_string(), detail: format!("{e:?}") })
    }

    /// Opens (or creates) a service, retrying briefly: iceoryx2 reports `IsMarkedForDestruction` or
    /// `ServiceInCorruptedState` while a concurrent dead-node cleanup runs (upstream #1578).
    fn with_retry<T, E: Debug>(context: &str, mut f: impl FnMut() -> Result<T, E>) -> Result<T, IpcError> {
        let mut delay = Duration::from_millis(2);
        let mut attempt = 0;
        loop {
            match f() {
                Ok(v) => return Ok(v),
                Err(e) => {
                    let transient = matches!(
                        format!("{e:?}").as_str(),
                        s if s.contains("IsMarkedForDestruction") || s.contains("CorruptedState") || s.contains("InProgress") || s.contains("IsBeingCreated") || s.contains("HangsInCreation")
                    );
                    attempt += 1;
                    if !transient || attempt > 8 {
                        return Err(iox(context.to_string())(e));
                    }
                    // A short back-off during service setup, never on a per-frame path.
                    std::thread::sleep(delay);
                    delay *= 2;
                }
            }
        }
    }

    pub fn frames(&self) -> Result<FramesService, IpcError> {
        let name = Self::service_name(Topic::Frames)?;
        Self::with_retry("open the frames service", || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<[u8]>()
                .user_header::<FrameHeader>()
                .max_publishers(qos::FRAMES_MAX_PUBLISHERS)
                .max_subscribers(qos::FRAMES_MAX_SUBSCRIBERS)
                .max_nodes(qos::MAX_NODES)
                .subscriber_max_buffer_size(qos::FRAMES_BUFFER)
                .subscriber_max_borrowed_samples(qos::FRAMES_BORROWED)
                .history_size(0)
                .enable_safe_overflow(true)
                .open_or_create()
        })
    }

    pub fn telemetry(&self) -> Result<TelemetryService, IpcError> {
        let name = Self::service_name(Topic::Telemetry)?;
        Self::with_retry("open the telemetry service", || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<TelemetryRecord>()
                .max_publishers(qos::TELEMETRY_MAX_PUBLISHERS)
                .max_subscribers(qos::TELEMETRY_MAX_SUBSCRIBERS)
                .max_nodes(qos::MAX_NODES)
                .subscriber_max_buffer_size(qos::TELEMETRY_BUFFER)
                .subscriber_max_borrowed_samples(2)
                .history_size(0)
                .enable_safe_overflow(true)
                .open_or_create()
        })
    }

    /// A reader of every process's telemetry records (the launcher, `probe telemetry`, `top`).
    pub fn telemetry_subscriber(
        &self,
        service: &TelemetryService,
    ) -> Result<Subscriber<ipc::Service, TelemetryRecord, ()>, IpcError> {
        service.subscriber_builder().buffer_size(qos::TELEMETRY_BUFFER).create().map_err(iox("subscribe to telemetry"))
    }

    /// The event service that wakes consumers of `topic` (same name as the topic).
    pub fn events(&self, topic: Topic) -> Result<Events, IpcError> {
        let name = Self::service_name(topic)?;
        self.event_service(&name, "events")
    }

    /// The event service through which consumers tell acquisition they released a frame (on-demand pacing).
    pub fn frames_consumed(&self) -> Result<Events, IpcError> {
        let name = format!("{}/consumed", Topic::Frames.service_name());
        let name =
            ServiceName::new(&name).map_err(|e| IpcError::Name { name: name.clone(), detail: format!("{e:?}") })?;
        self.event_service(&name, "consumed events")
    }

    fn event_service(&self, name: &ServiceName, what: &str) -> Result<Events, IpcError> {
        Self::with_retry(&format!("open the {what} service `{name}`"), || {
            self.node
                .service_builder(name)
                .event()
                .max_nodes(qos::MAX_NODES)
                .max_notifiers(qos::TELEMETRY_MAX_PUBLISHERS)
                .max_listeners(qos::TELEMETRY_MAX_PUBLISHERS)
                .event_id_max_value(event_id::MAX)
                .notifier_dead_event(EventId::new(event_id::NOTIFIER_DEAD))
                .open_or_create()
        })
    }

    /// A publisher of frames up to `max_frame_bytes`, with one loan outstanding at a time. `Static` allocation:
    /// the segment is sized once, a frame never triggers a re-mapping.
    pub fn frame_publisher(
        &self,
        service: &FramesService,
        max_frame_bytes: usize,
    ) -> Result<Publisher<ipc::Service, [u8], FrameHeader>, IpcError> {
        slice_publisher(service, max_frame_bytes, "create the frames publisher")
    }

    /// A frames subscriber with the service's full buffer (loses nothing at the rate it keeps up with).
    pub fn frame_subscriber(
        &self,
        service: &FramesService,
    ) -> Result<Subscriber<ipc::Service, [u8], FrameHeader>, IpcError> {
        service
            .subscriber_builder()
            .buffer_size(qos::FRAMES_BUFFER)
            .create()
            .map_err(iox("create the frames subscriber"))
    }

    pub fn poses(&self) -> Result<PosesService, IpcError> {
        self.record_service::<PoseRecord>(Topic::Poses, qos::POSES_BUFFER)
    }

    pub fn corrections(&self) -> Result<CorrectionsService, IpcError> {
        self.record_service::<KeyframePose>(Topic::Corrections, qos::CORRECTIONS_BUFFER)
    }

    /// A topic of small fixed-size records (poses, corrections): two publishers, a few subscribers, `buffer`
    /// records per subscriber.
    fn record_service<T: std::fmt::Debug + ZeroCopySend + 'static>(
        &self,
        topic: Topic,
        buffer: usize,
    ) -> Result<PubSubFactory<ipc::Service, T, ()>, IpcError> {
        let name = Self::service_name(topic)?;
        Self::with_retry(&format!("open the {} service", topic.short_name()), || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<T>()
                .max_publishers(2)
                .max_subscribers(qos::POSES_MAX_SUBSCRIBERS)
                .max_nodes(qos::MAX_NODES)
                .subscriber_max_buffer_size(buffer)
                .subscriber_max_borrowed_samples(2)
                .history_size(0)
                .enable_safe_overflow(true)
                .open_or_create()
        })
    }

    pub fn keyframes(&self) -> Result<KeyframesService, IpcError> {
        let name = Self::service_name(Topic::Keyframes)?;
        Self::with_retry("open the keyframes service", || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<[u8]>()
                .user_header::<KeyframeHeader>()
                .max_publishers(qos::KEYFRAMES_MAX_PUBLISHERS)
                .max_subscribers(qos::KEYFRAMES_MAX_SUBSCRIBERS)
                .max_nodes(qos::MAX_NODES)
                .subscriber_max_buffer_size(qos::KEYFRAMES_BUFFER)
                .subscriber_max_borrowed_samples(qos::KEYFRAMES_BORROWED)
                .history_size(qos::KEYFRAMES_HISTORY)
                .enable_safe_overflow(true)
                .open_or_create()
        })
    }

    /// A keyframe publisher for frames of up to `max_frame_bytes` (as [`Ipc::frame_publisher`]).
    pub fn keyframe_publisher(
        &self,
        service: &KeyframesService,
        max_frame_bytes: usize,
    ) -> Result<Publisher<ipc::Service, [u8], KeyframeHeader>, IpcError> {
        slice_publisher(service, max_frame_bytes, "create the keyframes publisher")
    }

    pub fn keyframe_subscriber(
        &self,
        service: &KeyframesService,
    ) -> Result<Subscriber<ipc::Service, [u8], KeyframeHeader>, IpcError> {
        service
            .subscriber_builder()
            .buffer_size(qos::KEYFRAMES_BUFFER)
            .create()
            .map_err(iox("create the keyframes subscriber"))
    }

    pub fn depth(&self) -> Result<DepthService, IpcError> {
        let name = Self::service_name(Topic::Depth)?;
        // No `payload_alignment`: iceoryx2 0.10 pads every *element* of a slice to the payload alignment
        // (`chunk_layout`: align(size, alignment) × elements), so alignment 8 on `[u8]` reserved 8× the bytes —
        // 513 MB of /dev/shm for 640×480 depth instead of 64 MB. The float arrays are aligned anyway: the payload
        // follows the 8-aligned `DepthHeader`, whose size is a multiple of 8, and `DepthView` checks it.
        Self::with_retry("open the depth service", || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<[u8]>()
                .user_header::<DepthHeader>()
                .max_publishers(qos::DEPTH_MAX_PUBLISHERS)
                .max_subscribers(qos::DEPTH_MAX_SUBSCRIBERS)
                .max_nodes(qos::MAX_NODES)
                .subscriber_max_buffer_size(qos::DEPTH_BUFFER)
                .subscriber_max_borrowed_samples(qos::DEPTH_BORROWED)
                .history_size(0)
                .enable_safe_overflow(true)
                .open_or_create()
        })
    }

    /// A depth publisher for keyframes of up to `max_bytes` (see [`DepthHeader::payload_len`]).
    pub fn depth_publisher(
        &self,
        service: &DepthService,
        max_bytes: usize,
    ) -> Result<Publisher<ipc::Service, [u8], DepthHeader>, IpcError> {
        slice_publisher(service, max_bytes, "create the depth publisher")
    }

    pub fn depth_subscriber(
        &self,
        service: &DepthService,
    ) -> Result<Subscriber<ipc::Service, [u8], DepthHeader>, IpcError> {
        service.subscriber_builder().buffer_size(qos::DEPTH_BUFFER).create().map_err(iox("create the depth subscriber"))
    }

    pub fn notifier(&self, events: &Events) -> Result<Notifier<ipc::Service>, IpcError> {
        events.notifier_builder().create().map_err(iox("create a notifier"))
    }

    pub fn listener(&self, events: &Events) -> Result<Listener<ipc::Service>, IpcError> {
        events.listener_builder().create().map_err(iox("create a listener"))
    }

    /// Reclaims the resources of dead processes of this run (cheap when there are none).
    pub fn cleanup_dead_nodes(&self) -> usize {
        self.node.try_cleanup_dead_nodes().cleanups as usize
    }
}

/// A publisher of `[u8]` samples up to `max_bytes` with one loan outstanding and a segment sized once.
fn slice_publisher<H: Debug + ZeroCopySend>(
    service: &PubSubFactory<ipc::Service, [u8], H>,
    max_bytes: usize,
    what: &'static str,
) -> Result<Publisher<ipc::Service, [u8], H>, IpcError> {
    service
        .publisher_builder()
        .initial_max_slice_len(max_bytes)
        .allocation_strategy(AllocationStrategy::Static)
        .max_loaned_samples(1)
        .create()
        .map_err(iox(what))
}

/// iceoryx2 0.10 creates the run's global management segment (`/dev/shm/<prefix>…global_mgmt`, 16 bytes) with
/// mode 0666 — readable and writable by every user — while every other file of the run, frames included, is 0600.
/// A run is one user's processes, so it is narrowed to 0600: other users can neither read nor disturb a run.
/// Best effort (a file of another user is left alone); the first node of a run (the launcher's) does it.
fn restrict_global_management(prefix: &str) {
    use std::os::unix::fs::PermissionsExt;
    let Ok(entries) = std::fs::read_dir("/dev/shm") else { return };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with(prefix)
            && name.ends_with("global_mgmt")
            && entry.metadata().is_ok_and(|m| m.permissions().mode() & 0o077 != 0)
        {
            let _ = std::fs::set_permissions(entry.path(), std::fs::Permissions::from_mode(0o600));
        }
    }
}

/// A string in a fixed-size, NUL-padded field of a message, cut at a character boundary so it stays UTF-8.
pub(crate) fn fixed<const N: usize>(s: &str) -> [u8; N] {
    let mut out = [0u8; N];
    let mut n = s.len().min(N);
    while !s.is_char_boundary(n) {
        n -= 1;
    }
    out[..n].copy_from_slice(&s.as_bytes()[..n]);
    out
}

/// The string in a fixed-size, NUL-padded field (`?` when a sender wrote something that is not UTF-8).
pub(crate) fn text(bytes: &[u8]) -> &str {
    let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
    std::str::from_utf8(&bytes[..end]).unwrap_or("?")
}

/// Notifies with one of the [`event_id`]s.
pub fn notify(notifier: &Notifier<ipc::Service>, id: usize) -> Result<usize, IpcError> {
    notifier.notify_with_custom_event_id(EventId::new(id)).map_err(iox("notify"))
}

/// Waits until `receive` yields something (a request-response answer, typically) or `deadline` passes; between
/// tries it sleeps in a WaitSet on `listener`, the event service the other side signals on. `None` on timeout.
pub fn wait_for<T>(
    listener: &Listener<ipc::Service>,
    deadline: std::time::Instant,
    mut receive: impl FnMut() -> Result<Option<T>, IpcError>,
) -> Result<Option<T>, IpcError> {
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(iox("create a WaitSet"))?;
    let _guard = waitset.attach_notification(listener).map_err(iox("attach the listener"))?;
    loop {
        if let Some(answer) = receive()? {
            return Ok(Some(answer));
        }
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        if left.is_zero() {
            return Ok(None);
        }
        waitset
            .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, left)
            .map_err(iox("wait for an answer"))?;
        let _ = drain_events(listener);
    }
}

/// Drains a listener's pending events and reports which ids were seen (bit `1 << id`).
pub fn drain_events(listener: &Listener<ipc::Service>) -> Result<u32, IpcError> {
    let mut seen = 0u32;
    listener
        .try_wait(|activation| {
            let id = activation.id.as_value();
            if id < 32 {
                seen |= 1 << id;
            }
        })
        .map_err(iox("read events"))?;
    Ok(seen)
}

/// Removes what dead processes of the run with `prefix` left behind (their nodes, ports, services), without
/// creating a node. Returns how many dead nodes were cleaned.
pub fn cleanup_dead_nodes_of_run(prefix: &str) -> Result<usize, IpcError> {
    let config = config_for_prefix(prefix)?;
    let mut cleaned = 0;
    Node::<ipc::Service>::list(&config, |state| {
        if let NodeState::Dead(view) = state
            && view.try_remove_stale_resources().is_ok()
        {
            cleaned += 1;
        }
        CallbackProgression::Continue
    })
    .map_err(iox("list nodes"))?;
    Ok(cleaned)
}

/// How many live nodes the run with `prefix` has.
pub fn live_nodes_of_run(prefix: &str) -> Result<usize, IpcError> {
    let config = config_for_prefix(prefix)?;
    let mut alive = 0;
    Node::<ipc::Service>::list(&config, |state| {
        if matches!(state, NodeState::Alive(_)) {
            alive += 1;
        }
        CallbackProgression::Continue
    })
    .map_err(iox("list nodes"))?;
    Ok(alive)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topics_parse_by_short_and_service_name() {
        for t in Topic::ALL {
            assert_eq!(Topic::parse(t.short_name()), Some(t));
            assert_eq!(Topic::parse(t.service_name()), Some(t));
        }
        assert_eq!(Topic::parse("nope"), None);
    }

    #[test]
    #[allow(clippy::unwrap_used)]
    fn no_file_of_a_run_is_accessible_by_other_users() {
        use std::os::unix::fs::PermissionsExt;
        let prefix = format!("bipcperm{}_", std::process::id());
        let ipc = Ipc::open("perm-test", &prefix).unwrap();
        let frames = ipc.frames().unwrap();
        let _publisher = ipc.frame_publisher(&frames, 1024).unwrap();
        let _events = ipc.events(Topic::Frames).unwrap();
        let files: Vec<_> = std::fs::read_dir("/dev/shm")
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with(prefix.as_str()))
            .collect();
        assert!(files.iter().any(|e| e.file_name().to_string_lossy().ends_with("global_mgmt")), "{files:?}");
        for e in &files {
            let mode = e.metadata().unwrap().permissions().mode();
            assert_eq!(mode & 0o077, 0, "{:?}: mode {mode:o}", e.path());
        }
        drop(ipc);
        // iceoryx2 keeps the global management file after the last node; a test leaves nothing behind.
        remove_run_files(&prefix);
    }

    /// Removes what a test run with `prefix` left in /dev/shm.
    pub(crate) fn remove_run_files(prefix: &str) {
        for e in std::fs::read_dir("/dev/shm").into_iter().flatten().flatten() {
            if e.file_name().to_string_lossy().starts_with(prefix) {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}
