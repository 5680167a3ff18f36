//! `tracking-quality.csv`: one line per frame on how well the images supported its pose (see
//! `bdis_track::TrackingQuality`), so a user can see where tracking was weak and why. Appended as frames are
//! tracked (a restarted tracker continues the file); buffered, flushed at the end of the stream.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use bdis_track::{FrameResult, TrackingState};

pub const FILE_NAME: &str = "tracking-quality.csv";
const HEADER: &str = "frame_seq,t_source_s,state,doubt,method,prior_rejected,matched,inliers,inlier_ratio,\
reprojection_rms_px,position_sigma_rel,rotation_sigma_deg,appearance_matches,appearance_consensus,\
appearance_agreement,cpu_ms,keyframe";

#[derive(Debug)]
pub struct QualityLog {
    path: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
}

pub fn state_name(state: TrackingState) -> &'static str {
    match state {
        TrackingState::NotInitialized => "not-initialised",
        TrackingState::Ok => "ok",
        TrackingState::Uncertain => "uncertain",
        TrackingState::Lost => "lost",
    }
}

impl QualityLog {
    pub fn open(dir: &Path) -> Result<Self> {
        let path = dir.join(FILE_NAME);
        let fresh = std::fs::metadata(&path).map_or(true, |m| m.len() == 0);
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
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
