//! What every bdis-slam binary does the same way at start and exit.

use std::process::ExitCode;

/// Logs to stderr (the launcher captures it into the run's log folder). `RUST_LOG` overrides the INFO default.
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
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
