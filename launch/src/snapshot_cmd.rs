//! `bdis-slam snapshot`: asks a running mosaic service for its current map (request-response over shared memory)
//! and writes it as a PLY — what a viewer does to draw the map while the pipeline runs.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Result, anyhow, bail};
use bdis_ipc::map::MapQuery;
use bdis_ipc::{Ipc, event_id};
use iceoryx2::prelude::*;

#[derive(Debug, clap::Args)]
pub struct SnapshotArgs {
    /// Where to write the snapshot (binary PLY: x y z, colour, keyframe_id, confidence).
    #[arg(long)]
    out: PathBuf,
    /// At most this many points (every k-th point when the map has more); 0 = all.
    #[arg(long, default_value_t = 0)]
    max_points: u64,
    /// Give up when no answer comes within this many seconds.
    #[arg(long, default_value_t = 5.0)]
    timeout: f64,
    /// Name of this process.
    #[arg(long, default_value = "snapshot")]
    name: String,
    /// Shared-memory name prefix of the run (printed by `bdis-slam run`, or BDIS_IPC_PREFIX).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
    /// The run folder of the pipeline (instead of --ipc-prefix: the launcher writes its prefix there).
    #[arg(long, value_name = "DIR")]
    run: Option<std::path::PathBuf>,
}

pub fn snapshot(mut args: SnapshotArgs) -> Result<()> {
    if let Some(dir) = &args.run {
        args.ipc_prefix = bdis_slam::run_dir::prefix_of_run(dir).map_err(anyhow::Error::msg)?;
    }
    if !(args.timeout.is_finite() && args.timeout > 0.0) {
        bail!("--timeout: must be > 0 seconds, found {}", args.timeout);
    }
    let ipc = Ipc::open(&args.name, &args.ipc_prefix)?;
    let service = ipc.map_snapshot()?;
    if service.dynamic_config().number_of_servers() == 0 {
        bail!("no mosaic service is running in the run with prefix `{}`", args.ipc_prefix);
    }
    let client = service.client_builder().create().map_err(|e| anyhow!("create the snapshot client: {e:?}"))?;
    let events = ipc.map_snapshot_events()?;
    let request_signal = ipc.notifier(&events)?;
    let responses = ipc.listener(&events)?;

    let start = Instant::now();
    let pending = client
        .send_copy(MapQuery { max_points: args.max_points, reserved: 0 })
        .map_err(|e| anyhow!("send the snapshot request: {e:?}"))?;
    bdis_ipc::notify(&request_signal, event_id::MAP_REQUEST)?;
    let deadline = start + Duration::from_secs_f64(args.timeout);
    let response =
        bdis_ipc::wait_for(&responses, deadline, || pending.receive().map_err(bdis_ipc::iox("receive the snapshot")))?
            .ok_or_else(|| anyhow!("no snapshot within {} s (is the mosaic service busy or stopped?)", args.timeout))?;
    let round_trip_ms = start.elapsed().as_secs_f64() * 1e3;
    let header = *response.user_header();
    let points = response.payload();
    let cloud = bdis_core::formats::ply::PointCloud {
        positions: points.iter().map(|p| p.xyz).collect(),
        colors: Some(points.iter().map(|p| p.rgb).collect()),
        scalars: vec![
            ("keyframe_id".into(), points.iter().map(|p| p.kf_id as f32).collect()),
            ("confidence".into(), points.iter().map(|p| f32::from(p.confidence) / 255.0).collect()),
        ],
        faces: Vec::new(),
    };
    bdis_core::formats::ply::write(&args.out, &cloud)?;
    println!(
        "{}: {} of {} map points (every {}), {} keyframes, {} pose corrections applied; round trip {:.1} ms",
        args.out.display(),
        points.len(),
        header.points_in_map,
        header.stride,
        header.keyframes,
        header.corrections_applied,
        round_trip_ms
    );
    Ok(())
}
