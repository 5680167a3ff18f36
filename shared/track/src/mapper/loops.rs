//! The mapper's side of loop closing: taking the loop worker's result at a keyframe, closing the loop in the
//! map, and the global bundle adjustment that follows it.

use super::*;

impl LocalMapper {
    /// Takes the loop job sent at the previous keyframe and applies it: a solved pose graph is written back; a
    /// verified place is checked against the map and, when it holds, the loop is closed and its pose graph
    /// returned for the worker.
    pub(super) fn take_loop_result(
        &mut self,
        map: &mut Map,
        kf: KfId,
        cam: &RectifiedCamera,
        scales: &Scales,
        report: &mut MapperReport,
    ) -> Option<crate::loop_closing::GraphJob> {
        let inline = self.mode == BaMode::Inline;
        let loops = self.loops.as_mut()?;
        let outcome = loops.collect()?;
        report.loop_detect_ms = outcome.detect_ms;
        report.pose_graph_ms = outcome.graph_ms;
        if let Some(job) = outcome.graph {
            report.moved.extend(apply_graph(map, &job, scales));
            loops.graph_done();
            report.pose_graph = Some(job.report);
            // The loop's correction is in: now the whole map, from its observations (§8.5).
            self.global = Some(GlobalBa::start(map, kf, cam, scales, inline, self.worker_start));
        }
        // A place the seam scan found counts only once consecutive keyframes agree on it.
        let scanned = outcome.scanned.and_then(|(q, place)| loops.seam_place(map, q, place).map(|m| (q, m)));
        let (query, found) = outcome.found.or(scanned)?;
        let seam = loops.seam_between(query, found.candidate);
        let closed = close_loop(map, cam, scales, query, &found, seam)?;
        report.fused += closed.fused;
        report.moved.extend(closed.moved);
        loops.closed(query, found.candidate);
        report.loop_closed = Some((query, found.candidate));
        report.loop_drift_chi2 = closed.drift_chi2;
        if closed.graph.is_none() {
            // Drift within noise: nothing was moved, but the fused points tie the two passes together, and a
            // global adjustment lets both passes' observations place every keyframe.
            self.global = Some(GlobalBa::start(map, kf, cam, scales, inline, self.worker_start));
        }
        closed.graph
    }

    /// Applies the global bundle adjustment when it is due (waiting for it if needed); `now` applies it whatever.
    pub(super) fn step_global_ba(&mut self, map: &mut Map, scales: &Scales, report: &mut MapperReport, now: bool) {
        let Some(global) = self.global.as_mut() else { return };
        global.due_in = global.due_in.saturating_sub(1);
        if global.due_in > 0 && !now {
            return;
        }
        if let Some(global) = self.global.take() {
            let moved = global.apply(map, scales, report);
            report.moved.extend(moved);
            report.moved.sort_unstable();
            report.moved.dedup();
        }
    }

    /// At the end of a run: the loop job in flight is taken and applied, and a loop it found is closed with its
    /// pose graph solved here, so the final map has every correction.
    pub fn finish_loops(&mut self, map: &mut Map, cam: &RectifiedCamera, scales: &Scales, report: &mut MapperReport) {
        let last = map.keyframes.len().saturating_sub(1);
        if let Some(mut job) = self.take_loop_result(map, last, cam, scales, report) {
            job.report = job.graph.optimise(crate::loop_closing::POSE_GRAPH_ITERATIONS);
            report.moved.extend(apply_graph(map, &job, scales));
            report.moved.sort_unstable();
            report.moved.dedup();
            if let Some(l) = self.loops.as_mut() {
                l.graph_done();
            }
            report.pose_graph = Some(job.report);
            self.global = Some(GlobalBa::start(map, last, cam, scales, true, None));
        }
        self.step_global_ba(map, scales, report, true);
    }
}
