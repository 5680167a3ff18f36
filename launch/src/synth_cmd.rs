//! `bdis-slam synth`: writes a synthetic stereo endoscopy sequence with exact ground truth.

use std::path::PathBuf;

use anyhow::{Result, bail};
use bdis_synth::StereoRig;
use bdis_synth::abdomen::Abdomen;
use bdis_synth::colon::Colon;
use bdis_synth::render::{Shading, Surface, WrittenSequence};
use nalgebra::Isometry3;

#[derive(Debug, clap::Args)]
pub struct SynthArgs {
    /// Scene: `colon` (a tube with haustral folds) or `abdomen` (a wall with organ-like blobs, seen from above).
    #[arg(long, default_value = "colon")]
    scene: String,
    /// Camera path. Colon: `forward` (through the tube, wobble and roll) or `revisit` (in, then back out over the
    /// same wall). Abdomen: `hover`, `sweep` (sideways), `revisit` (out and back). Default: forward / sweep.
    #[arg(long)]
    trajectory: Option<String>,
    #[arg(long, default_value_t = 60)]
    frames: usize,
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Speed along the path, mm/s.
    #[arg(long, default_value_t = 20.0)]
    speed: f64,
    #[arg(long, default_value_t = 640)]
    width: u32,
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// Focal length in px (fx = fy); the principal point is the image centre.
    #[arg(long, default_value_t = 520.0)]
    focal: f64,
    #[arg(long, default_value_t = 5.0)]
    baseline_mm: f64,
    /// Texture and shape seed: the same seed gives byte-identical files.
    #[arg(long, default_value_t = 2026)]
    seed: u64,
    /// Output folder (left/, right/, times.txt, settings.yaml, gt/).
    #[arg(long)]
    out: PathBuf,
}

pub fn synth(args: SynthArgs) -> Result<()> {
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if args.frames == 0
        || args.width < 32
        || args.height < 32
        || !positive(args.focal)
        || !positive(args.baseline_mm)
        || !positive(args.fps)
    {
        bail!("give frames ≥ 1, an image of at least 32×32, and positive focal, baseline and fps");
    }
    let rig = StereoRig {
        width: args.width,
        height: args.height,
        fx: args.focal,
        fy: args.focal,
        cx: f64::from(args.width) / 2.0,
        cy: f64::from(args.height) / 2.0,
        baseline_mm: args.baseline_mm,
    };
    let total_s = (args.frames.max(1) - 1) as f64 / args.fps;
    let (speed, seed) = (args.speed, args.seed);
    let written = match (args.scene.as_str(), args.trajectory.as_deref()) {
        ("colon", trajectory @ (None | Some("forward") | Some("revisit"))) => {
            let colon = Colon { seed, texture: bdis_synth::TissueTexture { seed }, ..Colon::default() };
            let revisit = trajectory == Some("revisit");
            let path = move |t: f64| {
                if revisit { colon.revisit_pose(t, total_s, speed) } else { colon.forward_pose(t, speed) }
            };
            let far = speed * if revisit { 0.5 * total_s } else { total_s };
            let mesh = colon.mesh(-20.0, far + 150.0, 0.5, 180);
            render_with_progress(&args.out, &rig, &colon, &path, mesh, &Shading::default(), args.frames, args.fps)?
        }
        ("abdomen", trajectory @ (None | Some("hover") | Some("sweep") | Some("revisit"))) => {
            let abdomen = Abdomen { seed, texture: bdis_synth::TissueTexture { seed }, ..Abdomen::default() };
            let a = abdomen.clone();
            let path = move |t: f64| match trajectory {
                Some("hover") => a.hover_pose(t),
                Some("revisit") => a.revisit_pose(t, total_s, speed),
                _ => a.sweep_pose(t, speed),
            };
            let extent = 60.0 + speed * total_s;
            // A laparoscope's light is stronger and the wall farther away than in a colon.
            let shading = Shading { exposure_distance_mm: 65.0, ..Shading::default() };
            render_with_progress(
                &args.out,
                &rig,
                &abdomen,
                &path,
                abdomen.mesh(extent, 0.5),
                &shading,
                args.frames,
                args.fps,
            )?
        }
        ("colon" | "abdomen", Some(other)) => bail!(
            "--trajectory: `{other}` does not fit scene `{}` (colon: forward, revisit; abdomen: hover, sweep, revisit)",
            args.scene
        ),
        (other, _) => bail!("--scene: `{other}` is not a scene (colon, abdomen)"),
    };
    println!(
        "{}: {} stereo frames of {}×{} with ground truth (gt/poses.tum, gt/depth, gt/disparity, gt/mesh.ply), mean depth {:.1} mm",
        args.out.display(),
        written.frames,
        args.width,
        args.height,
        written.mean_depth_mm
    );
    Ok(())
}

/// Renders a camera path over a scene into `out`, with a progress bar on a terminal.
#[allow(clippy::too_many_arguments)]
pub fn render_with_progress(
    out: &std::path::Path,
    rig: &StereoRig,
    surface: &dyn Surface,
    path: &dyn Fn(f64) -> Isometry3<f64>,
    mesh: (Vec<[f32; 3]>, Vec<[u32; 3]>),
    shading: &Shading,
    frames: usize,
    fps: f64,
) -> Result<WrittenSequence> {
    let bar = indicatif::ProgressBar::new(frames as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("rendering {bar:40} {pos}/{len} frames ({eta} left)")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let written =
        bdis_synth::render::write_sequence(out, rig, surface, path, mesh, shading, frames, fps, |_| bar.inc(1))?;
    bar.finish_and_clear();
    Ok(written)
}
