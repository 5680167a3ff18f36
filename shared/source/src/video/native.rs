//! Video read here, without an ffmpeg child, where it is cheap: YUV4MPEG2 (raw planes) and Motion-JPEG AVI (a
//! JPEG per frame, which `image` already decodes). The file is indexed once (every frame's offset and time), so
//! a frame is one seek and one read: seeking and replays cost nothing, and a machine without ffmpeg still reads
//! these files. Anything else goes to ffmpeg.

use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use image::ImageDecoder;

use super::VideoError;
use super::y4m::PlaneLayout;

/// What the frames of an indexed file are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Container {
    Y4m(PlaneLayout),
    MjpegAvi,
}

/// Where one frame's data lies in the file. Only whole frames are indexed: a file cut short lists the frames
/// it still holds, as ffprobe does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct FrameSpan {
    pub offset: u64,
    pub bytes: u64,
}

/// A file's frames, in display order, with their times.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct NativeIndex {
    pub container: Container,
    pub width: u32,
    pub height: u32,
    pub frames: Vec<FrameSpan>,
    pub timestamps_s: Vec<f64>,
}

impl NativeIndex {
    /// How the file is read, for `--check` and logs.
    pub fn decoder(&self) -> &'static str {
        match self.container {
            Container::Y4m(_) => "Y4M, read here",
            Container::MjpegAvi => "Motion-JPEG AVI, read here",
        }
    }
}

/// The longest side of a frame read here: a header's size is checked before a frame buffer is made for it.
pub(super) const MAX_SIDE: u32 = 16_384;

/// What the indexers read from: a file, or bytes in memory (the fuzz target).
pub(super) trait ReadSeek: Read + Seek {}
impl<T: Read + Seek> ReadSeek for T {}

/// Indexes `path` when it is a container read here (by its first bytes); `Ok(None)` for anything else.
pub(super) fn index(path: &Path) -> Result<Option<NativeIndex>, VideoError> {
    let mut file = std::fs::File::open(path).map_err(|_| VideoError::Missing { path: path.to_path_buf() })?;
    let len = file.metadata().map_err(|e| VideoError::Probe { path: path.to_path_buf(), detail: e.to_string() })?.len();
    index_of(path, &mut file, len)
}

/// Indexes what `file` (of `len` bytes) holds, named `path` in errors.
fn index_of(path: &Path, file: &mut impl ReadSeek, len: u64) -> Result<Option<NativeIndex>, VideoError> {
    let mut magic = [0u8; 12];
    let mut got = 0;
    while got < magic.len() {
        match file.read(&mut magic[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(VideoError::Probe { path: path.to_path_buf(), detail: e.to_string() }),
        }
    }
    if magic.starts_with(b"YUV4MPEG2") {
        super::y4m::index(path, file, len)
    } else if &magic[..4] == b"RIFF" && &magic[8..12] == b"AVI " {
        super::avi::index(path, file, len)
    } else {
        Ok(None)
    }
}

/// Reads an indexed file frame by frame into packed RGB. Its buffers are reused: a warmed-up Y4M frame
/// allocates nothing (the JPEG decoder of an MJPEG frame allocates inside `image`).
pub(super) struct NativeReader {
    path: PathBuf,
    file: std::fs::File,
    index: NativeIndex,
    /// The frame the next read returns (an index into `index.frames`).
    next: usize,
    /// One frame's bytes as stored (planes or a JPEG).
    stored: Vec<u8>,
    /// A JPEG completed with the standard Huffman tables, when it came without them.
    completed: Vec<u8>,
}

impl NativeReader {
    pub fn open(path: &Path, index: NativeIndex) -> Result<Self, VideoError> {
        let file = std::fs::File::open(path).map_err(|_| VideoError::Missing { path: path.to_path_buf() })?;
        Ok(Self { path: path.to_path_buf(), file, index, next: 0, stored: Vec::new(), completed: Vec::new() })
    }

    /// The next read returns the first frame at or after `first_frame` (numbered as in the file's times).
    pub fn seek_to(&mut self, first_frame: u64, timestamps_s: &[f64]) {
        let t = timestamps_s.get(first_frame as usize).copied().unwrap_or(f64::INFINITY);
        self.next = self.index.timestamps_s.partition_point(|&x| x < t - 1e-9);
    }

    /// A Y4M file's planes (what [`NativeReader::read_planes`] gives), `None` for other containers.
    pub fn planes(&self) -> Option<PlaneLayout> {
        match self.index.container {
            Container::Y4m(planes) => Some(planes),
            Container::MjpegAvi => None,
        }
    }

    /// A Y4M file's next frame as it is stored (its planes, [`NativeReader::planes`]) into `planes`, and its
    /// number as [`NativeReader::read_frame`] gives it; converted later, only as far as it is needed (the
    /// right view's colour never is). `Ok(None)` at the end of the file.
    pub fn read_planes(&mut self, planes: &mut Vec<u8>, timestamps_s: &[f64]) -> Result<Option<u64>, VideoError> {
        let Some(&span) = self.index.frames.get(self.next) else { return Ok(None) };
        let frame = self.next;
        self.next += 1;
        planes.resize(span.bytes as usize, 0);
        self.file.seek(SeekFrom::Start(span.offset)).map_err(|e| self.pipe(e.to_string()))?;
        self.file.read_exact(planes).map_err(|e| self.pipe(e.to_string()))?;
        let t = self.index.timestamps_s[frame];
        Ok(Some(timestamps_s.partition_point(|&x| x < t - 1e-9) as u64))
    }

    /// Decodes the next frame into `rgb` (the file's `width × height × 3` bytes) and returns its number in
    /// `timestamps_s` (the source's times). A frame that does not decode is passed over, as ffmpeg's decoder
    /// passes over a corrupt one, and the reader reports it lost; `Ok(None)` at the end of the file.
    pub fn read_frame(&mut self, rgb: &mut [u8], timestamps_s: &[f64]) -> Result<Option<u64>, VideoError> {
        let (w, h) = (self.index.width as usize, self.index.height as usize);
        if rgb.len() != 3 * w * h {
            return Err(self.pipe(format!("a frame buffer of {} bytes for {w}×{h} RGB", rgb.len())));
        }
        while let Some(&span) = self.index.frames.get(self.next) {
            let frame = self.next;
            self.next += 1;
            self.stored.resize(span.bytes as usize, 0);
            self.file.seek(SeekFrom::Start(span.offset)).map_err(|e| self.pipe(e.to_string()))?;
            self.file.read_exact(&mut self.stored).map_err(|e| self.pipe(e.to_string()))?;
            let decoded = match self.index.container {
                Container::Y4m(planes) => {
                    planes.convert_into_rgb(&self.stored, rgb);
                    true
                }
                Container::MjpegAvi => {
                    let jpeg = crate::jpeg::with_huffman_tables(&self.stored, &mut self.completed);
                    decode_jpeg(jpeg, self.index.width, self.index.height, rgb)
                }
            };
            if decoded {
                let t = self.index.timestamps_s[frame];
                let number = timestamps_s.partition_point(|&x| x < t - 1e-9);
                return Ok(Some(number as u64));
            }
        }
        Ok(None)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn pipe(&self, detail: String) -> VideoError {
        VideoError::Pipe { path: self.path.clone(), detail }
    }
}

/// Decodes one JPEG of `width × height` into packed RGB; `false` when it is corrupt or of another size.
fn decode_jpeg(jpeg: &[u8], width: u32, height: u32, rgb: &mut [u8]) -> bool {
    let Ok(decoder) = image::codecs::jpeg::JpegDecoder::new(std::io::Cursor::new(jpeg)) else {
        return false;
    };
    if decoder.dimensions() != (width, height) {
        return false;
    }
    let pixels = width as usize * height as usize;
    match decoder.color_type() {
        image::ColorType::Rgb8 => decoder.read_image(rgb).is_ok(),
        image::ColorType::L8 => {
            if decoder.read_image(&mut rgb[..pixels]).is_err() {
                return false;
            }
            // Spread in place from the back, so every grey value is read before it is overwritten.
            for i in (0..pixels).rev() {
                let v = rgb[i];
                rgb[3 * i..3 * i + 3].fill(v);
            }
            true
        }
        _ => false,
    }
}

/// For fuzzing: indexes `data` as a file would be, then decodes every frame it lists. Returns the frames that
/// decoded; an error is what a user would be told.
#[doc(hidden)]
pub fn index_and_decode(data: &[u8]) -> Result<usize, VideoError> {
    let path = Path::new("fuzz-input");
    let Some(index) = index_of(path, &mut std::io::Cursor::new(data), data.len() as u64)? else {
        return Ok(0);
    };
    assert_eq!(index.frames.len(), index.timestamps_s.len(), "a time per frame");
    assert!(index.timestamps_s.iter().all(|t| t.is_finite()), "finite times");
    // The product makes a frame buffer of the header's size (at most MAX_SIDE²); here, for small inputs, a
    // header that large is only indexed.
    if u64::from(index.width) * u64::from(index.height) > 1 << 22 {
        return Ok(0);
    }
    let mut rgb = vec![0u8; 3 * index.width as usize * index.height as usize];
    let (mut decoded, mut completed) = (0, Vec::new());
    for span in &index.frames {
        let end = span.offset.saturating_add(span.bytes);
        assert!(end <= data.len() as u64, "an indexed frame lies inside the file");
        let stored = &data[span.offset as usize..end as usize];
        decoded += usize::from(match index.container {
            Container::Y4m(planes) => {
                planes.convert_into_rgb(stored, &mut rgb);
                true
            }
            Container::MjpegAvi => decode_jpeg(
                crate::jpeg::with_huffman_tables(stored, &mut completed),
                index.width,
                index.height,
                &mut rgb,
            ),
        });
    }
    Ok(decoded)
}
