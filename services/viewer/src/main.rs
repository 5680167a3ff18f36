//! `bdis-viewer`: the viewer service. It watches a running pipeline — the tracker's poses, the depth keyframes
//! and pose corrections (from which it keeps a replica of the mosaic's map), and every process's telemetry — and
//! serves a local web page that shows it live. It only reads: it publishes nothing the pipeline consumes, never
//! back-pressures a producer (a browser that falls behind is dropped and reconnects), and its page loads nothing
//! from off the machine. When the depth stream ends it waits for the mosaic's last map and shows that.

mod node;

use std::process::ExitCode;
use std::time::Duration;

use clap::Parser;

/// Viewer service: a live web page of the running pipeline (map, path, depth, processes).
#[derive(Debug, Parser)]
#[command(name = "bdis-viewer", version)]
struct Args {
    /// Address to serve the page on; the default serves this machine only. Port 0 picks a free port.
    #[arg(long, default_value = "127.0.0.1:8470")]
    listen: String,
    /// The newest depth keyframe (left image and depth) is sent at most this wide, pixels.
    #[arg(long, default_value_t = 480)]
    image_width: usize,
    /// ... and at most this often, seconds (an image pair is ~0.46 MB at 320×240, most of what the page is sent).
    #[arg(long, default_value_t = 0.5)]
    image_period: f64,
    /// The mosaic's map parameters (`--map-param NAME=VALUE`, as `bdis-mosaic` takes them; the launcher passes
    /// the mosaic's own), so the viewer's replica of the map is the same map.
    #[arg(long = "map-param", value_name = "NAME=VALUE")]
    map_params: Vec<String>,
    /// The run folder (the launcher gives it): the mosaic's final map.bin is read from it at the end.
    #[arg(long, env = "BDIS_RUN_DIR")]
    run_dir: Option<std::path::PathBuf>,
    /// Name of this process in the run.
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "viewer")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
}

fn main() -> ExitCode {
    bdis_node::init_logging();
    bdis_node::protect_patient_data();
    let args = Args::parse();
    let seconds = |what: &str, s: f64| {
        if s.is_finite() && s > 0.0 {
            Ok(Duration::from_secs_f64(s))
        } else {
            Err(anyhow::anyhow!("--{what}: give seconds > 0, found {s}"))
        }
    };
    let config = (|| {
        let mut map_params = bdis_mosaic::MosaicParams::default();
        map_params.apply_overrides(&args.map_params).map_err(|e| anyhow::anyhow!("--map-param {e}"))?;
        Ok(node::Config {
            listen: args.listen,
            image_width: args.image_width.max(16),
            image_period: seconds("image-period", args.image_period)?,
            map_params,
            run_dir: args.run_dir,
            name: args.name,
            ipc_prefix: args.ipc_prefix,
        })
    })();
    bdis_node::finish("bdis-viewer", config.and_then(node::run))
}
