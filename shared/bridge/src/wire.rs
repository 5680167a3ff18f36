//! The messages between a bridge's two sides. Each is one Zenoh sample: `[u64 epoch][u8 flags][u32 length][u8
//! kind][body]` (little-endian; the length counts kind and body and must be the rest of the message). The epoch
//! names a conversation: the receiver starts a new one with every HELLO, and counts and acknowledges only the
//! samples of its current one, so a sample still on its way from before (Zenoh delivers what was in flight) never
//! shifts the count. The one flag, [`AGAIN`], marks a sample sent again in a new conversation: the receiver
//! publishes what is catching up at a pace its consumers can take.
//!
//! * `WANT_HELLO` (sender → receiver): the sender has no conversation (it started, or the receiver came or went);
//! * `HELLO` (receiver → sender): protocol version, then per topic the last id the receiver has published
//!   (`u64::MAX`: none) — where the sender resumes; its epoch is the new conversation's;
//! * `SAMPLE` (sender → receiver): topic, id, the time the sender sent it (its CLOCK_MONOTONIC), the header's
//!   length, the header, the payload;
//! * `ACK` (receiver → sender): how many samples of this conversation the receiver has handled, in order.
//!
//! Everything read is checked before use: a length beyond [`MAX_FRAME_BYTES`] or other than the message's, an
//! unknown kind or topic, a body shorter than its fields is an error, never a panic.

use crate::{BridgeError, Carried};

pub const VERSION: u32 = 2;
/// The longest frame accepted: a 4K depth keyframe (11 bytes a pixel) with room to spare.
pub const MAX_FRAME_BYTES: u64 = 128 << 20;

const KIND_HELLO: u8 = 1;
const KIND_SAMPLE: u8 = 2;
const KIND_ACK: u8 = 3;
const KIND_WANT_HELLO: u8 = 4;

/// Bytes before a frame in a message: its epoch and flags.
pub const ENVELOPE_BYTES: usize = 9;
/// The flag of a sample sent again (it was pending when the conversation began).
pub const AGAIN: u8 = 1;

/// What comes before a message's frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Envelope {
    pub epoch: u64,
    /// Sent again in a new conversation ([`AGAIN`]).
    pub again: bool,
}

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
    WantHello,
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

/// Appends a message's envelope; the frame follows it.
pub fn envelope(out: &mut Vec<u8>, epoch: u64, again: bool) {
    out.extend_from_slice(&epoch.to_le_bytes());
    out.push(if again { AGAIN } else { 0 });
}

/// Appends a WANT_HELLO.
pub fn want_hello(out: &mut Vec<u8>) {
    let start = begin(out, KIND_WANT_HELLO);
    end(out, start);
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

/// One whole message: its envelope and its frame.
pub fn message(bytes: &[u8]) -> Result<(Envelope, Frame<'_>), BridgeError> {
    let epoch = u64::from_le_bytes(le(bytes, 0, "message")?);
    let flags = le::<1>(bytes, 8, "message")?[0];
    let rest = &bytes[ENVELOPE_BYTES..];
    let len = u64::from(u32::from_le_bytes(le(rest, 0, "length")?));
    if len > MAX_FRAME_BYTES || len == 0 {
        return Err(BridgeError::FrameTooLong(len));
    }
    let frame = &rest[4..];
    if frame.len() as u64 != len {
        return Err(BridgeError::Truncated { what: "message", len: bytes.len() });
    }
    parse(frame).map(|f| (Envelope { epoch, again: flags & AGAIN != 0 }, f))
}

fn parse(frame: &[u8]) -> Result<Frame<'_>, BridgeError> {
    let (&kind, body) = frame.split_first().ok_or(BridgeError::Truncated { what: "frame", len: 0 })?;
    match kind {
        KIND_WANT_HELLO => Ok(Frame::WantHello),
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

    fn with_epoch(e: u64, frame: impl FnOnce(&mut Vec<u8>)) -> Vec<u8> {
        let mut out = Vec::new();
        envelope(&mut out, e, e == 8);
        frame(&mut out);
        out
    }

    #[test]
    fn each_message_reads_back_with_its_epoch() {
        let hello_msg = with_epoch(7, |o| hello(o, &[(Carried::Depth, Some(41)), (Carried::Corrections, None)]));
        assert_eq!(
            message(&hello_msg),
            Ok((
                Envelope { epoch: 7, again: false },
                Frame::Hello { last: vec![(Carried::Depth, Some(41)), (Carried::Corrections, None)] }
            ))
        );
        let what = SampleId { topic: Carried::Depth, id: 42, t_sent_ns: 7 };
        let sample_msg = with_epoch(8, |o| sample(o, what, &[1, 2, 3], &[9; 1000]));
        let (e, frame) = message(&sample_msg).unwrap();
        let Frame::Sample { what: w, header, payload } = frame else { panic!("{frame:?}") };
        assert_eq!((e, w, header, payload.len()), (Envelope { epoch: 8, again: true }, what, &[1u8, 2, 3][..], 1000));
        assert_eq!(
            message(&with_epoch(9, |o| ack(o, 5))),
            Ok((Envelope { epoch: 9, again: false }, Frame::Ack { published: 5 }))
        );
        assert_eq!(message(&with_epoch(0, want_hello)), Ok((Envelope { epoch: 0, again: false }, Frame::WantHello)));
    }

    #[test]
    fn hostile_messages_are_errors_not_panics() {
        let mut m = with_epoch(1, |o| o.extend_from_slice(&u32::MAX.to_le_bytes()));
        m.push(KIND_ACK);
        assert_eq!(message(&m), Err(BridgeError::FrameTooLong(u64::from(u32::MAX))));
        assert!(message(&[1, 2, 3]).is_err());
        for body in [&[9u8][..], &[KIND_SAMPLE, 1, 0], &[KIND_SAMPLE, 77, 0, 0, 0, 0, 0, 0, 0, 0], &[KIND_ACK, 1]] {
            let m = with_epoch(1, |o| {
                o.extend_from_slice(&(body.len() as u32).to_le_bytes());
                o.extend_from_slice(body);
            });
            assert!(message(&m).is_err(), "{body:?}");
        }
        // A length that is not the rest of the message, either way.
        let mut m = with_epoch(1, |o| ack(o, 5));
        m.push(0);
        assert!(message(&m).is_err());
        m.truncate(m.len() - 2);
        assert!(message(&m).is_err());
        // A header longer than the sample.
        let mut m = with_epoch(1, |o| sample(o, SampleId { topic: Carried::Depth, id: 1, t_sent_ns: 0 }, &[1; 8], &[]));
        m[ENVELOPE_BYTES + 4 + 1 + 17] = 200;
        assert!(matches!(message(&m), Err(BridgeError::Truncated { .. })));
        let mut m = with_epoch(1, |o| hello(o, &[]));
        m[ENVELOPE_BYTES + 5] = 9;
        assert_eq!(message(&m), Err(BridgeError::Version(9)));
    }
}
