//! Dense stereo for bdis-slam: BDIS (Bayesian Dense Inverse Searching) and plain DIS behind one interface, and
//! the evaluation against ground truth. Pure compute: no files, no processes.

pub mod eval;
pub mod kernels;
pub mod matcher;
pub mod params;
pub mod preview;

pub use matcher::{DisparityMap, GrayImage, MatchError, Matcher};
pub use params::{Algorithm, ParamError, Params};
