//! The depth-keyframe contract: what the stereo service publishes for each keyframe. A `[u8]` payload, 8-byte
//! aligned, holding the disparity (f32, px, NaN = no answer), the confidence (f32 in [0, 1]) and the left RGB
//! image, described by a versioned `#[repr(C)]` header that also carries the keyframe's pose and intrinsics, so
//! a consumer needs nothing else to build the keyframe's points.

use iceoryx2::prelude::*;

use crate::track::KeyframeMeta;

/// Header of every depth sample (`bdis.v2.DepthHeader`).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v2.DepthHeader")]
pub struct DepthHeader {
    /// The keyframe this depth belongs to: its id, pose, intrinsics and correction generation, as the tracker
    /// published them (with frames as input: the frame's number as id, no pose, the settings' intrinsics).
    pub meta: KeyframeMeta,
    /// The frame the keyframe was made from.
    pub frame_seq: u64,
    /// Copied from the frame: CLOCK_MONOTONIC at capture.
    pub t_capture_ns: u64,
    /// When the stereo service published this sample.
    pub t_publish_ns: u64,
    pub width: u32,
    pub height: u32,
    /// Byte offsets in the payload; the float arrays are tightly packed rows (4·width bytes).
    pub disparity_offset: u32,
    pub confidence_offset: u32,
    pub rgb_offset: u32,
    /// [`DepthHeader::BDIS`] or [`DepthHeader::DIS`].
    pub algorithm: u32,
    /// [`DepthHeader::END_OF_STREAM`], …
    pub flags: u32,
    /// Fraction of pixels with a disparity, in ‰.
    pub density_permille: u32,
}

impl DepthHeader {
    pub const END_OF_STREAM: u32 = 1;
    pub const BDIS: u32 = 1;
    pub const DIS: u32 = 2;

    pub fn is_end_of_stream(&self) -> bool {
        self.flags & Self::END_OF_STREAM != 0
    }

    /// Payload bytes for a w×h depth keyframe, laid out as [`DepthHeader::set_layout`] does.
    pub fn payload_len(width: u32, height: u32) -> usize {
        let n = width as usize * height as usize;
        n * 4 * 2 + n * 3
    }

    /// Packs disparity, confidence, RGB (the float arrays first, so they stay 4-byte aligned).
    pub fn set_layout(&mut self, width: u32, height: u32) {
        let n = width * height;
        self.width = width;
        self.height = height;
        self.disparity_offset = 0;
        self.confidence_offset = 4 * n;
        self.rgb_offset = 8 * n;
    }
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DepthLayoutError {
    #[error("depth keyframe {kf_id}: header describes {needed} bytes but the payload has {actual}")]
    PayloadTooShort { kf_id: u64, needed: usize, actual: usize },
    #[error("depth keyframe {kf_id}: arrays not 4-byte aligned in the payload")]
    Misaligned { kf_id: u64 },
}

/// A depth keyframe read in place.
#[derive(Debug, Clone, Copy)]
pub struct DepthView<'a> {
    pub header: &'a DepthHeader,
    pub disparity: &'a [f32],
    pub confidence: &'a [f32],
    pub rgb: &'a [u8],
}

fn floats(bytes: &[u8], kf_id: u64) -> Result<&[f32], DepthLayoutError> {
    // SAFETY: every bit pattern is a valid f32; align_to only hands out the aligned middle part.
    let (head, body, tail) = unsafe { bytes.align_to::<f32>() };
    if !head.is_empty() || !tail.is_empty() {
        return Err(DepthLayoutError::Misaligned { kf_id });
    }
    Ok(body)
}

impl<'a> DepthView<'a> {
    pub fn new(header: &'a DepthHeader, payload: &'a [u8]) -> Result<Self, DepthLayoutError> {
        // Checked: a header can claim any sizes, and 4·w·h wraps 64 bits for the largest.
        let too_short = |needed: usize| DepthLayoutError::PayloadTooShort {
            kf_id: header.meta.kf_id,
            needed,
            actual: payload.len(),
        };
        let n = (header.width as usize).checked_mul(header.height as usize).ok_or(too_short(usize::MAX))?;
        let end = |off: u32, per_pixel: usize| n.checked_mul(per_pixel).and_then(|b| b.checked_add(off as usize));
        let needed = [end(header.disparity_offset, 4), end(header.confidence_offset, 4), end(header.rgb_offset, 3)]
            .into_iter()
            .try_fold(0usize, |m, e| e.map(|e| m.max(e)))
            .unwrap_or(usize::MAX);
        if needed > payload.len() {
            return Err(too_short(needed));
        }
        let span = |off: u32, len: usize| &payload[off as usize..off as usize + len];
        Ok(Self {
            header,
            disparity: floats(span(header.disparity_offset, 4 * n), header.meta.kf_id)?,
            confidence: floats(span(header.confidence_offset, 4 * n), header.meta.kf_id)?,
            rgb: span(header.rgb_offset, 3 * n),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layout_round_trips_and_is_checked() {
        let mut h = DepthHeader { meta: KeyframeMeta { kf_id: 3, ..Default::default() }, ..Default::default() };
        h.set_layout(4, 2);
        assert_eq!(DepthHeader::payload_len(4, 2), 88);
        // An 8-aligned buffer, as the payload in a sample is (see the next test).
        let storage = [0u64; 11];
        // SAFETY: u64 storage viewed as bytes, for the test.
        let payload = unsafe { std::slice::from_raw_parts(storage.as_ptr().cast::<u8>(), 88) };
        let v = DepthView::new(&h, payload).unwrap();
        assert_eq!((v.disparity.len(), v.confidence.len(), v.rgb.len()), (8, 8, 24));
        assert!(matches!(DepthView::new(&h, &payload[..87]), Err(DepthLayoutError::PayloadTooShort { .. })));
    }

    #[test]
    #[allow(clippy::unwrap_used)]
    fn a_loaned_payload_is_8_aligned_without_a_payload_alignment_override() {
        let prefix = format!("bipcdal{}_", std::process::id());
        let ipc = crate::Ipc::open("depth-align", &prefix).unwrap();
        let service = ipc.depth().unwrap();
        let bytes = DepthHeader::payload_len(64, 48);
        let publisher = ipc.depth_publisher(&service, bytes).unwrap();
        for _ in 0..3 {
            let loan = publisher.loan_slice_uninit(bytes).unwrap();
            assert_eq!(loan.payload().as_ptr() as usize % 8, 0);
        }
        drop((publisher, service, ipc));
        crate::remove_run_files(&prefix);
    }
}
