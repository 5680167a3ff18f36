//! Local bundle adjustment (§6.5): the problem cut out of the map around the new keyframe, solved on the
//! worker thread (or inline), and its result written back; and the global one after a loop (§8.5), on a thread
//! of its own, written back as corrections.
use super::*;

/// A local bundle adjustment taken out of the map: the problem and which map ids its rows are.
#[derive(Debug)]
pub struct BaJob {
    /// The keyframe it was made for (its epoch).
    pub kf: KfId,
    problem: BaProblem,
    cam: RectifiedCamera,
    pose_ids: Vec<KfId>,
    point_ids: Vec<PointId>,
    edge_keys: Vec<(PointId, KfId)>,
    iterations: usize,
}

/// The share of a local adjustment's observations that the keyframes it holds fixed must carry at least
/// ([`hold_enough_fixed`]). Measured on the unseen renders at 0.1 / 0.2 / 0.3 of the observations (issue #17's
/// tenth part): 0.2 and 0.3 alike, 0.1 about half the gain.
pub const MIN_FIXED_SHARE: f64 = 0.2;

/// §6.5, step 1–2: local keyframes = `kf` and its ordered covisibles; fixed = other keyframes seeing local
/// points (and keyframe 0); every observation of a local point by a good keyframe is an edge. Not in ORB-SLAM2:
/// the least covisible local keyframes are held fixed too until the fixed ones carry [`MIN_FIXED_SHARE`] of the
/// observations ([`hold_enough_fixed`]).
pub(super) fn snapshot_local_ba(map: &Map, kf: KfId, cam: &RectifiedCamera, scales: &Scales) -> BaJob {
    let mut local: Vec<KfId> = vec![kf];
    local.extend(map.keyframes[kf].ordered.iter().map(|(k, _)| *k).filter(|&k| !map.keyframes[k].bad));
    hold_enough_fixed(map, &mut local);
    snapshot_ba(map, kf, local, None, cam, scales)
}

/// The fixed keyframes are what holds a local adjustment's window in place (its six degrees of freedom). Where
/// the whole map stays covisible (a view that keeps the same tissue in sight) ORB-SLAM2's rule leaves keyframe 0
/// alone fixed: on the oblique view of seed 106 it carried 0.4–1.6 % of the local points' observations, and a
/// window of twenty keyframes floated by millimetres wherever the measurements' small biases pushed it
/// (BENCHMARKS.md, issue #17's tenth part). So keyframes move from the end of `local` (the new keyframe first,
/// then its covisibles by decreasing weight) to the fixed side until the fixed ones observe [`MIN_FIXED_SHARE`]
/// of what all keyframes observe of the local points (each point counted once, as its observations stand).
/// The new keyframe stays free.
fn hold_enough_fixed(map: &Map, local: &mut Vec<KfId>) {
    let local_set: BTreeSet<KfId> = local.iter().copied().collect();
    let mut observations: BTreeMap<KfId, usize> = BTreeMap::new();
    let mut counted: BTreeSet<PointId> = BTreeSet::new();
    for &k in local.iter() {
        for &p in map.keyframes[k].points.iter().flatten() {
            if map.points[p].bad || !counted.insert(p) {
                continue;
            }
            for &o in map.points[p].observations.keys() {
                if !map.keyframes[o].bad {
                    *observations.entry(o).or_default() += 1;
                }
            }
        }
    }
    let total: usize = observations.values().sum();
    // Keyframe 0 is fixed wherever it is.
    let mut fixed: usize =
        observations.iter().filter(|&(k, _)| *k == 0 || !local_set.contains(k)).map(|(_, n)| n).sum();
    while local.len() > 1 && (fixed as f64) < MIN_FIXED_SHARE * total as f64 {
        if let Some(k) = local.pop()
            && k != 0
        {
            fixed += observations.get(&k).copied().unwrap_or(0);
        }
    }
}

/// §8.5's global bundle adjustment: every good keyframe (the oldest held, as the pose graph holds it) and every
/// point they observe. `kf` is the keyframe it was cut at.
pub(super) fn snapshot_global_ba(map: &Map, kf: KfId, cam: &RectifiedCamera, scales: &Scales) -> BaJob {
    let all: Vec<KfId> = map.good_keyframes().map(|k| k.id).collect();
    let oldest = all.first().copied();
    snapshot_ba(map, kf, all, oldest, cam, scales)
}

/// The problem over keyframes `local` (free, but `hold`) and their points; keyframes outside `local` that see
/// those points join fixed.
fn snapshot_ba(
    map: &Map,
    kf: KfId,
    local: Vec<KfId>,
    hold: Option<KfId>,
    cam: &RectifiedCamera,
    scales: &Scales,
) -> BaJob {
    let local_set: BTreeSet<KfId> = local.iter().copied().collect();
    let mut points: BTreeSet<PointId> = BTreeSet::new();
    for &k in &local {
        points.extend(map.keyframes[k].points.iter().flatten().copied().filter(|&p| !map.points[p].bad));
    }
    let mut fixed: BTreeSet<KfId> = BTreeSet::new();
    for &p in &points {
        for &k in map.points[p].observations.keys() {
            if !local_set.contains(&k) && !map.keyframes[k].bad {
                fixed.insert(k);
            }
        }
    }
    let mut pose_index: BTreeMap<KfId, usize> = BTreeMap::new();
    let mut problem = BaProblem::default();
    let mut pose_ids = Vec::new();
    for (&k, is_fixed) in local.iter().map(|k| (k, false)).chain(fixed.iter().map(|k| (k, true))) {
        pose_index.insert(k, problem.poses.len());
        pose_ids.push(k);
        problem.poses.push(map.keyframes[k].camera_from_world);
        problem.fixed.push(is_fixed || k == 0 || Some(k) == hold);
    }
    let point_ids: Vec<PointId> = points.into_iter().collect();
    let mut edge_keys: Vec<(PointId, KfId)> = Vec::new();
    for (pi, &p) in point_ids.iter().enumerate() {
        problem.points.push(map.points[p].position);
        for (&k, &idx) in &map.points[p].observations {
            let Some(&pose) = pose_index.get(&k) else { continue };
            let keyframe = &map.keyframes[k];
            let aligned = keyframe.aligned[idx];
            let octave = keyframe.keypoints[idx].octave;
            let obs = keyframe.observation(idx, scales.information(octave, aligned, map.refined_sigma));
            let sigma = Scales::relative_sigma(aligned, map.refined_sigma);
            let octave_chi2_scale = sigma * sigma;
            problem.edges.push(BaEdge { pose, point: pi, obs, octave_chi2_scale });
            edge_keys.push((p, k));
        }
    }
    problem.excluded = vec![false; problem.edges.len()];
    BaJob { kf, problem, cam: *cam, pose_ids, point_ids, edge_keys, iterations: 0 }
}

/// §6.5 steps 3–4, on the snapshot alone (no map): 5 robust iterations, outliers excluded, 10 plain ones.
pub fn solve_local_ba(mut job: BaJob) -> BaJob {
    job.iterations = job.problem.solve_robust_then_plain(&job.cam);
    job
}

/// §6.5 step 5: writes a solved snapshot back into the map. What changed in the map since the snapshot wins:
/// culled keyframes and bad points are skipped, observations already erased stay erased. Poses and positions are
/// replaced (the map's owner applies results in keyframe order, so nothing newer is overwritten).
pub(super) fn apply_local_ba(map: &mut Map, job: &BaJob, scales: &Scales, report: &mut MapperReport) {
    let cam = job.cam;
    for (k, &(p, kf)) in job.edge_keys.iter().enumerate() {
        let e = &job.problem.edges[k];
        // Observations leave the map by their χ² at the octave's σ: a refined one that fits to 2σ_r is no
        // mismatch (it still weighs only as much as its precision in the next adjustment).
        let x2 = job.problem.edge_chi2(&cam, k) * e.octave_chi2_scale;
        if (x2.is_nan() || x2 > if e.obs.is_stereo() { CHI2_STEREO } else { CHI2_MONO })
            && map.points[p].observations.contains_key(&kf)
        {
            map.erase_observation(p, kf);
        }
    }
    for (i, &k) in job.pose_ids.iter().enumerate() {
        if !job.problem.fixed[i] && !map.keyframes[k].bad {
            if k == job.kf {
                let centre = |pose: &CameraFromWorld| pose.inverse_transform_point(&Point3::origin());
                let moved = (centre(&job.problem.poses[i]) - centre(&map.keyframes[k].camera_from_world)).norm();
                let depth = map.keyframes[k].median_depth;
                report.ba_moved_rel = (depth.is_finite() && depth > 0.0).then(|| moved / depth);
            }
            map.keyframes[k].camera_from_world = job.problem.poses[i];
            report.moved.push(k);
        }
    }
    for (pi, &p) in job.point_ids.iter().enumerate() {
        if !map.points[p].bad {
            map.points[p].position = job.problem.points[pi];
            map.update_normal_and_depth(p, scales);
        }
    }
    report.ba_iterations = job.iterations;
    report.ba_keyframes = job.pose_ids.iter().zip(&job.problem.fixed).filter(|(_, f)| !**f).count();
    report.ba_points = job.point_ids.len();
}

/// A global bundle adjustment in flight: the snapshot as cut (the correction is solved minus cut, so what local
/// bundle adjustment changed meanwhile stays) and the solve, on its own thread or already done.
#[derive(Debug)]
pub(super) struct GlobalBa {
    /// Keyframes processed before it is applied (it waits there if the solve is not done: deterministic).
    pub due_in: usize,
    cut_poses: Vec<CameraFromWorld>,
    cut_points: Vec<Point3<f64>>,
    /// `None` once taken by `apply`.
    solve: Option<GlobalSolve>,
}

impl Drop for GlobalBa {
    /// A solve still running is waited for, not left detached (ORB-SLAM2-STEREO.md §10): it owns nothing shared
    /// and ends within its iterations.
    fn drop(&mut self) {
        if let Some(GlobalSolve::Thread(handle)) = self.solve.take() {
            let _ = handle.join();
        }
    }
}

#[derive(Debug)]
enum GlobalSolve {
    Thread(std::thread::JoinHandle<(BaJob, f64)>),
    Done(Box<(BaJob, f64)>),
}

/// Solves a global adjustment; returns it with its wall time, ms.
fn solve_timed(job: BaJob) -> (BaJob, f64) {
    let start = std::time::Instant::now();
    let solved = solve_local_ba(job);
    (solved, start.elapsed().as_secs_f64() * 1e3)
}

impl GlobalBa {
    /// Cuts the problem at keyframe `kf` and starts solving it: on a thread of its own (`on_start` first), or
    /// here when `inline` (or when no thread can be made).
    pub fn start(
        map: &Map,
        kf: KfId,
        cam: &RectifiedCamera,
        scales: &Scales,
        inline: bool,
        on_start: Option<WorkerStart>,
    ) -> Self {
        let job = snapshot_global_ba(map, kf, cam, scales);
        let cut_poses = job.problem.poses.clone();
        let cut_points = job.problem.points.clone();
        let solve = if inline {
            GlobalSolve::Done(Box::new(solve_timed(job)))
        } else {
            let spawned = std::thread::Builder::new().name("global-ba".into()).spawn(move || {
                if let Some(start) = on_start {
                    start();
                }
                solve_timed(job)
            });
            match spawned {
                Ok(handle) => GlobalSolve::Thread(handle),
                // No thread to be had (the job went with the closure): cut again and solve here.
                Err(_) => GlobalSolve::Done(Box::new(solve_timed(snapshot_global_ba(map, kf, cam, scales)))),
            }
        };
        Self { due_in: GLOBAL_BA_AFTER_KEYFRAMES, cut_poses, cut_points, solve: Some(solve) }
    }

    /// Waits for the solve and writes it into the map as corrections: keyframe k moves by cut⁻¹·solved (what
    /// changed since the cut stays), a keyframe made since moves with its nearest cut ancestor, a cut point by
    /// solved − cut, any other point with its reference keyframe. No observation is erased (ORB-SLAM2's global
    /// adjustment does not either). Returns the keyframes moved, or nothing if the solve was lost.
    pub fn apply(mut self, map: &mut Map, scales: &Scales, report: &mut MapperReport) -> Vec<KfId> {
        let (job, solve_ms) = match self.solve.take() {
            Some(GlobalSolve::Done(solved)) => *solved,
            Some(GlobalSolve::Thread(handle)) => match handle.join() {
                Ok(solved) => solved,
                Err(_) => return Vec::new(),
            },
            None => return Vec::new(),
        };
        if job.pose_ids.len() != self.cut_poses.len() || job.point_ids.len() != self.cut_points.len() {
            return Vec::new();
        }
        let mut correction: BTreeMap<KfId, nalgebra::Isometry3<f64>> = BTreeMap::new();
        for (i, &k) in job.pose_ids.iter().enumerate() {
            correction.insert(k, self.cut_poses[i].inverse() * job.problem.poses[i]);
        }
        let of_keyframe = crate::loop_closing::corrections_by_ancestry(map, &correction);
        let mut moved = Vec::new();
        for (k, w) in of_keyframe.iter().enumerate() {
            if !map.keyframes[k].bad {
                map.keyframes[k].camera_from_world =
                    crate::loop_closing::renormalised(map.keyframes[k].camera_from_world * w);
                moved.push(k);
            }
        }
        let mut in_cut = vec![false; map.points.len()];
        for (pi, &p) in job.point_ids.iter().enumerate() {
            if p < map.points.len() && !map.points[p].bad {
                map.points[p].position += job.problem.points[pi] - self.cut_points[pi];
                in_cut[p] = true;
            }
        }
        for p in 0..map.points.len() {
            if map.points[p].bad {
                continue;
            }
            if !in_cut[p] {
                let w = of_keyframe[map.points[p].ref_kf];
                map.points[p].position = w.inverse() * map.points[p].position;
            }
            map.update_normal_and_depth(p, scales);
        }
        report.global_ba_iterations = job.iterations;
        report.global_ba_keyframes = job.pose_ids.len();
        report.global_ba_points = job.point_ids.len();
        report.global_ba_ms = solve_ms;
        moved
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::tests::{keyframe, keyframe_with_aligned_keypoints};

    /// Keyframes 0–5, each with 20 keypoints; 20 points seen by keyframes 1–5 (keypoint i is point i), and
    /// keyframe 0 seeing the first `seen_by_0` of them.
    fn covisible_map(seen_by_0: usize) -> Map {
        let scales = Scales::new(1.2, 8, 0);
        let mut map =
            Map { keyframes: (0..6).map(|k| keyframe_with_aligned_keypoints(k, 20)).collect(), ..Default::default() };
        for i in 0..20 {
            let p = map.new_point(Point3::new(0.0, 0.0, 60.0), 1, i, &scales);
            for k in (2..6).chain((i < seen_by_0).then_some(0)) {
                map.add_observation(p, k, i);
            }
        }
        map
    }

    /// Where only keyframe 0 (always fixed) anchors a window of covisible keyframes and it sees a point of
    /// twenty, the least covisible keyframes are held fixed too until the fixed side carries a fifth of the
    /// observations; the new keyframe and the most covisible stay free. A firm anchor changes nothing.
    #[test]
    fn a_window_held_by_a_weak_anchor_holds_its_least_covisible_keyframes_fixed() {
        let map = covisible_map(1);
        // The new keyframe, then its covisibles by decreasing weight (keyframe 0 last: it shares one point).
        let mut local = vec![5, 4, 3, 2, 1, 0];
        hold_enough_fixed(&map, &mut local);
        // 101 observations: keyframe 0 carries 1, with keyframe 1 the fixed side carries 21 ≥ 20.2.
        assert_eq!(local, vec![5, 4, 3, 2]);

        // Keyframes 0 and 1 outside the window, seeing every point: 40 of 120.
        let mut local = vec![5, 4, 3, 2];
        hold_enough_fixed(&covisible_map(20), &mut local);
        assert_eq!(local, vec![5, 4, 3, 2], "the fixed keyframes carry a third: anchor enough");

        // However weak the anchor, the new keyframe stays free: with every other keyframe of the window fixed
        // it is alone, and the loop stops there.
        let mut pair = vec![5, 1];
        let mut just_two = covisible_map(0);
        for k in [2, 3, 4] {
            just_two.keyframes[k].bad = true;
        }
        hold_enough_fixed(&just_two, &mut pair);
        assert_eq!(pair, vec![5]);
    }

    /// The report says how far the adjustment moved the keyframe it was made for, over that keyframe's median
    /// depth (units-free), and nothing when the keyframe has no depth to compare with.
    #[test]
    fn the_report_gives_the_keyframe_s_move_relative_to_its_depth() {
        let cam = RectifiedCamera { fx: 260.0, fy: 260.0, cx: 159.5, cy: 119.5, bf: 1300.0, width: 320, height: 240 };
        let scales = Scales::new(1.2, 8, 0);
        for (depth, expected) in [(50.0, Some(2.5 / 50.0)), (f64::NAN, None)] {
            let mut made_for = keyframe(1, Some(0), false);
            made_for.median_depth = depth;
            let mut map = Map { keyframes: vec![keyframe(0, None, false), made_for], ..Default::default() };
            let mut job = snapshot_local_ba(&map, 1, &cam, &scales);
            let at = job.pose_ids.iter().position(|&k| k == 1).unwrap_or_else(|| panic!("keyframe 1 not in the job"));
            // Its centre 2 mm along the view and 1.5 mm sideways: 2.5 mm.
            job.problem.poses[at] = nalgebra::Isometry3::translation(-1.5, 0.0, -2.0);
            let mut report = MapperReport::default();
            apply_local_ba(&mut map, &job, &scales, &mut report);
            assert_eq!(map.keyframes[1].camera_from_world, job.problem.poses[at]);
            match (report.ba_moved_rel, expected) {
                (Some(got), Some(want)) => assert!((got - want).abs() < 1e-12, "reported {got}, expected {want}"),
                (None, None) => {}
                (got, want) => panic!("depth {depth}: reported {got:?}, expected {want:?}"),
            }
        }
    }
}
