//! Per-message timing records: every process reports, for each message it handles, when the message was
//! captured, when its upstream published it, when this process received it and when it was done with it.
//! From those the launcher derives queue wait (receive − upstream publish), processing time (done − receive)
//! and the output's age (done − capture), per process and per hop.

use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::*;

use crate::validate::{Reason, Rejection};
use crate::{Ipc, IpcError, Topic, clock, event_id, fixed, iox, text};

/// What a telemetry record reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum TelemetryKind {
    /// The process has opened its ports and can take input.
    Ready = 1,
    /// One message handled.
    Message = 2,
    /// The process finished its stream normally (totals in `messages`, `dropped`, `cpu_time_ns`).
    Finished = 3,
    /// The process stopped on an error (totals as for `Finished`).
    Failed = 4,
    /// Nothing to report, but alive: sent when a process has been quiet for [`HEARTBEAT_PERIOD`], so the launcher
    /// can tell an idle service from a hung one (its liveness deadline).
    Heartbeat = 5,
    /// One input sample refused by validation ([`crate::validate`]): `input_topic` names the topic it came on,
    /// `reason` says why ([`crate::validate::Reason`]), `frame_seq` the id it carried.
    Rejected = 6,
}

/// A process that has sent no record for this long sends a heartbeat at its next wake-up. Services wake at least
/// once a second (their WaitSet deadlines), so a live service is never silent for much over a second.
pub const HEARTBEAT_PERIOD: std::time::Duration = std::time::Duration::from_millis(500);

impl TelemetryKind {
    pub fn from_u32(v: u32) -> Option<Self> {
        Some(match v {
            1 => Self::Ready,
            2 => Self::Message,
            3 => Self::Finished,
            4 => Self::Failed,
            5 => Self::Heartbeat,
            6 => Self::Rejected,
            _ => return None,
        })
    }
}

/// One record on the telemetry topic (`bdis.v2.TelemetryRecord`). Times are CLOCK_MONOTONIC ns, 0 = not
/// applicable (a source has no upstream).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("bdis.v2.TelemetryRecord")]
pub struct TelemetryRecord {
    pub kind: u32,
    pub pid: u32,
    /// Consecutive per process: a gap means the launcher lost records.
    pub record_seq: u64,
    /// The service name of the process (`acquisition`, `probe`, …), NUL-padded.
    pub process: [u8; 32],
    pub input_topic: [u8; 16],
    pub output_topic: [u8; 16],
    /// The id of the message handled: the frame sequence number, or the keyframe id on the keyframes and depth
    /// topics (a keyframe-consuming service reports the keyframe id, so the launcher knows which keyframes are
    /// done downstream when it swaps the stereo service).
    pub frame_seq: u64,
    pub t_capture_ns: u64,
    pub t_upstream_publish_ns: u64,
    pub t_receive_ns: u64,
    pub t_done_ns: u64,
    /// Messages handled so far.
    pub messages: u64,
    /// Input messages this process saw missing (sequence gaps) so far.
    pub dropped: u64,
    /// CPU time of the process so far.
    pub cpu_time_ns: u64,
    /// In a `Ready` record: one past the highest message id this instance restored from a save (the mosaic's
    /// checkpoint), so the launcher knows what a restarted consumer already has; 0 = nothing restored (the
    /// default, so a record built field by field cannot claim a restore by accident).
    pub restored_next: u64,
    /// Input samples this process refused so far (all topics, all reasons).
    pub rejected: u64,
    /// In a `Rejected` record: the [`crate::validate::Reason`].
    pub reason: u32,
    pub reserved: u32,
}

impl TelemetryRecord {
    /// The highest message id restored from a save, from a `Ready` record.
    pub fn restored(&self) -> Option<u64> {
        self.restored_next.checked_sub(1)
    }

    pub fn kind(&self) -> Option<TelemetryKind> {
        TelemetryKind::from_u32(self.kind)
    }
    pub fn process(&self) -> &str {
        text(&self.process)
    }
    pub fn input_topic(&self) -> &str {
        text(&self.input_topic)
    }
    pub fn output_topic(&self) -> &str {
        text(&self.output_topic)
    }
    /// receive − upstream publish: time on the wire and in the queue.
    pub fn queue_wait_ns(&self) -> u64 {
        clock::elapsed_ns(self.t_upstream_publish_ns, self.t_receive_ns)
    }
    /// done − receive (for a source: done − capture).
    pub fn processing_ns(&self) -> u64 {
        if self.t_receive_ns != 0 {
            clock::elapsed_ns(self.t_receive_ns, self.t_done_ns)
        } else {
            clock::elapsed_ns(self.t_capture_ns, self.t_done_ns)
        }
    }
    /// done − capture: how old the output is when it leaves this process.
    pub fn age_ns(&self) -> u64 {
        clock::elapsed_ns(self.t_capture_ns, self.t_done_ns)
    }
}

/// A telemetry record: a defined kind and a process name.
pub fn validate(r: &TelemetryRecord) -> Result<TelemetryKind, Rejection> {
    let kind = r.kind().ok_or_else(|| {
        Rejection::new(
            Reason::UnknownValue,
            r.record_seq,
            format!("telemetry from pid {}: unknown kind {}", r.pid, r.kind),
        )
    })?;
    if r.process().is_empty() || r.process() == "?" {
        return Err(Rejection::new(
            Reason::UnknownValue,
            r.record_seq,
            format!("telemetry from pid {}: no process name", r.pid),
        ));
    }
    Ok(kind)
}

/// The times of one handled message.
#[derive(Debug, Clone, Copy, Default)]
pub struct MessageTiming {
    pub frame_seq: u64,
    pub t_capture_ns: u64,
    pub t_upstream_publish_ns: u64,
    pub t_receive_ns: u64,
    pub t_done_ns: u64,
}

/// A process's telemetry sender. Sending never blocks and never fails the pipeline: a failure is counted and
/// reported once.
#[derive(Debug)]
pub struct TelemetryPublisher {
    publisher: Publisher<ipc::Service, TelemetryRecord, ()>,
    notifier: Notifier<ipc::Service>,
    template: TelemetryRecord,
    failures: u64,
    last_sent_ns: u64,
    /// (topic, reason) pairs already logged: each is logged once, then only counted.
    logged_rejections: Vec<(Topic, Reason)>,
}

impl TelemetryPublisher {
    pub fn new(ipc: &Ipc, process: &str, input: Option<Topic>, output: Option<Topic>) -> Result<Self, IpcError> {
        let service = ipc.telemetry()?;
        let publisher = service
            .publisher_builder()
            .max_loaned_samples(1)
            .create()
            .map_err(iox("create the telemetry publisher"))?;
        let notifier = ipc.notifier(&ipc.events(Topic::Telemetry)?)?;
        let template = TelemetryRecord {
            pid: std::process::id(),
            process: fixed(process),
            input_topic: fixed(input.map_or("", Topic::short_name)),
            output_topic: fixed(output.map_or("", Topic::short_name)),
            ..Default::default()
        };
        Ok(Self {
            publisher,
            notifier,
            template,
            failures: 0,
            last_sent_ns: clock::monotonic_ns(),
            logged_rejections: Vec::new(),
        })
    }

    fn send(&mut self, kind: TelemetryKind, timing: MessageTiming, wake_launcher: bool) {
        let mut record = self.template;
        record.kind = kind as u32;
        record.frame_seq = timing.frame_seq;
        record.t_capture_ns = timing.t_capture_ns;
        record.t_upstream_publish_ns = timing.t_upstream_publish_ns;
        record.t_receive_ns = timing.t_receive_ns;
        record.t_done_ns = timing.t_done_ns;
        if kind != TelemetryKind::Message {
            record.cpu_time_ns = clock::process_cpu_ns();
        }
        self.template.record_seq += 1;
        self.last_sent_ns = clock::monotonic_ns();
        let sent = self.publisher.send_copy(record).map(|_| ());
        let notified = if wake_launcher {
            self.notifier
                .notify_with_custom_event_id(EventId::new(event_id::NEW_SAMPLE))
                .map(|_| ())
                .map_err(|e| format!("{e:?}"))
        } else {
            Ok(())
        };
        if let Err(e) = sent.map_err(|e| format!("{e:?}")).and(notified) {
            self.failures += 1;
            if self.failures == 1 {
                tracing::warn!("telemetry could not be sent ({e}); latency figures of this process will be incomplete");
            }
        }
    }

    /// Announces that the process's ports are open and that it restored messages up to `restored` from a save.
    pub fn ready_restored(&mut self, restored: Option<u64>) {
        self.template.restored_next = restored.map_or(0, |id| id.saturating_add(1));
        self.ready();
        self.template.restored_next = 0;
    }

    /// Announces that the process's ports are open (the launcher starts upstream processes after this).
    pub fn ready(&mut self) {
        self.send(TelemetryKind::Ready, MessageTiming { t_done_ns: clock::monotonic_ns(), ..Default::default() }, true);
    }

    /// Records one handled message; `dropped` is the running count of input messages seen missing.
    pub fn message(&mut self, timing: MessageTiming, dropped: u64) {
        self.template.messages += 1;
        self.template.dropped = dropped;
        self.send(TelemetryKind::Message, timing, false);
    }

    /// The running count of input messages seen missing, when it grows without a message handled (gaps
    /// before the end of the stream); the end record carries it.
    pub fn set_dropped(&mut self, dropped: u64) {
        self.template.dropped = dropped;
    }

    /// The stream ended normally.
    pub fn finished(&mut self) {
        self.send(
            TelemetryKind::Finished,
            MessageTiming { t_done_ns: clock::monotonic_ns(), ..Default::default() },
            true,
        );
    }

    /// The process is stopping on an error.
    pub fn failed(&mut self) {
        self.send(
            TelemetryKind::Failed,
            MessageTiming { t_done_ns: clock::monotonic_ns(), ..Default::default() },
            true,
        );
    }

    /// Sends a heartbeat when nothing was sent for [`HEARTBEAT_PERIOD`]; cheap to call at every wake-up.
    pub fn keepalive(&mut self) {
        if clock::elapsed_ns(self.last_sent_ns, clock::monotonic_ns()) >= HEARTBEAT_PERIOD.as_nanos() as u64 {
            self.send(
                TelemetryKind::Heartbeat,
                MessageTiming { t_done_ns: clock::monotonic_ns(), ..Default::default() },
                false,
            );
        }
    }

    pub fn messages(&self) -> u64 {
        self.template.messages
    }

    /// Records an input sample refused on `topic`: counted, reported to the launcher, and logged the first time
    /// this (topic, reason) occurs — a publisher sending garbage at frame rate must not flood the log.
    pub fn rejected(&mut self, topic: Topic, rejection: &Rejection) {
        let key = (topic, rejection.reason);
        if !self.logged_rejections.contains(&key) {
            self.logged_rejections.push(key);
            tracing::warn!(
                "{}: refused ({}): {}; further refusals of this kind are counted, not logged",
                topic.short_name(),
                rejection.reason.name(),
                rejection.detail
            );
        }
        self.template.rejected += 1;
        let input = self.template.input_topic;
        self.template.input_topic = fixed(topic.short_name());
        self.template.reason = rejection.reason as u32;
        // Signalled (unlike message records): refusals are rare in a healthy run, and whoever watches for them
        // (the launcher, a test's rogue publisher) learns of each at once.
        self.send(
            TelemetryKind::Rejected,
            MessageTiming { frame_seq: rejection.id, t_done_ns: clock::monotonic_ns(), ..Default::default() },
            true,
        );
        self.template.input_topic = input;
        self.template.reason = 0;
    }

    /// Input samples refused so far.
    pub fn rejected_count(&self) -> u64 {
        self.template.rejected
    }
}

/// Waits for a process of the run to report ready, for a tool or a test that starts a service itself and must
/// not send before the service has subscribed (the launcher's aggregator does this, and more, for a whole run).
/// Open it before the process starts: records sent before the subscription are not seen.
#[derive(Debug)]
pub struct ReadyWatch {
    records: iceoryx2::port::subscriber::Subscriber<ipc::Service, TelemetryRecord, ()>,
    events: iceoryx2::port::listener::Listener<ipc::Service>,
}

impl ReadyWatch {
    pub fn open(ipc: &Ipc) -> Result<Self, IpcError> {
        let service = ipc.telemetry()?;
        Ok(Self { records: ipc.telemetry_subscriber(&service)?, events: ipc.listener(&ipc.events(Topic::Telemetry)?)? })
    }

    /// Whether `process` reported ready before `deadline`.
    pub fn wait(&self, process: &str, deadline: std::time::Instant) -> Result<bool, IpcError> {
        let ready = crate::wait_for(&self.events, deadline, || {
            while let Some(r) = self.records.receive().map_err(iox("receive telemetry"))? {
                if r.payload().process() == process && r.payload().kind() == Some(TelemetryKind::Ready) {
                    return Ok(Some(()));
                }
            }
            Ok(None)
        })?;
        Ok(ready.is_some())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_need_a_defined_kind_and_a_process() {
        let mut r =
            TelemetryRecord { kind: TelemetryKind::Message as u32, process: fixed("tracking"), ..Default::default() };
        assert_eq!(validate(&r), Ok(TelemetryKind::Message));
        r.kind = 99;
        assert_eq!(validate(&r).unwrap_err().reason, Reason::UnknownValue);
        r.kind = TelemetryKind::Ready as u32;
        r.process = [0; 32];
        assert_eq!(validate(&r).unwrap_err().reason, Reason::UnknownValue);
    }
}
