//! The launcher's control contracts.
//!
//! * **Control requests** (request-response, `bdis.v1.ControlRequest` → `bdis.v1.ControlResponse`): a tool such
//!   as `bdis-slam swap` asks the running launcher to act on one of its services. The launcher is the only
//!   server. Requests and responses are signalled on the event service of the same name
//!   ([`event_id::CONTROL_REQUEST`], [`event_id::CONTROL_RESPONSE`]), so neither side polls.
//! * **Activations** (publish-subscribe, `bdis.v1.Activation`): a replacement instance started with `--standby`
//!   opens its ports, reports ready and then waits until the launcher activates it — after its predecessor has
//!   stopped — with the last keyframe id its downstream already has. Make-before-break without two instances
//!   ever working on the same keyframes.

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory as PubSubFactory;
use iceoryx2::service::port_factory::request_response::PortFactory as RequestResponseFactory;

use crate::{Ipc, IpcError, fixed, iox, qos, text};

/// Room for a service name, a binary path and the arguments of a swap request.
pub const NAME_BYTES: usize = 32;
pub const PATH_BYTES: usize = 512;
pub const ARGS_BYTES: usize = 2048;
pub const MESSAGE_BYTES: usize = 256;

/// What a control request asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum ControlCommand {
    /// Start a new instance of the service, wait until it is ready, stop the old one gracefully, activate the
    /// new one (make-before-break).
    Swap = 1,
    /// As `Swap`, but the old instance is killed with SIGKILL first (a crash, for fault drills).
    Kill = 2,
}

/// A control request (`bdis.v1.ControlRequest`). Strings are UTF-8, NUL-padded; `args` holds NUL-terminated
/// arguments one after another.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("bdis.v1.ControlRequest")]
pub struct ControlRequest {
    pub command: u32,
    /// Number of arguments in `args` (0 = keep the service's arguments).
    pub n_args: u32,
    pub service: [u8; NAME_BYTES],
    /// The new binary (empty = keep the service's binary).
    pub binary: [u8; PATH_BYTES],
    pub args: [u8; ARGS_BYTES],
}

/// The launcher's answer (`bdis.v1.ControlResponse`).
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[type_name("bdis.v1.ControlResponse")]
pub struct ControlResponse {
    /// 1 when the request was carried out.
    pub ok: u32,
    pub old_pid: u32,
    pub new_pid: u32,
    pub reserved: u32,
    /// The new instance resumed after this keyframe id (`u64::MAX`: from the start of what it receives).
    pub resume_after: u64,
    /// From the request to the new instance's activation.
    pub duration_us: u64,
    /// What happened, or why not, in one line.
    pub message: [u8; MESSAGE_BYTES],
}

/// Activates a standby instance (`bdis.v1.Activation`).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("bdis.v1.Activation")]
pub struct Activation {
    /// The process this activation is for (other standby instances ignore it).
    pub pid: u32,
    pub reserved: u32,
    /// Skip keyframes up to and including this id (`u64::MAX`: skip nothing).
    pub resume_after: u64,
}

impl Activation {
    pub const RESUME_FROM_START: u64 = u64::MAX;
}

/// Why a request cannot be encoded.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum EncodeError {
    #[error("service name `{0}` is longer than {NAME_BYTES} bytes")]
    Name(String),
    #[error("binary path is longer than {PATH_BYTES} bytes")]
    Path,
    #[error("arguments take more than {ARGS_BYTES} bytes")]
    Args,
    #[error("argument {0:?} contains a NUL byte")]
    Nul(String),
}

impl ControlRequest {
    pub fn new(
        command: ControlCommand,
        service: &str,
        binary: Option<&str>,
        args: &[String],
    ) -> Result<Self, EncodeError> {
        if service.len() >= NAME_BYTES {
            return Err(EncodeError::Name(service.into()));
        }
        let binary = binary.unwrap_or("");
        if binary.len() >= PATH_BYTES {
            return Err(EncodeError::Path);
        }
        let mut packed = [0u8; ARGS_BYTES];
        let mut at = 0;
        for a in args {
            if a.contains('\0') {
                return Err(EncodeError::Nul(a.clone()));
            }
            let end = at + a.len() + 1;
            if end > ARGS_BYTES {
                return Err(EncodeError::Args);
            }
            packed[at..end - 1].copy_from_slice(a.as_bytes());
            at = end;
        }
        Ok(Self {
            command: command as u32,
            n_args: args.len() as u32,
            service: fixed(service),
            binary: fixed(binary),
            args: packed,
        })
    }

    pub fn command(&self) -> Option<ControlCommand> {
        match self.command {
            1 => Some(ControlCommand::Swap),
            2 => Some(ControlCommand::Kill),
            _ => None,
        }
    }

    pub fn service(&self) -> String {
        text(&self.service).to_string()
    }

    pub fn binary(&self) -> Option<String> {
        Some(text(&self.binary).to_string()).filter(|b| !b.is_empty())
    }

    pub fn args(&self) -> Vec<String> {
        self.args
            .split(|&b| b == 0)
            .take(self.n_args as usize)
            .map(|a| String::from_utf8_lossy(a).into_owned())
            .collect()
    }
}

impl ControlResponse {
    pub fn new(ok: bool, message: &str) -> Self {
        Self {
            ok: u32::from(ok),
            old_pid: 0,
            new_pid: 0,
            reserved: 0,
            resume_after: Activation::RESUME_FROM_START,
            duration_us: 0,
            message: fixed(message),
        }
    }

    pub fn message(&self) -> String {
        text(&self.message).to_string()
    }
}

pub type ControlService = RequestResponseFactory<ipc::Service, ControlRequest, (), ControlResponse, ()>;
pub type ActivationService = PubSubFactory<ipc::Service, Activation, ()>;

/// The service names of the control and activation services (each with an event service of the same name).
pub const CONTROL_SERVICE: &str = "bdis/v1/launcher/control";
pub const ACTIVATION_SERVICE: &str = "bdis/v1/launcher/activation";

fn name(s: &str) -> Result<ServiceName, IpcError> {
    ServiceName::new(s).map_err(|e| IpcError::Name { name: s.into(), detail: format!("{e:?}") })
}

impl Ipc {
    pub fn control(&self) -> Result<ControlService, IpcError> {
        let name = name(CONTROL_SERVICE)?;
        Self::with_retry("open the launcher's control service", || {
            self.node
                .service_builder(&name)
                .request_response::<ControlRequest, ControlResponse>()
                .max_servers(qos::CONTROL_MAX_SERVERS)
                .max_clients(qos::CONTROL_MAX_CLIENTS)
                .max_nodes(qos::MAX_NODES)
                .max_active_requests_per_client(1)
                .max_response_buffer_size(1)
                .enable_safe_overflow_for_responses(true)
                .open_or_create()
        })
    }

    pub fn control_events(&self) -> Result<crate::Events, IpcError> {
        self.event_service(&name(CONTROL_SERVICE)?, "control events")
    }

    pub fn activation(&self) -> Result<ActivationService, IpcError> {
        let name = name(ACTIVATION_SERVICE)?;
        Self::with_retry("open the activation service", || {
            self.node
                .service_builder(&name)
                .publish_subscribe::<Activation>()
                .max_publishers(qos::ACTIVATION_MAX_PUBLISHERS)
                .max_subscribers(qos::ACTIVATION_MAX_SUBSCRIBERS)
                .max_nodes(qos::MAX_NODES)
                .subscriber_max_buffer_size(qos::ACTIVATION_BUFFER)
                .history_size(0)
                .enable_safe_overflow(true)
                .open_or_create()
        })
    }

    pub fn activation_events(&self) -> Result<crate::Events, IpcError> {
        self.event_service(&name(ACTIVATION_SERVICE)?, "activation events")
    }

    pub fn activation_subscriber(
        &self,
        service: &ActivationService,
    ) -> Result<Subscriber<ipc::Service, Activation, ()>, IpcError> {
        service
            .subscriber_builder()
            .buffer_size(qos::ACTIVATION_BUFFER)
            .create()
            .map_err(iox("subscribe to activations"))
    }
}

/// Waits in standby until the launcher activates this process; returns the keyframe id to resume after, or
/// `None` when the process was asked to stop (SIGTERM/SIGINT) first. The subscription is opened before the
/// caller reports ready, so no activation can be missed.
pub struct Standby {
    subscriber: Subscriber<ipc::Service, Activation, ()>,
    listener: iceoryx2::port::listener::Listener<ipc::Service>,
    _service: ActivationService,
}

impl std::fmt::Debug for Standby {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Standby")
    }
}

impl Standby {
    pub fn open(ipc: &Ipc) -> Result<Self, IpcError> {
        let service = ipc.activation()?;
        let subscriber = ipc.activation_subscriber(&service)?;
        let listener = ipc.listener(&ipc.activation_events()?)?;
        Ok(Self { subscriber, listener, _service: service })
    }

    /// Blocks (in a WaitSet, no polling) until an activation for this pid arrives. `on_wake` runs at every wake-up
    /// and at least once a second (for heartbeats).
    pub fn wait(&self, mut on_wake: impl FnMut()) -> Result<Option<u64>, IpcError> {
        let pid = std::process::id();
        let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(iox("create a WaitSet"))?;
        let _guard = waitset
            .attach_deadline(&self.listener, std::time::Duration::from_secs(1))
            .map_err(iox("attach the activation listener"))?;
        loop {
            while let Some(sample) = self.subscriber.receive().map_err(iox("receive an activation"))? {
                if sample.pid == pid {
                    return Ok(Some(sample.resume_after));
                }
            }
            let result = waitset
                .wait_and_process_once(|_| CallbackProgression::Continue)
                .map_err(iox("wait for the activation"))?;
            if matches!(
                result,
                iceoryx2::waitset::WaitSetRunResult::TerminationRequest
                    | iceoryx2::waitset::WaitSetRunResult::Interrupt
            ) {
                return Ok(None);
            }
            let _ = crate::drain_events(&self.listener);
            on_wake();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn request_round_trips_and_refuses_what_does_not_fit() {
        let args = vec!["--algorithm".to_string(), "dis".to_string(), "--param".into(), "patchsz=8".into()];
        let r = ControlRequest::new(ControlCommand::Swap, "stereo", Some("/opt/bdis-stereo"), &args).unwrap();
        assert_eq!(r.command(), Some(ControlCommand::Swap));
        assert_eq!(r.service(), "stereo");
        assert_eq!(r.binary().as_deref(), Some("/opt/bdis-stereo"));
        assert_eq!(r.args(), args);
        let r = ControlRequest::new(ControlCommand::Kill, "stereo", None, &[]).unwrap();
        assert_eq!((r.binary(), r.args()), (None, Vec::<String>::new()));
        // An empty argument survives.
        let r = ControlRequest::new(ControlCommand::Swap, "s", None, &["".into(), "x".into()]).unwrap();
        assert_eq!(r.args(), vec!["".to_string(), "x".to_string()]);
        assert_eq!(
            ControlRequest::new(ControlCommand::Swap, &"n".repeat(40), None, &[]).unwrap_err(),
            EncodeError::Name("n".repeat(40))
        );
        assert_eq!(
            ControlRequest::new(ControlCommand::Swap, "s", None, &["a".repeat(ARGS_BYTES)]).unwrap_err(),
            EncodeError::Args
        );
        assert!(matches!(
            ControlRequest::new(ControlCommand::Swap, "s", None, &["a\0b".into()]),
            Err(EncodeError::Nul(_))
        ));
        assert!(ControlResponse::new(true, &"é".repeat(200)).message().len() <= MESSAGE_BYTES);
    }
}
