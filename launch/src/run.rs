//! One run of a pipeline: start services downstream first (each after the one below it reports ready), let the
//! stream flow to its end — restarting services that crash or hang under their policy, swapping a service when a
//! tool asks for it — stop in order, and report.

mod handover;

use handover::{replace, resume_point, resume_text, swap};

use std::collections::VecDeque;
use std::path::Path;
use std::time::{Duration, Instant};

use bdis_ipc::control::{Activation, ControlCommand, ControlResponse};
use serde::{Deserialize, Serialize};

use crate::latency::LatencyReport;
use crate::launch_file::{LaunchFile, ResolvedService, RestartPolicy};
use crate::supervisor::{ControlCall, PumpEnd, SuperviseError, Supervisor};

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
    /// Instances started after the first: restarts after a failure and swaps.
    #[serde(default)]
    pub restarts: u32,
    /// The instances it had before the last one, oldest first: `pid N: <how it ended> (<why>)`.
    #[serde(default)]
    pub earlier_instances: Vec<String>,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct RunResult {
    pub services: Vec<ServiceResult>,
    pub latency: LatencyReport,
    pub stop_requested: bool,
    /// Why the run failed, in one line; `None` when every service finished normally.
    pub failure: Option<String>,
    pub duration_s: f64,
    /// Every restart and swap, in order, one line each.
    #[serde(default)]
    pub events: Vec<String>,
}

/// `latency.json` (`bdis.v1.run`): how a run went — every service's end and restarts, the latency of every
/// process and hop, end to end, and the restarts and swaps as they happened.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunRecord {
    pub schema: String,
    pub name: String,
    pub ipc_prefix: String,
    pub duration_s: f64,
    pub stop_requested: bool,
    pub failure: Option<String>,
    pub services: Vec<ServiceResult>,
    pub processes: Vec<crate::latency::ProcessReport>,
    pub hops: Vec<crate::latency::HopReport>,
    pub end_to_end: Vec<crate::latency::EndToEndReport>,
    pub events: Vec<String>,
    pub telemetry_records_lost: u64,
    /// Telemetry records refused as malformed (see `LatencyReport::telemetry_records_refused`).
    #[serde(default)]
    pub telemetry_records_refused: u64,
}

impl RunRecord {
    pub const SCHEMA: &'static str = "bdis.v1.run";

    pub fn new(name: &str, ipc_prefix: &str, result: &RunResult) -> Self {
        Self {
            schema: Self::SCHEMA.to_string(),
            name: name.to_string(),
            ipc_prefix: ipc_prefix.to_string(),
            duration_s: result.duration_s,
            stop_requested: result.stop_requested,
            failure: result.failure.clone(),
            services: result.services.clone(),
            processes: result.latency.processes.clone(),
            hops: result.latency.hops.clone(),
            end_to_end: result.latency.end_to_end.clone(),
            events: result.events.clone(),
            telemetry_records_lost: result.latency.telemetry_records_lost,
            telemetry_records_refused: result.latency.telemetry_records_refused,
        }
    }
}

/// One service of the run and its current instance.
#[derive(Debug)]
struct Slot {
    service: ResolvedService,
    /// Index into the supervisor's children of the instance now in charge.
    current: Option<usize>,
    /// Every instance so far, oldest first.
    instances: Vec<usize>,
    /// Restarts within the policy's window (for max_restarts and the back-off).
    recent_restarts: VecDeque<Instant>,
    restarts: u32,
    restart_at: Option<Instant>,
    drain_deadline: Option<Instant>,
    /// The launcher is stopping it (drain timeout): its end is not restarted.
    stopping: bool,
    /// Keyframes up to this id were done by earlier instances (handover services).
    resume_floor: Option<u64>,
}

impl Slot {
    fn new(service: ResolvedService) -> Self {
        Self {
            service,
            current: None,
            instances: Vec::new(),
            recent_restarts: VecDeque::new(),
            restarts: 0,
            restart_at: None,
            drain_deadline: None,
            stopping: false,
            resume_floor: None,
        }
    }

    fn name(&self) -> &str {
        &self.service.spec.name
    }

    /// Running, or about to be restarted.
    fn is_live(&self, sup: &Supervisor) -> bool {
        self.restart_at.is_some() || self.current.is_some_and(|i| sup.children[i].is_running())
    }
}

struct Timeouts {
    ready: Duration,
    drain: Duration,
    grace: Duration,
}

/// Runs `services` (pipeline order, upstream first) with the timeouts of `launch.run`.
pub fn execute(
    launch: &LaunchFile,
    services: &[ResolvedService],
    prefix: &str,
    run_dir: &Path,
) -> Result<RunResult, SuperviseError> {
    let started = Instant::now();
    if let Some(core) = launch.run.launcher_core {
        crate::supervisor::pin_this_process(core);
    }
    let mut sup = Supervisor::new(prefix, run_dir)?;
    let t = Timeouts {
        ready: Duration::from_secs_f64(launch.run.ready_timeout_s),
        drain: Duration::from_secs_f64(launch.run.drain_timeout_s),
        grace: Duration::from_secs_f64(launch.run.stop_grace_s),
    };
    let mut slots: Vec<Slot> = services.iter().cloned().map(Slot::new).collect();
    let mut failure: Option<String> = None;
    let mut stop_requested = false;
    let mut events: Vec<String> = Vec::new();

    // Downstream first: a consumer's subscription exists before its producer sends the first frame.
    for k in (0..slots.len()).rev() {
        match start_instance(&mut sup, &mut slots[k], false, &t)? {
            Start::Ready(_) => {}
            Start::StopRequested => {
                stop_requested = true;
                break;
            }
            // A service with a restart policy gets its restarts at start too (the flow below applies the policy
            // and the back-off to the ended instance).
            Start::Failed(why) if slots[k].service.spec.restart.policy != RestartPolicy::Never => {
                tracing::warn!("{why}");
                events.push(why);
            }
            Start::Failed(why) => {
                failure = Some(why);
                break;
            }
        }
    }

    if failure.is_none() && !stop_requested {
        let end = flow(&mut sup, &mut slots, &t, &mut events)?;
        match end {
            FlowEnd::Done => {}
            FlowEnd::StopRequested => stop_requested = true,
            FlowEnd::Failed(why) => failure = Some(why),
        }
    }
    if stop_requested {
        tracing::info!("stop requested: stopping services upstream first");
    }
    // Upstream first: the current instances, then any replaced one still ending.
    let mut order: Vec<usize> = slots.iter().filter_map(|s| s.current).collect();
    let replaced: Vec<usize> =
        slots.iter().flat_map(|s| s.instances.iter().copied()).filter(|i| !order.contains(i)).collect();
    order.extend(replaced);
    sup.stop_in_order(&order, t.grace)?;
    // After a stop request, a service that needed SIGKILL was logged above; the run still ends as stopped (130).
    if failure.is_none() && !stop_requested {
        for slot in slots.iter() {
            let Some(c) = slot.current.or(slot.instances.last().copied()).map(|i| &sup.children[i]) else { continue };
            if c.retired || c.succeeded() {
                continue;
            }
            let line = format!("{} failed ({}): {}", c.name, c.exit_text(), c.last_error_line().unwrap_or_default());
            if slot.service.spec.essential {
                failure = Some(line);
                break;
            }
            go_on_without(&line, &mut events);
        }
    }
    // Crashed children leave their nodes behind; reclaim them now rather than at the next run's start.
    sup.cleanup_dead();

    let results = slots
        .iter()
        .map(|slot| match slot.current.or(slot.instances.last().copied()) {
            Some(i) => {
                let c = &sup.children[i];
                ServiceResult {
                    name: c.name.clone(),
                    pid: c.pid,
                    core: c.core,
                    exit: c.exit_text(),
                    ok: c.succeeded(),
                    error: (!c.succeeded()).then(|| c.last_error_line()).flatten(),
                    log: c.log.display().to_string(),
                    restarts: slot.restarts,
                    earlier_instances: slot
                        .instances
                        .iter()
                        .filter(|&&j| j != i)
                        .map(|&j| {
                            let e = &sup.children[j];
                            let why = if e.retired { "replaced" } else { "failed" };
                            format!("pid {}: {} ({why})", e.pid, e.exit_text())
                        })
                        .collect(),
                }
            }
            // Services that never started (a failure before their turn) are listed too.
            None => ServiceResult {
                name: slot.name().to_string(),
                pid: 0,
                core: slot.service.spec.core,
                exit: "not started".into(),
                ok: false,
                error: None,
                log: String::new(),
                restarts: 0,
                earlier_instances: Vec::new(),
            },
        })
        .collect();
    Ok(RunResult {
        services: results,
        latency: sup.latency.report(),
        stop_requested,
        failure,
        duration_s: started.elapsed().as_secs_f64(),
        events,
    })
}

enum Start {
    Ready(usize),
    StopRequested,
    Failed(String),
}

/// Starts an instance of the slot's service and waits until it reports ready. A replacement of a handover
/// service starts in standby (`--standby`) and must be activated by the caller.
fn start_instance(
    sup: &mut Supervisor,
    slot: &mut Slot,
    replacement: bool,
    t: &Timeouts,
) -> Result<Start, SuperviseError> {
    let standby = replacement && slot.service.spec.handover.is_some();
    let mut extra: Vec<String> = Vec::new();
    if replacement {
        extra.extend(slot.service.spec.replacement_args.iter().cloned());
    }
    if standby {
        extra.push("--standby".into());
    }
    let index = sup.spawn(&slot.service, &extra)?;
    slot.instances.push(index);
    slot.current = Some(index);
    let pid = sup.children[index].pid;
    let end = sup.pump(t.ready, |s| s.latency.is_pid_ready(pid) || !s.children[index].is_running())?;
    let child = &sup.children[index];
    Ok(match end {
        PumpEnd::StopRequested => Start::StopRequested,
        _ if sup.latency.is_pid_ready(pid) => Start::Ready(index),
        PumpEnd::Timeout => {
            let why = format!("{} did not report ready within {:.0} s", slot.name(), t.ready.as_secs_f64());
            sup.children[index].hung = true;
            sup.stop_one(index, t.grace)?;
            Start::Failed(why)
        }
        PumpEnd::Done => Start::Failed(format!(
            "{} ended before it was ready ({}): {}",
            slot.name(),
            child.exit_text(),
            child.last_error_line().unwrap_or_default()
        )),
    })
}

/// Whose word says which keyframes are done when a replacement resumes.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Resume {
    /// The old instance stopped cleanly: what it published was delivered.
    Graceful,
    /// The old instance died: only what the consumers took in.
    Crashed,
    /// The named consumer was restarted from a checkpoint: what it has now.
    ConsumerRestored(String),
}

enum FlowEnd {
    Done,
    StopRequested,
    Failed(String),
}

/// A service the run does not depend on (it only watches) has failed for good: noted, and the run goes on.
fn go_on_without(line: &str, events: &mut Vec<String>) {
    let line = format!("{line}; it is not essential: the run goes on without it");
    tracing::warn!("{line}");
    events.push(line);
}

/// Lets the stream flow until every service has ended: restarts under each service's policy, liveness deadlines,
/// drain deadlines once upstream has ended, and control requests.
fn flow(
    sup: &mut Supervisor,
    slots: &mut [Slot],
    t: &Timeouts,
    events: &mut Vec<String>,
) -> Result<FlowEnd, SuperviseError> {
    // Services restarted in this turn, whose feeders may have to redo what they lost.
    let mut replays: Vec<String> = Vec::new();
    loop {
        let now = Instant::now();
        let mut next_wake = now + Duration::from_secs(3600);

        // Ends of current instances: restart under the policy, or fail the run.
        for k in 0..slots.len() {
            let Some(i) = slots[k].current else { continue };
            if sup.children[i].is_running() {
                // Liveness: a ready instance silent for longer than its deadline is hung.
                if let Some(limit) = slots[k].service.spec.liveness_s.map(Duration::from_secs_f64)
                    && let Some(heard) = sup.latency.last_heard(sup.children[i].pid)
                {
                    if now.duration_since(heard) > limit {
                        let line = format!(
                            "{} (pid {}) sent nothing for {:.1} s (liveness deadline {:.1} s): stopping it",
                            slots[k].name(),
                            sup.children[i].pid,
                            now.duration_since(heard).as_secs_f64(),
                            limit.as_secs_f64()
                        );
                        tracing::warn!("{line}");
                        events.push(line);
                        sup.children[i].hung = true;
                        sup.stop_one(i, t.grace)?;
                    } else {
                        next_wake = next_wake.min(heard + limit + Duration::from_millis(50));
                    }
                }
                if sup.children[i].is_running() {
                    continue;
                }
            }
            slots[k].current = None;
            let c = &sup.children[i];
            let upstream_live = slots[..k].iter().any(|s| s.is_live(sup));
            let restart = slots[k].service.spec.restart.clone();
            let wanted = !slots[k].stopping
                && match (c.succeeded(), restart.policy) {
                    (false, RestartPolicy::OnFailure | RestartPolicy::Always) => true,
                    (true, RestartPolicy::Always) => upstream_live,
                    _ => false,
                };
            if wanted {
                let window = Duration::from_secs_f64(restart.window_s);
                while slots[k].recent_restarts.front().is_some_and(|&r| now.duration_since(r) > window) {
                    slots[k].recent_restarts.pop_front();
                }
                let recent = slots[k].recent_restarts.len();
                if recent >= restart.max_restarts as usize {
                    let line = format!(
                        "{} ended {} times within {:.0} s ({} this time): giving up after {} restarts — {}",
                        slots[k].name(),
                        recent + 1,
                        restart.window_s,
                        c.exit_text(),
                        recent,
                        c.last_error_line().unwrap_or_default()
                    );
                    if slots[k].service.spec.essential {
                        return Ok(FlowEnd::Failed(line));
                    }
                    go_on_without(&line, events);
                    continue;
                }
                let delay = restart.backoff(recent);
                let line = format!(
                    "{} (pid {}) ended ({}): restart {} of at most {} within {:.0} s, in {:.2} s",
                    slots[k].name(),
                    c.pid,
                    c.exit_text(),
                    recent + 1,
                    restart.max_restarts,
                    restart.window_s,
                    delay.as_secs_f64()
                );
                tracing::warn!("{line}");
                events.push(line);
                slots[k].restart_at = Some(now + delay);
            } else if !c.succeeded() && !slots[k].stopping {
                let line =
                    format!("{} failed ({}): {}", c.name, c.exit_text(), c.last_error_line().unwrap_or_default());
                if slots[k].service.spec.essential {
                    return Ok(FlowEnd::Failed(line));
                }
                go_on_without(&line, events);
            }
        }

        // Restarts that are due.
        for slot in slots.iter_mut() {
            let Some(at) = slot.restart_at else { continue };
            if at > Instant::now() {
                next_wake = next_wake.min(at);
                continue;
            }
            slot.restart_at = None;
            slot.recent_restarts.push_back(Instant::now());
            slot.restarts += 1;
            let old_pid = slot.instances.last().map(|&i| sup.children[i].pid);
            // The dead instance's node and ports are reclaimed before the new one opens its own.
            let cleaned = sup.cleanup_dead();
            match start_instance(sup, slot, true, t)? {
                Start::StopRequested => return Ok(FlowEnd::StopRequested),
                // Its end is picked up above, at the next turn, and handled under the policy again.
                Start::Failed(why) => events.push(format!("restart of {} failed: {why}", slot.name())),
                Start::Ready(index) => {
                    let pid = sup.children[index].pid;
                    let mut line = format!("{} restarted (pid {pid}", slot.name());
                    if cleaned > 0 {
                        line.push_str(&format!(", {cleaned} dead node(s) cleaned"));
                    }
                    if slot.service.spec.handover.is_some() {
                        let resume = resume_point(sup, slot, old_pid, &Resume::Crashed);
                        sup.activate(pid, resume)?;
                        slot.resume_floor = (resume != Activation::RESUME_FROM_START).then_some(resume);
                        line.push_str(&resume_text(resume));
                    }
                    line.push(')');
                    tracing::info!("{line}");
                    events.push(line);
                    replays.push(slot.name().to_string());
                }
            }
        }
        // A restarted consumer resumed from its checkpoint: the handover services feeding it redo what it lost.
        for consumer in std::mem::take(&mut replays) {
            let Some(input) = sup.latency.input_topic(&consumer) else { continue };
            let feeders: Vec<usize> = (0..slots.len())
                .filter(|&k| {
                    slots[k].service.spec.handover.is_some()
                        && sup.latency.output_topic(slots[k].name()).as_deref() == Some(input.as_str())
                })
                .collect();
            for k in feeders {
                let why = format!("{consumer} restarted from its checkpoint");
                let rule = Resume::ConsumerRestored(consumer.clone());
                match replace(sup, slots, k, ControlCommand::Swap, None, Vec::new(), rule, t, events)? {
                    Swapped::StopRequested(_) => return Ok(FlowEnd::StopRequested),
                    Swapped::Answer(r) if r.ok == 0 => tracing::warn!("replay for {why}: {}", r.message()),
                    Swapped::Answer(_) => tracing::info!("replayed for {why}"),
                }
            }
        }

        // Control requests (swaps).
        while let Some(call) = sup.next_control_request() {
            match swap(sup, slots, &call, t, events)? {
                Swapped::StopRequested(response) => {
                    sup.answer(call, response);
                    return Ok(FlowEnd::StopRequested);
                }
                Swapped::Answer(response) => sup.answer(call, response),
            }
        }

        // A service whose upstreams have all ended gets `drain` to finish its stream, then is stopped.
        let now = Instant::now();
        for pos in 1..slots.len() {
            let Some(i) = slots[pos].current.filter(|&i| sup.children[i].is_running()) else { continue };
            if slots[..pos].iter().any(|s| s.is_live(sup)) {
                continue;
            }
            let deadline = *slots[pos].drain_deadline.get_or_insert(now + t.drain);
            if now >= deadline {
                tracing::warn!(
                    "{} did not finish within {:.1} s of its upstream; stopping it",
                    slots[pos].name(),
                    t.drain.as_secs_f64()
                );
                slots[pos].stopping = true;
                sup.stop_one(i, t.grace)?;
            } else {
                next_wake = next_wake.min(deadline);
            }
        }

        if !slots.iter().any(|s| s.is_live(sup)) {
            // Every service ended; one that ended badly without a restart was reported above.
            return Ok(FlowEnd::Done);
        }
        let running: Vec<usize> = slots.iter().filter_map(|s| s.current).collect();
        let wait = next_wake.saturating_duration_since(Instant::now());
        let end = sup.pump(wait, |s| s.control_pending || running.iter().any(|&i| !s.children[i].is_running()))?;
        if end == PumpEnd::StopRequested {
            return Ok(FlowEnd::StopRequested);
        }
    }
}

enum Swapped {
    Answer(ControlResponse),
    StopRequested(ControlResponse),
}
