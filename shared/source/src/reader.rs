//! One frame reader for every kind of sequence: image pairs decoded by `image`, or a video decoded by an ffmpeg
//! child process. Acquisition asks it for a frame entry and gets the packed payload written once.

use std::mem::MaybeUninit;

use bdis_ipc::FrameLayout;

use crate::decode::{DecodeError, FrameDecoder};
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
}

impl ReadError {
    /// A frame the video's decoder could not decode: the stream goes on after it.
    pub fn is_frame_lost(&self) -> bool {
        matches!(self, ReadError::Video(VideoError::FrameLost { .. }))
    }
}

impl FrameReader {
    pub fn new(sequence: &Sequence) -> Self {
        Self { images: FrameDecoder::new(), video: sequence.video.as_ref().map(VideoDecoder::new) }
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
        match &mut self.video {
            Some(video) => Ok(video.read_into(u64::from(entry.source_index), layout, payload)?),
            None => Ok(self.images.decode_pair_into(&entry.left, &entry.right, layout, payload)?),
        }
    }
}
