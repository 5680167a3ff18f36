//! Validation at the shared-memory boundary: one check per message type, run by every consumer before it uses
//! a sample. Any process of the run's user that knows the run's prefix can publish on its topics, and a
//! producer of another build, a stale instance or a bug can send what the contract does not allow; a consumer
//! therefore trusts nothing in a header it has not checked against the payload and the stream.
//!
//! What this is not: a defence against a malicious process of the same user, which could as well ptrace or
//! kill the pipeline. It keeps every consumer memory-safe and alive whatever arrives, keeps malformed samples
//! out of the trajectory and the map, and counts them (`Rejected` telemetry records, per topic and reason).
//! (The telemetry record's own check is `validate` in the telemetry module, beside the record, so that this module
//! does not depend on telemetry, which reports what it refuses.)

use iceoryx2::identifiers::UniquePublisherId;
use nalgebra::Isometry3;

use crate::depth::{DepthHeader, DepthView};
use crate::frame::{FrameHeader, FrameLayout, FrameView};
use crate::track::{KeyframeHeader, KeyframeMeta, KeyframePose, PoseRecord, StereoIntrinsics, tracking_state};

/// Why a received sample was refused. The numbers travel in telemetry (`TelemetryRecord::reason`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[repr(u32)]
pub enum Reason {
    /// The header describes more bytes than the payload holds (offsets or sizes past its end).
    PayloadSize = 1,
    /// Sizes that describe no image: zero width or height, rows longer than their stride, unaligned floats,
    /// a layout this consumer does not read (padded grey rows).
    Layout = 2,
    /// An image of another size than the stream's (the camera the consumer was configured with).
    Dimensions = 3,
    /// A pose that is not a rigid transform: NaN or infinite numbers, a quaternion off unit length.
    Pose = 4,
    /// Intrinsics that describe no camera: focal lengths or `bf` not finite and positive, a principal point
    /// not finite.
    Intrinsics = 5,
    /// An id at or before one already taken (repeated, or out of order), from a publisher that is not
    /// replaying the stream.
    StaleId = 6,
    /// An end of stream from a publisher that has not been sending the stream, or numbered before what was
    /// already received.
    StrayEndOfStream = 7,
    /// A field holding a value the contract does not define (a state, kind, algorithm or flag).
    UnknownValue = 8,
    /// A correction for a keyframe the consumer has never had.
    UnknownKeyframe = 9,
}

impl Reason {
    pub const ALL: [Reason; 9] = [
        Reason::PayloadSize,
        Reason::Layout,
        Reason::Dimensions,
        Reason::Pose,
        Reason::Intrinsics,
        Reason::StaleId,
        Reason::StrayEndOfStream,
        Reason::UnknownValue,
        Reason::UnknownKeyframe,
    ];

    pub fn from_u32(v: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|r| *r as u32 == v)
    }

    /// The name used in `latency.json`, `top` and logs.
    pub fn name(self) -> &'static str {
        match self {
            Reason::PayloadSize => "payload-size",
            Reason::Layout => "layout",
            Reason::Dimensions => "dimensions",
            Reason::Pose => "pose",
            Reason::Intrinsics => "intrinsics",
            Reason::StaleId => "stale-id",
            Reason::StrayEndOfStream => "stray-end-of-stream",
            Reason::UnknownValue => "unknown-value",
            Reason::UnknownKeyframe => "unknown-keyframe",
        }
    }
}

/// A refused sample: why, the id it carried (frame sequence number, keyframe id, generation), and a sentence
/// for the log.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{detail}")]
pub struct Rejection {
    pub reason: Reason,
    pub id: u64,
    pub detail: String,
}

impl Rejection {
    pub fn new(reason: Reason, id: u64, detail: impl Into<String>) -> Self {
        Self { reason, id, detail: detail.into() }
    }
}

/// Refuses a header whose spans (offset, bytes; `None` = more than 2^64) reach past the payload. The sizes are
/// a header's claims, so everything is computed in checked 64-bit arithmetic.
fn spans_fit<const N: usize>(
    spans: [(u32, Option<u64>); N],
    payload: &[u8],
    id: u64,
    what: &str,
) -> Result<(), Rejection> {
    let needed = spans
        .into_iter()
        .try_fold(0u64, |m, (offset, len)| len.and_then(|l| u64::from(offset).checked_add(l)).map(|e| m.max(e)));
    if needed.is_none_or(|n| n > payload.len() as u64) {
        return Err(Rejection::new(
            Reason::PayloadSize,
            id,
            format!(
                "{what} {id}: header describes {} bytes but the payload has {}",
                needed.map_or_else(|| "more than 2^64".to_string(), |n| n.to_string()),
                payload.len()
            ),
        ));
    }
    Ok(())
}

/// A frame (frames topic, or the frame part of a keyframe): its layout against the payload. The returned view
/// borrows the three images (and the mask) in place.
pub fn frame<'a>(header: &'a FrameHeader, payload: &'a [u8]) -> Result<FrameView<'a>, Rejection> {
    let id = header.frame_seq;
    let l = FrameLayout::of(header);
    if l.width == 0 || l.height == 0 || l.gray_stride < l.width || u64::from(l.rgb_stride) < 3 * u64::from(l.width) {
        return Err(Rejection::new(
            Reason::Layout,
            id,
            format!("frame {id}: invalid layout {}×{}, strides {}/{}", l.width, l.height, l.gray_stride, l.rgb_stride),
        ));
    }
    let h = u64::from(l.height);
    let gray = u64::from(l.gray_stride).checked_mul(h);
    let rgb = u64::from(l.rgb_stride).checked_mul(h);
    let mask = l.mask_offset.map_or((0, Some(0)), |offset| (offset, gray));
    spans_fit(
        [(l.left_gray_offset, gray), (l.right_gray_offset, gray), (l.left_rgb_offset, rgb), mask],
        payload,
        id,
        "frame",
    )?;
    // In bounds (checked above), so the view's own check passes; it is kept as the one place that slices.
    FrameView::new(header, payload).map_err(|e| Rejection::new(Reason::PayloadSize, id, e.to_string()))
}

/// A frame a consumer reads as tightly packed grey rows of the size it was configured for.
pub fn packed_frame<'a>(
    header: &'a FrameHeader,
    payload: &'a [u8],
    expected: Option<(u32, u32)>,
) -> Result<FrameView<'a>, Rejection> {
    let view = frame(header, payload)?;
    let id = header.frame_seq;
    if header.gray_stride != header.width {
        return Err(Rejection::new(Reason::Layout, id, format!("frame {id}: padded grey rows are not supported")));
    }
    if let Some((w, h)) = expected
        && (header.width, header.height) != (w, h)
    {
        return Err(Rejection::new(
            Reason::Dimensions,
            id,
            format!("frame {id} is {}×{}, but this stream's camera is {w}×{h}", header.width, header.height),
        ));
    }
    Ok(view)
}

/// A rigid `world_from_camera` (translation, unit quaternion x y z w), or why not. The tracker writes
/// quaternions normalised to machine precision; 1e-6 leaves room for any honest writer.
pub fn pose(a: &[f64; 7], id: u64, what: &str) -> Result<Isometry3<f64>, Rejection> {
    let norm = (a[3] * a[3] + a[4] * a[4] + a[5] * a[5] + a[6] * a[6]).sqrt();
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    let unit = (norm - 1.0).abs() <= 1e-6;
    match (a.iter().all(|v| v.is_finite()) && unit).then(|| crate::track::pose_from_array(a)).flatten() {
        Some(p) => Ok(p),
        None => Err(Rejection::new(Reason::Pose, id, format!("{what} {id}: pose {a:?} is not a rigid transform"))),
    }
}

/// Intrinsics of a rectified pair: positive finite focal lengths and `bf`, a finite principal point.
pub fn intrinsics(k: &StereoIntrinsics, id: u64, what: &str) -> Result<(), Rejection> {
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if positive(k.fx) && positive(k.fy) && positive(k.bf) && k.cx.is_finite() && k.cy.is_finite() {
        Ok(())
    } else {
        Err(Rejection::new(
            Reason::Intrinsics,
            id,
            format!(
                "{what} {id}: intrinsics fx {} fy {} cx {} cy {} bf {} describe no camera",
                k.fx, k.fy, k.cx, k.cy, k.bf
            ),
        ))
    }
}

/// The pose a keyframe's meta carries (required) and its intrinsics.
fn meta(m: &KeyframeMeta, what: &str) -> Result<Isometry3<f64>, Rejection> {
    let p = pose(&m.world_from_camera, m.kf_id, what)?;
    intrinsics(&m.intrinsics, m.kf_id, what)?;
    Ok(p)
}

/// A keyframe from the tracker: its frame layout, pose and intrinsics.
pub fn keyframe<'a>(
    header: &'a KeyframeHeader,
    payload: &'a [u8],
) -> Result<(FrameView<'a>, Isometry3<f64>), Rejection> {
    let p = meta(&header.meta, "keyframe")?;
    let view = packed_frame(&header.frame, payload, None).map_err(|mut r| {
        r.id = header.meta.kf_id;
        r
    })?;
    Ok((view, p))
}

/// A depth keyframe: its layout against the (8-aligned) payload, algorithm, intrinsics, and its pose when it
/// has one (`None`: all zero, a keyframe made from frames without a tracker).
pub fn depth<'a>(
    header: &'a DepthHeader,
    payload: &'a [u8],
) -> Result<(DepthView<'a>, Option<Isometry3<f64>>), Rejection> {
    let id = header.meta.kf_id;
    if header.width == 0 || header.height == 0 {
        return Err(Rejection::new(
            Reason::Layout,
            id,
            format!("depth keyframe {id}: {}×{}", header.width, header.height),
        ));
    }
    if header.algorithm != DepthHeader::BDIS && header.algorithm != DepthHeader::DIS {
        return Err(Rejection::new(
            Reason::UnknownValue,
            id,
            format!("depth keyframe {id}: unknown algorithm {}", header.algorithm),
        ));
    }
    let n = u64::from(header.width) * u64::from(header.height);
    let floats = n.checked_mul(4);
    spans_fit(
        [(header.disparity_offset, floats), (header.confidence_offset, floats), (header.rgb_offset, n.checked_mul(3))],
        payload,
        id,
        "depth keyframe",
    )?;
    intrinsics(&header.meta.intrinsics, id, "depth keyframe")?;
    let p = if header.meta.world_from_camera == [0.0; 7] {
        None
    } else {
        Some(pose(&header.meta.world_from_camera, id, "depth keyframe")?)
    };
    let view = DepthView::new(header, payload).map_err(|e| {
        let reason = match e {
            crate::depth::DepthLayoutError::Misaligned { .. } => Reason::Layout,
            crate::depth::DepthLayoutError::PayloadTooShort { .. } => Reason::PayloadSize,
        };
        Rejection::new(reason, id, e.to_string())
    })?;
    Ok((view, p))
}

/// A pose correction: a rigid pose, a generation (they count from 1) and a defined `culled` flag.
pub fn correction(c: &KeyframePose) -> Result<Isometry3<f64>, Rejection> {
    if c.generation == 0 || c.culled > 1 {
        return Err(Rejection::new(
            Reason::UnknownValue,
            c.kf_id,
            format!("correction of keyframe {}: generation {}, culled {}", c.kf_id, c.generation, c.culled),
        ));
    }
    pose(&c.world_from_camera, c.kf_id, "correction of keyframe")
}

/// A pose record: a defined state, doubt and method, and a rigid pose when the state is OK or UNCERTAIN.
/// Returns the pose, if any.
pub fn pose_record(r: &PoseRecord) -> Result<Option<Isometry3<f64>>, Rejection> {
    let id = r.frame_seq;
    if r.doubt > crate::track::doubt::LAST || r.method > crate::track::pose_method::LAST || r.prior_rejected > 1 {
        let detail =
            format!("pose of frame {id}: doubt {}, method {}, prior_rejected {}", r.doubt, r.method, r.prior_rejected);
        return Err(Rejection::new(Reason::UnknownValue, id, detail));
    }
    match r.state {
        tracking_state::OK | tracking_state::UNCERTAIN => pose(&r.world_from_camera, id, "pose of frame").map(Some),
        tracking_state::NOT_INITIALIZED | tracking_state::LOST | tracking_state::END_OF_STREAM => Ok(None),
        s => Err(Rejection::new(Reason::UnknownValue, id, format!("pose of frame {id}: unknown state {s}"))),
    }
}

/// What a consumer knows of one input stream: the last id it took (frame sequence number or keyframe id), the
/// last frame sequence number it took (every stream's samples carry the frame they came from), and which
/// publisher has been sending the stream. Ids must grow. A publisher that replays the stream (an on-demand
/// acquisition sending again what a dead consumer held, a tracker's keyframe history for a new stereo
/// instance) sends ids the consumer has already taken: those are skipped, not refused.
///
/// An end of stream carries the number of frames of the stream, so it must be numbered after every frame
/// taken: one numbered in the middle is refused. (It is not required to come from the publisher of the
/// stream: a restarted producer — a new tracker after a crash — may end a stream it has sent nothing on.)
///
/// `O` is what identifies a publisher: iceoryx2's [`UniquePublisherId`] (a sample's `origin()`).
#[derive(Debug, Clone)]
pub struct StreamGuard<O = UniquePublisherId> {
    last_id: Option<u64>,
    last_frame_seq: Option<u64>,
    producer: Option<O>,
}

impl<O> Default for StreamGuard<O> {
    fn default() -> Self {
        Self { last_id: None, last_frame_seq: None, producer: None }
    }
}

/// What to do with a sample's id.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Admit {
    /// A new id: take the sample.
    New,
    /// An id already taken, from the stream's producer (or, before any sample was taken, from anyone): skip
    /// it quietly.
    Replay,
}

impl<O: Copy + Eq> StreamGuard<O> {
    /// A guard that has taken everything up to `last_id` already (a resumed consumer).
    pub fn resuming_after(last_id: Option<u64>) -> Self {
        Self { last_id, last_frame_seq: None, producer: None }
    }

    pub fn last_id(&self) -> Option<u64> {
        self.last_id
    }

    /// Whether a sample has been taken, and so the stream's publisher is known.
    pub fn knows_producer(&self) -> bool {
        self.producer.is_some()
    }

    /// Whether `origin` is the publisher whose samples this stream has been taking.
    pub fn is_producer(&self, origin: O) -> bool {
        self.producer == Some(origin)
    }

    /// Whether a sample with `id` from `origin` is new, a replay to skip, or refused.
    pub fn admit(&self, id: u64, origin: O, what: &str) -> Result<Admit, Rejection> {
        match self.last_id {
            Some(last) if id <= last => {
                if self.producer.is_none() || self.is_producer(origin) {
                    Ok(Admit::Replay)
                } else {
                    Err(Rejection::new(Reason::StaleId, id, format!("{what} {id}: already had up to {last}")))
                }
            }
            _ => Ok(Admit::New),
        }
    }

    /// Records that the sample `id`, made from frame `frame_seq`, from `origin` was taken.
    pub fn taken(&mut self, id: u64, frame_seq: u64, origin: O) {
        self.last_id = Some(self.last_id.map_or(id, |l| l.max(id)));
        self.last_frame_seq = Some(self.last_frame_seq.map_or(frame_seq, |l| l.max(frame_seq)));
        self.producer = Some(origin);
    }

    /// Whether an end of stream numbered `frame_seq` (the stream's frame count) ends this stream.
    pub fn end_of_stream(&self, frame_seq: u64, what: &str) -> Result<(), Rejection> {
        match self.last_frame_seq {
            Some(last) if frame_seq <= last => Err(Rejection::new(
                Reason::StrayEndOfStream,
                frame_seq,
                format!("{what}: end of stream numbered {frame_seq}, but frame {last} was already taken"),
            )),
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests;
