//! `bdis-slam map`: builds the dense map offline from a sequence and a trajectory — BDIS on the chosen keyframes,
//! the mosaic rule, then `map.ply`, `map.png` and `map.bin`. With ground-truth poses it measures the mapping
//! alone; with a run's `keyframes.tum` (poses and keyframe choice from the tracker) it rebuilds the run's map.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use bdis_core::formats::trajectory;
use bdis_mosaic::{DepthKeyframe, Mosaic, MosaicParams, RectifiedCamera};
use bdis_stereo::{DisparityMap, Matcher, Params};

#[derive(Debug, clap::Args)]
pub struct MapArgs {
    /// Sequence folder (any layout `bdis-slam run` reads).
    #[arg(long)]
    sequence: PathBuf,
    /// Settings: the camera (fx, fy, cx, cy, bf) and `BDISparam.*`.
    #[arg(long)]
    settings: PathBuf,
    /// `world_from_camera` per frame (TUM; matched to the sequence's times within 1 ms), e.g. `gt/poses.tum`
    /// or a run's `trajectory.tum`.
    #[arg(long)]
    poses: PathBuf,
    /// Keyframes: the frames whose times are in this TUM file (e.g. a run's `keyframes.tum`). Without it, every
    /// `--every`-th frame.
    #[arg(long)]
    keyframes: Option<PathBuf>,
    /// Without --keyframes: every N-th frame is a keyframe.
    #[arg(long, default_value_t = 7, conflicts_with = "keyframes")]
    every: usize,
    /// Output folder: map.ply, map.png, map.bin.
    #[arg(long)]
    out: PathBuf,
    /// Override a map parameter, e.g. `--map-param fusion=weighted` (repeatable; names: depth_gap_px,
    /// min_colour, min_confidence, min_disparity_px, depth_tolerance_ratio, disparity_tolerance_px, keep_closer_ratio, fusion,
    /// max_weight).
    #[arg(long = "map-param", value_name = "NAME=VALUE")]
    map_params: Vec<String>,
}

/// A keyframe is matched to its frame, and a frame to its pose, within 1 ms of its time.
const MAX_POSE_DT_S: f64 = 1e-3;

pub fn map(args: MapArgs) -> Result<()> {
    let mut params = MosaicParams::default();
    params.apply_overrides(&args.map_params).map_err(|e| anyhow::anyhow!("--map-param {e}"))?;
    let settings = bdis_core::Settings::load(&args.settings)?;
    let camera = settings.camera;
    let sequence = bdis_source::Sequence::open(&args.sequence)?;
    let mut poses = trajectory::read_tum(&args.poses)?;
    poses.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    let chosen: Vec<usize> = match &args.keyframes {
        Some(path) => {
            let keyframes = trajectory::read_tum(path)?;
            let mut frames = Vec::new();
            for kf in &keyframes {
                let found = sequence
                    .frames
                    .iter()
                    .position(|f| f.t_source_s.is_some_and(|t| (t - kf.t_s).abs() <= MAX_POSE_DT_S))
                    .with_context(|| {
                        format!(
                            "{}: keyframe at t = {} s is no frame of {}",
                            path.display(),
                            kf.t_s,
                            args.sequence.display()
                        )
                    })?;
                frames.push(found);
            }
            frames
        }
        None => (0..sequence.len()).step_by(args.every.max(1)).collect(),
    };
    if chosen.is_empty() {
        bail!("no keyframes chosen");
    }
    let stereo_params = Params::from_settings(&settings.bdis);
    stereo_params.validate().map_err(|e| anyhow::anyhow!("{}: {e}", args.settings.display()))?;
    let mut matcher = Matcher::new(stereo_params)?;
    let mut disparity = DisparityMap::default();
    let mut mosaic = Mosaic::new(params);
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("{}: cannot create the output folder", args.out.display()))?;
    let bar = bdis_slam::progress::bar(chosen.len() as u64, "mapping {bar:40} {pos}/{len} keyframes ({eta} left)");
    let mut insert_ms = Vec::with_capacity(chosen.len());
    for (kf_id, &index) in chosen.iter().enumerate() {
        let entry = &sequence.frames[index];
        let Some(t_s) = entry.t_source_s else {
            bail!("{}: frame {index} has no time, so no pose can be matched to it", args.sequence.display())
        };
        let Some(pose) = bdis_core::geometry::pose_nearest_in_time(&poses, t_s, MAX_POSE_DT_S) else {
            bail!("{}: no pose within 1 ms of frame {index} (t = {t_s} s)", args.poses.display())
        };
        let (left_gray, left_rgb) = crate::stereo_cmd::load(&entry.left)?;
        let (right_gray, _) = crate::stereo_cmd::load(&entry.right)?;
        matcher
            .compute_into(crate::stereo_cmd::view(&left_gray), crate::stereo_cmd::view(&right_gray), &mut disparity)
            .with_context(|| format!("{} + {}", entry.left.display(), entry.right.display()))?;
        let intrinsics = RectifiedCamera {
            fx: camera.fx,
            fy: camera.fy,
            cx: camera.cx,
            cy: camera.cy,
            bf: camera.bf,
            width: left_rgb.width(),
            height: left_rgb.height(),
        };
        let start = std::time::Instant::now();
        mosaic
            .insert(&DepthKeyframe {
                kf_id: kf_id as u64,
                t_capture_ns: (t_s * 1e9) as u64,
                world_from_camera: pose.world_from_camera,
                intrinsics,
                disparity: &disparity.disparity,
                confidence: &disparity.confidence,
                rgb: left_rgb.as_raw(),
            })
            .with_context(|| format!("{}", entry.left.display()))?;
        insert_ms.push(start.elapsed().as_secs_f64() * 1e3);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let written = write_map(&mosaic, &args.out)?;
    println!(
        "{} keyframes → {} points; mosaic update p50 {:.2} ms, max {:.2} ms per keyframe",
        chosen.len(),
        mosaic.n_points(),
        bdis_core::stats::percentile(&mut insert_ms, 0.5).unwrap_or(0.0),
        bdis_core::stats::percentile(&mut insert_ms, 1.0).unwrap_or(0.0)
    );
    println!("{written}");
    Ok(())
}

/// map.ply, map.bin and map.png in `dir`; returns a line naming them.
pub fn write_map(mosaic: &Mosaic, dir: &Path) -> Result<String> {
    let out = bdis_mosaic::write_outputs(mosaic, dir, 1024)?;
    Ok(match out.png {
        Some(png) => format!("map: {}, {} (preview), {}", out.ply.display(), png.display(), out.bin.display()),
        None => format!("map: {} (empty: no preview), {}", out.ply.display(), out.bin.display()),
    })
}
