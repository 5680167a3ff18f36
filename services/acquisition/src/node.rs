//! The acquisition node: for each frame, wait until it is due (a consumer's credit on demand, its time when
//! paced by a rate), decode it straight into a loaned sample, send, notify, record timings. The end of the
//! stream is a last sample flagged `END_OF_STREAM`, so consumers finish cleanly, also after an error or a stop
//! request.

use std::time::Duration;

use anyhow::{Context, Result};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::{FrameHeader, FrameLayout, event_id, monotonic_ns};
use bdis_source::{CheckedInput, FrameReader, Pacing, Schedule};
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

use crate::credits::{ConsumerEvents, Credits};

/// The checked input of one acquisition instance.
#[derive(Debug)]
pub struct Config {
    pub input: CheckedInput,
    /// Rectification applied to every frame as it is read (a raw calibration).
    pub rectifier: Option<bdis_source::Rectifier>,
    /// One field of each interlaced frame (or the frame bobbed), instead of the woven frame.
    pub fields: Option<bdis_source::FieldMode>,
    /// The user's masks, one per frame, written into each frame's mask plane (`layout` has one then).
    pub masks: Option<bdis_source::MaskFolder>,
    pub layout: FrameLayout,
    /// Frames to publish (the sequence, or fewer with `--max-frames`).
    pub frame_count: usize,
    pub pacing: Pacing,
    /// The frame rate a fixed-rate schedule falls back to without timestamps.
    pub schedule_fps: f64,
    pub name: String,
    pub ipc_prefix: String,
}

/// How the stream ended.
#[derive(Debug)]
enum End {
    Completed,
    StopRequested,
    Failed(anyhow::Error),
}

pub fn run(config: Config) -> Result<()> {
    let Config { input, rectifier, fields, mut masks, layout, frame_count, pacing, schedule_fps, name, ipc_prefix } =
        config;
    let sequence = &input.sequence;
    let frame_bytes = layout.payload_len();
    let mut ports = crate::ports::Ports::open(&name, &ipc_prefix, frame_bytes)?;
    // Acquisition waits on its consumers' credits with a timeout of its own (a frame's due time), so it keeps
    // its own WaitSet rather than `bdis_node::serve`.
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(bdis_node::NodeError::WaitSet)?;
    let consumed_guard = waitset.attach_notification(&ports.consumed).map_err(bdis_node::NodeError::Attach)?;
    ports.telemetry.ready();
    tracing::info!(
        "streaming {frame_count} frames of {}×{} from {} ({pacing:?} pacing, prefix {ipc_prefix})",
        sequence.width,
        sequence.height,
        sequence.root.display(),
    );

    let schedule = Schedule::new(pacing, sequence.frames[0].t_source_s, schedule_fps);
    let mut reader = FrameReader::new(sequence);
    if let Some(rectifier) = rectifier {
        reader = reader.with_rectifier(rectifier);
    }
    if let Some(mode) = fields {
        reader = reader
            .with_fields(mode, sequence.width, sequence.height)
            .context("interlaced frames: their size cannot be split into fields")?;
    }
    if let Err(e) = reader.prepare(&sequence.frames[0]) {
        // Said again, and the stream ended cleanly, when the first frame is read.
        tracing::warn!("{e}");
    }
    // Frames of a video its decoder could not decode: passed over, each said in the log and counted.
    let mut lost_in_decoding: u64 = 0;
    let on_demand = pacing.waits_for_consumer();
    let mut credits = Credits::new(on_demand, ports.frames.dynamic_config().number_of_subscribers() > 0);
    let t_start_ns = monotonic_ns();
    let mut published: u64 = 0;
    let mut end = End::Completed;
    let mut index = 0usize;
    // The next frame answers consumers that announced themselves (FrameHeader::ANSWERS_JOIN). The first frame
    // answers every consumer that subscribed before acquisition existed (its JOINED reached no listener).
    let mut answer_join = true;

    'frames: while index < frame_count {
        let entry = &sequence.frames[index];
        // Wait until the frame is due: a consumer's credit (on demand) or its time (recorded / fixed rate).
        let due_ns = schedule.due_offset_ns(index, entry.t_source_s).map(|offset| t_start_ns + offset);
        let mut waited_ms: u64 = 0;
        loop {
            let now = monotonic_ns();
            let timeout = match due_ns {
                _ if credits.waiting_for_consumer() => Duration::from_secs(1),
                None => Duration::ZERO,
                Some(due) => Duration::from_nanos(due.saturating_sub(now)),
            };
            let mut events = ConsumerEvents::default();
            let result = waitset
                .wait_and_process_once_with_timeout(
                    |id| {
                        if id.has_event_from(&consumed_guard) {
                            let _ = ports.consumed.try_wait(|activation| match activation.id.as_value() {
                                event_id::CONSUMED => events.released += activation.count,
                                event_id::JOINED => events.joined += activation.count,
                                event_id::NOTIFIER_DEAD => events.died += activation.count,
                                _ => {}
                            });
                        }
                        CallbackProgression::Continue
                    },
                    timeout,
                )
                .map_err(bdis_node::NodeError::Wait)?;
            if events != ConsumerEvents::default() {
                tracing::debug!("frame {index}: consumer events {events:?}");
            }
            answer_join |= events.joined > 0;
            let replay_from = credits.on_events(events);
            ports.telemetry.keepalive();
            if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
                end = End::StopRequested;
                break 'frames;
            }
            if let Some(first) = replay_from {
                tracing::info!("a consumer replaced one that died: sending frames {first}..{index} again");
                index = first;
                continue 'frames;
            }
            // Due when a consumer has asked for it (on demand) and its time has come (a rate).
            if credits.waiting_for_consumer() {
                waited_ms += timeout.as_millis() as u64;
                if waited_ms > 0 && waited_ms.is_multiple_of(5000) {
                    tracing::warn!("no consumer has asked for frame {index} for {} s", waited_ms / 1000);
                    ports.ipc.cleanup_dead_nodes();
                }
                continue;
            }
            if due_ns.is_none_or(|due| monotonic_ns() >= due) {
                credits.spend();
                break;
            }
        }

        let t_capture_ns = monotonic_ns();
        let mut sample = match ports.publisher.loan_slice_uninit(frame_bytes) {
            Ok(s) => s,
            Err(e) => {
                end = End::Failed(anyhow::Error::new(e).context("loan a shared-memory frame"));
                break;
            }
        };
        // The reader writes the three images (their layout is the packed one either way); the mask plane after
        // them is the user's mask.
        let images = FrameLayout { mask_offset: None, ..layout };
        let (image_bytes, mask_bytes) = sample.payload_mut().split_at_mut(images.payload_len());
        match reader.read_into(entry, &images, image_bytes) {
            Ok(()) => {}
            Err(e) if e.is_frame_lost() => {
                tracing::warn!("{e}");
                lost_in_decoding += 1;
                credits.refund();
                index += 1;
                continue;
            }
            Err(e) => {
                end = End::Failed(e.into());
                break;
            }
        }
        if let Some(masks) = &mut masks
            && let Err(e) = masks.read_into(index, mask_bytes)
        {
            end = End::Failed(anyhow::Error::new(e).context(format!("the mask of frame {index}")));
            break;
        }
        // SAFETY: read_into wrote every byte of the images' packed layout and the masks every byte of the mask
        // plane (present exactly when there are masks): the whole loaned slice.
        let sample = unsafe { sample.assume_init() };
        let header = FrameHeader {
            frame_seq: index as u64,
            t_capture_ns,
            t_source_ns: entry.t_source_s.map_or(0, |t| (t * 1e9) as u64),
            source_index: entry.source_index,
            flags: if answer_join { FrameHeader::ANSWERS_JOIN } else { 0 },
            ..Default::default()
        };
        let t_publish_ns = match ports.publish(sample, header, &layout) {
            Ok(t) => t,
            Err(e) => {
                end = End::Failed(e);
                break;
            }
        };
        published += 1;
        answer_join = false;
        ports.telemetry.message(
            MessageTiming { frame_seq: index as u64, t_capture_ns, t_done_ns: t_publish_ns, ..Default::default() },
            0,
        );
        credits.sent(index);
        index += 1;
    }

    // Its sequence number is the number of frames of the stream (replays sent some twice; they count once).
    let eos_sent = ports.end_stream(index as u64);
    match end {
        End::Completed | End::StopRequested => {
            ports.telemetry.finished();
            let how = if matches!(end, End::StopRequested) { "stop requested: " } else { "" };
            let lost = if lost_in_decoding > 0 {
                format!(" ({lost_in_decoding} the video's decoder could not decode)")
            } else {
                String::new()
            };
            tracing::info!("{how}published {published} frames{lost}; end of stream");
            Ok(eos_sent?)
        }
        End::Failed(e) => {
            ports.telemetry.failed();
            Err(e.context(format!("stopped after {published} frames")))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bdis_ipc::{Ipc, Topic};

    /// `n` PNG pairs of `w`×`h` whose pixels encode their number, and an on-demand acquisition over them.
    #[allow(clippy::unwrap_used)]
    fn fixture(tag: &str, w: u32, h: u32, n: usize) -> (String, std::path::PathBuf, Config) {
        let prefix = format!("ba{tag}{}_", std::process::id());
        let dir = std::env::temp_dir().join(format!("bdis-acquisition-{tag}-{}", std::process::id()));
        for side in ["left", "right"] {
            std::fs::create_dir_all(dir.join(side)).unwrap();
            for i in 1..=n as u32 {
                let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 5 + i) as u8, (y * 7) as u8, 90]));
                img.save(dir.join(format!("{side}/{i}.png"))).unwrap();
            }
        }
        let input = bdis_source::check_input(&dir, None).unwrap();
        let config = Config {
            rectifier: None,
            fields: None,
            masks: None,
            layout: FrameLayout::packed(w, h).unwrap(),
            frame_count: input.sequence.len(),
            input,
            pacing: Pacing::OnDemand,
            schedule_fps: 30.0,
            name: "acquisition".into(),
            ipc_prefix: prefix.clone(),
        };
        (prefix, dir, config)
    }

    /// The node as a whole, in process, over real shared memory, paced by its consumer: every frame once, in
    /// order, only when asked for, decoded in place (the left grey plane is the PNG's BT.601 grey), then the end
    /// of the stream numbered after the last frame.
    #[test]
    #[allow(clippy::unwrap_used, clippy::expect_used)]
    fn every_frame_once_in_order_when_the_consumer_asks() {
        let (w, h, n) = (48u32, 32u32, 5usize);
        let (prefix, dir, config) = fixture("order", w, h, n);
        // The consumer exists before acquisition: it counts as one credit.
        let ipc = Ipc::open("node-test", &prefix).unwrap();
        let frames = ipc.frames().unwrap();
        let subscriber = ipc.frame_subscriber(&frames).unwrap();
        let frame_events = ipc.listener(&ipc.events(Topic::Frames).unwrap()).unwrap();
        let credits = ipc.notifier(&ipc.frames_consumed().unwrap()).unwrap();

        let node = std::thread::spawn(move || run(config));
        let mut seen = Vec::new();
        let deadline = || std::time::Instant::now() + std::time::Duration::from_secs(20);
        loop {
            let header = bdis_ipc::wait_for(&frame_events, deadline(), || {
                let Some(sample) = subscriber.receive().map_err(bdis_ipc::iox("frames"))? else { return Ok(None) };
                let header = *sample.user_header();
                if !header.is_end_of_stream() {
                    let view = bdis_ipc::FrameView::new(sample.user_header(), sample.payload()).unwrap();
                    let expected = |x: u32, y: u32| {
                        let (r, g, b) = (x * 5 + header.frame_seq as u32 + 1, y * 7, 90u32);
                        bdis_core::pixel::gray_of(r as u8, g as u8, b as u8)
                    };
                    assert_eq!(view.left_gray[(3 * w + 10) as usize], expected(10, 3), "frame {}", header.frame_seq);
                    // Nothing more is sent until this one is released (the end of the stream needs no credit).
                    if header.frame_seq + 1 < n as u64 {
                        assert!(subscriber.receive().unwrap().is_none(), "frame {} sent unasked", header.frame_seq + 1);
                    }
                }
                Ok(Some(header))
            });
            let Some(header) = header.unwrap() else {
                let ended = if node.is_finished() { format!("{:?}", node.join()) } else { "still running".into() };
                panic!("no frame within the deadline; acquisition: {ended}");
            };
            if header.is_end_of_stream() {
                assert_eq!(header.frame_seq, n as u64, "the end of the stream is numbered after the last frame");
                break;
            }
            seen.push(header.frame_seq);
            bdis_ipc::notify(&credits, event_id::CONSUMED).unwrap();
        }
        node.join().unwrap().unwrap();
        assert_eq!(seen, (0..n as u64).collect::<Vec<_>>());

        drop((subscriber, frames, credits, ipc));
        let _ = std::fs::remove_dir_all(&dir);
        bdis_ipc::remove_run_files(&prefix);
    }

    /// A consumer replacing one that died, with the race a swap under load hits: the dead consumer's last
    /// acknowledgement arrives after the newcomer subscribed, so acquisition sends the newcomer a frame (2) before
    /// it has read the newcomer's JOINED, and only then sends again what the dead one held (1, 2). Taking frame 2
    /// first made 1 look old and lost it. Through the join gate the newcomer takes 1, 2, 3, … once each, in order.
    #[test]
    #[allow(clippy::unwrap_used, clippy::expect_used)]
    fn a_replacement_takes_every_frame_its_predecessor_held_even_behind_a_stray_one() {
        let (w, h, n) = (16u32, 8u32, 6usize);
        let (prefix, dir, config) = fixture("replace", w, h, n);
        let ipc = Ipc::open("node-test", &prefix).unwrap();
        let frames = ipc.frames().unwrap();
        let frame_events = ipc.events(Topic::Frames).unwrap();
        let consumed = ipc.frames_consumed().unwrap();
        let credits = ipc.notifier(&consumed).unwrap();
        let deadline = || std::time::Instant::now() + std::time::Duration::from_secs(20);
        let next = |subscriber: &iceoryx2::port::subscriber::Subscriber<ipc::Service, [u8], FrameHeader>,
                    listener: &iceoryx2::port::listener::Listener<ipc::Service>| {
            bdis_ipc::wait_for(listener, deadline(), || {
                Ok(subscriber.receive().map_err(bdis_ipc::iox("frames"))?.map(|s| *s.user_header()))
            })
            .unwrap()
            .expect("a frame within the deadline")
        };

        // The first consumer subscribed before acquisition (one credit), then announced itself (a second).
        let first = ipc.frame_subscriber(&frames).unwrap();
        let first_events = ipc.listener(&frame_events).unwrap();
        let node = std::thread::spawn(move || run(config));
        let f0 = next(&first, &first_events);
        assert_eq!(f0.frame_seq, 0);
        assert!(f0.answers_join(), "the first frame answers consumers that subscribed before acquisition");
        bdis_ipc::notify(&credits, event_id::JOINED).unwrap();
        assert_eq!(next(&first, &first_events).frame_seq, 1);
        // It dies holding frames 0 and 1, its acknowledgement of frame 0 still on the way.
        drop((first, first_events));
        bdis_ipc::notify(&credits, event_id::NOTIFIER_DEAD).unwrap();
        let newcomer = ipc.frame_subscriber(&frames).unwrap();
        let newcomer_events = ipc.listener(&frame_events).unwrap();
        bdis_ipc::notify(&credits, event_id::CONSUMED).unwrap();
        let mut gate = bdis_ipc::JoinGate::default();
        let stray = next(&newcomer, &newcomer_events);
        assert_eq!(stray.frame_seq, 2, "the race: frame 2 reaches the newcomer first");
        assert!(!gate.admit(&stray), "a frame sent before acquisition read the newcomer's JOINED is not its own");
        bdis_ipc::notify(&credits, event_id::JOINED).unwrap();

        let mut taken = Vec::new();
        loop {
            let header = next(&newcomer, &newcomer_events);
            if !gate.admit(&header) {
                continue;
            }
            if header.is_end_of_stream() {
                break;
            }
            taken.push(header.frame_seq);
            bdis_ipc::notify(&credits, event_id::CONSUMED).unwrap();
        }
        node.join().unwrap().unwrap();
        assert_eq!(taken, (1..n as u64).collect::<Vec<_>>(), "every frame from the first one the dead consumer held");

        drop((newcomer, newcomer_events, credits, consumed, frame_events, frames, ipc));
        let _ = std::fs::remove_dir_all(&dir);
        bdis_ipc::remove_run_files(&prefix);
    }
}
