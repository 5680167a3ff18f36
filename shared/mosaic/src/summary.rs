//! `mosaic.json` (`bdis.v1.mosaic`): what the mosaic service did in a run and where it wrote the map. The
//! service writes it when it stops; the launcher's demo and the tests read it.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::{MosaicError, MosaicParams};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MosaicSummary {
    /// `bdis.v1.mosaic`.
    pub schema: String,
    /// The depth stream ended (rather than a stop request or a failure).
    pub end_of_stream: bool,
    /// Keyframes this instance inserted (a restarted one counts from its restart).
    pub keyframes_inserted: u64,
    /// Keyframes in the map (restored ones included).
    pub keyframes_in_map: u64,
    /// Keyframe ids below the highest one seen that the map never got (ids are consecutive from the tracker).
    pub keyframes_missing: u64,
    /// Depth keyframes received again (a replacement stereo instance redid them) and dropped.
    pub duplicates: u64,
    /// Depth samples that broke their contract (sizes, no pose, a bad camera), skipped.
    pub malformed: u64,
    pub corrections_applied: u64,
    pub snapshots_served: u64,
    pub points: u64,
    /// Points a later, closer view replaced, and points kept behind a closer surface.
    pub points_replaced: u64,
    pub points_kept_behind: u64,
    /// Points removed when the overlap rule ran again after corrections had moved keyframes (a loop's second
    /// surface, [`crate::Mosaic::realign`]). Absent from summaries written before it existed.
    #[serde(default)]
    pub points_removed_realigned: u64,
    /// The map update per keyframe, ms, by the nearest-rank rule; `None` without keyframes.
    pub update_ms_p50: Option<f64>,
    pub update_ms_p99: Option<f64>,
    pub overlapping_keyframes_max: Option<u64>,
    pub params: MosaicParams,
    pub map_ply: PathBuf,
    /// `None` for an empty map (nothing to show).
    pub map_png: Option<PathBuf>,
    pub map_bin: PathBuf,
}

impl MosaicSummary {
    pub const SCHEMA: &'static str = "bdis.v1.mosaic";

    pub fn read(path: &Path) -> Result<Self, MosaicError> {
        let fail = |what: String| MosaicError::File { path: path.display().to_string(), what };
        let text = std::fs::read_to_string(path).map_err(|e| fail(format!("cannot read: {e}")))?;
        let summary: Self = serde_json::from_str(&text).map_err(|e| fail(format!("not a mosaic summary: {e}")))?;
        if summary.schema != Self::SCHEMA {
            return Err(fail(format!("schema `{}`, expected `{}`", summary.schema, Self::SCHEMA)));
        }
        Ok(summary)
    }

    pub fn write(&self, path: &Path) -> Result<(), MosaicError> {
        let fail = |what: String| MosaicError::File { path: path.display().to_string(), what };
        let text = serde_json::to_string_pretty(self).map_err(|e| fail(e.to_string()))?;
        std::fs::write(path, text).map_err(|e| fail(format!("cannot write: {e}")))
    }
}
