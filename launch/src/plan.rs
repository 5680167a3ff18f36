//! The pipeline plan for a sequence, described once: which services run, on which core, with which
//! arguments, restart policies and handovers. `run --sequence`, the demo and the isolation benchmark all start
//! from it.

use std::path::Path;

use anyhow::{Context, Result};

/// What a plan streams: a sequence (folder, video or live source), its settings, and whether acquisition
/// splits interlaced frames (the settings then describe the fields).
#[derive(Debug, Clone, Copy)]
pub struct PlanInput<'a> {
    pub sequence: &'a Path,
    pub settings: Option<&'a Path>,
    pub interlaced: Option<bdis_source::FieldMode>,
}

impl<'a> PlanInput<'a> {
    pub fn new(sequence: &'a Path, settings: Option<&'a Path>) -> Self {
        Self { sequence, settings, interlaced: None }
    }
}

/// The launch plan `run --sequence` builds: acquisition, then the probe as its consumer.
pub fn plan_for_sequence(
    input: PlanInput<'_>,
    pacing: bdis_source::Pacing,
    checksums: bool,
    stereo_every: Option<u64>,
    track: bool,
    map_params: &[String],
) -> Result<bdis_slam::launch_file::LaunchFile> {
    use bdis_slam::launch_file::{LaunchFile, RunSection, ServiceSpec};
    let PlanInput { sequence, settings, interlaced } = input;
    // Check the input before anything starts: a bad sequence or settings file is reported here, by file and
    // field, and no process or shared memory is created.
    let absolute = |p: &Path| std::fs::canonicalize(p).with_context(|| format!("{}: cannot resolve", p.display()));
    // A live source is opened by acquisition itself (its devices are single-user); checked here as a spec.
    let live = sequence.to_str().and_then(bdis_source::LiveSpec::parse).transpose()?;
    let (mut acquisition_args, settings_path, name): (Vec<String>, Option<std::path::PathBuf>, String) = match &live {
        Some(spec) => {
            if pacing != bdis_source::Pacing::OnDemand {
                anyhow::bail!("`{}`: a live source is paced by its devices; leave out --pacing", spec.text);
            }
            (vec!["--sequence".to_string(), spec.text.clone()], settings.map(Path::to_path_buf), "live".to_string())
        }
        None => {
            // The settings of fields do not describe the woven frames on disk: acquisition checks them against
            // the fields it publishes.
            let checked = bdis_source::check_input(sequence, if interlaced.is_some() { None } else { settings })?;
            let name = checked
                .sequence
                .root
                .file_name()
                .map_or_else(|| "sequence".into(), |n| n.to_string_lossy().into_owned());
            let args = vec!["--sequence".to_string(), checked.sequence.argument()?];
            (args, settings.map(Path::to_path_buf).or(checked.settings_path), name)
        }
    };
    if let Some(mode) = interlaced {
        acquisition_args.extend(["--interlaced".to_string(), mode.name().to_string()]);
    }
    if let Some(settings) = &settings_path {
        acquisition_args.extend(["--settings".to_string(), absolute(settings)?.display().to_string()]);
    }
    let pacing = match pacing {
        _ if live.is_some() => None,
        bdis_source::Pacing::OnDemand => Some("on-demand".to_string()),
        bdis_source::Pacing::Recorded => Some("recorded".to_string()),
        bdis_source::Pacing::Fixed(hz) => Some(format!("{hz}hz")),
        bdis_source::Pacing::OnDemandAtMost(hz) => Some(format!("on-demand:{hz}hz")),
    };
    if let Some(pacing) = pacing {
        acquisition_args.extend(["--pacing".to_string(), pacing]);
    }
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
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
        essential: true,
    };
    let mut services = vec![spec("acquisition", "bdis-acquisition", acquisition_args, 0)];
    if track {
        let Some(settings) = &settings_path else {
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
    match (stereo_every, &settings_path) {
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

/// Adds the live viewer (`bdis-viewer`, serving on `listen`) to a plan that has a mosaic, on the dense side's
/// core. It only reads, so a crash of it loses nothing: it is restarted and the page reconnects.
pub fn add_viewer(plan: &mut bdis_slam::launch_file::LaunchFile, listen: &str) -> Result<()> {
    let mosaic = plan.services.iter().find(|s| s.binary == "bdis-mosaic");
    let Some(core) = mosaic.map(|m| m.core) else {
        anyhow::bail!("--view needs the map: run with --track (the viewer draws the mosaic's map)");
    };
    // The mosaic's map parameters: the viewer keeps a replica of the same map.
    let mut args = vec!["--listen".to_string(), listen.to_string()];
    for p in mosaic.into_iter().flat_map(|m| m.args.windows(2)).filter(|w| w[0] == "--map-param") {
        args.extend(["--map-param".to_string(), p[1].clone()]);
    }
    let viewer = watcher("viewer", "bdis-viewer", args, core);
    plan.services.push(viewer);
    Ok(())
}

/// Where `--igtl` listens when no address is given: OpenIGTLink's port, this machine only.
pub const DEFAULT_IGTL_LISTEN: &str = "127.0.0.1:18944";

/// Adds the OpenIGTLink output (`bdis-igtl`, serving on `listen`, the map sent as `map`) to a plan that tracks,
/// on the dense side's core. Like the viewer it only watches: restarted when it crashes, given up without
/// ending the run when it cannot run at all.
pub fn add_igtl(plan: &mut bdis_slam::launch_file::LaunchFile, listen: &str, map: &str) -> Result<()> {
    let Some(core) = plan.services.iter().find(|s| s.binary == "bdis-mosaic").map(|m| m.core) else {
        anyhow::bail!("--igtl needs the tracker and the map: run with --track");
    };
    let igtl = watcher("igtl", "bdis-igtl", vec!["--listen".into(), listen.into(), "--map".into(), map.into()], core);
    plan.services.push(igtl);
    Ok(())
}

/// A service that only watches the pipeline (the viewer, the OpenIGTLink output): restarted when it crashes, and
/// its failing for good must not end a surgery's run.
fn watcher(name: &str, binary: &str, args: Vec<String>, core: Option<usize>) -> bdis_slam::launch_file::ServiceSpec {
    let mut spec = bdis_slam::launch_file::ServiceSpec {
        name: name.into(),
        binary: binary.into(),
        args,
        core,
        env: Default::default(),
        restart: Default::default(),
        liveness_s: None,
        handover: None,
        replacement_args: Vec::new(),
        essential: false,
    };
    spec.restart.policy = bdis_slam::launch_file::RestartPolicy::OnFailure;
    spec
}
