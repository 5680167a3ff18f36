//! The acquisition node for a live source: the devices set the pace. Their wake-up descriptors sit in the
//! WaitSet beside the consumers' events; each complete frame is converted straight into a loaned sample and
//! published at once. No frame waits for a consumer (a camera does not wait either): a consumer that falls
//! behind misses frames, which it counts from the gaps in the frame numbers, as acquisition counts the
//! frames the devices dropped before it took them.

use std::time::Duration;

use anyhow::{Context, Result};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::{FrameHeader, FrameLayout, event_id};
use bdis_source::live::{LiveSource, Poll};
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

/// A device's wake-up descriptor, as the WaitSet takes it.
#[derive(Debug)]
struct DeviceFd(FileDescriptor);

impl FileDescriptorBased for DeviceFd {
    fn file_descriptor(&self) -> &FileDescriptor {
        &self.0
    }
}

impl SynchronousMultiplexing for DeviceFd {}

/// What `bdis-acquisition` was asked to do with a live source.
#[derive(Debug)]
pub struct Options {
    pub spec: bdis_source::LiveSpec,
    pub settings: Option<std::path::PathBuf>,
    pub start: usize,
    pub max_frames: Option<usize>,
    pub interlaced: Option<bdis_source::FieldMode>,
    /// A raw stereo calibration to rectify every frame with, and its free scaling.
    pub calibration: Option<(std::path::PathBuf, Option<f64>)>,
    /// Only open the devices, print what they deliver, and exit.
    pub check: bool,
    pub name: String,
    pub ipc_prefix: String,
}

/// Opens the devices (an emulated one starts capturing) and checks them against the settings before any
/// shared memory exists, then streams.
pub fn open_and_run(options: Options) -> Result<()> {
    let Options { spec, settings, start, max_frames, interlaced, calibration, check, name, ipc_prefix } = options;
    let mut source = LiveSource::open(&spec, start)?;
    if let Some((path, alpha)) = &calibration {
        let rectifier = crate::input::rectifier(path, source.view_size(), *alpha)?;
        source = source.with_rectifier(rectifier).context("the rectification's maps do not fit the views")?;
    }
    if let Some(mode) = interlaced {
        let (w, h) = source.view_size();
        source = source
            .with_fields(mode)
            .with_context(|| format!("`{}`: {w}×{h} views cannot be split into fields", spec.text))?;
    }
    let (width, height) = source.view_size();
    if let Some(path) = &settings {
        let settings = bdis_core::Settings::load(path)?;
        if let Some((field, expected, _)) = bdis_source::size_mismatch(&settings.camera, (width, height)) {
            anyhow::bail!("{}: {field} is {expected}, but the live views are {width}×{height}", path.display());
        }
    }
    let layout = FrameLayout::packed(width, height)
        .with_context(|| format!("`{}`: {width}×{height} views are too large", spec.text))?;
    if check {
        println!("{}: live ({}), {}, views of {width}×{height}", spec.text, spec.arrangement.name(), source.describe());
        return Ok(());
    }
    run(Config { source, layout, max_frames, name, ipc_prefix })
}

#[derive(Debug)]
pub struct Config {
    pub source: LiveSource,
    pub layout: FrameLayout,
    /// Stop after this many published frames.
    pub max_frames: Option<usize>,
    pub name: String,
    pub ipc_prefix: String,
}

pub fn run(config: Config) -> Result<()> {
    let Config { mut source, layout, max_frames, name, ipc_prefix } = config;
    let frame_bytes = layout.payload_len();
    let mut ports = crate::ports::Ports::open(&name, &ipc_prefix, frame_bytes)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(bdis_node::NodeError::WaitSet)?;
    let consumed_guard = waitset.attach_notification(&ports.consumed).map_err(bdis_node::NodeError::Attach)?;
    let device_fds: Vec<DeviceFd> = source
        .wake_fds()
        .map(|fd| {
            use std::os::fd::AsRawFd;
            // Non-owning: the source keeps its descriptors open for as long as this node runs.
            FileDescriptor::non_owning_new(fd.as_raw_fd()).map(DeviceFd)
        })
        .collect::<Option<_>>()
        .context("a device's descriptor")?;
    let _device_guards = device_fds
        .iter()
        .map(|fd| waitset.attach_notification(fd).map_err(bdis_node::NodeError::Attach))
        .collect::<Result<Vec<_>, _>>()?;
    ports.telemetry.ready();
    let (w, h) = source.view_size();
    tracing::info!("streaming {w}×{h} stereo frames live from {} (prefix {ipc_prefix})", source.describe());

    let mut published: u64 = 0;
    // Frames the devices captured that were never published (dropped by a device, or overwritten before this
    // node took them): the gaps in the devices' frame numbers.
    let mut dropped: u64 = 0;
    let mut last_sequence: Option<u64> = None;
    let mut answer_join = true;
    let mut result = Ok(());
    let stop_requested = 'stream: loop {
        let mut joined = false;
        let run = waitset
            .wait_and_process_once_with_timeout(
                |id| {
                    if id.has_event_from(&consumed_guard) {
                        // Credits mean nothing to a live source; only a consumer's announcement matters.
                        let _ = ports.consumed.try_wait(|activation| {
                            joined |= activation.id.as_value() == event_id::JOINED;
                        });
                    }
                    CallbackProgression::Continue
                },
                // The timeout only keeps the liveness record fresh while a device is silent.
                Duration::from_secs(1),
            )
            .map_err(bdis_node::NodeError::Wait)?;
        ports.telemetry.keepalive();
        answer_join |= joined;
        if matches!(run, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            break true;
        }
        loop {
            match source.poll() {
                Ok(Poll::Waiting) => break,
                Ok(Poll::Ended) => break 'stream false,
                Ok(Poll::Ready) => {}
                Err(e) => {
                    result = Err(anyhow::Error::new(e));
                    break 'stream false;
                }
            }
            let mut sample = match ports.publisher.loan_slice_uninit(frame_bytes) {
                Ok(s) => s,
                Err(e) => {
                    result = Err(anyhow::Error::new(e).context("loan a shared-memory frame"));
                    break 'stream false;
                }
            };
            let captured = match source.read_into(&layout, sample.payload_mut()) {
                Ok(c) => c,
                // A corrupt compressed frame: dropped and counted, the stream goes on.
                Err(e @ bdis_source::LiveError::Convert { sequence, .. }) => {
                    tracing::warn!("{e}");
                    dropped += (sequence + 1).saturating_sub(last_sequence.map_or(0, |last| last + 1));
                    last_sequence = Some(sequence);
                    continue;
                }
                Err(e) => {
                    result = Err(e.into());
                    break 'stream false;
                }
            };
            // Device frames from 0: the first published one may already follow some that were dropped.
            dropped += captured.sequence.saturating_sub(last_sequence.map_or(0, |last| last + 1));
            last_sequence = Some(captured.sequence);
            // SAFETY: read_into wrote every byte of the packed layout, which is the whole loaned slice.
            let sample = unsafe { sample.assume_init() };
            // Frames are numbered as published (consumers count their own misses from the gaps); the device's
            // number is kept as the source index.
            let header = FrameHeader {
                frame_seq: published,
                t_capture_ns: captured.t_capture_ns,
                // The device's clock from the start of its stream: what a recording's timestamps are.
                t_source_ns: captured.t_stream_ns,
                source_index: u32::try_from(captured.sequence).unwrap_or(u32::MAX),
                flags: if answer_join { FrameHeader::ANSWERS_JOIN } else { 0 },
                ..Default::default()
            };
            let t_publish_ns = match ports.publish(sample, header, &layout) {
                Ok(t) => t,
                Err(e) => {
                    result = Err(e);
                    break 'stream false;
                }
            };
            published += 1;
            answer_join = false;
            ports.telemetry.message(
                MessageTiming {
                    frame_seq: published - 1,
                    t_capture_ns: captured.t_capture_ns,
                    t_done_ns: t_publish_ns,
                    ..Default::default()
                },
                dropped,
            );
            if max_frames.is_some_and(|m| published >= m as u64) {
                break 'stream false;
            }
        }
    };

    let eos_sent = ports.end_stream(published);
    let unpaired = if source.unpaired > 0 { format!(", {} unpaired", source.unpaired) } else { String::new() };
    let how = if stop_requested { "stop requested: " } else { "" };
    match result {
        Ok(()) => {
            ports.telemetry.finished();
            tracing::info!(
                "{how}published {published} live frames ({dropped} dropped before publishing{unpaired}); end of stream"
            );
            Ok(eos_sent?)
        }
        Err(e) => {
            ports.telemetry.failed();
            Err(e.context(format!("stopped after {published} live frames")))
        }
    }
}
