//! `bdis-slam demo`: render a synthetic colon flight, run the whole pipeline over it, and print a summary a
//! person can read in ten seconds, with pictures to look at.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};

use bdis_core::formats::summary::TrackingSummary;

use crate::plan::plan_for_sequence;
use crate::run_cmd::{execute_and_report, make_run_dir};
use crate::{eval_cmd, synth_cmd};

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Frames to render.
    #[arg(long, default_value_t = 45)]
    frames: usize,
    /// Run folder to write (default: runs/<UTC time>-demo).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Pacing: on-demand (as fast as the pipeline consumes), recorded (30 fps), or a rate such as 60hz.
    #[arg(long, default_value = "on-demand")]
    pacing: bdis_source::Pacing,
    /// Watch it in a browser: live while it runs (the viewer service), then the finished run (as `bdis-slam view
    /// RUN_DIR` shows it) until Ctrl-C. The address is printed.
    #[arg(long)]
    view: bool,
    /// Address for `--view` (default: this machine only).
    #[arg(long, default_value = crate::view_cmd::DEFAULT_LISTEN, requires = "view")]
    listen: String,
    /// Also send the scope's pose and the map over OpenIGTLink (to 3D Slicer or any OpenIGTLink receiver; default
    /// address 127.0.0.1:18944).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = crate::plan::DEFAULT_IGTL_LISTEN)]
    igtl: Option<String>,
}

pub fn demo(args: DemoArgs) -> Result<ExitCode> {
    anyhow::ensure!(args.frames >= 2 && args.frames <= 100_000, "--frames: give 2 to 100000 frames");
    let run_dir = make_run_dir(args.out.as_deref(), "demo")?;
    let sequence = run_dir.join("sequence");
    let rig = bdis_synth::default_camera();
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

    let mut launch = plan_for_sequence(
        crate::plan::PlanInput::new(&sequence, Some(&settings)),
        args.pacing,
        false,
        None,
        true,
        &[],
    )?;
    if args.view {
        crate::plan::add_viewer(&mut launch, &args.listen)?;
        eprintln!("bdis-slam demo: live view at http://{}/ while it runs", args.listen);
    }
    if let Some(listen) = &args.igtl {
        crate::plan::add_igtl(&mut launch, listen, "polydata")?;
        eprintln!("bdis-slam demo: OpenIGTLink at {listen} (pose: CameraToWorld; map: MapKf<id>)");
    }
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
    match TrackingSummary::read(&run_dir.join("tracking.json")) {
        Ok(t) => println!(
            "  tracking    CPU per frame p50 {:.1} ms (ORB on both images, stereo matching, pose, local map), per keyframe {:.1} ms; {} frames lost",
            t.frame_cpu_ms_p50.unwrap_or(f64::NAN),
            t.keyframe_cpu_ms_p50.unwrap_or(f64::NAN),
            t.lost
        ),
        Err(e) => println!("  tracking    no summary ({e})"),
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
    let mosaic = bdis_mosaic::MosaicSummary::read(&run_dir.join("mosaic.json"));
    if let Err(e) = &mosaic {
        println!("  map         no summary ({e})");
    }
    if let Ok(m) = &mosaic {
        println!(
            "  map         {} points from {} keyframes ({} pose corrections applied), update p50 {:.1} ms per keyframe",
            m.points,
            m.keyframes_inserted,
            m.corrections_applied,
            m.update_ms_p50.unwrap_or(f64::NAN)
        );
        // The map against the renderer's mesh, brought into its frame by the alignment of the keyframe trajectory
        // (the poses that place the map's points).
        let trajectory = run_dir.join("keyframes.tum");
        let gt_poses = sequence.join("gt/poses.tum");
        match eval_cmd::score_map_file(
            &sequence.join("gt/mesh.ply"),
            &run_dir.join("map.ply"),
            Some(eval_cmd::MapAlignment { est: &trajectory, gt: &gt_poses, first_pose: false }),
            5.0,
            1.0,
            bdis_eval::map::Layers { max_gap: 2.0, thickness: None },
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
    if args.view {
        crate::view_cmd::view(crate::view_cmd::ViewArgs { run_dir: run_dir.clone(), listen: args.listen })?;
    } else {
        println!("              or in a browser: bdis-slam view {}", run_dir.display());
    }
    Ok(code)
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
