//! The producing host's side: the carried topics taken from shared memory into the outbox as they are published
//! (so shared memory's small buffers never overflow while the link is slow or down), written to the receiver in
//! order, dropped when it says it has published them, written again after a broken connection. Its first
//! connection tells it what the receiver already has: a sender that restarted reports that as the point it
//! restored (`ready_restored`), and the launcher has the stereo service redo the keyframes after it from the
//! tracker's keyframe history, as it does for a restarted mosaic.

use std::io::Write;
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use bdis_bridge::ledger::{CorrectionIds, Entry, Outbox};
use bdis_bridge::wire::{self, Frame, FrameReader, ResumePoints, SampleId};
use bdis_bridge::{Carried, records};
use bdis_ipc::telemetry::MessageTiming;
use bdis_ipc::track::tracking_state;
use bdis_ipc::{DepthHeader, Ipc, KeyframeHeader, KeyframePose, PoseRecord, TelemetryPublisher, Topic};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

use crate::node::{Common, PeerState, SocketFd, read_available};

/// How long a connection attempt may take, and how long the receiver has to say hello.
const CONNECT_TIMEOUT: Duration = Duration::from_millis(500);
const HELLO_TIMEOUT: Duration = Duration::from_secs(10);
/// While the receiver cannot be reached: how often to try again.
const RETRY_PERIOD: Duration = Duration::from_millis(250);
/// The first connection must be made within this (the launcher's readiness deadline is 20 s).
const FIRST_CONNECTION: Duration = Duration::from_secs(15);
/// How long a write may block before the connection counts as broken.
const WRITE_TIMEOUT: Duration = Duration::from_secs(10);

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

/// A connection to the receiver.
struct Connection {
    stream: TcpStream,
    reader: FrameReader,
}

fn resolve(to: &str) -> Result<SocketAddr> {
    to.to_socket_addrs()
        .with_context(|| format!("--to {to}: not an address"))?
        .next()
        .with_context(|| format!("--to {to}: names no address"))
}

/// Connects and reads the receiver's HELLO: what it has already published.
fn connect(addr: SocketAddr, topics: &[Carried]) -> Result<(Connection, ResumePoints)> {
    let mut stream = TcpStream::connect_timeout(&addr, CONNECT_TIMEOUT)?;
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(HELLO_TIMEOUT))?;
    stream.set_write_timeout(Some(WRITE_TIMEOUT))?;
    let mut reader = FrameReader::default();
    let deadline = Instant::now() + HELLO_TIMEOUT;
    let hello = loop {
        if Instant::now() > deadline {
            bail!("{addr}: no hello from the receiver");
        }
        let space = reader.space(256);
        let n = std::io::Read::read(&mut stream, space)?;
        reader.extend(256, n);
        if n == 0 {
            bail!("{addr}: the receiver closed the connection");
        }
        match reader.next_frame()? {
            Some(Frame::Hello { last }) => break last,
            Some(_) => bail!("{addr}: the receiver did not begin with a hello"),
            None => {}
        }
    };
    for topic in topics {
        if !hello.iter().any(|(t, _)| t == topic) {
            bail!("{addr}: the receiver does not carry {}", topic.name());
        }
    }
    stream.set_nonblocking(true)?;
    Ok((Connection { stream, reader }, hello))
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

/// Reads the receiver's acknowledgements and writes what it has not been sent; `Closed` when the connection broke.
fn exchange(connection: &mut Connection, outbox: &mut Outbox) -> PeerState {
    // What arrived is taken in even when the receiver then closed: its last acknowledgement (after the end of
    // the stream) comes just before it goes.
    let state = read_available(&mut connection.stream, &mut connection.reader);
    loop {
        match connection.reader.next_frame() {
            Ok(Some(Frame::Ack { published })) => outbox.acknowledged(published),
            Ok(Some(_)) | Err(_) => return PeerState::Closed,
            Ok(None) => break,
        }
    }
    if state == PeerState::Closed {
        return PeerState::Closed;
    }
    // Writes block (up to WRITE_TIMEOUT) rather than spin: what cannot be written now stays in the outbox.
    if connection.stream.set_nonblocking(false).is_err() {
        return PeerState::Closed;
    }
    let mut written = 0;
    for entry in outbox.unsent() {
        if connection.stream.write_all(&entry.frame).is_err() {
            return PeerState::Closed;
        }
        written += 1;
    }
    outbox.mark_sent(written);
    if connection.stream.flush().is_err() || connection.stream.set_nonblocking(true).is_err() {
        return PeerState::Closed;
    }
    PeerState::Open
}

pub fn run(common: Common, to: &str, budget_bytes: usize) -> Result<()> {
    let Common { topics, name, ipc_prefix } = common;
    let addr = resolve(to)?;
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
    let _keepalive = waitset.attach_interval(bdis_node::WAKE_DEADLINE).map_err(bdis_node::NodeError::Attach)?;

    // The first connection, before this service says it is ready: what the receiver already has is where a
    // restarted sender resumes.
    let started = Instant::now();
    let (connection, hello) = loop {
        match connect(addr, &topics) {
            Ok(c) => break c,
            Err(e) if started.elapsed() < FIRST_CONNECTION => {
                tracing::debug!("{e:#}; trying again");
                let retry = waitset.attach_interval(RETRY_PERIOD).map_err(bdis_node::NodeError::Attach)?;
                let run = waitset.wait_and_process_once(|_| CallbackProgression::Continue);
                drop(retry);
                if matches!(run, Ok(WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt)) {
                    return Ok(());
                }
            }
            Err(e) => return Err(e.context(format!("no receiver at {addr} within {FIRST_CONNECTION:?}"))),
        }
    };
    let mut outbox = Outbox::new(budget_bytes);
    outbox.connected(&hello);
    let restored = hello.iter().find(|(t, _)| *t == Carried::Depth).and_then(|(_, id)| *id);
    tracing::info!("sending {} to {addr}; the receiver has up to keyframe {restored:?}", names(&topics));
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
    let mut connected: Option<Connection> = Some(connection);
    let mut next_attempt = Instant::now();
    let mut reconnects = 0u64;
    let stopped = loop {
        let socket_fd = connected.as_ref().map(|c| SocketFd::of(&c.stream));
        let socket_guard = match socket_fd.as_ref() {
            Some(Some(fd)) => Some(waitset.attach_notification(fd).map_err(bdis_node::NodeError::Attach)?),
            _ => None,
        };
        let retry = match connected {
            None => Some(waitset.attach_interval(RETRY_PERIOD).map_err(bdis_node::NodeError::Attach)?),
            Some(_) => None,
        };
        let run =
            waitset.wait_and_process_once(|_| CallbackProgression::Continue).map_err(bdis_node::NodeError::Wait)?;
        drop(retry);
        drop(socket_guard);
        if matches!(run, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            break true;
        }
        for listener in inputs.listeners() {
            // Only wake-ups: the samples are received below.
            let _ = bdis_ipc::drain_events(listener);
        }
        telemetry.keepalive();
        take_inputs(&inputs, &mut outbox, &mut ids, &mut telemetry, &mut scratch, &mut ends)?;
        let ended = all_ended(ends);

        if connected.is_none() && Instant::now() >= next_attempt {
            match connect(addr, &topics) {
                Ok((c, hello)) => {
                    outbox.connected(&hello);
                    reconnects += 1;
                    tracing::info!("reconnected to {addr} ({} samples to send)", outbox.len());
                    connected = Some(c);
                }
                Err(e) => {
                    tracing::debug!("{e:#}");
                    next_attempt = Instant::now() + RETRY_PERIOD;
                }
            }
        }
        if let Some(c) = connected.as_mut()
            && exchange(c, &mut outbox) == PeerState::Closed
            && !(ended && outbox.is_empty())
        {
            tracing::warn!("the connection to {addr} broke; {} samples kept to send again", outbox.len());
            connected = None;
            next_attempt = Instant::now();
        }
        if ended && outbox.is_empty() {
            break false;
        }
    };
    tracing::info!(
        "bridge sender done: {} samples left unsent, {} given up over budget, {reconnects} reconnections",
        outbox.len(),
        outbox.overflowed
    );
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
