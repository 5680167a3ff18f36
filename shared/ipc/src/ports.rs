//! Opening every topic's service with its QoS, and the ports on it. Every process opens its services through
//! these functions, so the QoS a service is created with is the same whoever creates it first.

use super::*;
use crate::error::Transient;

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
        // iceoryx2 installs its SIGINT/SIGTERM handler lazily, at the first check for a termination request. Check
        // once now: a stop that arrived between a service saying it is ready and its first wait would otherwise
        // take the default action and kill it, skipping the ordered shutdown (the map written, the telemetry
        // closed). No signal can have been captured yet, so nothing is lost by the check.
        let _ = node.wait(Duration::ZERO);
        Ok(Self { node, prefix: prefix.to_string() })
    }

    pub(crate) fn service_name(topic: Topic) -> Result<ServiceName, IpcError> {
        let name = topic.service_name();
        ServiceName::new(name).map_err(|e| IpcError::Name { name: name.to_string(), detail: format!("{e:?}") })
    }

    /// Opens (or creates) a service, retrying briefly: iceoryx2 reports `IsMarkedForDestruction` or
    /// `ServiceInCorruptedState` while a concurrent dead-node cleanup runs (upstream #1578).
    pub(crate) fn with_retry<T, E: Transient + std::error::Error + Send + Sync + 'static>(
        context: &str,
        mut f: impl FnMut() -> Result<T, E>,
    ) -> Result<T, IpcError> {
        let mut delay = Duration::from_millis(2);
        let mut attempt = 0;
        loop {
            match f() {
                Ok(v) => return Ok(v),
                Err(e) => {
                    attempt += 1;
                    if !e.is_transient() || attempt > 8 {
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

    pub(crate) fn event_service(&self, name: &ServiceName, what: &str) -> Result<Events, IpcError> {
        Self::with_retry(&format!("open the {what} service `{name}`"), || {
            self.node
                .service_builder(name)
                .event()
                .max_nodes(qos::MAX_NODES)
                .max_notifiers(qos::EVENT_MAX_NOTIFIERS)
                .max_listeners(qos::EVENT_MAX_LISTENERS)
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
        self.record_service::<PoseRecord>(
            Topic::Poses,
            qos::POSES_MAX_PUBLISHERS,
            qos::POSES_MAX_SUBSCRIBERS,
            qos::POSES_BUFFER,
        )
    }

    pub fn corrections(&self) -> Result<CorrectionsService, IpcError> {
        self.record_service::<KeyframePose>(
            Topic::Corrections,
            qos::CORRECTIONS_MAX_PUBLISHERS,
            qos::CORRECTIONS_MAX_SUBSCRIBERS,
            qos::CORRECTIONS_BUFFER,
        )
    }

    /// A topic of small fixed-size records (poses, corrections), with the topic's own limits and `buffer`
    /// records per subscriber.
    pub(crate) fn record_service<T: std::fmt::Debug + ZeroCopySend + 'static>(
        &self,
        topic: Topic,
        max_publishers: usize,
        max_subscribers: usize,
        buffer: usize,
    ) -> Result<PubSubFactory<ipc::Service, T, ()>, IpcError> {
        let name = Self::service_name(topic)?;
        Self::with_retry(&format!("open the {} service", topic.short_name()), || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<T>()
                .max_publishers(max_publishers)
                .max_subscribers(max_subscribers)
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
pub(crate) fn slice_publisher<H: Debug + ZeroCopySend>(
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
