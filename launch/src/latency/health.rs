//! The health ledger the supervisor reads: which instance of a service is ready, when it was last heard from,
//! the last item each instance and each topic's consumers have, and what a restarted one restored.

use super::*;

impl LatencyAggregator {
    /// True once an instance of `process` has reported ready.
    pub fn is_ready(&self, process: &str) -> bool {
        self.processes.get(process).is_some_and(|p| self.instances.get(&p.pid).is_some_and(|i| i.ready))
    }

    /// True once the process `pid` has reported ready.
    pub fn is_pid_ready(&self, pid: u32) -> bool {
        self.instances.get(&pid).is_some_and(|i| i.ready)
    }

    /// When the launcher last heard from process `pid`.
    pub fn last_heard(&self, pid: u32) -> Option<std::time::Instant> {
        self.instances.get(&pid).map(|i| i.last_heard)
    }

    /// The highest message id process `pid` has handled.
    pub fn last_item_of_pid(&self, pid: u32) -> Option<u64> {
        self.instances.get(&pid).and_then(|i| i.last_item)
    }

    /// The highest message id that the current instance of every consumer of `topic` has (handled, or
    /// restored from a save): e.g. the last keyframe id both the mosaic and the depth probe took in. `None` when
    /// some consumer has nothing yet.
    pub fn last_item_consumed(&self, topic: &str) -> Option<u64> {
        let mut consumers = self.processes.values().filter(|p| p.input_topic == topic).peekable();
        consumers.peek()?;
        consumers.map(|p| p.last_item).min().flatten()
    }

    /// What the current instance of `process` restored from a save: it has every message up to this id (what it
    /// handled since may have gaps: messages sent while it was down).
    pub fn restored_of(&self, process: &str) -> Option<u64> {
        self.processes.get(process).and_then(|p| p.restored)
    }

    /// The highest message id the current instance of `process` has.
    pub fn last_item_of(&self, process: &str) -> Option<u64> {
        self.processes.get(process).and_then(|p| p.last_item)
    }

    /// The topic `process` consumes, as its telemetry names it.
    pub fn input_topic(&self, process: &str) -> Option<String> {
        self.processes.get(process).map(|p| p.input_topic.clone()).filter(|t| !t.is_empty())
    }

    /// The topic `process` publishes, as its telemetry names it.
    pub fn output_topic(&self, process: &str) -> Option<String> {
        self.processes.get(process).map(|p| p.output_topic.clone()).filter(|t| !t.is_empty())
    }

    /// True when some process of the run consumes `topic`.
    pub fn has_consumer(&self, topic: &str) -> bool {
        self.processes.values().any(|p| p.input_topic == topic)
    }

    pub fn ended(&self, process: &str) -> Option<TelemetryKind> {
        self.processes.get(process).and_then(|p| p.ended)
    }

    pub fn messages(&self, process: &str) -> u64 {
        self.processes.get(process).map_or(0, |p| p.messages)
    }
}
