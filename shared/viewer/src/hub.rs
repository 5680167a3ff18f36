//! The browsers watching a live pipeline. Each has a WebSocket written by a thread of its own from a bounded
//! queue; the owner of the live state (the viewer service's node thread) only ever `try_send`s, so a browser that
//! cannot keep up never slows the pipeline: when its queue is full it is dropped, and the page reconnects and is
//! sent the whole state afresh.

use std::sync::mpsc::{Receiver, Sender, SyncSender, TryRecvError, TrySendError, channel, sync_channel};

use tungstenite::protocol::Role;
use tungstenite::{Message, WebSocket};

/// Messages a browser may have waiting before it counts as unable to keep up. A keyframe block is ~40 kB at
/// 640×480, so this is a few MB at most per browser.
pub const WATCHER_QUEUE: usize = 256;

/// One browser: the queue its writer thread sends from.
#[derive(Debug)]
pub struct Watcher {
    queue: SyncSender<Message>,
    /// Signalled by the writer thread when it has sent what it had and closed the connection.
    written: Receiver<()>,
}

/// The HTTP side's end: a browser that opened the WebSocket is handed to the hub through it.
pub type Doorbell = Sender<Watcher>;

/// Every browser watching, owned by the thread that owns the live state.
#[derive(Debug)]
pub struct Hub {
    arriving: Receiver<Watcher>,
    watchers: Vec<Watcher>,
    /// Browsers dropped because their queue was full or their connection closed.
    pub dropped: u64,
    /// Bytes queued for browsers so far (each browser counted).
    pub bytes_queued: u64,
}

impl Hub {
    pub fn new() -> (Self, Doorbell) {
        let (doorbell, arriving) = channel();
        (Self { arriving, watchers: Vec::new(), dropped: 0, bytes_queued: 0 }, doorbell)
    }

    pub fn watchers(&self) -> usize {
        self.watchers.len()
    }

    /// Takes in the browsers that connected since the last call, each sent `replay()` (the whole state) first.
    pub fn admit(&mut self, mut replay: impl FnMut() -> Vec<Message>) {
        loop {
            let watcher = match self.arriving.try_recv() {
                Ok(w) => w,
                Err(TryRecvError::Empty | TryRecvError::Disconnected) => return,
            };
            let mut accepted = true;
            for message in replay() {
                let bytes = message.len() as u64;
                if watcher.queue.try_send(message).is_err() {
                    accepted = false;
                    break;
                }
                self.bytes_queued += bytes;
            }
            if accepted {
                self.watchers.push(watcher);
            } else {
                self.dropped += 1;
            }
        }
    }

    /// Queues `message` for every browser; one whose queue is full or closed is let go.
    pub fn broadcast(&mut self, message: Message) {
        let bytes = message.len() as u64;
        let before = self.watchers.len();
        self.watchers.retain(|w| match w.queue.try_send(message.clone()) {
            Ok(()) => true,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => false,
        });
        self.dropped += (before - self.watchers.len()) as u64;
        self.bytes_queued += bytes * self.watchers.len() as u64;
    }
}

impl Hub {
    /// Lets every browser go once it has been sent what is queued for it, waiting at most `patience` in all
    /// (the last map of a run reaches the page before the process ends).
    pub fn close(mut self, patience: std::time::Duration) {
        let deadline = std::time::Instant::now() + patience;
        let watchers = std::mem::take(&mut self.watchers);
        let written: Vec<Receiver<()>> = watchers.into_iter().map(|w| w.written).collect();
        for done in written {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            let _ = done.recv_timeout(left);
        }
    }
}

/// Starts the writer of one upgraded connection and returns the watcher to hand to the hub. The thread ends when
/// the hub lets the watcher go (its queue closes) or the browser goes away (a write fails).
pub fn start_writer<S: std::io::Read + std::io::Write + Send + 'static>(stream: S) -> std::io::Result<Watcher> {
    let (queue, outgoing) = sync_channel::<Message>(WATCHER_QUEUE);
    let (done, written) = sync_channel::<()>(1);
    std::thread::Builder::new().name("viewer-ws".into()).spawn(move || {
        let mut socket = WebSocket::from_raw_socket(stream, Role::Server, None);
        while let Ok(message) = outgoing.recv() {
            if socket.send(message).is_err() {
                let _ = done.send(());
                return;
            }
        }
        let _ = socket.close(None);
        let _ = socket.flush();
        let _ = done.send(());
    })?;
    Ok(Watcher { queue, written })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_browser_that_does_not_keep_up_is_let_go_and_the_others_keep_theirs() {
        let (mut hub, doorbell) = Hub::new();
        // Two browsers whose writers are stand-ins: one drains its queue, one never does.
        let (slow_queue, _slow_outgoing) = sync_channel(WATCHER_QUEUE);
        let (fast_queue, fast_outgoing) = sync_channel(WATCHER_QUEUE);
        let (_, written) = sync_channel(1);
        doorbell.send(Watcher { queue: slow_queue, written }).unwrap();
        let (_, written) = sync_channel(1);
        doorbell.send(Watcher { queue: fast_queue, written }).unwrap();
        hub.admit(|| vec![Message::text("hello")]);
        assert_eq!(hub.watchers(), 2);
        let _ = fast_outgoing.recv();
        for i in 0..WATCHER_QUEUE + 10 {
            hub.broadcast(Message::binary(vec![0u8; 8]));
            while fast_outgoing.try_recv().is_ok() {}
            if i < WATCHER_QUEUE - 1 {
                assert_eq!(hub.watchers(), 2, "message {i}");
            }
        }
        // The broadcasts never waited; the slow browser was let go when its queue filled.
        assert_eq!((hub.watchers(), hub.dropped), (1, 1));
    }
}
