//! The shared-memory ports of an acquisition instance, the same for a sequence and for a live source.

use anyhow::Result;
use bdis_ipc::{FrameHeader, FramesService, Ipc, TelemetryPublisher, Topic, event_id, monotonic_ns};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;

pub struct Ports {
    /// The frames service, kept open for its subscriber count.
    pub frames: FramesService,
    pub publisher: Publisher<ipc::Service, [u8], FrameHeader>,
    /// Wakes the consumers: a new frame, the end of the stream.
    pub notifier: Notifier<ipc::Service>,
    /// The consumers' events: a frame released, a consumer joined, a consumer died.
    pub consumed: Listener<ipc::Service>,
    pub telemetry: TelemetryPublisher,
    /// Last, so every port above is closed before the node.
    pub ipc: Ipc,
}

impl std::fmt::Debug for Ports {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ports").finish_non_exhaustive()
    }
}

impl Ports {
    pub fn open(name: &str, ipc_prefix: &str, frame_bytes: usize) -> Result<Self> {
        let ipc = Ipc::open(name, ipc_prefix)?;
        let frames = ipc.frames()?;
        Ok(Self {
            publisher: ipc.frame_publisher(&frames, frame_bytes)?,
            notifier: ipc.notifier(&ipc.events(Topic::Frames)?)?,
            consumed: ipc.listener(&ipc.frames_consumed()?)?,
            telemetry: TelemetryPublisher::new(&ipc, name, None, Some(Topic::Frames))?,
            frames,
            ipc,
        })
    }

    /// Sends the end of the stream, numbered after the last frame, so consumers stop cleanly and keep what
    /// they have; sent in every case, also after an error or a stop request.
    pub fn end_stream(&self, frame_seq: u64) -> Result<(), bdis_node::NodeError> {
        let sent = bdis_node::send_end_of_stream(
            &self.publisher,
            FrameHeader {
                frame_seq,
                flags: FrameHeader::END_OF_STREAM,
                t_capture_ns: monotonic_ns(),
                t_publish_ns: monotonic_ns(),
                ..Default::default()
            },
        );
        if let Err(e) = bdis_ipc::notify(&self.notifier, event_id::END_OF_STREAM) {
            tracing::warn!("end of stream: {:#}", anyhow::Error::from(e));
        }
        sent
    }
}
