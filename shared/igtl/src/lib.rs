//! OpenIGTLink output for surgical navigation: the endoscope's pose per frame (TRANSFORM, its tracking state in
//! the metadata and as a STRING when it changes) and the dense map, one block per keyframe (POLYDATA point
//! clouds, or POINT messages with the tissue's colour), sent again only when a keyframe changes. A library that
//! knows nothing of processes: the `bdis-igtl` service feeds it from the pipeline's topics.
//!
//! * [`message`]: the messages as bytes (header version 2 with metadata, CRC-64 over the body);
//! * [`map`]: which keyframes changed between two pictures of the map;
//! * [`server`]: the TCP server the receivers connect to, each fed from a bounded queue.

pub mod crc64;
pub mod map;
pub mod message;
pub mod server;

pub use message::{DeviceName, Encoder, Timestamp};

/// OpenIGTLink's registered port.
pub const DEFAULT_PORT: u16 = 18944;

#[derive(Debug, thiserror::Error)]
pub enum IgtlError {
    #[error("cannot listen on {addr}: {what}")]
    Listen { addr: String, what: String },
    #[error("`{0}` is not an OpenIGTLink device name (1-20 printable ASCII characters, no spaces)")]
    DeviceName(String),
}
