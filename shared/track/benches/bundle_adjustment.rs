//! Criterion benchmark: bundle adjustment (`BaProblem::solve` as the mapper's worker runs it: 5 robust
//! iterations, outliers excluded, 10 plain ones), single thread, on two problems built from a fixed seed (so the
//! figures do not depend on a rendered sequence): keyframes along a wall, each point seen by the keyframes whose
//! view holds it.
//! - a local window the size of the lit 320×240 circle's (measured there: ~25 free keyframes and ~10 fixed ones,
//!   ~1 450 points, ~10 000 observations);
//! - a whole map of 200 keyframes 2 mm apart (~8 observations a point), as the global adjustment after a loop
//!   solves it: its reduced camera system is banded, which the envelope Cholesky exploits.
//!
//! cargo bench -p bdis-track --bench bundle_adjustment

use bdis_track::geometry::exp_se3;
use bdis_track::optim::{BaEdge, BaProblem, Observation};
use bdis_track::{CameraFromWorld, RectifiedCamera};
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Point3, Vector3, Vector6};

/// Keyframes free and fixed, points, and the keyframes' spacing along the wall (mm).
struct Shape {
    free: usize,
    fixed: usize,
    points: usize,
    spacing_mm: f64,
}

const LOCAL: Shape = Shape { free: 25, fixed: 10, points: 1450, spacing_mm: 0.6 };
const WHOLE_MAP: Shape = Shape { free: 199, fixed: 1, points: 11_600, spacing_mm: 2.0 };

/// Uniform in [−1, 1) from a 64-bit LCG.
fn noise(state: &mut u64) -> f64 {
    *state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
    ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

/// The local window: the fixed keyframes first (older, further back along the path), then the free ones; points
/// on a wall 45–85 mm away; every point observed (stereo, 0.3 px noise) by each keyframe that sees it, poses and
/// points perturbed as a window is before its adjustment.
/// The lit circle's camera: 320×240, f = 260 px, 5 mm baseline.
fn camera() -> RectifiedCamera {
    RectifiedCamera { fx: 260.0, fy: 260.0, cx: 159.5, cy: 119.5, bf: 1300.0, width: 320, height: 240 }
}

fn problem(shape: &Shape) -> BaProblem {
    let cam = camera();
    let mut s = 2026u64;
    let n_poses = shape.fixed + shape.free;
    let truth: Vec<CameraFromWorld> = (0..n_poses)
        .map(|i| {
            let along = i as f64 * shape.spacing_mm;
            let world_from_camera = Isometry3::new(
                Vector3::new(along, 0.3 * (i as f64 * 0.4).sin(), 0.0),
                Vector3::new(0.0, 0.05 * (i as f64 * 0.1).sin(), 0.0),
            );
            world_from_camera.inverse()
        })
        .collect();
    let points: Vec<Point3<f64>> = (0..shape.points)
        .map(|_| {
            let x = shape.spacing_mm * n_poses as f64 * 0.5 * (noise(&mut s) + 1.0) + 30.0 * noise(&mut s);
            Point3::new(x, 24.0 * noise(&mut s), 65.0 + 20.0 * noise(&mut s))
        })
        .collect();
    let mut edges = Vec::new();
    for (i, pose) in truth.iter().enumerate() {
        for (p, x) in points.iter().enumerate() {
            let z = cam.project_stereo(&(pose * x));
            // A keyframe keeps about a fifth of what its view holds as tracked points.
            if !cam.in_image(z.x, z.y) || noise(&mut s) < 0.6 {
                continue;
            }
            let mut n = || 0.3 * noise(&mut s);
            let (du, dv) = (n(), n());
            let obs = Observation { u: z.x + du, v: z.y + dv, u_right: Some(z.z + du + n()), inv_sigma2: 1.0 };
            edges.push(BaEdge { pose: i, point: p, obs, octave_chi2_scale: 1.0 });
        }
    }
    let poses = truth
        .iter()
        .enumerate()
        .map(|(i, t)| {
            if i < shape.fixed {
                *t
            } else {
                let d = Vector6::from_fn(|k, _| if k < 3 { 0.002 } else { 0.2 } * noise(&mut s));
                exp_se3(&d) * t
            }
        })
        .collect();
    let points = points.iter().map(|p| p + Vector3::from_fn(|_, _| 0.3 * noise(&mut s))).collect();
    BaProblem {
        poses,
        fixed: (0..n_poses).map(|i| i < shape.fixed).collect(),
        points,
        excluded: vec![false; edges.len()],
        edges,
    }
}

fn bench(c: &mut Criterion) {
    let cam = camera();
    let mut group = c.benchmark_group("bundle adjustment");
    group.sample_size(10);
    for (name, shape) in [("local window", LOCAL), ("whole map", WHOLE_MAP)] {
        let start = problem(&shape);
        let mut seen = vec![0usize; start.points.len()];
        start.edges.iter().for_each(|e| seen[e.point] += 1);
        let observed_points = seen.iter().filter(|&&n| n > 0).count();
        let label = format!(
            "{name}: {} free + {} fixed keyframes, {observed_points} points, {} observations",
            shape.free,
            shape.fixed,
            start.edges.len()
        );
        group.bench_function(label, |b| {
            b.iter_batched(|| start.clone(), |mut p| p.solve_robust_then_plain(&cam), criterion::BatchSize::LargeInput)
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
