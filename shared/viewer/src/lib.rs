//! The viewer's library: what a person looks at while bdis-slam runs and afterwards — the coloured dense map lit
//! so surfaces read as surfaces, the scope's path with each frame's tracking state, the newest depth, and every
//! process's rate, latency, CPU and restarts — as a local web page (three.js, vendored, served from the binary;
//! no request leaves the machine). It knows nothing of processes: [`RunView`] reads a finished run's folder,
//! [`encode_map`] turns a map into the per-keyframe blocks the page draws, and [`Site`] answers HTTP requests.

mod assets;
mod encode;
pub mod health;
pub mod hub;
pub mod live;
mod run;
mod server;

pub use encode::{BlockScratch, KEYFRAME_HEADER_BYTES, MAP_MAGIC, encode_block, encode_map, put_matrix};
pub use run::{PathPose, RunView};
pub use server::{Site, bind};

use std::path::PathBuf;

/// What went wrong reading a run or serving it; every case names the file or address.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error("{path}: {what}")]
    File { path: PathBuf, what: String },
    #[error("{dir}: nothing to show: neither map.bin nor trajectory.tum is there (is it a run folder?)")]
    NothingToShow { dir: PathBuf },
    /// A trajectory or the quality log (the message names the file and the line).
    #[error(transparent)]
    Format(#[from] bdis_core::formats::FormatError),
    /// The map file (its error names it).
    #[error(transparent)]
    Map(#[from] bdis_mosaic::MosaicError),
    #[error("cannot listen on {addr}: {what}")]
    Listen { addr: String, what: String },
}

#[cfg(test)]
mod tests;
