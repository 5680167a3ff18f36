//! What both roles of the bridge share: their configuration, and a socket as the WaitSet takes it. The roles are
//! `send.rs` (the producing host) and `receive.rs` (the consuming host); `link.rs` is the Zenoh link between them.

use std::os::fd::AsRawFd;

use bdis_bridge::Carried;
use iceoryx2::prelude::*;

#[derive(Debug)]
pub struct Common {
    pub topics: Vec<Carried>,
    pub name: String,
    pub ipc_prefix: String,
    /// Carry the map snapshot's request-response too (`snapshot.rs`).
    pub map_snapshots: bool,
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
