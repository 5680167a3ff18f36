//! Aggregates telemetry records into per-process and per-hop latency figures (p50/p90/p99/max), the
//! `latency.json` of a run and the table the launcher prints.

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
}

impl LatencyAggregator {
    pub fn new() -> Self {
        Self::default()
    }

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

    pub fn record(&mut self, r: &TelemetryRecord) {
        let Some(kind) = r.kind() else { return };
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
                }
            })
            .collect();
        let hops = self
            .hops
            .iter()
            .filter_map(|((topic, to), h)| {
                let from = self
                    .processes
                    .iter()
                    .find(|(_, p)| &p.output_topic == topic)
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
                let path = if p.output_topic == "keyframes" && p.input_topic == "frames" {
                    "capture → pose"
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
        LatencyReport { processes, hops, end_to_end, telemetry_records_lost: self.records_lost }
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

/// One row of a latency chart: a label and percentiles in µs.
struct ChartRow<'a> {
    label: String,
    p: &'a Percentiles,
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

/// A horizontal log-scale chart: per row a bar to p50, a whisker to p99 and a mark at max.
fn chart(out: &mut String, title: &str, rows: &[ChartRow], y0: f64) -> f64 {
    const LEFT: f64 = 250.0;
    const WIDTH: f64 = 560.0;
    const ROW: f64 = 22.0;
    let _ = writeln!(out, r#"<text x="10" y="{:.0}" class="title">{}</text>"#, y0 + 16.0, xml_escape(title));
    if rows.is_empty() {
        return y0 + 30.0;
    }
    // Decades from below the smallest p50 to above the largest max.
    let lo = rows.iter().map(|r| r.p.p50.max(0.1)).fold(f64::INFINITY, f64::min).log10().floor();
    let hi = rows.iter().map(|r| r.p.max.max(r.p.p99).max(1.0)).fold(0.0, f64::max).log10().ceil().max(lo + 1.0);
    let x = |us: f64| LEFT + WIDTH * ((us.max(10f64.powf(lo)).log10() - lo) / (hi - lo)).clamp(0.0, 1.0);
    let top = y0 + 26.0;
    let bottom = top + ROW * rows.len() as f64;
    for d in lo as i32..=hi as i32 {
        let us = 10f64.powi(d);
        let label = if us >= 1000.0 { format!("{} ms", us / 1000.0) } else { format!("{us} µs") };
        let _ = writeln!(
            out,
            r#"<line x1="{0:.1}" y1="{top:.0}" x2="{0:.1}" y2="{bottom:.0}" class="grid"/><text x="{0:.1}" y="{1:.0}" class="axis">{label}</text>"#,
            x(us),
            bottom + 14.0
        );
    }
    for (i, r) in rows.iter().enumerate() {
        let y = top + ROW * i as f64;
        let _ = writeln!(
            out,
            r#"<text x="{:.0}" y="{:.0}" class="label">{}</text><rect x="{LEFT}" y="{:.0}" width="{:.1}" height="12" class="p50"><title>p50 {:.1} µs, p90 {:.1} µs, p99 {:.1} µs, max {:.1} µs</title></rect><line x1="{:.1}" y1="{:.0}" x2="{:.1}" y2="{:.0}" class="p99"/><line x1="{:.1}" y1="{:.0}" x2="{:.1}" y2="{:.0}" class="p99"/><circle cx="{:.1}" cy="{:.0}" r="2.5" class="max"/>"#,
            LEFT - 8.0,
            y + 11.0,
            xml_escape(&r.label),
            y + 2.0,
            (x(r.p.p50) - LEFT).max(1.0),
            r.p.p50,
            r.p.p90,
            r.p.p99,
            r.p.max,
            x(r.p.p50),
            y + 8.0,
            x(r.p.p99),
            y + 8.0,
            x(r.p.p99),
            y + 3.0,
            x(r.p.p99),
            y + 13.0,
            x(r.p.max),
            y + 8.0
        );
    }
    bottom + 24.0
}

impl LatencyReport {
    /// `latency.svg`: the table's figures to look at — per process the time spent on a message and the age of
    /// its output since capture, per hop the transport latency; bars to p50, whiskers to p99, dots at max, on a
    /// log scale (hover a bar for the numbers).
    pub fn svg(&self) -> String {
        let mut body = String::new();
        let processing: Vec<ChartRow> = self
            .processes
            .iter()
            .filter_map(|p| {
                p.processing_us.as_ref().map(|q| ChartRow { label: format!("{} ({} msgs)", p.name, p.messages), p: q })
            })
            .collect();
        let age: Vec<ChartRow> = self
            .processes
            .iter()
            .filter_map(|p| p.age_us.as_ref().map(|q| ChartRow { label: format!("{} output", p.name), p: q }))
            .collect();
        let hops: Vec<ChartRow> = self
            .hops
            .iter()
            .map(|h| ChartRow { label: format!("{}→{} ({})", h.from, h.to, h.topic), p: &h.latency_us })
            .collect();
        let end_to_end: Vec<ChartRow> = self
            .end_to_end
            .iter()
            .map(|e| ChartRow { label: format!("{} ({})", e.path, e.process), p: &e.latency_us })
            .collect();
        let mut y = 0.0;
        if !end_to_end.is_empty() {
            y = chart(&mut body, "End to end: from a frame's capture to its pose and to the map", &end_to_end, y);
        }
        y = chart(&mut body, "Processing per message (p50 bar, p99 whisker, max dot)", &processing, y);
        y = chart(&mut body, "Age of each process's output since capture", &age, y);
        y = chart(&mut body, "Transport latency per hop (publish → receive, zero copy)", &hops, y);
        format!(
            r#"<svg xmlns="http://www.w3.org/2000/svg" width="840" height="{:.0}" viewBox="0 0 840 {:.0}" font-family="sans-serif" font-size="12">
<style>.title{{font-weight:bold;font-size:13px}} .label{{text-anchor:end}} .axis{{text-anchor:middle;fill:#666;font-size:10px}} .grid{{stroke:#ddd}} .p50{{fill:#4a7fb5}} .p99{{stroke:#b5524a;stroke-width:1.5}} .max{{fill:#b5524a}}</style>
<rect width="100%" height="100%" fill="white"/>
{body}</svg>
"#,
            y, y
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(process: &str, kind: TelemetryKind, seq: u64, t: [u64; 4], input: &str, output: &str) -> TelemetryRecord {
        let mut r = TelemetryRecord { kind: kind as u32, pid: 7, record_seq: seq, ..Default::default() };
        r.process[..process.len()].copy_from_slice(process.as_bytes());
        r.input_topic[..input.len()].copy_from_slice(input.as_bytes());
        r.output_topic[..output.len()].copy_from_slice(output.as_bytes());
        [r.t_capture_ns, r.t_upstream_publish_ns, r.t_receive_ns, r.t_done_ns] = t;
        r
    }

    #[test]
    fn derives_hops_and_percentiles_and_counts_lost_records() {
        let mut agg = LatencyAggregator::new();
        agg.record(&rec("acq", TelemetryKind::Ready, 0, [0; 4], "", "frames"));
        agg.record(&rec("probe", TelemetryKind::Ready, 0, [0; 4], "frames", ""));
        for i in 0..100u64 {
            let t0 = 1_000_000_000 + i * 40_000_000;
            // acquisition: capture → publish takes 10 ms.
            agg.record(&rec("acq", TelemetryKind::Message, i + 1, [t0, 0, 0, t0 + 10_000_000], "", "frames"));
            // probe: receives 50 µs (+i ns) after publish, works 1 ms.
            let rx = t0 + 10_000_000 + 50_000 + i;
            if i != 50 {
                agg.record(&rec(
                    "probe",
                    TelemetryKind::Message,
                    i + 1 - u64::from(i > 50),
                    [t0, t0 + 10_000_000, rx, rx + 1_000_000],
                    "frames",
                    "",
                ));
            }
        }
        assert!(agg.is_ready("acq") && agg.is_ready("probe"));
        let report = agg.report();
        let hop = &report.hops[0];
        assert_eq!((hop.from.as_str(), hop.to.as_str(), hop.topic.as_str()), ("acq", "probe", "frames"));
        assert_eq!(hop.latency_us.count, 99);
        assert!((hop.latency_us.p50 - 50.0).abs() < 0.1, "{hop:?}");
        let acq = report.processes.iter().find(|p| p.name == "acq").unwrap();
        assert!((acq.processing_us.unwrap().p50 - 10_000.0).abs() < 10.0);
        assert!((acq.rate_hz - 25.0).abs() < 1e-6);
        let probe = report.processes.iter().find(|p| p.name == "probe").unwrap();
        assert!((probe.age_us.unwrap().p50 - 11_050.0).abs() < 15.0);
        assert_eq!(report.telemetry_records_lost, 0);
        // A gap in record numbers is reported.
        agg.record(&rec("acq", TelemetryKind::Finished, 105, [0; 4], "", "frames"));
        assert_eq!(agg.report().telemetry_records_lost, 4);
        assert!(agg.report().table().contains("acq→probe (frames)"));
    }

    #[test]
    fn instances_of_a_service_are_told_apart_for_readiness_liveness_and_resume_points() {
        let mut agg = LatencyAggregator::new();
        let with_pid = |mut r: TelemetryRecord, pid: u32, item: u64| {
            r.pid = pid;
            r.frame_seq = item;
            r
        };
        agg.record(&with_pid(rec("mosaic", TelemetryKind::Ready, 0, [0; 4], "depth", ""), 9, 0));
        agg.record(&with_pid(rec("stereo", TelemetryKind::Ready, 0, [0; 4], "keyframes", "depth"), 1, 0));
        for kf in 0..5u64 {
            let t = [1_000 + kf, 2_000, 3_000, 4_000 + kf];
            agg.record(&with_pid(rec("stereo", TelemetryKind::Message, kf + 1, t, "keyframes", "depth"), 1, kf));
            if kf < 3 {
                agg.record(&with_pid(rec("mosaic", TelemetryKind::Message, kf + 1, t, "depth", ""), 9, kf));
            }
        }
        // A replacement reports ready while the old instance still sends (make-before-break); its record
        // numbers start at 0 again without counting as lost.
        agg.record(&with_pid(rec("stereo", TelemetryKind::Ready, 0, [0; 4], "keyframes", "depth"), 2, 0));
        assert!(agg.is_pid_ready(2) && agg.is_pid_ready(1) && !agg.is_pid_ready(3));
        agg.record(&with_pid(rec("stereo", TelemetryKind::Heartbeat, 6, [0; 4], "keyframes", "depth"), 1, 0));
        assert_eq!(agg.last_item_of_pid(1), Some(4));
        assert_eq!(agg.last_item_of_pid(2), None);
        assert_eq!(agg.output_topic("stereo").as_deref(), Some("depth"));
        assert_eq!(agg.last_item_consumed("depth"), Some(2), "the mosaic took in keyframes 0–2");
        // Every consumer must have it: a probe that saw keyframes 0–4 does not move the resume point.
        agg.record(&with_pid(rec("probe", TelemetryKind::Ready, 0, [0; 4], "depth", ""), 11, 0));
        assert_eq!(agg.last_item_consumed("depth"), None, "the probe has nothing yet");
        for kf in 0..5u64 {
            agg.record(&with_pid(rec("probe", TelemetryKind::Message, kf + 1, [1, 2, 3, 4], "depth", ""), 11, kf));
        }
        assert_eq!(agg.last_item_consumed("depth"), Some(2));
        // A restarted mosaic has what it restored from its checkpoint, not what its predecessor had.
        let mut ready = with_pid(rec("mosaic", TelemetryKind::Ready, 0, [0; 4], "depth", ""), 12, 0);
        ready.restored_next = 2;
        agg.record(&ready);
        assert_eq!((agg.last_item_of("mosaic"), agg.last_item_consumed("depth")), (Some(1), Some(1)));
        // It then takes in keyframe 4 (sent while it was down, 2–3 lost): it still has everything up to 1 only.
        agg.record(&with_pid(rec("mosaic", TelemetryKind::Message, 1, [1, 2, 3, 4], "depth", ""), 12, 4));
        assert_eq!((agg.last_item_of("mosaic"), agg.restored_of("mosaic")), (Some(4), Some(1)));
        assert!(agg.has_consumer("depth") && !agg.has_consumer("poses"));
        assert!(agg.last_heard(1).is_some() && agg.last_heard(7).is_none());
        let report = agg.report();
        assert_eq!(report.telemetry_records_lost, 0);
        let stereo = report.processes.iter().find(|p| p.name == "stereo").unwrap();
        assert_eq!((stereo.restarts, stereo.pid, stereo.messages), (1, 2, 5));
        assert_eq!(report.end_to_end.len(), 1, "the mosaic's output age is capture → map");
        assert_eq!(report.end_to_end[0].path, "capture → map");
    }

    #[test]
    fn the_plot_has_a_bar_per_process_and_hop_scaled_by_p50() {
        let p = |p50: f64| Percentiles { count: 10, p50, p90: p50 * 2.0, p99: p50 * 3.0, max: p50 * 4.0, mean: p50 };
        let process = |name: &str, us: f64| ProcessReport {
            name: name.into(),
            pid: 1,
            input_topic: String::new(),
            output_topic: String::new(),
            messages: 10,
            dropped: 0,
            rate_hz: 30.0,
            cpu_time_s: 0.1,
            processing_us: Some(p(us)),
            queue_wait_us: None,
            age_us: Some(p(us * 2.0)),
            ended: "finished".into(),
            restarts: 0,
        };
        let report = LatencyReport {
            processes: vec![process("fast", 50.0), process("slow<&>", 20_000.0)],
            hops: vec![HopReport {
                from: "fast".into(),
                to: "slow<&>".into(),
                topic: "frames".into(),
                latency_us: p(80.0),
            }],
            end_to_end: Vec::new(),
            telemetry_records_lost: 0,
        };
        let svg = report.svg();
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches("class=\"p50\"").count(), 5, "2 processing + 2 age + 1 hop bars");
        assert!(svg.contains("slow&lt;&amp;&gt;") && !svg.contains("slow<&>"), "labels are escaped");
        let widths: Vec<f64> = svg
            .match_indices("class=\"p50\"")
            .map(|(i, _)| {
                let before = &svg[..i];
                let w = before.rfind("width=\"").unwrap() + 7;
                before[w..].split('"').next().unwrap().parse().unwrap()
            })
            .collect();
        assert!(widths[1] > widths[0], "the slower process has the longer bar: {widths:?}");
    }
}
