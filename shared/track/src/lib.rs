//! Stereo tracking in the manner of ORB-SLAM2 (ORB-SLAM2-STEREO.md §3–§7), written from the specification, as
//! pure compute: no processes, no I/O.

pub mod frame;
pub mod geometry;
pub mod ids;
pub mod instruments;
pub mod journal;
pub mod loop_closing;
pub mod map;
pub mod mapper;
pub mod optim;
pub mod refine;
pub mod search;
mod stats;
pub mod tracker;
pub mod workers;

pub use geometry::{CameraFromWorld, RectifiedCamera};
pub use tracker::{
    Doubt, FrameResult, PoseMethod, RESTART_AFTER_S, TrackError, Tracker, TrackerSettings, TrackingQuality,
    TrackingState,
};
