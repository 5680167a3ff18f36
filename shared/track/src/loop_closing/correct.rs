//! The map's side of a loop (§8.3–§8.5): the verified match extended by projection and checked by a pose
//! optimisation, the current neighbourhood moved onto the old map, duplicated points fused, the essential graph
//! cut out for the worker, and the solved graph written back.

use super::pose_graph::{GraphEdge, GraphReport, PoseGraph};
use super::{PlaceMatch, PoseSnapshot};
use crate::frame::Scales;
use crate::geometry::{CameraFromWorld, RectifiedCamera};
use crate::map::{KfId, Map, PointId};
use crate::optim::{Observation, PoseOptimizer};
use crate::search::{TH_LOW, fuse_point};
use bdis_orb::hamming;
use nalgebra::Isometry3;
use std::collections::{BTreeMap, BTreeSet};

/// Matches of the loop keyframe's neighbourhood's points in the current keyframe, after the pose check, for a
/// loop to be accepted (ORB-SLAM2's 40, §8.2).
pub const MIN_LOOP_MATCHES_AFTER_PROJECTION: usize = 40;
/// Search radius of the guided matching, pixels at the octave's scale (ORB-SLAM2's 10 for the loop, §8.2).
pub const LOOP_SEARCH_RADIUS_PX: f64 = 10.0;
/// χ² of 6 degrees of freedom at 95 %: a loop correction below it is within the pose's noise.
pub const CHI2_6DOF_95: f64 = 12.592;
/// Covisibility weight of the essential graph's extra edges (ORB-SLAM2's 100, §8.4).
const ESSENTIAL_MIN_WEIGHT: u32 = 100;

/// A pose graph cut out of the map, with which keyframe each node is and its pose when cut.
#[derive(Debug)]
pub struct GraphJob {
    pub graph: PoseGraph,
    pub nodes: Vec<KfId>,
    pub initial: Vec<CameraFromWorld>,
    pub report: GraphReport,
}

/// A loop closed in the map, its pose graph still to solve.
#[derive(Debug)]
pub struct ClosedLoop {
    /// The pose graph to solve; `None` when the drift was within the noise (the sides were fused, nothing
    /// moved).
    pub graph: Option<GraphJob>,
    /// The correction's χ² against the pose's uncertainty (6 DoF).
    pub drift_chi2: f64,
    /// Points fused (duplicates merged, or observations added).
    pub fused: usize,
    /// Keyframes moved onto the old map.
    pub moved: Vec<KfId>,
}

/// Steps §8.2 (end) to §8.4 for query keyframe `kf` and its verified match. `None` when the loop does not hold
/// up against the map (then nothing has changed).
///
/// `seam`: the first keyframe of the detached map segment `kf` is on, when the candidate is older than it (the
/// loop ties the segment back). The whole segment then moves rigidly onto the old map and no pose graph is
/// solved: the segment was placed by dead reckoning, so the link across its seam is a guess, not a measurement,
/// and a graph would spread the guess's error over both maps. The global adjustment that follows weighs the
/// fused observations.
pub fn close_loop(
    map: &mut Map,
    cam: &RectifiedCamera,
    scales: &Scales,
    kf: KfId,
    found: &PlaceMatch,
    seam: Option<KfId>,
) -> Option<ClosedLoop> {
    let candidate = found.candidate;
    if map.keyframes[kf].bad || map.keyframes[candidate].bad {
        return None;
    }
    let guess = found.query_from_candidate * map.keyframes[candidate].camera_from_world;
    // The loop's side: the candidate and every keyframe connected to it, with their points.
    let mut loop_kfs: BTreeSet<KfId> = map.keyframes[candidate].connections.keys().copied().collect();
    loop_kfs.insert(candidate);
    // A tied-in query is already linked to the candidate's neighbours, and they to it: its own side stays its.
    loop_kfs.retain(|&k| !map.keyframes[k].bad && k < kf && !found.tied_side.contains(&k));
    // The current side: the query, its connections and every keyframe made since (they were tracked in the
    // drifted frame too); what is on both sides is already tied and stays where it is.
    let mut group: BTreeSet<KfId> = map.keyframes[kf].connections.keys().copied().collect();
    group.insert(kf);
    group.extend(seam.unwrap_or(kf).min(kf)..map.keyframes.len());
    group.retain(|&k| !map.keyframes[k].bad && !loop_kfs.contains(&k));
    if !group.contains(&kf) {
        return None;
    }
    let loop_points: Vec<PointId> = {
        let mut s = BTreeSet::new();
        for &k in &loop_kfs {
            s.extend(map.keyframes[k].points.iter().flatten().copied().filter(|&p| !map.points[p].bad));
        }
        s.into_iter().collect()
    };
    // Matches: the verified keypoint pairs' points, then the loop points found by projection at the guess.
    let mut matched: BTreeMap<usize, PointId> = BTreeMap::new();
    for &(i, j) in &found.pairs {
        if let Some(p) = map.keyframes[candidate].points[j].and_then(|p| map.resolve(p)) {
            matched.insert(i, p);
        }
    }
    let taken: BTreeSet<PointId> = matched.values().copied().collect();
    search_by_projection(map, cam, scales, kf, &guess, &loop_points, &taken, &mut matched);
    // The pose check: the query's pose against the old points alone.
    let k = &map.keyframes[kf];
    let pairs: Vec<(usize, PointId)> = matched.into_iter().collect();
    let points: Vec<nalgebra::Point3<f64>> = pairs.iter().map(|&(_, p)| map.points[p].position).collect();
    let observations: Vec<Observation> =
        pairs.iter().map(|&(i, _)| k.observation(i, scales.inv_sigma2[usize::from(k.keypoints[i].octave)])).collect();
    let mut outlier = vec![false; pairs.len()];
    let mut corrected = guess;
    let mut optimiser = PoseOptimizer::without_influence_check();
    let inliers = optimiser.optimize(cam, &mut corrected, &points, &observations, &mut outlier);
    if inliers < MIN_LOOP_MATCHES_AFTER_PROJECTION {
        return None;
    }
    // Is the drift real? The correction (a twist, ω then υ, as the optimiser perturbs) against the pose's
    // uncertainty from the old points: below the 95 % χ² of 6 DoF it is measurement noise, and spreading it
    // over the map would add error, not remove it. The two sides are still fused (the same points, tied as map
    // reuse would), without moving anything, and the global adjustment after the loop weighs both.
    // Tied in by map reuse, the query's pose is a compromise of both sides: the drift is then between the
    // pose its own side's points give and the old side's, each with its own uncertainty.
    let (own_pose, information) = if found.tied_side.is_empty() {
        (map.keyframes[kf].camera_from_world, *optimiser.information())
    } else {
        let own_side = own_side_pose(map, cam, scales, kf, &loop_kfs);
        let combined = own_side.and_then(|(pose, own_information)| {
            let sum = optimiser.information().try_inverse()? + own_information.try_inverse()?;
            Some((pose, sum.try_inverse()?))
        });
        combined.unwrap_or((map.keyframes[kf].camera_from_world, *optimiser.information()))
    };
    let twist = super::log_se3(&(corrected * own_pose.inverse()));
    let drift_chi2 = (twist.transpose() * information * twist)[(0, 0)];
    let significant = drift_chi2 > CHI2_6DOF_95;
    let corrected = if significant { corrected } else { map.keyframes[kf].camera_from_world };
    // Every keyframe's pose before the correction: the odometry's relative poses the graph must keep.
    let before: PoseSnapshot = map.good_keyframes().map(|k| (k.id, k.camera_from_world)).collect();
    // Move the current side rigidly: T ← T · W with W = T_kf⁻¹ · T_kf,corrected (so kf lands on its corrected
    // pose and the side keeps its shape); its points move with it.
    let w = map.keyframes[kf].camera_from_world.inverse() * corrected;
    let w_inv = w.inverse();
    for &g in &group {
        map.keyframes[g].camera_from_world = renormalised(map.keyframes[g].camera_from_world * w);
    }
    for p in 0..map.points.len() {
        let point = &map.points[p];
        if !point.bad && group.contains(&point.ref_kf) && !point.observations.keys().any(|o| loop_kfs.contains(o)) {
            map.points[p].position = w_inv * map.points[p].position;
        }
    }
    // Fusion: the query's verified matches first (the old point survives), then the loop points projected into
    // every keyframe of the current side.
    for (&(i, p), out) in pairs.iter().zip(&outlier) {
        if *out || map.points[p].bad {
            continue;
        }
        match map.keyframes[kf].points[i] {
            Some(q) if q != p && !map.points[q].bad => map.replace_point(q, p),
            Some(q) if q == p => {}
            _ => {
                if !map.points[p].observations.contains_key(&kf) {
                    map.add_observation(p, kf, i);
                }
            }
        }
    }
    let connected_before: BTreeMap<KfId, BTreeSet<KfId>> =
        group.iter().map(|&g| (g, map.keyframes[g].connections.keys().copied().collect())).collect();
    let mut fused = 0;
    for &g in &group {
        for &p in &loop_points {
            if let Some(p) = map.resolve(p) {
                fused += usize::from(fuse_point(map, cam, scales, g, p));
            }
        }
    }
    for &g in group.iter().chain(loop_kfs.iter()) {
        if !map.keyframes[g].bad {
            map.update_connections(g);
        }
    }
    for p in 0..map.points.len() {
        if !map.points[p].bad && group.contains(&map.points[p].ref_kf) {
            map.update_normal_and_depth(p, scales);
        }
    }
    // The loop's edges: links the fusion made from the current side to keyframes it was not linked to.
    let mut loop_edges: BTreeSet<(KfId, KfId)> = BTreeSet::new();
    for &g in &group {
        for &other in map.keyframes[g].connections.keys() {
            if !group.contains(&other) && !connected_before[&g].contains(&other) {
                loop_edges.insert((g.min(other), g.max(other)));
            }
        }
    }
    loop_edges.insert((candidate.min(kf), candidate.max(kf)));
    if !significant {
        return Some(ClosedLoop { graph: None, fused, moved: Vec::new(), drift_chi2 });
    }
    if seam.is_some() {
        return Some(ClosedLoop { graph: None, fused, moved: group.into_iter().collect(), drift_chi2 });
    }
    Some(ClosedLoop {
        graph: Some(essential_graph(map, &before, &loop_edges)),
        fused,
        moved: group.into_iter().collect(),
        drift_chi2,
    })
}

/// The pose of keyframe `kf` from its own side's points alone (those no keyframe of `loop_kfs` observes), and
/// its information; `None` when too few of them hold.
fn own_side_pose(
    map: &Map,
    cam: &RectifiedCamera,
    scales: &Scales,
    kf: KfId,
    loop_kfs: &BTreeSet<KfId>,
) -> Option<(CameraFromWorld, nalgebra::Matrix6<f64>)> {
    let k = &map.keyframes[kf];
    let mut points = Vec::new();
    let mut observations = Vec::new();
    for (i, p) in k.points.iter().enumerate() {
        let Some(p) = *p else { continue };
        let point = &map.points[p];
        if point.bad || point.observations.keys().any(|o| loop_kfs.contains(o)) {
            continue;
        }
        points.push(point.position);
        observations.push(k.observation(i, scales.inv_sigma2[usize::from(k.keypoints[i].octave)]));
    }
    let mut outlier = vec![false; points.len()];
    let mut pose = k.camera_from_world;
    let mut optimiser = PoseOptimizer::without_influence_check();
    let inliers = optimiser.optimize(cam, &mut pose, &points, &observations, &mut outlier);
    (inliers >= MIN_LOOP_MATCHES_AFTER_PROJECTION).then(|| (pose, *optimiser.information()))
}

/// The essential graph (§8.4): every good keyframe; edges of the spanning tree and of strong covisibility with
/// the odometry's relative poses (before the correction), the loop's edges with the corrected ones. Keyframe 0
/// (or the oldest good one) is held.
fn essential_graph(map: &Map, before: &PoseSnapshot, loop_edges: &BTreeSet<(KfId, KfId)>) -> GraphJob {
    let nodes: Vec<KfId> = map.good_keyframes().map(|k| k.id).collect();
    let index: BTreeMap<KfId, usize> = nodes.iter().enumerate().map(|(i, &k)| (k, i)).collect();
    let initial: Vec<CameraFromWorld> = nodes.iter().map(|&k| map.keyframes[k].camera_from_world).collect();
    let mut edges = Vec::new();
    let mut seen: BTreeSet<(KfId, KfId)> = BTreeSet::new();
    let odometry = |a: KfId, b: KfId| -> Option<Isometry3<f64>> {
        let (ta, tb) = (before.get(&a)?, before.get(&b)?);
        Some(tb * ta.inverse())
    };
    for &(a, b) in loop_edges {
        let (Some(&i), Some(&j)) = (index.get(&a), index.get(&b)) else { continue };
        if seen.insert((a, b)) {
            edges.push(GraphEdge { i, j, j_from_i: initial[j] * initial[i].inverse() });
        }
    }
    for &k in &nodes {
        let kf = &map.keyframes[k];
        let mut linked: Vec<KfId> = kf.parent.into_iter().collect();
        linked.extend(kf.connections.iter().filter(|(_, w)| **w >= ESSENTIAL_MIN_WEIGHT).map(|(n, _)| *n));
        for n in linked {
            let key = (k.min(n), k.max(n));
            let (Some(&i), Some(&j)) = (index.get(&key.0), index.get(&key.1)) else { continue };
            if seen.contains(&key) {
                continue;
            }
            let Some(j_from_i) = odometry(key.0, key.1) else { continue };
            seen.insert(key);
            edges.push(GraphEdge { i, j, j_from_i });
        }
    }
    let mut depths: Vec<f64> = nodes.iter().map(|&k| map.keyframes[k].median_depth).filter(|d| d.is_finite()).collect();
    depths.sort_by(f64::total_cmp);
    let depth_scale = depths.get(depths.len() / 2).copied().unwrap_or(1.0);
    let fixed = nodes.iter().enumerate().map(|(i, _)| i == 0).collect();
    GraphJob {
        graph: PoseGraph { poses: initial.clone(), fixed, edges, depth_scale },
        nodes,
        initial,
        report: GraphReport::default(),
    }
}

/// §8.5: writes a solved graph back as corrections of the poses it was cut with — what local bundle adjustment
/// changed since stays, moved along. A keyframe made since the cut moves with its nearest ancestor that was cut,
/// and a point with its reference keyframe.
/// Returns the keyframes moved.
pub fn apply_graph(map: &mut Map, job: &GraphJob, scales: &Scales) -> Vec<KfId> {
    let mut correction: BTreeMap<KfId, Isometry3<f64>> = BTreeMap::new();
    for (n, &k) in job.nodes.iter().enumerate() {
        correction.insert(k, job.initial[n].inverse() * job.graph.poses[n]);
    }
    let of_keyframe = corrections_by_ancestry(map, &correction);
    let mut moved = Vec::new();
    for (k, w) in of_keyframe.iter().enumerate() {
        if !map.keyframes[k].bad {
            map.keyframes[k].camera_from_world = renormalised(map.keyframes[k].camera_from_world * w);
            moved.push(k);
        }
    }
    for p in 0..map.points.len() {
        if map.points[p].bad {
            continue;
        }
        let w = of_keyframe[map.points[p].ref_kf];
        map.points[p].position = w.inverse() * map.points[p].position;
        map.update_normal_and_depth(p, scales);
    }
    moved
}

/// Per keyframe of the map, the correction (applied as `camera_from_world · w`) it takes: its own when it has
/// one, else its nearest ancestor's that has (a keyframe made after the cut), else the newest keyframe's.
pub fn corrections_by_ancestry(map: &Map, correction: &BTreeMap<KfId, Isometry3<f64>>) -> Vec<Isometry3<f64>> {
    let newest = correction.last_key_value().map_or_else(Isometry3::identity, |(_, w)| *w);
    let mut of_keyframe: Vec<Isometry3<f64>> = Vec::with_capacity(map.keyframes.len());
    for k in 0..map.keyframes.len() {
        let w = correction.get(&k).copied().unwrap_or_else(|| {
            let mut ancestor = map.keyframes[k].parent;
            for _ in 0..map.keyframes.len() {
                match ancestor {
                    Some(a) if correction.contains_key(&a) => return correction[&a],
                    Some(a) if a < k => return of_keyframe[a],
                    Some(a) => ancestor = map.keyframes[a].parent,
                    None => break,
                }
            }
            newest
        });
        of_keyframe.push(w);
    }
    of_keyframe
}

/// A rotation renormalised after products of corrections (rounding would otherwise accumulate).
pub fn renormalised(mut t: Isometry3<f64>) -> Isometry3<f64> {
    t.rotation = nalgebra::UnitQuaternion::new_normalize(t.rotation.into_inner());
    t
}

/// The loop points that project into keyframe `kf` at `pose`, each matched to the nearest-in-descriptor free
/// keypoint within the radius at its predicted octave (≤ `TH_LOW`).
#[allow(clippy::too_many_arguments)]
fn search_by_projection(
    map: &Map,
    cam: &RectifiedCamera,
    scales: &Scales,
    kf: KfId,
    pose: &CameraFromWorld,
    points: &[PointId],
    taken: &BTreeSet<PointId>,
    matched: &mut BTreeMap<usize, PointId>,
) {
    let k = &map.keyframes[kf];
    let mut found = Vec::new();
    let mut best_for_keypoint: BTreeMap<usize, (u32, PointId)> = BTreeMap::new();
    for &p in points {
        if taken.contains(&p) {
            continue;
        }
        let point = &map.points[p];
        let Some(seen) = map.projection_from(cam, p, pose) else { continue };
        let (u, v) = (seen.u, seen.v);
        let level = scales.predict_level(seen.distance, point.max_dist);
        let r = LOOP_SEARCH_RADIUS_PX * scales.scale[level];
        found.clear();
        k.grid.features_in_area(
            &k.keypoints,
            (u as f32, v as f32),
            r as f32,
            level.saturating_sub(1) as u8..=level as u8,
            &mut found,
        );
        let mut best = (u32::MAX, usize::MAX);
        for &j in &found {
            if matched.contains_key(&j) {
                continue;
            }
            let h = hamming(&point.descriptor, &k.descriptors[j]);
            if h < best.0 {
                best = (h, j);
            }
        }
        if best.0 <= TH_LOW {
            let entry = best_for_keypoint.entry(best.1).or_insert((u32::MAX, p));
            if best.0 < entry.0 {
                *entry = (best.0, p);
            }
        }
    }
    for (j, (_, p)) in best_for_keypoint {
        matched.insert(j, p);
    }
}
