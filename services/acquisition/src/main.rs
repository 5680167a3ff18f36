//! `bdis-acquisition`: reads a stereo sequence and publishes every frame once into shared memory.
//!
//! Shell only: check the input (before any shared memory exists), open the ports, then for each frame wait until
//! it is due, decode it straight into a loaned sample, send, notify, record timings. End of stream is a last
//! sample flagged `END_OF_STREAM`, so consumers finish cleanly, also after an error or a stop request.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use bdis_acquisition::{FrameDecoder, Pacing, Schedule, check_input};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::{FrameHeader, FrameLayout, Ipc, TelemetryPublisher, Topic, event_id, monotonic_ns};
use clap::Parser;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

/// Publish a stereo image sequence into shared memory, frame by frame.
#[derive(Debug, Parser)]
#[command(name = "bdis-acquisition", version)]
struct Args {
    /// Sequence folder: BDIS-SLAM/Hamlyn (`images_rectified/{left,right}`), plain (`left/`, `right/`) or KITTI
    /// (`image_0/`, `image_1/`); or `synthetic:<scene>[:<trajectory>][:<frames>]` (e.g. `synthetic:colon`,
    /// `synthetic:abdomen:hover:90`), rendered before streaming into the run folder (or a temporary folder).
    #[arg(long)]
    sequence: PathBuf,
    /// Settings file (ORB-SLAM2 YAML or bdis-slam TOML); checked against the images.
    #[arg(long)]
    settings: Option<PathBuf>,
    /// `on-demand` (next frame when a consumer asks), `recorded` (follow times.txt), a rate such as `30hz`, or
    /// `on-demand:30hz` (when a consumer asks, but no faster than the rate: never drops a frame).
    #[arg(long, default_value = "on-demand")]
    pacing: Pacing,
    /// Stop after this many frames.
    #[arg(long)]
    max_frames: Option<usize>,
    /// Name of this process in the run (telemetry, logs).
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "acquisition")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
    /// Only check the sequence and settings, print a summary, and exit.
    #[arg(long)]
    check: bool,
}

/// How the stream ended.
#[derive(Debug)]
enum End {
    Completed,
    StopRequested,
    Failed(anyhow::Error),
}

fn main() -> ExitCode {
    bdis_ipc::process::init_logging();
    bdis_ipc::process::finish("bdis-acquisition", run(Args::parse()))
}

fn run(args: Args) -> Result<()> {
    let (sequence_dir, settings) = match args.sequence.to_str().and_then(bdis_acquisition::parse_synthetic) {
        Some(request) => {
            let request = request.map_err(anyhow::Error::msg)?;
            let base = std::env::var_os("BDIS_RUN_DIR").map(PathBuf::from).unwrap_or_else(std::env::temp_dir);
            let dir = base.join(format!("synthetic-{}-{}", request.scene, std::process::id()));
            tracing::info!("rendering {} frames of `{}` into {}", request.frames, request.scene, dir.display());
            let frames = request.frames;
            let (dir, rendered_settings) = bdis_acquisition::render_synthetic(&request, &dir, |i| {
                if (i + 1) % 10 == 0 || i + 1 == frames {
                    tracing::info!("rendered {}/{frames}", i + 1);
                }
            })?;
            (dir, Some(args.settings.clone().unwrap_or(rendered_settings)))
        }
        None => (args.sequence.clone(), args.settings.clone()),
    };
    let input = check_input(&sequence_dir, settings.as_deref())?;
    let sequence = &input.sequence;
    let layout = FrameLayout::packed(sequence.width, sequence.height).with_context(|| {
        format!("{}: {}×{} images are too large", sequence.root.display(), sequence.width, sequence.height)
    })?;
    let frame_count = args.max_frames.map_or(sequence.len(), |m| m.min(sequence.len()));
    if args.check {
        println!(
            "{}: {:?} layout, {} stereo pairs of {}×{}, timestamps: {}",
            sequence.root.display(),
            sequence.layout,
            sequence.len(),
            sequence.width,
            sequence.height,
            if sequence.frames[0].t_source_s.is_some() { "yes" } else { "no" }
        );
        return Ok(());
    }

    let ipc = Ipc::open(&args.name, &args.ipc_prefix)?;
    let frames = ipc.frames()?;
    let frame_bytes = layout.payload_len();
    let publisher = ipc.frame_publisher(&frames, frame_bytes)?;
    let notifier = ipc.notifier(&ipc.events(Topic::Frames)?)?;
    let consumed = ipc.listener(&ipc.frames_consumed()?)?;
    let mut telemetry = TelemetryPublisher::new(&ipc, &args.name, None, Some(Topic::Frames))?;
    let waitset =
        WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| anyhow::anyhow!("create a WaitSet: {e:?}"))?;
    let consumed_guard =
        waitset.attach_notification(&consumed).map_err(|e| anyhow::anyhow!("attach the consumed listener: {e:?}"))?;
    telemetry.ready();
    tracing::info!(
        "streaming {frame_count} frames of {}×{} from {} ({:?} pacing, prefix {})",
        sequence.width,
        sequence.height,
        sequence.root.display(),
        args.pacing,
        args.ipc_prefix
    );

    let schedule = Schedule::new(args.pacing, sequence.frames[0].t_source_s, input.fps.unwrap_or(30.0));
    let mut decoder = FrameDecoder::new();
    // Credits for on-demand pacing: a consumer sends one each time it is ready for the next frame. A consumer
    // that subscribed before this process existed sent its first one into the void, so an existing subscriber
    // counts as one credit.
    let mut credits: u64 = u64::from(frames.dynamic_config().number_of_subscribers() > 0);
    // On demand, frames sent but not yet released by a consumer. When a consumer (re)joins mid-stream (a
    // replacement stereo instance), these are sent again: the instance that held them may have died with them.
    let mut unacked: std::collections::VecDeque<usize> = std::collections::VecDeque::with_capacity(8);
    let on_demand = args.pacing.waits_for_consumer();
    // Set when iceoryx2 reports a consumer's notifier dead (its process died and was cleaned up): the next
    // consumer to join gets the frames the dead one held. A consumer joining while all others live gets none.
    let mut consumer_died = false;
    let t_start_ns = monotonic_ns();
    let mut published: u64 = 0;
    let mut end = End::Completed;
    let mut index = 0usize;

    'frames: while index < frame_count {
        let entry = &sequence.frames[index];
        // Wait until the frame is due: a consumer's credit (on demand) or its time (recorded / fixed rate).
        let due_ns = schedule.due_offset_ns(index, entry.t_source_s).map(|offset| t_start_ns + offset);
        let mut waited_ms: u64 = 0;
        loop {
            let now = monotonic_ns();
            let timeout = match due_ns {
                _ if on_demand && credits == 0 => Duration::from_secs(1),
                None => Duration::ZERO,
                Some(due) => Duration::from_nanos(due.saturating_sub(now)),
            };
            let (mut released, mut joined, mut died) = (0u64, 0u64, 0u64);
            let result = waitset
                .wait_and_process_once_with_timeout(
                    |id| {
                        if id.has_event_from(&consumed_guard) {
                            let _ = consumed.try_wait(|activation| match activation.id.as_value() {
                                event_id::CONSUMED => released += activation.count,
                                event_id::JOINED => joined += activation.count,
                                event_id::NOTIFIER_DEAD => died += activation.count,
                                _ => {}
                            });
                        }
                        CallbackProgression::Continue
                    },
                    timeout,
                )
                .map_err(|e| anyhow::anyhow!("wait for the next frame: {e:?}"))?;
            credits += released + joined;
            telemetry.keepalive();
            for _ in 0..released {
                unacked.pop_front();
            }
            if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
                end = End::StopRequested;
                break 'frames;
            }
            consumer_died |= died > 0;
            if on_demand && joined > 0 && consumer_died {
                consumer_died = false;
                if let Some(&first) = unacked.front() {
                    tracing::info!("a consumer replaced one that died: sending frames {first}..{index} again");
                    unacked.clear();
                    credits = joined;
                    index = first;
                    continue 'frames;
                }
            }
            // Due when a consumer has asked for it (on demand) and its time has come (a rate).
            if on_demand && credits == 0 {
                waited_ms += timeout.as_millis() as u64;
                if waited_ms > 0 && waited_ms.is_multiple_of(5000) {
                    tracing::warn!("no consumer has asked for frame {index} for {} s", waited_ms / 1000);
                    ipc.cleanup_dead_nodes();
                }
                continue;
            }
            if due_ns.is_none_or(|due| monotonic_ns() >= due) {
                if on_demand {
                    credits -= 1;
                }
                break;
            }
        }

        let t_capture_ns = monotonic_ns();
        let mut sample = match publisher.loan_slice_uninit(frame_bytes) {
            Ok(s) => s,
            Err(e) => {
                end = End::Failed(anyhow::anyhow!("loan a shared-memory frame: {e:?}"));
                break;
            }
        };
        if let Err(e) = decoder.decode_pair_into(&entry.left, &entry.right, &layout, sample.payload_mut()) {
            end = End::Failed(e.into());
            break;
        }
        // SAFETY: decode_pair_into wrote every byte of the packed layout, which is the whole loaned slice.
        let mut sample = unsafe { sample.assume_init() };
        let header = sample.user_header_mut();
        *header = FrameHeader {
            frame_seq: index as u64,
            t_capture_ns,
            t_source_ns: entry.t_source_s.map_or(0, |t| (t * 1e9) as u64),
            source_index: entry.source_index,
            ..Default::default()
        };
        layout.write_into(header);
        let t_publish_ns = monotonic_ns();
        header.t_publish_ns = t_publish_ns;
        if let Err(e) = sample.send() {
            end = End::Failed(anyhow::anyhow!("send frame {index}: {e:?}"));
            break;
        }
        if let Err(e) = bdis_ipc::notify(&notifier, event_id::NEW_SAMPLE) {
            tracing::warn!("frame {index}: {e}");
        }
        published += 1;
        telemetry.message(
            MessageTiming { frame_seq: index as u64, t_capture_ns, t_done_ns: t_publish_ns, ..Default::default() },
            0,
        );
        if on_demand {
            unacked.push_back(index);
        }
        index += 1;
    }

    // End of stream in every case, so consumers stop cleanly and keep what they have.
    let eos_sent = send_end_of_stream(&publisher, published);
    if let Err(e) = bdis_ipc::notify(&notifier, event_id::END_OF_STREAM) {
        tracing::warn!("end of stream: {e}");
    }
    match end {
        End::Completed => {
            telemetry.finished();
            tracing::info!("published {published} frames; end of stream");
            eos_sent
        }
        End::StopRequested => {
            telemetry.finished();
            tracing::info!("stop requested: published {published} frames; end of stream");
            eos_sent
        }
        End::Failed(e) => {
            telemetry.failed();
            bail!(e.context(format!("stopped after {published} frames")))
        }
    }
}

fn send_end_of_stream(
    publisher: &iceoryx2::port::publisher::Publisher<ipc::Service, [u8], FrameHeader>,
    frames_published: u64,
) -> Result<()> {
    let sample = publisher.loan_slice_uninit(0).map_err(|e| anyhow::anyhow!("loan the end-of-stream sample: {e:?}"))?;
    // SAFETY: a zero-length slice has no bytes to initialise.
    let mut sample = unsafe { sample.assume_init() };
    *sample.user_header_mut() = FrameHeader {
        frame_seq: frames_published,
        flags: FrameHeader::END_OF_STREAM,
        t_capture_ns: monotonic_ns(),
        t_publish_ns: monotonic_ns(),
        ..Default::default()
    };
    sample.send().map_err(|e| anyhow::anyhow!("send the end-of-stream sample: {e:?}"))?;
    Ok(())
}
