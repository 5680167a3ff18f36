//! `bdis-slam`: the one command users type. Subcommands are thin: each parses its arguments and calls the
//! library (`bdis_slam`) or a service library.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod bench_cmd;
mod calib_cmd;
mod demo_cmd;
mod eval_cmd;
mod eval_masks;
mod eval_plot;
mod fields;
mod map_cmd;
mod plan;
mod probe_cmd;
mod run_cmd;
mod snapshot_cmd;
mod stereo_cmd;
mod swap_cmd;
mod synth_cmd;
mod top_cmd;
mod view_cmd;

/// bdis-slam: lightweight CPU-only dense stereo SLAM for minimally invasive surgery, as separate processes
/// over zero-copy shared memory.
#[derive(Debug, Parser)]
#[command(name = "bdis-slam", version, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// Let the user's group read what a run writes (folders 0750, files 0640). By default run folders and their
    /// files — images, maps, previews, logs — are readable by their owner only (0700, 0600): they hold patient
    /// data.
    #[arg(long, global = true, env = bdis_ipc::process::SHARE_WITH_GROUP_ENV)]
    share_with_group: bool,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Start a pipeline from a launch file or a sequence, wait for its end, and report per-process latency.
    Run(run_cmd::RunArgs),
    /// Subscribe to a live topic and print its rate, age and hop latency (like `ros2 topic hz`).
    Probe(probe_cmd::ProbeArgs),
    /// The built-in demo: render a synthetic stereo endoscope sweep and run the pipeline over it.
    Demo(demo_cmd::DemoArgs),
    /// Dense stereo (BDIS or plain DIS) on one rectified pair or a whole sequence: disparity, confidence, preview.
    Stereo(stereo_cmd::StereoArgs),
    /// Build the dense map offline from a sequence and a trajectory (BDIS + mosaic): map.ply, map.png, map.bin.
    Map(map_cmd::MapArgs),
    /// A live view of a running pipeline: every service's rate, latency, CPU and core, redrawn in place.
    Top(top_cmd::TopArgs),
    /// Benchmarks of the whole pipeline (`bench isolation`).
    #[command(subcommand)]
    Bench(bench_cmd::BenchCommand),
    /// Replace a service of a running pipeline without stopping it (make-before-break), e.g. the dense stereo
    /// with another algorithm, parameters or binary; `--kill` drills a crash instead.
    Swap(swap_cmd::SwapArgs),
    /// Ask a running mosaic service for its current map and write it as PLY (what a viewer does).
    Snapshot(snapshot_cmd::SnapshotArgs),
    /// Write a synthetic stereo endoscopy sequence with exact ground truth (poses, depth, disparity, mesh).
    Synth(synth_cmd::SynthArgs),
    /// Stereo calibration files: `calib show FILE` prints what a file says and the rectification it gives.
    #[command(subcommand)]
    Calib(calib_cmd::CalibCommand),
    /// Rectify a raw stereo sequence with its calibration (distortion removed, rows aligned): rectified pairs,
    /// `times.txt` and the rectified `settings.yaml`, ready for `run`.
    Rectify(calib_cmd::RectifyArgs),
    /// Look at a finished run in a browser: the dense map, the scope's path, the depth and every process's
    /// health, served as a local web page (nothing leaves the machine).
    View(view_cmd::ViewArgs),
    /// Score results against ground truth: trajectories, maps, disparity.
    #[command(subcommand)]
    Eval(eval_cmd::EvalCommand),
}

fn main() -> ExitCode {
    bdis_ipc::process::init_logging();
    let cli = Cli::parse();
    if cli.share_with_group {
        // SAFETY: before any thread exists; the services started later inherit the setting.
        unsafe { std::env::set_var(bdis_ipc::process::SHARE_WITH_GROUP_ENV, "1") };
    }
    bdis_ipc::process::private_files();
    let result = match cli.command {
        Command::Run(args) => run_cmd::run(args),
        Command::Probe(args) => probe_cmd::probe(args).map(|()| ExitCode::SUCCESS),
        Command::Demo(args) => demo_cmd::demo(args),
        Command::Stereo(args) => stereo_cmd::stereo(args).map(|()| ExitCode::SUCCESS),
        Command::Map(args) => {
            // Its files are written before the summary line is printed.
            quiet_on_closed_pipe();
            map_cmd::map(args).map(|()| ExitCode::SUCCESS)
        }
        Command::Snapshot(args) => snapshot_cmd::snapshot(args).map(|()| ExitCode::SUCCESS),
        Command::Swap(args) => swap_cmd::swap(args).map(|()| ExitCode::SUCCESS),
        Command::Bench(bench_cmd::BenchCommand::Isolation(args)) => bench_cmd::bench_isolation(args),
        Command::Top(args) => top_cmd::top(args).map(|()| ExitCode::SUCCESS),
        Command::Eval(command) => {
            quiet_on_closed_pipe();
            eval_cmd::eval(command).map(|()| ExitCode::SUCCESS)
        }
        Command::Calib(command) => calib_cmd::calib(command).map(|()| ExitCode::SUCCESS),
        Command::Rectify(args) => calib_cmd::rectify(args).map(|()| ExitCode::SUCCESS),
        Command::View(args) => view_cmd::view(args).map(|()| ExitCode::SUCCESS),
        Command::Synth(args) => synth_cmd::synth(args).map(|()| ExitCode::SUCCESS),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("bdis-slam: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// A report piped into `head` ends quietly, as other command-line tools do, instead of panicking on the closed
/// pipe. Only for commands that start no process and hold no shared memory, so dying on SIGPIPE loses nothing.
fn quiet_on_closed_pipe() {
    // SAFETY: restoring the default disposition of SIGPIPE before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
