//! The consuming host's side: listens for the sender, begins a conversation with a HELLO that says what it has
//! already published (at its start, and whenever the sender asks), and publishes each new sample into this host's
//! shared memory with the topic's own QoS — checked first, as every consumer checks what it receives — then
//! acknowledges it. A sample it already published (sent again in a later conversation) is acknowledged and not
//! published twice. It ends after it has published the end of every carried stream that has one (keyframes,
//! depth, poses) and the sender, which waits for the last acknowledgement, has gone.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use bdis_bridge::clock::ClockOffset;
use bdis_bridge::ledger::Inbox;
use bdis_bridge::pace::Pace;
use bdis_bridge::wire::{self, Frame, SampleId};
use bdis_bridge::{BridgeError, Carried, records};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::track::tracking_state;
use bdis_ipc::validate::{self, Reason, Rejection};
use bdis_ipc::{DepthHeader, Ipc, KeyframeHeader, KeyframePose, PoseRecord, TelemetryPublisher, Topic, event_id};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

use crate::link::{Arrival, Link, Side};
use crate::node::Common;
use crate::snapshot::Relay;

/// After the ends of the streams: how long the sender has to take the last acknowledgement and go.
const SENDER_LEAVES: Duration = Duration::from_secs(10);

type DepthPublisher = Publisher<ipc::Service, [u8], DepthHeader>;

struct DepthOut {
    service: bdis_ipc::DepthService,
    /// Made for the first keyframe, with the largest payload it can take.
    publisher: Option<(DepthPublisher, usize)>,
    events: Notifier<ipc::Service>,
}

/// A publisher of fixed-size records and the notifier that wakes its consumers.
type RecordOut<T> = (Publisher<ipc::Service, T, ()>, Notifier<ipc::Service>);

type KeyframePublisher = Publisher<ipc::Service, [u8], KeyframeHeader>;

struct KeyframesOut {
    service: bdis_ipc::KeyframesService,
    /// Made for the first keyframe, with the largest payload it can take.
    publisher: Option<(KeyframePublisher, usize)>,
    events: Notifier<ipc::Service>,
}

struct Outputs {
    keyframes: Option<KeyframesOut>,
    depth: Option<DepthOut>,
    corrections: Option<RecordOut<KeyframePose>>,
    poses: Option<RecordOut<PoseRecord>>,
}

/// The sender's clock in this host's, and the (depth) keyframes' delays on the link beyond its shortest.
#[derive(Default)]
struct LinkTime {
    clock: ClockOffset,
    delays_us: Vec<u64>,
    /// When the sample being published arrived here (it may have waited in the backlog since).
    arrived_ns: u64,
}

/// When the producer's side sent the sample in `message`.
fn sent_at(message: &[u8]) -> Option<u64> {
    match wire::message(message) {
        Ok((_, Frame::Sample { what, .. })) => Some(what.t_sent_ns),
        _ => None,
    }
}

/// The receiver's side of a conversation.
struct Conversation {
    epoch: u64,
    /// Samples of this conversation handled so far (published, or recognised as already published).
    handled: u64,
}

impl Conversation {
    /// Begins a new conversation: a HELLO with what is already published, under an epoch no earlier one had.
    fn begin(link: &Link, previous: Option<u64>, inbox: &Inbox, topics: &[Carried]) -> Result<Conversation> {
        // The clock makes epochs differ between runs and restarts; the previous one + 1 within a run.
        let epoch = previous.map_or_else(
            || bdis_ipc::clock::monotonic_ns() ^ (u64::from(std::process::id()) << 40),
            |e| e.wrapping_add(1),
        );
        let mut hello = Vec::with_capacity(64);
        wire::envelope(&mut hello, epoch, false);
        wire::hello(&mut hello, &inbox.hello(topics));
        link.send(hello)?;
        Ok(Conversation { epoch, handled: 0 })
    }

    fn acknowledge(&self, link: &Link) -> Result<()> {
        let mut ack = Vec::with_capacity(24);
        wire::envelope(&mut ack, self.epoch, false);
        wire::ack(&mut ack, self.handled);
        link.send(ack)
    }
}

/// What handling one sample came to.
enum Handled {
    Published,
    Again,
    EndOfStream,
    Refused(Rejection),
}

fn protocol(e: BridgeError) -> Rejection {
    Rejection::new(Reason::Layout, 0, format!("bridge: {e}"))
}

fn publish_depth(
    ipc: &Ipc,
    out: &mut DepthOut,
    what: SampleId,
    link: &mut LinkTime,
    header: &[u8],
    payload: &[u8],
    telemetry: &mut TelemetryPublisher,
) -> Result<Handled> {
    let t_receive_ns = link.arrived_ns;
    link.clock.observe(what.t_sent_ns, t_receive_ns);
    // The link's delay beyond its shortest (the part of it the clocks' offset does not hide).
    link.delays_us.push((link.clock.here(what.t_sent_ns).abs_diff(t_receive_ns)) / 1000);
    let mut h = match records::depth_header(header) {
        Ok(h) => h,
        Err(e) => return Ok(Handled::Refused(protocol(e))),
    };
    // The capture time in this host's clock: this host's latency report measures capture → map.
    h.t_capture_ns = link.clock.here(h.t_capture_ns);
    if h.is_end_of_stream() {
        let publisher = match &out.publisher {
            Some((p, _)) => p,
            None => &out.publisher.insert((ipc.depth_publisher(&out.service, 1)?, 1)).0,
        };
        h.t_publish_ns = bdis_ipc::clock::monotonic_ns();
        bdis_node::send_end_of_stream(publisher, h)?;
        bdis_ipc::notify(&out.events, event_id::END_OF_STREAM)?;
        return Ok(Handled::EndOfStream);
    }
    // The publisher is made for the first keyframe's size (the stream's images do not change size).
    if out.publisher.as_ref().is_none_or(|(_, max)| payload.len() > *max) {
        out.publisher = None;
        out.publisher = Some((ipc.depth_publisher(&out.service, payload.len())?, payload.len()));
    }
    let Some((publisher, _)) = &out.publisher else { return Ok(Handled::Again) };
    let mut loan = publisher.loan_slice_uninit(payload.len()).context("loan a depth keyframe")?;
    bdis_node::copy_into(loan.payload_mut(), payload);
    // SAFETY: copy_into wrote every byte of the loan (it is exactly the payload's length).
    let mut sample = unsafe { loan.assume_init() };
    // Checked where the consumers will read it: in shared memory, whose float arrays are aligned (the bytes as
    // they came off the socket are not).
    if let Err(rejection) = validate::depth(&h, sample.payload()) {
        return Ok(Handled::Refused(rejection));
    }
    h.t_publish_ns = bdis_ipc::clock::monotonic_ns();
    *sample.user_header_mut() = h;
    sample.send().with_context(|| format!("publish depth keyframe {}", h.meta.kf_id))?;
    bdis_ipc::notify(&out.events, event_id::NEW_SAMPLE)?;
    let timing = MessageTiming {
        frame_seq: h.meta.kf_id,
        t_capture_ns: h.t_capture_ns,
        // As a source: what crossed the link has no upstream publisher on this host (the link's own delay is
        // logged at the end).
        t_upstream_publish_ns: 0,
        t_receive_ns,
        t_done_ns: bdis_ipc::clock::monotonic_ns(),
    };
    telemetry.message(timing, 0);
    Ok(Handled::Published)
}

fn publish_keyframe(
    ipc: &Ipc,
    out: &mut KeyframesOut,
    what: SampleId,
    link: &mut LinkTime,
    header: &[u8],
    payload: &[u8],
    telemetry: &mut TelemetryPublisher,
) -> Result<Handled> {
    let t_receive_ns = link.arrived_ns;
    link.clock.observe(what.t_sent_ns, t_receive_ns);
    link.delays_us.push((link.clock.here(what.t_sent_ns).abs_diff(t_receive_ns)) / 1000);
    let mut h = match records::keyframe_header(header) {
        Ok(h) => h,
        Err(e) => return Ok(Handled::Refused(protocol(e))),
    };
    h.frame.t_capture_ns = link.clock.here(h.frame.t_capture_ns);
    if h.frame.flags & bdis_ipc::FrameHeader::END_OF_STREAM != 0 {
        let publisher = match &out.publisher {
            Some((p, _)) => p,
            None => &out.publisher.insert((ipc.keyframe_publisher(&out.service, 1)?, 1)).0,
        };
        h.frame.t_publish_ns = bdis_ipc::clock::monotonic_ns();
        bdis_node::send_end_of_stream(publisher, h)?;
        bdis_ipc::notify(&out.events, event_id::END_OF_STREAM)?;
        return Ok(Handled::EndOfStream);
    }
    if out.publisher.as_ref().is_none_or(|(_, max)| payload.len() > *max) {
        out.publisher = None;
        out.publisher = Some((ipc.keyframe_publisher(&out.service, payload.len())?, payload.len()));
    }
    let Some((publisher, _)) = &out.publisher else { return Ok(Handled::Again) };
    let mut loan = publisher.loan_slice_uninit(payload.len()).context("loan a keyframe")?;
    bdis_node::copy_into(loan.payload_mut(), payload);
    // SAFETY: copy_into wrote every byte of the loan (it is exactly the payload's length).
    let mut sample = unsafe { loan.assume_init() };
    if let Err(rejection) = validate::keyframe(&h, sample.payload()) {
        return Ok(Handled::Refused(rejection));
    }
    h.frame.t_publish_ns = bdis_ipc::clock::monotonic_ns();
    *sample.user_header_mut() = h;
    sample.send().with_context(|| format!("publish keyframe {}", h.meta.kf_id))?;
    bdis_ipc::notify(&out.events, event_id::NEW_SAMPLE)?;
    let timing = MessageTiming {
        frame_seq: h.meta.kf_id,
        t_capture_ns: h.frame.t_capture_ns,
        t_upstream_publish_ns: 0,
        t_receive_ns,
        t_done_ns: bdis_ipc::clock::monotonic_ns(),
    };
    telemetry.message(timing, 0);
    Ok(Handled::Published)
}

fn publish_pose(out: &RecordOut<PoseRecord>, header: &[u8], link: &mut LinkTime, what: SampleId) -> Result<Handled> {
    let mut record = match records::pose(header) {
        Ok(r) => r,
        Err(e) => return Ok(Handled::Refused(protocol(e))),
    };
    link.clock.observe(what.t_sent_ns, link.arrived_ns);
    if record.state == tracking_state::END_OF_STREAM {
        out.0.send_copy(record).context("publish the end of the poses")?;
        bdis_ipc::notify(&out.1, event_id::END_OF_STREAM)?;
        return Ok(Handled::EndOfStream);
    }
    if let Err(rejection) = validate::pose_record(&record) {
        return Ok(Handled::Refused(rejection));
    }
    record.t_capture_ns = link.clock.here(record.t_capture_ns);
    record.t_publish_ns = bdis_ipc::clock::monotonic_ns();
    out.0.send_copy(record).context("publish a pose")?;
    bdis_ipc::notify(&out.1, event_id::NEW_SAMPLE)?;
    Ok(Handled::Published)
}

fn publish_correction(out: &RecordOut<KeyframePose>, header: &[u8]) -> Result<Handled> {
    let record = match records::correction(header) {
        Ok(r) => r,
        Err(e) => return Ok(Handled::Refused(protocol(e))),
    };
    if let Err(rejection) = validate::correction(&record) {
        return Ok(Handled::Refused(rejection));
    }
    out.0.send_copy(record).context("publish a correction")?;
    bdis_ipc::notify(&out.1, event_id::NEW_SAMPLE)?;
    Ok(Handled::Published)
}

pub fn run(common: Common, listen: &str) -> Result<()> {
    let Common { topics, name, ipc_prefix, map_snapshots } = common;
    // The address first: refused before shared memory is touched.
    let mut link = Link::open(Side::Receiver, "--listen", listen)?;
    let ipc = Ipc::open(&name, &ipc_prefix)?;
    let mut outputs = Outputs {
        keyframes: if topics.contains(&Carried::Keyframes) {
            Some(KeyframesOut {
                service: ipc.keyframes()?,
                publisher: None,
                events: ipc.notifier(&ipc.events(Topic::Keyframes)?)?,
            })
        } else {
            None
        },
        depth: if topics.contains(&Carried::Depth) {
            Some(DepthOut { service: ipc.depth()?, publisher: None, events: ipc.notifier(&ipc.events(Topic::Depth)?)? })
        } else {
            None
        },
        corrections: if topics.contains(&Carried::Corrections) {
            let service = ipc.corrections()?;
            let publisher = service.publisher_builder().create().context("create the corrections publisher")?;
            Some((publisher, ipc.notifier(&ipc.events(Topic::Corrections)?)?))
        } else {
            None
        },
        poses: if topics.contains(&Carried::Poses) {
            let service = ipc.poses()?;
            let publisher = service.publisher_builder().create().context("create the poses publisher")?;
            Some((publisher, ipc.notifier(&ipc.events(Topic::Poses)?)?))
        } else {
            None
        },
    };
    let output_topic = match (&outputs.keyframes, &outputs.depth, &outputs.poses) {
        (Some(_), _, _) => Topic::Keyframes,
        (None, Some(_), _) => Topic::Depth,
        (None, None, Some(_)) => Topic::Poses,
        (None, None, None) => Topic::Corrections,
    };
    let mut telemetry = TelemetryPublisher::new(&ipc, &name, None, Some(output_topic))?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(bdis_node::NodeError::WaitSet)?;
    let (mut relay, snapshot_responses) = match map_snapshots {
        true => {
            link.serve_snapshots()?;
            Relay::open(&ipc).map(|(r, l)| (Some(r), Some(l)))?
        }
        false => (None, None),
    };
    let _relay_guard = match &snapshot_responses {
        Some(listener) => Some(waitset.attach_notification(listener).map_err(bdis_node::NodeError::Attach)?),
        None => None,
    };
    let link_fd = link.wake_fd().context("the link's wake-up descriptor")?;
    let _link_guard = waitset.attach_notification(&link_fd).map_err(bdis_node::NodeError::Attach)?;
    let _keepalive = waitset.attach_interval(bdis_node::WAKE_DEADLINE).map_err(bdis_node::NodeError::Attach)?;
    tracing::info!("receiving {} on {}", topics.iter().map(|t| t.name()).collect::<Vec<_>>().join(", "), listen);
    telemetry.ready();

    let mut inbox = Inbox::default();
    // A sender already running (this receiver restarted) is told at once; one that starts later asks.
    let mut conversation = Conversation::begin(&link, None, &inbox, &topics)?;
    let (mut published, mut again, mut refused, mut conversations) = (0u64, 0u64, 0u64, 1u64);
    // When every carried stream with an end has ended: from then the sender has a while to take the last
    // acknowledgement and go.
    let mut ended_at: Option<Instant> = None;
    // The ends of the depth, pose and keyframe streams, published.
    let mut ends = (false, false, false);
    let mut sender_left = false;
    let mut link_time = LinkTime::default();
    // Samples received and not yet published, in order; each marked whether it found the backlog empty.
    let mut backlog: VecDeque<(Vec<u8>, bool, u64)> = VecDeque::new();
    let mut pace = Pace::default();
    // From a sample sent again until the backlog is empty: what is published is paced.
    let mut catching_up = false;
    loop {
        let timer = match backlog.front().and_then(|(m, _, _)| sent_at(m)).and_then(|t| pace.wait(t, Instant::now())) {
            Some(wait) => Some(waitset.attach_interval(wait).map_err(bdis_node::NodeError::Attach)?),
            None => None,
        };
        let run =
            waitset.wait_and_process_once(|_| CallbackProgression::Continue).map_err(bdis_node::NodeError::Wait)?;
        drop(timer);
        if matches!(run, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            break;
        }
        telemetry.keepalive();
        let before = conversation.handled;
        for arrival in link.arrivals() {
            let bytes = match arrival {
                Arrival::Message(bytes) => bytes,
                Arrival::PeerCame => {
                    sender_left = false;
                    continue;
                }
                Arrival::PeerLeft => {
                    sender_left = true;
                    continue;
                }
                Arrival::SnapshotAsked(query) => {
                    match relay.as_mut() {
                        Some(relay) => relay.asked(query),
                        None => tracing::warn!("the sender asked for the map; not carried (--map-snapshots)"),
                    }
                    continue;
                }
                Arrival::SnapshotAnswer { .. } => continue,
            };
            match wire::message(&bytes) {
                Ok((_, Frame::WantHello)) => {
                    conversation = Conversation::begin(&link, Some(conversation.epoch), &inbox, &topics)?;
                    conversations += 1;
                }
                Ok((envelope, Frame::Sample { .. })) => {
                    catching_up |= envelope.again;
                    let alone = backlog.is_empty();
                    backlog.push_back((bytes, alone, bdis_ipc::clock::monotonic_ns()));
                }
                Ok((_, other)) => tracing::warn!("the link carried a {other:?} to the receiver; ignored"),
                Err(e) => {
                    refused += 1;
                    telemetry.rejected(Topic::Depth, &protocol(e));
                }
            }
        }
        // Published in order; what the sender sends again after a restart or a broken link, and what queues behind
        // it, at twice the pace it was produced: the consumers here have the small buffers of the topics' QoS,
        // sized for that pace (a burst of 17 depth keyframes at once lost 3 of them to the mosaic's 4).
        while let Some((front, alone, _)) = backlog.front() {
            // What is here already goes at once: only what is published is paced.
            let fresh = match wire::message(front) {
                Ok((_, Frame::Sample { what, .. })) => inbox.fresh(what.topic, what.id),
                _ => false,
            };
            if fresh && catching_up && !*alone && sent_at(front).and_then(|t| pace.wait(t, Instant::now())).is_some() {
                break;
            }
            let Some((bytes, _, arrived_ns)) = backlog.pop_front() else { break };
            link_time.arrived_ns = arrived_ns;
            let Ok((wire::Envelope { epoch, .. }, Frame::Sample { what, header, payload })) = wire::message(&bytes)
            else {
                continue;
            };
            // Counted only in its own conversation: one sent before the current HELLO is not what the sender
            // counts now (it comes again in this one if it is still owed).
            if epoch == conversation.epoch {
                conversation.handled += 1;
            }
            if !inbox.fresh(what.topic, what.id) {
                again += 1;
                continue;
            }
            pace.published(what.t_sent_ns, Instant::now());
            let handled = match (what.topic, &mut outputs) {
                (Carried::Depth, Outputs { depth: Some(out), .. }) => {
                    publish_depth(&ipc, out, what, &mut link_time, header, payload, &mut telemetry)?
                }
                (Carried::Corrections, Outputs { corrections: Some(out), .. }) => publish_correction(out, header)?,
                (Carried::Poses, Outputs { poses: Some(out), .. }) => publish_pose(out, header, &mut link_time, what)?,
                (Carried::Keyframes, Outputs { keyframes: Some(out), .. }) => {
                    publish_keyframe(&ipc, out, what, &mut link_time, header, payload, &mut telemetry)?
                }
                (topic, _) => Handled::Refused(Rejection::new(
                    Reason::Layout,
                    what.id,
                    format!("bridge: {} is not carried here", topic.name()),
                )),
            };
            match handled {
                Handled::Published => published += 1,
                Handled::Again => again += 1,
                Handled::EndOfStream => {
                    match what.topic {
                        Carried::Depth => ends.0 = true,
                        Carried::Poses => ends.1 = true,
                        Carried::Keyframes => ends.2 = true,
                        Carried::Corrections => {}
                    }
                    let ended = (ends.0 || outputs.depth.is_none())
                        && (ends.1 || outputs.poses.is_none())
                        && (ends.2 || outputs.keyframes.is_none());
                    if ended && ended_at.is_none() {
                        ended_at = Some(Instant::now());
                    }
                }
                Handled::Refused(rejection) => {
                    refused += 1;
                    let topic = match what.topic {
                        Carried::Keyframes => Topic::Keyframes,
                        Carried::Depth => Topic::Depth,
                        Carried::Corrections => Topic::Corrections,
                        Carried::Poses => Topic::Poses,
                    };
                    telemetry.rejected(topic, &rejection);
                }
            }
            inbox.published(what.topic, what.id);
        }
        catching_up &= !backlog.is_empty();
        if conversation.handled != before {
            conversation.acknowledge(&link)?;
        }
        if let (Some(relay), Some(responses)) = (relay.as_mut(), &snapshot_responses) {
            let _ = bdis_ipc::drain_events(responses);
            relay.progress()?;
        }
        if ended_at.is_some_and(|t| sender_left || t.elapsed() > SENDER_LEAVES) {
            break;
        }
    }
    if let Some(relay) = &relay {
        tracing::info!("map snapshots relayed to the far host: {}", relay.relayed);
    }
    drop(_relay_guard);
    drop(relay);
    link.close();
    link_time.delays_us.sort_unstable();
    let at = |q: f64| link_time.delays_us.get(((link_time.delays_us.len() as f64 - 1.0) * q).round() as usize).copied();
    tracing::info!(
        "bridge receiver done: {published} published, {again} already had, {refused} refused, {conversations} \
         conversations; the sender's clock {:?} µs from this one's (with the link's shortest delay); keyframes' \
         delay beyond the shortest p50 {:?} µs, p99 {:?} µs",
        link_time.clock.offset_ns().map(|o| o / 1000),
        at(0.5),
        at(0.99)
    );
    telemetry.finished();
    Ok(())
}
