//! `tracking-quality.csv`: the tracking service's log of one line per frame, on how well the images supported
//! its pose and what the tracker reported for it. The service writes it (its `quality_log`, with [`HEADER`] and
//! [`ReportedState::name`]); the viewer, `eval traj --quality` and the tests read it here, so there is one
//! reading of the format and one set of error lines.
//!
//! Columns are found by name, so a log with columns added later still reads. `frame_seq`, `t_source_s` and
//! `state` are required; `doubt` and `keyframe` are read where the header has them (a log from before keyframes
//! were logged has no `keyframe` column: [`QualityLog::logs_keyframes`] says so).

use std::path::Path;

use super::{FormatError, invalid, io_error};

pub const FILE_NAME: &str = "tracking-quality.csv";

/// The header line the service writes, column by column in the order of its lines.
pub const HEADER: &str = "frame_seq,t_source_s,state,doubt,method,prior_rejected,matched,inliers,inlier_ratio,\
reprojection_rms_px,position_sigma_rel,rotation_sigma_deg,appearance_matches,appearance_consensus,\
appearance_agreement,cpu_ms,keyframe";

/// What the tracker reported for a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReportedState {
    NotInitialised,
    Ok,
    Uncertain,
    Lost,
}

impl ReportedState {
    const ALL: [Self; 4] = [Self::NotInitialised, Self::Ok, Self::Uncertain, Self::Lost];

    /// The name in the log's `state` column.
    pub fn name(self) -> &'static str {
        match self {
            Self::NotInitialised => "not-initialised",
            Self::Ok => "ok",
            Self::Uncertain => "uncertain",
            Self::Lost => "lost",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }
}

/// One frame's line, the columns a reader uses (the rest are for people reading the file).
#[derive(Debug, Clone, PartialEq)]
pub struct QualityLine {
    pub frame_seq: u64,
    /// The frame's source time, seconds: the time stamp of its pose in `trajectory.tum`.
    pub t_source_s: f64,
    pub state: ReportedState,
    /// Why the tracker doubted the frame (`low-contrast`, …), when it did.
    pub doubt: Option<String>,
    /// The run's id of the keyframe made from this frame.
    pub keyframe: Option<u64>,
}

/// A whole log.
#[derive(Debug, Clone, PartialEq)]
pub struct QualityLog {
    /// In the order written (frame order; a restarted tracker continues after the earlier instance's frames).
    pub lines: Vec<QualityLine>,
    /// The header has a `keyframe` column: where [`QualityLine::keyframe`] is `None`, no keyframe was made.
    pub logs_keyframes: bool,
}

/// Reads a log; an error names the file, the line and the field.
pub fn read_quality_log(path: &Path) -> Result<QualityLog, FormatError> {
    let text = std::fs::read_to_string(path).map_err(io_error(path))?;
    parse_quality_log(&text, path)
}

pub fn parse_quality_log(text: &str, path: &Path) -> Result<QualityLog, FormatError> {
    let mut lines = text.lines();
    let header: Vec<&str> =
        lines.next().ok_or_else(|| invalid(path, None, "empty: no header line"))?.split(',').map(str::trim).collect();
    let position = |column: &str| header.iter().position(|h| *h == column);
    let required = |column: &str| {
        position(column).ok_or_else(|| invalid(path, Some(1), format!("the header has no column `{column}`")))
    };
    let (seq_col, t_col, state_col) = (required("frame_seq")?, required("t_source_s")?, required("state")?);
    let (doubt_col, keyframe_col) = (position("doubt"), position("keyframe"));
    let mut log = QualityLog { lines: Vec::new(), logs_keyframes: keyframe_col.is_some() };
    for (i, line) in lines.enumerate() {
        let line_no = i + 2;
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != header.len() {
            return Err(invalid(
                path,
                Some(line_no),
                format!("{} fields, the header has {}", fields.len(), header.len()),
            ));
        }
        let bad = |column: &str, problem: String| invalid(path, Some(line_no), format!("field `{column}`: {problem}"));
        let seq_text = fields[seq_col];
        let frame_seq =
            seq_text.parse().map_err(|_| bad("frame_seq", format!("`{seq_text}` is not a frame number")))?;
        let t_text = fields[t_col];
        let t_source_s = t_text
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite())
            .ok_or_else(|| bad("t_source_s", format!("`{t_text}` is not a time in seconds")))?;
        let state_text = fields[state_col];
        let state = ReportedState::from_name(state_text).ok_or_else(|| {
            let names: Vec<&str> = ReportedState::ALL.iter().map(|s| s.name()).collect();
            bad("state", format!("`{state_text}` is not one of {}", names.join(", ")))
        })?;
        let doubt = doubt_col.map(|c| fields[c]).filter(|d| !d.is_empty()).map(str::to_owned);
        let keyframe = match keyframe_col.map(|c| fields[c]).filter(|k| !k.is_empty()) {
            Some(k) => Some(k.parse().map_err(|_| bad("keyframe", format!("`{k}` is not a keyframe id")))?),
            None => None,
        };
        log.lines.push(QualityLine { frame_seq, t_source_s, state, doubt, keyframe });
    }
    Ok(log)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)] // test code: a panic is the failure report
    use super::*;

    fn parse(text: &str) -> Result<QualityLog, String> {
        parse_quality_log(text, Path::new("run/tracking-quality.csv")).map_err(|e| e.to_string())
    }

    #[test]
    fn the_written_header_and_states_read_back() {
        let ok =
            format!("{HEADER}\n0,0.000000,ok,,stereo,0,300,290,0.9667,0.4000,1.000e-3,0.0100,0,0,0.0000,5.000,0\n");
        let veiled =
            "1,0.033333,uncertain,low-contrast,motion,0,40,20,0.5000,1.2000,4.000e-2,0.3000,0,0,0.0000,4.000,\n";
        let log = parse(&(ok + veiled + "\n")).unwrap();
        assert!(log.logs_keyframes);
        assert_eq!(log.lines.len(), 2);
        assert_eq!(
            log.lines[0],
            QualityLine { frame_seq: 0, t_source_s: 0.0, state: ReportedState::Ok, doubt: None, keyframe: Some(0) }
        );
        let second = &log.lines[1];
        assert_eq!(
            (second.state, second.doubt.as_deref(), second.keyframe),
            (ReportedState::Uncertain, Some("low-contrast"), None)
        );
        for state in ReportedState::ALL {
            assert_eq!(ReportedState::from_name(state.name()), Some(state));
        }
    }

    #[test]
    fn a_log_without_the_later_columns_reads_and_says_so() {
        let log = parse("frame_seq,t_source_s,state\n0,0.5,lost\n").unwrap();
        assert!(!log.logs_keyframes);
        assert_eq!(
            (log.lines[0].state, log.lines[0].doubt.clone(), log.lines[0].keyframe),
            (ReportedState::Lost, None, None)
        );
    }

    #[test]
    fn bad_lines_are_refused_naming_the_file_line_and_field() {
        let cases = [
            ("", "tracking-quality.csv: empty"),
            ("frame_seq,state\n", "tracking-quality.csv:1: the header has no column `t_source_s`"),
            ("frame_seq,t_source_s,state\n0,0.0,ok\n1,soon,ok\n", ":3: field `t_source_s`: `soon` is not a time"),
            ("frame_seq,t_source_s,state\n0,NaN,ok\n", ":2: field `t_source_s`: `NaN` is not a time"),
            ("frame_seq,t_source_s,state\n0,0.0,fine\n", ":2: field `state`: `fine` is not one of not-initialised"),
            ("frame_seq,t_source_s,state\nx,0.0,ok\n", ":2: field `frame_seq`: `x` is not a frame number"),
            ("frame_seq,t_source_s,state,keyframe\n0,0.0,ok,k\n", ":2: field `keyframe`: `k` is not a keyframe id"),
            ("frame_seq,t_source_s,state\n0,0.0\n", ":2: 2 fields, the header has 3"),
        ];
        for (text, expected) in cases {
            let message = parse(text).unwrap_err();
            assert!(message.contains(expected), "{text:?}: {message}");
        }
        let missing = read_quality_log(Path::new("/nonexistent/tracking-quality.csv")).unwrap_err().to_string();
        assert!(missing.contains("/nonexistent/tracking-quality.csv"), "{missing}");
    }
}
