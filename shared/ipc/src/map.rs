//! The map-snapshot contract: a viewer or tool asks the mosaic service for the current dense map
//! (request-response) and gets its points as one slice of fixed-size records in shared memory. Requests and
//! responses are signalled on the event service of the same name ([`event_id::MAP_REQUEST`],
//! [`event_id::MAP_RESPONSE`](crate::event_id::MAP_RESPONSE)), so neither side polls.
//!
//! [`event_id::MAP_REQUEST`]: crate::event_id::MAP_REQUEST

use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::request_response::PortFactory as RequestResponseFactory;

use crate::{Ipc, IpcError, iox, qos};

/// A snapshot request (`bdis.v1.MapQuery`).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v1.MapQuery")]
pub struct MapQuery {
    /// At most this many points (every k-th point of the map is sent when it has more); 0 = all.
    pub max_points: u64,
    pub reserved: u64,
}

/// One map point in world coordinates (`bdis.v1.MapPoint`), millimetres.
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v1.MapPoint")]
pub struct MapPoint {
    pub xyz: [f32; 3],
    pub rgb: [u8; 3],
    /// Confidence in [0, 1] scaled to 0–255.
    pub confidence: u8,
    pub kf_id: u32,
}

/// Header of a snapshot response (`bdis.v1.MapSnapshotHeader`).
#[repr(C)]
#[derive(Debug, Default, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("bdis.v1.MapSnapshotHeader")]
pub struct MapSnapshotHeader {
    /// Points in the map when the snapshot was taken.
    pub points_in_map: u64,
    /// Every `stride`-th point was sent (1 = all).
    pub stride: u64,
    pub keyframes: u64,
    /// Depth keyframes the map has taken in so far, and pose corrections applied.
    pub keyframes_inserted: u64,
    pub corrections_applied: u64,
    pub t_publish_ns: u64,
}

pub type MapSnapshotService = RequestResponseFactory<ipc::Service, MapQuery, (), [MapPoint], MapSnapshotHeader>;

/// The service name of the snapshot service and of its event service.
pub const MAP_SNAPSHOT_SERVICE: &str = "bdis/v1/map/snapshot";

impl Ipc {
    pub fn map_snapshot(&self) -> Result<MapSnapshotService, IpcError> {
        let name = ServiceName::new(MAP_SNAPSHOT_SERVICE)
            .map_err(|e| IpcError::Name { name: MAP_SNAPSHOT_SERVICE.into(), detail: format!("{e:?}") })?;
        Self::with_retry("open the map snapshot service", || {
            self.node
                .service_builder(&name)
                .request_response::<MapQuery, [MapPoint]>()
                .response_user_header::<MapSnapshotHeader>()
                .max_servers(qos::MAP_SNAPSHOT_MAX_SERVERS)
                .max_clients(qos::MAP_SNAPSHOT_MAX_CLIENTS)
                .max_nodes(qos::MAX_NODES)
                .max_active_requests_per_client(1)
                .max_response_buffer_size(1)
                .enable_safe_overflow_for_responses(true)
                .open_or_create()
        })
    }

    /// The event service on which requests and responses of the snapshot service are signalled.
    pub fn map_snapshot_events(&self) -> Result<crate::Events, IpcError> {
        let name = ServiceName::new(MAP_SNAPSHOT_SERVICE)
            .map_err(|e| IpcError::Name { name: MAP_SNAPSHOT_SERVICE.into(), detail: format!("{e:?}") })?;
        self.event_service(&name, "map snapshot events")
    }
}

/// The server side: the map's owner answers requests with `initial_points` of room to start with (the segment
/// grows when the map does).
pub fn map_server(
    service: &MapSnapshotService,
    initial_points: usize,
) -> Result<iceoryx2::port::server::Server<ipc::Service, MapQuery, (), [MapPoint], MapSnapshotHeader>, IpcError> {
    service
        .server_builder()
        .initial_max_slice_len(initial_points.max(1))
        .allocation_strategy(AllocationStrategy::PowerOfTwo)
        .create()
        .map_err(iox("create the map snapshot server"))
}
