//! `bdis-mosaic`: the mosaic service. Keeps the dense map (`bdis-mosaic`): takes each depth keyframe once
//! (de-duplicated by keyframe id, since a replacement stereo instance may send one again), moves keyframes'
//! points when bundle adjustment corrects their poses, answers snapshot requests so a viewer can draw the map,
//! and on stop writes `map.ply`, `map.png`, `map.bin` and `mosaic.json` into the run folder. It saves `map.bin`
//! every few keyframes too, so a crash loses little and `--load` can resume.

mod node;
mod pending;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Result, anyhow};
use bdis_mosaic::{Mosaic, MosaicParams};
use clap::Parser;

/// Mosaic service: depth keyframes and pose corrections in; the dense coloured map kept, served and exported.
#[derive(Debug, Parser)]
#[command(name = "bdis-mosaic", version)]
struct Args {
    /// Folder for map.ply, map.png, map.bin, mosaic.json (default: the run folder the launcher gives, else the
    /// current folder).
    #[arg(long, env = "BDIS_RUN_DIR")]
    out: Option<PathBuf>,
    /// Start from a saved map (map.bin), e.g. to resume after this service was restarted within a run. Keyframe
    /// ids continue: a keyframe already in it is not added twice.
    #[arg(long)]
    load: Option<PathBuf>,
    /// Override a map parameter, e.g. `--map-param fusion=weighted` (repeatable; names: depth_gap_px,
    /// min_colour, min_confidence, min_disparity_px, depth_tolerance_ratio, disparity_tolerance_px, keep_closer_ratio, fusion,
    /// max_weight, carve_disparity_px: an earlier view that saw this much disparity behind a new point drops it, 0 = off).
    #[arg(long = "map-param", value_name = "NAME=VALUE")]
    map_params: Vec<String>,
    /// Resume from the run folder's map.bin when there is one (the checkpoint of a predecessor that crashed);
    /// the launcher gives this to a restarted instance. Without a checkpoint it starts empty.
    #[arg(long, conflicts_with = "load")]
    resume: bool,
    /// Save map.bin after every this many new keyframes (0 = only at the end).
    #[arg(long, default_value_t = 10)]
    save_every: u64,
    /// Width of the map.png preview, pixels.
    #[arg(long, default_value_t = 1024)]
    preview_width: u32,
    /// Name of this process in the run.
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "mosaic")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
}

fn main() -> ExitCode {
    bdis_node::init_logging();
    bdis_node::protect_patient_data();
    bdis_node::finish("bdis-mosaic", run(Args::parse()))
}

/// The map to start from (a saved one, or empty) and its parameters, before shared memory is touched.
fn run(args: Args) -> Result<()> {
    let out_dir = args.out.clone().unwrap_or_else(|| PathBuf::from("."));
    let checkpoint = out_dir.join("map.bin");
    let load = match (&args.load, args.resume) {
        (Some(path), _) => Some(path.clone()),
        (None, true) if checkpoint.is_file() => Some(checkpoint),
        (None, true) => {
            tracing::info!("no checkpoint in {}: starting an empty map", out_dir.display());
            None
        }
        (None, false) => None,
    };
    let mosaic = match &load {
        Some(path) => {
            let mut m = bdis_mosaic::load(path)?;
            m.params.apply_overrides(&args.map_params).map_err(|e| anyhow!("--map-param {e}"))?;
            tracing::info!("resumed {} keyframes, {} points from {}", m.n_keyframes(), m.n_points(), path.display());
            m
        }
        None => {
            let mut params = MosaicParams::default();
            params.apply_overrides(&args.map_params).map_err(|e| anyhow!("--map-param {e}"))?;
            Mosaic::new(params)
        }
    };

    node::run(node::Config {
        mosaic,
        out_dir,
        save_every: args.save_every,
        preview_width: args.preview_width,
        name: args.name,
        ipc_prefix: args.ipc_prefix,
    })
}
