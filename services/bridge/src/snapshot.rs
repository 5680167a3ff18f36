//! The map snapshot across the link (`--map-snapshots` on both sides): on the host without the mosaic the bridge
//! serves `bdis/v1/map/snapshot` as the mosaic would ([`Serve`]: each request becomes a Zenoh query), and on the
//! mosaic's host it asks the mosaic for each query it receives ([`Relay`]: one request at a time, as the
//! contract allows a client), answering with the snapshot as bytes (`bdis_bridge::records`). So `bdis-slam
//! snapshot` and the OpenIGTLink output work on host A against the map made on host B. A request the far side
//! cannot answer (no mosaic there, or no answer within [`ANSWER_WITHIN`]) gets no response: the asker's own
//! deadline tells it, as when the mosaic is busy on one host.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow};
use bdis_bridge::records;
use bdis_ipc::map::{MapPoint, MapQuery, MapSnapshotHeader, MapSnapshotService};
use bdis_ipc::{Ipc, event_id};
use iceoryx2::active_request::ActiveRequest;
use iceoryx2::pending_response::PendingResponse;
use iceoryx2::port::client::Client;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::server::Server;
use iceoryx2::prelude::*;
use zenoh::Wait;

use crate::link::Link;

/// How long the far side has to answer a snapshot request (`bdis-slam snapshot` waits 5 s by default).
pub const ANSWER_WITHIN: Duration = Duration::from_secs(4);

type Request = ActiveRequest<ipc::Service, MapQuery, (), [MapPoint], MapSnapshotHeader>;

/// The host without the mosaic: serves snapshots from the far host's map.
pub struct Serve {
    server: Server<ipc::Service, MapQuery, (), [MapPoint], MapSnapshotHeader>,
    _service: MapSnapshotService,
    responses: Notifier<ipc::Service>,
    /// Requests asked of the far side, by the number their answer will carry.
    waiting: Vec<(u64, Request)>,
    next: u64,
    pub served: u64,
    pub unanswered: u64,
}

impl Serve {
    /// The server, and the listener its clients' requests wake (for the service's WaitSet, which drains it).
    pub fn open(ipc: &Ipc) -> Result<(Serve, Listener<ipc::Service>)> {
        let service = ipc.map_snapshot()?;
        let server = bdis_ipc::map::map_server(&service, 32_768)?;
        let events = ipc.map_snapshot_events()?;
        let requests = ipc.listener(&events)?;
        let serve = Serve {
            server,
            _service: service,
            responses: ipc.notifier(&events)?,
            waiting: Vec::new(),
            next: 0,
            served: 0,
            unanswered: 0,
        };
        Ok((serve, requests))
    }

    /// Takes this host's requests and asks the far side for each.
    pub fn take_requests(&mut self, link: &Link) -> Result<()> {
        while let Some(request) = self.server.receive().context("receive a snapshot request")? {
            let mut query = Vec::with_capacity(records::QUERY_BYTES);
            records::put_query(&mut query, request.payload());
            let number = self.next;
            self.next += 1;
            link.ask_snapshot(number, query, ANSWER_WITHIN)?;
            self.waiting.push((number, request));
        }
        Ok(())
    }

    /// The far side's answer to request `number`: the snapshot, sent to the client that asked; or nothing (its
    /// deadline tells it).
    pub fn answered(&mut self, number: u64, answer: Result<Vec<u8>, String>) -> Result<()> {
        let Some(at) = self.waiting.iter().position(|(n, _)| *n == number) else { return Ok(()) };
        let (_, request) = self.waiting.swap_remove(at);
        let bytes = match answer {
            Ok(bytes) => bytes,
            Err(why) => {
                self.unanswered += 1;
                tracing::warn!("a map snapshot request went unanswered by the far host: {why}");
                return Ok(());
            }
        };
        let (header, count) = match records::snapshot_header(&bytes) {
            Ok(h) => h,
            Err(e) => {
                self.unanswered += 1;
                tracing::warn!("the far host's map snapshot is refused: {e}");
                return Ok(());
            }
        };
        let mut loan =
            request.loan_slice_uninit(count).with_context(|| format!("loan a snapshot of {count} points"))?;
        for slot in loan.payload_mut().iter_mut() {
            slot.write(MapPoint::default());
        }
        // SAFETY: every element of the slice was written just above.
        let mut response = unsafe { loan.assume_init() };
        if let Err(e) = records::snapshot_points(&bytes, response.payload_mut()) {
            self.unanswered += 1;
            tracing::warn!("the far host's map snapshot is refused: {e}");
            return Ok(());
        }
        *response.user_header_mut() = header;
        response.send().context("send a snapshot")?;
        bdis_ipc::notify(&self.responses, event_id::MAP_RESPONSE)?;
        self.served += 1;
        Ok(())
    }
}

type Pending = PendingResponse<ipc::Service, MapQuery, (), [MapPoint], MapSnapshotHeader>;

/// The mosaic's host: answers the far side's queries by asking the mosaic here.
pub struct Relay {
    service: MapSnapshotService,
    client: Option<Client<ipc::Service, MapQuery, (), [MapPoint], MapSnapshotHeader>>,
    requests: Notifier<ipc::Service>,
    queue: VecDeque<zenoh::query::Query>,
    /// The query being answered, the mosaic's pending response, and when it was asked.
    in_flight: Option<(zenoh::query::Query, Pending, Instant)>,
    pub relayed: u64,
}

impl Relay {
    /// The relay, and the listener the mosaic's responses wake (for the service's WaitSet, which drains it).
    pub fn open(ipc: &Ipc) -> Result<(Relay, Listener<ipc::Service>)> {
        let events = ipc.map_snapshot_events()?;
        let relay = Relay {
            service: ipc.map_snapshot()?,
            client: None,
            requests: ipc.notifier(&events)?,
            queue: VecDeque::new(),
            in_flight: None,
            relayed: 0,
        };
        Ok((relay, ipc.listener(&events)?))
    }

    pub fn asked(&mut self, query: zenoh::query::Query) {
        self.queue.push_back(query);
    }

    /// Answers what the mosaic has answered, and asks it the next query.
    pub fn progress(&mut self) -> Result<()> {
        if let Some((query, pending, asked_at)) = &self.in_flight {
            match pending.receive().map_err(|e| anyhow!("receive a snapshot: {e:?}"))? {
                Some(response) => {
                    let mut bytes = Vec::new();
                    records::put_snapshot(&mut bytes, response.user_header(), response.payload());
                    if let Err(e) = query.reply(query.key_expr().clone(), bytes).wait() {
                        tracing::warn!("answer the far host's map snapshot request: {e}");
                    }
                    self.relayed += 1;
                }
                // The mosaic stopped or is stuck: the asker has given up by now; the next query may fare better.
                None if asked_at.elapsed() > ANSWER_WITHIN => {
                    tracing::warn!("the mosaic did not answer a map snapshot request within {ANSWER_WITHIN:?}");
                }
                None => return Ok(()),
            }
            self.in_flight = None;
        }
        while let Some(query) = self.queue.pop_front() {
            let asked = query.payload().map(|p| p.to_bytes()).ok_or_else(|| "no request".to_string());
            let asked = asked.and_then(|bytes| records::query(&bytes).map_err(|e| e.to_string()));
            let refused = match asked {
                Err(why) => Some(format!("a malformed request: {why}")),
                Ok(_) if self.service.dynamic_config().number_of_servers() == 0 => {
                    Some("no mosaic service runs on the far host".to_string())
                }
                Ok(map_query) => {
                    let client = match &self.client {
                        Some(c) => c,
                        None => self.client.insert(
                            self.service
                                .client_builder()
                                .create()
                                .map_err(|e| anyhow!("create the snapshot client: {e:?}"))?,
                        ),
                    };
                    let pending = client.send_copy(map_query).map_err(|e| anyhow!("ask the mosaic: {e:?}"))?;
                    bdis_ipc::notify(&self.requests, event_id::MAP_REQUEST)?;
                    self.in_flight = Some((query, pending, Instant::now()));
                    return Ok(());
                }
            };
            if let Some(why) = refused
                && let Err(e) = query.reply_err(why).wait()
            {
                tracing::warn!("refuse a map snapshot request: {e}");
            }
        }
        Ok(())
    }
}
