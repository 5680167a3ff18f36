//! Stereo sources: sequence layouts, frame decoding straight into the shared-memory frame layout, pacing and
//! the input checks, with no knowledge of processes or transport. The `bdis-acquisition` service and the
//! launcher's offline commands use it.

pub mod decode;
pub mod fields;
mod jpeg;
pub mod live;
pub mod masks;
pub mod pacing;
pub mod reader;
pub mod source;
pub mod video;

pub use decode::{DecodeError, FrameDecoder};
pub use fields::FieldMode;
pub use live::{LiveError, LiveSource, LiveSpec};
pub use masks::{MaskError, MaskFolder};
pub use pacing::{Pacing, Schedule};
pub use reader::{FrameReader, ReadError, Rectifier};
pub use source::{FrameEntry, Layout, Sequence, SourceError, size_mismatch};
pub use video::{Arrangement, VideoDecoder, VideoError, VideoSource, VideoSpec, split_into};

use std::path::{Path, PathBuf};

use bdis_core::{Settings, StereoCamera};

/// A sequence with its calibration, checked against each other: what `bdis-acquisition` and
/// `bdis-slam run --sequence` validate before any process or shared memory exists.
#[derive(Debug, Clone)]
pub struct CheckedInput {
    pub sequence: Sequence,
    pub camera: Option<StereoCamera>,
    pub fps: Option<f64>,
    pub settings_path: Option<PathBuf>,
}

#[derive(Debug, thiserror::Error)]
pub enum InputError {
    #[error(transparent)]
    Source(#[from] SourceError),
    #[error(transparent)]
    Settings(#[from] bdis_core::SettingsError),
}

/// A `synthetic:<scene>[:<trajectory>][:<motion>][:<frames>]` source, e.g. `synthetic:colon`,
/// `synthetic:abdomen:hover:90`, `synthetic:colon:forward:jerk:120`.
pub fn parse_synthetic(source: &str) -> Option<Result<bdis_synth::SceneRequest, String>> {
    let spec = source.strip_prefix("synthetic:")?;
    let mut request = bdis_synth::SceneRequest::default();
    let mut parts = spec.split(':');
    request.scene = parts.next().unwrap_or_default().to_string();
    for part in parts {
        match part.parse::<usize>() {
            Ok(frames) => request.frames = frames,
            Err(_) => match bdis_synth::Motion::parse(part) {
                Some(motion) => request.motion = motion,
                None => request.trajectory = Some(part.to_string()),
            },
        }
    }
    Some(request.validate().map(|()| request).map_err(|e| e.to_string()))
}

/// Renders a synthetic source into `dir` (once: the pipeline then streams the files) and returns the sequence
/// folder and its settings file. Rendering is slower than streaming at VGA, so frames are rendered before the
/// first is published; `progress(i)` reports each.
pub fn render_synthetic(
    request: &bdis_synth::SceneRequest,
    dir: &Path,
    progress: impl FnMut(usize),
) -> Result<(PathBuf, PathBuf), bdis_synth::SynthError> {
    let written = bdis_synth::write_scene(dir, &bdis_synth::default_camera(), request, progress)?;
    Ok((dir.to_path_buf(), written.settings))
}

/// Opens and checks a sequence, and the settings file when one is given.
pub fn check_input(sequence: &Path, settings: Option<&Path>) -> Result<CheckedInput, InputError> {
    let settings = settings.map(Settings::load).transpose()?;
    let sequence = Sequence::open(sequence)?;
    if let Some(s) = &settings {
        sequence.check_camera(&s.camera, &s.source)?;
    }
    Ok(CheckedInput {
        camera: settings.as_ref().map(|s| s.camera).or(sequence.camera),
        fps: settings.as_ref().map(|s| s.fps),
        settings_path: settings.map(|s| s.source),
        sequence,
    })
}
