//! A V4L2 capture device (UVC grabbers and cameras), through `linuxvideo`: pure Rust over the kernel's ioctls,
//! mmap'ed buffers, no libv4l and no build-time bindings.
//!
//! The device keeps the format it was set to (`v4l2-ctl --set-fmt-video=width=…,height=…,pixelformat=YUYV`):
//! a console's grabber is configured once for its input signal, and guessing a mode here could pick one
//! the signal does not have. Only what bdis-slam cannot read is refused.
//!
//! Not tested on a device on the machines this was written on (no hardware, and v4l2loopback is a kernel
//! module that cannot be loaded there): everything above the device is tested through the emulated device.

use std::os::fd::{AsFd, BorrowedFd};
use std::path::{Path, PathBuf};

use linuxvideo::format::Format;
use linuxvideo::stream::ReadStream;
use linuxvideo::{BufType, Device};

use super::convert::{DeviceFormat, PixelFormat};
use super::{LiveError, Pending, Take};

pub struct V4l2Device {
    path: PathBuf,
    stream: ReadStream,
    format: DeviceFormat,
    next_sequence: u64,
    t_first_ns: Option<u64>,
}

impl std::fmt::Debug for V4l2Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("V4l2Device").field("path", &self.path).field("format", &self.format).finish_non_exhaustive()
    }
}

impl V4l2Device {
    pub fn open(path: &Path) -> Result<Self, LiveError> {
        let io = |what: &'static str| {
            let path = path.to_path_buf();
            move |e: std::io::Error| LiveError::Device { path: path.clone(), what, detail: e.to_string() }
        };
        if !path.exists() {
            return Err(LiveError::Device { path: path.into(), what: "open", detail: "no such device".into() });
        }
        let device = Device::open(path).map_err(io("open"))?;
        let caps = device.capabilities().map_err(io("query its capabilities"))?;
        if !caps.device_capabilities().contains(linuxvideo::CapabilityFlags::VIDEO_CAPTURE) {
            return Err(LiveError::Device {
                path: path.into(),
                what: "open",
                detail: format!("`{}` is not a single-planar video capture device", caps.card()),
            });
        }
        let Format::VideoCapture(current) = device.format(BufType::VIDEO_CAPTURE).map_err(io("read its format"))?
        else {
            return Err(LiveError::Device {
                path: path.into(),
                what: "read its format",
                detail: "not a capture format".into(),
            });
        };
        let fourcc = current.pixel_format().as_fourcc();
        let pixel = PixelFormat::from_fourcc(fourcc).ok_or_else(|| LiveError::UnsupportedFormat {
            path: path.into(),
            fourcc: String::from_utf8_lossy(&fourcc).into_owned(),
        })?;
        let capture = device.video_capture(current).map_err(io("set its format"))?;
        let negotiated = capture.format();
        let format = DeviceFormat {
            width: negotiated.width(),
            height: negotiated.height(),
            stride: negotiated.bytes_per_line(),
            pixel,
        };
        let stream = capture.into_stream().map_err(io("start streaming"))?;
        Ok(Self { path: path.into(), stream, format, next_sequence: 0, t_first_ns: None })
    }

    pub fn format(&self) -> DeviceFormat {
        self.format
    }

    pub fn fd(&self) -> BorrowedFd<'_> {
        self.stream.as_fd()
    }

    /// Dequeues every filled buffer, keeping the newest in `pending`. The capture time is the dequeue's
    /// (linuxvideo 0.3.5 does not hand out the driver's buffer timestamp), so capture → pose latency from a
    /// V4L2 device leaves out the driver's own delay.
    pub fn take(&mut self, pending: &mut Pending) -> Result<Take, LiveError> {
        let path = &self.path;
        let io = |e: std::io::Error| LiveError::Device {
            path: path.clone(),
            what: "dequeue a frame",
            detail: e.to_string(),
        };
        // Only buffers the driver has filled: a wake-up may come from the other device or the WaitSet's timeout,
        // and a dequeue with none filled would block acquisition until this device delivers.
        while !self.stream.will_block().map_err(io)? {
            let data = &mut pending.data;
            let corrupt = self
                .stream
                .dequeue(|buf| {
                    data.clear();
                    data.extend_from_slice(&buf);
                    Ok(buf.is_error())
                })
                .map_err(io)?;
            let sequence = self.next_sequence;
            self.next_sequence += 1;
            if corrupt {
                // The driver flagged the buffer: a frame lost, seen as a gap in the sequence numbers.
                pending.full = false;
            } else {
                let now = bdis_ipc::monotonic_ns();
                let t_first = *self.t_first_ns.get_or_insert(now);
                pending.fill(sequence, now, now - t_first);
            }
        }
        Ok(if pending.full { Take::Frame } else { Take::Nothing })
    }
}
