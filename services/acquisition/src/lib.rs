//! Acquisition: stereo sources and frame decoding, with no knowledge of processes or transport. The
//! `bdis-acquisition` binary wires this to shared memory.

pub mod decode;
pub mod pacing;
pub mod source;

pub use decode::{DecodeError, FrameDecoder};
pub use pacing::{Pacing, Schedule};
pub use source::{FrameEntry, Layout, Sequence, SourceError};

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
