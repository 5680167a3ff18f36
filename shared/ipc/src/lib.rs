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

mod error;
mod ports;
pub mod qos;
mod topic;

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
pub mod validate;

pub use clock::monotonic_ns;
pub use depth::{DepthHeader, DepthView};
pub use frame::{FrameHeader, FrameLayout, FrameView, JoinGate};
pub use map::{MapPoint, MapQuery, MapSnapshotHeader};
pub use telemetry::{ReadyWatch, TelemetryKind, TelemetryPublisher, TelemetryRecord};
pub use track::{KeyframeHeader, KeyframeMeta, KeyframePose, PoseRecord, StereoIntrinsics};

pub use error::{IceoryxError, IpcError, Transient, iox};
pub use topic::{Topic, event_id};

/// The environment variable through which the launcher hands each child its run's name prefix.
pub const PREFIX_ENV: &str = "BDIS_IPC_PREFIX";
/// The prefix used when none is given (a user starting services by hand).
pub const DEFAULT_PREFIX: &str = "bdis_";

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

/// How often the launcher drains telemetry. Message records are not individually signalled (that would add a
/// wake-up syscall per frame to every process's hot path); lifecycle records are.
pub const TELEMETRY_DRAIN_PERIOD: Duration = Duration::from_millis(100);

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

/// Removes every file of the run with `prefix` from /dev/shm (once its processes are gone: iceoryx2 keeps the
/// global management file after the last node); returns how many.
pub fn remove_run_files(prefix: &str) -> usize {
    let mut removed = 0;
    for e in std::fs::read_dir("/dev/shm").into_iter().flatten().flatten() {
        if e.file_name().to_string_lossy().starts_with(prefix) && std::fs::remove_file(e.path()).is_ok() {
            removed += 1;
        }
    }
    removed
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
mod tests;
