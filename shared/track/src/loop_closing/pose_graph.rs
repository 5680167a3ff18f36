//! Pose-graph optimisation over SE(3) (ORB-SLAM2-STEREO.md §8.4, stereo: the scale is known, so no Sim(3)):
//! keyframe poses as nodes, relative poses as edges, Levenberg–Marquardt on the edges' twist residuals with a
//! block-sparse system solved by preconditioned conjugate gradients (the graph is mostly a chain: a dense solve
//! would cost (6n)³, this one a few hundred sparse products).
//!
//! Units: an edge's residual is a twist (ω, υ). A rotation error of ω radians moves the image by about ω·f px;
//! a translation error υ moves a point at depth d by |υ|/d·f px. So the translation rows are divided by the
//! scene's depth (`depth_scale`, the keyframes' median depth) and both parts weigh as image motion — in the
//! scene's own unit, whatever it is (mm for an endoscope, m for a car).

use crate::geometry::{exp_se3, skew, update};
use nalgebra::{Isometry3, Matrix3, Matrix6, Vector3, Vector6};
use std::collections::BTreeMap;

/// One relative-pose constraint: the measured `j_from_i` (camera j from camera i, T_j·T_i⁻¹).
#[derive(Debug, Clone, Copy)]
pub struct GraphEdge {
    pub i: usize,
    pub j: usize,
    pub j_from_i: Isometry3<f64>,
}

/// A pose graph: `camera_from_world` per node, which nodes are held, the edges.
#[derive(Debug, Clone, Default)]
pub struct PoseGraph {
    pub poses: Vec<Isometry3<f64>>,
    pub fixed: Vec<bool>,
    pub edges: Vec<GraphEdge>,
    /// The scene's depth in its own unit (see the module's note).
    pub depth_scale: f64,
}

/// What a solve did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct GraphReport {
    pub iterations: usize,
    pub initial_cost: f64,
    pub final_cost: f64,
    pub cg_iterations: usize,
}

/// The twist ξ = (ω, υ) with `exp_se3(ξ) = t` (rotation angle below π).
pub fn log_se3(t: &Isometry3<f64>) -> Vector6<f64> {
    let omega = t.rotation.scaled_axis();
    let theta = omega.norm();
    let w = skew(&omega);
    // V⁻¹ = I − ½[ω]× + (1/θ²)(1 − θ sin θ / (2(1 − cos θ)))[ω]×², with its series near 0.
    let c = if theta < 1e-5 {
        1.0 / 12.0 + theta * theta / 720.0
    } else {
        (1.0 - theta * theta.sin() / (2.0 * (1.0 - theta.cos()))) / (theta * theta)
    };
    let v_inv = Matrix3::identity() - w * 0.5 + w * w * c;
    let upsilon: Vector3<f64> = v_inv * t.translation.vector;
    Vector6::new(omega.x, omega.y, omega.z, upsilon.x, upsilon.y, upsilon.z)
}

impl PoseGraph {
    /// The weighted residual of edge `e` at poses `ti`, `tj`.
    fn residual(&self, e: &GraphEdge, ti: &Isometry3<f64>, tj: &Isometry3<f64>) -> Vector6<f64> {
        let mut r = log_se3(&(e.j_from_i.inverse() * tj * ti.inverse()));
        let s = 1.0 / self.depth_scale;
        for k in 3..6 {
            r[k] *= s;
        }
        r
    }

    pub fn cost(&self) -> f64 {
        self.edges.iter().map(|e| self.residual(e, &self.poses[e.i], &self.poses[e.j]).norm_squared()).sum()
    }

    /// Levenberg–Marquardt, at most `max_iterations` steps; the fixed nodes do not move.
    pub fn optimise(&mut self, max_iterations: usize) -> GraphReport {
        let n = self.poses.len();
        let mut report = GraphReport { initial_cost: self.cost(), ..GraphReport::default() };
        report.final_cost = report.initial_cost;
        if n == 0 || self.edges.is_empty() || self.depth_scale.is_nan() || self.depth_scale <= 0.0 {
            return report;
        }
        // Unknown index per node (fixed nodes have none).
        let mut unknown: Vec<Option<usize>> = vec![None; n];
        let mut m = 0;
        for (k, u) in unknown.iter_mut().enumerate() {
            if !self.fixed[k] {
                *u = Some(m);
                m += 1;
            }
        }
        if m == 0 {
            return report;
        }
        let mut lambda = 1e-4;
        let mut cost = report.initial_cost;
        for _ in 0..max_iterations {
            report.iterations += 1;
            let (diag, off, b) = self.normal_equations(&unknown, m);
            let mut accepted = false;
            for _ in 0..8 {
                let mut damped = diag.clone();
                for d in &mut damped {
                    for k in 0..6 {
                        d[(k, k)] += lambda * d[(k, k)].max(1e-12);
                    }
                }
                let (step, cg) = solve_pcg(&damped, &off, &b);
                report.cg_iterations += cg;
                let mut candidate = self.poses.clone();
                for (node, u) in unknown.iter().enumerate() {
                    if let Some(u) = *u {
                        let mut xi = Vector6::from_iterator(step[6 * u..6 * u + 6].iter().copied());
                        for k in 3..6 {
                            xi[k] *= self.depth_scale;
                        }
                        candidate[node] = update(&(-xi), &self.poses[node]);
                    }
                }
                let before = std::mem::replace(&mut self.poses, candidate);
                let new_cost = self.cost();
                if new_cost < cost {
                    cost = new_cost;
                    lambda = (lambda / 10.0).max(1e-9);
                    accepted = true;
                    break;
                }
                self.poses = before;
                lambda *= 10.0;
            }
            if !accepted || cost < 1e-20 {
                break;
            }
            let relative_gain = (report.final_cost - cost) / report.final_cost.max(1e-300);
            report.final_cost = cost;
            if relative_gain < 1e-9 {
                break;
            }
        }
        report.final_cost = cost;
        report
    }

    /// JᵀJ in blocks (diagonal per unknown; upper off-diagonal per edge pair) and Jᵀr, by central differences in
    /// the scaled twist (translation in depths, so the step sizes mean the same in every unit).
    #[allow(clippy::type_complexity)]
    fn normal_equations(
        &self,
        unknown: &[Option<usize>],
        m: usize,
    ) -> (Vec<Matrix6<f64>>, BTreeMap<(usize, usize), Matrix6<f64>>, Vec<f64>) {
        let mut diag = vec![Matrix6::zeros(); m];
        let mut off: BTreeMap<(usize, usize), Matrix6<f64>> = BTreeMap::new();
        let mut b = vec![0.0; 6 * m];
        const H: f64 = 1e-6;
        for e in &self.edges {
            let (ti, tj) = (self.poses[e.i], self.poses[e.j]);
            let r = self.residual(e, &ti, &tj);
            let jacobian = |moving_i: bool| -> Matrix6<f64> {
                let mut jac = Matrix6::zeros();
                for k in 0..6 {
                    let mut xi = Vector6::zeros();
                    xi[k] = if k < 3 { H } else { H * self.depth_scale };
                    let (plus, minus) = (exp_se3(&xi), exp_se3(&(-xi)));
                    let (rp, rm) = if moving_i {
                        (self.residual(e, &(plus * ti), &tj), self.residual(e, &(minus * ti), &tj))
                    } else {
                        (self.residual(e, &ti, &(plus * tj)), self.residual(e, &ti, &(minus * tj)))
                    };
                    jac.set_column(k, &((rp - rm) / (2.0 * H)));
                }
                jac
            };
            let blocks: Vec<(usize, Matrix6<f64>)> = [(e.i, true), (e.j, false)]
                .into_iter()
                .filter_map(|(node, is_i)| unknown[node].map(|u| (u, jacobian(is_i))))
                .collect();
            for &(u, ref ju) in &blocks {
                diag[u] += ju.transpose() * ju;
                let g = ju.transpose() * r;
                for k in 0..6 {
                    b[6 * u + k] += g[k];
                }
            }
            if let [(u, ju), (v, jv)] = blocks.as_slice() {
                if u == v {
                    diag[*u] += ju.transpose() * jv + jv.transpose() * ju;
                } else if u < v {
                    *off.entry((*u, *v)).or_insert_with(Matrix6::zeros) += ju.transpose() * jv;
                } else {
                    *off.entry((*v, *u)).or_insert_with(Matrix6::zeros) += jv.transpose() * ju;
                }
            }
        }
        (diag, off, b)
    }
}

/// y = H·x for the block-symmetric H (diagonal blocks, upper off-diagonal blocks).
fn multiply(diag: &[Matrix6<f64>], off: &BTreeMap<(usize, usize), Matrix6<f64>>, x: &[f64], y: &mut [f64]) {
    let block = |v: &[f64], u: usize| Vector6::from_iterator(v[6 * u..6 * u + 6].iter().copied());
    for (u, d) in diag.iter().enumerate() {
        let r = d * block(x, u);
        y[6 * u..6 * u + 6].copy_from_slice(r.as_slice());
    }
    for (&(u, v), h) in off {
        let a = h * block(x, v);
        let c = h.transpose() * block(x, u);
        for k in 0..6 {
            y[6 * u + k] += a[k];
            y[6 * v + k] += c[k];
        }
    }
}

/// Solves H·x = b by conjugate gradients with the diagonal blocks' inverses as preconditioner; returns x and
/// the iterations. Stops at a residual 10⁻¹⁰ of |b| or after 2·dim iterations.
fn solve_pcg(diag: &[Matrix6<f64>], off: &BTreeMap<(usize, usize), Matrix6<f64>>, b: &[f64]) -> (Vec<f64>, usize) {
    let dim = b.len();
    let inverse: Vec<Matrix6<f64>> = diag.iter().map(|d| d.try_inverse().unwrap_or_else(Matrix6::identity)).collect();
    let precondition = |r: &[f64], z: &mut [f64]| {
        for (u, inv) in inverse.iter().enumerate() {
            let v = inv * Vector6::from_iterator(r[6 * u..6 * u + 6].iter().copied());
            z[6 * u..6 * u + 6].copy_from_slice(v.as_slice());
        }
    };
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let mut x = vec![0.0; dim];
    let mut r = b.to_vec();
    let mut z = vec![0.0; dim];
    precondition(&r, &mut z);
    let mut p = z.clone();
    let mut hp = vec![0.0; dim];
    let mut rz = dot(&r, &z);
    let stop = 1e-20 * dot(b, b);
    let mut iterations = 0;
    while iterations < 2 * dim && dot(&r, &r) > stop {
        iterations += 1;
        multiply(diag, off, &p, &mut hp);
        let php = dot(&p, &hp);
        if php <= 0.0 || !php.is_finite() {
            break;
        }
        let alpha = rz / php;
        for k in 0..dim {
            x[k] += alpha * p[k];
            r[k] -= alpha * hp[k];
        }
        precondition(&r, &mut z);
        let rz_new = dot(&r, &z);
        let beta = rz_new / rz;
        rz = rz_new;
        for k in 0..dim {
            p[k] = z[k] + beta * p[k];
        }
    }
    (x, iterations)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_inverts_exp() {
        for xi in [Vector6::new(1e-7, 2e-7, -1e-7, 0.5, -0.2, 0.1), Vector6::new(0.4, -0.9, 0.3, 10.0, -3.0, 2.0)] {
            assert!((log_se3(&exp_se3(&xi)) - xi).norm() < 1e-9, "{xi}");
        }
    }

    /// A camera going round a circle (poses every 10°), the odometry edges with a small drift in yaw each step,
    /// and a loop edge from the last pose to the first that is exact: the optimised loop must land back near the
    /// truth, where the odometry alone ends far from it.
    #[test]
    fn a_loop_edge_pulls_a_drifted_circle_back() {
        let radius = 40.0;
        let truth: Vec<Isometry3<f64>> = (0..36)
            .map(|k| {
                let a = f64::from(k) * 10f64.to_radians();
                let world_from_camera =
                    Isometry3::new(Vector3::new(radius * a.cos(), radius * a.sin(), 60.0), Vector3::new(0.0, 0.0, a));
                world_from_camera.inverse()
            })
            .collect();
        let drift = Isometry3::new(Vector3::new(0.05, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.004));
        let mut graph = PoseGraph { depth_scale: 60.0, ..PoseGraph::default() };
        let mut pose = truth[0];
        for k in 0..truth.len() {
            if k > 0 {
                let j_from_i = drift * truth[k] * truth[k - 1].inverse();
                graph.edges.push(GraphEdge { i: k - 1, j: k, j_from_i });
                pose = j_from_i * pose;
            }
            graph.poses.push(pose);
            graph.fixed.push(k == 0);
        }
        let last = truth.len() - 1;
        let error = |g: &PoseGraph| {
            (0..truth.len())
                .map(|k| (g.poses[k].inverse().translation.vector - truth[k].inverse().translation.vector).norm())
                .fold(0.0, f64::max)
        };
        let before = error(&graph);
        graph.edges.push(GraphEdge { i: 0, j: last, j_from_i: truth[last] * truth[0].inverse() });
        let report = graph.optimise(20);
        let after = error(&graph);
        assert!(before > 5.0, "the odometry drifts: {before}");
        assert!(after < 0.2 * before, "the loop brings the circle back: {before} → {after}");
        // The drift is in every odometry edge, so some residual stays: spread over 36 edges, not gone.
        assert!(report.final_cost < 0.1 * report.initial_cost, "{report:?}");
        assert_eq!(graph.poses[0], truth[0], "the fixed node does not move");
    }
}
