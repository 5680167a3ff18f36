//! A finished run's folder, read once into what the page asks for: the map in blocks ([`crate::encode_map`]),
//! the path with each frame's tracking state, the keyframes, the launcher's latency report and the previews.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use bdis_core::formats::quality::{self, read_quality_log};
use bdis_core::formats::trajectory::read_tum;
use serde::Serialize;

use crate::ViewerError;

/// One pose of the path: time, position, orientation (x, y, z, w) and the tracker's state for that frame.
#[derive(Debug, Clone, Serialize)]
pub struct PathPose {
    pub t_s: f64,
    pub position: [f64; 3],
    pub orientation_xyzw: [f64; 4],
    /// `ok`, `uncertain`, `lost` or `not-initialised`; `unknown` when the run wrote no `tracking-quality.csv`.
    pub state: String,
}

/// What `/api/run` answers.
#[derive(Debug, Clone, Serialize)]
pub struct RunSummary {
    pub name: String,
    pub path: Vec<PathPose>,
    pub keyframes: Vec<PathPose>,
    pub map_keyframes: usize,
    pub map_points: usize,
    /// The launcher's `latency.json` as written (processes, hops, end-to-end, events), when the run has one.
    pub latency: Option<serde_json::Value>,
    pub has_depth_preview: bool,
    pub has_map_preview: bool,
}

/// A finished run, read into memory.
#[derive(Debug, Clone)]
pub struct RunView {
    pub dir: PathBuf,
    pub summary: RunSummary,
    /// [`crate::encode_map`] of `map.bin` (just the header when the run has no map).
    pub map_blocks: Vec<u8>,
    pub depth_preview_png: Option<Vec<u8>>,
    pub map_preview_png: Option<Vec<u8>>,
}

fn file_error(path: &Path, what: impl std::fmt::Display) -> ViewerError {
    ViewerError::File { path: path.to_path_buf(), what: what.to_string() }
}

fn read_optional(path: &Path) -> Result<Option<Vec<u8>>, ViewerError> {
    match std::fs::read(path) {
        Ok(bytes) => Ok(Some(bytes)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(file_error(path, e)),
    }
}

/// The state of every frame by its time in microseconds (the key both `trajectory.tum` and the quality log
/// round to); none when the run wrote no quality log.
fn frame_states(path: &Path) -> Result<HashMap<i64, String>, ViewerError> {
    if !path.exists() {
        return Ok(HashMap::new());
    }
    // Its errors name the file, the line and the field.
    let log = read_quality_log(path)?;
    Ok(log.lines.iter().map(|l| (micros(l.t_source_s), l.state.name().to_owned())).collect())
}

fn micros(t_s: f64) -> i64 {
    (t_s * 1e6).round() as i64
}

fn read_path(path: &Path, states: &HashMap<i64, String>) -> Result<Option<Vec<PathPose>>, ViewerError> {
    if !path.exists() {
        return Ok(None);
    }
    // Its errors name the file and the line.
    let poses = read_tum(path)?;
    Ok(Some(
        poses
            .iter()
            .map(|p| {
                let q = p.world_from_camera.rotation.quaternion().coords;
                PathPose {
                    t_s: p.t_s,
                    position: p.world_from_camera.translation.vector.into(),
                    orientation_xyzw: [q.x, q.y, q.z, q.w],
                    state: states.get(&micros(p.t_s)).cloned().unwrap_or_else(|| "unknown".into()),
                }
            })
            .collect(),
    ))
}

impl RunView {
    /// Reads the run in `dir`. A run needs a map or a trajectory to be worth a look; the rest (keyframes,
    /// quality log, latency report, previews) is shown when it is there.
    pub fn open(dir: &Path) -> Result<Self, ViewerError> {
        if !dir.is_dir() {
            return Err(file_error(dir, "not a folder"));
        }
        let states = frame_states(&dir.join(quality::FILE_NAME))?;
        let path = read_path(&dir.join("trajectory.tum"), &states)?;
        let keyframes = read_path(&dir.join("keyframes.tum"), &states)?.unwrap_or_default();
        let map_file = dir.join("map.bin");
        let mosaic = if map_file.exists() { Some(bdis_mosaic::load(&map_file)?) } else { None };
        if path.is_none() && mosaic.is_none() {
            return Err(ViewerError::NothingToShow { dir: dir.to_path_buf() });
        }
        let mut map_blocks = Vec::new();
        let mosaic = mosaic.unwrap_or_else(|| bdis_mosaic::Mosaic::new(bdis_mosaic::MosaicParams::default()));
        crate::encode_map(&mosaic, &mut map_blocks);
        let latency_file = dir.join("latency.json");
        let latency = match read_optional(&latency_file)? {
            Some(bytes) => Some(serde_json::from_slice(&bytes).map_err(|e| file_error(&latency_file, e))?),
            None => None,
        };
        let depth_preview_png = read_optional(&dir.join("depth-preview.png"))?;
        let map_preview_png = read_optional(&dir.join("map.png"))?;
        let name = latency
            .as_ref()
            .and_then(|l: &serde_json::Value| l.get("name")?.as_str().map(str::to_owned))
            .or_else(|| dir.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_default();
        let summary = RunSummary {
            name,
            path: path.unwrap_or_default(),
            keyframes,
            map_keyframes: mosaic.keyframes().filter(|k| !k.points.is_empty()).count(),
            map_points: mosaic.n_points(),
            latency,
            has_depth_preview: depth_preview_png.is_some(),
            has_map_preview: map_preview_png.is_some(),
        };
        Ok(Self { dir: dir.to_path_buf(), summary, map_blocks, depth_preview_png, map_preview_png })
    }
}
