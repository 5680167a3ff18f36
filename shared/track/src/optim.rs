//! Pose-only optimisation (ORB-SLAM2-STEREO.md §5.5) and local bundle adjustment (§6.5), written directly on
//! nalgebra: Levenberg–Marquardt on SE(3) with the left-multiplicative update T ← exp(ξ)·T, Huber kernels,
//! stereo residuals e = (u_L, v, u_R) − π_s(T·X) and monocular e = (u, v) − π(T·X), information σ⁻²·I.
//! Bundle adjustment marginalises the points with the Schur complement and solves the reduced camera system
//! densely (a local window holds tens of keyframes).

use crate::geometry::{CameraFromWorld, RectifiedCamera, skew, update};
use nalgebra::{DMatrix, DVector, Matrix3, Matrix3x6, Matrix6, Point3, SMatrix, Vector3, Vector6};

mod pose;
pub use pose::PoseOptimizer;

/// χ² thresholds (95 %) of 2 and 3 degrees of freedom: outlier classification.
pub const CHI2_MONO: f64 = 5.991;
pub const CHI2_STEREO: f64 = 7.815;
/// Huber widths of the pose-only optimisation: √5.991 (mono) and √7.815 (stereo, ORB-SLAM2's value; BDIS-SLAM
/// uses √0.7815, which down-weights every stereo edge beyond 0.9 px: ATE on the synthetic colon 0.59 → 0.39 mm
/// with ORB-SLAM2's).
pub const HUBER_MONO: f64 = 2.447_651_936_039_926;
pub const HUBER_STEREO_POSE: f64 = 2.795_532_111_925_299;
/// The largest influence one measurement may have on a pose (Cook's distance): how far the pose the other
/// measurements give lies from the pose fitted with it, in the other measurements' own information
/// (`Δᵀ H₍ᵢ₎ Δ`, `Δ = H₍ᵢ₎⁻¹ Jᵢᵀ Ωᵢ eᵢ`). A spurious stereo point a tenth of the scene's depth from the camera,
/// say, pins down a hover's weak direction (sideways and a turn) alone: the fit follows it a millimetre off and
/// its residual stays within the χ² gate, so the gate cannot see it, but the others put the pose far outside
/// the ellipsoid of the fit. A true point as near, which agrees with them, moves the pose little and stays.
/// The bound is χ²'s 95 % quantile with the pose's 6 degrees of freedom; in units of the measurements' σ, so
/// footage in metres or millimetres, at any image size, is judged alike.
pub const MAX_INFLUENCE: f64 = 12.59;

/// The fewest inliers among which one measurement's influence is judged: with fewer each of them moves the pose
/// (and the tracker, which needs 30 to hold a frame, is losing it anyway).
const MIN_JUDGED_INLIERS: usize = 20;

/// How many measurements one pose optimisation may leave out for their influence (each is a solve again).
const MAX_EXCLUDED: usize = 3;

/// Huber width of stereo edges in bundle adjustment: √7.815.
pub const HUBER_STEREO_BA: f64 = 2.795_532_111_925_299;

/// One measurement of a point in a camera: (u, v) and, for stereo keypoints, u_R; with σ⁻² of its octave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    pub u: f64,
    pub v: f64,
    pub u_right: Option<f64>,
    pub inv_sigma2: f64,
}

impl Observation {
    pub fn is_stereo(&self) -> bool {
        self.u_right.is_some()
    }

    fn chi2_threshold(&self) -> f64 {
        if self.is_stereo() { CHI2_STEREO } else { CHI2_MONO }
    }
}

/// Residual (3 rows; the third is 0 for monocular edges) and its Jacobian with respect to the camera-frame point.
fn residual_and_jacobian(cam: &RectifiedCamera, pc: &Point3<f64>, obs: &Observation) -> (Vector3<f64>, Matrix3<f64>) {
    let iz = 1.0 / pc.z;
    let iz2 = iz * iz;
    let u = cam.fx * pc.x * iz + cam.cx;
    let v = cam.fy * pc.y * iz + cam.cy;
    // ∂π/∂X_c; the residual is z − π, hence the minus signs.
    let mut j = Matrix3::new(
        -cam.fx * iz,
        0.0,
        cam.fx * pc.x * iz2,
        0.0,
        -cam.fy * iz,
        cam.fy * pc.y * iz2,
        -cam.fx * iz,
        0.0,
        (cam.fx * pc.x - cam.bf) * iz2,
    );
    let e = match obs.u_right {
        Some(ur) => Vector3::new(obs.u - u, obs.v - v, ur - (u - cam.bf * iz)),
        None => {
            j.row_mut(2).fill(0.0);
            Vector3::new(obs.u - u, obs.v - v, 0.0)
        }
    };
    (e, j)
}

/// χ² = eᵀΩe of a point (world frame) seen from `pose`; infinite behind the camera.
pub fn chi2(cam: &RectifiedCamera, pose: &CameraFromWorld, x_w: &Point3<f64>, obs: &Observation) -> f64 {
    let pc = pose * x_w;
    if pc.z <= 0.0 {
        return f64::INFINITY;
    }
    let (e, _) = residual_and_jacobian(cam, &pc, obs);
    e.norm_squared() * obs.inv_sigma2
}

/// Levenberg–Marquardt damping, one schedule for pose-only optimisation and bundle adjustment. Marquardt's
/// form: each diagonal entry grows by λ times itself (H + λ·diag H), so the damping is the same whatever the
/// units of the parameters. (λ·I mixes them: rotations are unit-free, translations are not. The same real clip
/// calibrated in millimetres had its translation steps damped 10⁶ times harder than in metres: a pose that had to
/// move 1.2 m from its start stopped 13 % short, and bundle adjustment hardly moved keyframes or points — ATE
/// 0.089 against 0.069 m. With this form both give 0.057 m. On our renders, in millimetres, that near-frozen
/// bundle adjustment had scored better on some sequences — the 640×480 colon revisit most; BENCHMARKS.md, issue
/// #16.) λ starts at 1e-5, grows ×10 on a rejected (or unsolvable) step and shrinks ÷3 (not below 1e-12) on an
/// accepted one; an iteration tries at most 10 λs. A diagonal entry below 1e-12 of the largest (a parameter the
/// data does not constrain) is damped as if it were that.
#[derive(Debug)]
struct Damping {
    lambda: f64,
    floor: f64,
}

impl Damping {
    fn new() -> Self {
        Self { lambda: 1e-5, floor: 0.0 }
    }

    /// Sets the floor of damped diagonal entries from this iteration's largest one.
    fn start(&mut self, max_diagonal: f64) {
        self.floor = 1e-12 * max_diagonal;
    }

    /// Tries `solve(add)` — a candidate and its cost, or `None` when the damped system cannot be solved — with
    /// growing λ until one lowers `current_cost`; `None` when none of 10 does (the optimisation has converged).
    /// `add(d)` is what a diagonal entry `d` grows by at the λ being tried.
    fn step<T>(
        &mut self,
        current_cost: f64,
        mut solve: impl FnMut(&dyn Fn(f64) -> f64) -> Option<(f64, T)>,
    ) -> Option<(f64, T)> {
        let mut lambda = self.lambda;
        let floor = self.floor;
        let mut accepted = None;
        for _ in 0..10 {
            let add = move |d: f64| lambda * d.max(floor);
            match solve(&add) {
                Some((cost, candidate)) if cost < current_cost => {
                    lambda = (lambda / 3.0).max(1e-12);
                    accepted = Some((cost, candidate));
                    break;
                }
                _ => lambda *= 10.0,
            }
        }
        self.lambda = lambda;
        accepted
    }
}

/// The cost of an edge with squared error `chi2`: Huber with width `delta` when `robust`, else χ² itself.
fn robust_cost(chi2: f64, delta: f64, robust: bool) -> f64 {
    if !robust || chi2.sqrt() <= delta { chi2 } else { 2.0 * delta * chi2.sqrt() - delta * delta }
}

/// Huber weight of an edge with squared error `chi2` and width `delta`.
fn huber_weight(chi2: f64, delta: f64) -> f64 {
    let e = chi2.sqrt();
    if e <= delta { 1.0 } else { delta / e }
}

/// ∂X_c/∂ξ for the left update: [−[X_c]× | I].
fn point_jacobian_pose(pc: &Point3<f64>) -> Matrix3x6<f64> {
    let mut m = Matrix3x6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-skew(&pc.coords)));
    m.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
    m
}

/// The edge's Jacobian with respect to the pose twist (rows as the residual).
pub fn pose_jacobian(
    cam: &RectifiedCamera,
    pose: &CameraFromWorld,
    x_w: &Point3<f64>,
    obs: &Observation,
) -> Matrix3x6<f64> {
    let pc = pose * x_w;
    let (_, j) = residual_and_jacobian(cam, &pc, obs);
    j * point_jacobian_pose(&pc)
}

/// The edge's Jacobian with respect to the world point.
pub fn point_jacobian(
    cam: &RectifiedCamera,
    pose: &CameraFromWorld,
    x_w: &Point3<f64>,
    obs: &Observation,
) -> Matrix3<f64> {
    let pc = pose * x_w;
    let (_, j) = residual_and_jacobian(cam, &pc, obs);
    j * pose.rotation.to_rotation_matrix().matrix()
}

/// One observation of point `point` by keyframe `pose` (indices into the problem's lists).
#[derive(Debug, Clone, Copy)]
pub struct BaEdge {
    pub pose: usize,
    pub point: usize,
    pub obs: Observation,
    /// χ² × this is the edge's χ² at its octave's σ: σ_r² for a refined measurement (σ_r relative to the
    /// octave's), 1 otherwise. The map keeps or erases the observation by that χ², as if it were not refined.
    pub octave_chi2_scale: f64,
}

/// `s[ba, bb] −= a · bᵀ` for the 6×6 block at block row `ba`, block column `bb`, with `a`, `b` 6×3. Written out
/// down each column of `s` (column-major) over the factors' column-major elements ((i, m) at 6m + i), with the
/// three terms summed in the order nalgebra's product sums them: the result is the product's to the bit, without
/// its bounds checks, and the inner loop vectorises.
fn subtract_block_product(s: &mut DMatrix<f64>, ba: usize, bb: usize, a: &SMatrix<f64, 6, 3>, b: &SMatrix<f64, 6, 3>) {
    let (a, b) = (a.as_slice(), b.as_slice());
    let rows = 6 * ba;
    for j in 0..6 {
        let (b0, b1, b2) = (b[j], b[6 + j], b[12 + j]);
        let mut column = s.column_mut(6 * bb + j);
        for (i, x) in column.as_mut_slice()[rows..rows + 6].iter_mut().enumerate() {
            *x -= a[i] * b0 + a[6 + i] * b1 + a[12 + i] * b2;
        }
    }
}

/// Solves `s · x = rhs` for a symmetric positive definite `s` of which only the lower triangle is read, as
/// nalgebra's Cholesky does, but over the matrix's envelope only. The factor is zero wherever `s` is zero ahead
/// of a row's first non-zero (no fill before a row's envelope), so column k of the factor ends at the last row
/// whose envelope reaches k; every update skipped here would have added an exact zero, and the factor and the
/// solution are nalgebra's to the bit. The reduced camera system of a bundle adjustment over keyframes in time
/// order is nearly banded (a keyframe shares points with its neighbours in time, and with the old side of a
/// loop), so over a whole map this is a small part of the dense factorisation's n³/3. `None` where nalgebra's
/// would be (a pivot that is zero, negative or NaN).
fn solve_by_envelope_cholesky(mut m: DMatrix<f64>, mut rhs: DVector<f64>) -> Option<DVector<f64>> {
    let n = m.nrows();
    // Each row's first non-zero column in the lower triangle, and each column's last row that reaches it.
    let first: Vec<usize> = (0..n).map(|j| (0..j).find(|&c| m[(j, c)] != 0.0).unwrap_or(j)).collect();
    let mut last: Vec<usize> = (0..n).collect();
    for (i, &f) in first.iter().enumerate() {
        for l in &mut last[f..i] {
            *l = (*l).max(i);
        }
    }
    let data = m.as_mut_slice();
    for j in 0..n {
        // Column j minus column k times the row's factor (nalgebra's left-looking loop), down to where
        // column k ends.
        let (before, from_j) = data.split_at_mut(j * n);
        let column_j = &mut from_j[j..n];
        for k in first[j]..j {
            let column_k = &before[k * n + j..k * n + last[k] + 1];
            let factor = -column_k[0];
            for (y, &x) in column_j.iter_mut().zip(column_k) {
                *y += factor * x;
            }
        }
        let pivot = column_j[0];
        if pivot == 0.0 || pivot.is_nan() || pivot < 0.0 {
            return None;
        }
        let denom = pivot.sqrt();
        column_j[0] = denom;
        for x in &mut column_j[1..=last[j] - j] {
            *x /= denom;
        }
    }
    m.solve_lower_triangular_unchecked_mut(&mut rhs);
    m.ad_solve_lower_triangular_unchecked_mut(&mut rhs);
    Some(rhs)
}

/// A bundle adjustment problem: poses (some fixed), points, edges. Solved in place.
#[derive(Debug, Default, Clone)]
pub struct BaProblem {
    pub poses: Vec<CameraFromWorld>,
    pub fixed: Vec<bool>,
    pub points: Vec<Point3<f64>>,
    pub edges: Vec<BaEdge>,
    /// Edges excluded from the problem (outliers).
    pub excluded: Vec<bool>,
}

/// What a bundle adjustment run did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaReport {
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
}

impl BaProblem {
    fn edge_cost(
        &self,
        cam: &RectifiedCamera,
        k: usize,
        poses: &[CameraFromWorld],
        points: &[Point3<f64>],
        robust: bool,
    ) -> f64 {
        let e = &self.edges[k];
        let x2 = chi2(cam, &poses[e.pose], &points[e.point], &e.obs);
        if !x2.is_finite() {
            return 1e12;
        }
        robust_cost(x2, if e.obs.is_stereo() { HUBER_STEREO_BA } else { HUBER_MONO }, robust)
    }

    fn cost(&self, cam: &RectifiedCamera, poses: &[CameraFromWorld], points: &[Point3<f64>], robust: bool) -> f64 {
        (0..self.edges.len())
            .filter(|&k| !self.excluded[k])
            .map(|k| self.edge_cost(cam, k, poses, points, robust))
            .sum()
    }

    /// χ² of edge `k` at the current estimate.
    pub fn edge_chi2(&self, cam: &RectifiedCamera, k: usize) -> f64 {
        let e = &self.edges[k];
        chi2(cam, &self.poses[e.pose], &self.points[e.point], &e.obs)
    }

    /// ORB-SLAM2's adjustment (§6.5 steps 3–4): 5 robust iterations, the edges then beyond their χ² gate
    /// excluded, 10 plain ones. Returns the iterations done.
    pub fn solve_robust_then_plain(&mut self, cam: &RectifiedCamera) -> usize {
        let first = self.solve(cam, 5, true, &|| false);
        for k in 0..self.edges.len() {
            let x2 = self.edge_chi2(cam, k);
            let e = &self.edges[k];
            if x2.is_nan() || x2 > if e.obs.is_stereo() { CHI2_STEREO } else { CHI2_MONO } {
                self.excluded[k] = true;
            }
        }
        let second = self.solve(cam, 10, false, &|| false);
        first.iterations + second.iterations
    }

    /// Levenberg–Marquardt for `iterations` steps (or until no step lowers the cost, or `abort` says so), with
    /// Huber kernels when `robust`. Points are eliminated (Schur complement); the reduced system over the free
    /// poses is dense.
    pub fn solve(
        &mut self,
        cam: &RectifiedCamera,
        iterations: usize,
        robust: bool,
        abort: &dyn Fn() -> bool,
    ) -> BaReport {
        if self.excluded.len() != self.edges.len() {
            self.excluded = vec![false; self.edges.len()];
        }
        // Free poses get consecutive blocks.
        let mut block = vec![usize::MAX; self.poses.len()];
        let mut n_free = 0;
        for (i, b) in block.iter_mut().enumerate() {
            if !self.fixed[i] {
                *b = n_free;
                n_free += 1;
            }
        }
        // Edges grouped by point.
        let mut by_point: Vec<Vec<usize>> = vec![Vec::new(); self.points.len()];
        let mut free: Vec<(usize, usize)> = Vec::new();
        for (k, e) in self.edges.iter().enumerate() {
            by_point[e.point].push(k);
        }
        let initial_cost = self.cost(cam, &self.poses, &self.points, robust);
        let mut current_cost = initial_cost;
        let mut damping = Damping::new();
        let mut done = 0;
        let dim = 6 * n_free;
        for _ in 0..iterations {
            if abort() {
                break;
            }
            done += 1;
            // Per-edge Jacobians and weighted residuals.
            let mut h_pp = DMatrix::<f64>::zeros(dim, dim);
            let mut g_p = DVector::<f64>::zeros(dim);
            let mut h_ll = vec![Matrix3::<f64>::zeros(); self.points.len()];
            let mut g_l = vec![Vector3::<f64>::zeros(); self.points.len()];
            // (edge → H_pl block), only for free poses.
            let mut h_pl: Vec<SMatrix<f64, 6, 3>> = vec![SMatrix::zeros(); self.edges.len()];
            for (k, e) in self.edges.iter().enumerate() {
                if self.excluded[k] {
                    continue;
                }
                let pose = &self.poses[e.pose];
                let pc = pose * self.points[e.point];
                if pc.z <= 0.0 {
                    continue;
                }
                let (r, jx) = residual_and_jacobian(cam, &pc, &e.obs);
                let x2 = r.norm_squared() * e.obs.inv_sigma2;
                let delta = if e.obs.is_stereo() { HUBER_STEREO_BA } else { HUBER_MONO };
                let w = e.obs.inv_sigma2 * if robust { huber_weight(x2, delta) } else { 1.0 };
                let jl = jx * pose.rotation.to_rotation_matrix().matrix();
                h_ll[e.point] += jl.transpose() * jl * w;
                g_l[e.point] += jl.transpose() * r * w;
                if let Some(&b) = block.get(e.pose).filter(|b| **b != usize::MAX) {
                    let jp = jx * point_jacobian_pose(&pc);
                    let hpp = jp.transpose() * jp * w;
                    let mut view = h_pp.view_mut((6 * b, 6 * b), (6, 6));
                    view += hpp;
                    let mut gv = g_p.rows_mut(6 * b, 6);
                    gv += jp.transpose() * r * w;
                    h_pl[k] = jp.transpose() * jl * w;
                }
            }
            damping.start(
                (0..dim)
                    .map(|k| h_pp[(k, k)])
                    .chain(h_ll.iter().flat_map(|m| (0..3).map(move |k| m[(k, k)])))
                    .fold(0.0, f64::max),
            );
            let accepted = damping.step(current_cost, |add| {
                // Schur complement with every diagonal damped.
                let mut s = h_pp.clone();
                let mut rhs = -g_p.clone();
                for k in 0..dim {
                    s[(k, k)] += add(h_pp[(k, k)]);
                }
                let mut c_inv = vec![Matrix3::<f64>::zeros(); self.points.len()];
                for (p, edges) in by_point.iter().enumerate() {
                    let mut c = h_ll[p];
                    for k in 0..3 {
                        c[(k, k)] += add(h_ll[p][(k, k)]);
                    }
                    let ci = c.try_inverse()?;
                    c_inv[p] = ci;
                    // This point's edges to free poses: (block, edge).
                    free.clear();
                    for &k in edges {
                        if let Some(&b) = block.get(self.edges[k].pose)
                            && b != usize::MAX
                            && !self.excluded[k]
                        {
                            free.push((b, k));
                        }
                    }
                    for &(ba, ka) in &free {
                        let bci = h_pl[ka] * ci;
                        let mut r = rhs.rows_mut(6 * ba, 6);
                        r += bci * g_l[p];
                        // Only the blocks on and below the diagonal: the Cholesky factorisation reads the lower
                        // triangle alone, and S is symmetric, so the upper blocks were half the work for nothing.
                        // A block gets one term per point (one observation per keyframe), in point order.
                        for &(bb, kb) in &free {
                            if bb <= ba {
                                subtract_block_product(&mut s, ba, bb, &bci, &h_pl[kb]);
                            }
                        }
                    }
                }
                let dp = if dim == 0 { DVector::zeros(0) } else { solve_by_envelope_cholesky(s, rhs)? };
                // Back-substitution for the points: dl = C⁻¹(−g_l − Σ H_plᵀ dp).
                let mut new_points = self.points.clone();
                for (p, edges) in by_point.iter().enumerate() {
                    let mut r = -g_l[p];
                    for &k in edges {
                        if self.excluded[k] {
                            continue;
                        }
                        if let Some(&b) = block.get(self.edges[k].pose).filter(|b| **b != usize::MAX) {
                            r -= h_pl[k].transpose() * dp.fixed_rows::<6>(6 * b);
                        }
                    }
                    new_points[p] += c_inv[p] * r;
                }
                let new_poses: Vec<CameraFromWorld> = self
                    .poses
                    .iter()
                    .enumerate()
                    .map(|(i, t)| {
                        if block[i] == usize::MAX {
                            *t
                        } else {
                            update(&Vector6::from_iterator(dp.fixed_rows::<6>(6 * block[i]).iter().copied()), t)
                        }
                    })
                    .collect();
                Some((self.cost(cam, &new_poses, &new_points, robust), (new_poses, new_points)))
            });
            let Some((c, (new_poses, new_points))) = accepted else { break };
            self.poses = new_poses;
            self.points = new_points;
            current_cost = c;
        }
        BaReport { iterations: done, initial_cost, final_cost: current_cost }
    }
}

#[cfg(test)]
mod tests;
