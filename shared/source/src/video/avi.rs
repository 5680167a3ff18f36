//! Motion-JPEG AVI: a RIFF file whose first video stream's frames are each a JPEG (`MJPG`). Indexed here by
//! walking the `movi` lists (OpenDML `AVIX` continuations too, so files over 1 GiB read whole); the frames are
//! decoded by `image`. Other AVI codecs are left to ffmpeg.

use std::io::SeekFrom;
use std::path::Path;

use super::VideoError;
use super::native::{Container, FrameSpan, NativeIndex, ReadSeek};

/// The largest header list read into memory; real ones are a few KiB.
const MAX_HEADER_BYTES: u32 = 1 << 20;

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

/// The first video stream, from `hdrl`.
struct VideoStream {
    /// The stream's number: its frames are chunks `NNdc` (or `NNdb`).
    number: u32,
    compression: [u8; 4],
    width: u32,
    height: u32,
    /// Seconds per frame as scale / rate, and the first frame's number.
    scale: u32,
    rate: u32,
    start: u32,
}

impl VideoStream {
    /// The two digits its chunks' ids start with.
    fn chunk_prefix(&self) -> [u8; 2] {
        [b'0' + (self.number / 10 % 10) as u8, b'0' + (self.number % 10) as u8]
    }
}

/// Finds the first video stream in the `hdrl` list's body.
fn video_stream(list: &[u8]) -> Option<VideoStream> {
    let mut at = 0;
    let mut number = 0;
    while at + 8 <= list.len() {
        let (id, size) = (&list[at..at + 4], u32_at(list, at + 4)? as usize);
        let body = list.get(at + 8..(at + 8 + size).min(list.len()))?;
        if id == b"LIST" && body.get(..4) == Some(b"strl") {
            let (mut strh, mut strf) = (None, None);
            let mut inner = 4;
            while inner + 8 <= body.len() {
                let (id, size) = (&body[inner..inner + 4], u32_at(body, inner + 4)? as usize);
                let chunk = body.get(inner + 8..(inner + 8 + size).min(body.len()))?;
                match id {
                    b"strh" if strh.is_none() => strh = Some(chunk),
                    b"strf" if strf.is_none() => strf = Some(chunk),
                    _ => {}
                }
                inner += 8 + size + (size & 1);
            }
            if let (Some(strh), Some(strf)) = (strh, strf)
                && strh.get(..4) == Some(b"vids")
            {
                let height = u32_at(strf, 8)? as i32;
                return Some(VideoStream {
                    number,
                    compression: strf.get(16..20)?.try_into().ok()?,
                    width: u32_at(strf, 4)?,
                    height: height.unsigned_abs(),
                    scale: u32_at(strh, 20)?,
                    rate: u32_at(strh, 24)?,
                    start: u32_at(strh, 28)?,
                });
            }
            number += 1;
        }
        at += 8 + size + (size & 1);
    }
    None
}

/// A video frame chunk in file order: where its data is and its size (0: a frame the recorder dropped).
struct Chunk {
    data: u64,
    size: u32,
}

/// What a walk of the file's chunks found.
#[derive(Default)]
struct Walk {
    stream: Option<VideoStream>,
    /// The video chunks met in the `movi` lists, in order.
    chunks: Vec<Chunk>,
    /// Where the first `movi` list's type is (idx1 offsets count from there) and where `idx1` is (body, size).
    movi: Option<u64>,
    idx1: Option<(u64, u32)>,
    /// An OpenDML continuation (`RIFF AVIX`): frames past the first GiB, which `idx1` does not list.
    continued: bool,
}

/// Indexes an AVI file. `Ok(None)`: not Motion-JPEG (ffmpeg reads it). The frames are `idx1`'s when the file
/// has one (it survives damage to the chunks in the middle, as ffprobe's listing does), otherwise the chunks
/// found by walking the `movi` lists.
pub(super) fn index(path: &Path, file: &mut impl ReadSeek, file_len: u64) -> Result<Option<NativeIndex>, VideoError> {
    let io = |e: std::io::Error| VideoError::Probe { path: path.to_path_buf(), detail: e.to_string() };
    let bad = |detail: String| VideoError::Probe { path: path.to_path_buf(), detail };
    let Some(walk) = walk(path, file, file_len)? else {
        return Ok(None);
    };
    let stream = walk.stream.ok_or_else(|| bad("no video stream in the AVI header".into()))?;
    if !(1..=super::native::MAX_SIDE).contains(&stream.width) || !(1..=super::native::MAX_SIDE).contains(&stream.height)
    {
        return Err(bad(format!("video stream size {}×{}", stream.width, stream.height)));
    }
    if stream.scale == 0 || stream.rate == 0 {
        return Err(bad(format!("video stream rate {}/{} is not a frame rate", stream.rate, stream.scale)));
    }
    let chunks = match (walk.idx1, walk.movi, walk.continued) {
        (Some((at, size)), Some(movi), false) => {
            idx1_chunks(file, at, size, movi, stream.chunk_prefix()).map_err(io)?
        }
        _ => walk.chunks,
    };
    // Each chunk is a frame slot; a slot of size 0 passes its time with no frame.
    let seconds =
        |slot: usize| (slot as u64 + u64::from(stream.start)) as f64 * f64::from(stream.scale) / f64::from(stream.rate);
    let (mut frames, mut timestamps_s) = (Vec::new(), Vec::new());
    for (slot, chunk) in chunks.iter().enumerate() {
        let bytes = u64::from(chunk.size);
        if bytes > 0 && chunk.data + bytes <= file_len {
            frames.push(FrameSpan { offset: chunk.data, bytes });
            timestamps_s.push(seconds(slot));
        }
    }
    if frames.is_empty() {
        return Err(bad("no video frames".into()));
    }
    Ok(Some(NativeIndex {
        container: Container::MjpegAvi,
        width: stream.width,
        height: stream.height,
        frames,
        timestamps_s,
    }))
}

/// The video chunks `idx1` lists, in order. Its offsets count from the `movi` list's type, or (some writers)
/// from the start of the file: the first entry tells which.
fn idx1_chunks(
    file: &mut impl ReadSeek,
    at: u64,
    size: u32,
    movi: u64,
    prefix: [u8; 2],
) -> std::io::Result<Vec<Chunk>> {
    let mut entries = vec![0u8; size as usize];
    file.seek(SeekFrom::Start(at))?;
    file.read_exact(&mut entries)?;
    let entry = |e: &[u8]| (u32_at(e, 8).unwrap_or(0), u32_at(e, 12).unwrap_or(0));
    let base = match entries.chunks_exact(16).next().map(entry) {
        Some((offset, _)) if u64::from(offset) >= movi => 0,
        _ => movi,
    };
    Ok(entries
        .chunks_exact(16)
        .filter(|e| e[..2] == prefix && matches!(&e[2..4], b"dc" | b"db"))
        .map(|e| {
            let (offset, size) = entry(e);
            Chunk { data: base + u64::from(offset) + 8, size }
        })
        .collect())
}

/// Walks the RIFF lists: the header's first video stream, the `movi` chunks, `idx1`. `Ok(None)`: the video
/// is not Motion-JPEG.
fn walk(path: &Path, file: &mut impl ReadSeek, file_len: u64) -> Result<Option<Walk>, VideoError> {
    let io = |e: std::io::Error| VideoError::Probe { path: path.to_path_buf(), detail: e.to_string() };
    let bad = |detail: String| VideoError::Probe { path: path.to_path_buf(), detail };
    let mut header = [0u8; 12];
    let mut found = Walk::default();
    // Lists to walk: (start of body, end). The top level is the RIFF lists one after the other.
    let mut pending: Vec<(u64, u64)> = Vec::new();
    let mut riff_at = 0u64;
    while riff_at + 12 <= file_len {
        file.seek(SeekFrom::Start(riff_at)).map_err(io)?;
        file.read_exact(&mut header).map_err(io)?;
        let size = u64::from(u32_at(&header, 4).unwrap_or(0));
        let continuation = riff_at > 0 && &header[8..12] == b"AVIX";
        if &header[..4] != b"RIFF" || !(&header[8..12] == b"AVI " || continuation) {
            if riff_at == 0 {
                return Err(bad("not an AVI (RIFF … AVI) file".into()));
            }
            break;
        }
        found.continued |= continuation;
        let end = (riff_at + 8 + size).min(file_len);
        pending.push((riff_at + 12, end));
        while let Some((mut at, end)) = pending.pop() {
            while at + 8 <= end {
                file.seek(SeekFrom::Start(at)).map_err(io)?;
                // A list's type follows its size; a chunk at the very end of the file may not have 4 more bytes.
                header.fill(0);
                let available = (file_len - at).min(12) as usize;
                file.read_exact(&mut header[..available]).map_err(io)?;
                let id: [u8; 4] = header[..4].try_into().unwrap_or_default();
                let size = u32_at(&header, 4).unwrap_or(0);
                let body = at + 8;
                let next = body + u64::from(size) + u64::from(size & 1);
                match (&id, &header[8..12]) {
                    (b"LIST", b"hdrl") if found.stream.is_none() => {
                        if size > MAX_HEADER_BYTES {
                            return Err(bad(format!("a header list of {size} bytes")));
                        }
                        let mut list = vec![0u8; size as usize];
                        file.seek(SeekFrom::Start(body)).map_err(io)?;
                        file.read_exact(&mut list).map_err(io)?;
                        let stream = video_stream(list.get(4..).unwrap_or_default())
                            .ok_or_else(|| bad("no video stream in the AVI header".into()))?;
                        if !matches!(&stream.compression, b"MJPG" | b"mjpg") {
                            return Ok(None);
                        }
                        found.stream = Some(stream);
                    }
                    (b"LIST", b"movi" | b"rec ") => {
                        if found.movi.is_none() && &header[8..12] == b"movi" {
                            found.movi = Some(body);
                        }
                        // Walk the list's children before what follows it, so frames stay in file order.
                        pending.push((next, end));
                        pending.push((body + 4, next.min(end)));
                        break;
                    }
                    (b"idx1", _) if found.idx1.is_none() && riff_at == 0 => {
                        if next <= file_len {
                            found.idx1 = Some((body, size));
                        }
                    }
                    _ => {
                        if let Some(s) = &found.stream
                            && id[..2] == s.chunk_prefix()
                            && matches!(&id[2..], b"dc" | b"db")
                        {
                            found.chunks.push(Chunk { data: body, size });
                        }
                    }
                }
                at = next;
            }
        }
        riff_at = end + (end & 1);
    }
    Ok(Some(found))
}
