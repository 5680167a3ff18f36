//! Local bundle adjustment (§6.5): the problem cut out of the map around the new keyframe, solved on the\n//! worker thread (or inline), and its result written back.
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

/// §6.5, step 1–2: local keyframes = `kf` and its ordered covisibles; fixed = other keyframes seeing local
/// points (and keyframe 0); every observation of a local point by a good keyframe is an edge.
pub(super) fn snapshot_local_ba(map: &Map, kf: KfId, cam: &RectifiedCamera, scales: &Scales) -> BaJob {
    let mut local: Vec<KfId> = vec![kf];
    local.extend(map.keyframes[kf].ordered.iter().map(|(k, _)| *k).filter(|&k| !map.keyframes[k].bad));
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
        problem.fixed.push(is_fixed || k == 0);
    }
    let point_ids: Vec<PointId> = points.into_iter().collect();
    let mut edge_keys: Vec<(PointId, KfId)> = Vec::new();
    for (pi, &p) in point_ids.iter().enumerate() {
        problem.points.push(map.points[p].position);
        for (&k, &idx) in &map.points[p].observations {
            let Some(&pose) = pose_index.get(&k) else { continue };
            let kp = &map.keyframes[k].keypoints[idx];
            let refined = map.keyframes[k].refined[idx];
            let obs = Observation {
                u: f64::from(kp.x),
                v: f64::from(kp.y),
                u_right: map.keyframes[k].is_stereo(idx).then(|| f64::from(map.keyframes[k].u_right[idx])),
                inv_sigma2: scales.information(kp.octave, refined, map.refined_sigma),
            };
            let octave_chi2_scale = if refined { map.refined_sigma * map.refined_sigma } else { 1.0 };
            problem.edges.push(BaEdge { pose, point: pi, obs, octave_chi2_scale });
            edge_keys.push((p, k));
        }
    }
    problem.excluded = vec![false; problem.edges.len()];
    BaJob { kf, problem, cam: *cam, pose_ids, point_ids, edge_keys, iterations: 0 }
}

/// §6.5 steps 3–4, on the snapshot alone (no map): 5 robust iterations, outliers excluded, 10 plain ones.
pub fn solve_local_ba(mut job: BaJob) -> BaJob {
    let cam = job.cam;
    let first = job.problem.solve(&cam, 5, true, &|| false);
    for k in 0..job.problem.edges.len() {
        let x2 = job.problem.edge_chi2(&cam, k);
        let e = &job.problem.edges[k];
        if x2.is_nan() || x2 > if e.obs.is_stereo() { CHI2_STEREO } else { CHI2_MONO } {
            job.problem.excluded[k] = true;
        }
    }
    let second = job.problem.solve(&cam, 10, false, &|| false);
    job.iterations = first.iterations + second.iterations;
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
