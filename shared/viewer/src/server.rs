//! The HTTP side: a small blocking server (no async runtime), read-only — it answers GET and HEAD and nothing
//! else, so the page cannot steer anything — with a content security policy that lets the page load only from
//! this server.

use std::net::SocketAddr;

use tiny_http::{Header, Method, Request, Response, Server, StatusCode};

use crate::hub::{Doorbell, start_writer};
use crate::{RunView, ViewerError, assets::ASSETS};

/// Everything the page may load comes from this origin; nothing from a CDN, no fonts from the web.
const CONTENT_SECURITY_POLICY: &str = "default-src 'self'; img-src 'self'; style-src 'self'; script-src 'self'; connect-src 'self'; frame-ancestors 'none'";

/// Listens on `addr` (port 0: any free port); returns the server and the address it got.
pub fn bind(addr: &str) -> Result<(Server, SocketAddr), ViewerError> {
    let listen_error = |what: String| ViewerError::Listen { addr: addr.to_string(), what };
    let server = Server::http(addr).map_err(|e| listen_error(e.to_string()))?;
    let local = server.server_addr().to_ip().ok_or_else(|| listen_error("not an IP address".into()))?;
    Ok((server, local))
}

/// What the server shows: a finished run, or a live pipeline (the page then opens `/ws`).
#[derive(Debug)]
pub struct Site {
    run: Option<RunView>,
    run_json: Vec<u8>,
    /// Live: where a browser that opened the WebSocket is handed to the live state's owner.
    doorbell: Option<Doorbell>,
    orbit_controls: Vec<u8>,
}

fn header(name: &str, value: &str) -> Option<Header> {
    Header::from_bytes(name.as_bytes(), value.as_bytes()).ok()
}

impl Site {
    pub fn new(run: RunView) -> Result<Self, ViewerError> {
        let run_json = serde_json::to_vec(&run.summary)
            .map_err(|e| ViewerError::File { path: run.dir.clone(), what: format!("cannot describe the run: {e}") })?;
        Ok(Self { run: Some(run), run_json, doorbell: None, orbit_controls: crate::assets::orbit_controls() })
    }

    /// A live pipeline called `name`: `/api/run` says so, and `/ws` streams the live state (see [`crate::live`]).
    pub fn live(name: &str, doorbell: Doorbell) -> Self {
        let run_json = serde_json::json!({
            "live": true, "name": name, "path": [], "keyframes": [], "map_keyframes": 0, "map_points": 0,
            "latency": null, "has_depth_preview": false, "has_map_preview": false,
        })
        .to_string()
        .into_bytes();
        Self { run: None, run_json, doorbell: Some(doorbell), orbit_controls: crate::assets::orbit_controls() }
    }

    /// The body and content type for `path`, or None (404).
    pub fn lookup(&self, path: &str) -> Option<(&[u8], &'static str)> {
        let path = path.split(['?', '#']).next().unwrap_or(path);
        if let Some((_, kind, bytes)) = ASSETS.iter().find(|(p, _, _)| *p == path) {
            return Some((bytes, kind));
        }
        match path {
            "/vendor/three/OrbitControls.js" => Some((&self.orbit_controls, "text/javascript; charset=utf-8")),
            "/api/run" => Some((&self.run_json, "application/json")),
            "/api/map" => self.run.as_ref().map(|r| (r.map_blocks.as_slice(), "application/octet-stream")),
            "/api/depth.png" => self.run.as_ref()?.depth_preview_png.as_deref().map(|b| (b, "image/png")),
            "/api/map.png" => self.run.as_ref()?.map_preview_png.as_deref().map(|b| (b, "image/png")),
            _ => None,
        }
    }

    /// Answers one request. An error sending (the browser went away) is the browser's business: it is returned
    /// for the caller to log, never fatal.
    pub fn answer(&self, request: Request) -> std::io::Result<()> {
        let mut headers: Vec<Header> = [
            header("Content-Security-Policy", CONTENT_SECURITY_POLICY),
            header("X-Content-Type-Options", "nosniff"),
            header("Cache-Control", "no-store"),
        ]
        .into_iter()
        .flatten()
        .collect();
        if !matches!(request.method(), Method::Get | Method::Head) {
            headers.extend(header("Allow", "GET, HEAD"));
            let body: &[u8] = b"read-only: GET and HEAD only\n";
            return request.respond(Response::new(StatusCode(405), headers, body, Some(body.len()), None));
        }
        if request.url() == "/ws"
            && let Some(doorbell) = &self.doorbell
        {
            return open_websocket(request, doorbell, headers);
        }
        let (status, body, kind): (u16, &[u8], &str) = match self.lookup(request.url()) {
            Some((body, kind)) => (200, body, kind),
            None => (404, b"not found\n", "text/plain; charset=utf-8"),
        };
        headers.extend(header("Content-Type", kind));
        // tiny_http leaves the body out of an answer to HEAD itself. The length is known, so it is sent, not
        // chunks: any client can read the answer.
        let response = Response::new(StatusCode(status), headers, body, Some(body.len()), None);
        request.respond(response.with_chunked_threshold(usize::MAX))
    }

    /// Serves until the process is stopped (the page reads a finished run; there is nothing to flush).
    pub fn serve(&self, server: &Server) {
        for request in server.incoming_requests() {
            if let Err(e) = self.answer(request) {
                eprintln!("bdis-viewer: a browser went away mid-answer: {e}");
            }
        }
    }
}

fn request_header<'a>(request: &'a Request, name: &'static str) -> Option<&'a str> {
    request.headers().iter().find(|h| h.field.equiv(name)).map(|h| h.value.as_str())
}

/// The WebSocket handshake (RFC 6455), then the connection is handed to a writer thread and the hub.
fn open_websocket(request: Request, doorbell: &Doorbell, mut headers: Vec<Header>) -> std::io::Result<()> {
    let upgrade = request_header(&request, "Upgrade").is_some_and(|v| v.eq_ignore_ascii_case("websocket"));
    let Some(key) = request_header(&request, "Sec-WebSocket-Key").filter(|_| upgrade).map(str::to_owned) else {
        let body: &[u8] = b"a WebSocket: send Upgrade: websocket and Sec-WebSocket-Key\n";
        return request.respond(Response::new(StatusCode(400), headers, body, Some(body.len()), None));
    };
    headers.extend(header("Upgrade", "websocket"));
    headers.extend(header("Connection", "Upgrade"));
    headers.extend(header("Sec-WebSocket-Accept", &tungstenite::handshake::derive_accept_key(key.as_bytes())));
    let empty: &[u8] = &[];
    let stream = request.upgrade("websocket", Response::new(StatusCode(101), headers, empty, Some(0), None));
    let watcher = start_writer(stream)?;
    // The live state's owner has ended (the run is over): the browser sees the socket close.
    let _ = doorbell.send(watcher);
    Ok(())
}
