//! `bdis-slam bench isolation`: does the dense mapper slow the tracker? Alternating runs with the tracker alone
//! and with the dense side on the other core.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};

use crate::plan::plan_for_sequence;
use crate::run_cmd::{execute_and_write, make_run_dir};

#[derive(Debug, clap::Subcommand)]
pub enum BenchCommand {
    /// Does the dense mapper slow the tracker? Runs the sequence alternately with the tracker alone
    /// (acquisition → tracking) and with the dense stereo and the mosaic on the other core, and reports the
    /// tracker's time per frame in both (median of the per-pair ratios, and their spread).
    Isolation(IsolationArgs),
}

#[derive(Debug, clap::Args)]
pub struct IsolationArgs {
    /// Sequence folder (a synthetic one comes with its settings.yaml).
    #[arg(long)]
    sequence: PathBuf,
    /// Settings (default: the sequence's settings.yaml).
    #[arg(long)]
    settings: Option<PathBuf>,
    /// Pairs of runs (alone, with the dense mapper), in alternating order.
    #[arg(long, default_value_t = 3)]
    pairs: usize,
    /// Folder for the runs and isolation.json (default: runs/<UTC time>-isolation).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Run the live viewer too, beside the dense side (on a free local port), to measure what it costs the
    /// tracker; its own CPU is in each run's latency report.
    #[arg(long)]
    view: bool,
}

/// The tracker's figures of one benchmark run.
#[derive(Debug, Clone, Copy, serde::Serialize)]
struct TrackerTimes {
    with_dense: bool,
    /// Wall time per frame in the tracking process (receive → poses published), µs.
    wall_p50_us: f64,
    wall_p99_us: f64,
    /// Tracking-thread CPU per frame without a new keyframe (tracking.json), ms.
    cpu_p50_ms: f64,
}

/// `isolation.json` (`bdis.v1.isolation`): the runs and the with-dense / alone ratios of the tracker's times.
#[derive(Debug, serde::Serialize)]
struct IsolationReport {
    schema: &'static str,
    sequence: PathBuf,
    pairs: usize,
    runs: Vec<TrackerTimes>,
    wall_p50_ratio: Spread,
    wall_p99_ratio: Spread,
    cpu_p50_ratio: Spread,
}

/// A ratio over the pairs: its median and range.
#[derive(Debug, serde::Serialize)]
struct Spread {
    median: f64,
    min: f64,
    max: f64,
}

pub fn bench_isolation(args: IsolationArgs) -> Result<ExitCode> {
    anyhow::ensure!((1..=50).contains(&args.pairs), "--pairs: give 1 to 50");
    let settings = args.settings.clone().unwrap_or_else(|| args.sequence.join("settings.yaml"));
    let mut full = plan_for_sequence(
        crate::plan::PlanInput::new(&args.sequence, Some(&settings)),
        bdis_source::Pacing::OnDemand,
        false,
        None,
        true,
        &[],
    )?;
    if args.view {
        crate::plan::add_viewer(&mut full, "127.0.0.1:0")?;
    }
    let mut alone = full.clone();
    alone.services.retain(|s| s.name == "acquisition" || s.name == "tracking");
    let root = make_run_dir(args.out.as_deref(), "isolation")?;
    let bar = bdis_slam::progress::bar(2 * args.pairs as u64, "isolation {bar:30} {pos}/{len} runs ({eta} left) {msg}");
    let mut runs: Vec<TrackerTimes> = Vec::new();
    for pair in 0..args.pairs {
        // Alternate the order (ABBA…) so a drift in the host's load does not favour one side.
        let order = if pair % 2 == 0 { [false, true] } else { [true, false] };
        for with_dense in order {
            let tag = format!("{pair}-{}", if with_dense { "with-dense" } else { "alone" });
            bar.set_message(tag.clone());
            let run_dir = root.join(&tag);
            std::fs::create_dir_all(&run_dir)
                .with_context(|| format!("{}: cannot create the run folder", run_dir.display()))?;
            let plan = if with_dense { &full } else { &alone };
            let (code, result) = execute_and_write(plan, Path::new("launch.toml"), &run_dir, None, false)?;
            if code != ExitCode::SUCCESS {
                anyhow::bail!("run {tag} failed: {}", result.failure.unwrap_or_default());
            }
            let tracking = result
                .latency
                .processes
                .iter()
                .find(|p| p.name == "tracking")
                .and_then(|p| p.processing_us)
                .with_context(|| format!("run {tag}: no tracking figures"))?;
            let summary = bdis_core::formats::summary::TrackingSummary::read(&run_dir.join("tracking.json"))?;
            runs.push(TrackerTimes {
                with_dense,
                wall_p50_us: tracking.p50,
                wall_p99_us: tracking.p99,
                cpu_p50_ms: summary.frame_cpu_ms_p50.unwrap_or(f64::NAN),
            });
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    let ratios = |f: fn(&TrackerTimes) -> f64| -> Vec<f64> {
        runs.chunks(2)
            .map(|pair| {
                let (a, b) = if pair[0].with_dense { (&pair[1], &pair[0]) } else { (&pair[0], &pair[1]) };
                f(b) / f(a)
            })
            .collect()
    };
    let median = |mut v: Vec<f64>| {
        let p50 = bdis_core::stats::percentile(&mut v, 0.5).unwrap_or(f64::NAN);
        let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| (lo.min(x), hi.max(x)));
        (p50, lo, hi)
    };
    let (p50_ratio, p50_lo, p50_hi) = median(ratios(|t| t.wall_p50_us));
    let (p99_ratio, p99_lo, p99_hi) = median(ratios(|t| t.wall_p99_us));
    let (cpu_ratio, cpu_lo, cpu_hi) = median(ratios(|t| t.cpu_p50_ms));
    println!("{:<6} {:<11} {:>16} {:>16} {:>18}", "pair", "dense", "wall p50 ms", "wall p99 ms", "thread CPU p50 ms");
    for (i, t) in runs.iter().enumerate() {
        println!(
            "{:<6} {:<11} {:>16.2} {:>16.2} {:>18.2}",
            i / 2,
            if t.with_dense { "other core" } else { "off" },
            t.wall_p50_us / 1000.0,
            t.wall_p99_us / 1000.0,
            t.cpu_p50_ms
        );
    }
    println!();
    println!("tracker with the dense mapper on the other core / alone (median of {} pairs, [min, max]):", args.pairs);
    println!(
        "  wall per frame p50  {:+.1} %  [{:+.1}, {:+.1}]",
        100.0 * (p50_ratio - 1.0),
        100.0 * (p50_lo - 1.0),
        100.0 * (p50_hi - 1.0)
    );
    println!(
        "  wall per frame p99  {:+.1} %  [{:+.1}, {:+.1}]",
        100.0 * (p99_ratio - 1.0),
        100.0 * (p99_lo - 1.0),
        100.0 * (p99_hi - 1.0)
    );
    println!(
        "  thread CPU p50      {:+.1} %  [{:+.1}, {:+.1}]",
        100.0 * (cpu_ratio - 1.0),
        100.0 * (cpu_lo - 1.0),
        100.0 * (cpu_hi - 1.0)
    );
    let json = IsolationReport {
        schema: "bdis.v1.isolation",
        sequence: args.sequence.clone(),
        pairs: args.pairs,
        runs,
        wall_p50_ratio: Spread { median: p50_ratio, min: p50_lo, max: p50_hi },
        wall_p99_ratio: Spread { median: p99_ratio, min: p99_lo, max: p99_hi },
        cpu_p50_ratio: Spread { median: cpu_ratio, min: cpu_lo, max: cpu_hi },
    };
    let path = root.join("isolation.json");
    std::fs::write(&path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("{}: cannot write", path.display()))?;
    println!("runs and isolation.json in {}", root.display());
    Ok(ExitCode::SUCCESS)
}
