//! Local mapping (ORB-SLAM2-STEREO.md §6): one keyframe at a time — its observations, recent point culling,
//! new points by triangulation with neighbours, duplicate fusion, local bundle adjustment, keyframe culling.

mod local_ba;
mod loops;

pub use local_ba::{BaJob, solve_local_ba};
use local_ba::{GlobalBa, apply_local_ba, snapshot_local_ba};

use crate::frame::Scales;
use crate::geometry::{CameraFromWorld, RectifiedCamera, skew};
use crate::loop_closing::{LoopCloser, apply_graph, close_loop};
use crate::map::{KfId, Map, PointId};
use crate::optim::{BaEdge, BaProblem, CHI2_MONO, CHI2_STEREO};
use crate::search::TH_LOW;
use crate::search::fuse_point;
use crate::workers::WorkerStart;
use bdis_orb::hamming;
use nalgebra::{Matrix3, Matrix4, Point3, Vector3};
use std::collections::{BTreeMap, BTreeSet};

/// What one keyframe cost and changed.
#[derive(Debug, Clone, Default)]
pub struct MapperReport {
    pub new_points: usize,
    pub fused: usize,
    pub culled_points: usize,
    pub culled_keyframes: usize,
    pub ba_keyframes: usize,
    pub ba_points: usize,
    pub ba_iterations: usize,
    /// How far the applied local bundle adjustment moved the camera centre of the keyframe it was made for,
    /// over that keyframe's median depth: units-free (0.01 is 1 mm at 100 mm); `None` when none was applied.
    /// Where the tracker is right this stays under half a percent; where the map it tracks against is wrong it
    /// reaches several percent (BENCHMARKS.md, issue #17's ninth part), and the frames that follow are doubted.
    pub ba_moved_rel: Option<f64>,
    /// Keyframes whose pose bundle adjustment changed.
    pub moved: Vec<KfId>,
    /// Wall time of the steps, ms: observations and point culling, new points, fusion, waiting for and applying
    /// the previous keyframe's bundle adjustment (all of it when it runs inline), snapshot and keyframe culling.
    pub step_ms: [f64; 5],
    /// A loop closed at this keyframe: (the keyframe that recognised the place, the old keyframe).
    pub loop_closed: Option<(KfId, KfId)>,
    /// The loop's correction against the pose's uncertainty (χ², 6 DoF): below 12.6 it was noise, and the two
    /// sides were fused without moving anything.
    pub loop_drift_chi2: f64,
    /// A pose graph applied at this keyframe (the loop's correction spread over the map).
    pub pose_graph: Option<crate::loop_closing::GraphReport>,
    /// Worker time of the previous keyframe's loop job, ms: recognition and verification, pose-graph solve.
    pub loop_detect_ms: f64,
    pub pose_graph_ms: f64,
    /// Wall time on this thread of taking the loop result and applying it (waiting included), ms.
    pub loop_apply_ms: f64,
    /// A global bundle adjustment applied at this keyframe (after a loop): its iterations, keyframes and points,
    /// and the wall time it took from its start to its result (on its own thread, while tracking went on), ms.
    pub global_ba_iterations: usize,
    pub global_ba_keyframes: usize,
    pub global_ba_points: usize,
    pub global_ba_ms: f64,
}

/// Keyframes processed after a loop before its global bundle adjustment is applied: time for the solve to run
/// beside tracking (≈ 170 ms for 60 keyframes and 4000 points here; a keyframe comes every ~0.3 s at 30 Hz),
/// and a fixed point of every run to apply it at, so runs stay deterministic. Within ORB-SLAM2's 10 keyframes
/// between loops, so no other loop starts meanwhile.
pub const GLOBAL_BA_AFTER_KEYFRAMES: usize = 2;

/// Where local bundle adjustment runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BaMode {
    /// On a worker thread: the map's owner hands it a snapshot and applies the result at the next keyframe.
    #[default]
    Worker,
    /// In the caller's thread, applied at once (tests, offline tools).
    Inline,
}

/// The bundle-adjustment worker: a thread that solves snapshots it receives on a channel.
#[derive(Debug)]
struct BaWorker {
    jobs: Option<std::sync::mpsc::Sender<BaJob>>,
    results: std::sync::mpsc::Receiver<BaJob>,
    thread: Option<std::thread::JoinHandle<()>>,
    in_flight: bool,
}

impl BaWorker {
    fn spawn(on_start: Option<WorkerStart>) -> Option<Self> {
        let (job_tx, job_rx) = std::sync::mpsc::channel::<BaJob>();
        let (result_tx, result_rx) = std::sync::mpsc::channel::<BaJob>();
        let thread = std::thread::Builder::new()
            .name("local-ba".into())
            .spawn(move || {
                if let Some(start) = on_start {
                    start();
                }
                // Ends when the sender side is dropped.
                for job in job_rx {
                    if result_tx.send(solve_local_ba(job)).is_err() {
                        break;
                    }
                }
            })
            .ok()?;
        Some(Self { jobs: Some(job_tx), results: result_rx, thread: Some(thread), in_flight: false })
    }
}

impl Drop for BaWorker {
    fn drop(&mut self) {
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[derive(Debug)]
pub struct LocalMapper {
    mode: BaMode,
    worker: Option<BaWorker>,
    recent: Vec<PointId>,
    /// Loop closing (§8), in the same mode as bundle adjustment; `None` when switched off.
    loops: Option<LoopCloser>,
    /// The global bundle adjustment after a loop, while it runs.
    global: Option<GlobalBa>,
    worker_start: Option<WorkerStart>,
}

impl Default for LocalMapper {
    fn default() -> Self {
        Self::new(BaMode::default())
    }
}

impl LocalMapper {
    pub fn new(mode: BaMode) -> Self {
        Self {
            mode,
            worker: None,
            recent: Vec::new(),
            loops: Some(LoopCloser::new(mode == BaMode::Inline)),
            global: None,
            worker_start: None,
        }
    }

    /// Switches loop closing on (the default) or off; set before the first keyframe.
    pub fn set_loop_closing(&mut self, on: bool) {
        self.loops = on.then(|| LoopCloser::new(self.mode == BaMode::Inline));
        if let Some(l) = self.loops.as_mut() {
            l.set_worker_start(self.worker_start);
        }
    }

    /// What every worker thread runs first ([`WorkerStart`]); set before the first keyframe.
    pub fn set_worker_start(&mut self, start: Option<WorkerStart>) {
        self.worker_start = start;
        if let Some(l) = self.loops.as_mut() {
            l.set_worker_start(start);
        }
    }

    pub fn worker_start(&self) -> Option<WorkerStart> {
        self.worker_start
    }

    /// Whether loop closing is on (the one place this is kept).
    pub fn loop_closing(&self) -> bool {
        self.loops.is_some()
    }

    /// The loops closed so far: (keyframe that recognised the place, old keyframe).
    pub fn loops_closed(&self) -> &[(KfId, KfId)] {
        self.loops.as_ref().map_or(&[], |l| l.loops.as_slice())
    }

    /// The tracker began a new map segment at keyframe `kf` ([`LoopCloser::segment_begun`]).
    pub fn segment_begun(&mut self, kf: KfId) {
        if let Some(l) = self.loops.as_mut() {
            l.segment_begun(kf);
        }
    }

    /// Hands a snapshot to the worker (spawned on first use), or solves and applies it here.
    fn submit_ba(&mut self, job: BaJob, map: &mut Map, scales: &Scales, report: &mut MapperReport) {
        if self.mode == BaMode::Worker {
            if self.worker.is_none() {
                self.worker = BaWorker::spawn(self.worker_start);
            }
            if let Some(w) = self.worker.as_mut()
                && let Some(tx) = &w.jobs
            {
                match tx.send(job) {
                    Ok(()) => {
                        w.in_flight = true;
                        return;
                    }
                    // The worker is gone (it cannot panic on valid input; be safe): solve here.
                    Err(std::sync::mpsc::SendError(job)) => {
                        let solved = solve_local_ba(job);
                        apply_local_ba(map, &solved, scales, report);
                        return;
                    }
                }
            }
        }
        let solved = solve_local_ba(job);
        apply_local_ba(map, &solved, scales, report);
    }

    /// Waits for the bundle adjustment in flight, if any, and applies it to the map.
    pub fn finish_ba(&mut self, map: &mut Map, scales: &Scales, report: &mut MapperReport) {
        let Some(w) = self.worker.as_mut() else { return };
        if !w.in_flight {
            return;
        }
        w.in_flight = false;
        if let Ok(job) = w.results.recv() {
            apply_local_ba(map, &job, scales, report);
        }
    }

    /// Runs every step of §6 for keyframe `kf` (already in the map with its tracked links and new stereo points).
    pub fn process(
        &mut self,
        map: &mut Map,
        kf: KfId,
        cam: &RectifiedCamera,
        scales: &Scales,
        th_depth: f64,
    ) -> MapperReport {
        let mut report = MapperReport::default();
        let mut clock = std::time::Instant::now();
        let mut lap = |report: &mut MapperReport, step: usize| {
            let now = std::time::Instant::now();
            report.step_ms[step] = (now - clock).as_secs_f64() * 1e3;
            clock = now;
        };
        // The previous keyframe's bundle adjustment first (waiting for it if it is still running): results are
        // applied in keyframe order, at the same point of every run, so runs are deterministic.
        self.finish_ba(map, scales, &mut report);
        lap(&mut report, 3);
        self.process_new_keyframe(map, kf, scales);
        report.culled_points = self.cull_recent_points(map, kf);
        lap(&mut report, 0);
        // The loop job of the previous keyframe, after this one is linked (so a correction moves it with its
        // parent).
        let loop_start = std::time::Instant::now();
        self.step_global_ba(map, scales, &mut report, false);
        let graph = self.take_loop_result(map, kf, cam, scales, &mut report);
        report.loop_apply_ms = loop_start.elapsed().as_secs_f64() * 1e3;
        report.new_points = self.create_new_points(map, kf, cam, scales);
        lap(&mut report, 1);
        report.fused = search_in_neighbours(map, kf, cam, scales);
        lap(&mut report, 2);
        if map.n_good_keyframes() > 2 {
            let job = snapshot_local_ba(map, kf, cam, scales);
            self.submit_ba(job, map, scales, &mut report);
        }
        report.culled_keyframes = cull_keyframes(map, kf, cam, th_depth);
        // No detection while a global adjustment is running: a loop closed now would be overwritten by it.
        let global_pending = self.global.is_some();
        if let Some(loops) = self.loops.as_mut() {
            loops.send_keyframe(map, kf, cam, scales, graph, global_pending);
        }
        lap(&mut report, 4);
        report
    }

    /// §6.1.
    fn process_new_keyframe(&mut self, map: &mut Map, kf: KfId, scales: &Scales) {
        let links: Vec<(usize, PointId)> =
            map.keyframes[kf].points.iter().enumerate().filter_map(|(i, p)| p.map(|p| (i, p))).collect();
        for (i, p) in links {
            if map.points[p].bad {
                map.keyframes[kf].points[i] = None;
                continue;
            }
            if map.points[p].observations.contains_key(&kf) {
                if map.points[p].first_kf == kf {
                    self.recent.push(p);
                }
            } else {
                map.add_observation(p, kf, i);
                map.update_normal_and_depth(p, scales);
                map.compute_descriptor(p);
            }
        }
        map.update_connections(kf);
    }

    /// §6.2.
    fn cull_recent_points(&mut self, map: &mut Map, kf: KfId) -> usize {
        let mut culled = 0;
        self.recent.retain(|&p| {
            let point = &map.points[p];
            if point.bad {
                return false;
            }
            let age = kf.saturating_sub(point.first_kf);
            if point.found_ratio() < 0.25 || (age >= 2 && point.n_obs <= 3) {
                map.set_bad_point(p);
                culled += 1;
                return false;
            }
            age < 3
        });
        culled
    }

    /// §6.3: matches between keypoints without points along epipolar lines (brute force over the unmatched
    /// keypoints instead of a vocabulary node), then triangulation or stereo unprojection.
    fn create_new_points(&mut self, map: &mut Map, kf1: KfId, cam: &RectifiedCamera, scales: &Scales) -> usize {
        let neighbours: Vec<KfId> = map.keyframes[kf1].best_covisibles(10).collect();
        let k_inv =
            Matrix3::new(1.0 / cam.fx, 0.0, -cam.cx / cam.fx, 0.0, 1.0 / cam.fy, -cam.cy / cam.fy, 0.0, 0.0, 1.0);
        let mut created = 0;
        let ratio_factor = 1.5 * scales.factor;
        for kf2 in neighbours {
            let (k1, k2) = (&map.keyframes[kf1], &map.keyframes[kf2]);
            // Two veiled keyframes may share the smoke's own texture: it is not triangulated.
            if (k1.centre() - k2.centre()).norm() < cam.baseline() || (k1.veiled && k2.veiled) {
                continue;
            }
            let t1 = k1.camera_from_world;
            let t2 = k2.camera_from_world;
            // F₁₂ = K⁻ᵀ [t₁₂]× R₁₂ K⁻¹ (x₁ᵀ F₁₂ x₂ = 0).
            let t12 = t1 * t2.inverse();
            let r12 = t12.rotation.to_rotation_matrix().into_inner();
            let f12 = k_inv.transpose() * skew(&t12.translation.vector) * r12 * k_inv;
            let free1: Vec<usize> = (0..k1.keypoints.len()).filter(|&i| k1.points[i].is_none()).collect();
            // The free keypoints of kf2 with their position and their epipolar band (3.84·σ², squared px).
            let free2: Vec<(usize, f64, f64, f64)> = (0..k2.keypoints.len())
                .filter(|&j| k2.points[j].is_none())
                .map(|j| {
                    let kp = &k2.keypoints[j];
                    (j, f64::from(kp.x), f64::from(kp.y), 3.84 / scales.inv_sigma2[usize::from(kp.octave)])
                })
                .collect();
            let mut taken2 = vec![false; k2.keypoints.len()];
            let mut pairs = Vec::new();
            for &i in &free1 {
                let kp1 = &k1.keypoints[i];
                let x1 = Vector3::new(f64::from(kp1.x), f64::from(kp1.y), 1.0);
                let line = f12.transpose() * x1;
                let norm2 = line.x * line.x + line.y * line.y;
                let mut best = (TH_LOW + 1, usize::MAX);
                // The epipolar band first: it is a few multiplications and rejects almost every candidate, the
                // descriptor distance then runs on the few near the line (same choice as the other order).
                for &(j, x2, y2, band) in &free2 {
                    let num = line.x * x2 + line.y * y2 + line.z;
                    if num * num >= band * norm2 || taken2[j] {
                        continue;
                    }
                    let d = hamming(&k1.descriptors[i], &k2.descriptors[j]);
                    if d < best.0 {
                        best = (d, j);
                    }
                }
                if best.1 != usize::MAX {
                    taken2[best.1] = true;
                    pairs.push((i, best.1));
                }
            }
            for (i, j) in pairs {
                let Some(x) = triangulate_pair(map, cam, scales, kf1, i, kf2, j, &k_inv, ratio_factor) else {
                    continue;
                };
                let p = map.new_point(x, kf1, i, scales);
                map.add_observation(p, kf2, j);
                map.compute_descriptor(p);
                map.update_normal_and_depth(p, scales);
                self.recent.push(p);
                created += 1;
            }
        }
        created
    }
}

/// Steps 3–5 of §6.3 for one keypoint pair; the world point when every check passes.
#[allow(clippy::too_many_arguments)]
fn triangulate_pair(
    map: &Map,
    cam: &RectifiedCamera,
    scales: &Scales,
    kf1: KfId,
    i: usize,
    kf2: KfId,
    j: usize,
    k_inv: &Matrix3<f64>,
    ratio_factor: f64,
) -> Option<Point3<f64>> {
    let (k1, k2) = (&map.keyframes[kf1], &map.keyframes[kf2]);
    let (kp1, kp2) = (&k1.keypoints[i], &k2.keypoints[j]);
    let (t1, t2) = (k1.camera_from_world, k2.camera_from_world);
    let ray = |t: &CameraFromWorld, u: f32, v: f32| {
        let r = k_inv * Vector3::new(f64::from(u), f64::from(v), 1.0);
        t.inverse().rotation * r
    };
    let (r1, r2) = (ray(&t1, kp1.x, kp1.y), ray(&t2, kp2.x, kp2.y));
    let cos_parallax = r1.dot(&r2) / (r1.norm() * r2.norm());
    let b = cam.baseline();
    let stereo_cos = |k: &crate::map::KeyFrame, idx: usize| {
        if k.is_stereo(idx) { (2.0 * (b / 2.0).atan2(f64::from(k.depth[idx]))).cos() } else { cos_parallax + 1.0 }
    };
    let (c1, c2) = (stereo_cos(k1, i), stereo_cos(k2, j));
    let min_stereo = c1.min(c2);
    let x = if cos_parallax < min_stereo
        && cos_parallax > 0.0
        && (k1.is_stereo(i) || k2.is_stereo(j) || cos_parallax < 0.9998)
    {
        // Linear triangulation (DLT): the null vector of the 4×4 system.
        let p1 = t1.to_homogeneous();
        let p2 = t2.to_homogeneous();
        let (x1, y1) = ((f64::from(kp1.x) - cam.cx) / cam.fx, (f64::from(kp1.y) - cam.cy) / cam.fy);
        let (x2, y2) = ((f64::from(kp2.x) - cam.cx) / cam.fx, (f64::from(kp2.y) - cam.cy) / cam.fy);
        let mut a = Matrix4::zeros();
        a.set_row(0, &(p1.row(2) * x1 - p1.row(0)));
        a.set_row(1, &(p1.row(2) * y1 - p1.row(1)));
        a.set_row(2, &(p2.row(2) * x2 - p2.row(0)));
        a.set_row(3, &(p2.row(2) * y2 - p2.row(1)));
        let svd = a.svd(false, true);
        let vt = svd.v_t?;
        // The singular vector of the smallest singular value.
        let (k_min, _) = svd.singular_values.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))?;
        let h = vt.row(k_min);
        if h[3].abs() < 1e-12 {
            return None;
        }
        Point3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3])
    } else if k1.is_stereo(i) && c1 < c2 {
        t1.inverse() * cam.unproject(f64::from(kp1.x), f64::from(kp1.y), f64::from(k1.depth[i]))
    } else if k2.is_stereo(j) && c2 < c1 {
        t2.inverse() * cam.unproject(f64::from(kp2.x), f64::from(kp2.y), f64::from(k2.depth[j]))
    } else {
        return None;
    };
    // Checks: in front of both, reprojection within χ², scale consistency.
    for (t, k, idx) in [(&t1, k1, i), (&t2, k2, j)] {
        let pc = t * x;
        if pc.z <= 0.0 {
            return None;
        }
        let obs = k.observation(idx, scales.inv_sigma2[usize::from(k.keypoints[idx].octave)]);
        let limit = if obs.is_stereo() { 7.8 } else { CHI2_MONO };
        if crate::optim::chi2(cam, t, &x, &obs) > limit {
            return None;
        }
    }
    let (d1, d2) = ((x - k1.centre()).norm(), (x - k2.centre()).norm());
    if d1 == 0.0 || d2 == 0.0 {
        return None;
    }
    let ratio_dist = d2 / d1;
    let ratio_octave = scales.scale[usize::from(kp1.octave)] / scales.scale[usize::from(kp2.octave)];
    if ratio_dist * ratio_factor < ratio_octave || ratio_dist > ratio_octave * ratio_factor {
        return None;
    }
    Some(x)
}

/// §6.4.
fn search_in_neighbours(map: &mut Map, kf: KfId, cam: &RectifiedCamera, scales: &Scales) -> usize {
    let mut targets: Vec<KfId> = Vec::new();
    for n in map.keyframes[kf].best_covisibles(10).collect::<Vec<_>>() {
        if map.keyframes[n].bad || targets.contains(&n) {
            continue;
        }
        targets.push(n);
        for n2 in map.keyframes[n].best_covisibles(5).collect::<Vec<_>>() {
            if n2 != kf && !map.keyframes[n2].bad && !targets.contains(&n2) {
                targets.push(n2);
            }
        }
    }
    let mut fused = 0;
    let own: Vec<PointId> = map.keyframes[kf].points.iter().flatten().copied().collect();
    for &t in &targets {
        for &p in &own {
            if let Some(p) = map.resolve(p) {
                fused += usize::from(fuse_point(map, cam, scales, t, p));
            }
        }
    }
    let mut candidates: BTreeSet<PointId> = BTreeSet::new();
    for &t in &targets {
        candidates.extend(map.keyframes[t].points.iter().flatten().copied().filter(|&p| !map.points[p].bad));
    }
    for p in candidates {
        fused += usize::from(fuse_point(map, cam, scales, kf, p));
    }
    let own: Vec<PointId> = map.keyframes[kf].points.iter().flatten().copied().collect();
    for p in own {
        if !map.points[p].bad {
            map.compute_descriptor(p);
            map.update_normal_and_depth(p, scales);
        }
    }
    map.update_connections(kf);
    fused
}

/// Keyframes younger than this (in keyframe ids) are never culled.
pub const CULL_MIN_AGE_KEYFRAMES: usize = 20;

/// §6.6: a covisible keyframe whose close stereo points are > 90 % seen by ≥ 3 other keyframes at the same or a
/// finer (or one coarser) octave is redundant.
fn cull_keyframes(map: &mut Map, kf: KfId, cam: &RectifiedCamera, th_depth: f64) -> usize {
    let close = th_depth * cam.baseline();
    let candidates: Vec<KfId> = map.keyframes[kf].ordered.iter().map(|(k, _)| *k).collect();
    let mut culled = 0;
    for k in candidates {
        // The most recent keyframes are the local window of bundle adjustment: culling them there threw away
        // constraints the next frames still used (ATE on the synthetic colon 0.39 → 0.31 mm with this rule).
        if k == 0 || map.keyframes[k].bad || k + CULL_MIN_AGE_KEYFRAMES > kf {
            continue;
        }
        let (mut n_mps, mut redundant) = (0, 0);
        let kfr = &map.keyframes[k];
        for (i, p) in kfr.points.iter().enumerate() {
            let Some(p) = *p else { continue };
            let point = &map.points[p];
            if point.bad {
                continue;
            }
            let z = f64::from(kfr.depth[i]);
            if z < 0.0 || z > close {
                continue;
            }
            n_mps += 1;
            if point.n_obs > 3 {
                let octave = kfr.keypoints[i].octave;
                let others = point
                    .observations
                    .iter()
                    .filter(|&(&o, &idx)| o != k && map.keyframes[o].keypoints[idx].octave <= octave + 1)
                    .count();
                if others >= 3 {
                    redundant += 1;
                }
            }
        }
        if n_mps > 0 && redundant as f64 > 0.9 * n_mps as f64 {
            map.set_bad_keyframe(k);
            culled += 1;
        }
    }
    culled
}
