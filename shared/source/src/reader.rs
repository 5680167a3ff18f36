//! One frame reader for every kind of sequence: image pairs decoded by `image`, or a video decoded by an ffmpeg
//! child process. Acquisition asks it for a frame entry and gets the packed payload written once.

use std::mem::MaybeUninit;

use bdis_ipc::FrameLayout;

use bdis_rectify::RectifyMap;

use crate::decode::{DecodeError, FrameDecoder};
use crate::fields::FieldMode;
use crate::source::{FrameEntry, Sequence};
use crate::video::{VideoDecoder, VideoError};

#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error(transparent)]
    Decode(#[from] DecodeError),
    #[error(transparent)]
    Video(#[from] VideoError),
}

/// Reads the frames of one sequence; owns its buffers (and, for a video, its decoder process).
#[derive(Debug)]
pub struct FrameReader {
    images: FrameDecoder,
    video: Option<VideoDecoder>,
    rectifier: Option<Rectifier>,
    fields: Option<Fields>,
}

/// Interlaced frames: the woven frame goes into a staging buffer this owns, and the field (or the bobbed
/// frame) is written from it into the payload, once.
#[derive(Debug)]
struct Fields {
    mode: FieldMode,
    woven_layout: FrameLayout,
    staging: Vec<u8>,
}

/// Rectification applied as frames are read (a raw stereo calibration): the raw frame goes into a staging
/// buffer this owns, and each view's map writes the rectified frame straight into the payload, once.
#[derive(Debug)]
pub struct Rectifier {
    maps: [RectifyMap; 2],
    raw_layout: FrameLayout,
    staging: Vec<u8>,
}

impl Rectifier {
    /// The maps of the left and the right camera (from raw images of one size into rectified images of one
    /// size); `None` when the sizes disagree or do not fit a frame.
    pub fn new(maps: [RectifyMap; 2]) -> Option<Self> {
        let [l, r] = &maps;
        let same = (l.width, l.height, l.source_width, l.source_height)
            == (r.width, r.height, r.source_width, r.source_height);
        let raw_layout =
            FrameLayout::packed(u32::try_from(l.source_width).ok()?, u32::try_from(l.source_height).ok()?)?;
        FrameLayout::packed(u32::try_from(l.width).ok()?, u32::try_from(l.height).ok()?)?;
        same.then(|| Self { staging: vec![0; raw_layout.payload_len()], maps, raw_layout })
    }

    /// The size of the rectified frames.
    pub fn rectified_size(&self) -> (u32, u32) {
        (self.maps[0].width as u32, self.maps[0].height as u32)
    }

    /// The size of the raw frames the maps read.
    pub fn raw_size(&self) -> (u32, u32) {
        (self.raw_layout.width, self.raw_layout.height)
    }

    /// Has `read` write the raw frame into the staging buffer (raw layout), then writes the rectified frame
    /// (`layout`) into `payload`.
    pub fn apply<T, E>(
        &mut self,
        layout: &FrameLayout,
        payload: &mut [MaybeUninit<u8>],
        read: impl FnOnce(&FrameLayout, &mut [MaybeUninit<u8>]) -> Result<T, E>,
    ) -> Result<T, E> {
        // SAFETY: a `u8` is a valid `MaybeUninit<u8>`, and the readers only ever write initialised bytes into
        // the slice they are given, so the staging buffer stays initialised.
        let staging = unsafe { &mut *(self.staging.as_mut_slice() as *mut [u8] as *mut [MaybeUninit<u8>]) };
        let read = read(&self.raw_layout, staging)?;
        let raw_n = self.raw_layout.width as usize * self.raw_layout.height as usize;
        let n = layout.width as usize * layout.height as usize;
        let (raw_left, rest) = self.staging.split_at(raw_n);
        let (raw_right, raw_rgb) = rest.split_at(raw_n);
        let (left, rest) = payload.split_at_mut(n);
        let (right, rgb) = rest.split_at_mut(n);
        let [left_map, right_map] = &self.maps;
        left_map.remap(raw_left, 1, left);
        right_map.remap(raw_right, 1, right);
        left_map.remap(&raw_rgb[..3 * raw_n], 3, &mut rgb[..3 * n]);
        Ok(read)
    }
}

impl ReadError {
    /// A frame the video's decoder could not decode: the stream goes on after it.
    pub fn is_frame_lost(&self) -> bool {
        matches!(self, ReadError::Video(VideoError::FrameLost { .. }))
    }
}

impl FrameReader {
    pub fn new(sequence: &Sequence) -> Self {
        Self {
            images: FrameDecoder::new(),
            video: sequence.video.as_ref().map(VideoDecoder::new),
            rectifier: None,
            fields: None,
        }
    }

    /// Rectifies every frame as it is read; the payload layout is then the rectified size's.
    pub fn with_rectifier(mut self, rectifier: Rectifier) -> Self {
        self.rectifier = Some(rectifier);
        self
    }

    /// Takes one field of (or bobs) each woven frame of `width × height`; the payload layout is then
    /// `mode.output_size`'s. `None` for a size the mode cannot split, or together with a rectifier (the maps
    /// are for whole frames).
    pub fn with_fields(mut self, mode: FieldMode, width: u32, height: u32) -> Option<Self> {
        mode.output_size(width, height)?;
        let woven_layout = FrameLayout::packed(width, height)?;
        if self.rectifier.is_some() {
            return None;
        }
        self.fields = Some(Fields { mode, staging: vec![0; woven_layout.payload_len()], woven_layout });
        Some(self)
    }

    /// Gets ready to read from `first` on (a video's decoder is started), so the first frame's latency is
    /// not the decoder's start-up.
    pub fn prepare(&mut self, first: &FrameEntry) -> Result<(), ReadError> {
        if let Some(video) = &mut self.video {
            video.start_at(u64::from(first.source_index))?;
        }
        Ok(())
    }

    /// Writes every byte of `layout` into `payload` for this frame of the sequence.
    pub fn read_into(
        &mut self,
        entry: &FrameEntry,
        layout: &FrameLayout,
        payload: &mut [MaybeUninit<u8>],
    ) -> Result<(), ReadError> {
        if let Some(fields) = &mut self.fields {
            // SAFETY: as for the rectifier's staging buffer below.
            let staging = unsafe { &mut *(fields.staging.as_mut_slice() as *mut [u8] as *mut [MaybeUninit<u8>]) };
            read_raw(&mut self.images, &mut self.video, entry, &fields.woven_layout, staging)?;
            fields.mode.apply(&fields.staging, &fields.woven_layout, layout, payload);
            return Ok(());
        }
        let Self { images, video, rectifier, .. } = self;
        match rectifier {
            Some(rect) => {
                rect.apply(layout, payload, |raw_layout, staging| read_raw(images, video, entry, raw_layout, staging))
            }
            None => read_raw(images, video, entry, layout, payload),
        }
    }
}

fn read_raw(
    images: &mut FrameDecoder,
    video: &mut Option<VideoDecoder>,
    entry: &FrameEntry,
    layout: &FrameLayout,
    payload: &mut [MaybeUninit<u8>],
) -> Result<(), ReadError> {
    match video {
        Some(video) => Ok(video.read_into(u64::from(entry.source_index), layout, payload)?),
        None => Ok(images.decode_pair_into(&entry.left, &entry.right, layout, payload)?),
    }
}
