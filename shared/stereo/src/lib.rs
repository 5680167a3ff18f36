//! Dense stereo for bdis-slam: BDIS (Bayesian Dense Inverse Searching) and plain DIS behind one interface.
//! Pure compute: no files, no processes (scoring against ground truth is `bdis_eval::stereo`).

pub mod kernels;
pub mod matcher;
pub mod params;
pub mod preview;

pub use matcher::{DisparityMap, GrayImage, MatchError, Matcher};
pub use params::{Algorithm, ParamError, Params};
