//! `bdis-slam run`: a launch file or a sequence, started, supervised and reported; the run folder and the
//! report every pipeline command shares.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};

use crate::plan::plan_for_sequence;
use crate::{calib_cmd, synth_cmd};

#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Launch file (`launch/*.toml`). Without it, give --sequence (and --settings).
    #[arg(conflicts_with_all = ["sequence"])]
    launch_file: Option<PathBuf>,
    /// Sequence folder to stream (BDIS-SLAM/Hamlyn, plain left/right, or KITTI layout); a stereo video
    /// (`video:top-bottom:FILE`, `video:side-by-side:FILE` or `video:two-files:LEFT,RIGHT`, decoded by ffmpeg);
    /// or `synthetic:<scene>[:<trajectory>][:<frames>]` (rendered first, e.g. `synthetic:abdomen:sweep:90`).
    #[arg(long, required_unless_present = "launch_file")]
    sequence: Option<PathBuf>,
    /// Settings file for --sequence (ORB-SLAM2 YAML or bdis-slam TOML). A raw stereo calibration (OpenCV
    /// `M1 D1 M2 D2 R T`, or ORB-SLAM2 settings with `LEFT`/`RIGHT` blocks) rectifies the sequence into the run
    /// folder first (as `bdis-slam rectify`), then runs on the rectified pairs.
    #[arg(long, requires = "sequence")]
    settings: Option<PathBuf>,
    /// Pacing for --sequence: on-demand, recorded, a rate such as 30hz (frames a slow consumer misses are
    /// dropped, as with a live camera), or on-demand:30hz (a live camera's pace that never drops a frame).
    #[arg(long, default_value = "on-demand", requires = "sequence")]
    pacing: bdis_source::Pacing,
    /// Interlaced footage (1080i): track one field of each frame (`top-field`, `bottom-field`: half the rows;
    /// the run folder gets settings.yaml with fy and cy halved) or the top field with the other rows
    /// interpolated (`bob`). --settings describe the woven frames.
    #[arg(long, value_name = "MODE", requires = "settings")]
    interlaced: Option<bdis_source::FieldMode>,
    /// Per-frame instrument masks for --sequence (PNG, non-zero = instrument; named like the left images, or
    /// `1.png`… for a video), e.g. from a tool segmentation network or `synth --instruments`' gt/masks: they go
    /// with each frame through shared memory, and the tracker takes no feature and the stereo no depth there.
    #[arg(long, value_name = "DIR", requires = "sequence")]
    masks: Option<PathBuf>,
    /// With --track, for frames without --masks: `estimate` (default) has the tracker find instruments itself
    /// (opaque grey regions entering from the border, smoke and membranes left; nothing on footage that is not
    /// tissue-coloured) and keep them out of the pose and the map; `off` takes every pixel.
    #[arg(long, value_name = "MODE", value_parser = ["estimate", "off"], requires = "track")]
    instrument_masks: Option<String>,
    /// Skip the first N frames of --sequence (a video is decoded from frame N, exactly).
    #[arg(long, default_value_t = 0, value_name = "N", requires = "sequence")]
    start: usize,
    /// Stream at most N frames of --sequence (after --start).
    #[arg(long, value_name = "N", requires = "sequence")]
    frames: Option<usize>,
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
    /// With --track: no loop closing (by default the tracker recognises tissue mapped long ago, fuses the two
    /// passes, corrects its map by a pose graph where the drift is beyond noise and then by a global bundle
    /// adjustment, and the dense map follows every moved keyframe; off, revisits are tied in by map reuse alone).
    /// For comparing the two: see BENCHMARKS.md.
    #[arg(long, requires = "track")]
    no_loop_closing: bool,
    /// Run folder to write (default: runs/<UTC time>-<name>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Shared-memory name prefix (default: a fresh one per run, so runs never see each other).
    #[arg(long)]
    ipc_prefix: Option<String>,
    /// With --track: a live view in a browser while it runs (the viewer service; its address is printed).
    #[arg(long, requires = "track")]
    view: bool,
    /// Address for --view (default: this machine only).
    #[arg(long, default_value = crate::view_cmd::DEFAULT_LISTEN, requires = "view")]
    listen: String,
    /// With --track: the scope's pose per frame and the map per keyframe over OpenIGTLink to a navigation
    /// workstation (3D Slicer: OpenIGTLinkIF, client, this address). Default address: 127.0.0.1:18944, this
    /// machine only; an open port shows the scope's path and a 3-D map of the patient's tissue.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = crate::plan::DEFAULT_IGTL_LISTEN, requires = "track")]
    igtl: Option<String>,
    /// With --igtl: how the map is sent (`polydata`: a point cloud per keyframe; `points`: POINT messages with
    /// the tissue's colour; `off`).
    #[arg(long, default_value = "polydata", value_parser = ["polydata", "points", "off"], requires = "igtl")]
    igtl_map: String,
}

pub fn run(args: RunArgs) -> Result<ExitCode> {
    use bdis_slam::launch_file::LaunchFile;
    // A synthetic source is rendered here first (with a progress bar), then streamed like any sequence.
    let mut rendered: Option<(PathBuf, PathBuf)> = None;
    // A raw calibration that acquisition applies as it reads (a video).
    let mut rectify_in_acquisition: Option<PathBuf> = None;
    if let Some(request) = args.sequence.as_ref().and_then(|s| s.to_str()).and_then(bdis_source::parse_synthetic) {
        let request = request.map_err(anyhow::Error::msg)?;
        let run_dir = make_run_dir(args.out.as_deref(), &format!("synthetic-{}", request.scene))?;
        let sequence = run_dir.join("sequence");
        let written = synth_cmd::render_with_progress(&sequence, &bdis_synth::default_camera(), &request)?;
        let settings = args.settings.clone().unwrap_or(written.settings);
        rendered = Some((run_dir, settings));
    } else if let (Some(sequence), Some(settings)) = (&args.sequence, &args.settings)
        && calib_cmd::is_raw_calibration(settings)
        && let Some(live) = sequence.to_str().and_then(bdis_source::LiveSpec::parse)
    {
        // A raw rig on a live device: acquisition rectifies each frame as it takes it.
        let live = live?;
        let run_dir = make_run_dir(args.out.as_deref(), "rectified-live")?;
        let camera = calib_cmd::rectified_settings_for_live(settings, &live, &run_dir.join("settings.yaml"))?;
        eprintln!(
            "bdis-slam: {} is a raw stereo calibration: acquisition rectifies every live frame (fx {:.2}, bf {:.4})",
            settings.display(),
            camera.fx,
            camera.bf
        );
        rectify_in_acquisition = Some(std::fs::canonicalize(settings).context("the calibration file")?);
        rendered = Some((run_dir.clone(), run_dir.join("settings.yaml")));
    } else if let (Some(sequence), Some(settings)) = (&args.sequence, &args.settings)
        && calib_cmd::is_raw_calibration(settings)
        && let Some(video) = sequence.to_str().and_then(bdis_source::VideoSpec::parse)
    {
        // A raw video: acquisition rectifies each frame as it reads it (nothing is written to disk); the
        // tracker and the dense stereo get the rectified camera's settings, written into the run folder.
        let video = video?;
        let name = video.left_file().file_stem().map_or("video".into(), |n| n.to_string_lossy().into_owned());
        let run_dir = make_run_dir(args.out.as_deref(), &format!("rectified-{name}"))?;
        let camera = calib_cmd::rectified_settings_for_video(settings, &video, &run_dir.join("settings.yaml"))?;
        eprintln!(
            "bdis-slam: {} is a raw stereo calibration: acquisition rectifies every frame of {} (fx {:.2}, bf {:.4})",
            settings.display(),
            video.left_file().display(),
            camera.fx,
            camera.bf
        );
        rectify_in_acquisition = Some(std::fs::canonicalize(settings).context("the calibration file")?);
        rendered = Some((run_dir.clone(), run_dir.join("settings.yaml")));
    } else if let (Some(sequence), Some(settings)) = (&args.sequence, &args.settings)
        && calib_cmd::is_raw_calibration(settings)
    {
        // Raw images with their calibration (ORB-SLAM2 rectifies with LEFT/RIGHT blocks too): rectified into the
        // run folder first, then streamed like any sequence.
        let name = sequence.file_name().map_or("raw".into(), |n| n.to_string_lossy().into_owned());
        let run_dir = make_run_dir(args.out.as_deref(), &format!("rectified-{name}"))?;
        let done = calib_cmd::rectify_sequence(settings, sequence, &run_dir.join("sequence"), None)?;
        eprintln!(
            "bdis-slam: {} is a raw stereo calibration: rectified {} pairs into {} (fx {:.2}, bf {:.4})",
            settings.display(),
            done.pairs,
            run_dir.join("sequence").display(),
            done.camera.fx,
            done.camera.bf
        );
        rendered = Some((run_dir, done.settings));
    }
    // Interlaced: the fields' settings are written into the run folder; acquisition splits each frame.
    if let (Some(mode), None, Some(sequence), Some(settings)) =
        (args.interlaced, &rendered, &args.sequence, &args.settings)
    {
        let name = sequence.file_name().map_or("interlaced".into(), |n| n.to_string_lossy().into_owned());
        let run_dir = make_run_dir(args.out.as_deref(), &format!("{}-{name}", mode.name()))?;
        let field_settings = run_dir.join("settings.yaml");
        crate::fields::write_field_settings(settings, mode, &field_settings)?;
        rendered = Some((run_dir, field_settings));
    } else if args.interlaced.is_some() {
        anyhow::bail!("--interlaced takes a sequence of woven frames with their (rectified) settings");
    }
    // The sequence to plan for: the rendered (or rectified) one, or the one given.
    let sequence = match (&args.sequence, &rendered) {
        // Acquisition reads the given sequence (rectifying it, or splitting its fields) with the run folder's
        // settings.
        (Some(sequence), Some((_, settings))) if rectify_in_acquisition.is_some() || args.interlaced.is_some() => {
            Some((sequence.clone(), Some(settings.clone())))
        }
        (Some(_), Some((run_dir, settings))) => Some((run_dir.join("sequence"), Some(settings.clone()))),
        (Some(sequence), None) => Some((sequence.clone(), args.settings.clone())),
        (None, _) => None,
    };
    let (launch, launch_path) = match (&args.launch_file, sequence) {
        (Some(path), _) => (LaunchFile::load(path)?, path.clone()),
        (None, Some((sequence, settings))) => {
            let input = crate::plan::PlanInput {
                sequence: &sequence,
                settings: settings.as_deref(),
                interlaced: args.interlaced,
            };
            let mut plan =
                plan_for_sequence(input, args.pacing, args.checksums, args.stereo_every, args.track, &args.map_params)?;
            if let Some(tracking) = plan.services.iter_mut().find(|s| s.binary == "bdis-tracking") {
                if args.no_loop_closing {
                    tracking.args.extend(["--loop-closing".to_string(), "off".to_string()]);
                }
                if let Some(mode) = &args.instrument_masks {
                    tracking.args.extend(["--instrument-masks".to_string(), mode.clone()]);
                }
            }
            if let Some(acquisition) = plan.services.iter_mut().find(|s| s.binary == "bdis-acquisition") {
                if args.start > 0 {
                    acquisition.args.extend(["--start".to_string(), args.start.to_string()]);
                }
                if let Some(frames) = args.frames {
                    acquisition.args.extend(["--max-frames".to_string(), frames.to_string()]);
                }
                if let Some(calibration) = &rectify_in_acquisition {
                    acquisition.args.extend(["--calibration".to_string(), calibration.display().to_string()]);
                }
                if let Some(masks) = &args.masks {
                    let masks = std::fs::canonicalize(masks)
                        .with_context(|| format!("--masks {}: no such folder", masks.display()))?;
                    acquisition.args.extend(["--masks".to_string(), masks.display().to_string()]);
                }
            }
            if args.view {
                crate::plan::add_viewer(&mut plan, &args.listen)?;
                eprintln!("bdis-slam: live view at http://{}/ while it runs", args.listen);
            }
            if let Some(listen) = &args.igtl {
                crate::plan::add_igtl(&mut plan, listen, &args.igtl_map)?;
                eprintln!("bdis-slam: OpenIGTLink at {listen} (pose: CameraToWorld; map: MapKf<id>)");
            }
            (plan, PathBuf::from("launch.toml"))
        }
        (None, None) => anyhow::bail!("give a launch file or --sequence"),
    };
    let name = launch.run.name.clone().unwrap_or_else(|| "run".into());
    let run_dir = match rendered {
        Some((run_dir, _)) => run_dir,
        None => make_run_dir(args.out.as_deref(), &name)?,
    };
    let (code, _) = execute_and_report(&launch, &launch_path, &run_dir, args.ipc_prefix.clone())?;
    Ok(code)
}

pub fn make_run_dir(out: Option<&Path>, name: &str) -> Result<PathBuf> {
    match out {
        Some(dir) => {
            let existed = dir.exists();
            std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the run folder", dir.display()))?;
            // A new folder is private by the umask; one that existed keeps its mode (it may be the user's own
            // folder of other things), with a word when others can read it.
            use std::os::unix::fs::PermissionsExt;
            if existed && std::fs::metadata(dir).is_ok_and(|m| m.permissions().mode() & 0o007 != 0) {
                tracing::warn!(
                    "{}: other users can read this folder; the run's images and maps hold patient data",
                    dir.display()
                );
            }
            Ok(dir.to_path_buf())
        }
        None => {
            bdis_slam::run_dir::create_run_dir(Path::new("runs"), name).context("runs/: cannot create the run folder")
        }
    }
}

/// Starts the plan, waits for its end, writes `latency.json`, prints the latency table; the exit code says how
/// the run ended.
pub fn execute_and_report(
    launch: &bdis_slam::launch_file::LaunchFile,
    launch_path: &Path,
    run_dir: &Path,
    ipc_prefix: Option<String>,
) -> Result<(ExitCode, bdis_slam::run::RunResult)> {
    execute_and_write(launch, launch_path, run_dir, ipc_prefix, true)
}

/// [`execute_and_report`], with the printed report optional (the benchmark runs many).
pub fn execute_and_write(
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

    let json = bdis_slam::run::RunRecord::new(&name, &prefix, &result);
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
