//! The pipeline's topics and the event ids of their wake-up services: names defined here and nowhere else.

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
