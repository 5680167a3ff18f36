//! Fan-out to watchers outside the pipeline (browsers, navigation workstations) that must never slow it down.
//! Each watcher has a writer thread of its own fed by a bounded queue; the owner of the state (a service's node
//! thread) only ever `try_send`s, so a watcher that cannot keep up is let go when its queue is full — it
//! reconnects and is sent the whole state afresh — and nothing upstream ever waits for it.
//!
//! The transport is the caller's: [`start_writer`] runs any `FnMut(M) -> io::Result<()>` on the writer thread
//! (a WebSocket's `send`, a TCP stream's `write_all`).

use std::sync::mpsc::{Receiver, Sender, SyncSender, TryRecvError, TrySendError, channel, sync_channel};
use std::time::{Duration, Instant};

/// One watcher: the queue its writer thread sends from.
#[derive(Debug)]
pub struct Watcher<M> {
    queue: SyncSender<M>,
    /// Signalled by the writer thread when it has sent what it had and closed the connection.
    written: Receiver<()>,
}

/// The accepting side's end: a watcher that connected is handed to the [`Fanout`] through it.
pub type Doorbell<M> = Sender<Watcher<M>>;

/// Every watcher, owned by the thread that owns the state they watch.
#[derive(Debug)]
pub struct Fanout<M> {
    arriving: Receiver<Watcher<M>>,
    watchers: Vec<Watcher<M>>,
    /// A message's size, for the count of bytes queued.
    size: fn(&M) -> usize,
    /// Watchers let go because their queue was full or their connection closed.
    pub dropped: u64,
    /// Bytes queued for watchers so far (each watcher counted).
    pub bytes_queued: u64,
}

impl<M: Clone> Fanout<M> {
    /// A fan-out of messages whose size in bytes `size` tells.
    pub fn new(size: fn(&M) -> usize) -> (Self, Doorbell<M>) {
        let (doorbell, arriving) = channel();
        (Self { arriving, watchers: Vec::new(), size, dropped: 0, bytes_queued: 0 }, doorbell)
    }

    pub fn watchers(&self) -> usize {
        self.watchers.len()
    }

    /// Takes in the watchers that connected since the last call, each sent `replay()` (the whole state) first.
    /// Returns how many were taken in.
    pub fn admit(&mut self, mut replay: impl FnMut() -> Vec<M>) -> usize {
        let mut admitted = 0;
        loop {
            let watcher = match self.arriving.try_recv() {
                Ok(w) => w,
                Err(TryRecvError::Empty | TryRecvError::Disconnected) => return admitted,
            };
            let mut accepted = true;
            for message in replay() {
                let bytes = (self.size)(&message) as u64;
                if watcher.queue.try_send(message).is_err() {
                    accepted = false;
                    break;
                }
                self.bytes_queued += bytes;
            }
            if accepted {
                self.watchers.push(watcher);
                admitted += 1;
            } else {
                self.dropped += 1;
            }
        }
    }

    /// Queues `message` for every watcher; one whose queue is full or closed is let go.
    pub fn broadcast(&mut self, message: M) {
        let bytes = (self.size)(&message) as u64;
        let before = self.watchers.len();
        self.watchers.retain(|w| match w.queue.try_send(message.clone()) {
            Ok(()) => true,
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => false,
        });
        self.dropped += (before - self.watchers.len()) as u64;
        self.bytes_queued += bytes * self.watchers.len() as u64;
    }

    /// Lets every watcher go once it has been sent what is queued for it, waiting at most `patience` in all
    /// (the last state of a run reaches the watchers before the process ends).
    pub fn close(mut self, patience: Duration) {
        let deadline = Instant::now() + patience;
        let watchers = std::mem::take(&mut self.watchers);
        let written: Vec<Receiver<()>> = watchers.into_iter().map(|w| w.written).collect();
        for done in written {
            let left = deadline.saturating_duration_since(Instant::now());
            let _ = done.recv_timeout(left);
        }
    }
}

/// Starts the writer thread of one connection, `queue` messages deep, and returns the watcher to hand to the
/// fan-out. The thread owns `connection`: `send` writes one message to it, `close` ends it once the fan-out has
/// let the watcher go. The thread ends when its queue closes or a write fails (the watcher went away).
pub fn start_writer<M: Send + 'static, C: Send + 'static>(
    thread_name: &str,
    queue: usize,
    mut connection: C,
    mut send: impl FnMut(&mut C, M) -> std::io::Result<()> + Send + 'static,
    close: impl FnOnce(C) + Send + 'static,
) -> std::io::Result<Watcher<M>> {
    let (queue, outgoing) = sync_channel::<M>(queue);
    let (done, written) = sync_channel::<()>(1);
    std::thread::Builder::new().name(thread_name.into()).spawn(move || {
        while let Ok(message) = outgoing.recv() {
            if send(&mut connection, message).is_err() {
                let _ = done.send(());
                return;
            }
        }
        close(connection);
        let _ = done.send(());
    })?;
    Ok(Watcher { queue, written })
}

#[cfg(test)]
mod tests {
    use super::*;

    const QUEUE: usize = 16;

    #[test]
    fn a_watcher_that_does_not_keep_up_is_let_go_and_the_others_keep_theirs() {
        let (mut fanout, doorbell) = Fanout::<Vec<u8>>::new(Vec::len);
        // Two watchers whose writers are stand-ins: one drains its queue, one never does.
        let (slow_queue, _slow_outgoing) = sync_channel(QUEUE);
        let (fast_queue, fast_outgoing) = sync_channel(QUEUE);
        let (_, written) = sync_channel(1);
        doorbell.send(Watcher { queue: slow_queue, written }).unwrap();
        let (_, written) = sync_channel(1);
        doorbell.send(Watcher { queue: fast_queue, written }).unwrap();
        assert_eq!(fanout.admit(|| vec![b"hello".to_vec()]), 2);
        let _ = fast_outgoing.recv();
        for i in 0..QUEUE + 10 {
            fanout.broadcast(vec![0u8; 8]);
            while fast_outgoing.try_recv().is_ok() {}
            if i < QUEUE - 1 {
                assert_eq!(fanout.watchers(), 2, "message {i}");
            }
        }
        // The broadcasts never waited; the slow watcher was let go when its queue filled.
        assert_eq!((fanout.watchers(), fanout.dropped), (1, 1));
    }

    #[test]
    fn a_writer_sends_in_order_and_closes_when_let_go() {
        let (mut fanout, doorbell) = Fanout::<Vec<u8>>::new(Vec::len);
        let (sent_to, sent) = channel();
        let (closed_to, closed) = channel();
        let watcher = start_writer(
            "fanout-test",
            QUEUE,
            sent_to,
            |to, m: Vec<u8>| to.send(m).map_err(|_| std::io::Error::other("gone")),
            move |_| closed_to.send(()).unwrap_or(()),
        )
        .unwrap();
        doorbell.send(watcher).unwrap();
        fanout.admit(|| vec![vec![1]]);
        fanout.broadcast(vec![2]);
        fanout.broadcast(vec![3]);
        fanout.close(Duration::from_secs(5));
        assert_eq!(sent.iter().collect::<Vec<_>>(), vec![vec![1], vec![2], vec![3]]);
        assert!(closed.try_recv().is_ok(), "the writer's close ran");
    }
}
