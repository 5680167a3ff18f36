//! The journal file this tracker instance appends to; the format (and the reader a restarted instance uses)
//! is [`bdis_track::journal`], a library so it can be fuzzed and reused without a process.

pub use bdis_track::journal::*;

/// The journal this instance appends to. A failed write costs only the ability
/// to resume, so it is reported once and tracking goes on.
#[derive(Debug)]
pub struct JournalWriter {
    file: Option<std::fs::File>,
    path: std::path::PathBuf,
    /// The line being written, reused: journalling a frame allocates nothing once warmed up.
    line: String,
}

impl JournalWriter {
    pub fn open(path: &std::path::Path, append: bool) -> std::io::Result<Self> {
        let file = std::fs::OpenOptions::new().create(true).append(append).write(true).truncate(!append).open(path)?;
        Ok(Self { file: Some(file), path: path.to_path_buf(), line: String::with_capacity(256) })
    }

    pub fn write(&mut self, format: impl FnOnce(&mut String)) {
        use std::io::Write;
        let Some(f) = &mut self.file else { return };
        self.line.clear();
        format(&mut self.line);
        // One write per line: a crash leaves at most the last line torn, which the reader ignores.
        if let Err(e) = f.write_all(self.line.as_bytes()) {
            tracing::warn!("{}: {e}; a restarted tracker could not continue from here", self.path.display());
            self.file = None;
        }
    }
}
