//! The frames on a bridge connection. Every frame is `[u32 length][u8 kind][body]` (little-endian; the length
//! counts kind and body), so a reader needs nothing but the bytes to find the next one:
//!
//! * `HELLO` (receiver → sender, first): protocol version, then per topic the last id the receiver has published
//!   (`u64::MAX`: none) — where a sender that restarted resumes;
//! * `SAMPLE` (sender → receiver): topic, id, the time the sender sent it (its CLOCK_MONOTONIC), the header's
//!   length, the header, the payload;
//! * `ACK` (receiver → sender): how many samples of this connection the receiver has published, in order.
//!
//! Everything read is checked before use: a length beyond [`MAX_FRAME_BYTES`], an unknown kind or topic, a body
//! shorter than its fields is an error, never a panic or an allocation of what a peer claims.

use crate::{BridgeError, Carried};

pub const VERSION: u32 = 1;
/// The longest frame accepted: a 4K depth keyframe (11 bytes a pixel) with room to spare.
pub const MAX_FRAME_BYTES: u64 = 128 << 20;

const KIND_HELLO: u8 = 1;
const KIND_SAMPLE: u8 = 2;
const KIND_ACK: u8 = 3;

/// What a sample is, before its header and payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleId {
    pub topic: Carried,
    pub id: u64,
    /// The sender's CLOCK_MONOTONIC when it sent the sample.
    pub t_sent_ns: u64,
}

/// Per topic, the id after which a sender resumes (`None`: from the start).
pub type ResumePoints = Vec<(Carried, Option<u64>)>;

#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Frame<'a> {
    Hello { last: ResumePoints },
    Sample { what: SampleId, header: &'a [u8], payload: &'a [u8] },
    Ack { published: u64 },
}

fn begin(out: &mut Vec<u8>, kind: u8) -> usize {
    let start = out.len();
    out.extend_from_slice(&[0; 4]);
    out.push(kind);
    start
}

fn end(out: &mut [u8], start: usize) {
    let len = (out.len() - start - 4) as u32;
    out[start..start + 4].copy_from_slice(&len.to_le_bytes());
}

/// Appends a HELLO.
pub fn hello(out: &mut Vec<u8>, last: &[(Carried, Option<u64>)]) {
    let start = begin(out, KIND_HELLO);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.push(last.len() as u8);
    for (topic, id) in last {
        out.push(topic.code());
        out.extend_from_slice(&id.unwrap_or(u64::MAX).to_le_bytes());
    }
    end(out, start);
}

/// Appends a SAMPLE.
pub fn sample(out: &mut Vec<u8>, what: SampleId, header: &[u8], payload: &[u8]) {
    let start = begin(out, KIND_SAMPLE);
    out.push(what.topic.code());
    out.extend_from_slice(&what.id.to_le_bytes());
    out.extend_from_slice(&what.t_sent_ns.to_le_bytes());
    out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    out.extend_from_slice(header);
    out.extend_from_slice(payload);
    end(out, start);
}

/// Appends an ACK.
pub fn ack(out: &mut Vec<u8>, published: u64) {
    let start = begin(out, KIND_ACK);
    out.extend_from_slice(&published.to_le_bytes());
    end(out, start);
}

/// Reads a little-endian integer of `N` bytes at `at`.
fn le<const N: usize>(body: &[u8], at: usize, what: &'static str) -> Result<[u8; N], BridgeError> {
    body.get(at..at + N).and_then(|b| b.try_into().ok()).ok_or(BridgeError::Truncated { what, len: body.len() })
}

fn topic(code: u8) -> Result<Carried, BridgeError> {
    Carried::from_code(code).ok_or(BridgeError::UnknownTopic(code))
}

/// Frames out of a byte stream: bytes go in as they arrive, whole frames come out.
#[derive(Debug, Default)]
pub struct FrameReader {
    buf: Vec<u8>,
    /// Bytes of `buf` already handed out as frames (dropped at the next `extend`).
    consumed: usize,
}

impl FrameReader {
    /// The buffer to read into: `extend(n)` then makes the first `n` bytes of it part of the stream.
    pub fn space(&mut self, at_least: usize) -> &mut [u8] {
        if self.consumed > 0 {
            self.buf.drain(..self.consumed);
            self.consumed = 0;
        }
        let filled = self.buf.len();
        self.buf.resize(filled + at_least, 0);
        &mut self.buf[filled..]
    }

    /// After a read into [`space`](Self::space): `n` bytes arrived, the rest of the space is given back.
    pub fn extend(&mut self, offered: usize, n: usize) {
        let keep = self.buf.len() - offered + n;
        self.buf.truncate(keep);
    }

    /// The next whole frame, if one has arrived.
    pub fn next_frame(&mut self) -> Result<Option<Frame<'_>>, BridgeError> {
        let rest = &self.buf[self.consumed..];
        let Ok(len_bytes) = le::<4>(rest, 0, "length") else { return Ok(None) };
        let len = u64::from(u32::from_le_bytes(len_bytes));
        if len > MAX_FRAME_BYTES || len == 0 {
            return Err(BridgeError::FrameTooLong(len));
        }
        let len = len as usize;
        if rest.len() < 4 + len {
            return Ok(None);
        }
        let start = self.consumed + 4;
        self.consumed += 4 + len;
        let frame = &self.buf[start..start + len];
        parse(frame).map(Some)
    }
}

fn parse(frame: &[u8]) -> Result<Frame<'_>, BridgeError> {
    let (&kind, body) = frame.split_first().ok_or(BridgeError::Truncated { what: "frame", len: 0 })?;
    match kind {
        KIND_HELLO => {
            let version = u32::from_le_bytes(le(body, 0, "hello")?);
            if version != VERSION {
                return Err(BridgeError::Version(version));
            }
            let n = le::<1>(body, 4, "hello")?[0] as usize;
            let mut last = Vec::with_capacity(n.min(Carried::ALL.len()));
            for i in 0..n {
                let at = 5 + 9 * i;
                let t = topic(le::<1>(body, at, "hello")?[0])?;
                let id = u64::from_le_bytes(le(body, at + 1, "hello")?);
                last.push((t, (id != u64::MAX).then_some(id)));
            }
            Ok(Frame::Hello { last })
        }
        KIND_SAMPLE => {
            let t = topic(le::<1>(body, 0, "sample")?[0])?;
            let id = u64::from_le_bytes(le(body, 1, "sample")?);
            let t_sent_ns = u64::from_le_bytes(le(body, 9, "sample")?);
            let header_len = u32::from_le_bytes(le(body, 17, "sample")?) as usize;
            let rest = &body[21..];
            if header_len > rest.len() {
                return Err(BridgeError::Truncated { what: "sample", len: body.len() });
            }
            let (header, payload) = rest.split_at(header_len);
            Ok(Frame::Sample { what: SampleId { topic: t, id, t_sent_ns }, header, payload })
        }
        KIND_ACK => Ok(Frame::Ack { published: u64::from_le_bytes(le(body, 0, "ack")?) }),
        other => Err(BridgeError::UnknownKind(other)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn feed(reader: &mut FrameReader, bytes: &[u8]) {
        let space = reader.space(bytes.len());
        space[..bytes.len()].copy_from_slice(bytes);
        reader.extend(bytes.len(), bytes.len());
    }

    #[test]
    fn frames_come_out_whole_whatever_the_reads_cut() {
        let mut stream = Vec::new();
        hello(&mut stream, &[(Carried::Depth, Some(41)), (Carried::Corrections, None)]);
        let what = SampleId { topic: Carried::Depth, id: 42, t_sent_ns: 7 };
        sample(&mut stream, what, &[1, 2, 3], &[9; 1000]);
        ack(&mut stream, 5);
        // Byte by byte, then all at once: the same frames.
        for chunk in [1usize, 7, stream.len()] {
            let mut reader = FrameReader::default();
            let mut kinds = Vec::new();
            for piece in stream.chunks(chunk) {
                feed(&mut reader, piece);
                while let Some(frame) = reader.next_frame().unwrap() {
                    kinds.push(match frame {
                        Frame::Hello { last } => {
                            assert_eq!(last, vec![(Carried::Depth, Some(41)), (Carried::Corrections, None)]);
                            1
                        }
                        Frame::Sample { what: w, header, payload } => {
                            assert_eq!((w, header, payload.len()), (what, &[1u8, 2, 3][..], 1000));
                            2
                        }
                        Frame::Ack { published } => {
                            assert_eq!(published, 5);
                            3
                        }
                    });
                }
            }
            assert_eq!(kinds, vec![1, 2, 3], "chunks of {chunk}");
        }
    }

    #[test]
    fn hostile_frames_are_errors_not_panics_or_allocations() {
        let mut reader = FrameReader::default();
        feed(&mut reader, &u32::MAX.to_le_bytes());
        assert_eq!(reader.next_frame(), Err(BridgeError::FrameTooLong(u64::from(u32::MAX))));
        for body in [&[9u8][..], &[KIND_SAMPLE, 1, 0], &[KIND_SAMPLE, 77, 0, 0, 0, 0, 0, 0, 0, 0], &[KIND_ACK, 1]] {
            let mut reader = FrameReader::default();
            let mut frame = (body.len() as u32).to_le_bytes().to_vec();
            frame.extend_from_slice(body);
            feed(&mut reader, &frame);
            assert!(reader.next_frame().is_err(), "{body:?}");
        }
        // A header longer than the sample.
        let mut stream = Vec::new();
        sample(&mut stream, SampleId { topic: Carried::Depth, id: 1, t_sent_ns: 0 }, &[1; 8], &[]);
        stream[4 + 1 + 17] = 200;
        let mut reader = FrameReader::default();
        feed(&mut reader, &stream);
        assert!(matches!(reader.next_frame(), Err(BridgeError::Truncated { .. })));
        let mut stream = Vec::new();
        hello(&mut stream, &[]);
        stream[5] = 9;
        let mut reader = FrameReader::default();
        feed(&mut reader, &stream);
        assert_eq!(reader.next_frame(), Err(BridgeError::Version(9)));
    }
}
