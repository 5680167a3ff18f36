//! What both roles of the bridge share: their configuration, a socket as the WaitSet takes it, and reading what
//! has arrived on a socket without waiting for more. The roles are `send.rs` (the producing host) and
//! `receive.rs` (the consuming host).

use std::io::Read;
use std::os::fd::AsRawFd;

use bdis_bridge::Carried;
use bdis_bridge::wire::FrameReader;
use iceoryx2::prelude::*;

#[derive(Debug)]
pub struct Common {
    pub topics: Vec<Carried>,
    pub name: String,
    pub ipc_prefix: String,
}

/// A socket's descriptor, as the WaitSet takes it (not owning it: the stream closes it).
#[derive(Debug)]
pub struct SocketFd(FileDescriptor);

impl SocketFd {
    pub fn of(socket: &impl AsRawFd) -> Option<Self> {
        FileDescriptor::non_owning_new(socket.as_raw_fd()).map(Self)
    }
}

impl FileDescriptorBased for SocketFd {
    fn file_descriptor(&self) -> &FileDescriptor {
        &self.0
    }
}

impl SynchronousMultiplexing for SocketFd {}

/// What a read of a non-blocking socket found.
#[derive(Debug, PartialEq, Eq)]
pub enum PeerState {
    /// Bytes (maybe none) went into the reader; the connection is open.
    Open,
    /// The peer closed the connection, or it failed.
    Closed,
}

/// Moves every byte waiting on a non-blocking `socket` into `reader`.
pub fn read_available(socket: &mut impl Read, reader: &mut FrameReader) -> PeerState {
    const CHUNK: usize = 1 << 16;
    loop {
        let space = reader.space(CHUNK);
        match socket.read(space) {
            Ok(0) => {
                reader.extend(CHUNK, 0);
                return PeerState::Closed;
            }
            Ok(n) => reader.extend(CHUNK, n),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                reader.extend(CHUNK, 0);
                return PeerState::Open;
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => reader.extend(CHUNK, 0),
            Err(_) => {
                reader.extend(CHUNK, 0);
                return PeerState::Closed;
            }
        }
    }
}
