//! QoS of every topic. Sizing (IPC-NOTES §2): samples per publisher segment =
//! subscribers · (buffer + borrowed) + history + loaned; frames: 4 · (2 + 2) + 0 + 1 = 17 frames of 5·W·H bytes
//! (26 MB at 640×480); depth: 3 · (4 + 2) + 0 + 1 = 19 keyframes of 11·W·H bytes (64 MB at 640×480). tmpfs backs
//! only the pages that are touched.

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
/// Poses and corrections are small; their buffers hold seconds of them. One tracker publishes each (two
/// during a make-before-break handover).
pub const POSES_MAX_PUBLISHERS: usize = 2;
pub const POSES_MAX_SUBSCRIBERS: usize = 4;
pub const POSES_BUFFER: usize = 256;
pub const CORRECTIONS_MAX_PUBLISHERS: usize = 2;
pub const CORRECTIONS_MAX_SUBSCRIBERS: usize = 4;
pub const CORRECTIONS_BUFFER: usize = 1024;
/// Every event service (wake-ups, consumed credits, snapshot and control signals): notifiers and listeners
/// per service. A topic's event service has a notifier per producer and a listener per consumer, plus the
/// launcher's and the tools'; 16 leaves room for the probe, `top` and a standby instance.
pub const EVENT_MAX_NOTIFIERS: usize = 16;
pub const EVENT_MAX_LISTENERS: usize = 16;
/// Telemetry readers: the launcher, `bdis-slam top`, the viewer and the OpenIGTLink service.
pub const TELEMETRY_MAX_SUBSCRIBERS: usize = 4;
/// Records are drained by the launcher every [`TELEMETRY_DRAIN_PERIOD`](super::TELEMETRY_DRAIN_PERIOD); the
/// buffer holds seconds of them at pipeline rates.
pub const TELEMETRY_BUFFER: usize = 512;
/// The launcher's control service (swap requests): the launcher serves, `bdis-slam swap` and tests ask.
pub const CONTROL_MAX_SERVERS: usize = 1;
pub const CONTROL_MAX_CLIENTS: usize = 4;
/// The map snapshot service: the mosaic serves (or, on a host without it, the bridge for the far host's);
/// `bdis-slam snapshot`, the OpenIGTLink service and the bridge (for the far host) ask — with one more for a
/// second `bdis-slam snapshot` at once.
pub const MAP_SNAPSHOT_MAX_SERVERS: usize = 1;
pub const MAP_SNAPSHOT_MAX_CLIENTS: usize = 4;
/// The launcher activates standby instances; standby instances waiting for the launcher's activation (at most one per swappable service at a time).
pub const ACTIVATION_MAX_PUBLISHERS: usize = 1;
pub const ACTIVATION_MAX_SUBSCRIBERS: usize = 4;
pub const ACTIVATION_BUFFER: usize = 4;
/// The last keyframes stay in the publisher's history: a stereo instance that joins late (a swap, a
/// restart after a crash, a replay for a restarted mosaic) receives them and redoes those its downstream
/// does not have yet. 16 covers a mosaic's checkpoint interval (4) plus its restart (~0.2 s) at the
/// highest keyframe rate seen (14 per second at 320×240). iceoryx2 delivers at most the subscriber's buffer
/// size of history: [`KEYFRAMES_BUFFER`] matches it.
pub const KEYFRAMES_HISTORY: usize = 16;
