//! `bdis-slam swap`: asks a running launcher (over iceoryx2 request-response) to replace one of its services
//! make-before-break, and prints what it did.

use std::time::{Duration, Instant};

use anyhow::{Result, anyhow, bail};
use bdis_ipc::control::{Activation, ControlCommand, ControlRequest};
use bdis_ipc::{Ipc, event_id};
use iceoryx2::prelude::*;

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Examples:\n  bdis-slam swap stereo --ipc-prefix bdis_r1234_\n  bdis-slam swap stereo -- --algorithm dis\n  bdis-slam swap stereo --bin ./target/release/bdis-stereo -- --param patchsz=12"
)]
pub struct SwapArgs {
    /// The service to replace (its name in the run, e.g. `stereo`).
    service: String,
    /// Start the new instance from this binary (default: the service's binary).
    #[arg(long = "bin", value_name = "PATH")]
    binary: Option<String>,
    /// Kill the old instance with SIGKILL instead of stopping it gracefully (a fault drill: what it was working
    /// on is redone by the new instance).
    #[arg(long)]
    kill: bool,
    /// Give up when the launcher has not answered within this many seconds.
    #[arg(long, default_value_t = 60.0)]
    timeout: f64,
    /// Shared-memory name prefix of the run (printed by `bdis-slam run`, or BDIS_IPC_PREFIX).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
    /// The run folder of the pipeline (instead of --ipc-prefix: the launcher writes its prefix there).
    #[arg(long, value_name = "DIR")]
    run: Option<std::path::PathBuf>,
    /// Arguments appended to the service's own for the new instance (and its later restarts); for bdis-stereo a
    /// later flag overrides an earlier one, e.g. `-- --algorithm dis`.
    #[arg(last = true)]
    args: Vec<String>,
}

pub fn swap(mut args: SwapArgs) -> Result<()> {
    if let Some(dir) = &args.run {
        args.ipc_prefix = bdis_slam::run_dir::prefix_of_run(dir).map_err(anyhow::Error::msg)?;
    }
    if !(args.timeout.is_finite() && args.timeout > 0.0) {
        bail!("--timeout: must be > 0 seconds, found {}", args.timeout);
    }
    let command = if args.kill { ControlCommand::Kill } else { ControlCommand::Swap };
    let request =
        ControlRequest::new(command, &args.service, args.binary.as_deref(), &args.args).map_err(|e| anyhow!("{e}"))?;
    let ipc = Ipc::open("swap", &args.ipc_prefix)?;
    let service = ipc.control()?;
    if service.dynamic_config().number_of_servers() == 0 {
        // Opening the control service made the run's files in /dev/shm; with nobody else on that prefix (a
        // mistyped one), they are removed again rather than left behind.
        drop((service, ipc));
        if bdis_ipc::live_nodes_of_run(&args.ipc_prefix).is_ok_and(|n| n == 0) {
            bdis_ipc::remove_run_files(&args.ipc_prefix);
        }
        bail!("no launcher is running with shared-memory prefix `{}`", args.ipc_prefix);
    }
    let client = service.client_builder().create().map_err(|e| anyhow!("create the control client: {e:?}"))?;
    let events = ipc.control_events()?;
    let request_signal = ipc.notifier(&events)?;
    let responses = ipc.listener(&events)?;

    let start = Instant::now();
    let pending = client.send_copy(request).map_err(|e| anyhow!("send the swap request: {e:?}"))?;
    bdis_ipc::notify(&request_signal, event_id::CONTROL_REQUEST)?;
    let deadline = start + Duration::from_secs_f64(args.timeout);
    let response = bdis_ipc::wait_for(&responses, deadline, || {
        pending.receive().map(|r| r.map(|r| *r.payload())).map_err(bdis_ipc::iox("receive the answer"))
    })?
    .ok_or_else(|| anyhow!("the launcher did not answer within {} s", args.timeout))?;
    if response.ok == 0 {
        bail!("{}", response.message());
    }
    println!("{}", response.message());
    if response.resume_after != Activation::RESUME_FROM_START {
        tracing::debug!("resumed after keyframe {}", response.resume_after);
    }
    Ok(())
}
