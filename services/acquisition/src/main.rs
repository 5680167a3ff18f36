//! `bdis-acquisition`: reads a stereo sequence and publishes every frame once into shared memory.
//!
//! Shell only: check the input (before any shared memory exists), open the ports, then for each frame wait until
//! it is due, decode it straight into a loaned sample, send, notify, record timings. End of stream is a last
//! sample flagged `END_OF_STREAM`, so consumers finish cleanly, also after an error or a stop request.

mod credits;
mod input;
mod live;
mod node;
mod ports;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use bdis_ipc::FrameLayout;
use bdis_source::{Pacing, check_input};
use clap::Parser;

/// Publish a stereo image sequence into shared memory, frame by frame.
#[derive(Debug, Parser)]
#[command(name = "bdis-acquisition", version)]
struct Args {
    /// Sequence folder: BDIS-SLAM/Hamlyn (`images_rectified/{left,right}`), plain (`left/`, `right/`) or KITTI
    /// (`image_0/`, `image_1/`); a stereo video (`video:top-bottom:FILE`, `video:side-by-side:FILE`,
    /// `video:two-files:LEFT,RIGHT`, decoded by ffmpeg, timestamps from the container); or
    /// `synthetic:<scene>[:<trajectory>][:<frames>]` (e.g. `synthetic:colon`, `synthetic:abdomen:hover:90`),
    /// rendered before streaming into the run folder (or a temporary folder); or a live source, paced by its
    /// devices: `live:v4l2:side-by-side:/dev/video0`, `live:v4l2:top-bottom:/dev/video0`,
    /// `live:v4l2:two-devices:/dev/video0,/dev/video2`, or an emulated device replaying a folder of pairs,
    /// `live:emulated:<side-by-side|top-bottom|two-devices>:<yuyv|nv12|mjpeg>:<rate>hz:DIR`.
    #[arg(long)]
    sequence: PathBuf,
    /// Settings file (ORB-SLAM2 YAML or bdis-slam TOML); checked against the images.
    #[arg(long)]
    settings: Option<PathBuf>,
    /// `on-demand` (next frame when a consumer asks), `recorded` (follow times.txt), a rate such as `30hz`, or
    /// `on-demand:30hz` (when a consumer asks, but no faster than the rate: never drops a frame).
    #[arg(long, default_value = "on-demand")]
    pacing: Pacing,
    /// A raw stereo calibration (any layout `bdis-slam calib show` reads): every frame is rectified with it as
    /// it is read, straight into the shared-memory frame. `--settings` then describes the rectified camera
    /// (`bdis-slam run` writes it).
    #[arg(long, value_name = "FILE")]
    calibration: Option<PathBuf>,
    /// With --calibration: Bouguet's free scaling (0 keeps only valid pixels, 1 every source pixel; unset keeps
    /// the cameras' mean focal length).
    #[arg(long, requires = "calibration")]
    alpha: Option<f64>,
    /// Interlaced frames (1080i): publish one field of each (`top-field`, `bottom-field`: half the rows; the
    /// settings then describe the field's camera, fy and cy halved — `bdis-slam run --interlaced` writes them)
    /// or the top field with the other rows interpolated (`bob`: same size and camera).
    #[arg(long, value_name = "MODE", conflicts_with = "calibration")]
    interlaced: Option<bdis_source::FieldMode>,
    /// Per-frame masks of instruments (or anything else to keep out of the pose and the map), e.g. from a tool
    /// segmentation network: one PNG per frame, non-zero = keep out, of the published frames' size, named like
    /// the left images (`left/000123.jpg` → `DIR/000123.png`; for a video `DIR/1.png` is the first frame).
    /// They travel with each frame in shared memory; the tracker takes no feature and the stereo no depth there
    #[arg(long, value_name = "DIR")]
    masks: Option<PathBuf>,
    /// Skip the first N frames (a video is decoded from frame N, exactly).
    #[arg(long, default_value_t = 0, value_name = "N")]
    start: usize,
    /// Stop after this many frames.
    #[arg(long, visible_alias = "frames")]
    max_frames: Option<usize>,
    /// Name of this process in the run (telemetry, logs).
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "acquisition")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
    /// Only check the sequence and settings, print a summary, and exit.
    #[arg(long)]
    check: bool,
}

fn main() -> ExitCode {
    bdis_node::init_logging();
    bdis_node::protect_patient_data();
    bdis_node::finish("bdis-acquisition", run(Args::parse()))
}

/// The input is rendered (a synthetic source) and checked here, before any shared memory exists.
fn run(args: Args) -> Result<()> {
    if let Some(spec) = args.sequence.to_str().and_then(bdis_source::LiveSpec::parse) {
        return run_live(args, spec?);
    }
    let (sequence_dir, settings) = match args.sequence.to_str().and_then(bdis_source::parse_synthetic) {
        Some(request) => {
            let request = request.map_err(anyhow::Error::msg)?;
            let base = std::env::var_os("BDIS_RUN_DIR").map(PathBuf::from).unwrap_or_else(std::env::temp_dir);
            let dir = base.join(format!("synthetic-{}-{}", request.scene, std::process::id()));
            tracing::info!("rendering {} frames of `{}` into {}", request.frames, request.scene, dir.display());
            let frames = request.frames;
            let (dir, rendered_settings) = bdis_source::render_synthetic(&request, &dir, |i| {
                if (i + 1) % 10 == 0 || i + 1 == frames {
                    tracing::info!("rendered {}/{frames}", i + 1);
                }
            })?;
            (dir, Some(args.settings.clone().unwrap_or(rendered_settings)))
        }
        None => (args.sequence.clone(), args.settings.clone()),
    };
    // Interlaced: the settings describe the published fields, not the woven frames; checked against those.
    let checked_settings = if args.interlaced.is_some() { None } else { settings.as_deref() };
    let mut input = check_input(&sequence_dir, checked_settings)?;
    if args.start > 0 {
        input.sequence.skip(args.start)?;
    }
    let sequence = &input.sequence;
    let rectifier = match &args.calibration {
        Some(path) => Some(input::rectifier(path, (sequence.width, sequence.height), args.alpha)?),
        None => None,
    };
    let (width, height) = match args.interlaced {
        Some(mode) => mode.output_size(sequence.width, sequence.height).with_context(|| {
            format!(
                "{}: {}×{} frames cannot be split into fields",
                sequence.root.display(),
                sequence.width,
                sequence.height
            )
        })?,
        None => rectifier.as_ref().map_or((sequence.width, sequence.height), |r| r.rectified_size()),
    };
    if let (Some(_), Some(path)) = (args.interlaced, &settings) {
        input::adopt_settings(&mut input, path, (width, height))?;
    }
    let sequence = &input.sequence;
    let images = FrameLayout::packed(width, height)
        .with_context(|| format!("{}: {width}×{height} images are too large", sequence.root.display()))?;
    let masks = match &args.masks {
        Some(dir) => Some(bdis_source::MaskFolder::open(dir, sequence, width, height)?),
        None => None,
    };
    let layout = match masks {
        Some(_) => images.with_mask_plane().with_context(|| {
            format!("{}: {width}×{height} images and a mask are too large", sequence.root.display())
        })?,
        None => images,
    };
    let frame_count = args.max_frames.map_or(sequence.len(), |m| m.min(sequence.len()));
    if args.check {
        input::print_check(sequence);
        return Ok(());
    }

    node::run(node::Config {
        rectifier,
        fields: args.interlaced,
        masks,
        schedule_fps: input.fps.unwrap_or(30.0),
        input,
        layout,
        frame_count,
        pacing: args.pacing,
        name: args.name,
        ipc_prefix: args.ipc_prefix,
    })
}

/// A live source: paced by its devices, so no --pacing.
fn run_live(args: Args, spec: bdis_source::LiveSpec) -> Result<()> {
    if args.masks.is_some() {
        anyhow::bail!("`{}`: --masks names masks per file; a live source has none (leave out --masks)", spec.text);
    }
    if args.pacing != Pacing::OnDemand {
        anyhow::bail!("`{}`: a live source is paced by its devices; leave out --pacing", spec.text);
    }
    live::open_and_run(live::Options {
        spec,
        settings: args.settings,
        start: args.start,
        max_frames: args.max_frames,
        interlaced: args.interlaced,
        calibration: args.calibration.map(|path| (path, args.alpha)),
        check: args.check,
        name: args.name,
        ipc_prefix: args.ipc_prefix,
    })
}
