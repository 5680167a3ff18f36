//! The shared-memory ports of an acquisition instance, the same for a sequence and for a live source.

use anyhow::Result;
use bdis_ipc::{FrameHeader, FrameLayout, FramesService, Ipc, TelemetryPublisher, Topic, event_id, monotonic_ns};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;
use iceoryx2::sample_mut::SampleMut;

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

    /// Sends a filled frame with `header` (completed with the payload's layout and the publish time) and wakes
    /// the consumers; the publish time.
    pub fn publish(
        &self,
        mut sample: SampleMut<ipc::Service, [u8], FrameHeader>,
        header: FrameHeader,
        layout: &FrameLayout,
    ) -> Result<u64> {
        let frame_seq = header.frame_seq;
        let slot = sample.user_header_mut();
        *slot = header;
        layout.write_into(slot);
        let t_publish_ns = monotonic_ns();
        slot.t_publish_ns = t_publish_ns;
        sample.send().map_err(|e| anyhow::Error::new(e).context(format!("send frame {frame_seq}")))?;
        if let Err(e) = bdis_ipc::notify(&self.notifier, event_id::NEW_SAMPLE) {
            tracing::warn!("frame {frame_seq}: {:#}", anyhow::Error::from(e));
        }
        Ok(t_publish_ns)
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
