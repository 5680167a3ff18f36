//! One run of a pipeline: start services downstream first (each after the one below it reports ready), let the
//! stream flow to its end, stop in order, and report.

use std::path::Path;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::latency::LatencyReport;
use crate::launch_file::{LaunchFile, ResolvedService};
use crate::supervisor::{PumpEnd, SuperviseError, Supervisor};

/// How one service ended.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ServiceResult {
    pub name: String,
    pub pid: u32,
    pub core: Option<usize>,
    pub exit: String,
    pub ok: bool,
    /// Its last error line, when it failed.
    pub error: Option<String>,
    pub log: String,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct RunResult {
    pub services: Vec<ServiceResult>,
    pub latency: LatencyReport,
    pub stop_requested: bool,
    /// Why the run failed, in one line; `None` when every service finished normally.
    pub failure: Option<String>,
    pub duration_s: f64,
}

/// Runs `services` (pipeline order, upstream first) with the timeouts of `launch.run`.
pub fn execute(
    launch: &LaunchFile,
    services: &[ResolvedService],
    prefix: &str,
    run_dir: &Path,
) -> Result<RunResult, SuperviseError> {
    let started = std::time::Instant::now();
    let mut sup = Supervisor::new(prefix, run_dir)?;
    let ready_timeout = Duration::from_secs_f64(launch.run.ready_timeout_s);
    let drain_timeout = Duration::from_secs_f64(launch.run.drain_timeout_s);
    let grace = Duration::from_secs_f64(launch.run.stop_grace_s);
    let mut failure: Option<String> = None;
    let mut stop_requested = false;

    // Downstream first: a consumer's subscription exists before its producer sends the first frame.
    for service in services.iter().rev() {
        let index = sup.spawn(service)?;
        let name = service.spec.name.clone();
        let end = sup.pump(ready_timeout, |s| s.latency.is_ready(&name) || !s.children[index].is_running())?;
        let child = &sup.children[index];
        match end {
            PumpEnd::StopRequested => {
                stop_requested = true;
                break;
            }
            PumpEnd::Timeout => {
                failure = Some(format!("{name} did not report ready within {:.0} s", ready_timeout.as_secs_f64()));
                break;
            }
            PumpEnd::Done if !sup.latency.is_ready(&name) => {
                failure = Some(format!(
                    "{name} ended before it was ready ({}): {}",
                    child.exit_text(),
                    child.last_error_line().unwrap_or_default()
                ));
                break;
            }
            PumpEnd::Done => {}
        }
    }

    // Upstream-first order of the children (they were started in reverse).
    let order: Vec<usize> = {
        let mut by_service: Vec<usize> = (0..sup.children.len()).collect();
        by_service.sort_by_key(|&i| services.iter().position(|s| s.spec.name == sup.children[i].name));
        by_service
    };

    if failure.is_none() && !stop_requested {
        // Flow until everything has ended. A service whose upstreams have all ended gets `drain_timeout` to
        // finish its stream, then is stopped.
        let mut drain_deadline: Vec<Option<std::time::Instant>> = vec![None; order.len()];
        loop {
            let now = std::time::Instant::now();
            let mut next_wake = Duration::from_secs(3600);
            for (pos, &i) in order.iter().enumerate() {
                if !sup.children[i].is_running() {
                    continue;
                }
                let upstream_done = order[..pos].iter().all(|&j| !sup.children[j].is_running());
                if pos > 0 && upstream_done {
                    let deadline = *drain_deadline[pos].get_or_insert(now + drain_timeout);
                    if now >= deadline {
                        tracing::warn!(
                            "{} did not finish within {:.0} s of its upstream; stopping it",
                            sup.children[i].name,
                            drain_timeout.as_secs_f64()
                        );
                        sup.stop_in_order(&[i], grace)?;
                    } else {
                        next_wake = next_wake.min(deadline - now);
                    }
                }
            }
            if order.iter().all(|&i| !sup.children[i].is_running()) {
                break;
            }
            let running_before: Vec<bool> = sup.children.iter().map(|c| c.is_running()).collect();
            let end = sup
                .pump(next_wake, |s| s.children.iter().zip(&running_before).any(|(c, &was)| was && !c.is_running()))?;
            if end == PumpEnd::StopRequested {
                stop_requested = true;
                break;
            }
            // A service that fails breaks the pipeline: stop the rest in order and report it.
            if let Some(c) = sup.children.iter().find(|c| !c.is_running() && !c.succeeded()) {
                failure =
                    Some(format!("{} failed ({}): {}", c.name, c.exit_text(), c.last_error_line().unwrap_or_default()));
                break;
            }
        }
    }
    if stop_requested {
        tracing::info!("stop requested: stopping services upstream first");
    }
    sup.stop_in_order(&order, grace)?;
    if failure.is_none()
        && let Some(c) = sup.children.iter().find(|c| !c.succeeded())
    {
        failure = Some(format!("{} failed ({}): {}", c.name, c.exit_text(), c.last_error_line().unwrap_or_default()));
    }
    // Crashed children leave their nodes behind; reclaim them now rather than at the next run's start.
    sup.cleanup_dead();

    let mut results: Vec<ServiceResult> = order
        .iter()
        .map(|&i| {
            let c = &sup.children[i];
            ServiceResult {
                name: c.name.clone(),
                pid: c.pid,
                core: c.core,
                exit: c.exit_text(),
                ok: c.succeeded(),
                error: (!c.succeeded()).then(|| c.last_error_line()).flatten(),
                log: c.log.display().to_string(),
            }
        })
        .collect();
    // Services that never started (a failure before their turn) are listed too.
    for s in services {
        if !results.iter().any(|r| r.name == s.spec.name) {
            results.push(ServiceResult {
                name: s.spec.name.clone(),
                pid: 0,
                core: s.spec.core,
                exit: "not started".into(),
                ok: false,
                error: None,
                log: String::new(),
            });
        }
    }
    results.sort_by_key(|r| services.iter().position(|s| s.spec.name == r.name));
    Ok(RunResult {
        services: results,
        latency: sup.latency.report(),
        stop_requested,
        failure,
        duration_s: started.elapsed().as_secs_f64(),
    })
}
