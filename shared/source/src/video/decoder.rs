//! Decoding a [`VideoSource`]: ffmpeg children writing raw RGB frames on pipes, each frame numbered by the time
//! ffmpeg's `showinfo` reports for it, then split into the packed frame layout.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Read};
use std::mem::MaybeUninit;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStderr, ChildStdout, Command, Stdio};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

use bdis_ipc::FrameLayout;

use super::native::{self, NativeReader};
use super::y4m::PlaneLayout;
use super::{Arrangement, VideoError, VideoSource};
use bdis_core::pixel::gray_of;

/// One file's decoder: the container read here, or an ffmpeg child.
enum Decoding {
    Native(NativeReader),
    Ffmpeg(FfmpegDecoding),
}

impl Decoding {
    fn start(path: &Path, first_frame: u64, timestamps_s: &[f64]) -> Result<Self, VideoError> {
        Ok(match native::index(path)? {
            Some(index) => {
                let mut reader = NativeReader::open(path, index)?;
                reader.seek_to(first_frame, timestamps_s);
                Decoding::Native(reader)
            }
            None => Decoding::Ffmpeg(FfmpegDecoding::start(path, first_frame, timestamps_s.to_vec())?),
        })
    }

    /// Reads the next frame into `buf` and returns its frame number (by its time). `Ok(None)` at the end.
    fn read_frame(&mut self, buf: &mut [u8], timestamps_s: &[f64]) -> Result<Option<u64>, VideoError> {
        match self {
            Decoding::Native(reader) => reader.read_frame(buf, timestamps_s),
            Decoding::Ffmpeg(child) => child.read_frame(buf),
        }
    }

    /// Why the file ended before its last frame, for [`VideoError::EndedEarly`].
    fn ended(&mut self, decoded: u64, expected: usize) -> VideoError {
        match self {
            Decoding::Native(reader) => {
                VideoError::EndedEarly { path: reader.path().to_path_buf(), decoded, expected, stderr: String::new() }
            }
            Decoding::Ffmpeg(child) => {
                VideoError::EndedEarly { path: child.path.clone(), decoded, expected, stderr: child.last_words() }
            }
        }
    }
}

/// One ffmpeg child decoding one file to raw RGB on its stdout.
struct FfmpegDecoding {
    path: PathBuf,
    child: Child,
    stdout: ChildStdout,
    /// Each decoded frame's presentation time, from ffmpeg's `showinfo` on stderr. A decoder drops a frame it
    /// cannot decode; the times say which frame each one on the pipe is, so none is mislabelled after a drop.
    pts_s: Receiver<f64>,
    /// The stderr reader: its result is ffmpeg's last message that was not a frame's time.
    stderr: Option<std::thread::JoinHandle<String>>,
    /// The frame times of this file (from ffprobe), to number each frame by its time.
    timestamps_s: Vec<f64>,
}

/// Reads ffmpeg's stderr: frame times go to `times`, the last other line is kept for an error. One line
/// buffer, reused; the channel is bounded (and so preallocated): a warmed-up frame allocates nothing here.
fn read_stderr(stderr: ChildStderr, times: SyncSender<f64>) -> String {
    let mut reader = BufReader::new(stderr);
    let mut line = String::with_capacity(512);
    let mut last = String::new();
    loop {
        line.clear();
        match reader.read_line(&mut line) {
            Ok(0) | Err(_) => return last,
            Ok(_) => {}
        }
        if line.contains("Parsed_showinfo") {
            let t = line.split("pts_time:").nth(1).and_then(|rest| rest.split_whitespace().next());
            if let Some(t) = t.and_then(|t| t.parse::<f64>().ok())
                && times.send(t).is_err()
            {
                return last;
            }
        } else if !line.trim().is_empty() {
            // At info level ffmpeg also describes the streams; an error line, once seen, is what is kept.
            let error = |l: &str| l.contains("rror") || l.contains("nvalid") || l.contains("corrupt");
            if error(&line) || !error(&last) {
                last.clear();
                last.push_str(line.trim());
            }
        }
    }
}

impl FfmpegDecoding {
    fn start(path: &Path, first_frame: u64, timestamps_s: Vec<f64>) -> Result<Self, VideoError> {
        let mut command = Command::new("ffmpeg");
        command.args(["-nostdin", "-hide_banner", "-nostats", "-loglevel", "info", "-i"]).arg(path);
        // Frame-exact skipping (decoded and dropped inside ffmpeg, never piped), then each frame's time.
        let filters = if first_frame > 0 {
            format!("trim=start_frame={first_frame},showinfo=checksum=0")
        } else {
            "showinfo=checksum=0".to_string()
        };
        // Passthrough: every decoded frame once, none duplicated or dropped to fit a constant rate.
        command.args(["-map", "0:v:0", "-vf", &filters, "-fps_mode", "passthrough"]);
        command.args(["-f", "rawvideo", "-pix_fmt", "rgb24", "pipe:1"]);
        let mut child = command
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| VideoError::Tool { tool: "ffmpeg", detail: e.to_string() })?;
        let pipe = |what: &str| VideoError::Pipe { path: path.to_path_buf(), detail: format!("no {what} pipe") };
        let stdout = child.stdout.take().ok_or_else(|| pipe("stdout"))?;
        let stderr = child.stderr.take().ok_or_else(|| pipe("stderr"))?;
        let (tx, pts_s) = sync_channel(64);
        let stderr = std::thread::Builder::new()
            .name("ffmpeg-stderr".into())
            .spawn(move || read_stderr(stderr, tx))
            .map_err(|e| VideoError::Tool { tool: "ffmpeg", detail: format!("stderr reader: {e}") })?;
        Ok(Self { path: path.to_path_buf(), child, stdout, pts_s, stderr: Some(stderr), timestamps_s })
    }

    /// Reads the next frame into `buf` and returns its frame number (by its time). `Ok(None)` at the end.
    fn read_frame(&mut self, buf: &mut [u8]) -> Result<Option<u64>, VideoError> {
        let mut filled = 0;
        while filled < buf.len() {
            match self.stdout.read(&mut buf[filled..]) {
                Ok(0) if filled == 0 => return Ok(None),
                Ok(0) => {
                    return Err(VideoError::Pipe {
                        path: self.path.clone(),
                        detail: format!("a frame cut short ({filled} of {} bytes){}", buf.len(), self.last_words()),
                    });
                }
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(VideoError::Pipe { path: self.path.clone(), detail: e.to_string() }),
            }
        }
        let t = self.pts_s.recv().map_err(|_| VideoError::Pipe {
            path: self.path.clone(),
            detail: "ffmpeg gave a frame without its time".into(),
        })?;
        // The nearest frame time; a decoded time matches one of the container's to well under a frame.
        let i = self.timestamps_s.partition_point(|&x| x < t);
        let nearest = [i.checked_sub(1), (i < self.timestamps_s.len()).then_some(i)]
            .into_iter()
            .flatten()
            .min_by(|&a, &b| (self.timestamps_s[a] - t).abs().total_cmp(&(self.timestamps_s[b] - t).abs()));
        nearest.map(|n| Some(n as u64)).ok_or_else(|| VideoError::Pipe {
            path: self.path.clone(),
            detail: format!("a frame at {t} s, which the container does not list"),
        })
    }

    /// ffmpeg's last message, for an error that ends the stream.
    fn last_words(&mut self) -> String {
        let _ = self.child.wait();
        let text = self.stderr.take().and_then(|h| h.join().ok()).unwrap_or_default();
        if text.is_empty() { String::new() } else { format!(" (ffmpeg: {text})") }
    }
}

impl Drop for FfmpegDecoding {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A decoded frame kept for a replay, with its frame number.
struct Kept {
    frame: u64,
    /// The left file's frame, and (two files) the right file's: RGB, or a Y4M's planes as stored (`planes`).
    left: Vec<u8>,
    right: Vec<u8>,
    planes: Option<PlaneLayout>,
}

/// Frames kept for replays: a consumer that replaces a crashed one is sent again the frames its predecessor
/// held, which on demand are the last one or two. Further back, decoding restarts at the frame.
const KEPT_FRAMES: usize = 4;

/// Decodes a [`VideoSource`] frame by frame into frame payloads. Buffers are allocated once (the first
/// frames); a warmed-up frame allocates nothing.
pub struct VideoDecoder {
    source: VideoSource,
    decoding: Vec<Decoding>,
    /// The most recent frames, oldest first; the oldest buffer is reused for the next frame.
    kept: VecDeque<Kept>,
    /// The frame the decoders are at (the next to come off the pipes, unless the decoder drops it).
    next_frame: u64,
}

impl std::fmt::Debug for VideoDecoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("VideoDecoder").field("spec", &self.source.spec).finish_non_exhaustive()
    }
}

impl VideoDecoder {
    pub fn new(source: &VideoSource) -> Self {
        Self { source: source.clone(), decoding: Vec::new(), kept: VecDeque::with_capacity(KEPT_FRAMES), next_frame: 0 }
    }

    fn file_frame_bytes(&self) -> usize {
        let (w, h) = (self.source.width as usize, self.source.height as usize);
        match self.source.spec.arrangement {
            Arrangement::TwoFiles => w * h * 3,
            _ => 2 * w * h * 3,
        }
    }

    /// Starts the decoder(s) at `frame`: before the first frame is due, so ffmpeg's start-up is not a frame's
    /// latency; and again when a replay goes back further than the kept frames.
    pub fn start_at(&mut self, frame: u64) -> Result<(), VideoError> {
        // A file read here is indexed: going back is a seek, not a new decoder.
        if !self.decoding.is_empty() && self.decoding.iter().all(|d| matches!(d, Decoding::Native(_))) {
            for d in &mut self.decoding {
                if let Decoding::Native(reader) = d {
                    reader.seek_to(frame, &self.source.timestamps_s);
                }
            }
            self.next_frame = frame;
            return Ok(());
        }
        self.decoding.clear();
        for f in &self.source.spec.files {
            self.decoding.push(Decoding::start(f, frame, &self.source.timestamps_s)?);
        }
        self.next_frame = frame;
        Ok(())
    }

    /// Decodes the next frame off the pipe(s) into a kept slot; with two files, both at the same frame (one
    /// that a decoder dropped in one file is passed over in the other).
    fn decode_next(&mut self) -> Result<u64, VideoError> {
        let mut slot = match self.kept.len() {
            KEPT_FRAMES => self.kept.pop_front(),
            _ => None,
        }
        .unwrap_or(Kept { frame: 0, left: Vec::new(), right: Vec::new(), planes: None });
        if let Some(planes) = self.planar() {
            return self.decode_planes(slot, planes);
        }
        slot.planes = None;
        let bytes = self.file_frame_bytes();
        slot.left.resize(bytes, 0);
        let expected = self.source.timestamps_s.len();
        let ended = |d: &mut Decoding, decoded: u64| d.ended(decoded, expected);
        let times = &self.source.timestamps_s;
        let next = self.next_frame;
        let (first, rest) = self.decoding.split_first_mut().ok_or_else(|| VideoError::Pipe {
            path: self.source.spec.left_file().to_path_buf(),
            detail: "no decoder running".into(),
        })?;
        let mut frame = first.read_frame(&mut slot.left, times)?.ok_or_else(|| ended(first, next))?;
        if let Some(second) = rest.first_mut() {
            slot.right.resize(bytes, 0);
            let mut right = second.read_frame(&mut slot.right, times)?.ok_or_else(|| ended(second, next))?;
            while right != frame {
                if right < frame {
                    right = second.read_frame(&mut slot.right, times)?.ok_or_else(|| ended(second, next))?;
                } else {
                    frame = first.read_frame(&mut slot.left, times)?.ok_or_else(|| ended(first, next))?;
                }
            }
        }
        slot.frame = frame;
        self.next_frame = frame + 1;
        self.kept.push_back(slot);
        Ok(frame)
    }

    /// Where each view starts in its file's frame: (left, right).
    fn view_origins(&self) -> ((u32, u32), (u32, u32)) {
        let (w, h) = (self.source.width, self.source.height);
        match self.source.spec.arrangement {
            Arrangement::TopBottom => ((0, 0), (0, h)),
            Arrangement::SideBySide => ((0, 0), (w, 0)),
            Arrangement::TwoFiles => ((0, 0), (0, 0)),
        }
    }

    /// The planes every file is read as, when all are Y4M files read here whose views have their own chroma
    /// samples: their frames are then kept as stored and converted straight into the packed layout (grey of
    /// both views, colour of the left only). `None`: frames are kept as RGB.
    fn planar(&self) -> Option<PlaneLayout> {
        let mut planes = None;
        for d in &self.decoding {
            let Decoding::Native(reader) = d else { return None };
            let p = reader.planes()?;
            if planes.is_some_and(|q| q != p) {
                return None;
            }
            planes = Some(p);
        }
        let p = planes?;
        let ((lx, ly), (rx, ry)) = self.view_origins();
        (p.view_aligned(lx, ly) && p.view_aligned(rx, ry)).then_some(p)
    }

    /// [`VideoDecoder::decode_next`] for Y4M files read as planes.
    fn decode_planes(&mut self, mut slot: Kept, planes: PlaneLayout) -> Result<u64, VideoError> {
        let expected = self.source.timestamps_s.len();
        let times = &self.source.timestamps_s;
        let next = self.next_frame;
        let mut readers = self.decoding.iter_mut().filter_map(|d| match d {
            Decoding::Native(reader) => Some(reader),
            Decoding::Ffmpeg(_) => None,
        });
        let ended = |r: &NativeReader| VideoError::EndedEarly {
            path: r.path().to_path_buf(),
            decoded: next,
            expected,
            stderr: String::new(),
        };
        let first = readers.next().ok_or_else(|| VideoError::Pipe {
            path: self.source.spec.left_file().to_path_buf(),
            detail: "no decoder running".into(),
        })?;
        let mut frame = first.read_planes(&mut slot.left, times)?.ok_or_else(|| ended(first))?;
        if let Some(second) = readers.next() {
            let mut right = second.read_planes(&mut slot.right, times)?.ok_or_else(|| ended(second))?;
            while right != frame {
                if right < frame {
                    right = second.read_planes(&mut slot.right, times)?.ok_or_else(|| ended(second))?;
                } else {
                    frame = first.read_planes(&mut slot.left, times)?.ok_or_else(|| ended(first))?;
                }
            }
        }
        slot.frame = frame;
        slot.planes = Some(planes);
        self.next_frame = frame + 1;
        self.kept.push_back(slot);
        Ok(frame)
    }

    /// Writes frame `frame` (numbered from the file's first) into `payload`, every byte of `layout`. A frame
    /// the decoder could not decode (a corrupt stretch of the file) is [`VideoError::FrameLost`]; the frames
    /// after it are read as usual.
    pub fn read_into(
        &mut self,
        frame: u64,
        layout: &FrameLayout,
        payload: &mut [MaybeUninit<u8>],
    ) -> Result<(), VideoError> {
        if !self.kept.iter().any(|k| k.frame == frame) {
            if self.decoding.is_empty() || self.next_frame > frame {
                self.start_at(frame)?;
            }
            while self.decode_next()? < frame {}
        }
        let Some(kept) = self.kept.iter().find(|k| k.frame == frame) else {
            let t = self.source.timestamps_s.get(frame as usize).copied().unwrap_or(f64::NAN);
            return Err(VideoError::FrameLost { path: self.source.spec.left_file().to_path_buf(), frame, t });
        };
        match kept.planes {
            Some(planes) => {
                let (w, h) = (layout.width as usize, layout.height as usize);
                let n = w * h;
                let (left_gray, rest) = payload.split_at_mut(n);
                let (right_gray, rgb) = rest.split_at_mut(n);
                let ((lx, ly), (rx, ry)) = self.view_origins();
                let right_planes = match self.source.spec.arrangement {
                    Arrangement::TwoFiles => &kept.right,
                    _ => &kept.left,
                };
                planes.view_into(&kept.left, (lx as usize, ly as usize, w, h), left_gray, Some(&mut rgb[..3 * n]));
                planes.view_into(right_planes, (rx as usize, ry as usize, w, h), right_gray, None);
            }
            None => split_into(self.source.spec.arrangement, &kept.left, &kept.right, layout, payload),
        }
        Ok(())
    }
}

/// Writes the packed layout (left grey, right grey, left RGB) from a decoded RGB frame: both views in `frame`
/// (stacked or side by side), or the left in `frame` and the right in `right` (two files).
pub fn split_into(
    arrangement: Arrangement,
    frame: &[u8],
    right_frame: &[u8],
    layout: &FrameLayout,
    payload: &mut [MaybeUninit<u8>],
) {
    let (w, h) = (layout.width as usize, layout.height as usize);
    let n = w * h;
    let (left_gray, rest) = payload.split_at_mut(n);
    let (right_gray, rgb) = rest.split_at_mut(n);
    let rgb = &mut rgb[..3 * n];
    // Where row y of each view starts in its source buffer, in bytes: (left, right).
    let row = 3 * w;
    let starts = |y: usize| match arrangement {
        Arrangement::TopBottom => (y * row, (y + h) * row),
        Arrangement::SideBySide => (2 * y * row, (2 * y + 1) * row),
        Arrangement::TwoFiles => (y * row, y * row),
    };
    let right_src = if arrangement == Arrangement::TwoFiles { right_frame } else { frame };
    for y in 0..h {
        let (l0, r0) = starts(y);
        let l = &frame[l0..l0 + row];
        let r = &right_src[r0..r0 + row];
        let out = y * w;
        for x in 0..w {
            let (lr, lg, lb) = (l[3 * x], l[3 * x + 1], l[3 * x + 2]);
            left_gray[out + x].write(gray_of(lr, lg, lb));
            rgb[3 * (out + x)].write(lr);
            rgb[3 * (out + x) + 1].write(lg);
            rgb[3 * (out + x) + 2].write(lb);
            right_gray[out + x].write(gray_of(r[3 * x], r[3 * x + 1], r[3 * x + 2]));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn views_split_by_arrangement() {
        // 2×1 views; pixel value = 10·view + x, grey sources so grey = value.
        let px = |v: u8| [v, v, v];
        let layout = FrameLayout::packed(2, 1).unwrap();
        let check = |arr: Arrangement, frame: Vec<u8>, right: Vec<u8>| {
            let mut out = vec![MaybeUninit::new(0u8); layout.payload_len()];
            split_into(arr, &frame, &right, &layout, &mut out);
            let b: Vec<u8> = out.iter().map(|b| unsafe { b.assume_init() }).collect();
            assert_eq!(&b[..4], &[0, 1, 10, 11], "{arr:?}");
            assert_eq!(&b[4..10], &[0, 0, 0, 1, 1, 1], "{arr:?}");
        };
        check(Arrangement::TopBottom, [px(0), px(1), px(10), px(11)].concat(), vec![]);
        check(Arrangement::SideBySide, [px(0), px(1), px(10), px(11)].concat(), vec![]);
        check(Arrangement::TwoFiles, [px(0), px(1)].concat(), [px(10), px(11)].concat());
    }
}
