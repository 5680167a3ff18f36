//! File formats: PFM (disparity, depth), binary PLY (maps, meshes), TUM and KITTI trajectories, the tracker's
//! run summary (tracking.json), the tracker's per-frame log (tracking-quality.csv).

use std::fmt;
use std::path::{Path, PathBuf};

pub mod pfm;
pub mod ply;
pub mod quality;
pub mod summary;
pub mod trajectory;

/// A file that could not be read or written, with the place in it when known.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{at}: {what}")]
    Invalid { at: FileAt, what: String },
}

/// A file, and a line (text formats) or byte offset (binary formats) in it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FileAt {
    pub path: PathBuf,
    pub line: Option<usize>,
}

impl fmt::Display for FileAt {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(line) => write!(f, "{}:{}", self.path.display(), line),
            None => write!(f, "{}", self.path.display()),
        }
    }
}

pub(crate) fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> FormatError + '_ {
    move |source| FormatError::Io { path: path.to_path_buf(), source }
}

pub(crate) fn invalid(path: &Path, line: Option<usize>, what: impl Into<String>) -> FormatError {
    FormatError::Invalid { at: FileAt { path: path.to_path_buf(), line }, what: what.into() }
}

/// Writes through a temporary file in the same folder and renames it into place, so a crash or full disk never
/// leaves a half-written file where a good one was.
pub(crate) fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> Result<(), FormatError> {
    use std::io::Write;
    let file_name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = path.with_file_name(format!(".{file_name}.tmp{}", std::process::id()));
    let result = (|| {
        let mut w = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        write(&mut w)?;
        w.flush()?;
        w.get_ref().sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io_error(path))
}
