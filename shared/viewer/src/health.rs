//! Every process's health as the page shows it — rate, processing time, CPU, restarts, state — from the
//! pipeline's telemetry, summed up once a report period.

use std::collections::{BTreeMap, VecDeque};

use serde::Serialize;

use crate::live::Update;

/// Processing times kept per process for its percentiles: the last few seconds at pipeline rates.
const RECENT: usize = 256;

/// What one telemetry record says, as far as the page cares.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BeatKind {
    Ready,
    /// One message handled in this many nanoseconds.
    Message {
        processing_ns: u64,
    },
    Finished,
    Failed,
    /// Alive, nothing to report.
    Heartbeat,
}

#[derive(Debug, Clone, Copy)]
pub struct Beat<'a> {
    pub process: &'a str,
    pub pid: u32,
    pub kind: BeatKind,
    /// The process's CPU time so far.
    pub cpu_time_ns: u64,
}

#[derive(Debug, Default)]
struct Entry {
    pid: u32,
    messages: u64,
    reported_messages: u64,
    cpu_ns: u64,
    reported_cpu_ns: u64,
    processing_ms: VecDeque<f64>,
    restarts: u32,
    state: &'static str,
}

/// One row of the page's process table.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct ProcessHealth {
    pub name: String,
    pub pid: u32,
    pub rate_hz: f64,
    pub processing_p50_ms: Option<f64>,
    pub processing_p99_ms: Option<f64>,
    pub cpu_percent: f64,
    pub restarts: u32,
    pub state: &'static str,
}

#[derive(Debug, Default)]
pub struct Health {
    processes: BTreeMap<String, Entry>,
    events: Vec<String>,
}

impl Health {
    /// Takes one record; `t_s` is the time since the viewer started, for the events it notes.
    pub fn record(&mut self, beat: Beat, t_s: f64) {
        let entry = self
            .processes
            .entry(beat.process.to_string())
            .or_insert_with(|| Entry { state: "running", ..Default::default() });
        if entry.pid != 0 && beat.pid != entry.pid {
            // Another instance under the same name: a restart after a crash, or a swap.
            entry.restarts += 1;
            entry.reported_cpu_ns = 0;
            self.events.push(format!("{t_s:.1} s: {} now pid {} (was {})", beat.process, beat.pid, entry.pid));
        }
        entry.pid = beat.pid;
        entry.cpu_ns = beat.cpu_time_ns;
        match beat.kind {
            BeatKind::Message { processing_ns } => {
                entry.messages += 1;
                if entry.processing_ms.len() == RECENT {
                    entry.processing_ms.pop_front();
                }
                entry.processing_ms.push_back(processing_ns as f64 / 1e6);
                entry.state = "running";
            }
            BeatKind::Ready | BeatKind::Heartbeat => entry.state = "running",
            BeatKind::Finished => entry.state = "finished",
            BeatKind::Failed => {
                entry.state = "failed";
                self.events.push(format!("{t_s:.1} s: {} failed", beat.process));
            }
        }
    }

    /// The table over the last `period_s` seconds, as the page's `health` message.
    pub fn report(&mut self, period_s: f64) -> Update {
        let period_s = period_s.max(1e-3);
        let processes: Vec<ProcessHealth> = self
            .processes
            .iter_mut()
            .map(|(name, e)| {
                let mut recent: Vec<f64> = e.processing_ms.iter().copied().collect();
                recent.sort_by(f64::total_cmp);
                let at = |q: f64| recent.get(((recent.len() as f64 - 1.0) * q).round() as usize).copied();
                let row = ProcessHealth {
                    name: name.clone(),
                    pid: e.pid,
                    rate_hz: (e.messages - e.reported_messages) as f64 / period_s,
                    processing_p50_ms: at(0.5),
                    processing_p99_ms: at(0.99),
                    cpu_percent: 100.0 * e.cpu_ns.saturating_sub(e.reported_cpu_ns) as f64 / 1e9 / period_s,
                    restarts: e.restarts,
                    state: e.state,
                };
                e.reported_messages = e.messages;
                e.reported_cpu_ns = e.cpu_ns;
                row
            })
            .collect();
        #[derive(Serialize)]
        struct Report<'a> {
            r#type: &'static str,
            processes: &'a [ProcessHealth],
            events: &'a [String],
        }
        Update::Text(
            serde_json::to_string(&Report { r#type: "health", processes: &processes, events: &self.events })
                .unwrap_or_default(),
        )
    }
}
