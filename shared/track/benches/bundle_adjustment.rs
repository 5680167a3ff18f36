//! Criterion benchmark: one local bundle adjustment (`BaProblem::solve`, as the mapper's worker runs it: 5 robust
//! iterations, outliers excluded, 10 plain ones), single thread, on a problem the size of the lit 320×240
//! circle's local windows (measured there: ~25 free keyframes and ~10 fixed ones, ~1 450 points, ~10 000
//! observations) — keyframes every few frames along a wall, each point seen by the keyframes whose view holds it.
//! Built here from a fixed seed, so the figure does not depend on a rendered sequence.
//!
//! cargo bench -p bdis-track --bench bundle_adjustment

use bdis_track::geometry::exp_se3;
use bdis_track::optim::{BaEdge, BaProblem, CHI2_MONO, CHI2_STEREO, Observation};
use bdis_track::{CameraFromWorld, RectifiedCamera};
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Isometry3, Point3, Vector3, Vector6};

const FREE: usize = 25;
const FIXED: usize = 10;
const POINTS: usize = 1450;

/// Uniform in [−1, 1) from a 64-bit LCG.
fn noise(state: &mut u64) -> f64 {
    *state = state.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1_442_695_040_888_963_407);
    ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

/// The local window: the fixed keyframes first (older, further back along the path), then the free ones; points
/// on a wall 45–85 mm away; every point observed (stereo, 0.3 px noise) by each keyframe that sees it, poses and
/// points perturbed as a window is before its adjustment.
fn problem() -> BaProblem {
    let cam = RectifiedCamera { fx: 260.0, fy: 260.0, cx: 159.5, cy: 119.5, bf: 1300.0, width: 320, height: 240 };
    let mut s = 2026u64;
    let n_poses = FIXED + FREE;
    let truth: Vec<CameraFromWorld> = (0..n_poses)
        .map(|i| {
            let along = i as f64 * 0.6;
            let world_from_camera = Isometry3::new(
                Vector3::new(along, 0.3 * (i as f64 * 0.4).sin(), 0.0),
                Vector3::new(0.0, 0.004 * i as f64, 0.0),
            );
            world_from_camera.inverse()
        })
        .collect();
    let points: Vec<Point3<f64>> = (0..POINTS)
        .map(|_| {
            let x = 0.6 * n_poses as f64 * 0.5 * (noise(&mut s) + 1.0) + 30.0 * noise(&mut s);
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
            if i < FIXED {
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
        fixed: (0..n_poses).map(|i| i < FIXED).collect(),
        points,
        excluded: vec![false; edges.len()],
        edges,
    }
}

/// The worker's local adjustment: robust, then without the outliers, plain.
fn local_ba(problem: &mut BaProblem, cam: &RectifiedCamera) {
    problem.solve(cam, 5, true, &|| false);
    for k in 0..problem.edges.len() {
        let x2 = problem.edge_chi2(cam, k);
        let e = &problem.edges[k];
        problem.excluded[k] = x2.is_nan() || x2 > if e.obs.is_stereo() { CHI2_STEREO } else { CHI2_MONO };
    }
    problem.solve(cam, 10, false, &|| false);
}

fn bench(c: &mut Criterion) {
    let cam = RectifiedCamera { fx: 260.0, fy: 260.0, cx: 159.5, cy: 119.5, bf: 1300.0, width: 320, height: 240 };
    let start = problem();
    let observed_points = {
        let mut seen = vec![0usize; start.points.len()];
        start.edges.iter().for_each(|e| seen[e.point] += 1);
        seen.iter().filter(|&&n| n > 0).count()
    };
    eprintln!(
        "local window: {FREE} free + {FIXED} fixed keyframes, {observed_points} points observed, {} observations",
        start.edges.len()
    );
    let mut group = c.benchmark_group("local bundle adjustment");
    group.sample_size(20);
    group.bench_function(format!("{FREE} free keyframes, {} observations", start.edges.len()), |b| {
        b.iter_batched(|| start.clone(), |mut p| local_ba(&mut p, &cam), criterion::BatchSize::LargeInput)
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
