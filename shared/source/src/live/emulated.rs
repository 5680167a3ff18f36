//! An emulated capture device: replays a folder of stereo pairs as a grabber delivers them — at its own
//! clock, in its pixel format (YUYV, NV12 or MJPEG), both views in one image or one view per device — so the
//! live path is tested end to end on machines without hardware.
//!
//! It behaves as a V4L2 device does where that matters: a few buffers (`BUFFERS`) cycle between the device
//! and its reader; when the reader has not given one back by the time a frame is captured, the device
//! drops that frame and its sequence number is skipped; a frame is stamped with its capture time on the
//! monotonic clock; the reader is woken through a file descriptor it can wait on.

use std::io::Write;
use std::os::fd::{AsFd, BorrowedFd};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, sync_channel};
use std::thread::JoinHandle;

use super::convert::{DeviceFormat, PixelFormat, nv12_of_rgb, yuyv_of_rgb};
use super::{LiveArrangement, LiveError, Pending, Take};
use crate::source::Sequence;

/// Buffers cycling between device and reader (V4L2 drivers default to 2–4; UVC's to 4).
const BUFFERS: usize = 4;

/// Which views one emulated device delivers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Views {
    /// Both, arranged in one image.
    Both(LiveArrangement),
    Left,
    Right,
}

enum Message {
    Frame { data: Vec<u8>, sequence: u64, t_capture_ns: u64 },
    End,
    Failed(String),
}

#[derive(Debug)]
pub struct EmulatedDevice {
    format: DeviceFormat,
    filled: Receiver<Message>,
    free: SyncSender<Vec<u8>>,
    wake: UnixStream,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    ended: bool,
    t_start_ns: u64,
}

impl std::fmt::Debug for Message {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Message::Frame { sequence, .. } => write!(f, "Frame({sequence})"),
            Message::End => f.write_str("End"),
            Message::Failed(e) => write!(f, "Failed({e})"),
        }
    }
}

impl EmulatedDevice {
    /// Starts the device on `sequence`'s frames, the first captured at `t_start_ns` and the others `1/rate_hz`
    /// apart.
    pub fn start(
        sequence: &Sequence,
        views: Views,
        pixel: PixelFormat,
        rate_hz: f64,
        t_start_ns: u64,
    ) -> Result<Self, LiveError> {
        if sequence.video.is_some() {
            return Err(LiveError::Spec(format!(
                "{}: the emulated device replays folders of image pairs, not videos",
                sequence.root.display()
            )));
        }
        let (w, h) = (sequence.width, sequence.height);
        let (width, height) = match views {
            Views::Both(LiveArrangement::SideBySide) => (2 * w, h),
            Views::Both(LiveArrangement::TopBottom) => (w, 2 * h),
            _ => (w, h),
        };
        let format = DeviceFormat::packed(width, height, pixel);
        let (align_x, align_y) = pixel.alignment();
        if w % align_x != 0 || h % align_y != 0 {
            return Err(LiveError::Spec(format!("{pixel:?} needs views of even size, the frames are {w}×{h}")));
        }
        let (filled_tx, filled) = sync_channel(BUFFERS + 1);
        let (free, free_rx) = sync_channel(BUFFERS);
        for _ in 0..BUFFERS {
            let _ = free.try_send(Vec::with_capacity(format.frame_len().max(1 << 16)));
        }
        let (wake, device_wake) = UnixStream::pair().map_err(|e| LiveError::Spec(format!("a wake-up socket: {e}")))?;
        for s in [&wake, &device_wake] {
            s.set_nonblocking(true).map_err(|e| LiveError::Spec(format!("a wake-up socket: {e}")))?;
        }
        let stop = Arc::new(AtomicBool::new(false));
        let device = Device {
            pairs: sequence.frames.iter().map(|f| (f.left.clone(), f.right.clone())).collect(),
            views,
            format,
            period_ns: 1e9 / rate_hz,
            t_start_ns,
            filled: filled_tx,
            free: free_rx,
            wake: device_wake,
            stop: stop.clone(),
        };
        let thread = std::thread::Builder::new()
            .name("emulated-device".into())
            .spawn(move || device.run())
            .map_err(|e| LiveError::Spec(format!("start the emulated device: {e}")))?;
        Ok(Self { format, filled, free, wake, stop, thread: Some(thread), ended: false, t_start_ns })
    }

    pub fn format(&self) -> DeviceFormat {
        self.format
    }

    pub fn fd(&self) -> BorrowedFd<'_> {
        self.wake.as_fd()
    }

    /// Takes every frame the device has filled, keeping the newest in `pending` and giving the buffers back.
    pub fn take(&mut self, pending: &mut Pending) -> Result<Take, LiveError> {
        let mut drain = [0u8; 64];
        while matches!(std::io::Read::read(&mut &self.wake, &mut drain), Ok(n) if n > 0) {}
        loop {
            match self.filled.try_recv() {
                Ok(Message::Frame { mut data, sequence, t_capture_ns }) => {
                    std::mem::swap(&mut data, &mut pending.data);
                    pending.fill(sequence, t_capture_ns, t_capture_ns.saturating_sub(self.t_start_ns));
                    let _ = self.free.try_send(data);
                }
                Ok(Message::End) | Err(TryRecvError::Disconnected) => self.ended = true,
                Ok(Message::Failed(e)) => return Err(LiveError::Spec(format!("the emulated device: {e}"))),
                Err(TryRecvError::Empty) => break,
            }
            if self.ended {
                break;
            }
        }
        Ok(match (pending.full, self.ended) {
            (true, _) => Take::Frame,
            (false, true) => Take::Ended,
            (false, false) => Take::Nothing,
        })
    }
}

impl Drop for EmulatedDevice {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// The device's side: its own thread, as a camera is its own hardware.
struct Device {
    pairs: Vec<(std::path::PathBuf, std::path::PathBuf)>,
    views: Views,
    format: DeviceFormat,
    period_ns: f64,
    t_start_ns: u64,
    filled: SyncSender<Message>,
    free: Receiver<Vec<u8>>,
    wake: UnixStream,
    stop: Arc<AtomicBool>,
}

impl Device {
    fn run(self) {
        let mut encoded = Vec::new();
        for (sequence, (left, right)) in self.pairs.iter().enumerate() {
            // The image is made before its capture time, so it is stamped exactly then (a camera's clock).
            if let Err(e) = self.encode(left, right, &mut encoded) {
                let _ = self.filled.send(Message::Failed(e));
                break;
            }
            let due_ns = self.t_start_ns + (sequence as f64 * self.period_ns) as u64;
            // The emulated sensor's clock: the thread sleeps until the frame's exposure ends.
            let now = bdis_ipc::monotonic_ns();
            if due_ns > now {
                std::thread::sleep(std::time::Duration::from_nanos(due_ns - now));
            }
            if self.stop.load(Ordering::Relaxed) {
                return;
            }
            // No buffer back from the reader: this frame is dropped, as a V4L2 driver drops it.
            let Ok(mut buffer) = self.free.try_recv() else { continue };
            buffer.clear();
            buffer.extend_from_slice(&encoded);
            let frame = Message::Frame { data: buffer, sequence: sequence as u64, t_capture_ns: due_ns };
            if self.filled.send(frame).is_err() {
                return;
            }
            let _ = (&self.wake).write(&[1]);
        }
        let _ = self.filled.send(Message::End);
        let _ = (&self.wake).write(&[1]);
    }

    /// The device image of one stereo pair, in the device's pixel format.
    fn encode(&self, left: &Path, right: &Path, out: &mut Vec<u8>) -> Result<(), String> {
        let load = |p: &Path| image::open(p).map(|i| i.to_rgb8()).map_err(|e| format!("{}: {e}", p.display()));
        let (width, height) = (self.format.width, self.format.height);
        let canvas = match self.views {
            Views::Left => load(left)?,
            Views::Right => load(right)?,
            Views::Both(arrangement) => {
                let (l, r) = (load(left)?, load(right)?);
                let mut canvas = image::RgbImage::new(width, height);
                let (x, y) = match arrangement {
                    LiveArrangement::SideBySide => (i64::from(l.width()), 0),
                    _ => (0, i64::from(l.height())),
                };
                image::imageops::replace(&mut canvas, &l, 0, 0);
                image::imageops::replace(&mut canvas, &r, x, y);
                canvas
            }
        };
        if canvas.dimensions() != (width, height) {
            return Err(format!(
                "{}: {}×{}, the device's images are {width}×{height}",
                left.display(),
                canvas.width(),
                canvas.height()
            ));
        }
        match self.format.pixel {
            PixelFormat::Yuyv => yuyv_of_rgb(&canvas, width, height, out),
            PixelFormat::Nv12 => nv12_of_rgb(&canvas, width, height, out),
            PixelFormat::Mjpeg => {
                out.clear();
                image::codecs::jpeg::JpegEncoder::new_with_quality(&mut *out, 95)
                    .encode(&canvas, width, height, image::ExtendedColorType::Rgb8)
                    .map_err(|e| e.to_string())?;
                // As UVC cameras send Motion-JPEG: without Huffman tables (the standard ones are meant).
                crate::jpeg::strip_huffman_tables(out);
            }
        }
        Ok(())
    }
}
