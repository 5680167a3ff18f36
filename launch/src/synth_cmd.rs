//! `bdis-slam synth`: writes a synthetic stereo endoscopy sequence with exact ground truth.

use std::path::PathBuf;

use anyhow::{Result, bail};
use bdis_synth::RectifiedCamera;
use bdis_synth::render::WrittenSequence;

#[derive(Debug, clap::Args)]
pub struct SynthArgs {
    /// Scene: `colon` (a tube with haustral folds) or `abdomen` (a wall with organ-like blobs, seen from above).
    #[arg(long, default_value = "colon")]
    scene: String,
    /// Camera path. Colon: `forward` (through the tube, wobble and roll) or `revisit` (in, then back out over the
    /// same wall). Abdomen: `hover`, `sweep` (sideways), `revisit` (out and back), `pan` (swinging ±17° at up to
    /// 120°/s while drifting sideways), `oblique` (looking across the wall: a far background), `circle` (round a
    /// 40 mm circle, back to the start after a lap: 377 frames at 20 mm/s and 30 fps), `twins` (the sweep over a
    /// wall that repeats, pattern and shape, every 80 mm: two places no view can tell apart, a loop that must not
    /// be closed). Default: forward / sweep.
    #[arg(long)]
    trajectory: Option<String>,
    /// How the speed varies: `steady`, `jerk` (a third of the way in, three frames at 10× the speed) or `stop` (a
    /// third of the way in, a dead stop for a second, then full speed at once).
    #[arg(long, default_value = "steady")]
    motion: String,
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
    /// Render through a raw stereo rig instead of a rectified one: `mild` (barrel distortion, cameras turned by
    /// up to 0.5°) or `strong` (a wide lens's 8-coefficient rational distortion, turned by up to 1.5°). Writes
    /// `calib.yaml` (OpenCV layout) instead of `settings.yaml`: rectify with `bdis-slam rectify`.
    #[arg(long)]
    raw: Option<String>,
    /// Interlaced footage, as an SDI camera (1080i) gives it: renders one frame per field at twice --fps and
    /// weaves each pair (top field first) into one frame; writes `interlaced/` (the woven frames) and
    /// `progressive/` (the top fields' frames whole: what a progressive camera would give), each with its
    /// settings and ground truth, and the field-rate render in `fields/`. Track with `run --interlaced`.
    #[arg(long, conflicts_with = "raw")]
    interlaced: bool,
    /// Blur of the optics, Gaussian σ in pixels of the camera (the raw one with --raw), applied before the
    /// sensor noise: a lens's spread and a pixel's area, which a real endoscope has and a ray per pixel has not
    /// (0.5 is a sharp HD endoscope). 0: none
    #[arg(long, default_value_t = 0.0)]
    optics_blur_px: f64,
    /// Instruments in the view: two laparoscopic graspers from the borders over the abdomen, a working-channel
    /// tool in the colon; metal, moving on their own, in the images and gt/depth but not gt/mesh.ply, with each
    /// frame's mask in gt/masks/ (what `run --masks` reads)
    #[arg(long)]
    instruments: bool,
    /// A puff of surgical smoke 40 % of the way in: a haze that rises in 0.3 s, hides most of the tissue's light
    /// at its thickest for 0.5 s and clears in 0.8 s (in the images only, not the ground truth). `cavity` (what a
    /// bare --smoke gives): a billowed cloud that stays where it was made, in front of the scope between it and
    /// the tissue, drifting up, as real smoke does (a moving scope sees it as a still scene at its depth, and
    /// flies into it). `scope`: a billowed sheet at half the working distance that rides with the scope, which
    /// no real smoke does; the harder case for a tracker, and the smoke of figures measured before 2026-11-30
    #[arg(long, value_name = "WHERE", num_args = 0..=1, default_missing_value = "cavity")]
    smoke: Option<String>,
    /// A bleed 30 % of the way in: a pool of blood spreads over 2 s from the tissue just below the centre of the
    /// view to about a fifth of the view across, dark red and wet (a sharp moving sheen), and stays. A film on the
    /// tissue: in the images only; depth and mesh are unchanged
    #[arg(long)]
    bleeding: bool,
    /// Breathing: the tissue swells and settles every 4 s (0.25 Hz) by up to this many mm, a standing wave over
    /// it (patches half a --breathing-wavelength apart move opposite ways: not a rigid motion the scope could be
    /// blamed for). gt/depth follows each frame's tissue; gt/mesh.ply is the mean surface, what the map should
    /// converge to. 0: still
    #[arg(long, default_value_t = 0.0, value_name = "MM")]
    breathing: f64,
    /// Breathing's wavelength over the tissue, mm: patches this far apart rise together, half of it apart
    /// opposite ways. Longer: more of what a view sees moves as a whole (which looks like the scope moving)
    #[arg(long, default_value_t = bdis_synth::breathing::WAVELENGTH_MM, value_name = "MM")]
    breathing_wavelength: f64,
    /// How the scene is lit: `scope` (the light at the scope's tip, as an endoscope's: falloff with distance,
    /// the relief's shading, moving highlights, vignetting), `no-highlights`, `flat-diffuse` (no relief shading:
    /// every patch lit as if it faced the light), `albedo` (no light model: the texture as it is; sensor noise
    /// kept). The light rides on the scope, so a patch's shading changes as it moves: vary it to see what
    /// depends on the light
    #[arg(long, default_value = "scope")]
    lighting: String,
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
    let Some(motion) = bdis_synth::Motion::parse(&args.motion) else {
        bail!("--motion: `{}` is not a motion ({})", args.motion, bdis_synth::Motion::NAMES);
    };
    let Some(lighting) = bdis_synth::Lighting::parse(&args.lighting) else {
        bail!("--lighting: `{}` is not a lighting ({})", args.lighting, bdis_synth::Lighting::NAMES);
    };
    let smoke = match args.smoke.as_deref() {
        None => None,
        Some("scope") => Some(bdis_synth::smoke::Anchoring::Scope),
        Some("cavity") => Some(bdis_synth::smoke::Anchoring::Cavity),
        Some(other) => bail!("--smoke: `{other}` is not where smoke can hang (cavity, scope)"),
    };
    let rig = RectifiedCamera {
        width: args.width,
        height: args.height,
        fx: args.focal,
        fy: args.focal,
        cx: f64::from(args.width) / 2.0,
        cy: f64::from(args.height) / 2.0,
        bf: args.focal * args.baseline_mm,
    };
    // Interlaced: one rendered frame per field, at twice the rate.
    let fields = if args.interlaced { 2 } else { 1 };
    let request = bdis_synth::SceneRequest {
        scene: args.scene.clone(),
        trajectory: args.trajectory.clone(),
        frames: args.frames * fields,
        fps: args.fps * fields as f64,
        speed_mm_s: args.speed,
        motion,
        seed: args.seed,
        raw: args.raw.clone(),
        optics_blur_px: args.optics_blur_px,
        instruments: args.instruments,
        smoke,
        breathing_mm: args.breathing,
        bleeding: args.bleeding,
        breathing_wavelength_mm: args.breathing_wavelength,
        lighting,
    };
    if args.interlaced {
        render_with_progress(&args.out.join("fields"), &rig, &request)?;
        let (interlaced, progressive) = (args.out.join("interlaced"), args.out.join("progressive"));
        let woven = bdis_synth::interlace::weave(&args.out.join("fields"), &interlaced, &progressive)?;
        println!(
            "{}: {} interlaced stereo frames of {}×{} (top field first) in interlaced/, the same frames progressive in \
             progressive/, {} fields in fields/; track with: bdis-slam run --track --sequence {} --settings {} \
             --interlaced top-field",
            args.out.display(),
            woven.frames,
            args.width,
            args.height,
            2 * woven.frames,
            interlaced.display(),
            interlaced.join("settings.yaml").display()
        );
        return Ok(());
    }
    let written = render_with_progress(&args.out, &rig, &request)?;
    if args.raw.is_some() {
        println!(
            "{}: {} raw stereo frames of {}×{} through the `{}` rig, its calibration in calib.yaml; rectify with: bdis-slam rectify --settings {} --sequence {} --out <dir>",
            args.out.display(),
            written.frames,
            args.width,
            args.height,
            args.raw.as_deref().unwrap_or_default(),
            written.settings.display(),
            args.out.display()
        );
        return Ok(());
    }
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

/// Renders a named scene and path into `out`, with a progress bar on a terminal.
pub fn render_with_progress(
    out: &std::path::Path,
    rig: &RectifiedCamera,
    request: &bdis_synth::SceneRequest,
) -> Result<WrittenSequence> {
    let bar = bdis_slam::progress::bar(request.frames as u64, "rendering {bar:40} {pos}/{len} frames ({eta} left)");
    let written = bdis_synth::write_scene(out, rig, request, |_| bar.inc(1))?;
    bar.finish_and_clear();
    if let Some(past) = written.past_the_scene {
        // Not an error (the oblique path looks into the distance by design), but a tracker judged on such frames
        // is judged on a view a third of which may be black: say so where the sequence is made.
        eprintln!(
            "note: {} of {} frames ({}–{} in left/) see past the modelled scene: up to {:.0} % of the view is black \
             there, with nothing to track (a path off the scene's edge, or a view across it into the distance); \
             fewer --frames or a lower --speed keeps a path over the tissue",
            past.frames,
            written.frames,
            past.first + 1,
            past.last + 1,
            100.0 * past.worst_share
        );
    }
    Ok(written)
}
