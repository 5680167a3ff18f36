//! Loop closing (ORB-SLAM2-STEREO.md §8): when the scope comes back to tissue mapped long ago, the old keyframe
//! is found by the tracked pose and recognised by appearance, the match is checked in 3-D, the current
//! neighbourhood is moved onto the old map and its duplicated points fused, and a pose graph spreads the
//! correction over the keyframes in between.
//!
//! Threads: recognition, verification and the pose-graph solve run on a worker thread (`loop-closing`) from
//! copies; the map's owner sends one job per keyframe and takes its result at the next keyframe (waiting if
//! it is not done), so every run applies the same corrections at the same keyframes: runs are deterministic.
//! The steps that read and write the map (guided matching, moving the neighbourhood, fusion, building the
//! graph, applying the solve) run on the owner's thread at that keyframe boundary; they are cheap next to the
//! search and the solve.
//!
//! What counts as a loop: an old keyframe the new one looks at again ([`revisited`], by its tracked pose; why
//! not an appearance search over the map: see `place`) that was outside the covisibility neighbourhood of
//! [`LOOP_HORIZON_HOPS`] hops of the keyframe made before it. Inside that, local tracking and bundle adjustment
//! already tied the two together; outside, only a long chain of keyframes did, and its drift is what the loop
//! removes.
//!
//! Map reuse (tracking) ties a revisit in as soon as the view overlaps the old keyframes, loop closing on or
//! off: holding it back until the loop is verified starved the tracker of the points in view, and it drifted
//! fastest exactly there (640×480 circle, start 11: from 0.2 to 0.7 mm off between the first overlap and the loop,
//! 65 frames later; BENCHMARKS.md).
//! So the loop is usually recognised by what tracking already matched: when the new keyframe observes enough
//! of a candidate's points ([`tied_in`]), that is the geometric check; otherwise the candidate goes through
//! the 3-D check of `place`. The candidates of a revisit stay candidates for the keyframes after it while
//! they are still looked at, though map reuse has linked them in by then ([`LoopCloser`]'s revisit side).
//!
//! After a loop, a global bundle adjustment (§8.5) re-solves every keyframe and point from both passes'
//! observations on a thread of its own, applied a fixed number of keyframes later (`mapper`).
//!
//! A detached map segment (the tracker lost in tissue it did not know, `tracker::segment`) is placed by dead
//! reckoning, possibly far from where the scope is, so the places its pose names may not be the ones it sees.
//! While it is detached, each of its keyframes is also checked against the older map's keyframes most like it
//! by appearance (the seam scan: [`PlaceStore::votes`], then the 3-D check), and a place the scan finds ties
//! the segment back once the next keyframe puts it in the same place ([`SEAM_CONFIRMATIONS`]). A loop across
//! the seam moves the whole segment rigidly onto the older map, with no pose graph: the link across the seam
//! is a guess, not a measurement.

mod correct;
pub mod place;
pub mod pose_graph;

pub use correct::{
    ClosedLoop, GraphJob, LOOP_SEARCH_RADIUS_PX, apply_graph, close_loop, corrections_by_ancestry, renormalised,
};
pub use place::{PlaceEntry, PlaceMatch, PlaceStore};
pub use pose_graph::{GraphEdge, GraphReport, PoseGraph, log_se3};

use crate::frame::Scales;
use crate::geometry::RectifiedCamera;
use crate::map::{KfId, Map};
use std::collections::{BTreeMap, BTreeSet};

/// Covisibility hops (over the strong links) within which a keyframe is the current one's neighbourhood, not a
/// loop: two hops is ORB-SLAM2's local map (the keyframes sharing points, and their best covisibles).
pub const LOOP_HORIZON_HOPS: usize = 2;
/// Candidates checked per keyframe, nearest first (relocalisation's 5).
pub const MAX_CANDIDATES: usize = 5;
/// Keyframes in the map before loops are looked for, and between two loops (ORB-SLAM2's 10, §8.1).
pub const MIN_KEYFRAMES_BETWEEN_LOOPS: usize = 10;
/// Levenberg–Marquardt iterations of the pose graph (ORB-SLAM2's 20, §8.4).
pub const POSE_GRAPH_ITERATIONS: usize = 20;
/// Keyframes of the older map each keyframe of a detached segment is checked against in 3-D (beside those its
/// guessed pose names): the ones most like it by [`PlaceStore::votes`], as many as relocalisation scans per lost
/// frame. Each check costs a descriptor matching of two keyframes (≈ 1 ms at 1000 features), on the loop worker.
pub const SEAM_SCAN_PER_KEYFRAME: usize = 6;
/// Keypoints of the query the votes are counted over: enough to tell a place seen again (a fifth to a third of
/// them match) from tissue merely alike (one in twenty) by several standard deviations of a binomial count, at a
/// tenth of a full matching's cost per keyframe of the older map.
pub const SEAM_VOTE_SAMPLE: usize = 100;
/// Consecutive keyframes of a segment whose places found by the scan must agree before the segment is tied
/// back. Each place has passed the 3-D check already; the second keyframe, seen from elsewhere, must put the
/// segment in the same place in the older map, which tissue that merely looks alike does not do twice. (ORB-SLAM2
/// asks 3 consecutive keyframes of its appearance candidates, §8.1, but before any geometric check.)
pub const SEAM_CONFIRMATIONS: usize = 2;
/// How closely two such places must agree on where the segment lies in the older map: the query's camera
/// placed by each within this share of its median depth, and turned by no more than this many radians (the
/// angle that moves the view by that share).
pub const SEAM_AGREEMENT: f64 = 0.1;

/// The keyframes within `hops` strong-covisibility links of `kf` (itself included), good ones only.
pub fn neighbourhood(map: &Map, kf: KfId, hops: usize) -> BTreeSet<KfId> {
    let mut near = BTreeSet::from([kf]);
    let mut frontier = vec![kf];
    for _ in 0..hops {
        let mut next = Vec::new();
        for k in frontier {
            for (n, _) in &map.keyframes[k].ordered {
                if !map.keyframes[*n].bad && near.insert(*n) {
                    next.push(*n);
                }
            }
        }
        frontier = next;
    }
    near
}

/// Old keyframe `candidate` as a verified place when keyframe `kf` already observes at least
/// [`place::MIN_LOOP_INLIERS`] of its points: map reuse matched them while tracking and the pose optimisation
/// kept them as inliers, the check the 3-D RANSAC would make. `side` is the neighbourhood `kf` was tracked in.
pub fn tied_in(map: &Map, kf: KfId, candidate: KfId, side: &BTreeSet<KfId>) -> Option<PlaceMatch> {
    let k = &map.keyframes[kf];
    let c = &map.keyframes[candidate];
    if k.bad || c.bad {
        return None;
    }
    let pairs: Vec<(usize, usize)> = k
        .points
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let point = &map.points[(*p)?];
            if point.bad {
                return None;
            }
            point.observations.get(&candidate).map(|&j| (i, j))
        })
        .collect();
    (pairs.len() >= place::MIN_LOOP_INLIERS).then(|| PlaceMatch {
        candidate,
        query_from_candidate: k.camera_from_world * c.camera_from_world.inverse(),
        pairs,
        tied_side: side.iter().copied().collect(),
    })
}

/// The old keyframes keyframe `kf` looks at again, beyond its neighbourhood `near`, nearest first (at most
/// [`MAX_CANDIDATES`]): the map-reuse test (the point an old keyframe looks at projects into this one, and its
/// centre is within its median depth of this one's: ratios of the scene's depth, no unit).
pub fn revisited(map: &Map, cam: &RectifiedCamera, kf: KfId, near: &BTreeSet<KfId>) -> Vec<KfId> {
    let k = &map.keyframes[kf];
    let centre = k.centre();
    let mut found: Vec<(f64, KfId)> = map
        .good_keyframes()
        .filter(|o| !near.contains(&o.id) && o.id != kf && o.median_depth.is_finite())
        .filter_map(|o| {
            let closeness = (o.centre() - centre).norm() / o.median_depth;
            let seen = k.camera_from_world * o.look_at();
            let inside = seen.z > 0.0 && {
                let (u, v) = cam.project(&seen);
                cam.in_image(u, v)
            };
            (closeness <= 1.0 && inside).then_some((closeness, o.id))
        })
        .collect();
    found.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    found.into_iter().take(MAX_CANDIDATES).map(|(_, k)| k).collect()
}

/// One keyframe for the worker: its place entry, and what to exclude and compare with.
#[derive(Debug, Clone)]
pub struct LoopQuery {
    pub kf: KfId,
    pub entry: PlaceEntry,
    /// The old keyframes it looks at again ([`revisited`]): the loop candidates.
    pub candidates: Vec<KfId>,
    /// Keyframes culled since the last query (dropped from the index).
    pub culled: Vec<KfId>,
    /// Look for a loop (off while a correction is in progress and just after one).
    pub detect: bool,
    /// A candidate map reuse already tied the keyframe to ([`tied_in`]): the loop, without the 3-D check.
    pub tied: Option<PlaceMatch>,
    /// While the keyframe is on a detached segment, the seam scan when no candidate holds (a place found by it
    /// is only a hypothesis until [`SEAM_CONFIRMATIONS`] agree): the places of the hypothesis so far, checked
    /// first, and the older map's keyframes, ranked by appearance.
    pub scan_first: Vec<KfId>,
    pub scan: Vec<KfId>,
}

/// One job: a keyframe to recognise and index, and perhaps a pose graph to solve.
#[derive(Debug, Default)]
pub struct LoopJob {
    pub query: Option<LoopQuery>,
    pub graph: Option<GraphJob>,
}

/// What the worker gives back.
#[derive(Debug, Default)]
pub struct LoopOutcome {
    /// (query keyframe, verified match).
    pub found: Option<(KfId, PlaceMatch)>,
    /// The seam scan's place, when the query had a scan and no candidate held: (query keyframe, match or none).
    pub scanned: Option<(KfId, Option<PlaceMatch>)>,
    pub graph: Option<GraphJob>,
    pub detect_ms: f64,
    pub graph_ms: f64,
}

/// The worker's state: the keyframes' places.
#[derive(Debug)]
pub struct LoopDetector {
    cam: RectifiedCamera,
    scales: Scales,
    index: PlaceStore,
}

impl LoopDetector {
    pub fn new(cam: RectifiedCamera, scales: Scales) -> Self {
        Self { cam, scales, index: PlaceStore::new() }
    }

    /// The seam scan of a detached segment's keyframe: the hypothesis's places first, then the older map's
    /// keyframes most like the query ([`PlaceStore::votes`] over [`SEAM_VOTE_SAMPLE`] of its keypoints), the
    /// best [`SEAM_SCAN_PER_KEYFRAME`] of them checked in 3-D; the first that passes.
    fn scan(&mut self, query: &LoopQuery) -> Option<PlaceMatch> {
        let mut ranked: Vec<(usize, KfId)> = query
            .scan
            .iter()
            .filter(|k| !query.scan_first.contains(k) && !query.candidates.contains(k))
            .map(|&k| (self.index.votes(&query.entry, k, SEAM_VOTE_SAMPLE), k))
            .collect();
        // Most votes first; among equals the newer keyframe (ids are unique: a total order, so runs agree).
        ranked.sort_unstable_by(|a, b| b.cmp(a));
        let best = ranked.into_iter().take(SEAM_SCAN_PER_KEYFRAME).map(|(_, k)| k);
        let order: Vec<KfId> = query.scan_first.iter().copied().chain(best).collect();
        order.into_iter().find_map(|c| self.index.verify(&self.cam, &self.scales, &query.entry, c))
    }

    /// Runs a job: the query first (recognition before indexing, so a keyframe never finds itself), then the
    /// pose graph.
    pub fn run(&mut self, job: LoopJob) -> LoopOutcome {
        let mut outcome = LoopOutcome::default();
        if let Some(query) = job.query {
            let start = std::time::Instant::now();
            outcome.found = self.detect(&query).map(|m| (query.kf, m));
            if outcome.found.is_none() && query.detect && !(query.scan_first.is_empty() && query.scan.is_empty()) {
                outcome.scanned = Some((query.kf, self.scan(&query)));
            }
            self.insert(query);
            outcome.detect_ms = start.elapsed().as_secs_f64() * 1e3;
        }
        if let Some(mut graph) = job.graph {
            let start = std::time::Instant::now();
            graph.report = graph.graph.optimise(POSE_GRAPH_ITERATIONS);
            outcome.graph_ms = start.elapsed().as_secs_f64() * 1e3;
            outcome.graph = Some(graph);
        }
        outcome
    }

    fn insert(&mut self, query: LoopQuery) {
        for k in query.culled {
            self.index.remove(k);
        }
        self.index.insert(query.kf, query.entry);
    }

    /// §8.2: the candidates are checked geometrically, nearest first; the first that passes is the loop.
    ///
    /// No consistency window: ORB-SLAM2 checks a candidate only after its group was a candidate for 3 keyframes
    /// in a row (§8.1), because its candidates come from an appearance search, where an unrelated keyframe can
    /// score high once. Ours come from the tracked pose, which names a candidate only where the scope is; waiting
    /// only lets the tracker build a second map over the old one for a few more keyframes (640×480 circle: the
    /// loop 21–33 frames later, median ATE over 8 starts 0.097 mm against 0.087 mm checking at once). The 3-D
    /// check and the pose check still decide, and a place that only looks the same is never a candidate
    /// (`tests/false_loop.rs`).
    fn detect(&mut self, query: &LoopQuery) -> Option<PlaceMatch> {
        if !query.detect {
            return None;
        }
        if let Some(tied) = &query.tied {
            return Some(tied.clone());
        }
        // A candidate culled since (no longer in the index) is passed over by `verify`.
        query.candidates.iter().find_map(|&c| self.index.verify(&self.cam, &self.scales, &query.entry, c))
    }
}

/// The worker thread: runs jobs it receives, in order.
#[derive(Debug)]
struct LoopWorker {
    jobs: Option<std::sync::mpsc::Sender<LoopJob>>,
    results: std::sync::mpsc::Receiver<LoopOutcome>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl LoopWorker {
    fn spawn(mut detector: LoopDetector, on_start: Option<crate::workers::WorkerStart>) -> Option<Self> {
        let (job_tx, job_rx) = std::sync::mpsc::channel::<LoopJob>();
        let (result_tx, result_rx) = std::sync::mpsc::channel::<LoopOutcome>();
        let thread = std::thread::Builder::new()
            .name("loop-closing".into())
            .spawn(move || {
                if let Some(start) = on_start {
                    start();
                }
                for job in job_rx {
                    if result_tx.send(detector.run(job)).is_err() {
                        break;
                    }
                }
            })
            .ok()?;
        Some(Self { jobs: Some(job_tx), results: result_rx, thread: Some(thread) })
    }
}

impl Drop for LoopWorker {
    fn drop(&mut self) {
        self.jobs = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Where the loop-closing work runs, like local bundle adjustment's.
#[derive(Debug)]
enum Runner {
    Worker(LoopWorker),
    Inline(Box<LoopDetector>),
}

/// The map owner's side of loop closing: sends a job per keyframe, takes results at the next one.
#[derive(Debug)]
pub struct LoopCloser {
    runner: Option<Runner>,
    inline: bool,
    in_flight: bool,
    /// Inline mode's result, waiting to be taken at the next keyframe as the worker's would be.
    ready: Option<LoopOutcome>,
    /// Keyframes the last query's index had not yet dropped.
    culled_sent: BTreeSet<KfId>,
    /// The keyframe of the last loop closed, and whether its pose graph is being solved.
    last_loop_kf: Option<KfId>,
    graph_pending: bool,
    /// Loops closed so far: (query keyframe, candidate).
    pub loops: Vec<(KfId, KfId)>,
    worker_start: Option<crate::workers::WorkerStart>,
    /// The neighbourhood of the last keyframe sent, as it was then (before the next one's map reuse linked it
    /// to old keyframes): what the next keyframe was tracked among.
    previous_near: BTreeSet<KfId>,
    /// The old side of a revisit in progress: the first candidates' neighbourhoods, beyond the horizon when
    /// the revisit began. Its keyframes stay candidates while they are looked at.
    revisit_side: BTreeSet<KfId>,
    /// The detached segment's search for the older map, while it is not tied back.
    seam: Option<SeamSearch>,
}

/// A detached segment looking for the older map by appearance ([`SEAM_SCAN_PER_KEYFRAME`]): its guessed pose
/// can be far off, so the places it names ([`revisited`]) need not be where the scope is.
#[derive(Debug, Clone)]
struct SeamSearch {
    /// The segment's first keyframe: what a loop across the seam moves is the keyframes from it on.
    first: KfId,
    /// The older map is the keyframes before this one: the segment's first, or, when the segment began while an
    /// earlier one was still detached, that one's bound (a segment is never tied to another one's guess).
    older_than: KfId,
    hypothesis: Option<SeamHypothesis>,
}

/// Where a scan put the segment in the older map, and how many consecutive keyframes agreed.
#[derive(Debug, Clone)]
struct SeamHypothesis {
    /// The older map's world from the segment's (the correction that ties it back).
    older_from_segment: nalgebra::Isometry3<f64>,
    candidate: KfId,
    agreed: usize,
}

impl LoopCloser {
    pub fn new(inline: bool) -> Self {
        Self {
            runner: None,
            inline,
            in_flight: false,
            ready: None,
            culled_sent: BTreeSet::new(),
            last_loop_kf: None,
            graph_pending: false,
            loops: Vec::new(),
            worker_start: None,
            previous_near: BTreeSet::new(),
            revisit_side: BTreeSet::new(),
            seam: None,
        }
    }

    /// What the worker thread runs first (`workers::WorkerStart`); set before the first keyframe.
    pub fn set_worker_start(&mut self, start: Option<crate::workers::WorkerStart>) {
        self.worker_start = start;
    }

    fn submit(&mut self, job: LoopJob, cam: &RectifiedCamera, scales: &Scales) {
        if self.runner.is_none() {
            let detector = LoopDetector::new(*cam, scales.clone());
            self.runner = if self.inline {
                Some(Runner::Inline(Box::new(detector)))
            } else {
                LoopWorker::spawn(detector, self.worker_start).map(Runner::Worker)
            };
        }
        match &mut self.runner {
            Some(Runner::Worker(w)) => {
                if let Some(tx) = &w.jobs {
                    match tx.send(job) {
                        Ok(()) => self.in_flight = true,
                        // The worker is gone: this keyframe goes unindexed (it cannot panic on valid input).
                        Err(_) => self.runner = None,
                    }
                }
            }
            Some(Runner::Inline(d)) => self.ready = Some(d.run(job)),
            None => {}
        }
    }

    /// The result of the job sent at the previous keyframe (waiting for it).
    pub fn collect(&mut self) -> Option<LoopOutcome> {
        if let Some(r) = self.ready.take() {
            return Some(r);
        }
        if !self.in_flight {
            return None;
        }
        self.in_flight = false;
        match &self.runner {
            Some(Runner::Worker(w)) => w.results.recv().ok(),
            _ => None,
        }
    }

    /// Sends keyframe `kf` (after local mapping has linked it) and the pose graph of a loop just closed;
    /// `global_pending`: the global bundle adjustment after a loop is still running (no new loop until it is in).
    pub fn send_keyframe(
        &mut self,
        map: &Map,
        kf: KfId,
        cam: &RectifiedCamera,
        scales: &Scales,
        graph: Option<GraphJob>,
        global_pending: bool,
    ) {
        let k = &map.keyframes[kf];
        if k.bad {
            return;
        }
        let entry = PlaceEntry::of_keyframe(k, cam);
        let culled: Vec<KfId> =
            map.keyframes.iter().filter(|x| x.bad && !self.culled_sent.contains(&x.id)).map(|x| x.id).collect();
        self.culled_sent.extend(culled.iter().copied());
        self.graph_pending |= graph.is_some();
        let quiet = self.last_loop_kf.is_some_and(|l| kf < l + MIN_KEYFRAMES_BETWEEN_LOOPS);
        let detect =
            !self.graph_pending && !global_pending && !quiet && map.n_good_keyframes() > MIN_KEYFRAMES_BETWEEN_LOOPS;
        let mut near = std::mem::replace(&mut self.previous_near, neighbourhood(map, kf, LOOP_HORIZON_HOPS));
        near.insert(kf);
        let candidates = if detect { self.candidates(map, cam, kf, &near) } else { Vec::new() };
        let tied = candidates.iter().find_map(|&c| tied_in(map, kf, c, &near));
        let (scan_first, scan) =
            if detect && tied.is_none() { self.seam_scan(map, kf) } else { (Vec::new(), Vec::new()) };
        let query = LoopQuery { kf, entry, candidates, culled, detect, tied, scan_first, scan };
        self.submit(LoopJob { query: Some(query), graph }, cam, scales);
    }

    /// The loop candidates of keyframe `kf`, tracked among `near`: the old keyframes it looks at beyond `near`,
    /// and those of the revisit in progress it still looks at. Updates the revisit side.
    fn candidates(&mut self, map: &Map, cam: &RectifiedCamera, kf: KfId, near: &BTreeSet<KfId>) -> Vec<KfId> {
        let mut candidates = revisited(map, cam, kf, near);
        if !self.revisit_side.is_empty() {
            let elsewhere: BTreeSet<KfId> =
                map.good_keyframes().map(|k| k.id).filter(|k| !self.revisit_side.contains(k)).collect();
            for c in revisited(map, cam, kf, &elsewhere) {
                if !candidates.contains(&c) {
                    candidates.push(c);
                }
            }
        }
        if candidates.is_empty() {
            // The scope has left the old tissue: the revisit is over.
            self.revisit_side.clear();
        }
        for &c in &candidates {
            if !self.revisit_side.contains(&c) {
                let side = neighbourhood(map, c, LOOP_HORIZON_HOPS);
                self.revisit_side.extend(side.into_iter().filter(|k| !near.contains(k)));
            }
        }
        candidates
    }

    /// The tracker began a new map segment at keyframe `kf` (after a loss in unknown tissue): the segment's
    /// neighbourhood starts there, so the next keyframe does not take its own segment's first keyframe for a
    /// place revisited, while everything before the restart stays a candidate (a true revisit ties the segment
    /// back).
    pub fn segment_begun(&mut self, kf: KfId) {
        self.previous_near = BTreeSet::from([kf]);
        self.revisit_side.clear();
        let older_than = self.seam.as_ref().map_or(kf, |earlier| earlier.older_than);
        self.seam = Some(SeamSearch { first: kf, older_than, hypothesis: None });
    }

    /// The first keyframe of the detached segment keyframe `kf` is on, when `candidate` is older than it: a loop
    /// between them ties the segment back ([`close_loop`]'s `seam`).
    pub fn seam_between(&self, kf: KfId, candidate: KfId) -> Option<KfId> {
        self.seam.as_ref().filter(|s| candidate < s.older_than && kf >= s.first).map(|s| s.first)
    }

    /// The seam scan of keyframe `kf` on a detached segment ([`LoopQuery::scan`]): the hypothesis's place and
    /// its best covisibles, and every good keyframe of the older map. Empty off a segment.
    fn seam_scan(&self, map: &Map, kf: KfId) -> (Vec<KfId>, Vec<KfId>) {
        let Some(seam) = self.seam.as_ref().filter(|s| kf >= s.first) else { return (Vec::new(), Vec::new()) };
        let older: Vec<KfId> = map.good_keyframes().map(|k| k.id).filter(|&k| k < seam.older_than).collect();
        let first = seam.hypothesis.as_ref().map_or_else(Vec::new, |h| {
            let c = &map.keyframes[h.candidate];
            let mut around: Vec<(u32, KfId)> = c
                .ordered
                .iter()
                .filter(|&&(k, _)| k < seam.older_than && !map.keyframes[k].bad)
                .map(|&(k, w)| (w, k))
                .collect();
            around.sort_unstable_by(|a, b| b.cmp(a));
            let best = around.into_iter().take(MAX_CANDIDATES - 1).map(|(_, k)| k);
            std::iter::once(h.candidate).filter(|_| !c.bad).chain(best).collect()
        });
        (first, older)
    }

    /// A place the seam scan found for keyframe `kf` (or none): the loop to close once
    /// [`SEAM_CONFIRMATIONS`] consecutive keyframes have placed the segment alike ([`SEAM_AGREEMENT`]).
    pub fn seam_place(&mut self, map: &Map, kf: KfId, place: Option<PlaceMatch>) -> Option<PlaceMatch> {
        let seam = self.seam.as_mut()?;
        let Some(place) = place else {
            seam.hypothesis = None;
            return None;
        };
        let (query, candidate) = (&map.keyframes[kf], &map.keyframes[place.candidate]);
        if query.bad || candidate.bad {
            seam.hypothesis = None;
            return None;
        }
        // camera_from_world of the query as the place puts it, against its own (segment) pose.
        let placed = place.query_from_candidate * candidate.camera_from_world;
        let older_from_segment = placed.inverse() * query.camera_from_world;
        let agrees = seam.hypothesis.as_ref().is_some_and(|h| {
            let by_hypothesis = query.camera_from_world * h.older_from_segment.inverse();
            let apart = by_hypothesis * placed.inverse();
            let depth = if query.median_depth.is_finite() { query.median_depth } else { return false };
            apart.translation.vector.norm() <= SEAM_AGREEMENT * depth && apart.rotation.angle() <= SEAM_AGREEMENT
        });
        let agreed = if agrees { seam.hypothesis.as_ref().map_or(1, |h| h.agreed + 1) } else { 1 };
        seam.hypothesis = Some(SeamHypothesis { older_from_segment, candidate: place.candidate, agreed });
        (agreed >= SEAM_CONFIRMATIONS).then_some(place)
    }

    /// A loop was closed at keyframe `kf` against `candidate`.
    pub fn closed(&mut self, kf: KfId, candidate: KfId) {
        if self.seam_between(kf, candidate).is_some() {
            self.seam = None;
        }
        self.revisit_side.clear();
        self.last_loop_kf = Some(kf);
        self.loops.push((kf, candidate));
    }

    /// A pose graph came back (applied by the caller).
    pub fn graph_done(&mut self) {
        self.graph_pending = false;
    }
}

/// Keyframes with their poses before a correction, for the edges that must keep the odometry's relative poses.
pub type PoseSnapshot = BTreeMap<KfId, crate::geometry::CameraFromWorld>;
