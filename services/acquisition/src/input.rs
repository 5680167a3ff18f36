//! What acquisition reads, checked before any shared memory exists: the rectification of a raw calibration,
//! the settings of interlaced fields, and the `--check` summary.

use anyhow::{Context, Result};
use bdis_source::{CheckedInput, FrameEntry, Sequence};

/// The settings of a stream published as fields (or bobbed): they describe the published frames, so they are
/// checked against those, not against the woven frames on disk.
pub fn adopt_settings(input: &mut CheckedInput, path: &std::path::Path, published: (u32, u32)) -> Result<()> {
    let settings = bdis_core::Settings::load(path)?;
    if let Some((field, expected, actual)) = bdis_source::size_mismatch(&settings.camera, published) {
        anyhow::bail!(
            "{}: {field} is {expected}, but the published frames are {actual} (with --interlaced the settings \
             describe the field: `bdis-slam run --interlaced` writes them from the frame's)",
            path.display()
        );
    }
    input.camera = Some(settings.camera);
    input.fps = Some(settings.fps);
    input.settings_path = Some(settings.source);
    Ok(())
}

/// `--check`: what the sequence is, in one line.
pub fn print_check(sequence: &Sequence) {
    let times = match (sequence.frames.first(), sequence.frames.last()) {
        (Some(FrameEntry { t_source_s: Some(a), .. }), Some(FrameEntry { t_source_s: Some(b), .. })) => {
            format!("{a:.3}–{b:.3} s")
        }
        _ => "no".to_string(),
    };
    let layout = match sequence.layout {
        bdis_source::Layout::Video(arrangement) => {
            let decoder = sequence.video.as_ref().map_or("ffmpeg", |v| v.decoder);
            format!("video ({}, {decoder})", arrangement.name())
        }
        other => format!("{other:?}"),
    };
    println!(
        "{}: {layout} layout, {} stereo pairs of {}×{}, timestamps: {times}",
        sequence.root.display(),
        sequence.len(),
        sequence.width,
        sequence.height,
    );
}

/// The undistort–rectify maps of a raw calibration for frames of `raw` size, built once before streaming.
pub fn rectifier(path: &std::path::Path, raw: (u32, u32), alpha: Option<f64>) -> Result<bdis_source::Rectifier> {
    if let Some(a) = alpha
        && !(0.0..=1.0).contains(&a)
    {
        anyhow::bail!("--alpha must be within 0..1, found {a}");
    }
    let calib = bdis_rectify::StereoCalibration::load(path)?;
    if let Some(size) = calib.size
        && size != raw
    {
        anyhow::bail!(
            "{}: the calibration is for {}×{} images, but the frames are {}×{}",
            path.display(),
            size.0,
            size.1,
            raw.0,
            raw.1
        );
    }
    let rect = calib.rectification(raw, alpha)?;
    if rect.camera().is_none() {
        anyhow::bail!("{}: the baseline is vertical: the tracker needs a horizontal rig", path.display());
    }
    bdis_source::Rectifier::new(calib.maps(&rect, raw))
        .with_context(|| format!("{}: the rectified frames do not fit a shared-memory frame", path.display()))
}
