//! Live capture: stereo frames from capture devices, paced by the devices.
//!
//! Sources are written `live:<backend>:<arrangement>:…`:
//! - `live:v4l2:side-by-side:/dev/video0` or `live:v4l2:top-bottom:/dev/video0`: one device whose image holds
//!   both views (a 3-D endoscope's side-by-side output through one grabber);
//! - `live:v4l2:two-devices:/dev/video0,/dev/video2`: one device per view, frames paired by capture time;
//! - `live:emulated:<arrangement>:<yuyv|nv12|mjpeg>:<rate>hz:DIR`: a folder of pairs replayed as a device
//!   delivers them (`emulated.rs`), for tests and for trying the live path without hardware.
//!
//! The source never waits: a device wakes its reader through a file descriptor (acquisition puts it in its
//! WaitSet), the reader takes what is there, and a frame is complete when every device has delivered its
//! part. A frame the reader was too slow for is overwritten by the next, and counted.

pub mod convert;
mod emulated;
#[cfg(target_os = "linux")]
mod v4l2;

use std::mem::MaybeUninit;
use std::os::fd::BorrowedFd;
use std::path::PathBuf;

use bdis_ipc::FrameLayout;

pub use convert::{Converter, DeviceFormat, PixelFormat, View};
pub use emulated::Views;

/// How the two views reach bdis-slam.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LiveArrangement {
    SideBySide,
    TopBottom,
    TwoDevices,
}

impl LiveArrangement {
    fn parse(s: &str) -> Option<Self> {
        match s {
            "side-by-side" => Some(Self::SideBySide),
            "top-bottom" => Some(Self::TopBottom),
            "two-devices" => Some(Self::TwoDevices),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::SideBySide => "side-by-side",
            Self::TopBottom => "top-bottom",
            Self::TwoDevices => "two-devices",
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub enum Backend {
    V4l2 { devices: Vec<PathBuf> },
    Emulated { pixel: PixelFormat, rate_hz: f64, sequence: PathBuf },
}

/// A parsed `live:` source.
#[derive(Debug, Clone, PartialEq)]
pub struct LiveSpec {
    pub backend: Backend,
    pub arrangement: LiveArrangement,
    /// The spec as written (passed on to acquisition).
    pub text: String,
}

const FORMS: &str = "live:v4l2:side-by-side:/dev/videoN, live:v4l2:top-bottom:/dev/videoN, \
live:v4l2:two-devices:/dev/videoL,/dev/videoR, or live:emulated:<arrangement>:<yuyv|nv12|mjpeg>:<rate>hz:DIR";

impl LiveSpec {
    /// `None` when `text` is not a live source at all.
    pub fn parse(text: &str) -> Option<Result<Self, LiveError>> {
        let rest = text.strip_prefix("live:")?;
        let bad = |why: &str| Some(Err(LiveError::Spec(format!("`{text}`: {why}; write {FORMS}"))));
        let mut parts = rest.splitn(3, ':');
        let (Some(backend), Some(arrangement), Some(rest)) = (parts.next(), parts.next(), parts.next()) else {
            return bad("too few fields");
        };
        let Some(arrangement) = LiveArrangement::parse(arrangement) else {
            return bad(&format!("unknown arrangement `{arrangement}`"));
        };
        let backend = match backend {
            "v4l2" => {
                let devices: Vec<PathBuf> = rest.split(',').map(PathBuf::from).collect();
                let want = if arrangement == LiveArrangement::TwoDevices { 2 } else { 1 };
                if devices.len() != want || devices.iter().any(|d| d.as_os_str().is_empty()) {
                    return bad(&format!("{} needs {want} device(s)", arrangement.name()));
                }
                Backend::V4l2 { devices }
            }
            "emulated" => {
                let mut fields = rest.splitn(3, ':');
                let (Some(pixel), Some(rate), Some(dir)) = (fields.next(), fields.next(), fields.next()) else {
                    return bad("the emulated device needs a pixel format, a rate and a folder");
                };
                let Some(pixel) = PixelFormat::parse(pixel) else {
                    return bad(&format!("unknown pixel format `{pixel}`"));
                };
                let rate_hz = rate.trim_end_matches("hz").trim_end_matches("Hz").parse::<f64>().ok();
                let Some(rate_hz) = rate_hz.filter(|r| r.is_finite() && *r > 0.0 && *r <= 1000.0) else {
                    return bad(&format!("the rate `{rate}` is not a rate in (0, 1000] Hz such as 30hz"));
                };
                Backend::Emulated { pixel, rate_hz, sequence: PathBuf::from(dir) }
            }
            other => return bad(&format!("unknown backend `{other}`")),
        };
        Some(Ok(Self { backend, arrangement, text: text.to_string() }))
    }
}

#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    #[error("{0}")]
    Spec(String),
    #[error("{}: cannot {what}: {detail}", .path.display())]
    Device { path: PathBuf, what: &'static str, detail: String },
    #[error("{}: the device delivers {fourcc}; bdis-slam reads YUYV, NV12 or MJPG (set one with `v4l2-ctl -d {} --set-fmt-video=pixelformat=YUYV`)", .path.display(), .path.display())]
    UnsupportedFormat { path: PathBuf, fourcc: String },
    #[error("frame {sequence}: {source}")]
    Convert { sequence: u64, source: convert::ConvertError },
    #[error(transparent)]
    Source(#[from] crate::SourceError),
}

/// The newest frame a device delivered that is not published yet; its buffer is reused.
#[derive(Debug, Default)]
pub struct Pending {
    data: Vec<u8>,
    sequence: u64,
    t_capture_ns: u64,
    /// Time since the device started streaming.
    t_stream_ns: u64,
    full: bool,
    /// Capture time of the frame before, to know the device's frame interval.
    t_previous_ns: Option<u64>,
    interval_ns: Option<u64>,
}

impl Pending {
    fn fill(&mut self, sequence: u64, t_capture_ns: u64, t_stream_ns: u64) {
        if let Some(t) = self.t_previous_ns {
            self.interval_ns = Some(t_capture_ns.saturating_sub(t));
        }
        self.t_previous_ns = Some(t_capture_ns);
        (self.sequence, self.t_capture_ns, self.t_stream_ns, self.full) = (sequence, t_capture_ns, t_stream_ns, true);
    }
}

/// What a device had.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Take {
    Nothing,
    Frame,
    Ended,
}

#[derive(Debug)]
enum Device {
    Emulated(emulated::EmulatedDevice),
    #[cfg(target_os = "linux")]
    V4l2(v4l2::V4l2Device),
}

impl Device {
    fn format(&self) -> DeviceFormat {
        match self {
            Device::Emulated(d) => d.format(),
            #[cfg(target_os = "linux")]
            Device::V4l2(d) => d.format(),
        }
    }

    fn fd(&self) -> BorrowedFd<'_> {
        match self {
            Device::Emulated(d) => d.fd(),
            #[cfg(target_os = "linux")]
            Device::V4l2(d) => d.fd(),
        }
    }

    fn take(&mut self, pending: &mut Pending) -> Result<Take, LiveError> {
        match self {
            Device::Emulated(d) => d.take(pending),
            #[cfg(target_os = "linux")]
            Device::V4l2(d) => d.take(pending),
        }
    }
}

/// A frame published from a live source.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Captured {
    /// The (left) device's frame number: gaps are frames dropped before they were published.
    pub sequence: u64,
    /// When the (left) device captured it, on the monotonic clock.
    pub t_capture_ns: u64,
    /// The same instant on the device's clock, from the start of its stream: the frame's timestamp as a
    /// recording would have it.
    pub t_stream_ns: u64,
}

/// What the devices have now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Poll {
    /// Nothing to publish yet.
    Waiting,
    /// A frame is complete: read it with [`LiveSource::read_into`].
    Ready,
    /// A device ended its stream (only an emulated one does).
    Ended,
}

/// One or two capture devices delivering stereo frames.
#[derive(Debug)]
pub struct LiveSource {
    devices: Vec<Device>,
    pending: Vec<Pending>,
    views: Vec<View>,
    converter: Converter,
    /// Interlaced devices: the woven frame is converted into this staging buffer, then split into fields.
    fields: Option<(crate::FieldMode, FrameLayout, Vec<u8>)>,
    /// A raw stereo rig: each frame is converted into the rectifier's staging buffer, then remapped.
    rectifier: Option<crate::Rectifier>,
    /// Frames one device delivered that found no partner from the other (two devices).
    pub unpaired: u64,
}

impl LiveSource {
    /// Opens the devices (an emulated one starts capturing at once, from frame `start` of its folder).
    pub fn open(spec: &LiveSpec, start: usize) -> Result<Self, LiveError> {
        let devices = match &spec.backend {
            Backend::Emulated { pixel, rate_hz, sequence } => {
                let mut folder = crate::Sequence::open(sequence)?;
                folder.skip(start)?;
                let t_start_ns = bdis_ipc::monotonic_ns();
                let views = match spec.arrangement {
                    LiveArrangement::TwoDevices => vec![Views::Left, Views::Right],
                    both => vec![Views::Both(both)],
                };
                views
                    .into_iter()
                    .map(|v| {
                        emulated::EmulatedDevice::start(&folder, v, *pixel, *rate_hz, t_start_ns).map(Device::Emulated)
                    })
                    .collect::<Result<Vec<_>, _>>()?
            }
            #[cfg(target_os = "linux")]
            Backend::V4l2 { devices } => {
                devices.iter().map(|d| v4l2::V4l2Device::open(d).map(Device::V4l2)).collect::<Result<Vec<_>, _>>()?
            }
            #[cfg(not(target_os = "linux"))]
            Backend::V4l2 { .. } => return Err(LiveError::Spec("V4L2 devices exist on Linux only".into())),
        };
        let views = views_of(spec, &devices)?;
        Ok(Self {
            pending: devices.iter().map(|_| Pending::default()).collect(),
            devices,
            views,
            converter: Converter::new(),
            fields: None,
            rectifier: None,
            unpaired: 0,
        })
    }

    /// Rectifies every frame (a raw rig's calibration, maps built for the views' size); `None` when the maps
    /// are for another size, or together with fields.
    pub fn with_rectifier(mut self, rectifier: crate::Rectifier) -> Option<Self> {
        if rectifier.raw_size() != (self.views[0].width, self.views[0].height) || self.fields.is_some() {
            return None;
        }
        self.rectifier = Some(rectifier);
        Some(self)
    }

    /// Publishes one field of each interlaced frame (or bobs it); `None` when the views cannot be split.
    pub fn with_fields(mut self, mode: crate::FieldMode) -> Option<Self> {
        if self.rectifier.is_some() {
            return None;
        }
        let (w, h) = (self.views[0].width, self.views[0].height);
        mode.output_size(w, h)?;
        let woven = FrameLayout::packed(w, h)?;
        self.fields = Some((mode, woven, vec![0; woven.payload_len()]));
        Some(self)
    }

    /// The size of the published frames: each camera's view (one field of it, when interlaced).
    pub fn view_size(&self) -> (u32, u32) {
        let (w, h) = (self.views[0].width, self.views[0].height);
        match (&self.fields, &self.rectifier) {
            (Some((mode, ..)), _) => mode.output_size(w, h).unwrap_or((w, h)),
            (None, Some(rectifier)) => rectifier.rectified_size(),
            (None, None) => (w, h),
        }
    }

    /// The devices' formats, to report.
    pub fn describe(&self) -> String {
        let f = self.devices[0].format();
        format!("{} device(s), {}×{} {}", self.devices.len(), f.width, f.height, f.pixel.name())
    }

    /// Descriptors that become readable when a device has a frame: wait on them, then [`Self::poll`].
    pub fn wake_fds(&self) -> impl Iterator<Item = BorrowedFd<'_>> {
        self.devices.iter().map(Device::fd)
    }

    /// Takes what the devices have. With two devices, a frame is complete when both have one captured within
    /// half a frame interval of each other; the older of two that are further apart is dropped.
    pub fn poll(&mut self) -> Result<Poll, LiveError> {
        let mut ended = false;
        for (device, pending) in self.devices.iter_mut().zip(&mut self.pending) {
            ended |= device.take(pending)? == Take::Ended;
        }
        if let [left, right] = &mut self.pending[..]
            && left.full
            && right.full
        {
            let apart = left.t_capture_ns.abs_diff(right.t_capture_ns);
            let tolerance = left.interval_ns.or(right.interval_ns).map_or(u64::MAX, |i| i / 2);
            if apart > tolerance {
                let older = if left.t_capture_ns < right.t_capture_ns { left } else { right };
                older.full = false;
                self.unpaired += 1;
            }
        }
        Ok(if self.pending.iter().all(|p| p.full) {
            Poll::Ready
        } else if ended {
            Poll::Ended
        } else {
            Poll::Waiting
        })
    }

    /// Writes the complete frame into `payload` (left grey, right grey, left RGB).
    pub fn read_into(&mut self, layout: &FrameLayout, payload: &mut [MaybeUninit<u8>]) -> Result<Captured, LiveError> {
        if let Some(mut rectifier) = self.rectifier.take() {
            let read = rectifier.apply(layout, payload, |raw, staging| self.convert_into(raw, staging));
            self.rectifier = Some(rectifier);
            return read;
        }
        let Some((mode, woven, mut staging)) = self.fields.take() else { return self.convert_into(layout, payload) };
        // SAFETY: a `u8` is a valid `MaybeUninit<u8>`, and the conversion writes only initialised bytes.
        let staging_uninit = unsafe { &mut *(staging.as_mut_slice() as *mut [u8] as *mut [MaybeUninit<u8>]) };
        let converted = self.convert_into(&woven, staging_uninit);
        if converted.is_ok() {
            mode.apply(&staging, &woven, layout, payload);
        }
        self.fields = Some((mode, woven, staging));
        converted
    }

    fn convert_into(&mut self, layout: &FrameLayout, payload: &mut [MaybeUninit<u8>]) -> Result<Captured, LiveError> {
        let n = layout.width as usize * layout.height as usize;
        let (left_gray, rest) = payload.split_at_mut(n);
        let (right_gray, rgb) = rest.split_at_mut(n);
        let first = &self.pending[0];
        let captured =
            Captured { sequence: first.sequence, t_capture_ns: first.t_capture_ns, t_stream_ns: first.t_stream_ns };
        let convert = |source| LiveError::Convert { sequence: captured.sequence, source };
        for p in &mut self.pending {
            p.full = false;
        }
        // The left view (with its colour) from the first device; the right from the same image (one device) or
        // from the second device's.
        let decoded = self.converter.decode(&self.pending[0].data, &self.devices[0].format()).map_err(convert)?;
        decoded.view_into(self.views[0], left_gray, Some(&mut rgb[..3 * n]));
        if let [_, second] = &self.devices[..] {
            let decoded = self.converter.decode(&self.pending[1].data, &second.format()).map_err(convert)?;
            decoded.view_into(self.views[1], right_gray, None);
        } else {
            decoded.view_into(self.views[1], right_gray, None);
        }
        Ok(captured)
    }
}

/// Each camera's rectangle in its device's image, checked against the format's alignment.
fn views_of(spec: &LiveSpec, devices: &[Device]) -> Result<Vec<View>, LiveError> {
    let f = devices[0].format();
    let views = match spec.arrangement {
        LiveArrangement::SideBySide => {
            let w = f.width / 2;
            vec![View { x: 0, y: 0, width: w, height: f.height }, View { x: w, y: 0, width: w, height: f.height }]
        }
        LiveArrangement::TopBottom => {
            let h = f.height / 2;
            vec![View { x: 0, y: 0, width: f.width, height: h }, View { x: 0, y: h, width: f.width, height: h }]
        }
        LiveArrangement::TwoDevices => {
            let g = devices[1].format();
            if (f.width, f.height) != (g.width, g.height) {
                return Err(LiveError::Spec(format!(
                    "`{}`: the devices deliver {}×{} and {}×{}: the two views must be one size",
                    spec.text, f.width, f.height, g.width, g.height
                )));
            }
            vec![View { x: 0, y: 0, width: f.width, height: f.height }; 2]
        }
    };
    let (ax, ay) = f.pixel.alignment();
    for v in &views {
        if v.width == 0 || v.height == 0 || v.x % ax != 0 || v.y % ay != 0 || v.width % ax != 0 || v.height % ay != 0 {
            return Err(LiveError::Spec(format!(
                "`{}`: {}×{} {} images cannot be split into two {} views",
                spec.text,
                f.width,
                f.height,
                f.pixel.name(),
                spec.arrangement.name()
            )));
        }
    }
    Ok(views)
}
