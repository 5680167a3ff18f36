//! The producing host's side: the carried topics taken from shared memory into the outbox as they are published
//! (so shared memory's small buffers never overflow while the link is slow or down), sent to the receiver in
//! order, dropped when it says it has published them, sent again in the next conversation. A conversation begins
//! with the receiver's HELLO, which says what it already has; the sender asks for one (WANT_HELLO) whenever it
//! has none — at its start, and when the receiver came or went. Its first HELLO tells it what the receiver
//! already has: a sender that restarted reports that as the point it restored (`ready_restored`), and the
//! launcher has the stereo service redo the keyframes after it from the tracker's keyframe history, as it does
//! for a restarted mosaic.

use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use bdis_bridge::ledger::{CorrectionIds, Entry, Outbox};
use bdis_bridge::wire::{self, Frame, SampleId};
use bdis_bridge::{Carried, records};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::track::tracking_state;
use bdis_ipc::{DepthHeader, Ipc, KeyframeHeader, KeyframePose, PoseRecord, TelemetryPublisher, Topic};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

use crate::link::{Arrival, Link, Side};
use crate::node::Common;
use crate::snapshot::Serve;

/// While there is no conversation: how often to ask the receiver for one.
const ASK_PERIOD: Duration = Duration::from_millis(250);
/// The first conversation must begin within this (the launcher's readiness deadline is 20 s).
const FIRST_CONVERSATION: Duration = Duration::from_secs(15);

/// A subscriber and the listener its producer wakes.
type Input<T, H> = (Subscriber<ipc::Service, T, H>, Listener<ipc::Service>);

struct Inputs {
    keyframes: Option<Input<[u8], KeyframeHeader>>,
    depth: Option<Input<[u8], DepthHeader>>,
    corrections: Option<Input<KeyframePose, ()>>,
    poses: Option<Input<PoseRecord, ()>>,
}

impl Inputs {
    fn listeners(&self) -> impl Iterator<Item = &Listener<ipc::Service>> {
        let corrections = self.corrections.iter().map(|(_, l)| l);
        let keyframes = self.keyframes.iter().map(|(_, l)| l);
        let poses = self.poses.iter().map(|(_, l)| l);
        self.depth.iter().map(|(_, l)| l).chain(corrections).chain(keyframes).chain(poses)
    }
}

/// Where the sender stands with the receiver.
#[derive(Debug, Default)]
struct Conversation {
    /// The receiver's current conversation, once its HELLO came.
    epoch: Option<u64>,
    /// When to ask again while there is none.
    next_ask: Option<Instant>,
    /// HELLOs taken (conversations begun).
    hellos: u64,
    /// What the first HELLO said the receiver had.
    first: Option<wire::ResumePoints>,
    /// Samples still to send that were pending when this conversation began: sent marked [`wire::AGAIN`].
    again: usize,
}

impl Conversation {
    /// Takes what arrived on the link: a HELLO begins a conversation (what the receiver has goes out of the
    /// outbox), an ACK of the current one drops what it covers, the receiver coming or going ends the
    /// conversation.
    fn take(
        &mut self,
        link: &mut Link,
        topics: &[Carried],
        outbox: &mut Outbox,
        serve: &mut Option<Serve>,
    ) -> Result<()> {
        for arrival in link.arrivals() {
            match arrival {
                Arrival::SnapshotAnswer { request, answer } => {
                    if let Some(serve) = serve.as_mut() {
                        serve.answered(request, answer)?;
                    }
                }
                Arrival::SnapshotAsked(_) => tracing::warn!("the receiver asked the sender for a map; ignored"),
                Arrival::PeerCame | Arrival::PeerLeft => {
                    if self.epoch.take().is_some() {
                        tracing::info!("the receiver came or went; asking it where it stands");
                    }
                    self.next_ask = None;
                }
                Arrival::Message(bytes) => match wire::message(&bytes) {
                    Ok((wire::Envelope { epoch, .. }, Frame::Hello { last })) => {
                        for topic in topics {
                            if !last.iter().any(|(t, _)| t == topic) {
                                bail!("the receiver does not carry {}", topic.name());
                            }
                        }
                        outbox.connected(&last);
                        self.again = outbox.len();
                        if self.hellos == 0 {
                            self.first = Some(last);
                        }
                        self.epoch = Some(epoch);
                        self.hellos += 1;
                    }
                    Ok((wire::Envelope { epoch, .. }, Frame::Ack { published })) => {
                        if self.epoch == Some(epoch) {
                            outbox.acknowledged(published);
                        }
                    }
                    Ok((_, other)) => tracing::warn!("the link carried a {other:?} to the sender; ignored"),
                    Err(e) => tracing::warn!("the link carried a message the sender cannot read: {e}; ignored"),
                },
            }
        }
        Ok(())
    }

    /// Asks for a conversation when there is none and it is time; returns when to wake to ask again.
    fn ask_if_due(&mut self, link: &Link) -> Result<Option<Duration>> {
        if self.epoch.is_some() {
            return Ok(None);
        }
        let now = Instant::now();
        if self.next_ask.is_none_or(|t| now >= t) {
            let mut message = Vec::with_capacity(16);
            wire::envelope(&mut message, 0, false);
            wire::want_hello(&mut message);
            link.send(message)?;
            self.next_ask = Some(now + ASK_PERIOD);
        }
        Ok(Some(ASK_PERIOD))
    }

    /// Sends what the receiver has not been sent in this conversation.
    fn send(&mut self, link: &Link, outbox: &mut Outbox) -> Result<()> {
        let Some(epoch) = self.epoch else { return Ok(()) };
        let mut sent = 0;
        for entry in outbox.unsent() {
            let mut message = Vec::with_capacity(wire::ENVELOPE_BYTES + entry.frame.len());
            wire::envelope(&mut message, epoch, self.again > 0);
            self.again = self.again.saturating_sub(1);
            message.extend_from_slice(&entry.frame);
            link.send(message)?;
            sent += 1;
        }
        outbox.mark_sent(sent);
        Ok(())
    }
}

/// The streams that have an end (depth, poses) and whether it has been taken in.
#[derive(Debug, Default, Clone, Copy)]
struct Ends {
    keyframes: bool,
    depth: bool,
    poses: bool,
}

/// Takes everything published on the inputs into the outbox, noting the ends of streams in `ends`.
fn take_inputs(
    inputs: &Inputs,
    outbox: &mut Outbox,
    ids: &mut CorrectionIds,
    telemetry: &mut TelemetryPublisher,
    scratch: &mut Vec<u8>,
    ends: &mut Ends,
) -> Result<()> {
    // Corrections first: those a keyframe was made after were published before it.
    if let Some((subscriber, _)) = &inputs.corrections {
        while let Some(sample) = subscriber.receive().context("receive a correction")? {
            let record = *sample.payload();
            let id = ids.next(record.generation);
            scratch.clear();
            records::put_correction(scratch, &record);
            let mut frame = Vec::with_capacity(scratch.len() + 32);
            let what = SampleId { topic: Carried::Corrections, id, t_sent_ns: bdis_ipc::clock::monotonic_ns() };
            wire::sample(&mut frame, what, scratch, &[]);
            outbox.push(Entry { topic: Carried::Corrections, id, frame });
        }
    }
    if let Some((subscriber, _)) = &inputs.keyframes {
        while let Some(sample) = subscriber.receive().context("receive a keyframe")? {
            let t_receive_ns = bdis_ipc::clock::monotonic_ns();
            let header = *sample.user_header();
            let end = header.frame.flags & bdis_ipc::FrameHeader::END_OF_STREAM != 0;
            let id = if end { u64::MAX } else { header.meta.kf_id };
            scratch.clear();
            records::put_keyframe_header(scratch, &header);
            let payload = sample.payload();
            let mut frame = Vec::with_capacity(scratch.len() + payload.len() + 32);
            let what = SampleId { topic: Carried::Keyframes, id, t_sent_ns: bdis_ipc::clock::monotonic_ns() };
            wire::sample(&mut frame, what, scratch, payload);
            outbox.push(Entry { topic: Carried::Keyframes, id, frame });
            if end {
                ends.keyframes = true;
            } else {
                let timing = MessageTiming {
                    frame_seq: header.meta.kf_id,
                    t_capture_ns: header.frame.t_capture_ns,
                    t_upstream_publish_ns: header.frame.t_publish_ns,
                    t_receive_ns,
                    t_done_ns: bdis_ipc::clock::monotonic_ns(),
                };
                telemetry.message(timing, outbox.overflowed);
            }
        }
    }
    if let Some((subscriber, _)) = &inputs.depth {
        while let Some(sample) = subscriber.receive().context("receive a depth keyframe")? {
            let t_receive_ns = bdis_ipc::clock::monotonic_ns();
            let header = *sample.user_header();
            let end = header.is_end_of_stream();
            let id = if end { u64::MAX } else { header.meta.kf_id };
            scratch.clear();
            records::put_depth_header(scratch, &header);
            let payload = sample.payload();
            let mut frame = Vec::with_capacity(scratch.len() + payload.len() + 32);
            let what = SampleId { topic: Carried::Depth, id, t_sent_ns: bdis_ipc::clock::monotonic_ns() };
            wire::sample(&mut frame, what, scratch, payload);
            outbox.push(Entry { topic: Carried::Depth, id, frame });
            if end {
                ends.depth = true;
            } else {
                let timing = MessageTiming {
                    frame_seq: header.meta.kf_id,
                    t_capture_ns: header.t_capture_ns,
                    t_upstream_publish_ns: header.t_publish_ns,
                    t_receive_ns,
                    t_done_ns: bdis_ipc::clock::monotonic_ns(),
                };
                telemetry.message(timing, outbox.overflowed);
            }
        }
    }
    if let Some((subscriber, _)) = &inputs.poses {
        while let Some(sample) = subscriber.receive().context("receive a pose")? {
            let record = *sample.payload();
            let end = record.state == tracking_state::END_OF_STREAM;
            let id = if end { u64::MAX } else { record.frame_seq };
            scratch.clear();
            records::put_pose(scratch, &record);
            let mut frame = Vec::with_capacity(scratch.len() + 32);
            let what = SampleId { topic: Carried::Poses, id, t_sent_ns: bdis_ipc::clock::monotonic_ns() };
            wire::sample(&mut frame, what, scratch, &[]);
            outbox.push(Entry { topic: Carried::Poses, id, frame });
            ends.poses |= end;
        }
    }
    Ok(())
}

pub fn run(common: Common, to: &str, budget_bytes: usize) -> Result<()> {
    let Common { topics, name, ipc_prefix, map_snapshots } = common;
    // The link first: a malformed address is refused before shared memory is touched.
    let mut link = Link::open(Side::Sender, "--to", to)?;
    let ipc = Ipc::open(&name, &ipc_prefix)?;
    let inputs = Inputs {
        // History: a sender that restarted is handed the tracker's last keyframes again, and sends on those the
        // receiver does not have.
        keyframes: if topics.contains(&Carried::Keyframes) {
            let service = ipc.keyframes()?;
            Some((ipc.keyframe_subscriber(&service)?, ipc.listener(&ipc.events(Topic::Keyframes)?)?))
        } else {
            None
        },
        depth: if topics.contains(&Carried::Depth) {
            let service = ipc.depth()?;
            Some((ipc.depth_subscriber(&service)?, ipc.listener(&ipc.events(Topic::Depth)?)?))
        } else {
            None
        },
        corrections: if topics.contains(&Carried::Corrections) {
            let service = ipc.corrections()?;
            let subscriber = service.subscriber_builder().create().context("create the corrections subscriber")?;
            Some((subscriber, ipc.listener(&ipc.events(Topic::Corrections)?)?))
        } else {
            None
        },
        poses: if topics.contains(&Carried::Poses) {
            let service = ipc.poses()?;
            let subscriber = service.subscriber_builder().create().context("create the poses subscriber")?;
            Some((subscriber, ipc.listener(&ipc.events(Topic::Poses)?)?))
        } else {
            None
        },
    };
    let input_topic = match (&inputs.keyframes, &inputs.depth, &inputs.poses) {
        (Some(_), _, _) => Topic::Keyframes,
        (None, Some(_), _) => Topic::Depth,
        (None, None, Some(_)) => Topic::Poses,
        (None, None, None) => Topic::Corrections,
    };
    let mut telemetry = TelemetryPublisher::new(&ipc, &name, Some(input_topic), None)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(bdis_node::NodeError::WaitSet)?;
    let mut input_guards = Vec::new();
    for listener in inputs.listeners() {
        input_guards.push(waitset.attach_notification(listener).map_err(bdis_node::NodeError::Attach)?);
    }
    let (mut serve, snapshot_requests) = match map_snapshots {
        true => Serve::open(&ipc).map(|(s, l)| (Some(s), Some(l)))?,
        false => (None, None),
    };
    let _snapshot_guard = match &snapshot_requests {
        Some(listener) => Some(waitset.attach_notification(listener).map_err(bdis_node::NodeError::Attach)?),
        None => None,
    };
    let link_fd = link.wake_fd().context("the link's wake-up descriptor")?;
    let _link_guard = waitset.attach_notification(&link_fd).map_err(bdis_node::NodeError::Attach)?;
    let _keepalive = waitset.attach_interval(bdis_node::WAKE_DEADLINE).map_err(bdis_node::NodeError::Attach)?;

    let mut outbox = Outbox::new(budget_bytes);
    let mut conversation = Conversation::default();
    // The first conversation, before this service says it is ready: what the receiver already has is where a
    // restarted sender resumes.
    let started = Instant::now();
    let first = loop {
        conversation.take(&mut link, &topics, &mut outbox, &mut serve)?;
        if let Some(first) = conversation.first.take() {
            break first;
        }
        if started.elapsed() > FIRST_CONVERSATION {
            bail!("no receiver answered at {to} within {FIRST_CONVERSATION:?}");
        }
        let wake = conversation.ask_if_due(&link)?;
        let retry = match wake {
            Some(period) => Some(waitset.attach_interval(period).map_err(bdis_node::NodeError::Attach)?),
            None => None,
        };
        let run = waitset.wait_and_process_once(|_| CallbackProgression::Continue);
        drop(retry);
        if matches!(run, Ok(WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt)) {
            link.close();
            return Ok(());
        }
    };
    let restored = first.iter().find(|(t, _)| *t == Carried::Depth).and_then(|(_, id)| *id);
    tracing::info!("sending {} to {to}; the receiver has up to keyframe {restored:?}", names(&topics));
    telemetry.ready_restored(restored);

    let mut ids = CorrectionIds::default();
    let mut scratch = Vec::new();
    let mut ends = Ends::default();
    // Done when every carried stream that has an end has ended and the receiver has everything.
    let all_ended = |e: Ends| {
        (e.depth || inputs.depth.is_none())
            && (e.poses || inputs.poses.is_none())
            && (e.keyframes || inputs.keyframes.is_none())
            && (inputs.depth.is_some() || inputs.poses.is_some() || inputs.keyframes.is_some())
    };
    let stopped = loop {
        let wake = conversation.ask_if_due(&link)?;
        let retry = match wake {
            Some(period) => Some(waitset.attach_interval(period).map_err(bdis_node::NodeError::Attach)?),
            None => None,
        };
        let run =
            waitset.wait_and_process_once(|_| CallbackProgression::Continue).map_err(bdis_node::NodeError::Wait)?;
        drop(retry);
        if matches!(run, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            break true;
        }
        for listener in inputs.listeners() {
            // Only wake-ups: the samples are received below.
            let _ = bdis_ipc::drain_events(listener);
        }
        telemetry.keepalive();
        take_inputs(&inputs, &mut outbox, &mut ids, &mut telemetry, &mut scratch, &mut ends)?;
        conversation.take(&mut link, &topics, &mut outbox, &mut serve)?;
        conversation.send(&link, &mut outbox)?;
        if let (Some(serve), Some(requests)) = (serve.as_mut(), &snapshot_requests) {
            let _ = bdis_ipc::drain_events(requests);
            serve.take_requests(&link)?;
        }
        if all_ended(ends) && outbox.is_empty() {
            break false;
        }
    };
    tracing::info!(
        "bridge sender done: {} samples left unsent, {} given up over budget, {} conversations after the first",
        outbox.len(),
        outbox.overflowed,
        conversation.hellos.saturating_sub(1)
    );
    if let Some(serve) = &serve {
        tracing::info!("map snapshots served from the far host: {}, unanswered {}", serve.served, serve.unanswered);
    }
    drop(serve);
    link.close();
    if !stopped && outbox.overflowed > 0 {
        telemetry.failed();
        bail!("{} samples were given up while the link was down (--outbox-mib)", outbox.overflowed);
    }
    telemetry.finished();
    Ok(())
}

fn names(topics: &[Carried]) -> String {
    topics.iter().map(|t| t.name()).collect::<Vec<_>>().join(", ")
}
