//! `bdis-slam view RUN_DIR`: the viewer's page over a finished run — the map, the scope's path with each frame's
//! tracking state, the newest depth, and every process's rate, latency, CPU and restarts.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

/// Where the viewer listens unless told otherwise: this machine only.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:8470";

#[derive(Debug, Args)]
pub struct ViewArgs {
    /// A run folder (what `run` or `demo` wrote: map.bin, trajectory.tum, latency.json, ...).
    pub run_dir: PathBuf,
    /// Address to serve the page on. The default serves this machine only; `0.0.0.0:8470` opens it to the
    /// network (the page is read-only). Port 0 picks a free port.
    #[arg(long, default_value = DEFAULT_LISTEN)]
    pub listen: String,
}

pub fn view(args: ViewArgs) -> anyhow::Result<()> {
    let run = bdis_viewer::RunView::open(&args.run_dir)?;
    let summary = format!(
        "{} keyframes, {} points, {} poses",
        run.summary.map_keyframes,
        run.summary.map_points,
        run.summary.path.len()
    );
    let site = bdis_viewer::Site::new(run)?;
    let (server, addr) = bdis_viewer::bind(&args.listen)?;
    let mut out = std::io::stdout().lock();
    writeln!(out, "bdis-slam view: {} ({summary}) at http://{addr}/ — Ctrl-C to stop", args.run_dir.display())
        .and_then(|()| out.flush())
        .context("writing the address")?;
    drop(out);
    site.serve(&server);
    Ok(())
}
