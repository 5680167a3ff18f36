//! `bdis-slam`: the one command users type. Subcommands are thin: each parses its arguments and calls the
//! library (`bdis_slam`) or a service library.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

mod eval_cmd;
mod map_cmd;
mod probe_cmd;
mod snapshot_cmd;
mod stereo_cmd;
mod swap_cmd;
mod synth_cmd;
mod top_cmd;

/// bdis-slam: lightweight CPU-only dense stereo SLAM for minimally invasive surgery, as separate processes
/// over zero-copy shared memory.
#[derive(Debug, Parser)]
#[command(name = "bdis-slam", version, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Start a pipeline from a launch file or a sequence, wait for its end, and report per-process latency.
    Run(RunArgs),
    /// Subscribe to a live topic and print its rate, age and hop latency (like `ros2 topic hz`).
    Probe(probe_cmd::ProbeArgs),
    /// The built-in demo: render a synthetic stereo endoscope sweep and run the pipeline over it.
    Demo(DemoArgs),
    /// Dense stereo (BDIS or plain DIS) on one rectified pair or a whole sequence: disparity, confidence, preview.
    Stereo(stereo_cmd::StereoArgs),
    /// Build the dense map offline from a sequence and a trajectory (BDIS + mosaic): map.ply, map.png, map.bin.
    Map(map_cmd::MapArgs),
    /// A live view of a running pipeline: every service's rate, latency, CPU and core, redrawn in place.
    Top(top_cmd::TopArgs),
    /// Benchmarks of the whole pipeline (`bench isolation`).
    #[command(subcommand)]
    Bench(BenchCommand),
    /// Replace a service of a running pipeline without stopping it (make-before-break), e.g. the dense stereo
    /// with another algorithm, parameters or binary; `--kill` drills a crash instead.
    Swap(swap_cmd::SwapArgs),
    /// Ask a running mosaic service for its current map and write it as PLY (what a viewer does).
    Snapshot(snapshot_cmd::SnapshotArgs),
    /// Write a synthetic stereo endoscopy sequence with exact ground truth (poses, depth, disparity, mesh).
    Synth(synth_cmd::SynthArgs),
    /// Score results against ground truth: trajectories, maps, disparity.
    #[command(subcommand)]
    Eval(eval_cmd::EvalCommand),
}

#[derive(Debug, clap::Subcommand)]
enum BenchCommand {
    /// Does the dense mapper slow the tracker? Runs the sequence alternately with the tracker alone
    /// (acquisition → tracking) and with the dense stereo and the mosaic on the other core, and reports the
    /// tracker's time per frame in both (median of the per-pair ratios, and their spread).
    Isolation(IsolationArgs),
}

#[derive(Debug, clap::Args)]
struct IsolationArgs {
    /// Sequence folder (a synthetic one comes with its settings.yaml).
    #[arg(long)]
    sequence: PathBuf,
    /// Settings (default: the sequence's settings.yaml).
    #[arg(long)]
    settings: Option<PathBuf>,
    /// Pairs of runs (alone, with the dense mapper), in alternating order.
    #[arg(long, default_value_t = 3)]
    pairs: usize,
    /// Folder for the runs and isolation.json (default: runs/<UTC time>-isolation).
    #[arg(long)]
    out: Option<PathBuf>,
}

#[derive(Debug, clap::Args)]
struct DemoArgs {
    /// Frames to render.
    #[arg(long, default_value_t = 45)]
    frames: usize,
    /// Run folder to write (default: runs/<UTC time>-demo).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Pacing: on-demand (as fast as the pipeline consumes), recorded (30 fps), or a rate such as 60hz.
    #[arg(long, default_value = "on-demand")]
    pacing: bdis_source::Pacing,
}

#[derive(Debug, clap::Args)]
struct RunArgs {
    /// Launch file (`launch/*.toml`). Without it, give --sequence (and --settings).
    #[arg(conflicts_with_all = ["sequence"])]
    launch_file: Option<PathBuf>,
    /// Sequence folder to stream (BDIS-SLAM/Hamlyn, plain left/right, or KITTI layout), or
    /// `synthetic:<scene>[:<trajectory>][:<frames>]` (rendered first, e.g. `synthetic:abdomen:sweep:90`).
    #[arg(long, required_unless_present = "launch_file")]
    sequence: Option<PathBuf>,
    /// Settings file for --sequence (ORB-SLAM2 YAML or bdis-slam TOML).
    #[arg(long, requires = "sequence")]
    settings: Option<PathBuf>,
    /// Pacing for --sequence: on-demand, recorded, a rate such as 30hz (frames a slow consumer misses are
    /// dropped, as with a live camera), or on-demand:30hz (a live camera's pace that never drops a frame).
    #[arg(long, default_value = "on-demand", requires = "sequence")]
    pacing: bdis_source::Pacing,
    /// Have the probe checksum every frame's pixels (for integrity checks; costs ~1 ms per VGA frame).
    #[arg(long, requires = "sequence")]
    checksums: bool,
    /// Also run the stereo service, taking every N-th frame as a keyframe (needs --settings with the image
    /// size); the probe then checks the depth keyframes.
    #[arg(long, requires = "sequence", value_name = "N")]
    stereo_every: Option<u64>,
    /// Run the full pipeline on --sequence: acquisition → tracking → dense stereo on the tracker's keyframes →
    /// mosaic; writes the trajectory (TUM, KITTI), the keyframe trajectory and the dense map (map.ply, map.png,
    /// map.bin) into the run folder. Needs the camera (--settings, or the settings.yaml a synthetic sequence
    /// comes with).
    #[arg(long, requires = "sequence", conflicts_with_all = ["stereo_every", "checksums"])]
    track: bool,
    /// With --track: override a map parameter of the mosaic, e.g. `--map-param fusion=weighted` (repeatable;
    /// see `bdis-mosaic --help`).
    #[arg(long = "map-param", value_name = "NAME=VALUE", requires = "track")]
    map_params: Vec<String>,
    /// Run folder to write (default: runs/<UTC time>-<name>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Shared-memory name prefix (default: a fresh one per run, so runs never see each other).
    #[arg(long)]
    ipc_prefix: Option<String>,
}

fn main() -> ExitCode {
    bdis_ipc::process::init_logging();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Run(args) => run(args),
        Command::Probe(args) => probe_cmd::probe(args).map(|()| ExitCode::SUCCESS),
        Command::Demo(args) => demo(args),
        Command::Stereo(args) => stereo_cmd::stereo(args).map(|()| ExitCode::SUCCESS),
        Command::Map(args) => {
            // Its files are written before the summary line is printed.
            quiet_on_closed_pipe();
            map_cmd::map(args).map(|()| ExitCode::SUCCESS)
        }
        Command::Snapshot(args) => snapshot_cmd::snapshot(args).map(|()| ExitCode::SUCCESS),
        Command::Swap(args) => swap_cmd::swap(args).map(|()| ExitCode::SUCCESS),
        Command::Bench(BenchCommand::Isolation(args)) => bench_isolation(args),
        Command::Top(args) => top_cmd::top(args).map(|()| ExitCode::SUCCESS),
        Command::Eval(command) => {
            quiet_on_closed_pipe();
            eval_cmd::eval(command).map(|()| ExitCode::SUCCESS)
        }
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

/// The launch plan `run --sequence` builds: acquisition, then the probe as its consumer.
fn plan_for_sequence(
    sequence: &Path,
    settings: Option<&Path>,
    pacing: bdis_source::Pacing,
    checksums: bool,
    stereo_every: Option<u64>,
    track: bool,
    map_params: &[String],
) -> Result<bdis_slam::launch_file::LaunchFile> {
    use bdis_slam::launch_file::{LaunchFile, RunSection, ServiceSpec};
    // Check the input before anything starts: a bad sequence or settings file is reported here, by file and
    // field, and no process or shared memory is created.
    let input = bdis_source::check_input(sequence, settings)?;
    let absolute = |p: &Path| std::fs::canonicalize(p).with_context(|| format!("{}: cannot resolve", p.display()));
    let mut acquisition_args = vec!["--sequence".to_string(), absolute(&input.sequence.root)?.display().to_string()];
    if let Some(settings) = &input.settings_path {
        acquisition_args.extend(["--settings".to_string(), absolute(settings)?.display().to_string()]);
    }
    let pacing = match pacing {
        bdis_source::Pacing::OnDemand => "on-demand".to_string(),
        bdis_source::Pacing::Recorded => "recorded".to_string(),
        bdis_source::Pacing::Fixed(hz) => format!("{hz}hz"),
        bdis_source::Pacing::OnDemandAtMost(hz) => format!("on-demand:{hz}hz"),
    };
    acquisition_args.extend(["--pacing".to_string(), pacing]);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let name = sequence.file_name().map_or_else(|| "sequence".into(), |n| n.to_string_lossy().into_owned());
    let spec = |name: &str, binary: &str, args: Vec<String>, core: usize| ServiceSpec {
        name: name.into(),
        binary: binary.into(),
        args,
        core: Some(core % cores),
        env: Default::default(),
        restart: Default::default(),
        liveness_s: None,
        handover: None,
        replacement_args: Vec::new(),
    };
    let mut services = vec![spec("acquisition", "bdis-acquisition", acquisition_args, 0)];
    if track {
        let Some(settings) = &input.settings_path else {
            anyhow::bail!("--track needs --settings (the tracker reads the camera and ORB settings from it)")
        };
        let settings = absolute(settings)?.display().to_string();
        // Acquisition and tracking share core 0; the dense stereo (and its consumer) run on core 1, so the dense
        // mapper does not slow the tracker.
        // A crashed tracker is restarted and continues from its journal: the same world frame, keyframe ids after
        // the last published one; acquisition sends it again the frame the dead one held.
        let mut tracking = spec("tracking", "bdis-tracking", vec!["--settings".into(), settings.clone()], 0);
        tracking.restart.policy = bdis_slam::launch_file::RestartPolicy::OnFailure;
        tracking.restart.backoff_initial_s = 0.1;
        tracking.replacement_args = vec!["--resume".into()];
        services.push(tracking);
        // The stereo service is replaceable while the tracker runs (`bdis-slam swap stereo`) and restarted when
        // it crashes: the tracker keeps its last keyframes in the topic's history, and a new instance resumes
        // after the last keyframe the mosaic has.
        let mut stereo =
            spec("stereo", "bdis-stereo", vec!["--settings".into(), settings, "--input".into(), "keyframes".into()], 1);
        stereo.handover = Some(bdis_slam::launch_file::Handover::Keyframes);
        stereo.restart.policy = bdis_slam::launch_file::RestartPolicy::OnFailure;
        stereo.liveness_s = Some(10.0);
        services.push(stereo);
        let mut mosaic_args = Vec::new();
        for p in map_params {
            mosaic_args.extend(["--map-param".to_string(), p.clone()]);
        }
        // A crashed mosaic is restarted from its last checkpoint (every 4 keyframes, well within the tracker's
        // keyframe history of 16), and the launcher has the stereo service redo the keyframes after it.
        mosaic_args.extend(["--save-every".to_string(), "4".to_string()]);
        let mut mosaic = spec("mosaic", "bdis-mosaic", mosaic_args, 1);
        mosaic.restart.policy = bdis_slam::launch_file::RestartPolicy::OnFailure;
        // Keyframes pass quickly (up to 14 per second): come back fast, so the tracker's history still has them.
        mosaic.restart.backoff_initial_s = 0.1;
        mosaic.replacement_args = vec!["--resume".into()];
        services.push(mosaic);
        // The probe keeps a preview of the last depth keyframe beside the map.
        services.push(spec(
            "probe",
            "bdis-slam",
            vec!["probe".into(), "depth".into(), "--preview".into(), "${RUN_DIR}/depth-preview.png".into()],
            1,
        ));
        // The launcher's own work (forking a replacement stereo, draining telemetry) stays off the tracker's core.
        let run = RunSection { name: Some(name), launcher_core: Some(1 % cores), ..Default::default() };
        return Ok(LaunchFile { run, services });
    }
    match (stereo_every, &input.settings_path) {
        (Some(every), Some(settings)) => {
            let settings = absolute(settings)?.display().to_string();
            services.push(spec(
                "stereo",
                "bdis-stereo",
                vec!["--settings".into(), settings, "--every".into(), every.to_string()],
                1,
            ));
            services.push(spec(
                "probe",
                "bdis-slam",
                vec!["probe".into(), "depth".into(), "--preview".into(), "${RUN_DIR}/depth-preview.png".into()],
                0,
            ));
        }
        (Some(_), None) => {
            anyhow::bail!("--stereo-every needs --settings (the stereo service reads the camera from it)")
        }
        (None, _) => {
            let mut probe_args = vec!["probe".to_string(), "frames".to_string()];
            if checksums {
                probe_args.push("--checksums".into());
            }
            services.push(spec("probe", "bdis-slam", probe_args, 1));
        }
    }
    Ok(LaunchFile { run: RunSection { name: Some(name), ..Default::default() }, services })
}

fn run(args: RunArgs) -> Result<ExitCode> {
    use bdis_slam::launch_file::LaunchFile;
    // A synthetic source is rendered here first (with a progress bar), then streamed like any sequence.
    let mut rendered: Option<(PathBuf, PathBuf)> = None;
    if let Some(request) = args.sequence.as_ref().and_then(|s| s.to_str()).and_then(bdis_source::parse_synthetic) {
        let request = request.map_err(anyhow::Error::msg)?;
        let run_dir = make_run_dir(args.out.as_deref(), &format!("synthetic-{}", request.scene))?;
        let sequence = run_dir.join("sequence");
        let written = synth_cmd::render_with_progress(&sequence, &bdis_synth::StereoRig::default(), &request)?;
        let settings = args.settings.clone().unwrap_or(written.settings);
        rendered = Some((run_dir, settings));
    }
    let (launch, launch_path) = match (&args.launch_file, &args.sequence, &rendered) {
        (Some(path), _, _) => (LaunchFile::load(path)?, path.clone()),
        (None, Some(_), Some((run_dir, settings))) => (
            plan_for_sequence(
                &run_dir.join("sequence"),
                Some(settings),
                args.pacing,
                args.checksums,
                args.stereo_every,
                args.track,
                &args.map_params,
            )?,
            PathBuf::from("launch.toml"),
        ),
        (None, Some(sequence), None) => (
            plan_for_sequence(
                sequence,
                args.settings.as_deref(),
                args.pacing,
                args.checksums,
                args.stereo_every,
                args.track,
                &args.map_params,
            )?,
            PathBuf::from("launch.toml"),
        ),
        (None, None, _) => anyhow::bail!("give a launch file or --sequence"),
    };
    let name = launch.run.name.clone().unwrap_or_else(|| "run".into());
    let run_dir = match rendered {
        Some((run_dir, _)) => run_dir,
        None => make_run_dir(args.out.as_deref(), &name)?,
    };
    let (code, _) = execute_and_report(&launch, &launch_path, &run_dir, args.ipc_prefix.clone())?;
    Ok(code)
}

/// A report piped into `head` ends quietly, as other command-line tools do, instead of panicking on the closed
/// pipe. Only for commands that start no process and hold no shared memory, so dying on SIGPIPE loses nothing.
fn quiet_on_closed_pipe() {
    // SAFETY: restoring the default disposition of SIGPIPE before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

fn make_run_dir(out: Option<&Path>, name: &str) -> Result<PathBuf> {
    match out {
        Some(dir) => {
            std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the run folder", dir.display()))?;
            Ok(dir.to_path_buf())
        }
        None => {
            bdis_slam::run_dir::create_run_dir(Path::new("runs"), name).context("runs/: cannot create the run folder")
        }
    }
}

/// Starts the plan, waits for its end, writes `latency.json`, prints the latency table; the exit code says how
/// the run ended.
fn execute_and_report(
    launch: &bdis_slam::launch_file::LaunchFile,
    launch_path: &Path,
    run_dir: &Path,
    ipc_prefix: Option<String>,
) -> Result<(ExitCode, bdis_slam::run::RunResult)> {
    execute_and_write(launch, launch_path, run_dir, ipc_prefix, true)
}

/// [`execute_and_report`], with the printed report optional (the benchmark runs many).
fn execute_and_write(
    launch: &bdis_slam::launch_file::LaunchFile,
    launch_path: &Path,
    run_dir: &Path,
    ipc_prefix: Option<String>,
    print: bool,
) -> Result<(ExitCode, bdis_slam::run::RunResult)> {
    let run_dir = run_dir.to_path_buf();
    let name = launch.run.name.clone().unwrap_or_else(|| "run".into());
    let services = launch.resolve(launch_path, &run_dir)?;
    let launch_text = toml::to_string_pretty(launch).context("serialise the launch plan")?;
    std::fs::write(run_dir.join("launch.toml"), launch_text)
        .with_context(|| format!("{}: cannot write launch.toml", run_dir.display()))?;
    let prefix = ipc_prefix.unwrap_or_else(bdis_slam::run_dir::unique_prefix);
    if print {
        eprintln!("bdis-slam: run `{name}` → {} (shared memory prefix {prefix})", run_dir.display());
    }
    // Tools find the running pipeline by its folder (`bdis-slam swap stereo --run DIR`, `top --run DIR`).
    let prefix_file = run_dir.join(bdis_slam::run_dir::PREFIX_FILE);
    std::fs::write(&prefix_file, format!("{prefix}\n"))
        .with_context(|| format!("{}: cannot write", prefix_file.display()))?;

    let result = bdis_slam::run::execute(launch, &services, &prefix, &run_dir)?;
    let leftovers = bdis_slam::run_dir::remove_leftovers(&prefix);
    tracing::debug!("removed {leftovers} shared-memory leftovers of {prefix}");

    let json = serde_json::json!({
        "schema": "bdis.v1.run",
        "name": name,
        "ipc_prefix": prefix,
        "duration_s": result.duration_s,
        "stop_requested": result.stop_requested,
        "failure": result.failure,
        "services": result.services,
        "processes": result.latency.processes,
        "hops": result.latency.hops,
        "end_to_end": result.latency.end_to_end,
        "events": result.events,
        "telemetry_records_lost": result.latency.telemetry_records_lost,
    });
    let latency_path = run_dir.join("latency.json");
    std::fs::write(&latency_path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("{}: cannot write", latency_path.display()))?;
    let plot_path = run_dir.join("latency.svg");
    std::fs::write(&plot_path, result.latency.svg())
        .with_context(|| format!("{}: cannot write", plot_path.display()))?;

    if print {
        println!();
        print!("{}", result.latency.table());
        println!();
        for s in &result.services {
            let restarts = if s.restarts > 0 { format!(" ({} restarts/swaps)", s.restarts) } else { String::new() };
            println!(
                "{:<14} {}{restarts}{}",
                s.name,
                s.exit,
                s.error.as_deref().map_or(String::new(), |e| format!(" — {e}"))
            );
        }
        for e in &result.events {
            println!("  {e}");
        }
        println!("run folder: {} ({:.1} s)", run_dir.display(), result.duration_s);
    }
    if let Some(failure) = &result.failure {
        eprintln!("bdis-slam: error: {failure}");
        return Ok((ExitCode::FAILURE, result));
    }
    let code = if result.stop_requested { ExitCode::from(130) } else { ExitCode::SUCCESS };
    Ok((code, result))
}

fn demo(args: DemoArgs) -> Result<ExitCode> {
    anyhow::ensure!(args.frames >= 2 && args.frames <= 100_000, "--frames: give 2 to 100000 frames");
    let run_dir = make_run_dir(args.out.as_deref(), "demo")?;
    let sequence = run_dir.join("sequence");
    let rig = bdis_synth::StereoRig::default();
    let fps = 30.0;
    eprintln!(
        "bdis-slam demo: rendering {} stereo frames of a flight through a synthetic colon into {}",
        args.frames,
        sequence.display()
    );
    let request = bdis_synth::SceneRequest { frames: args.frames, fps, ..Default::default() };
    let written = synth_cmd::render_with_progress(&sequence, &rig, &request)?;
    let settings = written.settings;
    let preview = run_dir.join("preview.png");
    write_side_by_side(&sequence.join("left/1.png"), &sequence.join("right/1.png"), &preview)?;

    let launch = plan_for_sequence(&sequence, Some(&settings), args.pacing, false, None, true, &[])?;
    let (code, result) = execute_and_report(&launch, Path::new("launch.toml"), &run_dir, None)?;
    let find = |name: &str| result.latency.processes.iter().find(|p| p.name == name);
    let depth: Option<bdis_slam::probe::DepthSummary> =
        std::fs::read_to_string(run_dir.join("probe.json")).ok().and_then(|t| serde_json::from_str(&t).ok());
    println!();
    println!("demo summary");
    println!(
        "  frames      {} rendered, {} published by acquisition, {} tracked",
        args.frames,
        find("acquisition").map_or(0, |p| p.messages),
        find("tracking").map_or(0, |p| p.messages)
    );
    // The trajectory against the renderer's ground truth.
    let trajectory = (|| -> Result<(bdis_eval::traj::Ate, f64, usize)> {
        use bdis_core::formats::trajectory::read_tum;
        let gt = read_tum(&sequence.join("gt/poses.tum"))?;
        let est = read_tum(&run_dir.join("trajectory.tum"))?;
        let ate = bdis_eval::traj::ate(&gt, &est, 0.01)?;
        let length: f64 = gt
            .windows(2)
            .map(|w| (w[1].world_from_camera.translation.vector - w[0].world_from_camera.translation.vector).norm())
            .sum();
        let keyframes = read_tum(&run_dir.join("keyframes.tum"))?.len();
        Ok((ate, length, keyframes))
    })();
    match &trajectory {
        Ok((ate, length, keyframes)) => println!(
            "  tracking    {keyframes} keyframes; ATE RMSE {:.3} mm over a {:.1} mm path ({:.2} %), vs the renderer's ground truth",
            ate.translation.rmse,
            length,
            100.0 * ate.translation.rmse / length.max(1e-9)
        ),
        Err(e) => println!("  tracking    no trajectory to evaluate ({e:#})"),
    }
    let tracking: Option<serde_json::Value> =
        std::fs::read_to_string(run_dir.join("tracking.json")).ok().and_then(|t| serde_json::from_str(&t).ok());
    if let Some(t) = &tracking {
        let ms = |key: &str| t[key].as_f64().unwrap_or(f64::NAN);
        println!(
            "  tracking    CPU per frame p50 {:.1} ms (ORB on both images, stereo matching, pose, local map), per keyframe {:.1} ms; {} frames lost",
            ms("frame_cpu_ms_p50"),
            ms("keyframe_cpu_ms_p50"),
            t["lost"]
        );
    }
    if let Some(d) = &depth {
        println!(
            "  dense       {} depth keyframes from the tracker's keyframes, mean density {:.1} % of pixels",
            d.keyframe_ids.len(),
            100.0 * d.mean_density
        );
    }
    if let Some(s) = find("stereo").and_then(|p| p.processing_us) {
        println!(
            "  stereo      BDIS per keyframe p50 {:.1} ms, p99 {:.1} ms (matching and publishing 640×480)",
            s.p50 / 1000.0,
            s.p99 / 1000.0
        );
    }
    let mosaic: Option<serde_json::Value> =
        std::fs::read_to_string(run_dir.join("mosaic.json")).ok().and_then(|t| serde_json::from_str(&t).ok());
    if let Some(m) = &mosaic {
        println!(
            "  map         {} points from {} keyframes ({} pose corrections applied), update p50 {:.1} ms per keyframe",
            m["points"],
            m["keyframes_inserted"],
            m["corrections_applied"],
            m["update_ms_p50"].as_f64().unwrap_or(f64::NAN)
        );
        // The map against the renderer's mesh, brought into its frame by the alignment of the keyframe trajectory
        // (the poses that place the map's points).
        let trajectory = run_dir.join("keyframes.tum");
        let gt_poses = sequence.join("gt/poses.tum");
        match eval_cmd::score_map_file(
            &sequence.join("gt/mesh.ply"),
            &run_dir.join("map.ply"),
            Some((&trajectory, &gt_poses)),
            5.0,
            1.0,
        ) {
            Ok(s) => println!(
                "  map         vs the renderer's mesh: mean {:.3} mm, median {:.3} mm, {:.1} % outliers (> 5 mm)",
                s.inliers.mean,
                s.inliers.median,
                100.0 * s.outlier_fraction
            ),
            Err(e) => println!("  map         not evaluated ({e:#})"),
        }
    }
    for h in &result.latency.hops {
        println!(
            "  transport   {}→{} ({}) p50 {:.0} µs, p99 {:.0} µs, zero copy",
            h.from, h.to, h.topic, h.latency_us.p50, h.latency_us.p99
        );
    }
    for e in &result.latency.end_to_end {
        println!(
            "  latency     {} p50 {:.1} ms, p99 {:.1} ms ({} {})",
            e.path,
            e.latency_us.p50 / 1000.0,
            e.latency_us.p99 / 1000.0,
            e.latency_us.count,
            if e.path.ends_with("map") { "keyframes" } else { "frames" }
        );
    }
    println!(
        "  look at     {} (the dense map), {} (a depth keyframe), {} (first stereo pair)",
        run_dir.join("map.png").display(),
        run_dir.join("depth-preview.png").display(),
        preview.display()
    );
    println!(
        "              {} (open in any point-cloud viewer), {} and {} (trajectory), {} (latency, drawn)",
        run_dir.join("map.ply").display(),
        run_dir.join("trajectory.tum").display(),
        run_dir.join("keyframes.tum").display(),
        run_dir.join("latency.svg").display()
    );
    Ok(code)
}

/// The tracker's figures of one benchmark run.
#[derive(Debug, Clone, Copy, serde::Serialize)]
struct TrackerTimes {
    with_dense: bool,
    /// Wall time per frame in the tracking process (receive → poses published), µs.
    wall_p50_us: f64,
    wall_p99_us: f64,
    /// Tracking-thread CPU per frame without a new keyframe (tracking.json), ms.
    cpu_p50_ms: f64,
}

fn bench_isolation(args: IsolationArgs) -> Result<ExitCode> {
    anyhow::ensure!((1..=50).contains(&args.pairs), "--pairs: give 1 to 50");
    let settings = args.settings.clone().unwrap_or_else(|| args.sequence.join("settings.yaml"));
    let full =
        plan_for_sequence(&args.sequence, Some(&settings), bdis_source::Pacing::OnDemand, false, None, true, &[])?;
    let mut alone = full.clone();
    alone.services.retain(|s| s.name == "acquisition" || s.name == "tracking");
    let root = make_run_dir(args.out.as_deref(), "isolation")?;
    let bar = bdis_slam::progress::bar(2 * args.pairs as u64, "isolation {bar:30} {pos}/{len} runs ({eta} left) {msg}");
    let mut runs: Vec<TrackerTimes> = Vec::new();
    for pair in 0..args.pairs {
        // Alternate the order (ABBA…) so a drift in the host's load does not favour one side.
        let order = if pair % 2 == 0 { [false, true] } else { [true, false] };
        for with_dense in order {
            let tag = format!("{pair}-{}", if with_dense { "with-dense" } else { "alone" });
            bar.set_message(tag.clone());
            let run_dir = root.join(&tag);
            std::fs::create_dir_all(&run_dir)
                .with_context(|| format!("{}: cannot create the run folder", run_dir.display()))?;
            let plan = if with_dense { &full } else { &alone };
            let (code, result) = execute_and_write(plan, Path::new("launch.toml"), &run_dir, None, false)?;
            if code != ExitCode::SUCCESS {
                anyhow::bail!("run {tag} failed: {}", result.failure.unwrap_or_default());
            }
            let tracking = result
                .latency
                .processes
                .iter()
                .find(|p| p.name == "tracking")
                .and_then(|p| p.processing_us)
                .with_context(|| format!("run {tag}: no tracking figures"))?;
            let summary: serde_json::Value = serde_json::from_str(
                &std::fs::read_to_string(run_dir.join("tracking.json"))
                    .with_context(|| format!("{}: cannot read tracking.json", run_dir.display()))?,
            )
            .context("tracking.json")?;
            runs.push(TrackerTimes {
                with_dense,
                wall_p50_us: tracking.p50,
                wall_p99_us: tracking.p99,
                cpu_p50_ms: summary["frame_cpu_ms_p50"].as_f64().unwrap_or(f64::NAN),
            });
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    let ratios = |f: fn(&TrackerTimes) -> f64| -> Vec<f64> {
        runs.chunks(2)
            .map(|pair| {
                let (a, b) = if pair[0].with_dense { (&pair[1], &pair[0]) } else { (&pair[0], &pair[1]) };
                f(b) / f(a)
            })
            .collect()
    };
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[v.len() / 2], v[0], v[v.len() - 1])
    };
    let (p50_ratio, p50_lo, p50_hi) = median(ratios(|t| t.wall_p50_us));
    let (p99_ratio, p99_lo, p99_hi) = median(ratios(|t| t.wall_p99_us));
    let (cpu_ratio, cpu_lo, cpu_hi) = median(ratios(|t| t.cpu_p50_ms));
    println!("{:<6} {:<11} {:>16} {:>16} {:>18}", "pair", "dense", "wall p50 ms", "wall p99 ms", "thread CPU p50 ms");
    for (i, t) in runs.iter().enumerate() {
        println!(
            "{:<6} {:<11} {:>16.2} {:>16.2} {:>18.2}",
            i / 2,
            if t.with_dense { "other core" } else { "off" },
            t.wall_p50_us / 1000.0,
            t.wall_p99_us / 1000.0,
            t.cpu_p50_ms
        );
    }
    println!();
    println!("tracker with the dense mapper on the other core / alone (median of {} pairs, [min, max]):", args.pairs);
    println!(
        "  wall per frame p50  {:+.1} %  [{:+.1}, {:+.1}]",
        100.0 * (p50_ratio - 1.0),
        100.0 * (p50_lo - 1.0),
        100.0 * (p50_hi - 1.0)
    );
    println!(
        "  wall per frame p99  {:+.1} %  [{:+.1}, {:+.1}]",
        100.0 * (p99_ratio - 1.0),
        100.0 * (p99_lo - 1.0),
        100.0 * (p99_hi - 1.0)
    );
    println!(
        "  thread CPU p50      {:+.1} %  [{:+.1}, {:+.1}]",
        100.0 * (cpu_ratio - 1.0),
        100.0 * (cpu_lo - 1.0),
        100.0 * (cpu_hi - 1.0)
    );
    let json = serde_json::json!({
        "schema": "bdis.v1.isolation",
        "sequence": args.sequence,
        "pairs": args.pairs,
        "runs": runs,
        "wall_p50_ratio": {"median": p50_ratio, "min": p50_lo, "max": p50_hi},
        "wall_p99_ratio": {"median": p99_ratio, "min": p99_lo, "max": p99_hi},
        "cpu_p50_ratio": {"median": cpu_ratio, "min": cpu_lo, "max": cpu_hi},
    });
    let path = root.join("isolation.json");
    std::fs::write(&path, serde_json::to_string_pretty(&json)?)
        .with_context(|| format!("{}: cannot write", path.display()))?;
    println!("runs and isolation.json in {}", root.display());
    Ok(ExitCode::SUCCESS)
}

/// Left and right image side by side, for a person to look at.
fn write_side_by_side(left: &Path, right: &Path, out: &Path) -> Result<()> {
    let l = image::open(left).with_context(|| format!("{}: cannot read", left.display()))?.to_rgb8();
    let r = image::open(right).with_context(|| format!("{}: cannot read", right.display()))?.to_rgb8();
    let mut both = image::RgbImage::new(l.width() + r.width(), l.height().max(r.height()));
    for (x, y, p) in l.enumerate_pixels() {
        both.put_pixel(x, y, *p);
    }
    for (x, y, p) in r.enumerate_pixels() {
        both.put_pixel(l.width() + x, y, *p);
    }
    both.save(out).with_context(|| format!("{}: cannot write", out.display()))
}
