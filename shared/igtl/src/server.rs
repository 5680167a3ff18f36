//! The TCP side: OpenIGTLink receivers (3D Slicer's OpenIGTLinkIF, PLUS clients, pyigtl) connect to us, the
//! server, as they do to a tracking device. Every connection gets a writer thread fed from a bounded queue
//! ([`bdis_core::fanout`]); the service only `try_send`s, so a receiver that falls behind is let go and never
//! slows the pipeline. What receivers send us is read and thrown away: the output is read-only, and a socket
//! closed with unread input would reset the connection and lose the last messages.

use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;

use bdis_core::fanout::{self, Doorbell, Fanout};

use crate::IgtlError;

/// A message as every receiver is sent it (one encoding, shared).
pub type Outgoing = Arc<[u8]>;

/// Messages a receiver may have waiting before it counts as unable to keep up: at 30 poses a second this is
/// seconds of them, or a few hundred keyframe blocks.
pub const RECEIVER_QUEUE: usize = 512;

/// The receivers, owned by the service's node thread.
pub type Receivers = Fanout<Outgoing>;

/// The receivers and the doorbell the accepting thread hands new ones through.
pub fn receivers() -> (Receivers, Doorbell<Outgoing>) {
    Fanout::new(|m: &Outgoing| m.len())
}

/// Listens on `addr` (OpenIGTLink's port is 18944; `127.0.0.1` keeps it on this machine).
pub fn bind(addr: &str) -> Result<(TcpListener, SocketAddr), IgtlError> {
    let listen_error = |what: String| IgtlError::Listen { addr: addr.to_string(), what };
    let listener = TcpListener::bind(addr).map_err(|e| listen_error(e.to_string()))?;
    let local = listener.local_addr().map_err(|e| listen_error(e.to_string()))?;
    Ok((listener, local))
}

/// Accepts receivers until the listener fails, each handed to the fan-out with a writer thread of its own. Runs
/// on a thread of its own.
pub fn accept(listener: &TcpListener, doorbell: &Doorbell<Outgoing>) {
    for stream in listener.incoming() {
        let Ok(stream) = stream else { continue };
        if let Err(e) = admit(stream, doorbell) {
            // One receiver that could not be set up; the others are unaffected.
            eprintln!("openigtlink: a receiver could not be served: {e}");
        }
    }
}

fn admit(stream: TcpStream, doorbell: &Doorbell<Outgoing>) -> std::io::Result<()> {
    // Poses are small and due now: no Nagle delay.
    stream.set_nodelay(true)?;
    let mut input = stream.try_clone()?;
    std::thread::Builder::new().name("igtl-in".into()).spawn(move || {
        let mut sink = [0u8; 4096];
        while matches!(input.read(&mut sink), Ok(n) if n > 0) {}
    })?;
    let watcher = fanout::start_writer(
        "igtl-out",
        RECEIVER_QUEUE,
        stream,
        |s, m: Outgoing| s.write_all(&m),
        |mut s| {
            // Everything queued was written: end our side (the reader thread drains its input, so closing resets nothing).
            let _ = s.flush();
            let _ = s.shutdown(Shutdown::Write);
        },
    )?;
    doorbell.send(watcher).map_err(|_| std::io::Error::other("the service has stopped"))
}
