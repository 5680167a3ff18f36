//! `bdis-tracking`: the tracking service. Reads each frame's grey images in place in shared memory, tracks it
//! (`bdis-track`), and publishes a pose per frame, each new keyframe with its stereo images, pose and
//! intrinsics (for the dense stereo service), and the keyframes bundle adjustment moved. It never waits for a
//! consumer of its outputs: their topics overflow safely. On the end of the stream it writes the trajectory
//! (TUM and KITTI) and the keyframe trajectory into the run folder.

mod counts;
mod journal;
mod node;
mod quality_log;
mod world;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result, anyhow, bail};
use bdis_track::{Tracker, TrackerSettings};
use clap::Parser;

use journal::{Continuation, JournalWriter};

/// Tracking service: stereo frames in; poses, keyframes and pose corrections out.
#[derive(Debug, Parser)]
#[command(name = "bdis-tracking", version)]
struct Args {
    /// Settings file: the camera (fx, fy, cx, cy, bf, width, height, fps), `ThDepth`, `ORBextractor.*`.
    #[arg(long)]
    settings: PathBuf,
    /// Folder for the trajectories (default: the run folder the launcher gives, else the current folder).
    #[arg(long, env = "BDIS_RUN_DIR")]
    out: Option<PathBuf>,
    /// Where local bundle adjustment runs: `worker` (its own thread; the per-frame path never waits for it) or
    /// `inline` (in the tracking thread, at each keyframe: single-core targets, or measuring its cost).
    #[arg(long, default_value = "worker", value_parser = ["worker", "inline"])]
    ba: String,
    /// Keypoint measurements: `aligned` (each match moved to sub-pixel precision by aligning the patch its map
    /// point was first seen with; ATE 2–8× lower on the synthetic sequences, +1–2 ms per frame) or `whole-pixel`
    /// (ORB-SLAM2's FAST positions as they are).
    #[arg(long, default_value = "aligned", value_parser = ["aligned", "whole-pixel"])]
    measurements: String,
    /// Loop closing (`on`): a keyframe that comes back to tissue mapped long ago (outside the neighbourhood it
    /// was tracked in) is recognised as a loop, the two passes' points are fused, a drift beyond noise is
    /// corrected by a pose graph, then the whole map by a global bundle adjustment on worker threads, and
    /// every keyframe moved goes out as a correction. `off`: revisits are tied in by map reuse alone.
    #[arg(long, default_value = "on", value_parser = ["on", "off"])]
    loop_closing: String,
    /// Instruments in frames that come without a mask: `estimate` finds them (opaque grey regions from the image
    /// border, see bdis_track::instruments; smoke and membranes are veils and left; nothing on a view that is
    /// not tissue-coloured) and keeps them out of the pose, and sends the estimate with each keyframe so the
    /// dense map leaves them out too. `off`: none. A frame's own mask (`--masks` at acquisition) is always used.
    #[arg(long, default_value = "estimate", value_parser = ["estimate", "off"])]
    instrument_masks: String,
    /// Continue after a crashed predecessor: its journal (`tracking.journal` in the run folder) gives the frames
    /// it tracked, the keyframe ids it published and the world frame; a new map continues the same trajectory.
    #[arg(long)]
    resume: bool,
    /// Name of this process in the run.
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "tracking")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
}

fn main() -> ExitCode {
    bdis_node::init_logging();
    bdis_node::protect_patient_data();
    bdis_node::finish("bdis-tracking", run(Args::parse()))
}

/// Everything that can be wrong with the input is found here, before shared memory is touched.
fn run(args: Args) -> Result<()> {
    let settings = bdis_core::Settings::load(&args.settings)?;
    let (Some(width), Some(height)) = (settings.camera.width, settings.camera.height) else {
        bail!("{}: the tracker needs `Camera.width` and `Camera.height`", args.settings.display());
    };
    let Some(camera) = settings.camera.rectified(width, height) else {
        bail!("{}: Camera.k1…: stereo tracking needs rectified images (no distortion)", args.settings.display());
    };
    let tracker_settings = TrackerSettings {
        th_depth: settings.th_depth,
        fps: settings.fps,
        orb: bdis_orb::OrbParams::from_settings(&settings.orb),
    };
    let mut tracker = Tracker::new(camera, tracker_settings).with_context(|| format!("{}", args.settings.display()))?;
    tracker.set_worker_start(background_priority);
    if args.ba == "inline" {
        tracker.set_ba_mode(bdis_track::mapper::BaMode::Inline);
    }
    tracker.set_refinement(args.measurements == "aligned");
    tracker.set_loop_closing(args.loop_closing == "on");
    let out_dir = args.out.clone().unwrap_or_else(|| PathBuf::from("."));
    // What earlier instances of this run published (a restart after a crash), and this instance's own journal.
    let journal_path = out_dir.join("tracking.journal");
    let earlier = if args.resume && journal_path.is_file() {
        let text = std::fs::read_to_string(&journal_path)
            .with_context(|| format!("{}: cannot read", journal_path.display()))?;
        Continuation::parse(&text).map_err(|e| anyhow!("{}: {e}", journal_path.display()))?
    } else {
        Continuation::default()
    };
    let journal = JournalWriter::open(&journal_path, args.resume)
        .with_context(|| format!("{}: cannot open the tracking journal", journal_path.display()))?;
    let world = world::WorldFrame::continuing(&earlier);
    if let Some(seq) = earlier.last_frame_seq() {
        tracing::info!(
            "resuming after frame {seq}: {} frames and {} keyframes of earlier instances; keyframe ids from {}",
            earlier.frames.len(),
            earlier.keyframes.len(),
            world.kf_offset
        );
    }

    node::run(node::Config {
        tracker,
        earlier,
        world,
        journal,
        camera,
        n_features: settings.orb.n_features,
        instruments: (args.instrument_masks == "estimate")
            .then(|| bdis_track::instruments::InstrumentMasker::new(Default::default())),
        settings: args.settings,
        out_dir,
        name: args.name,
        ipc_prefix: args.ipc_prefix,
    })
}

/// The tracker's background threads (local bundle adjustment, loop closing) share the tracking core with the
/// frames and must yield to them: nice +10 gives them about a tenth of the core while a frame is being tracked,
/// all of it otherwise. Measured on a 1080p flight: while they competed as equals, frames that met a bundle
/// adjustment waited for the core (capture → pose p99 74 ms for 15 ms of CPU); yielding, 38 ms.
fn background_priority() {
    // SAFETY: gettid and setpriority only read their arguments and change the calling thread's own nice value.
    let (tid, result) = unsafe {
        let tid = libc::gettid();
        (tid, libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, 10))
    };
    if result != 0 {
        tracing::warn!("could not lower the priority of background thread {tid}: {}", std::io::Error::last_os_error());
    }
}
