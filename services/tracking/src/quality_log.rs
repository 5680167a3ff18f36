//! `tracking-quality.csv`: one line per frame on how well the images supported its pose (see
//! `bdis_track::TrackingQuality`), so a user can see where tracking was weak and why. Appended as frames are
//! tracked (a tracker restarted after a crash continues the file; a new run in the same folder starts it
//! anew); buffered, flushed at the end of the stream. The format (header, state names) and its one reader are
//! `bdis_core::formats::quality`.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use bdis_track::{FrameResult, TrackingState};

pub use bdis_core::formats::quality::FILE_NAME;
use bdis_core::formats::quality::{HEADER, ReportedState};

#[derive(Debug)]
pub struct QualityLog {
    path: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
}

fn state_name(state: TrackingState) -> &'static str {
    match state {
        TrackingState::NotInitialized => ReportedState::NotInitialised,
        TrackingState::Ok => ReportedState::Ok,
        TrackingState::Uncertain => ReportedState::Uncertain,
        TrackingState::Lost => ReportedState::Lost,
    }
    .name()
}

impl QualityLog {
    /// Opens the log in run folder `dir`: continued when `continuing` an earlier instance of the same run (its
    /// frames are already there), else started anew, so that a run in a folder an earlier run used does not
    /// carry that run's frames.
    pub fn open(dir: &Path, continuing: bool) -> Result<Self> {
        let path = dir.join(FILE_NAME);
        let fresh = !continuing || std::fs::metadata(&path).map_or(true, |m| m.len() == 0);
        let file = if continuing {
            std::fs::OpenOptions::new().create(true).append(true).open(&path)
        } else {
            std::fs::File::create(&path)
        }
        .with_context(|| format!("{}: cannot open", path.display()))?;
        let mut out = std::io::BufWriter::new(file);
        if fresh {
            writeln!(out, "{HEADER}").with_context(|| format!("{}: cannot write", path.display()))?;
        }
        Ok(Self { path, out })
    }

    /// One frame's line (`keyframe`: the run's id of the keyframe made from it).
    pub fn frame(&mut self, frame_seq: u64, result: &FrameResult, cpu_ns: u64, keyframe: Option<u64>) -> Result<()> {
        let q = &result.quality;
        let ratio = if q.matched > 0 { f64::from(q.inliers) / f64::from(q.matched) } else { f64::NAN };
        write!(
            self.out,
            "{frame_seq},{:.6},{},{},{},{},{},{},{:.4},{:.4},{:.3e},{:.4},{},{},{:.4},{:.3},",
            result.t_ns as f64 * 1e-9,
            state_name(result.state),
            q.doubt.map_or("", |d| d.name()),
            q.method.name(),
            u8::from(q.prior_rejected),
            q.matched,
            q.inliers,
            ratio,
            q.reprojection_rms_px,
            q.position_sigma_rel,
            q.rotation_sigma_deg,
            q.appearance_matches,
            q.appearance_consensus,
            q.appearance_agreement,
            cpu_ns as f64 / 1e6,
        )
        .and_then(|()| match keyframe {
            Some(k) => writeln!(self.out, "{k}"),
            None => writeln!(self.out),
        })
        .with_context(|| format!("{}: cannot write", self.path.display()))
    }

    pub fn finish(&mut self) -> Result<()> {
        self.out.flush().with_context(|| format!("{}: cannot write", self.path.display()))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)] // test code: a panic is the failure report
    use super::*;

    fn lines(dir: &Path) -> Vec<String> {
        std::fs::read_to_string(dir.join(FILE_NAME)).unwrap().lines().map(str::to_owned).collect()
    }

    #[test]
    fn a_new_run_starts_the_log_anew_and_a_restarted_tracker_continues_it() {
        let dir = std::env::temp_dir().join(format!("bdis-quality-log-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let result = FrameResult {
            frame_id: 0,
            t_ns: 0,
            state: TrackingState::Lost,
            camera_from_world: None,
            inliers: 0,
            new_keyframe: None,
            mapper: None,
            relocalised: false,
            new_segment: false,
            quality: bdis_track::TrackingQuality::default(),
        };
        let mut log = QualityLog::open(&dir, false).unwrap();
        log.frame(0, &result, 1_000_000, None).unwrap();
        log.frame(1, &result, 1_000_000, Some(1)).unwrap();
        log.finish().unwrap();
        drop(log);
        assert_eq!(lines(&dir).len(), 3);
        // What it wrote is what the format's reader (the viewer's, `eval`'s) reads.
        let read = bdis_core::formats::quality::read_quality_log(&dir.join(FILE_NAME)).unwrap();
        let seen: Vec<_> = read.lines.iter().map(|l| (l.frame_seq, l.state, l.keyframe)).collect();
        assert_eq!(seen, [(0, ReportedState::Lost, None), (1, ReportedState::Lost, Some(1))]);
        assert!(read.logs_keyframes);
        // The same run's tracker restarted after frame 1 adds its frames after the earlier ones.
        let mut log = QualityLog::open(&dir, true).unwrap();
        log.frame(2, &result, 1_000_000, None).unwrap();
        log.finish().unwrap();
        drop(log);
        let continued = lines(&dir);
        assert_eq!(continued.len(), 4, "{continued:?}");
        assert_eq!(continued[0], HEADER);
        assert!(continued[3].starts_with("2,"));
        // A new run in the same folder: its frames only.
        let mut log = QualityLog::open(&dir, false).unwrap();
        log.frame(0, &result, 1_000_000, None).unwrap();
        log.finish().unwrap();
        drop(log);
        let anew = lines(&dir);
        assert_eq!(anew.len(), 2, "{anew:?}");
        assert_eq!(anew[0], HEADER);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
