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
        if append {
            // A predecessor killed mid-line left a torn last line, which the reader ignores only as the last
            // line: cut it off, or this instance's first line would be glued to it and read as corrupt later.
            let text = std::fs::read(path)?;
            let whole = text.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
            if whole < text.len() {
                file.set_len(whole as u64)?;
            }
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_torn_last_line_is_cut_before_appending() {
        use std::io::Write;
        let path = std::env::temp_dir().join(format!("bdis-torn-journal-{}", std::process::id()));
        let mut first = JournalWriter::open(&path, false).unwrap();
        first.write(|l| frame_line(l, 0, 0, None));
        std::fs::OpenOptions::new().append(true).open(&path).unwrap().write_all(b"F 1 10").unwrap();
        let mut second = JournalWriter::open(&path, true).unwrap();
        second.write(|l| frame_line(l, 1, 1, None));
        let read = Continuation::parse(&std::fs::read_to_string(&path).unwrap()).unwrap();
        let _ = std::fs::remove_file(&path);
        assert_eq!(read.frames.len(), 2);
    }
}
