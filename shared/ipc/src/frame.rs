//! The stereo frame contract: a `[u8]` payload holding left grey, right grey and left RGB images, and optionally
//! a mask of the left view (instruments: no features, no map points), described by a versioned `#[repr(C)]` user
//! header. One type serves every resolution (a fixed-size struct per resolution would
//! be a new iceoryx2 type, and a resolution change an `IncompatibleTypes` error).

use iceoryx2::prelude::*;

/// Header of every frame sample (`bdis.v2.FrameHeader`; v2 gave v1's reserved word to the mask plane).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("bdis.v2.FrameHeader")]
pub struct FrameHeader {
    /// 0, 1, 2, … within one stream: a consumer sees a gap as a lost frame.
    pub frame_seq: u64,
    /// CLOCK_MONOTONIC when the frame was captured (for a file source: when acquisition began reading it).
    /// Copied forward unchanged through every stage, so any consumer knows the age of what it holds.
    pub t_capture_ns: u64,
    /// CLOCK_MONOTONIC when the producer sent this sample: receive − publish is the hop's latency.
    pub t_publish_ns: u64,
    /// The recording's own timestamp (times.txt), in ns; 0 when the source has none.
    pub t_source_ns: u64,
    pub width: u32,
    pub height: u32,
    pub left_gray_offset: u32,
    pub right_gray_offset: u32,
    pub left_rgb_offset: u32,
    /// Bytes per row of the grey images (≥ width).
    pub gray_stride: u32,
    /// Bytes per row of the RGB image (≥ 3·width).
    pub rgb_stride: u32,
    /// [`FrameHeader::END_OF_STREAM`], …
    pub flags: u32,
    /// Index of the frame in its source (the image number for folder layouts).
    pub source_index: u32,
    /// With [`FrameHeader::HAS_MASK`]: where the left view's mask lies (one byte per pixel, rows of
    /// `gray_stride` bytes; non-zero = an instrument or anything else to keep out of the pose and the map).
    pub mask_offset: u32,
}

impl FrameHeader {
    /// The last sample of a stream carries this flag and no pixels.
    pub const END_OF_STREAM: u32 = 1;
    /// The first frame acquisition sent after a consumer announced itself (`event_id::JOINED`), and the first
    /// frame of a stream. Frames that reach a consumer before it are not its own: see [`JoinGate`].
    pub const ANSWERS_JOIN: u32 = 2;
    /// The payload holds a mask of the left view at `mask_offset`.
    pub const HAS_MASK: u32 = 4;

    pub fn is_end_of_stream(&self) -> bool {
        self.flags & Self::END_OF_STREAM != 0
    }

    pub fn answers_join(&self) -> bool {
        self.flags & Self::ANSWERS_JOIN != 0
    }
}

/// A consumer's side of joining a running stream. Between the moment a consumer subscribes and the moment
/// acquisition reads its `JOINED`, acquisition may still send frames on the credits of others — also of a
/// consumer that has just died. Such a frame can reach the newcomer ahead of the frames acquisition sends again
/// for the dead one; taken, it would make those look like old ids and be skipped (a lost keyframe, seen in a
/// swap under load). So a consumer takes nothing before acquisition's answer, the first frame flagged
/// [`FrameHeader::ANSWERS_JOIN`], and does not acknowledge what it passed over: those frames were not sent on
/// its credit, and any a dead consumer held come again after the answer.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct JoinGate {
    answered: bool,
    passed_over: u64,
}

impl JoinGate {
    /// Whether the consumer takes this frame. An end of stream always passes: the stream is over either way.
    pub fn admit(&mut self, header: &FrameHeader) -> bool {
        self.answered |= header.answers_join() || header.is_end_of_stream();
        if !self.answered {
            self.passed_over += 1;
        }
        self.answered
    }

    /// Frames passed over while waiting for acquisition's answer.
    pub fn passed_over(&self) -> u64 {
        self.passed_over
    }
}

/// Where the three images (and the mask, if any) lie in a frame payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameLayout {
    pub width: u32,
    pub height: u32,
    pub left_gray_offset: u32,
    pub right_gray_offset: u32,
    pub left_rgb_offset: u32,
    pub gray_stride: u32,
    pub rgb_stride: u32,
    /// The left view's mask (rows of `gray_stride` bytes), if the payload has one.
    pub mask_offset: Option<u32>,
}

impl FrameLayout {
    /// Tightly packed: left grey, right grey, left RGB. `None` if the frame would not fit 4 GiB offsets.
    pub fn packed(width: u32, height: u32) -> Option<Self> {
        let gray = u64::from(width) * u64::from(height);
        let total = gray * 5;
        if width == 0 || height == 0 || total > u64::from(u32::MAX) {
            return None;
        }
        Some(Self {
            width,
            height,
            left_gray_offset: 0,
            right_gray_offset: gray as u32,
            left_rgb_offset: (2 * gray) as u32,
            gray_stride: width,
            rgb_stride: width * 3,
            mask_offset: None,
        })
    }

    /// This layout with a mask plane after everything else (the three images keep their places, so a reader
    /// that writes them is unchanged). `None` past 4 GiB.
    pub fn with_mask_plane(self) -> Option<Self> {
        let mask_offset = u32::try_from(self.images_len()).ok()?;
        let end = u64::from(mask_offset) + u64::from(self.gray_stride) * u64::from(self.height);
        (end <= u64::from(u32::MAX)).then_some(Self { mask_offset: Some(mask_offset), ..self })
    }

    /// Bytes of the three images (the payload without the mask plane).
    pub fn images_len(&self) -> usize {
        let h = self.height as usize;
        let gray_end = |off: u32| off as usize + self.gray_stride as usize * h;
        gray_end(self.left_gray_offset)
            .max(gray_end(self.right_gray_offset))
            .max(self.left_rgb_offset as usize + self.rgb_stride as usize * h)
    }

    /// Payload bytes the layout needs.
    pub fn payload_len(&self) -> usize {
        let mask_end =
            self.mask_offset.map_or(0, |off| off as usize + self.gray_stride as usize * self.height as usize);
        self.images_len().max(mask_end)
    }

    pub fn write_into(&self, header: &mut FrameHeader) {
        header.width = self.width;
        header.height = self.height;
        header.left_gray_offset = self.left_gray_offset;
        header.right_gray_offset = self.right_gray_offset;
        header.left_rgb_offset = self.left_rgb_offset;
        header.gray_stride = self.gray_stride;
        header.rgb_stride = self.rgb_stride;
        header.mask_offset = self.mask_offset.unwrap_or(0);
        header.flags = (header.flags & !FrameHeader::HAS_MASK)
            | if self.mask_offset.is_some() { FrameHeader::HAS_MASK } else { 0 };
    }

    pub fn of(header: &FrameHeader) -> Self {
        Self {
            width: header.width,
            height: header.height,
            left_gray_offset: header.left_gray_offset,
            right_gray_offset: header.right_gray_offset,
            left_rgb_offset: header.left_rgb_offset,
            gray_stride: header.gray_stride,
            rgb_stride: header.rgb_stride,
            mask_offset: (header.flags & FrameHeader::HAS_MASK != 0).then_some(header.mask_offset),
        }
    }
}

/// Why a received frame cannot be read: its header does not describe its payload.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameLayoutError {
    #[error("frame {frame_seq}: header describes {needed} bytes of images but the payload has {actual}")]
    PayloadTooShort { frame_seq: u64, needed: usize, actual: usize },
    #[error("frame {frame_seq}: invalid layout {width}×{height}, strides {gray_stride}/{rgb_stride}")]
    BadLayout { frame_seq: u64, width: u32, height: u32, gray_stride: u32, rgb_stride: u32 },
}

/// The three images of a frame (and its mask), borrowed in place from the payload (no copy).
#[derive(Debug, Clone, Copy)]
pub struct FrameView<'a> {
    pub header: &'a FrameHeader,
    pub left_gray: &'a [u8],
    pub right_gray: &'a [u8],
    pub left_rgb: &'a [u8],
    /// The left view's mask, rows of `gray_stride` bytes, non-zero = keep out.
    pub mask: Option<&'a [u8]>,
}

impl<'a> FrameView<'a> {
    /// Checks the header against the payload (a consumer never trusts offsets blindly) and borrows the images.
    pub fn new(header: &'a FrameHeader, payload: &'a [u8]) -> Result<Self, FrameLayoutError> {
        let layout = FrameLayout::of(header);
        if layout.width == 0
            || layout.height == 0
            || layout.gray_stride < layout.width
            || (layout.rgb_stride as u64) < 3 * u64::from(layout.width)
        {
            return Err(FrameLayoutError::BadLayout {
                frame_seq: header.frame_seq,
                width: layout.width,
                height: layout.height,
                gray_stride: layout.gray_stride,
                rgb_stride: layout.rgb_stride,
            });
        }
        let needed = layout.payload_len();
        if needed > payload.len() {
            return Err(FrameLayoutError::PayloadTooShort {
                frame_seq: header.frame_seq,
                needed,
                actual: payload.len(),
            });
        }
        let h = layout.height as usize;
        let gray = |off: u32| &payload[off as usize..off as usize + layout.gray_stride as usize * h];
        Ok(Self {
            header,
            left_gray: gray(layout.left_gray_offset),
            right_gray: gray(layout.right_gray_offset),
            left_rgb: &payload
                [layout.left_rgb_offset as usize..layout.left_rgb_offset as usize + layout.rgb_stride as usize * h],
            mask: layout.mask_offset.map(gray),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packed_layout_round_trips_through_the_header_and_is_checked() {
        let layout = FrameLayout::packed(4, 2).unwrap();
        assert_eq!(layout.payload_len(), 40);
        let mut header = FrameHeader { frame_seq: 7, ..Default::default() };
        layout.write_into(&mut header);
        let payload: Vec<u8> = (0..40).collect();
        let view = FrameView::new(&header, &payload).unwrap();
        assert_eq!(view.left_gray, &payload[0..8]);
        assert_eq!(view.right_gray, &payload[8..16]);
        assert_eq!(view.left_rgb, &payload[16..40]);
        assert!(view.mask.is_none());
        let e = FrameView::new(&header, &payload[..39]).unwrap_err();
        assert_eq!(e, FrameLayoutError::PayloadTooShort { frame_seq: 7, needed: 40, actual: 39 });
        header.gray_stride = 3;
        assert!(matches!(FrameView::new(&header, &payload), Err(FrameLayoutError::BadLayout { .. })));
        assert!(FrameLayout::packed(0, 5).is_none());
        assert!(FrameLayout::packed(70_000, 70_000).is_none());
    }

    #[test]
    fn a_mask_plane_follows_the_images_and_travels_in_the_header() {
        let layout = FrameLayout::packed(4, 2).unwrap().with_mask_plane().unwrap();
        assert_eq!((layout.images_len(), layout.payload_len()), (40, 48));
        let mut header = FrameHeader { frame_seq: 7, flags: FrameHeader::ANSWERS_JOIN, ..Default::default() };
        layout.write_into(&mut header);
        assert_eq!(header.flags, FrameHeader::ANSWERS_JOIN | FrameHeader::HAS_MASK);
        assert_eq!(FrameLayout::of(&header), layout);
        let payload: Vec<u8> = (0..48).collect();
        let view = FrameView::new(&header, &payload).unwrap();
        assert_eq!(view.left_rgb, &payload[16..40]);
        assert_eq!(view.mask, Some(&payload[40..48]));
        assert!(FrameView::new(&header, &payload[..47]).is_err(), "a mask past the payload is refused");
        // Writing a maskless layout clears the flag.
        FrameLayout::packed(4, 2).unwrap().write_into(&mut header);
        assert_eq!(header.flags, FrameHeader::ANSWERS_JOIN);
        assert!(FrameView::new(&header, &payload).unwrap().mask.is_none());
    }

    #[test]
    fn a_joining_consumer_takes_nothing_before_acquisitions_answer() {
        let frame = |seq, flags| FrameHeader { frame_seq: seq, flags, ..Default::default() };
        let mut gate = JoinGate::default();
        // Frame 7, sent on a dead consumer's last credit, arrives first; the answer replays 6.
        assert!(!gate.admit(&frame(7, 0)));
        assert!(gate.admit(&frame(6, FrameHeader::ANSWERS_JOIN)));
        assert!(gate.admit(&frame(7, 0)));
        // Another consumer's answer later changes nothing.
        assert!(gate.admit(&frame(8, FrameHeader::ANSWERS_JOIN)));
        assert_eq!(gate.passed_over(), 1);
        // The end of the stream passes unanswered: there is nothing left to wait for.
        let mut gate = JoinGate::default();
        assert!(gate.admit(&frame(60, FrameHeader::END_OF_STREAM)));
    }
}
