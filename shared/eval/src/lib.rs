//! Evaluation against ground truth: trajectories (ATE RMSE/mean/median/max after SE(3) Umeyama alignment without
//! scale — the number `evo_ape tum gt est -a` gives — and RPE per second) and maps (the paper's metric: distance
//! from each map point to the closest point of the ground-truth mesh, points farther than a threshold excluded
//! and counted as outliers) and disparity maps (density, depth errors, bad-1/bad-2 over an evaluation region), and whether the tracker's `Ok` was honest (`status`).

pub mod map;
pub mod stats;
pub mod status;
pub mod stereo;
pub mod traj;

pub use stats::Stats;
