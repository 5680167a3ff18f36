//! Stereo tracking in the manner of ORB-SLAM2 (ORB-SLAM2-STEREO.md §3–§7), written from the specification, as
//! pure compute: no threads it does not own, no processes, no I/O.

pub mod geometry;
pub mod optim;
