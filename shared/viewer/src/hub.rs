//! The browsers watching a live pipeline: a [`bdis_core::fanout`] of WebSocket messages. Each browser has a
//! WebSocket written by a thread of its own from a bounded queue; the owner of the live state (the viewer
//! service's node thread) only ever `try_send`s, so a browser that cannot keep up never slows the pipeline: when
//! its queue is full it is dropped, and the page reconnects and is sent the whole state afresh.

use bdis_core::fanout::{self, Fanout, Watcher};
use tungstenite::protocol::Role;
use tungstenite::{Message, WebSocket};

/// Messages a browser may have waiting before it counts as unable to keep up. A keyframe block is ~40 kB at
/// 640×480, so this is a few MB at most per browser.
pub const WATCHER_QUEUE: usize = 256;

/// Every browser watching, owned by the thread that owns the live state.
pub type Hub = Fanout<Message>;

/// The HTTP side's end: a browser that opened the WebSocket is handed to the hub through it.
pub type Doorbell = fanout::Doorbell<Message>;

/// The hub and its doorbell.
pub fn hub() -> (Hub, Doorbell) {
    Fanout::new(Message::len)
}

/// Starts the writer of one upgraded connection and returns the watcher to hand to the hub. The thread ends when
/// the hub lets the watcher go (its queue closes) or the browser goes away (a write fails).
pub fn start_writer<S: std::io::Read + std::io::Write + Send + 'static>(
    stream: S,
) -> std::io::Result<Watcher<Message>> {
    fanout::start_writer(
        "viewer-ws",
        WATCHER_QUEUE,
        WebSocket::from_raw_socket(stream, Role::Server, None),
        |socket, message| socket.send(message).map_err(std::io::Error::other),
        |mut socket| {
            let _ = socket.close(None);
            let _ = socket.flush();
        },
    )
}
