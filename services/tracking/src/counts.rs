//! What a run of the tracker counts for `tracking.json`: frames, keyframes, losses, doubts, CPU times, loops.

use bdis_track::mapper::MapperReport;

/// Per-run counts and CPU times for tracking.json.
#[derive(Debug, Default)]
pub struct Counts {
    pub frames: u64,
    pub keyframes: u64,
    pub lost: u64,
    pub lost_reasons: std::collections::BTreeMap<&'static str, u64>,
    pub uncertain: u64,
    pub doubts: std::collections::BTreeMap<&'static str, u64>,
    pub appearance_frames: u64,
    pub priors_rejected: u64,
    /// CPU of the frames posed by appearance, ms.
    pub appearance_ms: Vec<f64>,
    pub relocalised: u64,
    pub segments_begun: u64,
    /// Per-frame CPU (frames without a new keyframe) and per-keyframe CPU (tracking plus local mapping), ms.
    pub frame_ms: Vec<f64>,
    pub keyframe_ms: Vec<f64>,
    /// Worker time of place recognition per keyframe, and of each pose-graph solve, ms.
    pub loop_detection_ms: Vec<f64>,
    pub pose_graph_ms: Vec<f64>,
    /// Wall time of each global bundle adjustment on its thread, ms.
    pub global_ba_ms: Vec<f64>,
}

impl Counts {
    pub fn loop_report(&mut self, report: &MapperReport) {
        if report.loop_detect_ms > 0.0 {
            self.loop_detection_ms.push(report.loop_detect_ms);
        }
        if report.pose_graph.is_some() {
            self.pose_graph_ms.push(report.pose_graph_ms);
        }
        if report.global_ba_keyframes > 0 {
            self.global_ba_ms.push(report.global_ba_ms);
            tracing::info!(
                "global bundle adjustment applied: {} keyframes, {} points, {} iterations, {:.0} ms on its thread",
                report.global_ba_keyframes,
                report.global_ba_points,
                report.global_ba_iterations,
                report.global_ba_ms
            );
        }
        if let Some((kf, old)) = report.loop_closed {
            tracing::info!(
                "loop closed: keyframe {kf} recognised keyframe {old}; {} keyframes moved",
                report.moved.len()
            );
        }
    }
}
