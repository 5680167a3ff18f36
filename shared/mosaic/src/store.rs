//! Saving and loading a map (bincode 2 over serde), so a run can be resumed or inspected later.

use std::path::Path;

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::{KeyframeCloud, Mosaic, MosaicError, MosaicParams};

/// The format tag at the start of every saved map; a file with another tag is refused with this name in the
/// message.
pub const MOSAIC_FORMAT: &str = "bdis.v1.mosaic";

#[derive(Serialize, Deserialize)]
struct MosaicFile {
    format: String,
    params: MosaicParams,
    keyframes: Vec<KeyframeCloud>,
    corrections: Vec<(u64, Isometry3<f64>)>,
}

fn file_error(path: &Path, what: impl Into<String>) -> MosaicError {
    MosaicError::File { path: path.display().to_string(), what: what.into() }
}

/// Writes the map to `path` (through a temporary file renamed into place, so a crash never leaves half a map).
pub fn save(mosaic: &Mosaic, path: &Path) -> Result<(), MosaicError> {
    let file = MosaicFile {
        format: MOSAIC_FORMAT.into(),
        params: mosaic.params,
        keyframes: mosaic.keyframes().cloned().collect(),
        corrections: mosaic.corrections().map(|(k, p)| (k, *p)).collect(),
    };
    let bytes = bincode::serde::encode_to_vec(&file, bincode::config::standard())
        .map_err(|e| file_error(path, format!("cannot encode the map: {e}")))?;
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, &bytes).map_err(|e| file_error(&tmp, format!("cannot write: {e}")))?;
    std::fs::rename(&tmp, path).map_err(|e| file_error(path, format!("cannot rename into place: {e}")))?;
    Ok(())
}

/// Reads a map written by [`save`].
pub fn load(path: &Path) -> Result<Mosaic, MosaicError> {
    let bytes = std::fs::read(path).map_err(|e| file_error(path, format!("cannot read: {e}")))?;
    let (file, used): (MosaicFile, usize) =
        bincode::serde::decode_from_slice(&bytes, bincode::config::standard().with_limit::<{ 1 << 31 }>())
            .map_err(|e| file_error(path, format!("not a bdis-slam map ({MOSAIC_FORMAT}): {e}")))?;
    if file.format != MOSAIC_FORMAT {
        return Err(file_error(path, format!("format `{}`, expected `{MOSAIC_FORMAT}`", file.format)));
    }
    if used != bytes.len() {
        return Err(file_error(path, format!("{} bytes after the map", bytes.len() - used)));
    }
    Ok(Mosaic::from_parts(file.params, file.keyframes, file.corrections))
}

/// What [`write_outputs`] wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Outputs {
    pub ply: std::path::PathBuf,
    pub bin: std::path::PathBuf,
    /// None for an empty map (nothing to show).
    pub png: Option<std::path::PathBuf>,
}

/// The map's files in `dir`: `map.ply` (binary; x y z, colour, keyframe_id, confidence), `map.bin` (for
/// [`load`]) and the `map.png` preview `preview_width` pixels wide.
pub fn write_outputs(mosaic: &Mosaic, dir: &Path, preview_width: u32) -> Result<Outputs, MosaicError> {
    let ply = dir.join("map.ply");
    bdis_core::formats::ply::write(&ply, &mosaic.world_cloud()).map_err(|e| file_error(&ply, e.to_string()))?;
    let bin = dir.join("map.bin");
    save(mosaic, &bin)?;
    let png = dir.join("map.png");
    let png = match crate::render_preview(mosaic, preview_width) {
        Some((image, _)) => {
            image.save(&png).map_err(|e| file_error(&png, format!("cannot write the preview: {e}")))?;
            Some(png)
        }
        None => None,
    };
    Ok(Outputs { ply, bin, png })
}
