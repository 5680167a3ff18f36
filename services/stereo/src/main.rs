//! `bdis-stereo`: the dense stereo service. Until the tracker publishes keyframes, it takes every N-th frame from
//! acquisition as a keyframe, matches it in place in shared memory (BDIS or plain DIS), and publishes a depth
//! keyframe (disparity, confidence, RGB, intrinsics) written once into a loaned sample.
//!
//! Hot-swappable: started with `--standby` (by the launcher, for a swap or a restart), it opens its ports,
//! reports ready and waits for the launcher's activation, which comes after its predecessor has stopped and says
//! after which keyframe to resume. The tracker keeps its last keyframes in the topic's history, so the new
//! instance receives the ones its predecessor did not finish.
//!
//! With frames as input it is replaceable at any moment too: with on-demand pacing, acquisition sends a frame only when a consumer has released
//! the last one, and when a consumer joins it sends again the frames nobody released, so a new instance first
//! receives the frame its predecessor died on. A keyframe may therefore be published twice; consumers
//! de-duplicate by keyframe id.

mod node;

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Result, bail};
use bdis_stereo::{Matcher, Params};
use clap::Parser;

use node::{Config, Input};

/// Dense stereo service: frames in, depth keyframes out.
#[derive(Debug, Parser)]
// A later flag overrides an earlier one, so a swap can append `--algorithm dis` to the service's arguments.
#[command(name = "bdis-stereo", version, args_override_self = true)]
struct Args {
    /// Settings file: the camera (fx, fy, cx, cy, bf) and `BDISparam.*`.
    #[arg(long)]
    settings: PathBuf,
    /// Take every N-th frame as a keyframe (frame_seq divisible by N), with `--input frames`.
    #[arg(long, default_value_t = 5)]
    every: u64,
    /// `frames`: keyframes picked from acquisition's frames (no tracker); `keyframes`: the tracker's keyframes,
    /// with their poses.
    #[arg(long, default_value = "frames")]
    input: String,
    /// `bdis` or `dis` (plain DIS).
    #[arg(long, default_value = "bdis")]
    algorithm: String,
    /// Override a BDIS parameter, e.g. `--param patchsz=8` (repeatable).
    #[arg(long = "param", value_name = "NAME=VALUE")]
    params: Vec<String>,
    /// Open the ports, report ready, then wait for the launcher's activation before taking keyframes (a
    /// replacement instance: make-before-break).
    #[arg(long)]
    standby: bool,
    /// Name of this process in the run.
    #[arg(long, env = "BDIS_SERVICE_NAME", default_value = "stereo")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
}

fn main() -> ExitCode {
    bdis_node::init_logging();
    bdis_node::protect_patient_data();
    bdis_node::finish("bdis-stereo", run(Args::parse()))
}

/// Everything that can be wrong with the input is found here, before shared memory is touched.
fn run(args: Args) -> Result<()> {
    let settings = bdis_core::Settings::load(&args.settings)?;
    let mut params = Params::from_settings(&settings.bdis);
    params.apply_overrides(&args.params, &args.algorithm)?;
    if args.every == 0 {
        bail!("--every: must be ≥ 1");
    }
    let input = match args.input.as_str() {
        "frames" => Input::Frames { every: args.every },
        "keyframes" => Input::Keyframes { standby: args.standby },
        other => bail!("--input: `{other}` is not an input (frames, keyframes)"),
    };
    if args.standby && matches!(input, Input::Frames { .. }) {
        bail!("--standby: only with --input keyframes (with frames as input a new instance simply joins)");
    }
    let matcher = Matcher::new(params)?;
    let (Some(width), Some(height)) = (settings.camera.width, settings.camera.height) else {
        bail!(
            "{}: the stereo service needs `Camera.width` and `Camera.height` (it sizes its shared memory from them)",
            args.settings.display()
        );
    };
    let Some(camera) = settings.camera.rectified(width, height) else {
        bail!("{}: Camera.k1…: dense stereo needs rectified images (no distortion)", args.settings.display());
    };
    node::run(Config { matcher, camera, input, settings: args.settings, name: args.name, ipc_prefix: args.ipc_prefix })
}
