//! Starts, watches and stops the processes of a run, and collects their telemetry.
//!
//! One WaitSet wakes the launcher for everything it reacts to: telemetry lifecycle events, a child's exit (a
//! pidfd per child, readable when the child ends), a periodic drain of message telemetry, and SIGINT/SIGTERM.
//! Nothing sleeps or polls.

use std::fs::File;
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use bdis_ipc::control::{Activation, ControlRequest, ControlResponse};
use bdis_ipc::{Ipc, IpcError, TELEMETRY_DRAIN_PERIOD, TelemetryRecord, Topic, event_id};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;

use crate::latency::LatencyAggregator;
use crate::launch_file::ResolvedService;

/// Environment variables every child receives.
pub const SERVICE_NAME_ENV: &str = "BDIS_SERVICE_NAME";
pub const RUN_DIR_ENV: &str = "BDIS_RUN_DIR";

#[derive(Debug, thiserror::Error)]
pub enum SuperviseError {
    #[error(transparent)]
    Ipc(#[from] IpcError),
    #[error("{what}: {detail}")]
    Os { what: String, detail: String },
}

fn os(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> SuperviseError {
    let what = what.into();
    move |e| SuperviseError::Os { what, detail: e.to_string() }
}

/// Pins the calling process (the launcher) to one core; a failure is logged, not fatal (the run still works).
pub fn pin_this_process(core: usize) {
    // SAFETY: zeroed cpu_set_t is the empty set; CPU_SET only writes into it; sched_setaffinity reads it.
    let ok = unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(core, &mut set);
        libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
    };
    if !ok {
        tracing::warn!("could not pin the launcher to core {core}: {}", std::io::Error::last_os_error());
    }
}

/// A Linux pidfd: becomes readable when its process exits, so a WaitSet can wait for children.
#[derive(Debug)]
pub struct PidFd {
    fd: FileDescriptor,
}

impl PidFd {
    pub fn open(pid: u32) -> std::io::Result<Self> {
        // SAFETY: pidfd_open takes a pid and flags and returns a new descriptor we own, or -1.
        let raw = unsafe { libc::syscall(libc::SYS_pidfd_open, pid as libc::pid_t, 0 as libc::c_uint) };
        if raw < 0 {
            return Err(std::io::Error::last_os_error());
        }
        FileDescriptor::new(raw as i32).map(|fd| Self { fd }).ok_or_else(|| std::io::Error::other("invalid pidfd"))
    }
}

impl FileDescriptorBased for PidFd {
    fn file_descriptor(&self) -> &FileDescriptor {
        &self.fd
    }
}

impl SynchronousMultiplexing for PidFd {}

/// One supervised process.
#[derive(Debug)]
pub struct Supervised {
    pub name: String,
    pub core: Option<usize>,
    pub pid: u32,
    pub log: PathBuf,
    pub started: Instant,
    pub exit: Option<ExitStatus>,
    /// Swapped out or stopped on purpose by the launcher: its end is expected, not a failure of the run.
    pub retired: bool,
    /// Stopped by the launcher because it missed its liveness deadline: a failure even if it exited cleanly.
    pub hung: bool,
    child: Child,
    pidfd: PidFd,
}

impl Supervised {
    pub fn is_running(&self) -> bool {
        self.exit.is_none()
    }

    /// `ok`, `exit code N` or `killed by signal S`; `running` while it runs.
    pub fn exit_text(&self) -> String {
        if self.hung && self.exit.is_some() {
            return format!("hung (missed its liveness deadline), then {}", self.exit_text_of_status());
        }
        self.exit_text_of_status()
    }

    fn exit_text_of_status(&self) -> String {
        match self.exit {
            None => "running".into(),
            Some(s) if s.success() => "ok".into(),
            Some(s) => match (s.code(), s.signal()) {
                (Some(c), _) => format!("exit code {c}"),
                (None, Some(sig)) => format!("killed by signal {sig}"),
                _ => "ended".into(),
            },
        }
    }

    pub fn succeeded(&self) -> bool {
        !self.hung && self.exit.is_some_and(|s| s.success())
    }

    /// The last line of its log that says what went wrong (or the last line).
    pub fn last_error_line(&self) -> Option<String> {
        let text = std::fs::read_to_string(&self.log).ok()?;
        let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
        lines.iter().rev().find(|l| l.contains("error")).or(lines.last()).map(|l| l.trim().to_string())
    }
}

/// Why [`Supervisor::pump`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PumpEnd {
    Done,
    Timeout,
    /// SIGINT or SIGTERM reached the launcher.
    StopRequested,
}

type ControlServer = iceoryx2::port::server::Server<ipc::Service, ControlRequest, (), ControlResponse, ()>;
/// A control request being carried out; answered with [`Supervisor::answer`].
pub type ControlCall = iceoryx2::active_request::ActiveRequest<ipc::Service, ControlRequest, (), ControlResponse, ()>;

/// The launcher's side of the control contract: requests in, activations out.
#[derive(Debug)]
struct ControlPorts {
    server: ControlServer,
    requests: Listener<ipc::Service>,
    responses: iceoryx2::port::notifier::Notifier<ipc::Service>,
    activations: iceoryx2::port::publisher::Publisher<ipc::Service, Activation, ()>,
    activation_events: iceoryx2::port::notifier::Notifier<ipc::Service>,
    /// Services kept alive with their ports.
    _control: bdis_ipc::control::ControlService,
    _activation: bdis_ipc::control::ActivationService,
}

/// Owns the run's children and its telemetry subscription.
#[derive(Debug)]
pub struct Supervisor {
    ipc: Ipc,
    telemetry: Subscriber<ipc::Service, TelemetryRecord, ()>,
    telemetry_listener: Listener<ipc::Service>,
    pub latency: LatencyAggregator,
    pub children: Vec<Supervised>,
    run_dir: PathBuf,
    control: ControlPorts,
    /// A control request was signalled and not yet taken.
    pub control_pending: bool,
}

impl Supervisor {
    /// Opens the run's telemetry before any child exists, so no record is missed.
    pub fn new(prefix: &str, run_dir: &Path) -> Result<Self, SuperviseError> {
        let ipc = Ipc::open("launcher", prefix)?;
        let service = ipc.telemetry()?;
        let telemetry = ipc.telemetry_subscriber(&service)?;
        let telemetry_listener = ipc.listener(&ipc.events(Topic::Telemetry)?)?;
        let control_service = ipc.control()?;
        let server = control_service.server_builder().create().map_err(bdis_ipc::iox("create the control server"))?;
        let control_events = ipc.control_events()?;
        let activation = ipc.activation()?;
        let activations =
            activation.publisher_builder().create().map_err(bdis_ipc::iox("create the activation publisher"))?;
        let control = ControlPorts {
            server,
            requests: ipc.listener(&control_events)?,
            responses: ipc.notifier(&control_events)?,
            activations,
            activation_events: ipc.notifier(&ipc.activation_events()?)?,
            _control: control_service,
            _activation: activation,
        };
        Ok(Self {
            ipc,
            telemetry,
            telemetry_listener,
            latency: LatencyAggregator::new(),
            children: Vec::new(),
            run_dir: run_dir.to_path_buf(),
            control,
            control_pending: false,
        })
    }

    /// The next control request, if one is waiting.
    pub fn next_control_request(&mut self) -> Option<ControlCall> {
        self.control_pending = false;
        match self.control.server.receive() {
            Ok(r) => r,
            Err(e) => {
                tracing::warn!("control request: {e:?}");
                None
            }
        }
    }

    /// Answers a control request (the caller may have given up waiting: that is not an error here).
    pub fn answer(&self, call: ControlCall, response: ControlResponse) {
        if let Err(e) = call.send_copy(response) {
            tracing::warn!("answer a control request: {e:?}");
        }
        let _ = bdis_ipc::notify(&self.control.responses, event_id::CONTROL_RESPONSE);
    }

    /// Tells the standby process `pid` to start, skipping keyframes up to `resume_after`.
    pub fn activate(&self, pid: u32, resume_after: u64) -> Result<(), SuperviseError> {
        self.control
            .activations
            .send_copy(Activation { pid, reserved: 0, resume_after })
            .map_err(bdis_ipc::iox("send an activation"))?;
        bdis_ipc::notify(&self.control.activation_events, event_id::NEW_SAMPLE)?;
        Ok(())
    }

    pub fn prefix(&self) -> &str {
        &self.ipc.prefix
    }

    /// Starts a service in its own process group (a terminal's Ctrl-C reaches only the launcher, which stops
    /// the pipeline in order), pinned to its core from its first instruction, output into its log file.
    /// Every instance of a service writes its own log: `<name>.log`, then `<name>.1.log`, `<name>.2.log`, … for
    /// replacements, so a crashed instance's last words are kept.
    pub fn spawn(&mut self, service: &ResolvedService, extra_args: &[String]) -> Result<usize, SuperviseError> {
        let logs = self.run_dir.join("logs");
        std::fs::create_dir_all(&logs).map_err(os(format!("create {}", logs.display())))?;
        let earlier = self.children.iter().filter(|c| c.name == service.spec.name).count();
        let log = if earlier == 0 {
            logs.join(format!("{}.log", service.spec.name))
        } else {
            logs.join(format!("{}.{earlier}.log", service.spec.name))
        };
        let out = File::create(&log).map_err(os(format!("create {}", log.display())))?;
        let err = out.try_clone().map_err(os(format!("open {}", log.display())))?;
        let mut cmd = Command::new(&service.program);
        cmd.args(&service.args)
            .args(extra_args)
            .envs(&service.spec.env)
            .env(bdis_ipc::PREFIX_ENV, &self.ipc.prefix)
            .env(SERVICE_NAME_ENV, &service.spec.name)
            .env(RUN_DIR_ENV, &self.run_dir)
            .stdin(Stdio::null())
            .stdout(out)
            .stderr(err)
            .process_group(0);
        let core_set = service.spec.core.map(|core| {
            // SAFETY: zeroed cpu_set_t is the empty set; CPU_SET only writes into it.
            let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
            unsafe { libc::CPU_SET(core, &mut set) };
            set
        });
        // SAFETY: runs in the forked child before exec; prctl and sched_setaffinity are async-signal-safe and the
        // closure touches nothing but the copied set.
        unsafe {
            cmd.pre_exec(move || {
                // If the launcher dies (even by SIGKILL), its children get SIGTERM and stop cleanly instead of
                // running on as orphans holding shared memory.
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                if let Some(set) = &core_set
                    && libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), set) != 0
                {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
        let child = cmd.spawn().map_err(os(format!("start {} ({})", service.spec.name, service.program.display())))?;
        let pid = child.id();
        let pidfd = PidFd::open(pid).map_err(os(format!("watch {} (pidfd_open)", service.spec.name)))?;
        tracing::info!(
            "started {} (pid {pid}{})",
            service.spec.name,
            service.spec.core.map_or(String::new(), |c| format!(", core {c}"))
        );
        self.children.push(Supervised {
            name: service.spec.name.clone(),
            core: service.spec.core,
            pid,
            log,
            started: Instant::now(),
            exit: None,
            retired: false,
            hung: false,
            child,
            pidfd,
        });
        Ok(self.children.len() - 1)
    }

    /// Sends a signal to a running child.
    pub fn signal(&self, index: usize, signal: libc::c_int) {
        let c = &self.children[index];
        if c.is_running() {
            // SAFETY: kill with a pid we spawned and have not reaped (it cannot have been reused).
            unsafe { libc::kill(c.pid as libc::pid_t, signal) };
        }
    }

    fn drain_telemetry(&mut self) {
        let _ = self.telemetry_listener.try_wait(|_| {});
        loop {
            match self.telemetry.receive() {
                Ok(Some(sample)) => self.latency.record(&sample),
                Ok(None) => break,
                Err(e) => {
                    tracing::warn!("telemetry: {e:?}");
                    break;
                }
            }
        }
    }

    fn reap(&mut self) {
        for c in self.children.iter_mut().filter(|c| c.exit.is_none()) {
            if let Ok(Some(status)) = c.child.try_wait() {
                c.exit = Some(status);
                let text = c.exit_text();
                if status.success() {
                    tracing::info!("{} ended ({text})", c.name);
                } else {
                    tracing::warn!("{} ended: {text}", c.name);
                }
            }
        }
    }

    /// Waits for telemetry and child exits until `done` holds, `timeout` passes, or a stop is requested.
    pub fn pump(&mut self, timeout: Duration, mut done: impl FnMut(&Self) -> bool) -> Result<PumpEnd, SuperviseError> {
        let deadline = Instant::now() + timeout;
        loop {
            self.drain_telemetry();
            self.reap();
            if done(self) {
                return Ok(PumpEnd::Done);
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(PumpEnd::Timeout);
            }
            // The WaitSet borrows the listener and the pidfds; it lives only for this wait.
            let stop_requested = {
                let waitset =
                    WaitSetBuilder::new().create::<ipc::Service>().map_err(bdis_ipc::iox("create a WaitSet"))?;
                let attach_err = |e| bdis_ipc::iox("attach to the WaitSet")(e);
                let _telemetry = waitset.attach_notification(&self.telemetry_listener).map_err(attach_err)?;
                let _control = waitset.attach_notification(&self.control.requests).map_err(attach_err)?;
                let _tick = waitset.attach_interval(TELEMETRY_DRAIN_PERIOD).map_err(attach_err)?;
                let _children = self
                    .children
                    .iter()
                    .filter(|c| c.is_running())
                    .map(|c| waitset.attach_notification(&c.pidfd))
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(attach_err)?;
                let result = waitset
                    .wait_and_process_once_with_timeout(|_| CallbackProgression::Continue, deadline - now)
                    .map_err(bdis_ipc::iox("wait"))?;
                matches!(result, WaitSetRunResult::TerminationRequest | WaitSetRunResult::Interrupt)
            };
            if bdis_ipc::drain_events(&self.control.requests).is_ok_and(|seen| seen != 0) {
                self.control_pending = true;
            }
            if stop_requested {
                self.drain_telemetry();
                self.reap();
                return Ok(PumpEnd::StopRequested);
            }
        }
    }

    /// Stops running children upstream first: SIGTERM, then SIGKILL after `grace`. A source stopped this way
    /// still sends end of stream, so downstream services usually finish by themselves before their turn.
    pub fn stop_in_order(&mut self, order: &[usize], grace: Duration) -> Result<(), SuperviseError> {
        for &i in order {
            self.stop_one(i, grace)?;
        }
        Ok(())
    }

    /// The stop ladder for one child: SIGTERM, up to `grace` to exit, then SIGKILL.
    pub fn stop_one(&mut self, i: usize, grace: Duration) -> Result<(), SuperviseError> {
        if !self.children[i].is_running() {
            return Ok(());
        }
        tracing::info!("stopping {} (pid {})", self.children[i].name, self.children[i].pid);
        self.signal(i, libc::SIGTERM);
        // A second Ctrl-C while stopping is not a reason to skip (or postpone) the SIGKILL step.
        let deadline = Instant::now() + grace;
        let mut end = self.pump(grace, |s| !s.children[i].is_running())?;
        while end == PumpEnd::StopRequested {
            end = self.pump(deadline.saturating_duration_since(Instant::now()), |s| !s.children[i].is_running())?;
        }
        if end == PumpEnd::Timeout {
            tracing::warn!(
                "{} (pid {}) ignored SIGTERM for {:.1} s: SIGKILL",
                self.children[i].name,
                self.children[i].pid,
                grace.as_secs_f64()
            );
            self.signal(i, libc::SIGKILL);
            self.pump(Duration::from_secs(5), |s| !s.children[i].is_running())?;
        }
        Ok(())
    }

    /// Reclaims what crashed children left in shared memory (their nodes, ports, services).
    pub fn cleanup_dead(&self) -> usize {
        self.ipc.cleanup_dead_nodes()
    }
}
