//! The bridge between two hosts' pipelines: chosen topics carried as Zenoh samples, each numbered by what it is
//! (a depth keyframe by its keyframe id, a correction by its generation and keyframe), kept by the sender until
//! the receiver says it has published it, and sent again in the next conversation when the link or either side
//! was lost. A library that knows nothing of processes or of Zenoh: the `bdis-bridge` service drives it.
//!
//! * [`wire`]: the messages (want-hello, hello, sample, acknowledgement), checked as hostile input;
//! * [`records`]: the topics' headers and the map snapshots as bytes, field by field (little-endian, no padding, no
//!   layout assumed);
//! * [`ledger`]: what the sender still owes the receiver, and what the receiver has already published;
//! * [`clock`]: the sender's clock in the receiver's, for the times the samples carry;
//! * [`pace`]: when a sample that is catching up may be published.

pub mod clock;
pub mod ledger;
pub mod pace;
pub mod records;
pub mod wire;

/// A topic the bridge carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Carried {
    /// Keyframes with their images (tracking → stereo): `bdis.v3.KeyframeHeader` + payload, numbered by keyframe
    /// id — what crosses when the stereo service runs on the far host.
    Keyframes,
    /// Depth keyframes (stereo → mosaic): `bdis.v2.DepthHeader` + payload, numbered by keyframe id.
    Depth,
    /// Keyframe pose corrections (tracking → mosaic): `bdis.v1.KeyframePose`, numbered by generation and keyframe.
    Corrections,
    /// The pose of every frame (tracking → viewer, OpenIGTLink output): `bdis.v2.PoseRecord`, numbered by frame.
    Poses,
}

impl Carried {
    pub const ALL: [Carried; 4] = [Carried::Keyframes, Carried::Depth, Carried::Corrections, Carried::Poses];

    pub fn code(self) -> u8 {
        match self {
            Carried::Depth => 1,
            Carried::Corrections => 2,
            Carried::Poses => 3,
            Carried::Keyframes => 4,
        }
    }

    pub fn from_code(code: u8) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.code() == code)
    }

    /// The name users give (`--topics depth,corrections`), the topic's short name.
    pub fn name(self) -> &'static str {
        match self {
            Carried::Depth => "depth",
            Carried::Corrections => "corrections",
            Carried::Poses => "poses",
            Carried::Keyframes => "keyframes",
        }
    }

    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|c| c.name() == name)
    }
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum BridgeError {
    #[error("a frame of {0} bytes (at most {max})", max = wire::MAX_FRAME_BYTES)]
    FrameTooLong(u64),
    #[error("a frame of unknown kind {0}")]
    UnknownKind(u8),
    #[error("a frame for unknown topic {0}")]
    UnknownTopic(u8),
    #[error("a {what} frame cut short ({len} bytes)")]
    Truncated { what: &'static str, len: usize },
    #[error("protocol version {0} (this bridge speaks {version})", version = wire::VERSION)]
    Version(u32),
    #[error("a {0} header of the wrong size")]
    HeaderSize(&'static str),
    #[error("a {0} that is not finite")]
    NotFinite(&'static str),
}
