//! The pose-only optimisation (§5.5): one camera's pose against fixed world points, with its outliers, the
//! influence check, and the information that says how well the images pin the pose down.

use super::*;

/// Reusable buffers of the pose-only optimisation.
#[derive(Debug, Default)]
pub struct PoseOptimizer {
    chi2: Vec<f64>,
    /// The caller's starting classification, kept for the solve again without a measurement of too much influence.
    start_outlier: Vec<bool>,
    /// Edges left out for their influence ([`MAX_INFLUENCE`]).
    excluded: Vec<bool>,
    /// Σ JᵀΩJ over the inliers at the final pose of the last optimisation (twist order ω, υ).
    information: Matrix6<f64>,
    /// Whether [`Self::optimize`] leaves out a measurement of too much influence ([`Self::for_tracking`]).
    judge_influence: bool,
}

impl PoseOptimizer {
    /// The tracker's optimiser: room for `edges` edges, so that optimising a frame with more links than any
    /// before allocates nothing, and the influence check on. A frame's pose rests on hundreds of links of which
    /// a stereo mismatch can be one that the fit follows; that is what the check is for. Loop closing's pose
    /// checks ([`Self::without_influence_check`]) go without it: they weigh an old map against a drifted guess,
    /// where the few links that agree with the old map are the evidence, and leaving out the most telling of them
    /// kept a detached segment from being tied back (`tests/restart.rs`).
    pub fn for_tracking(edges: usize) -> Self {
        Self {
            chi2: Vec::with_capacity(edges),
            start_outlier: Vec::with_capacity(edges),
            excluded: Vec::with_capacity(edges),
            information: Matrix6::zeros(),
            judge_influence: true,
        }
    }

    /// An optimiser without the influence check, its buffers grown as needed: loop closing's pose checks (see
    /// [`Self::for_tracking`] for why they go without it). The same as [`Self::default`], said outright.
    pub fn without_influence_check() -> Self {
        Self { judge_influence: false, ..Self::default() }
    }

    /// The Gauss–Newton information of the last optimised pose over its inliers (twist ω, υ; υ is the camera
    /// centre's displacement in the camera frame, to first order). Its inverse is the pose's covariance in units
    /// of the measurements' σ: how well the images pin the pose down.
    pub fn information(&self) -> &Matrix6<f64> {
        &self.information
    }

    /// χ² of every edge of the last optimisation at its final pose (outliers included).
    pub fn chi2(&self) -> &[f64] {
        &self.chi2
    }

    /// Optimises `pose` against fixed world points (§5.5): 4 rounds of 10 LM iterations, each round from the
    /// initial pose, edges re-classified after each round (χ² > 5.991 / 7.815 → outlier, excluded next round,
    /// and they may come back), no robust kernel in round 4. `outlier` is read as the starting classification
    /// and written with the final one. Then, in the tracker's optimiser ([`Self::for_tracking`]) only, the one
    /// inlier of the greatest influence ([`MAX_INFLUENCE`]), if it is over the bound, is left out (marked an
    /// outlier) and the rounds run again from the initial pose, up to [`MAX_EXCLUDED`] times. Returns the number
    /// of inliers (0 with fewer than 3 edges, pose unchanged).
    pub fn optimize(
        &mut self,
        cam: &RectifiedCamera,
        pose: &mut CameraFromWorld,
        points: &[Point3<f64>],
        observations: &[Observation],
        outlier: &mut [bool],
    ) -> usize {
        let n = points.len();
        self.information = Matrix6::zeros();
        if n < 3 {
            return 0;
        }
        self.start_outlier.clear();
        self.start_outlier.extend_from_slice(outlier);
        self.excluded.clear();
        self.excluded.resize(n, false);
        let initial = *pose;
        for attempt in 0..=MAX_EXCLUDED {
            self.solve_rounds(cam, pose, initial, points, observations, outlier);
            // Influence needs redundancy to be judged: with few inliers every one of them moves the pose.
            if !self.judge_influence
                || attempt == MAX_EXCLUDED
                || outlier.iter().filter(|o| !**o).count() < MIN_JUDGED_INLIERS
            {
                break;
            }
            // One measurement that moves the pose far from where the others put it: its own residual is small,
            // since the fit follows it, but without it the pose would lie outside the ellipsoid it is fitted
            // within (Cook's distance). Solve again without it.
            let mut most = (0.0, usize::MAX);
            for (i, e, j) in inlier_terms(cam, pose, points, observations, outlier) {
                let w = observations[i].inv_sigma2;
                // The information of the others; where it leaves a direction undetermined, nothing checks the
                // measurement, and it stays.
                let Some(others) = (self.information - j.transpose() * j * w).cholesky() else { continue };
                let pull = j.transpose() * e * w;
                let influence = pull.dot(&others.solve(&pull));
                if influence > most.0 {
                    most = (influence, i);
                }
            }
            if most.0 <= MAX_INFLUENCE {
                break;
            }
            self.excluded[most.1] = true;
            for ((out, &start), &excluded) in outlier.iter_mut().zip(&self.start_outlier).zip(&self.excluded) {
                *out = start || excluded;
            }
            *pose = initial;
        }
        outlier.iter().filter(|o| !**o).count()
    }

    /// The four rounds of [`Self::optimize`] from `initial`, with the excluded edges kept out; leaves the pose in
    /// `pose` and its information in `self.information`.
    fn solve_rounds(
        &mut self,
        cam: &RectifiedCamera,
        pose: &mut CameraFromWorld,
        initial: CameraFromWorld,
        points: &[Point3<f64>],
        observations: &[Observation],
        outlier: &mut [bool],
    ) {
        let n = points.len();
        let mut best = initial;
        self.chi2.clear();
        self.chi2.resize(n, 0.0);
        for round in 0..4 {
            let robust = round < 3;
            let mut current = initial;
            let cost = |t: &CameraFromWorld, outlier: &[bool]| -> f64 {
                let mut c = 0.0;
                for i in 0..n {
                    if outlier[i] {
                        continue;
                    }
                    let x2 = chi2(cam, t, &points[i], &observations[i]);
                    let delta = if observations[i].is_stereo() { HUBER_STEREO_POSE } else { HUBER_MONO };
                    c += robust_cost(x2, delta, robust);
                }
                c
            };
            let mut damping = Damping::new();
            let mut current_cost = cost(&current, outlier);
            for _ in 0..10 {
                let (mut h, mut b) = (Matrix6::<f64>::zeros(), Vector6::<f64>::zeros());
                for (i, e, j) in inlier_terms(cam, &current, points, observations, outlier) {
                    let obs = &observations[i];
                    let x2 = e.norm_squared() * obs.inv_sigma2;
                    let delta = if obs.is_stereo() { HUBER_STEREO_POSE } else { HUBER_MONO };
                    let w = obs.inv_sigma2 * if robust { huber_weight(x2, delta) } else { 1.0 };
                    h += j.transpose() * j * w;
                    b += j.transpose() * e * w;
                }
                damping.start((0..6).map(|k| h[(k, k)]).fold(0.0, f64::max));
                let accepted = damping.step(current_cost, |add| {
                    let mut hd = h;
                    for k in 0..6 {
                        hd[(k, k)] += add(h[(k, k)]);
                    }
                    let step = hd.cholesky().map(|c| c.solve(&(-b)))?;
                    let candidate = update(&step, &current);
                    Some((cost(&candidate, outlier), candidate))
                });
                let Some((c, candidate)) = accepted else { break };
                current = candidate;
                current_cost = c;
            }
            // Classify every edge, excluded ones included.
            for i in 0..n {
                let x2 = chi2(cam, &current, &points[i], &observations[i]);
                self.chi2[i] = x2;
                // A NaN χ² (degenerate point) is an outlier too.
                outlier[i] = self.excluded[i] || x2.is_nan() || x2 > observations[i].chi2_threshold();
            }
            best = current;
        }
        *pose = best;
        self.information = Matrix6::zeros();
        for (i, _, j) in inlier_terms(cam, &best, points, observations, outlier) {
            self.information += j.transpose() * j * observations[i].inv_sigma2;
        }
    }
}

/// Each inlier in front of the camera at `pose`: its index, residual and Jacobian with respect to the pose's
/// twist.
fn inlier_terms<'a>(
    cam: &'a RectifiedCamera,
    pose: &'a CameraFromWorld,
    points: &'a [Point3<f64>],
    observations: &'a [Observation],
    outlier: &'a [bool],
) -> impl Iterator<Item = (usize, Vector3<f64>, Matrix3x6<f64>)> + 'a {
    (0..points.len()).filter(|&i| !outlier[i]).filter_map(move |i| {
        let pc = pose * points[i];
        (pc.z > 0.0).then(|| {
            let (e, jp) = residual_and_jacobian(cam, &pc, &observations[i]);
            (i, e, jp * point_jacobian_pose(&pc))
        })
    })
}
