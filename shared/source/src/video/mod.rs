//! Stereo video files: one file with both views stacked top/bottom or side by side, or one file per view.
//!
//! Decoding goes through the `ffmpeg` command-line tool as a child process that writes raw RGB frames on a
//! pipe: every codec ffmpeg knows, no libav linked into the product (Debian's build is GPL), and a decoder that
//! crashes on a corrupt file takes down its child, not acquisition. Timestamps are the container's (packet
//! presentation times, read once by `ffprobe` before the first frame is published). Y4M and Motion-JPEG AVI
//! are read here instead, without ffmpeg (`native`): they need no codec the product does not already have.

mod avi;
mod decoder;
mod native;
mod y4m;

pub use decoder::{VideoDecoder, split_into};
#[doc(hidden)]
pub use native::index_and_decode;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

/// How the two views are laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Arrangement {
    /// One file, left view above right (SCARED, StereoMIS).
    TopBottom,
    /// One file, left view beside right (Hamlyn `stereo.avi`).
    SideBySide,
    /// Two files, the left view's and the right view's, paired by frame number.
    TwoFiles,
}

impl Arrangement {
    pub fn name(self) -> &'static str {
        match self {
            Arrangement::TopBottom => "top-bottom",
            Arrangement::SideBySide => "side-by-side",
            Arrangement::TwoFiles => "two-files",
        }
    }
}

/// A stereo video source as given on the command line: `video:top-bottom:FILE`, `video:side-by-side:FILE` or
/// `video:two-files:LEFT,RIGHT`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VideoSpec {
    pub arrangement: Arrangement,
    /// One file, or the left and the right file.
    pub files: Vec<PathBuf>,
}

/// What goes wrong with a video source, each naming the file.
#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    #[error(
        "`{spec}`: not a video source (expected video:top-bottom:FILE, video:side-by-side:FILE or video:two-files:LEFT,RIGHT)"
    )]
    Spec { spec: String },
    #[error("{path}: video file not found")]
    Missing { path: PathBuf },
    #[error(
        "{tool}: cannot run it ({detail}); video input needs ffmpeg (Debian: apt-get install ffmpeg), or convert the video to PNG pairs"
    )]
    Tool { tool: &'static str, detail: String },
    #[error("{path}: {detail}")]
    Probe { path: PathBuf, detail: String },
    #[error("{path}: {w}×{h} cannot be split {how} into two equal views")]
    Split { path: PathBuf, w: u32, h: u32, how: &'static str },
    #[error(
        "{right}: {right_frames} frames of {right_w}×{right_h}, but the left video {left} has {left_frames} of {left_w}×{left_h}"
    )]
    Pairing {
        left: PathBuf,
        right: PathBuf,
        left_frames: usize,
        right_frames: usize,
        left_w: u32,
        left_h: u32,
        right_w: u32,
        right_h: u32,
    },
    #[error("{path}: the video ended after {decoded} of its {expected} frames{stderr}")]
    EndedEarly { path: PathBuf, decoded: u64, expected: usize, stderr: String },
    #[error("{path}: frame {frame} (at {t:.3} s) could not be decoded; passed over")]
    FrameLost { path: PathBuf, frame: u64, t: f64 },
    #[error("{path}: reading decoded frames from ffmpeg: {detail}")]
    Pipe { path: PathBuf, detail: String },
}

impl VideoSpec {
    /// `None` when `source` is not a `video:` source; otherwise the spec or what is wrong with it.
    pub fn parse(source: &str) -> Option<Result<Self, VideoError>> {
        let rest = source.strip_prefix("video:")?;
        let bad = || VideoError::Spec { spec: source.to_string() };
        let parsed = (|| {
            let (arrangement, files) = rest.split_once(':')?;
            let arrangement = match arrangement {
                "top-bottom" => Arrangement::TopBottom,
                "side-by-side" => Arrangement::SideBySide,
                "two-files" => Arrangement::TwoFiles,
                _ => return None,
            };
            let files: Vec<PathBuf> = match arrangement {
                Arrangement::TwoFiles => {
                    let (l, r) = files.split_once(',')?;
                    vec![l.into(), r.into()]
                }
                _ => vec![files.into()],
            };
            files.iter().all(|f| !f.as_os_str().is_empty()).then_some(Self { arrangement, files })
        })();
        Some(parsed.ok_or_else(bad))
    }

    /// The spec with absolute paths, for a child process started elsewhere.
    pub fn to_absolute_argument(&self) -> Result<String, VideoError> {
        let files = self
            .files
            .iter()
            .map(|f| {
                std::fs::canonicalize(f)
                    .map(|p| p.display().to_string())
                    .map_err(|_| VideoError::Missing { path: f.clone() })
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(format!("video:{}:{}", self.arrangement.name(), files.join(",")))
    }

    /// The file the left view comes from, and the right's.
    pub fn left_file(&self) -> &Path {
        &self.files[0]
    }

    pub fn right_file(&self) -> &Path {
        self.files.last().map_or(self.left_file(), |p| p.as_path())
    }
}

/// One video stream as ffprobe reads it.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoProbe {
    pub width: u32,
    pub height: u32,
    /// Presentation time of each frame in seconds, in display order.
    pub timestamps_s: Vec<f64>,
    /// Who decodes it: `ffmpeg`, or the container read here.
    pub decoder: &'static str,
}

fn run_tool(tool: &'static str, args: &[&std::ffi::OsStr], path: &Path) -> Result<String, VideoError> {
    let out = Command::new(tool)
        .args(args)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| VideoError::Tool { tool, detail: e.to_string() })?;
    if !out.status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        let line = stderr.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or("no message").trim();
        return Err(VideoError::Probe { path: path.to_path_buf(), detail: format!("{tool}: {line}") });
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// `ffprobe`'s answer for `entries` of the first video stream, one CSV line per item.
fn ffprobe(path: &Path, entries: &str) -> Result<String, VideoError> {
    let args = ["-v", "error", "-select_streams", "v:0", "-show_entries", entries, "-of", "csv=p=0"];
    let mut all: Vec<&std::ffi::OsStr> = args.iter().map(std::ffi::OsStr::new).collect();
    all.push(path.as_os_str());
    run_tool("ffprobe", &all, path)
}

/// Reads the first video stream's size and the presentation time of every frame (from the packets: the
/// container's clock, without decoding). A frame without a time gets its predecessor's plus the mean step.
pub fn probe(path: &Path) -> Result<VideoProbe, VideoError> {
    if !path.is_file() {
        return Err(VideoError::Missing { path: path.to_path_buf() });
    }
    if let Some(index) = native::index(path)? {
        let decoder = index.decoder();
        return Ok(VideoProbe { width: index.width, height: index.height, timestamps_s: index.timestamps_s, decoder });
    }
    let bad = |detail: String| VideoError::Probe { path: path.to_path_buf(), detail };
    let stream = ffprobe(path, "stream=width,height")?;
    let line = stream.lines().next().map(str::trim).unwrap_or_default();
    let (w, h) = line.split_once(',').ok_or_else(|| bad("no video stream".into()))?;
    let size = |s: &str, field: &str| {
        s.trim()
            .trim_end_matches(',')
            .parse::<u32>()
            .ok()
            .filter(|v| (1..=native::MAX_SIDE).contains(v))
            .ok_or_else(|| bad(format!("stream {field} `{s}` is not a size (1 to {})", native::MAX_SIDE)))
    };
    let (width, height) = (size(w, "width")?, size(h, "height")?);
    let packets = ffprobe(path, "packet=pts_time")?;
    let mut times: Vec<Option<f64>> = packets
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .map(|l| l.trim_end_matches(',').parse().ok())
        .collect();
    if times.is_empty() {
        return Err(bad("no video frames".into()));
    }
    // Packets come in decoding order; frames are shown in presentation order.
    let known: Vec<f64> = times.iter().flatten().copied().collect();
    if known.len() < times.len() {
        let step = if known.len() >= 2 {
            let (lo, hi) = known.iter().fold((f64::MAX, f64::MIN), |(lo, hi), &t| (lo.min(t), hi.max(t)));
            (hi - lo) / (known.len() - 1) as f64
        } else {
            0.0
        };
        let mut last = known.iter().copied().fold(f64::MAX, f64::min);
        if !last.is_finite() || last == f64::MAX {
            last = 0.0;
        }
        for t in times.iter_mut() {
            match t {
                Some(v) => last = *v,
                None => {
                    last += step;
                    *t = Some(last);
                }
            }
        }
    }
    let mut timestamps_s: Vec<f64> = times.into_iter().flatten().collect();
    timestamps_s.sort_by(f64::total_cmp);
    Ok(VideoProbe { width, height, timestamps_s, decoder: "ffmpeg" })
}

/// A checked video source: its views' size and every frame's time.
#[derive(Debug, Clone, PartialEq)]
pub struct VideoSource {
    pub spec: VideoSpec,
    /// The size of one view.
    pub width: u32,
    pub height: u32,
    pub timestamps_s: Vec<f64>,
    /// Who decodes the (left) file: `ffmpeg`, or the container read here.
    pub decoder: &'static str,
}

impl VideoSource {
    /// Probes the file(s) and checks that they split (or pair) into two views of one size.
    pub fn open(spec: &VideoSpec) -> Result<Self, VideoError> {
        let left = probe(spec.left_file())?;
        let (width, height) = match spec.arrangement {
            Arrangement::TopBottom if left.height.is_multiple_of(2) => (left.width, left.height / 2),
            Arrangement::SideBySide if left.width.is_multiple_of(2) => (left.width / 2, left.height),
            Arrangement::TwoFiles => {
                let right = probe(spec.right_file())?;
                if (right.width, right.height, right.timestamps_s.len())
                    != (left.width, left.height, left.timestamps_s.len())
                {
                    return Err(VideoError::Pairing {
                        left: spec.left_file().to_path_buf(),
                        right: spec.right_file().to_path_buf(),
                        left_frames: left.timestamps_s.len(),
                        right_frames: right.timestamps_s.len(),
                        left_w: left.width,
                        left_h: left.height,
                        right_w: right.width,
                        right_h: right.height,
                    });
                }
                (left.width, left.height)
            }
            arrangement => {
                return Err(VideoError::Split {
                    path: spec.left_file().to_path_buf(),
                    w: left.width,
                    h: left.height,
                    how: if arrangement == Arrangement::TopBottom { "top/bottom" } else { "side by side" },
                });
            }
        };
        Ok(Self { spec: spec.clone(), width, height, timestamps_s: left.timestamps_s, decoder: left.decoder })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn specs_parse_and_name_what_is_wrong() {
        assert!(VideoSpec::parse("/data/seq").is_none());
        let s = VideoSpec::parse("video:top-bottom:/d/rgb.mp4").unwrap().unwrap();
        assert_eq!((s.arrangement, s.files.len()), (Arrangement::TopBottom, 1));
        assert_eq!(s.right_file(), Path::new("/d/rgb.mp4"));
        let s = VideoSpec::parse("video:two-files:l.avi,r.avi").unwrap().unwrap();
        assert_eq!((s.left_file(), s.right_file()), (Path::new("l.avi"), Path::new("r.avi")));
        for bad in ["video:stacked:x.mp4", "video:two-files:l.avi", "video:top-bottom:", "video:"] {
            let e = VideoSpec::parse(bad).unwrap().unwrap_err().to_string();
            assert!(e.contains(bad) && e.contains("video:top-bottom:FILE"), "{e}");
        }
    }
}
