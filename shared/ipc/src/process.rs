//! What every bdis-slam binary does the same way at start and exit.

use std::process::ExitCode;

/// Logs to stderr (the launcher captures it into the run's log folder). `RUST_LOG` overrides the INFO default.
pub fn init_logging() {
    // Zenoh (the bridge's link) logs its routine at info and its handled failures at warn; the bridge logs what
    // they mean for the pipeline. `RUST_LOG=info` shows Zenoh's own log.
    let filter = tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
        tracing_subscriber::EnvFilter::new(
            "info,zenoh=error,zenoh_transport=error,zenoh_link_tcp=error,zenoh_link_commons=error,zenoh_config=error",
        )
    });
    // Colours only on a terminal: a service's stderr is its log file, where escape codes are noise.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(ansi)
        .with_target(false)
        .try_init();
    // iceoryx2 logs its own failures at warn level by default, which would print each of our handled errors
    // twice; our own messages carry its detail.
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
}

/// Ends a binary: success, or one line `PROGRAM: error: …` (the whole cause chain) and exit code 1.
pub fn finish(program: &str, result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("{program}: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Set to `1` to let run folders and their files be read by the user's group (a site where the console's
/// operators share a group): folders 0750, files 0640 instead of 0700 and 0600.
pub const SHARE_WITH_GROUP_ENV: &str = "BDIS_SHARE_WITH_GROUP";
/// Set to `1` to allow core dumps of the services that hold frames (for debugging a crash on a bench, never on a
/// console with patient data).
pub const CORE_DUMPS_ENV: &str = "BDIS_CORE_DUMPS";

fn env_is_one(name: &str) -> bool {
    std::env::var(name).is_ok_and(|v| v == "1")
}

/// Patient images stay with the user who recorded them: every file and folder this process creates is
/// owner-only (0600 / 0700), or group-readable with [`SHARE_WITH_GROUP_ENV`]. The mode comes from the umask, so
/// it covers every writer (maps, previews, logs, copied sequences) without a permission argument at each, and
/// child processes inherit it. Returns the umask set.
pub fn private_files() -> u32 {
    let mask = if env_is_one(SHARE_WITH_GROUP_ENV) { 0o027 } else { 0o077 };
    // SAFETY: umask has no preconditions and cannot fail.
    unsafe { libc::umask(mask) };
    mask
}

/// For a service that holds frames in memory: no core dump, so a crash does not write patient images to disk
/// (the kernel's core pattern may name any place). RLIMIT_CORE 0 stops core files; PR_SET_DUMPABLE 0 also stops
/// a core pattern that pipes to a collector. [`CORE_DUMPS_ENV`] keeps dumps allowed. Best effort: a failure is
/// logged, not fatal. Returns whether dumps are now off.
pub fn no_core_dumps() -> bool {
    if env_is_one(CORE_DUMPS_ENV) {
        tracing::warn!("{CORE_DUMPS_ENV}=1: a crash of this process may write its frames to disk");
        return false;
    }
    let zero = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: setrlimit reads the struct passed by reference; prctl with PR_SET_DUMPABLE takes integer arguments.
    let (limit, dumpable) =
        unsafe { (libc::setrlimit(libc::RLIMIT_CORE, &zero), libc::prctl(libc::PR_SET_DUMPABLE, 0, 0, 0, 0)) };
    if limit != 0 || dumpable != 0 {
        tracing::warn!("could not turn core dumps off: {}", std::io::Error::last_os_error());
        return false;
    }
    true
}
