//! `tracking.json` (`bdis.v1.tracking`): what the tracking service did in a run, over all its instances. The
//! service writes it at the end of the stream; the launcher's demo and benchmark read it.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{FormatError, invalid, io_error};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrackingSummary {
    /// `bdis.v1.tracking`.
    pub schema: String,
    /// Frames tracked, by every instance of the run.
    pub frames: u64,
    /// Of those, the frames of instances that crashed (from the journal).
    pub frames_of_earlier_instances: u64,
    pub lost: u64,
    /// Of the lost frames, why, by reason (`few-inliers`, `unconfirmed`: a view that changed wholesale).
    #[serde(default)]
    pub lost_reasons: std::collections::BTreeMap<String, u64>,
    /// Frames tracked whose pose the tracker did not trust (`Uncertain`), and why, by reason.
    #[serde(default)]
    pub uncertain: u64,
    #[serde(default)]
    pub doubts: std::collections::BTreeMap<String, u64>,
    /// Frames posed by matching the reference keyframe by appearance (no prior): the start, after a
    /// relocalisation, when the motion model failed, and when it disagreed with appearance (`priors_rejected`).
    #[serde(default)]
    pub appearance_frames: u64,
    #[serde(default)]
    pub priors_rejected: u64,
    /// Tracking-thread CPU of those frames, ms (keyframe frames included).
    #[serde(default)]
    pub appearance_frame_cpu_ms_p50: Option<f64>,
    #[serde(default)]
    pub appearance_frame_cpu_ms_p99: Option<f64>,
    pub relocalisations: u64,
    /// Map segments begun after a loss in tissue relocalisation did not know (their frames are doubted
    /// `detached` until tied back).
    #[serde(default)]
    pub segments_begun: u64,
    /// Keyframe ids handed out (the next id is this number). A keyframe made under a veil (smoke) takes an id
    /// but is not published: it serves tracking only.
    pub keyframes_created: u64,
    /// Keyframes in the last instance's map after culling.
    pub keyframes_in_map: u64,
    pub map_points: u64,
    /// Tracking-thread CPU per frame without a new keyframe, and per keyframe (tracking plus local mapping),
    /// ms, by the nearest-rank rule (`bdis_core::stats::percentile`); `None` without such frames.
    pub frame_cpu_ms_p50: Option<f64>,
    pub frame_cpu_ms_p99: Option<f64>,
    pub keyframe_cpu_ms_p50: Option<f64>,
    pub keyframe_cpu_ms_p99: Option<f64>,
    /// Loops closed: (keyframe that recognised the place, the old keyframe), in the run's keyframe ids.
    #[serde(default)]
    pub loops_closed: Vec<(u64, u64)>,
    /// Worker time of place recognition per keyframe and of each pose-graph solve, ms.
    #[serde(default)]
    pub loop_detection_ms_p50: Option<f64>,
    /// The keyframe whose place recognition took longest, ms: most keyframes have no candidate and cost
    /// nothing, so the median hides the keyframes that search (a detached segment's scan of the older map).
    #[serde(default)]
    pub loop_detection_ms_max: Option<f64>,
    #[serde(default)]
    pub pose_graph_ms: Vec<f64>,
    /// Each global bundle adjustment after a loop, its own thread's wall time, ms (it runs beside tracking).
    #[serde(default)]
    pub global_ba_ms: Vec<f64>,
}

impl TrackingSummary {
    pub const SCHEMA: &'static str = "bdis.v1.tracking";

    pub fn read(path: &Path) -> Result<Self, FormatError> {
        let text = std::fs::read_to_string(path).map_err(io_error(path))?;
        let summary: Self = serde_json::from_str(&text).map_err(|e| invalid(path, Some(e.line()), e.to_string()))?;
        if summary.schema != Self::SCHEMA {
            return Err(invalid(path, None, format!("schema `{}`, expected `{}`", summary.schema, Self::SCHEMA)));
        }
        Ok(summary)
    }

    pub fn write(&self, path: &Path) -> Result<(), FormatError> {
        let text = serde_json::to_string_pretty(self).map_err(|e| invalid(path, None, e.to_string()))?;
        std::fs::write(path, text).map_err(io_error(path))
    }
}
