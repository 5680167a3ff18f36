//! Stereo image sequences on disk, checked completely before the first frame is published.
//!
//! Layouts:
//! * BDIS-SLAM / Hamlyn rectified: `SEQ/times.txt` + `SEQ/images_rectified/{left,right}/<n>.png`, n = 1, 2, …
//! * plain: `SEQ/left/` + `SEQ/right/` with the same file names (sorted numerically when every name is a number),
//!   `SEQ/times.txt` optional;
//! * KITTI odometry: `SEQ/image_0/` (left), `SEQ/image_1/` (right), `SEQ/times.txt`, `SEQ/calib.txt`;
//! * video: `video:top-bottom:FILE`, `video:side-by-side:FILE`, `video:two-files:LEFT,RIGHT` (see [`crate::video`]).

use std::path::{Path, PathBuf};

use bdis_core::{Distortion, StereoCamera};

use crate::video::{VideoError, VideoSource, VideoSpec};

#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    #[error("{path}: sequence folder not found")]
    MissingFolder { path: PathBuf },
    #[error(
        "{path}: not a stereo sequence (expected images_rectified/{{left,right}}/, left/ + right/, or image_0/ + image_1/)"
    )]
    UnknownLayout { path: PathBuf },
    #[error("{path}: cannot read: {detail}")]
    Io { path: PathBuf, detail: String },
    #[error("{path}: no images (.png, .jpg)")]
    NoImages { path: PathBuf },
    #[error("{path}: missing right image for {left}")]
    MissingRight { path: PathBuf, left: PathBuf },
    #[error("{path}: no left image for this right image")]
    ExtraRight { path: PathBuf },
    #[error("{path}: missing image (the sequence numbers run 1..={count})")]
    MissingNumbered { path: PathBuf, count: usize },
    #[error("{path}: unreadable image: {detail}")]
    UnreadableImage { path: PathBuf, detail: String },
    #[error("{right}: size {right_w}×{right_h} differs from the left image {left} ({left_w}×{left_h})")]
    SizeMismatch { left: PathBuf, right: PathBuf, left_w: u32, left_h: u32, right_w: u32, right_h: u32 },
    #[error("{path}: size {w}×{h} differs from the sequence's first image ({w0}×{h0})")]
    SizeChanges { path: PathBuf, w: u32, h: u32, w0: u32, h0: u32 },
    #[error("{path}: {lines} timestamps for {images} image pairs")]
    TimesCount { path: PathBuf, lines: usize, images: usize },
    #[error("{path}:{line}: `{text}` is not a timestamp in seconds")]
    TimesValue { path: PathBuf, line: usize, text: String },
    #[error("{path}:{line}: timestamp {t} goes back in time")]
    TimesOrder { path: PathBuf, line: usize, t: f64 },
    #[error("{path}: {field}: {detail}")]
    Calibration { path: PathBuf, field: String, detail: String },
    #[error(transparent)]
    Video(#[from] VideoError),
    #[error(
        "{path}: a video file; say how its views are arranged: video:top-bottom:{path}, video:side-by-side:{path}, or video:two-files:LEFT,RIGHT"
    )]
    VideoWithoutArrangement { path: PathBuf },
    #[error("--start {start}: the sequence has {count} frames")]
    StartBeyondEnd { start: usize, count: usize },
    #[error("{settings}: `{field}` is {expected} but the images are {actual} ({image})")]
    SettingsMismatch { settings: PathBuf, field: &'static str, expected: u32, actual: u32, image: PathBuf },
}

/// Which on-disk layout a sequence uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    Hamlyn,
    Plain,
    Kitti,
    /// A video file or two (decoded by ffmpeg); the entries' `left`/`right` are the files, `source_index` the
    /// frame number in them.
    Video(crate::video::Arrangement),
}

/// One stereo pair of a sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameEntry {
    pub left: PathBuf,
    pub right: PathBuf,
    /// The recording's timestamp in seconds, when the sequence has `times.txt`.
    pub t_source_s: Option<f64>,
    /// The image number (file stem) when it is a number, otherwise the position.
    pub source_index: u32,
}

/// A checked sequence: every pair exists, decodes its header, and has one size.
#[derive(Debug, Clone)]
pub struct Sequence {
    pub root: PathBuf,
    pub layout: Layout,
    pub frames: Vec<FrameEntry>,
    pub width: u32,
    pub height: u32,
    /// Calibration carried by the sequence itself (KITTI `calib.txt`).
    pub camera: Option<StereoCamera>,
    /// The video behind a [`Layout::Video`] sequence.
    pub video: Option<VideoSource>,
}

/// File extensions taken for a video given without its arrangement.
fn looks_like_video(path: &Path) -> bool {
    matches!(
        path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref(),
        Some("mp4" | "avi" | "mkv" | "mov" | "m4v" | "webm" | "y4m" | "mpg" | "mpeg" | "ts")
    )
}

fn is_image(path: &Path) -> bool {
    matches!(
        path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref(),
        Some("png") | Some("jpg") | Some("jpeg")
    )
}

/// Image files of a folder, sorted numerically when every stem is a number, else by name.
fn list_images(dir: &Path) -> Result<Vec<PathBuf>, SourceError> {
    let io = |e: std::io::Error| SourceError::Io { path: dir.to_path_buf(), detail: e.to_string() };
    let mut files = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(io)? {
        let path = entry.map_err(io)?.path();
        if path.is_file() && is_image(&path) {
            files.push(path);
        }
    }
    let number = |p: &PathBuf| p.file_stem().and_then(|s| s.to_str()).and_then(|s| s.parse::<u64>().ok());
    if files.iter().all(|p| number(p).is_some()) {
        files.sort_by_key(|p| number(p));
    } else {
        files.sort();
    }
    Ok(files)
}

fn image_size(path: &Path) -> Result<(u32, u32), SourceError> {
    let unreadable = |detail: String| SourceError::UnreadableImage { path: path.to_path_buf(), detail };
    image::ImageReader::open(path)
        .map_err(|e| unreadable(e.to_string()))?
        .with_guessed_format()
        .map_err(|e| unreadable(e.to_string()))?
        .into_dimensions()
        .map_err(|e| unreadable(e.to_string()))
}

/// Reads `times.txt`: one timestamp in seconds per non-empty line, non-decreasing.
pub fn read_times(path: &Path) -> Result<Vec<f64>, SourceError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SourceError::Io { path: path.to_path_buf(), detail: e.to_string() })?;
    parse_times(&text, path)
}

/// [`read_times`] on text already read; `path` names it in errors.
pub fn parse_times(text: &str, path: &Path) -> Result<Vec<f64>, SourceError> {
    let mut times = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        // Some recorders write `index time`; the time is the last column.
        let field = line.split_whitespace().last().unwrap_or(line);
        let t: f64 = field.parse().ok().filter(|t: &f64| t.is_finite()).ok_or_else(|| SourceError::TimesValue {
            path: path.to_path_buf(),
            line: i + 1,
            text: line.to_string(),
        })?;
        if times.last().is_some_and(|&prev| t < prev) {
            return Err(SourceError::TimesOrder { path: path.to_path_buf(), line: i + 1, t });
        }
        times.push(t);
    }
    Ok(times)
}

/// Reads KITTI's `calib.txt` (`P0:` and `P1:` 3×4 projection matrices): fx, fy, cx, cy from P0, bf = −P1[0,3].
pub fn read_kitti_calib(path: &Path) -> Result<StereoCamera, SourceError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SourceError::Io { path: path.to_path_buf(), detail: e.to_string() })?;
    parse_kitti_calib(&text, path)
}

/// [`read_kitti_calib`] on text already read; `path` names it in errors.
pub fn parse_kitti_calib(text: &str, path: &Path) -> Result<StereoCamera, SourceError> {
    let bad = |field: &str, detail: String| SourceError::Calibration {
        path: path.to_path_buf(),
        field: field.into(),
        detail,
    };
    let matrix = |name: &str| -> Result<[f64; 12], SourceError> {
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{name}:")))
            .ok_or_else(|| bad(name, "missing".into()))?;
        let values: Vec<f64> = line
            .split_once(':')
            .map(|(_, v)| v)
            .unwrap_or("")
            .split_whitespace()
            .map(|v| v.parse::<f64>().map_err(|_| bad(name, format!("`{v}` is not a number"))))
            .collect::<Result<_, _>>()?;
        let values: [f64; 12] =
            values.try_into().map_err(|v: Vec<f64>| bad(name, format!("{} values, expected 12", v.len())))?;
        if !values.iter().all(|v| v.is_finite()) {
            return Err(bad(name, "non-finite value".into()));
        }
        Ok(values)
    };
    let p0 = matrix("P0")?;
    let p1 = matrix("P1")?;
    let camera = StereoCamera {
        fx: p0[0],
        fy: p0[5],
        cx: p0[2],
        cy: p0[6],
        bf: -p1[3],
        distortion: Distortion::default(),
        width: None,
        height: None,
    };
    // Negated comparisons so that NaN is rejected too.
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    if !(camera.fx > 0.0 && camera.fy > 0.0) {
        return Err(bad("P0", format!("focal lengths must be > 0 (fx {}, fy {})", camera.fx, camera.fy)));
    }
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    if !(camera.bf > 0.0) {
        return Err(bad("P1", format!("−P1[0,3] = bf must be > 0, found {}", camera.bf)));
    }
    Ok(camera)
}

impl Sequence {
    /// Finds the layout of `root`, lists and pairs its images, checks every image header and `times.txt`.
    pub fn open(root: &Path) -> Result<Self, SourceError> {
        if let Some(spec) = root.to_str().and_then(VideoSpec::parse) {
            return Self::open_video(&spec?);
        }
        if root.is_file() && looks_like_video(root) {
            return Err(SourceError::VideoWithoutArrangement { path: root.to_path_buf() });
        }
        if !root.is_dir() {
            return Err(SourceError::MissingFolder { path: root.to_path_buf() });
        }
        let (layout, left_dir, right_dir) = if root.join("images_rectified/left").is_dir() {
            (Layout::Hamlyn, root.join("images_rectified/left"), root.join("images_rectified/right"))
        } else if root.join("image_0").is_dir() {
            (Layout::Kitti, root.join("image_0"), root.join("image_1"))
        } else if root.join("left").is_dir() {
            (Layout::Plain, root.join("left"), root.join("right"))
        } else {
            return Err(SourceError::UnknownLayout { path: root.to_path_buf() });
        };
        if !right_dir.is_dir() {
            return Err(SourceError::MissingFolder { path: right_dir });
        }
        let lefts = list_images(&left_dir)?;
        if lefts.is_empty() {
            return Err(SourceError::NoImages { path: left_dir });
        }
        let mut frames = Vec::with_capacity(lefts.len());
        match layout {
            Layout::Hamlyn => {
                // 1-based and consecutive: a gap is a missing image, not a shorter sequence.
                let count = lefts.len();
                let ext =
                    lefts[0].extension().map(|e| e.to_string_lossy().into_owned()).unwrap_or_else(|| "png".into());
                for n in 1..=count {
                    let name = format!("{n}.{ext}");
                    let (left, right) = (left_dir.join(&name), right_dir.join(&name));
                    if !left.is_file() {
                        return Err(SourceError::MissingNumbered { path: left, count });
                    }
                    if !right.is_file() {
                        return Err(SourceError::MissingRight { path: right, left });
                    }
                    frames.push(FrameEntry { left, right, t_source_s: None, source_index: n as u32 });
                }
            }
            Layout::Plain | Layout::Kitti | Layout::Video(_) => {
                for (i, left) in lefts.iter().enumerate() {
                    let Some(name) = left.file_name() else { continue };
                    let right = right_dir.join(name);
                    if !right.is_file() {
                        return Err(SourceError::MissingRight { path: right, left: left.clone() });
                    }
                    let source_index = left
                        .file_stem()
                        .and_then(|s| s.to_str())
                        .and_then(|s| s.parse::<u32>().ok())
                        .unwrap_or(i as u32);
                    frames.push(FrameEntry { left: left.clone(), right, t_source_s: None, source_index });
                }
                // A right image with no left partner means the folders disagree; say so rather than skip it.
                for right in list_images(&right_dir)? {
                    if let Some(name) = right.file_name()
                        && !left_dir.join(name).is_file()
                    {
                        return Err(SourceError::ExtraRight { path: right });
                    }
                }
            }
        }

        let times_path = root.join("times.txt");
        if times_path.is_file() {
            let times = read_times(&times_path)?;
            if times.len() != frames.len() {
                return Err(SourceError::TimesCount { path: times_path, lines: times.len(), images: frames.len() });
            }
            for (f, t) in frames.iter_mut().zip(times) {
                f.t_source_s = Some(t);
            }
        } else if layout == Layout::Kitti {
            return Err(SourceError::Io { path: times_path, detail: "KITTI sequences need times.txt".into() });
        }

        let camera = if layout == Layout::Kitti {
            let calib = root.join("calib.txt");
            calib.is_file().then(|| read_kitti_calib(&calib)).transpose()?
        } else {
            None
        };

        let (width, height) = image_size(&frames[0].left)?;
        for f in &frames {
            let (lw, lh) = image_size(&f.left)?;
            let (rw, rh) = image_size(&f.right)?;
            if (lw, lh) != (rw, rh) {
                return Err(SourceError::SizeMismatch {
                    left: f.left.clone(),
                    right: f.right.clone(),
                    left_w: lw,
                    left_h: lh,
                    right_w: rw,
                    right_h: rh,
                });
            }
            if (lw, lh) != (width, height) {
                return Err(SourceError::SizeChanges { path: f.left.clone(), w: lw, h: lh, w0: width, h0: height });
            }
        }
        Ok(Self { root: root.to_path_buf(), layout, frames, width, height, camera, video: None })
    }

    /// A video source: its frames with the container's timestamps, numbered from the file's first frame.
    pub fn open_video(spec: &VideoSpec) -> Result<Self, SourceError> {
        let video = VideoSource::open(spec)?;
        let frames = video
            .timestamps_s
            .iter()
            .enumerate()
            .map(|(i, &t)| FrameEntry {
                left: spec.left_file().to_path_buf(),
                right: spec.right_file().to_path_buf(),
                t_source_s: Some(t),
                source_index: i as u32,
            })
            .collect();
        Ok(Self {
            root: spec.left_file().to_path_buf(),
            layout: Layout::Video(spec.arrangement),
            frames,
            width: video.width,
            height: video.height,
            camera: None,
            video: Some(video),
        })
    }

    /// Drops the first `start` frames (`--start`); a video then starts decoding at that frame.
    pub fn skip(&mut self, start: usize) -> Result<(), SourceError> {
        if start >= self.frames.len() {
            return Err(SourceError::StartBeyondEnd { start, count: self.frames.len() });
        }
        self.frames.drain(..start);
        Ok(())
    }

    /// The sequence as another process is given it: the folder's absolute path, or the video spec with
    /// absolute file names.
    pub fn argument(&self) -> Result<String, SourceError> {
        match &self.video {
            Some(v) => Ok(v.spec.to_absolute_argument()?),
            None => std::fs::canonicalize(&self.root)
                .map(|p| p.display().to_string())
                .map_err(|e| SourceError::Io { path: self.root.clone(), detail: e.to_string() }),
        }
    }

    /// Checks the sequence against a calibration's image size, when the calibration states one.
    pub fn check_camera(&self, camera: &StereoCamera, settings_path: &Path) -> Result<(), SourceError> {
        match size_mismatch(camera, (self.width, self.height)) {
            Some((field, expected, actual)) => Err(SourceError::SettingsMismatch {
                settings: settings_path.to_path_buf(),
                field,
                expected,
                actual,
                image: self.frames[0].left.clone(),
            }),
            None => Ok(()),
        }
    }

    pub fn len(&self) -> usize {
        self.frames.len()
    }

    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

/// The first of `Camera.width` / `Camera.height` that a camera states and that differs from `size`: the field,
/// the camera's value and the size's.
pub fn size_mismatch(camera: &StereoCamera, size: (u32, u32)) -> Option<(&'static str, u32, u32)> {
    [("Camera.width", camera.width, size.0), ("Camera.height", camera.height, size.1)]
        .into_iter()
        .find_map(|(field, expected, actual)| expected.filter(|&e| e != actual).map(|e| (field, e, actual)))
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Tmp(PathBuf);
    impl Drop for Tmp {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
    fn tmp(tag: &str) -> Tmp {
        let p = std::env::temp_dir().join(format!("bdis-src-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        Tmp(p)
    }
    fn img(path: &Path, w: u32, h: u32) {
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        image::GrayImage::new(w, h).save(path).unwrap();
    }

    #[test]
    fn hamlyn_layout_is_one_based_with_times() {
        let t = tmp("hamlyn");
        for n in 1..=3 {
            img(&t.0.join(format!("images_rectified/left/{n}.png")), 8, 6);
            img(&t.0.join(format!("images_rectified/right/{n}.png")), 8, 6);
        }
        std::fs::write(t.0.join("times.txt"), "0.0\n0.04\n0.08\n").unwrap();
        let s = Sequence::open(&t.0).unwrap();
        assert_eq!(s.layout, Layout::Hamlyn);
        assert_eq!(s.frames.iter().map(|f| f.source_index).collect::<Vec<_>>(), vec![1, 2, 3]);
        assert_eq!(s.frames[2].t_source_s, Some(0.08));
        // A gap in the numbering is a missing image, not a shorter sequence.
        std::fs::rename(t.0.join("images_rectified/left/2.png"), t.0.join("images_rectified/left/9.png")).unwrap();
        let e = Sequence::open(&t.0).unwrap_err().to_string();
        assert!(e.ends_with("images_rectified/left/2.png: missing image (the sequence numbers run 1..=3)"), "{e}");
    }

    #[test]
    fn kitti_layout_reads_calib_and_needs_times() {
        let t = tmp("kitti");
        for n in 0..2 {
            img(&t.0.join(format!("image_0/{n:06}.png")), 8, 6);
            img(&t.0.join(format!("image_1/{n:06}.png")), 8, 6);
        }
        let e = Sequence::open(&t.0).unwrap_err().to_string();
        assert!(e.contains("times.txt: cannot read: KITTI sequences need times.txt"), "{e}");
        std::fs::write(t.0.join("times.txt"), "0.000000e+00\n1.036400e-01\n").unwrap();
        std::fs::write(
            t.0.join("calib.txt"),
            "P0: 718.856 0 607.1928 0 0 718.856 185.2157 0 0 0 1 0\nP1: 718.856 0 607.1928 -386.1448 0 718.856 185.2157 0 0 0 1 0\n",
        )
        .unwrap();
        let s = Sequence::open(&t.0).unwrap();
        assert_eq!(s.layout, Layout::Kitti);
        let cam = s.camera.unwrap();
        assert_eq!((cam.fx, cam.cx, cam.cy, cam.bf), (718.856, 607.1928, 185.2157, 386.1448));
        assert_eq!(s.frames[1].t_source_s, Some(0.10364));
        std::fs::write(t.0.join("calib.txt"), "P0: 718.856 0 607.1928 0 0 718.856 185.2157 0 0 0 1 0\n").unwrap();
        let e = Sequence::open(&t.0).unwrap_err().to_string();
        assert!(e.ends_with("calib.txt: P1: missing"), "{e}");
    }

    #[test]
    fn plain_layout_sorts_numerically_and_rejects_unpaired_images() {
        let t = tmp("plain");
        for n in [1, 51, 101, 1001] {
            img(&t.0.join(format!("left/{n}.png")), 8, 6);
            img(&t.0.join(format!("right/{n}.png")), 8, 6);
        }
        let s = Sequence::open(&t.0).unwrap();
        assert_eq!(s.frames.iter().map(|f| f.source_index).collect::<Vec<_>>(), vec![1, 51, 101, 1001]);
        img(&t.0.join("right/7.png"), 8, 6);
        let e = Sequence::open(&t.0).unwrap_err().to_string();
        assert!(e.ends_with("right/7.png: no left image for this right image"), "{e}");
        std::fs::remove_file(t.0.join("right/7.png")).unwrap();
        std::fs::write(t.0.join("times.txt"), "0\n1\nx\n3\n").unwrap();
        let e = Sequence::open(&t.0).unwrap_err().to_string();
        assert!(e.ends_with("times.txt:3: `x` is not a timestamp in seconds"), "{e}");
        std::fs::write(t.0.join("times.txt"), "0\n2\n1\n3\n").unwrap();
        let e = Sequence::open(&t.0).unwrap_err().to_string();
        assert!(e.ends_with("times.txt:3: timestamp 1 goes back in time"), "{e}");
    }
}
