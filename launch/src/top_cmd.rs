//! `bdis-slam top`: a live view of a running pipeline — every service's rate, latency, CPU, core and restarts — read from
//! the run's telemetry topic and /proc, redrawn in place on a terminal.

use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::time::Duration;

use anyhow::{Result, anyhow, bail};
use bdis_ipc::Ipc;
use bdis_slam::latency::LatencyAggregator;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

#[derive(Debug, clap::Args)]
pub struct TopArgs {
    /// Seconds between refreshes.
    #[arg(long, default_value_t = 1.0)]
    interval: f64,
    /// Stop after this many refreshes (default: until Ctrl-C).
    #[arg(long)]
    iterations: Option<u64>,
    /// Name of this process.
    #[arg(long, default_value = "top")]
    name: String,
    /// Shared-memory name prefix of the run to watch (printed by `bdis-slam run`, or BDIS_IPC_PREFIX).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
    /// The run folder of the pipeline (instead of --ipc-prefix: the launcher writes its prefix there).
    #[arg(long, value_name = "DIR")]
    run: Option<std::path::PathBuf>,
}

/// CPU time (user + system, clock ticks) and the core a process last ran on, from /proc/<pid>/stat.
fn proc_stat(pid: u32) -> Option<(u64, u32)> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name is in parentheses and may contain spaces: fields are counted after the last ')'.
    let rest = &text[text.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // After the name: state is field 3 → index 0; utime 14 → 11, stime 15 → 12, processor 39 → 36.
    let utime: u64 = fields.get(11)?.parse().ok()?;
    let stime: u64 = fields.get(12)?.parse().ok()?;
    let core: u32 = fields.get(36)?.parse().ok()?;
    Some((utime + stime, core))
}

pub fn top(mut args: TopArgs) -> Result<()> {
    if let Some(dir) = &args.run {
        args.ipc_prefix = bdis_slam::run_dir::prefix_of_run(dir).map_err(anyhow::Error::msg)?;
    }
    if !(args.interval.is_finite() && args.interval >= 0.05) {
        bail!("--interval: give at least 0.05 s, found {}", args.interval);
    }
    let ipc = Ipc::open(&args.name, &args.ipc_prefix)?;
    let service = ipc.telemetry()?;
    let subscriber = ipc.telemetry_subscriber(&service)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| anyhow!("create a WaitSet: {e:?}"))?;
    let interval = Duration::from_secs_f64(args.interval);
    let _tick = waitset.attach_interval(interval).map_err(|e| anyhow!("attach a tick: {e:?}"))?;
    // SAFETY: sysconf has no preconditions.
    let ticks_per_s = unsafe { libc::sysconf(libc::_SC_CLK_TCK) }.max(1) as f64;
    let terminal = std::io::stdout().is_terminal();
    let mut aggregator = LatencyAggregator::new();
    let mut last_messages: BTreeMap<String, u64> = BTreeMap::new();
    let mut last_cpu: BTreeMap<u32, u64> = BTreeMap::new();
    let mut refreshes = 0u64;
    loop {
        let result =
            waitset.wait_and_process_once(|_| CallbackProgression::Continue).map_err(|e| anyhow!("wait: {e:?}"))?;
        if matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt) {
            return Ok(());
        }
        while let Ok(Some(record)) = subscriber.receive() {
            aggregator.record(&record);
        }
        let report = aggregator.report();
        let mut out = String::new();
        if terminal {
            out += "\x1b[H\x1b[2J";
        }
        out += &format!(
            "bdis-slam top — run prefix {} — every {:.1} s (Ctrl-C to quit)\n\n",
            args.ipc_prefix, args.interval
        );
        out += &format!(
            "{:<14} {:>7} {:>4} {:>6} {:>8} {:>8} {:>7} {:>7} {:>16} {:>16} {:>8} {:>9}\n",
            "process",
            "pid",
            "core",
            "CPU %",
            "rate Hz",
            "msgs",
            "dropped",
            "refused",
            "processing ms",
            "output age ms",
            "restarts",
            "state"
        );
        out += &format!(
            "{:<14} {:>7} {:>4} {:>6} {:>8} {:>8} {:>7} {:>7} {:>16} {:>16} {:>8} {:>9}\n",
            "", "", "", "", "now", "", "", "", "p50 / p99", "p50 / p99", "", ""
        );
        let ms = |p: Option<bdis_slam::latency::Percentiles>| {
            p.map_or_else(|| "-".to_string(), |p| format!("{:.2} / {:.2}", p.p50 / 1000.0, p.p99 / 1000.0))
        };
        for p in &report.processes {
            // Rates and CPU are over the last interval: nothing to show on a process's first refresh.
            let rate_now = match last_messages.insert(p.name.clone(), p.messages) {
                Some(previous) => format!("{:.1}", p.messages.saturating_sub(previous) as f64 / args.interval),
                None => "-".into(),
            };
            let (cpu, core) = match proc_stat(p.pid) {
                Some((ticks, core)) => {
                    let percent = last_cpu.insert(p.pid, ticks).map_or_else(
                        || "-".to_string(),
                        |before| {
                            format!("{:.0}", 100.0 * ticks.saturating_sub(before) as f64 / ticks_per_s / args.interval)
                        },
                    );
                    (percent, core.to_string())
                }
                None => ("-".into(), "-".into()),
            };
            // Ready records may predate this viewer (they are not kept): a process sending messages is running.
            let state = match aggregator.ended(&p.name) {
                Some(kind) => format!("{kind:?}").to_lowercase(),
                None if aggregator.is_ready(&p.name) || p.messages > 0 => "running".into(),
                None => "starting".into(),
            };
            out += &format!(
                "{:<14} {:>7} {:>4} {:>6} {:>8} {:>8} {:>7} {:>7} {:>16} {:>16} {:>8} {:>9}\n",
                p.name,
                p.pid,
                core,
                cpu,
                rate_now,
                p.messages,
                p.dropped,
                p.rejected_total(),
                ms(p.processing_us),
                ms(p.age_us),
                // Instances seen starting (a swap or a restart) since this view started.
                p.restarts,
                state
            );
        }
        if report.processes.is_empty() {
            out += "(no telemetry yet: is a pipeline running with this prefix?)\n";
        }
        if !report.hops.is_empty() {
            out += "\nhop (topic)                          p50 µs    p99 µs\n";
            for h in &report.hops {
                out += &format!(
                    "{:<34} {:>9.1} {:>9.1}\n",
                    format!("{}→{} ({})", h.from, h.to, h.topic),
                    h.latency_us.p50,
                    h.latency_us.p99
                );
            }
        }
        if !terminal {
            out += "\n";
        }
        let mut stdout = std::io::stdout().lock();
        stdout.write_all(out.as_bytes()).and_then(|()| stdout.flush()).map_err(|e| anyhow!("stdout: {e}"))?;
        refreshes += 1;
        if args.iterations.is_some_and(|n| refreshes >= n) {
            return Ok(());
        }
    }
}
