//! The TCP side: OpenIGTLink receivers (3D Slicer's OpenIGTLinkIF, PLUS clients, pyigtl) connect to us, the
//! server, as they do to a tracking device. Every connection gets a writer thread fed from a bounded queue
//! ([`bdis_core::fanout`]); the service only `try_send`s, so a receiver that falls behind is let go and never
//! slows the pipeline. What receivers send us is read and thrown away: the output is read-only, and a socket
//! closed with unread input would reset the connection and lose the last messages.

use std::io::{Read, Write};
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

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

/// Receivers served at once, at most: a receiver costs two threads (its writer and the reader that drains what
/// it sends), so connections beyond this are closed at once rather than let grow without bound.
pub const MAX_RECEIVERS: usize = 16;

/// Accepts receivers until the listener fails, each handed to the fan-out with a writer thread of its own, at most
/// [`MAX_RECEIVERS`] at a time. Runs on a thread of its own.
pub fn accept(listener: &TcpListener, doorbell: &Doorbell<Outgoing>) {
    let live = Arc::new(AtomicUsize::new(0));
    for stream in listener.incoming() {
        let Ok(stream) = stream else { continue };
        if live.load(Ordering::Acquire) >= MAX_RECEIVERS {
            tracing::warn!("openigtlink: {MAX_RECEIVERS} receivers already; a new connection is closed");
            let _ = stream.shutdown(Shutdown::Both);
            continue;
        }
        if let Err(e) = admit(stream, doorbell, Seat::take(&live)) {
            // One receiver that could not be set up; the others are unaffected.
            tracing::warn!("openigtlink: a receiver could not be served: {e}");
        }
    }
}

/// One receiver's place among the [`MAX_RECEIVERS`], given back when its writer thread ends, however it ends.
#[derive(Debug)]
struct Seat(Arc<AtomicUsize>);

impl Seat {
    fn take(live: &Arc<AtomicUsize>) -> Self {
        live.fetch_add(1, Ordering::AcqRel);
        Self(Arc::clone(live))
    }
}

impl Drop for Seat {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

fn admit(stream: TcpStream, doorbell: &Doorbell<Outgoing>, seat: Seat) -> std::io::Result<()> {
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
        (stream, seat),
        |(s, _), m: Outgoing| s.write_all(&m),
        |(mut s, _seat)| {
            // Everything queued was written: end our side (the reader thread drains its input, so closing resets
            // nothing).
            let _ = s.flush();
            let _ = s.shutdown(Shutdown::Write);
        },
    )?;
    doorbell.send(watcher).map_err(|_| std::io::Error::other("the service has stopped"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    #[allow(clippy::unwrap_used)]
    fn connections_beyond_the_cap_are_closed_and_a_seat_frees_when_a_receiver_goes() {
        let (listener, addr) = bind("127.0.0.1:0").unwrap();
        let (mut receivers, doorbell) = receivers();
        std::thread::spawn(move || accept(&listener, &doorbell));
        let connect = || {
            let s = TcpStream::connect(addr).unwrap();
            s.set_read_timeout(Some(Duration::from_millis(500))).unwrap();
            s
        };
        let mut held: Vec<TcpStream> = (0..MAX_RECEIVERS).map(|_| connect()).collect();
        // Every seat is taken once the accepting thread has handed them over.
        while receivers.watchers() < MAX_RECEIVERS {
            receivers.admit(Vec::new);
            std::thread::sleep(Duration::from_millis(10));
        }
        let mut refused = connect();
        let mut byte = [0u8; 1];
        assert_eq!(refused.read(&mut byte).unwrap(), 0, "a connection beyond the cap is closed at once");
        // A receiver that goes frees its seat: its peer hangs up, the next message to it fails.
        drop(held.pop());
        for _ in 0..50 {
            receivers.broadcast(Outgoing::from(&b"x"[..]));
            std::thread::sleep(Duration::from_millis(10));
        }
        let mut welcome = connect();
        assert!(
            matches!(welcome.read(&mut byte), Err(e) if e.kind() == std::io::ErrorKind::WouldBlock),
            "a free seat: the new connection stays open"
        );
    }
}
