//! Aggregates telemetry records into per-process and per-hop latency figures (p50/p90/p99/max), the
//! `latency.json` of a run and the table the launcher prints.

mod health;
mod svg;

use std::collections::BTreeMap;
use std::fmt::Write as _;

use bdis_ipc::{TelemetryKind, TelemetryRecord};
use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};

fn histogram() -> Histogram<u64> {
    // 3 significant digits, auto-resizing: exact enough for µs figures, bounded memory for long runs.
    Histogram::new(3).unwrap_or_else(|_| unreachable_histogram())
}

#[cold]
fn unreachable_histogram() -> Histogram<u64> {
    // `new(3)` only fails for sigfig > 5; keep a valid fallback rather than a panic path.
    Histogram::new_with_bounds(1, 3_600_000_000_000, 2).unwrap_or_else(|_| std::process::abort())
}

/// Percentiles of one quantity, in microseconds.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
pub struct Percentiles {
    pub count: u64,
    pub p50: f64,
    pub p90: f64,
    pub p99: f64,
    pub max: f64,
    pub mean: f64,
}

impl Percentiles {
    /// The percentiles of a histogram of nanoseconds, in µs; `None` when it is empty.
    pub fn of(h: &Histogram<u64>) -> Option<Self> {
        if h.is_empty() {
            return None;
        }
        let us = |ns: u64| ns as f64 / 1000.0;
        Some(Self {
            count: h.len(),
            p50: us(h.value_at_quantile(0.50)),
            p90: us(h.value_at_quantile(0.90)),
            p99: us(h.value_at_quantile(0.99)),
            max: us(h.max()),
            mean: h.mean() / 1000.0,
        })
    }
}

/// Figures of one service over all its instances (a restart or a swap starts a new instance, same name).
#[derive(Debug)]
struct ProcessAcc {
    /// The latest instance.
    pid: u32,
    input_topic: String,
    output_topic: String,
    messages: u64,
    /// Per instance, its latest running count of missing input messages (summed in the report).
    dropped_by_pid: BTreeMap<u32, u64>,
    cpu_time_ns: u64,
    processing: Histogram<u64>,
    queue_wait: Histogram<u64>,
    age: Histogram<u64>,
    first_done_ns: u64,
    last_done_ns: u64,
    /// How the latest instance ended.
    ended: Option<TelemetryKind>,
    instances: u32,
    /// The highest message id (frame sequence number or keyframe id) any instance has handled.
    last_item: Option<u64>,
    /// What the latest instance restored from a save (it has every message up to this one).
    restored: Option<u64>,
    /// Input samples refused by validation, per `topic/reason`, over all instances.
    rejected: BTreeMap<String, u64>,
}

/// One process instance: readiness, liveness and record numbering are per process, not per service name.
#[derive(Debug)]
struct InstanceAcc {
    ready: bool,
    ended: Option<TelemetryKind>,
    next_record_seq: u64,
    /// When the launcher last heard from it (any record), for the liveness deadline.
    last_heard: std::time::Instant,
    last_item: Option<u64>,
}

/// Collects telemetry for one run.
#[derive(Debug, Default)]
pub struct LatencyAggregator {
    processes: BTreeMap<String, ProcessAcc>,
    instances: BTreeMap<u32, InstanceAcc>,
    /// (topic, consumer) → receive − publish.
    hops: BTreeMap<(String, String), Histogram<u64>>,
    records_lost: u64,
    /// Telemetry records that were not records (unknown kind, no process name): refused here.
    records_refused: u64,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ProcessReport {
    pub name: String,
    pub pid: u32,
    pub input_topic: String,
    pub output_topic: String,
    pub messages: u64,
    /// Input messages the process saw missing (sequence gaps).
    pub dropped: u64,
    pub rate_hz: f64,
    pub cpu_time_s: f64,
    /// done − receive (for a source: done − capture).
    pub processing_us: Option<Percentiles>,
    /// receive − upstream publish.
    pub queue_wait_us: Option<Percentiles>,
    /// done − capture: age of the output when it leaves the process.
    pub age_us: Option<Percentiles>,
    /// `finished`, `failed` or `no end record` (crashed or killed), of the latest instance.
    pub ended: String,
    /// Instances after the first (restarts and swaps).
    #[serde(default)]
    pub restarts: u32,
    /// Input samples the process refused (validation at the shared-memory boundary), per `topic/reason`.
    #[serde(default)]
    pub rejected: BTreeMap<String, u64>,
}

impl ProcessReport {
    /// Input samples refused, all topics and reasons.
    pub fn rejected_total(&self) -> u64 {
        self.rejected.values().sum()
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct HopReport {
    pub from: String,
    pub to: String,
    pub topic: String,
    pub latency_us: Percentiles,
}

/// An end-to-end figure: from a frame's capture to a result (`capture → pose`, `capture → map`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct EndToEndReport {
    pub path: String,
    /// The process whose output ends the path.
    pub process: String,
    pub latency_us: Percentiles,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct LatencyReport {
    pub processes: Vec<ProcessReport>,
    pub hops: Vec<HopReport>,
    /// capture → pose (the tracker's pose published) and capture → map (the mosaic has taken the keyframe in).
    #[serde(default)]
    pub end_to_end: Vec<EndToEndReport>,
    /// Telemetry records the launcher missed (gaps in record sequence numbers): figures are then partial.
    pub telemetry_records_lost: u64,
    /// Telemetry records refused as malformed (unknown kind, no process name).
    #[serde(default)]
    pub telemetry_records_refused: u64,
}

impl LatencyAggregator {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn record(&mut self, r: &TelemetryRecord) {
        let kind = match bdis_ipc::telemetry::validate(r) {
            Ok(kind) => kind,
            Err(e) => {
                if self.records_refused == 0 {
                    tracing::warn!("telemetry: refused: {e}; further refusals are counted in latency.json");
                }
                self.records_refused += 1;
                return;
            }
        };
        let now = std::time::Instant::now();
        let instance = self.instances.entry(r.pid).or_insert_with(|| InstanceAcc {
            ready: false,
            ended: None,
            next_record_seq: r.record_seq,
            last_heard: now,
            last_item: None,
        });
        if r.record_seq > instance.next_record_seq {
            self.records_lost += r.record_seq - instance.next_record_seq;
        }
        instance.next_record_seq = instance.next_record_seq.max(r.record_seq + 1);
        instance.last_heard = now;
        let acc = self.processes.entry(r.process().to_string()).or_insert_with(|| ProcessAcc {
            pid: r.pid,
            input_topic: r.input_topic().to_string(),
            output_topic: r.output_topic().to_string(),
            messages: 0,
            dropped_by_pid: BTreeMap::new(),
            cpu_time_ns: 0,
            processing: histogram(),
            queue_wait: histogram(),
            age: histogram(),
            first_done_ns: 0,
            last_done_ns: 0,
            ended: None,
            instances: 1,
            last_item: None,
            restored: None,
            rejected: BTreeMap::new(),
        });
        if kind == TelemetryKind::Ready && r.pid != acc.pid {
            // A new instance (restart or swap) takes over the name.
            acc.pid = r.pid;
            acc.instances += 1;
            acc.ended = None;
            // A replacement may be started with other arguments (another input, say).
            acc.input_topic = r.input_topic().to_string();
            acc.output_topic = r.output_topic().to_string();
            // What this instance has is what it restored, not what its predecessor had taken in.
            acc.last_item = r.restored();
            acc.restored = r.restored();
        } else if kind == TelemetryKind::Ready && acc.last_item.is_none() {
            acc.last_item = r.restored();
            acc.restored = r.restored();
        }
        match kind {
            TelemetryKind::Ready => instance.ready = true,
            TelemetryKind::Heartbeat => {}
            TelemetryKind::Rejected => {
                let reason = bdis_ipc::validate::Reason::from_u32(r.reason).map_or("unknown", |r| r.name());
                *acc.rejected.entry(format!("{}/{reason}", r.input_topic())).or_default() += 1;
            }
            TelemetryKind::Message => {
                instance.last_item = Some(instance.last_item.map_or(r.frame_seq, |l| l.max(r.frame_seq)));
                acc.last_item = Some(acc.last_item.map_or(r.frame_seq, |l| l.max(r.frame_seq)));
                acc.messages += 1;
                acc.dropped_by_pid.insert(r.pid, r.dropped);
                let _ = acc.processing.record(r.processing_ns().max(1));
                if r.t_capture_ns != 0 {
                    let _ = acc.age.record(r.age_ns().max(1));
                }
                if r.t_upstream_publish_ns != 0 {
                    let wait = r.queue_wait_ns().max(1);
                    let _ = acc.queue_wait.record(wait);
                    let _ = self
                        .hops
                        .entry((r.input_topic().to_string(), r.process().to_string()))
                        .or_insert_with(histogram)
                        .record(wait);
                }
                if acc.first_done_ns == 0 {
                    acc.first_done_ns = r.t_done_ns;
                }
                acc.last_done_ns = r.t_done_ns;
            }
            TelemetryKind::Finished | TelemetryKind::Failed => {
                // The final count: inputs seen missing only at the end of the stream (its number tells).
                if r.dropped > 0 {
                    acc.dropped_by_pid.insert(r.pid, r.dropped);
                }
                instance.ended = Some(kind);
                if r.pid == acc.pid {
                    acc.ended = Some(kind);
                }
                acc.cpu_time_ns += r.cpu_time_ns;
            }
        }
    }

    pub fn report(&self) -> LatencyReport {
        let processes = self
            .processes
            .iter()
            .map(|(name, p)| {
                let span_s = (p.last_done_ns.saturating_sub(p.first_done_ns)) as f64 / 1e9;
                ProcessReport {
                    name: name.clone(),
                    pid: p.pid,
                    input_topic: p.input_topic.clone(),
                    output_topic: p.output_topic.clone(),
                    messages: p.messages,
                    dropped: p.dropped_by_pid.values().sum(),
                    rate_hz: if p.messages > 1 && span_s > 0.0 { (p.messages - 1) as f64 / span_s } else { 0.0 },
                    cpu_time_s: p.cpu_time_ns as f64 / 1e9,
                    processing_us: Percentiles::of(&p.processing),
                    queue_wait_us: Percentiles::of(&p.queue_wait),
                    age_us: Percentiles::of(&p.age),
                    ended: match p.ended {
                        Some(TelemetryKind::Finished) => "finished",
                        Some(TelemetryKind::Failed) => "failed",
                        _ => "no end record",
                    }
                    .to_string(),
                    restarts: p.instances - 1,
                    rejected: p.rejected.clone(),
                }
            })
            .collect();
        let hops = self
            .hops
            .iter()
            .filter_map(|((topic, to), h)| {
                // A process declares one output topic; the tracker's is keyframes, and its poses and corrections
                // come from the same process.
                let declared = match topic.as_str() {
                    "poses" | "corrections" => "keyframes",
                    other => other,
                };
                let from = self
                    .processes
                    .iter()
                    .find(|(_, p)| p.output_topic == topic.as_str() || p.output_topic == declared)
                    .map_or_else(|| "?".to_string(), |(n, _)| n.clone());
                Percentiles::of(h).map(|latency_us| HopReport {
                    from,
                    to: to.clone(),
                    topic: topic.clone(),
                    latency_us,
                })
            })
            .collect();
        let end_to_end = self
            .processes
            .iter()
            .filter_map(|(name, p)| {
                // The tracker publishes poses and keyframes (its telemetry names the keyframes topic); the map's
                // owner consumes depth and publishes nothing. Probes only watch.
                // A bridge's sending side (bdis-bridge send) also consumes depth and publishes nothing here: what
                // it measures is the depth handed to the link (the map is made on the other host).
                let path = if p.output_topic == "keyframes" && p.input_topic == "frames" {
                    "capture → pose"
                } else if p.input_topic == "depth" && p.output_topic.is_empty() && name.starts_with("bridge") {
                    "capture → bridge"
                } else if p.input_topic == "depth" && p.output_topic.is_empty() && !name.starts_with("probe") {
                    "capture → map"
                } else {
                    return None;
                };
                Percentiles::of(&p.age).map(|latency_us| EndToEndReport {
                    path: path.into(),
                    process: name.clone(),
                    latency_us,
                })
            })
            .collect();
        LatencyReport {
            processes,
            hops,
            end_to_end,
            telemetry_records_lost: self.records_lost,
            telemetry_records_refused: self.records_refused,
        }
    }
}

impl LatencyReport {
    /// The table printed at the end of a run.
    pub fn table(&self) -> String {
        let ms = |p: &Option<Percentiles>| {
            p.map_or_else(|| "-".to_string(), |p| format!("{:.3} / {:.3}", p.p50 / 1000.0, p.p99 / 1000.0))
        };
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{:<14} {:>6} {:>8} {:>7} {:>18} {:>18} {:>18} {:>7} {:>8}",
            "process",
            "msgs",
            "rate Hz",
            "dropped",
            "processing ms",
            "queue wait ms",
            "output age ms",
            "cpu s",
            "restarts"
        );
        let _ = writeln!(
            out,
            "{:<14} {:>6} {:>8} {:>7} {:>18} {:>18} {:>18} {:>7} {:>8}",
            "", "", "", "", "p50 / p99", "p50 / p99", "p50 / p99", "", ""
        );
        for p in &self.processes {
            let _ = writeln!(
                out,
                "{:<14} {:>6} {:>8.1} {:>7} {:>18} {:>18} {:>18} {:>7.2} {:>8}",
                p.name,
                p.messages,
                p.rate_hz,
                p.dropped,
                ms(&p.processing_us),
                ms(&p.queue_wait_us),
                ms(&p.age_us),
                p.cpu_time_s,
                p.restarts
            );
        }
        let refused: Vec<(&str, &str, u64)> = self
            .processes
            .iter()
            .flat_map(|p| p.rejected.iter().map(move |(k, n)| (p.name.as_str(), k.as_str(), *n)))
            .collect();
        if !refused.is_empty() || self.telemetry_records_refused > 0 {
            let _ = writeln!(out);
            let _ = writeln!(out, "{:<14} {:<34} {:>8}", "refused by", "topic/reason", "samples");
            for (process, what, n) in refused {
                let _ = writeln!(out, "{process:<14} {what:<34} {n:>8}");
            }
            if self.telemetry_records_refused > 0 {
                let _ = writeln!(
                    out,
                    "{:<14} {:<34} {:>8}",
                    "launcher", "telemetry/unknown-value", self.telemetry_records_refused
                );
            }
        }
        if !self.end_to_end.is_empty() {
            let _ = writeln!(out);
            let _ = writeln!(
                out,
                "{:<34} {:>6} {:>9} {:>9} {:>9} {:>9}",
                "end to end", "msgs", "p50 ms", "p90 ms", "p99 ms", "max ms"
            );
            for e in &self.end_to_end {
                let _ = writeln!(
                    out,
                    "{:<34} {:>6} {:>9.2} {:>9.2} {:>9.2} {:>9.2}",
                    format!("{} ({})", e.path, e.process),
                    e.latency_us.count,
                    e.latency_us.p50 / 1000.0,
                    e.latency_us.p90 / 1000.0,
                    e.latency_us.p99 / 1000.0,
                    e.latency_us.max / 1000.0
                );
            }
        }
        if !self.hops.is_empty() {
            let _ = writeln!(out);
            let _ = writeln!(
                out,
                "{:<34} {:>6} {:>9} {:>9} {:>9} {:>9}",
                "hop (topic)", "msgs", "p50 µs", "p90 µs", "p99 µs", "max µs"
            );
            for h in &self.hops {
                let _ = writeln!(
                    out,
                    "{:<34} {:>6} {:>9.1} {:>9.1} {:>9.1} {:>9.1}",
                    format!("{}→{} ({})", h.from, h.to, h.topic),
                    h.latency_us.count,
                    h.latency_us.p50,
                    h.latency_us.p90,
                    h.latency_us.p99,
                    h.latency_us.max
                );
            }
        }
        if self.telemetry_records_lost > 0 {
            let _ =
                writeln!(out, "note: {} telemetry records were lost; figures are partial", self.telemetry_records_lost);
        }
        out
    }
}

#[cfg(test)]
mod tests;
