//! Handing a service over to a new instance: the resume point (which keyframe a replacement continues after),\n//! and make-before-break swaps and replacements.
use super::*;

/// After which keyframe a new instance of a handover service resumes. What the consumers of its output have
/// taken in is done; after a graceful stop, so is everything the old instance published (its samples stay
/// deliverable). After a crash only the consumers' word counts: a sample in flight may be lost with the dead
/// process's memory, so it is redone (and a duplicate is dropped downstream by keyframe id).
pub(super) fn resume_point(sup: &Supervisor, slot: &Slot, old_pid: Option<u32>, rule: &Resume) -> u64 {
    let output = sup.latency.output_topic(slot.name());
    let consumed = output.as_deref().and_then(|t| sup.latency.last_item_consumed(t));
    let own = old_pid.and_then(|p| sup.latency.last_item_of_pid(p));
    let has_consumer = output.as_deref().is_some_and(|t| sup.latency.has_consumer(t));
    let done = match rule {
        Resume::Graceful => consumed.max(own).max(slot.resume_floor),
        Resume::Crashed if has_consumer => consumed.max(slot.resume_floor),
        Resume::Crashed => own.max(slot.resume_floor),
        // A consumer lost what it had taken in since its checkpoint: its word alone counts, even if it is
        // behind what was done before.
        // What it restored, not the highest it has taken in since: that may be a keyframe sent after a gap.
        Resume::ConsumerRestored(consumer) => sup.latency.restored_of(consumer),
    };
    done.unwrap_or(Activation::RESUME_FROM_START)
}

pub(super) fn resume_text(resume: u64) -> String {
    if resume == Activation::RESUME_FROM_START {
        ", from the first keyframe it receives".into()
    } else {
        format!(", resuming after keyframe {resume}")
    }
}

/// Carries out a control request (a swap).
pub(super) fn swap(
    sup: &mut Supervisor,
    slots: &mut [Slot],
    call: &ControlCall,
    t: &Timeouts,
    events: &mut Vec<String>,
) -> Result<Swapped, SuperviseError> {
    let request = *call.payload();
    let no = |m: String| Ok(Swapped::Answer(ControlResponse::new(false, &m)));
    let Some(command) = request.command() else { return no(format!("unknown command {}", request.command)) };
    let name = request.service();
    let Some(k) = slots.iter().position(|s| s.name() == name) else {
        let names: Vec<&str> = slots.iter().map(|s| s.name()).collect();
        return no(format!("no service `{name}` in this run (it has: {})", names.join(", ")));
    };
    let rule = if command == ControlCommand::Swap { Resume::Graceful } else { Resume::Crashed };
    replace(sup, slots, k, command, request.binary(), request.args(), rule, t, events)
}

/// Make-before-break: the new instance starts (in standby for a handover service) and reports ready, the old
/// one is stopped (SIGTERM ladder, or SIGKILL for a fault drill), then the new one is activated to resume after
/// what downstream already has. If the new instance cannot start, the old one keeps running.
#[allow(clippy::too_many_arguments)] // one call site each for a swap request and a replay; a struct adds nothing
pub(super) fn replace(
    sup: &mut Supervisor,
    slots: &mut [Slot],
    k: usize,
    command: ControlCommand,
    binary: Option<String>,
    extra: Vec<String>,
    rule: Resume,
    t: &Timeouts,
    events: &mut Vec<String>,
) -> Result<Swapped, SuperviseError> {
    let began = Instant::now();
    let no = |m: String| Ok(Swapped::Answer(ControlResponse::new(false, &m)));
    let name = slots[k].name().to_string();
    let Some(old) = slots[k].current.filter(|&i| sup.children[i].is_running()) else {
        return no(format!("`{name}` is not running"));
    };
    let mut service = slots[k].service.clone();
    if let Some(binary) = binary {
        let Some(program) = crate::launch_file::find_binary(&binary) else {
            return no(format!("binary `{binary}` not found (a path, a bdis-slam binary or a program on PATH)"));
        };
        service.program = program;
        service.spec.binary = binary;
    }
    service.args.extend(extra.iter().cloned());
    service.spec.args.extend(extra);
    let old_pid = sup.children[old].pid;
    let previous = std::mem::replace(&mut slots[k].service, service);
    let new = match start_instance(sup, &mut slots[k], true, t)? {
        Start::Ready(index) => index,
        other => {
            // Break nothing: the old instance stays in charge with its old command line.
            slots[k].service = previous;
            slots[k].current = Some(old);
            let stop = matches!(other, Start::StopRequested);
            let why = match other {
                Start::Failed(why) => why,
                _ => "stop requested".into(),
            };
            let line =
                format!("swap of {name} refused: the new instance did not start ({why}); pid {old_pid} keeps running");
            tracing::warn!("{line}");
            events.push(line.clone());
            let response = ControlResponse::new(false, &line);
            return Ok(if stop { Swapped::StopRequested(response) } else { Swapped::Answer(response) });
        }
    };
    let new_pid = sup.children[new].pid;
    sup.children[old].retired = true;
    let graceful = command == ControlCommand::Swap;
    if graceful {
        sup.stop_one(old, t.grace)?;
    } else {
        sup.signal(old, libc::SIGKILL);
        sup.pump(Duration::from_secs(5), |s| !s.children[old].is_running())?;
    }
    // The old instance's last records are in; a cleanly stopped one may have needed SIGKILL after all.
    sup.pump(Duration::ZERO, |_| true)?;
    let rule = if rule == Resume::Graceful && !sup.children[old].succeeded() { Resume::Crashed } else { rule };
    let mut response = ControlResponse::new(true, "");
    let mut line = format!(
        "{name} swapped: pid {old_pid} ({}) → pid {new_pid}",
        if graceful { format!("stopped: {}", sup.children[old].exit_text()) } else { "killed with SIGKILL".into() }
    );
    if slots[k].service.spec.handover.is_some() {
        let resume = resume_point(sup, &slots[k], Some(old_pid), &rule);
        sup.activate(new_pid, resume)?;
        slots[k].resume_floor = (resume != Activation::RESUME_FROM_START).then_some(resume);
        response.resume_after = resume;
        line.push_str(&resume_text(resume));
    }
    slots[k].restarts += 1;
    let elapsed = began.elapsed();
    line.push_str(&format!(", {:.0} ms", elapsed.as_secs_f64() * 1e3));
    tracing::info!("{line}");
    events.push(line.clone());
    response.old_pid = old_pid;
    response.new_pid = new_pid;
    response.duration_us = elapsed.as_micros() as u64;
    response.message = ControlResponse::new(true, &line).message;
    Ok(Swapped::Answer(response))
}
