//! `bdis-bridge`: carries chosen topics of a pipeline to a pipeline on another host (or another iceoryx2 system on
//! this one). On the host that produces them, `bdis-bridge send --to HOST:PORT` takes the topics from shared
//! memory and sends them over a Zenoh link (TCP); on the host that consumes them, `bdis-bridge receive --listen ADDR` publishes
//! them into its shared memory with the topics' own QoS, as if their producer ran there. Every sample is kept by
//! the sender until the receiver has published it, so a broken connection or a restart of either side loses
//! nothing and publishes nothing twice. The raw frame stream is never carried (two 1080p frames at 30 fps are
//! beyond a hospital's gigabit link): put acquisition and tracking on the same host.

mod link;
mod node;
mod receive;
mod send;
mod snapshot;

use clap::{Parser, Subcommand};

/// Bridge service: the pipeline's keyframes, depth keyframes, pose corrections and poses between two hosts over
/// Zenoh (TCP, peer to peer: the receiver listens, the sender connects; nothing else is opened).
#[derive(Debug, Parser)]
#[command(name = "bdis-bridge", version)]
struct Args {
    #[command(subcommand)]
    role: Role,
    /// The topics to carry, comma-separated: keyframes, depth, corrections, poses (both sides must name the same).
    /// The mosaic on the far host needs depth and corrections — or keyframes and corrections with the stereo
    /// service there too —, a viewer or the OpenIGTLink output there also poses.
    #[arg(long, global = true, value_delimiter = ',', default_value = "depth,corrections,poses")]
    topics: Vec<String>,
    /// Carry the map snapshot too (both sides): the sender's host gets `bdis/v1/map/snapshot` answered by the
    /// mosaic on the receiver's host, so `bdis-slam snapshot` and the OpenIGTLink output work there. Only where
    /// no mosaic runs on the sender's host.
    #[arg(long, global = true)]
    map_snapshots: bool,
    /// Name of this process in the run.
    #[arg(long, global = true, env = "BDIS_SERVICE_NAME", default_value = "bridge")]
    name: String,
    /// Shared-memory name prefix of the run (set by the launcher).
    #[arg(long, global = true, env = bdis_ipc::PREFIX_ENV, default_value = bdis_ipc::DEFAULT_PREFIX)]
    ipc_prefix: String,
}

#[derive(Debug, Subcommand)]
enum Role {
    /// On the producing host: take the topics from shared memory and send them to a receiver.
    Send {
        /// The receiver's address (`bdis-bridge receive --listen` on the other host).
        #[arg(long)]
        to: String,
        /// Samples kept for the receiver while the link is down, at most this many MiB (the oldest unsent go
        /// first, counted and logged).
        #[arg(long, default_value_t = 512)]
        outbox_mib: usize,
    },
    /// On the consuming host: publish what a sender sends into this host's shared memory.
    Receive {
        /// Address to listen on; the default takes connections from this machine only. What an open port
        /// carries: depth keyframes with the left images of the patient's tissue, and the scope's poses.
        #[arg(long, default_value = "127.0.0.1:18960")]
        listen: String,
    },
}

fn main() -> std::process::ExitCode {
    bdis_node::init_logging();
    bdis_node::protect_patient_data();
    let args = Args::parse();
    let topics = (|| {
        let mut topics = Vec::new();
        for name in &args.topics {
            let topic = bdis_bridge::Carried::parse(name.trim()).ok_or_else(|| {
                anyhow::anyhow!(
                    "--topics: `{name}` is not a topic the bridge carries (keyframes, depth, corrections, poses)"
                )
            })?;
            if !topics.contains(&topic) {
                topics.push(topic);
            }
        }
        Ok(topics)
    })();
    let result = topics.and_then(|topics| {
        let common =
            node::Common { topics, name: args.name, ipc_prefix: args.ipc_prefix, map_snapshots: args.map_snapshots };
        match args.role {
            Role::Send { to, outbox_mib } => send::run(common, &to, outbox_mib << 20),
            Role::Receive { listen } => receive::run(common, &listen),
        }
    });
    bdis_node::finish("bdis-bridge", result)
}
