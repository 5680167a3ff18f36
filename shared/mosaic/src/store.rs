//! Saving and loading a map (bincode 2 over serde), so a run can be resumed or inspected later.

use std::path::Path;

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

use crate::{KeyframeCloud, Mosaic, MosaicError, MosaicParams};

/// The format tag at the start of every saved map; a file with another tag is refused with this name in the
/// message.
pub const MOSAIC_FORMAT: &str = "bdis.v2.mosaic";

/// The format before the depth tolerance became a share of the depth (its value was a length in the map's unit):
/// recognised, to say so, and refused.
const MOSAIC_FORMAT_V1: &str = "bdis.v1.mosaic";

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
    decode(&bytes, path)
}

/// [`load`] on bytes already read; `path` names them in errors.
pub fn decode(bytes: &[u8], path: &Path) -> Result<Mosaic, MosaicError> {
    // The format tag is checked before bincode reads the file: bincode allocates a string's claimed length
    // before it reads it, so a corrupt length in the tag's place would ask for gigabytes (found by fuzzing).
    // Containers of the map itself grow as they are read (serde preallocates cautiously).
    let tag = bincode::serde::encode_to_vec(MOSAIC_FORMAT, bincode::config::standard())
        .map_err(|e| file_error(path, format!("cannot encode the format tag: {e}")))?;
    if !bytes.starts_with(&tag) {
        let v1 = bincode::serde::encode_to_vec(MOSAIC_FORMAT_V1, bincode::config::standard())
            .map_err(|e| file_error(path, format!("cannot encode the format tag: {e}")))?;
        if bytes.starts_with(&v1) {
            return Err(file_error(
                path,
                format!(
                    "a map of an earlier bdis-slam (`{MOSAIC_FORMAT_V1}`, whose depth tolerance was a length; this \
                     one reads `{MOSAIC_FORMAT}`): build it again from its run with `bdis-slam map`"
                ),
            ));
        }
        return Err(file_error(path, format!("not a bdis-slam map: it does not start with `{MOSAIC_FORMAT}`")));
    }
    let (file, used): (MosaicFile, usize) =
        bincode::serde::decode_from_slice(bytes, bincode::config::standard().with_limit::<{ 1 << 31 }>())
            .map_err(|e| file_error(path, format!("not a bdis-slam map ({MOSAIC_FORMAT}): {e}")))?;
    if file.format != MOSAIC_FORMAT {
        return Err(file_error(path, format!("format `{}`, expected `{MOSAIC_FORMAT}`", file.format)));
    }
    if used != bytes.len() {
        return Err(file_error(path, format!("{} bytes after the map", bytes.len() - used)));
    }
    check(&file).map_err(|what| file_error(path, what))?;
    Ok(Mosaic::from_parts(file.params, file.keyframes, file.corrections))
}

/// A map file that decodes is not yet a map: a corrupted or hand-made one can hold numbers no insert would
/// have produced (a zero grid step, NaN poses or points, a camera with no focal length), which would panic or
/// poison every later insert and the written cloud. Everything the mosaic relies on is checked here.
fn check(file: &MosaicFile) -> Result<(), String> {
    let p = &file.params;
    let finite =
        [p.min_confidence, p.min_disparity_px, p.keep_closer_ratio, p.max_weight].iter().all(|v| v.is_finite())
            && p.depth_tolerance_ratio.is_finite()
            && p.disparity_tolerance_px.is_finite();
    if p.depth_gap_px == 0 || !finite {
        return Err(format!("params: {p:?} are not usable (a grid step ≥ 1 and finite numbers)"));
    }
    for k in &file.keyframes {
        crate::check_pose(k.kf_id, &k.world_from_camera).map_err(|e| e.to_string())?;
        let c = &k.intrinsics;
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !(positive(c.fx) && positive(c.fy) && positive(c.bf) && c.cx.is_finite() && c.cy.is_finite())
            || c.width == 0
            || c.height == 0
        {
            return Err(format!("keyframe {}: camera {c:?} describes no camera", k.kf_id));
        }
        // Finite where they are written too: the world cloud is f32, so a pose far out of range would turn
        // finite points into infinities in map.ply.
        let bad_point = k.points.iter().position(|pt| {
            let world = k.world_from_camera * nalgebra::Point3::from(pt.xyz.map(f64::from));
            !world.coords.iter().all(|&v| (v as f32).is_finite())
                || !pt.xyz.iter().all(|v| v.is_finite())
                || !pt.confidence.is_finite()
                || !pt.weight.is_finite()
        });
        if let Some(i) = bad_point {
            return Err(format!("keyframe {}: point {i} has non-finite numbers", k.kf_id));
        }
    }
    for (kf_id, pose) in &file.corrections {
        crate::check_pose(*kf_id, pose).map_err(|e| format!("correction: {e}"))?;
    }
    Ok(())
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
