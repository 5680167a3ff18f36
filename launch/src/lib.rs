//! The `bdis-slam` launcher as a library: launch files, supervision of the pipeline's processes, latency
//! aggregation, and the checks behind `bdis-slam probe`.

pub mod latency;
pub mod launch_file;
pub mod preview;
pub mod probe;
pub mod progress;
pub mod run;
pub mod run_dir;
pub mod supervisor;
