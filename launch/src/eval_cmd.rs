//! `bdis-slam eval traj|map|stereo|masks`: scores against ground truth, for people (a short report) and programs
//! (`--json`).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use bdis_core::formats::{pfm, ply, quality, trajectory};
use bdis_core::geometry::StampedPose;
use bdis_eval::map::Layers;
use bdis_eval::status::{StatusBar, StatusHonesty};
use nalgebra::Point3;

#[derive(Debug, clap::Subcommand)]
pub enum EvalCommand {
    /// Trajectory error: ATE after SE(3) alignment without scale (as `evo_ape tum gt est -a`), RPE, and the
    /// estimate's scale error (a Sim(3) fit, as `evo_ape -as`, and the ratio of step lengths).
    Traj(TrajArgs),
    /// Map error: distance of each map point to the ground-truth mesh (the paper's metric), and coverage.
    Map(MapArgs),
    /// Dense stereo error: density, depth MAE / median, bad-1 / bad-2 px, against GT depth or disparity.
    Stereo(StereoEvalArgs),
    /// Instrument masks: our own estimate (colour and shape, no network) on every left image of a sequence,
    /// scored against true masks (precision, recall); optionally written out, for a look or for `run --masks`.
    Masks(crate::eval_masks::MasksArgs),
}

#[derive(Debug, clap::Args)]
pub struct TrajArgs {
    /// Ground-truth trajectory.
    #[arg(long)]
    gt: PathBuf,
    /// Estimated trajectory.
    #[arg(long)]
    est: PathBuf,
    /// `tum` (t tx ty tz qx qy qz qw) or `kitti` (3×4 per line; poses are matched by line).
    #[arg(long, default_value = "tum")]
    format: String,
    /// Largest timestamp difference for two poses to be matched, seconds.
    #[arg(long, default_value_t = 0.01)]
    max_dt: f64,
    /// Time step of the relative pose error, seconds (for KITTI: lines).
    #[arg(long, default_value_t = 1.0)]
    delta: f64,
    /// The run's `tracking-quality.csv` (or its run folder): also judge each frame reported `Ok` against its last
    /// keyframe — its position relative to it must be within --max-error-of-travel of the distance travelled
    /// since it (issue #22's honesty bar), judged from --min-steps median ground-truth steps of travel on.
    #[arg(long)]
    quality: Option<PathBuf>,
    /// The run's `keyframes.tum`, for --quality: each keyframe's own pose, which the frames after it were tracked
    /// against (without it, the written trajectory's pose at the keyframe's time, which a veil's bridge may have
    /// replaced).
    #[arg(long, requires = "quality")]
    keyframes: Option<PathBuf>,
    /// The honesty bar: an `Ok` frame's error relative to its keyframe over the travel since it.
    #[arg(long, default_value_t = 0.01, requires = "quality")]
    max_error_of_travel: f64,
    /// Frames are judged from this many median steps of travel since their keyframe (1 % of a shorter travel is
    /// under the measurement noise of any tracker).
    #[arg(long, default_value_t = 4.0, requires = "quality")]
    min_steps: f64,
    /// Also draw it, as an SVG to look at: each pose's position error over time (with --quality, the frames not
    /// reported `Ok` shaded, the keyframes ticked, and a second panel with each judged frame against the
    /// honesty bar).
    #[arg(long, value_name = "FILE.svg")]
    plot: Option<PathBuf>,
    /// Print JSON instead of the report.
    #[arg(long)]
    json: bool,
}

#[derive(Debug, clap::Args)]
pub struct MapArgs {
    /// Ground-truth mesh (PLY with faces).
    #[arg(long)]
    mesh: PathBuf,
    /// The map's points (PLY).
    #[arg(long)]
    map: PathBuf,
    /// Points farther than this from the mesh are outliers (the paper: 5 mm).
    #[arg(long, default_value_t = 5.0)]
    outlier_mm: f64,
    /// A mesh triangle counts as covered when a map point lies within this of its centroid.
    #[arg(long, default_value_t = 1.0)]
    coverage_mm: f64,
    /// A second layer counts up to this far in front of or behind a point (issue #17's "one surface": two
    /// passes over the same tissue should not leave two surfaces).
    #[arg(long, default_value_t = 2.0)]
    layer_gap_mm: f64,
    /// A second layer counts from this far on; by default from the map's own thickness (3 robust σ of its
    /// distances to the mesh, so noise is not a layer). Give one value to compare maps of different noise: a
    /// sharper map's own thickness is thinner, so more of its tail would count.
    #[arg(long)]
    layer_thickness_mm: Option<f64>,
    /// Bring the map into the ground truth's frame first: the SE(3) alignment of this estimated trajectory
    /// (TUM) onto --align-gt, as the ATE computes it.
    #[arg(long, requires = "align_gt")]
    align_est: Option<PathBuf>,
    /// Ground-truth trajectory (TUM) for --align-est.
    #[arg(long, requires = "align_est")]
    align_gt: Option<PathBuf>,
    /// How --align-est places the map: `trajectory` (the SE(3) fit of the whole trajectory, as the ATE) or
    /// `first` (the first frame's pose, no fit: for short paths such as a hover, whose fit leaves the rotation
    /// loose — a degree of it moves tissue 55 mm away by a millimetre)
    #[arg(long, default_value = "trajectory", value_parser = ["trajectory", "first"], requires = "align_est")]
    align_by: String,
    #[arg(long)]
    json: bool,
}

#[derive(Debug, clap::Args)]
pub struct StereoEvalArgs {
    /// Estimated disparity (PFM; non-finite = no answer).
    #[arg(long)]
    disparity: PathBuf,
    /// Ground-truth depth (PFM; non-finite or ≤ 0 = no ground truth). Needs --bf.
    #[arg(long, conflicts_with = "gt_disparity", required_unless_present = "gt_disparity")]
    gt_depth: Option<PathBuf>,
    /// Ground-truth disparity (PFM), instead of depth.
    #[arg(long)]
    gt_disparity: Option<PathBuf>,
    /// fx · baseline: depth = bf / disparity.
    #[arg(long)]
    bf: f64,
    /// Left image: pixels whose red channel is 0 are outside the evaluation region.
    #[arg(long)]
    region_from: Option<PathBuf>,
    #[arg(long)]
    json: bool,
}

fn load_traj(path: &Path, format: &str) -> Result<Vec<StampedPose>> {
    Ok(match format {
        "tum" => trajectory::read_tum(path)?,
        // KITTI has no times: the line number is the time, so poses pair up by line.
        "kitti" => trajectory::read_kitti(path)?
            .into_iter()
            .enumerate()
            .map(|(i, world_from_camera)| StampedPose { t_s: i as f64, world_from_camera })
            .collect(),
        other => bail!("--format: `{other}` is not a trajectory format (tum, kitti)"),
    })
}

pub fn eval(command: EvalCommand) -> Result<()> {
    match command {
        EvalCommand::Traj(a) => {
            let gt = load_traj(&a.gt, &a.format)?;
            let est = load_traj(&a.est, &a.format)?;
            let ate = bdis_eval::traj::ate(&gt, &est, a.max_dt)
                .with_context(|| format!("{} vs {}", a.est.display(), a.gt.display()))?;
            let rpe = bdis_eval::traj::rpe(&gt, &est, a.max_dt, a.delta)?;
            let log = match &a.quality {
                Some(path) => {
                    let file = if path.is_dir() { path.join(quality::FILE_NAME) } else { path.clone() };
                    let log = quality::read_quality_log(&file)?;
                    Some((file, log))
                }
                None => None,
            };
            let status = match &log {
                Some((file, log)) => {
                    let keyframes = match &a.keyframes {
                        Some(k) => load_traj(k, "tum")?,
                        None => Vec::new(),
                    };
                    let bar = StatusBar { max_error_of_travel: a.max_error_of_travel, min_steps: a.min_steps };
                    Some(judge_status(&gt, &est, &keyframes, file, log, a.max_dt, bar)?)
                }
                None => None,
            };
            if let Some(plot) = &a.plot {
                let errors = bdis_eval::traj::position_errors(&gt, &est, a.max_dt)?;
                let title = a.est.display().to_string();
                let svg = crate::eval_plot::TrajPlot {
                    title: &title,
                    time_unit: if a.format == "kitti" { "" } else { " s" },
                    errors: &errors,
                    ate_rmse: ate.translation.rmse,
                    log: log.as_ref().map(|(_, log)| log),
                    status: status.as_ref(),
                }
                .svg();
                std::fs::write(plot, svg).with_context(|| format!("{}: cannot write the plot", plot.display()))?;
                if !a.json {
                    eprintln!("plot: {}", plot.display());
                }
            }
            if a.json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&serde_json::json!({ "ate": ate, "rpe": rpe, "status": status }))?
                );
            } else {
                let t = &ate.translation;
                println!(
                    "ATE (SE(3)-aligned, {} pose pairs): RMSE {:.6}  mean {:.6}  median {:.6}  max {:.6}",
                    ate.pairs, t.rmse, t.mean, t.median, t.max
                );
                println!(
                    "RPE per {} {}: translation RMSE {:.6}, rotation RMSE {:.4}°",
                    a.delta,
                    if a.format == "kitti" { "poses" } else { "s" },
                    rpe.translation.rmse,
                    rpe.rotation_deg.rmse
                );
                println!(
                    "alignment: rotation {:.3}°, translation {:?}",
                    ate.alignment_rotation_deg, ate.alignment_translation
                );
                // Stereo fixes the scale, so a scale off 1 is an error; shown apart so that a scale error can be
                // told from drift.
                println!(
                    "scale error: {:+.3} % by a Sim(3) fit, {:+.3} % by the length of {} {} steps (+: the \
                     estimate is too large); ATE after Sim(3) alignment: RMSE {:.6}",
                    100.0 * (ate.sim3.est_over_gt - 1.0),
                    100.0 * (rpe.length_ratio - 1.0),
                    a.delta,
                    if a.format == "kitti" { "pose" } else { "s" },
                    ate.sim3.translation.rmse
                );
                if let Some(status) = &status {
                    print_status(status);
                }
            }
        }
        EvalCommand::Map(a) => {
            let align = a.align_est.as_deref().zip(a.align_gt.as_deref()).map(|(est, gt)| MapAlignment {
                est,
                gt,
                first_pose: a.align_by == "first",
            });
            let layers = Layers { max_gap: a.layer_gap_mm, thickness: a.layer_thickness_mm };
            let score = score_map_file(&a.mesh, &a.map, align, a.outlier_mm, a.coverage_mm, layers)?;
            if a.json {
                println!("{}", serde_json::to_string_pretty(&score)?);
            } else {
                println!(
                    "map: {} points, {} outliers (> {} mm, {:.1} %); inliers: mean {:.4} mm, median {:.4} mm, RMSE {:.4} mm; coverage {:.1} % (within {} mm); second layer {:.2} % ({:.3}–{} mm)",
                    score.points,
                    score.outliers,
                    score.outlier_threshold,
                    100.0 * score.outlier_fraction,
                    score.inliers.mean,
                    score.inliers.median,
                    score.inliers.rmse,
                    100.0 * score.coverage,
                    score.coverage_radius,
                    100.0 * score.second_layer,
                    score.second_layer_thickness,
                    score.second_layer_gap
                );
                if let Some(in_front) = score.in_front {
                    println!(
                        "in front of the tissue (> {} mm, on the cameras' side: instruments, smoke): {:.2} %",
                        score.outlier_threshold,
                        100.0 * in_front
                    );
                }
            }
        }
        EvalCommand::Masks(a) => crate::eval_masks::eval_masks(a)?,
        EvalCommand::Stereo(a) => {
            if !(a.bf.is_finite() && a.bf > 0.0) {
                bail!("--bf: must be > 0, found {}", a.bf);
            }
            let est = pfm::read_disparity(&a.disparity)?;
            let gt_depth: Vec<f32> = match (&a.gt_depth, &a.gt_disparity) {
                (Some(p), _) => check_size(pfm::read_disparity(p)?, &est, p)?.data,
                (None, Some(p)) => check_size(pfm::read_disparity(p)?, &est, p)?
                    .data
                    .iter()
                    .map(|&d| if d.is_finite() && d > 0.0 { a.bf as f32 / d } else { f32::NAN })
                    .collect(),
                (None, None) => bail!("give --gt-depth or --gt-disparity"),
            };
            let region: Vec<bool> = match &a.region_from {
                Some(p) => {
                    let img = image::open(p)
                        .with_context(|| format!("{}: cannot read the region image", p.display()))?
                        .to_rgb8();
                    if (img.width() as usize, img.height() as usize) != (est.width, est.height) {
                        bail!(
                            "{}: {}×{} but the disparity is {}×{}",
                            p.display(),
                            img.width(),
                            img.height(),
                            est.width,
                            est.height
                        );
                    }
                    img.pixels().map(|px| px[0] != 0).collect()
                }
                None => vec![true; est.data.len()],
            };
            let mut score = bdis_eval::stereo::StereoScore::new();
            score.add(&est.data, &gt_depth, &region, a.bf as f32);
            let s = score.summary();
            if a.json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&serde_json::json!({
                        "density": s.density, "depth_mae": s.depth_mae, "depth_median": s.depth_median,
                        "disparity_mae_px": s.disparity_mae, "bad1": s.bad1, "bad2": s.bad2,
                        "region_pixels": s.region_pixels, "scored_pixels": s.scored_pixels,
                    }))?
                );
            } else {
                println!(
                    "stereo: density {:.1} %, depth MAE {:.4}, median {:.4}, disparity MAE {:.3} px, bad-1 {:.1} %, bad-2 {:.1} % ({} pixels scored)",
                    100.0 * s.density,
                    s.depth_mae,
                    s.depth_median,
                    s.disparity_mae,
                    100.0 * s.bad1,
                    100.0 * s.bad2,
                    s.scored_pixels
                );
            }
        }
    }
    Ok(())
}

/// Judges the frames of the run's quality log (`log`, read from `file`) reported `Ok`.
fn judge_status(
    gt: &[StampedPose],
    est: &[StampedPose],
    keyframes: &[StampedPose],
    file: &Path,
    log: &quality::QualityLog,
    max_dt: f64,
    bar: StatusBar,
) -> Result<StatusHonesty> {
    if !(bar.max_error_of_travel.is_finite() && bar.max_error_of_travel > 0.0) {
        bail!("--max-error-of-travel: must be > 0, found {}", bar.max_error_of_travel);
    }
    if !(bar.min_steps.is_finite() && bar.min_steps >= 0.0) {
        bail!("--min-steps: must be ≥ 0, found {}", bar.min_steps);
    }
    bdis_eval::status::judge_ok_frames(gt, est, keyframes, log, max_dt, bar)
        .with_context(|| format!("{}", file.display()))
}

fn print_status(s: &StatusHonesty) {
    println!(
        "status: {} frames Ok, {} judged (≥ {} median steps = {:.6} from their keyframe); {} over {} % of the travel \
         since their keyframe; worst {:.2} %",
        s.ok_frames,
        s.judged,
        s.bar.min_steps,
        s.min_travel,
        s.wrong_ok.len(),
        100.0 * s.bar.max_error_of_travel,
        100.0 * s.worst_error_of_travel
    );
    for w in &s.wrong_ok {
        println!(
            "  Ok at {:.3} s: {:.2} % of the {:.6} travelled since the keyframe at {:.3} s",
            w.t_s,
            100.0 * w.error_of_travel,
            w.travelled,
            w.keyframe_t_s
        );
    }
}

/// How a map is brought into the ground truth's frame: by its run's estimated trajectory and the ground truth's.
#[derive(Debug, Clone, Copy)]
pub struct MapAlignment<'a> {
    pub est: &'a Path,
    pub gt: &'a Path,
    /// By the first frame's pose ([`bdis_eval::traj::align_first`]) rather than the SE(3) fit of the whole
    /// trajectory.
    pub first_pose: bool,
}

/// The paper's map metric for a PLY map against a mesh; with `align`, the map is first moved into the ground
/// truth's frame.
pub fn score_map_file(
    mesh_path: &Path,
    map_path: &Path,
    align: Option<MapAlignment>,
    outlier_mm: f64,
    coverage_mm: f64,
    layers: Layers,
) -> Result<bdis_eval::map::MapScore> {
    let mesh =
        bdis_eval::map::Mesh::from_cloud(&ply::read(mesh_path)?).with_context(|| mesh_path.display().to_string())?;
    let map = ply::read(map_path)?;
    let mut points: Vec<Point3<f64>> =
        map.positions.iter().map(|p| Point3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))).collect();
    let mut cameras = Vec::new();
    if let Some(align) = align {
        let (est, gt) = (trajectory::read_tum(align.est)?, trajectory::read_tum(align.gt)?);
        let gt_from_est = if align.first_pose {
            bdis_eval::traj::align_first(&gt, &est, 0.01)
        } else {
            bdis_eval::traj::align_se3(&gt, &est, 0.01)
        }
        .context("--align-est / --align-gt")?;
        for p in &mut points {
            *p = gt_from_est * *p;
        }
        cameras.extend(gt.iter().map(|pose| Point3::from(pose.world_from_camera.translation.vector)));
    }
    let index = bdis_eval::map::MeshIndex::new(mesh)?;
    let mut score = bdis_eval::map::score_map(&points, &index, outlier_mm, coverage_mm, layers)
        .with_context(|| map_path.display().to_string())?;
    if !cameras.is_empty() {
        score.in_front = Some(bdis_eval::map::in_front_fraction(&points, &index, &cameras, outlier_mm));
    }
    Ok(score)
}

fn check_size(gt: pfm::PfmImage, est: &pfm::PfmImage, path: &Path) -> Result<pfm::PfmImage> {
    if (gt.width, gt.height) != (est.width, est.height) {
        bail!("{}: {}×{} but the disparity is {}×{}", path.display(), gt.width, gt.height, est.width, est.height);
    }
    Ok(gt)
}
