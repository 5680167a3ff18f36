//! The link between the bridge's two sides: a Zenoh session in peer mode over TCP, the receiver listening, the
//! sender connecting — nothing else (no multicast scouting, no gossip, the sender listens nowhere), so nothing is
//! reachable beyond the one address the receiver was told to listen on. Each side publishes its messages on its
//! own key and declares a liveliness token, and watches the other's: a side that comes or goes is seen, which is
//! how the sender knows it must ask for a new conversation.
//!
//! Zenoh hands what arrives to its own threads; they queue it here and write a byte to a socket pair whose other
//! end sits in the service's WaitSet, so the service wakes for the link as for shared memory and nothing polls.
//! The queue is bounded: a receiver that falls behind holds Zenoh's reader, Zenoh's TCP window fills, and the
//! sender's puts block (congestion control `Block`) — the link slows, nothing is dropped on the way.

use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::sync::{Arc, mpsc};

use anyhow::{Context, Result, anyhow};
use zenoh::Wait;
use zenoh::qos::CongestionControl;
use zenoh::sample::SampleKind;

use crate::node::SocketFd;

/// Which side of the bridge this is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    Sender,
    Receiver,
}

impl Side {
    fn name(self) -> &'static str {
        match self {
            Side::Sender => "sender",
            Side::Receiver => "receiver",
        }
    }

    fn other(self) -> Side {
        match self {
            Side::Sender => Side::Receiver,
            Side::Receiver => Side::Sender,
        }
    }
}

/// What came over the link.
#[derive(Debug)]
pub enum Arrival {
    /// A message from the other side (`bdis_bridge::wire`), not yet checked.
    Message(Vec<u8>),
    /// The other side appeared (it started, or the link came back).
    PeerCame,
    /// The other side is gone (it stopped or died, or the link broke).
    PeerLeft,
    /// The far side asks for this host's map (the receiver with `--map-snapshots`); answered through the query.
    SnapshotAsked(zenoh::query::Query),
    /// The far side's answer to [`Link::ask_snapshot`] number `request`: the snapshot's bytes, or why there is
    /// none (no answer within the time, the far side has no mosaic).
    SnapshotAnswer { request: u64, answer: Result<Vec<u8>, String> },
}

/// Where map snapshots are asked for.
const SNAPSHOT_KEY: &str = "bdis/bridge/map-snapshot";

/// Arrivals queued by Zenoh's threads before the service takes them; beyond this, Zenoh's reader waits.
const QUEUE: usize = 64;

pub struct Link {
    session: zenoh::Session,
    deliver: Deliver,
    snapshots: Option<zenoh::query::Queryable<()>>,
    publisher: zenoh::pubsub::Publisher<'static>,
    _messages: zenoh::pubsub::Subscriber<()>,
    _peer: zenoh::pubsub::Subscriber<()>,
    _token: zenoh::liveliness::LivelinessToken,
    arrivals: mpsc::Receiver<Arrival>,
    wake: UnixStream,
}

/// Hands an arrival to the service: queued, and the service woken.
type Deliver = Arc<dyn Fn(Arrival) + Send + Sync>;

/// Sends the `None` answer of a snapshot request whose query ended without a reply.
struct Unanswered {
    deliver: Deliver,
    request: u64,
    answered: std::sync::atomic::AtomicBool,
}

impl Drop for Unanswered {
    fn drop(&mut self) {
        if !self.answered.load(std::sync::atomic::Ordering::Acquire) {
            (self.deliver)(Arrival::SnapshotAnswer { request: self.request, answer: Err("no answer".into()) });
        }
    }
}

/// `HOST:PORT` as a Zenoh TCP endpoint.
fn endpoint(flag: &str, address: &str) -> Result<String> {
    let (host, port) = address.rsplit_once(':').with_context(|| format!("{flag} {address}: not HOST:PORT"))?;
    if host.is_empty() || port.parse::<u16>().is_err() || host.contains(['/', '#', '?', '"', ' ']) {
        return Err(anyhow!("{flag} {address}: not HOST:PORT"));
    }
    Ok(format!("tcp/{address}"))
}

/// The session's configuration: peer mode, only the given endpoint, no discovery.
fn config(side: Side, endpoint: &str) -> Result<zenoh::Config> {
    let mut config = zenoh::Config::default();
    let (listen, connect) = match side {
        Side::Receiver => (format!(r#"["{endpoint}"]"#), "[]".to_string()),
        Side::Sender => ("[]".to_string(), format!(r#"["{endpoint}"]"#)),
    };
    for (key, value) in [
        ("mode", r#""peer""#),
        ("listen/endpoints", listen.as_str()),
        ("connect/endpoints", connect.as_str()),
        ("scouting/multicast/enabled", "false"),
        ("scouting/gossip/enabled", "false"),
        // The admin space would let any peer on the link read the session's state.
        ("adminspace/enabled", "false"),
        // A restarted receiver is found again within a tenth of a second (Zenoh's default waits a second first:
        // a second of keyframes piled up to be sent again).
        ("connect/retry", r#"{ period_init_ms: 100, period_max_ms: 1000, period_increase_factor: 2 }"#),
    ] {
        config.insert_json5(key, value).map_err(|e| anyhow!("zenoh configuration {key}: {e}"))?;
    }
    Ok(config)
}

/// A Zenoh error without the ` at /path/to/file.rs:61.` it appends to each cause.
fn without_locations(message: &str) -> String {
    let mut out = String::with_capacity(message.len());
    let mut rest = message;
    while let Some(at) = rest.find(" at /") {
        out.push_str(&rest[..at]);
        rest = &rest[at + 5..];
        // The location runs to the next space (or the end).
        rest = rest.find(' ').map_or("", |end| &rest[end..]);
    }
    out.push_str(rest);
    out
}

impl Link {
    /// Opens this side's session. The receiver's listening address is taken here: a port in use is an error now.
    pub fn open(side: Side, flag: &str, address: &str) -> Result<Link> {
        let endpoint = endpoint(flag, address)?;
        if side == Side::Receiver {
            // Said plainly here rather than in Zenoh's words (it names its own source files).
            std::net::TcpListener::bind(address).with_context(|| format!("{flag} {address}: cannot listen"))?;
        }
        let session = zenoh::open(config(side, &endpoint)?)
            .wait()
            .map_err(|e| anyhow!("{flag} {address}: cannot open the link: {}", without_locations(&e.to_string())))?;
        let (wake_tx, wake) = UnixStream::pair().context("the link's wake-up pair")?;
        wake.set_nonblocking(true).context("a non-blocking wake-up socket")?;
        wake_tx.set_nonblocking(true).context("a non-blocking wake-up socket")?;
        let (tx, arrivals) = mpsc::sync_channel(QUEUE);
        let deliver: Deliver = Arc::new(move |arrival: Arrival| {
            // A closed queue: the service is stopping, nothing to tell.
            if tx.send(arrival).is_ok() {
                // Full: the service has a wake-up waiting already.
                let _ = (&wake_tx).write(&[1]);
            }
        });
        let root = "bdis/bridge";
        let publisher = session
            .declare_publisher(format!("{root}/to-{}", side.other().name()))
            .congestion_control(CongestionControl::Block)
            .wait()
            .map_err(|e| anyhow!("the link's publisher: {e}"))?;
        let on_message = Arc::clone(&deliver);
        let messages = session
            .declare_subscriber(format!("{root}/to-{}", side.name()))
            .callback(move |sample| on_message(Arrival::Message(sample.payload().to_bytes().into_owned())))
            .wait()
            .map_err(|e| anyhow!("the link's subscriber: {e}"))?;
        let peer = session
            .liveliness()
            .declare_subscriber(format!("{root}/{}", side.other().name()))
            .history(true)
            .callback({
                let deliver = Arc::clone(&deliver);
                move |sample| {
                    deliver(match sample.kind() {
                        SampleKind::Put => Arrival::PeerCame,
                        SampleKind::Delete => Arrival::PeerLeft,
                    })
                }
            })
            .wait()
            .map_err(|e| anyhow!("the link's watch on the {}: {e}", side.other().name()))?;
        // Declared last: when the other side sees it, this side's subscriber is already known.
        let token = session
            .liveliness()
            .declare_token(format!("{root}/{}", side.name()))
            .wait()
            .map_err(|e| anyhow!("the link's liveliness token: {e}"))?;
        Ok(Link {
            session,
            deliver,
            snapshots: None,
            publisher,
            _messages: messages,
            _peer: peer,
            _token: token,
            arrivals,
            wake,
        })
    }

    /// What the WaitSet waits on for this link.
    pub fn wake_fd(&self) -> Option<SocketFd> {
        SocketFd::of(&self.wake)
    }

    /// Everything that has arrived, oldest first.
    pub fn arrivals(&mut self) -> Vec<Arrival> {
        let mut drained = [0u8; 256];
        while matches!((&self.wake).read(&mut drained), Ok(n) if n > 0) {}
        self.arrivals.try_iter().collect()
    }

    /// Sends one message; blocks while the link is congested.
    pub fn send(&self, message: Vec<u8>) -> Result<()> {
        self.publisher.put(message).wait().map_err(|e| anyhow!("send on the link: {e}"))
    }

    /// Answers the far side's requests for this host's map: each comes as [`Arrival::SnapshotAsked`].
    pub fn serve_snapshots(&mut self) -> Result<()> {
        let deliver = Arc::clone(&self.deliver);
        let queryable = self
            .session
            .declare_queryable(SNAPSHOT_KEY)
            .callback(move |query| deliver(Arrival::SnapshotAsked(query)))
            .wait()
            .map_err(|e| anyhow!("the link's snapshot queryable: {e}"))?;
        self.snapshots = Some(queryable);
        Ok(())
    }

    /// Asks the far side for its map; the answer comes as [`Arrival::SnapshotAnswer`] with this `request`
    /// number, within `within` (or as an error).
    pub fn ask_snapshot(&self, request: u64, query: Vec<u8>, within: std::time::Duration) -> Result<()> {
        let pending = Unanswered {
            deliver: Arc::clone(&self.deliver),
            request,
            answered: std::sync::atomic::AtomicBool::new(false),
        };
        self.session
            .get(SNAPSHOT_KEY)
            .payload(query)
            .timeout(within)
            .callback(move |reply| {
                // The first reply answers; the query's end (dropping this callback) answers "none" otherwise.
                if pending.answered.swap(true, std::sync::atomic::Ordering::AcqRel) {
                    return;
                }
                let answer = match reply.result() {
                    Ok(sample) => Ok(sample.payload().to_bytes().into_owned()),
                    Err(e) => Err(String::from_utf8_lossy(&e.payload().to_bytes()).into_owned()),
                };
                (pending.deliver)(Arrival::SnapshotAnswer { request, answer });
            })
            .wait()
            .map_err(|e| anyhow!("ask the far side for its map: {e}"))
    }

    /// Closes the session, after what was sent has gone out.
    pub fn close(self) {
        let Link { session, publisher, _messages, _peer, _token, snapshots, .. } = self;
        drop((publisher, _messages, _peer, _token, snapshots));
        if let Err(e) = session.close().wait() {
            tracing::debug!("closing the link: {e}");
        }
    }
}
