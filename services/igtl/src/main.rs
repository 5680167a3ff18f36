//! `bdis-igtl`: the OpenIGTLink service. Navigation workstations (3D Slicer's OpenIGTLinkIF, anything speaking
//! OpenIGTLink) connect to it as to a tracking device and receive the endoscope's pose for every frame and the
//! dense map, keyframe by keyframe, as it grows and is corrected. It only reads the pipeline: it publishes
//! nothing the pipeline consumes, a receiver that falls behind is let go, and it listens on this machine only
//! unless told otherwise.

mod node;

use std::time::Duration;

use clap::Parser;

/// OpenIGTLink service: the scope's pose per frame (TRANSFORM) and the dense map per keyframe to navigation
/// workstations.
#[derive(Debug, Parser)]
#[command(name = "bdis-igtl", version)]
struct Args {
    /// Address receivers connect to (OpenIGTLink's port is 18944); the default serves this machine only. Port 0
    /// picks a free port. What an open port shows: the scope's path and a 3-D map of the patient's tissue.
    #[arg(long, default_value = "127.0.0.1:18944")]
    listen: String,
    /// How the map is sent: `polydata` (a point cloud per keyframe, device `MapKf<id>`: what 3D Slicer shows as
    /// models), `points` (POINT messages with the tissue's colour, 136 bytes a point, for receivers that keep
    /// fiducials), or `off` (poses only).
    #[arg(long, default_value = "polydata", value_parser = ["polydata", "points", "off"])]
    map: String,
    /// The map is asked of the mosaic at most this often, seconds; only keyframes that changed go out.
    #[arg(long, default_value_t = 1.0)]
    map_period: f64,
    /// The run folder (the launcher gives it): at the end the mosaic's map.bin and the tracker's trajectory.tum
    /// are read from it and sent as the run's last word.
    #[arg(long, env = "BDIS_RUN_DIR")]
    run_dir: Option<std::path::PathBuf>,
    /// Name of this process in the run.
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "igtl")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
}

fn main() -> std::process::ExitCode {
    bdis_node::init_logging();
    bdis_node::protect_patient_data();
    let args = Args::parse();
    let config = (|| {
        if !(args.map_period.is_finite() && args.map_period > 0.0) {
            anyhow::bail!("--map-period: give seconds > 0, found {}", args.map_period);
        }
        let map = match args.map.as_str() {
            "polydata" => node::MapOut::PolyData,
            "points" => node::MapOut::Points,
            _ => node::MapOut::Off,
        };
        Ok(node::Config {
            listen: args.listen,
            map,
            map_period: Duration::from_secs_f64(args.map_period),
            run_dir: args.run_dir,
            name: args.name,
            ipc_prefix: args.ipc_prefix,
        })
    })();
    bdis_node::finish("bdis-igtl", config.and_then(node::run))
}
