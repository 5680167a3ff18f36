#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! `bdis-slam view RUN_DIR` over a real demo run: the page and its data over HTTP (the map's blocks are the
//! points of `map.ply`, the path is `trajectory.tum`), read-only, nothing from off the machine; and the page in
//! headless Chromium with software GL and no name resolution beyond this machine: the map is drawn as tissue,
//! the scope's frustum and the depth panel are there. And the live view: `run --track --view` with the viewer
//! service over a real pipeline, its WebSocket stream checked message by message against the run's results.

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::Duration;

use common::{TempDir, bdis_slam, prefix, render_small_colon, run_with_timeout, text};

/// One demo run for every test here.
fn demo_run() -> &'static Path {
    static RUN: OnceLock<TempDir> = OnceLock::new();
    RUN.get_or_init(|| {
        let tmp = TempDir::new("viewer").removed_at_exit();
        let out = run_with_timeout(
            Command::new(bdis_slam()).args(["demo", "--frames", "24", "--out"]).arg(tmp.path()),
            Duration::from_secs(180),
        );
        assert!(out.status.success(), "{}\n{}", text(&out.stdout), text(&out.stderr));
        tmp
    })
    .path()
}

/// `bdis-slam view` on a free port; killed when dropped.
struct Viewer {
    child: Child,
    addr: String,
}

impl Viewer {
    fn start(run_dir: &Path) -> Self {
        let mut child = Command::new(bdis_slam())
            .arg("view")
            .arg(run_dir)
            .args(["--listen", "127.0.0.1:0"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
        let addr = line.split("http://").nth(1).and_then(|s| s.split('/').next()).unwrap_or_default().to_string();
        assert!(addr.starts_with("127.0.0.1:"), "the viewer said {line:?}");
        Self { child, addr }
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        self.child.kill().ok();
        self.child.wait().ok();
    }
}

/// One HTTP/1.1 exchange: status, headers (lower-case names), body (Content-Length of it, or to the close).
fn http(addr: &str, method: &str, path: &str) -> (u16, Vec<(String, String)>, Vec<u8>) {
    let mut stream = TcpStream::connect(addr).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(stream, "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: 0\r\n\r\n")
        .unwrap();
    let mut raw = Vec::new();
    let mut chunk = [0u8; 65536];
    let split = loop {
        if let Some(at) = raw.windows(4).position(|w| w == b"\r\n\r\n") {
            break at;
        }
        let n = stream.read(&mut chunk).unwrap();
        assert!(n > 0, "{addr}{path}: the connection closed before the headers ended");
        raw.extend_from_slice(&chunk[..n]);
    };
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let mut lines = head.lines();
    let status = lines.next().unwrap().split(' ').nth(1).unwrap().parse().unwrap();
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    let mut body = raw[split + 4..].to_vec();
    match header(&headers, "content-length").and_then(|v| v.parse::<usize>().ok()) {
        Some(length) => {
            while body.len() < length {
                let n = stream.read(&mut chunk).unwrap();
                assert!(n > 0, "{addr}{path}: {} of {length} bytes", body.len());
                body.extend_from_slice(&chunk[..n]);
            }
        }
        None => {
            stream.read_to_end(&mut body).unwrap();
        }
    }
    (status, headers, body)
}

fn header<'a>(headers: &'a [(String, String)], name: &str) -> Option<&'a str> {
    headers.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
}

/// The map's blocks (see shared/viewer/src/encode.rs): every point in world coordinates, and every normal.
fn decode_map(bytes: &[u8]) -> (Vec<[f32; 3]>, Vec<[i8; 3]>, usize) {
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    let f32_at = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    assert_eq!(&bytes[..8], bdis_viewer::MAP_MAGIC);
    let blocks = u32_at(8) as usize;
    let (mut world, mut normals) = (Vec::new(), Vec::new());
    let mut at = 16;
    for _ in 0..blocks {
        let n = u32_at(at + 8) as usize;
        let m: Vec<f32> = (0..16).map(|i| f32_at(at + 4 * (4 + 6 + i))).collect();
        at += bdis_viewer::KEYFRAME_HEADER_BYTES;
        for i in 0..n {
            let p: Vec<f32> = (0..3).map(|k| f32_at(at + 12 * i + 4 * k)).collect();
            // Column-major 4x4: world = M · (p, 1).
            world.push([0, 1, 2].map(|r| m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r]));
        }
        at += 12 * n;
        for i in 0..n {
            normals.push([0, 1, 2].map(|k| bytes[at + 3 * i + k] as i8));
        }
        at += 6 * n;
        at = at.next_multiple_of(4);
    }
    assert_eq!(at, bytes.len(), "the map's blocks end where the answer ends");
    (world, normals, blocks)
}

#[test]
fn the_page_and_its_data_are_served_read_only_and_match_the_run() {
    let run = demo_run();
    let viewer = Viewer::start(run);

    let (status, headers, page) = http(&viewer.addr, "GET", "/");
    assert_eq!(status, 200);
    let policy = header(&headers, "content-security-policy").unwrap_or_default();
    assert!(policy.contains("default-src 'self'"), "the page may load only from the viewer: {policy:?}");
    for (path, body) in [("/", page), ("/viewer.js", http(&viewer.addr, "GET", "/viewer.js").2)] {
        let body = String::from_utf8(body).unwrap();
        assert!(!body.contains("http://") && !body.contains("https://"), "{path} names a place off the machine");
    }
    for asset in ["/vendor/three/three.module.js", "/vendor/three/three.core.js", "/vendor/three/OrbitControls.js"] {
        let (status, headers, body) = http(&viewer.addr, "GET", asset);
        assert_eq!(status, 200, "{asset}");
        assert!(header(&headers, "content-type").unwrap_or_default().starts_with("text/javascript"), "{asset}");
        assert!(
            !String::from_utf8(body).unwrap().contains("from 'three'"),
            "{asset}: a bare import needs an import map"
        );
    }
    // Read-only: nothing but GET and HEAD.
    assert_eq!(http(&viewer.addr, "POST", "/api/run").0, 405);
    assert_eq!(http(&viewer.addr, "PUT", "/").0, 405);
    assert_eq!(http(&viewer.addr, "GET", "/../map.bin").0, 404);

    // The map's blocks are map.ply's points, in the same order, placed by their keyframes' matrices.
    let ply = bdis_core::formats::ply::read(&run.join("map.ply")).unwrap();
    let (status, _, map) = http(&viewer.addr, "GET", "/api/map");
    assert_eq!(status, 200);
    let (world, normals, blocks) = decode_map(&map);
    assert!(blocks >= 2 && world.len() > 1000, "{blocks} keyframes, {} points", world.len());
    assert_eq!(world.len(), ply.positions.len());
    let scale = ply.positions.iter().map(|p| p[2].abs()).fold(0f32, f32::max);
    for (a, b) in world.iter().zip(&ply.positions) {
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() <= 1e-5 * scale, "{a:?} against map.ply's {b:?}");
        }
    }
    for n in &normals {
        let len = n.iter().map(|&v| f32::from(v).powi(2)).sum::<f32>().sqrt() / 127.0;
        assert!((len - 1.0).abs() < 0.03, "{n:?} is not a unit normal");
    }

    // The path is the trajectory, each pose with the tracker's state; the latency report rides along.
    let trajectory = bdis_core::formats::trajectory::read_tum(&run.join("trajectory.tum")).unwrap();
    let (_, _, body) = http(&viewer.addr, "GET", "/api/run");
    let summary: serde_json::Value = serde_json::from_slice(&body).unwrap();
    let path = summary["path"].as_array().unwrap();
    assert_eq!(path.len(), trajectory.len());
    assert!(path.iter().all(|p| ["ok", "uncertain", "lost"].contains(&p["state"].as_str().unwrap())), "{path:?}");
    assert_eq!(summary["map_points"].as_u64().unwrap() as usize, world.len());
    let processes = summary["latency"]["processes"].as_array().unwrap();
    assert!(processes.iter().any(|p| p["name"] == "tracking"), "{processes:?}");
    let (status, headers, png) = http(&viewer.addr, "GET", "/api/depth.png");
    assert_eq!((status, header(&headers, "content-type")), (200, Some("image/png")));
    assert!(image::load_from_memory(&png).is_ok());
}

fn chromium() -> PathBuf {
    let found = ["chromium", "chromium-browser", "google-chrome"].iter().find_map(|name| {
        std::env::var_os("PATH")?.to_str()?.split(':').map(|d| Path::new(d).join(name)).find(|p| p.is_file())
    });
    found.expect("the viewer's test needs Chromium: `apt-get install chromium` (the README's set-up line)")
}

/// Headless Chromium with software GL, and no name resolution beyond this machine: a page that fetched
/// anything from the web would not load it.
fn headless(url: &str, what: &[&str]) -> std::process::Output {
    let profile = TempDir::new("chromium");
    run_with_timeout(
        Command::new(chromium())
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu-sandbox",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                "--no-first-run",
                "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
                "--window-size=1280,800",
                "--virtual-time-budget=30000",
            ])
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .args(what)
            .arg(url),
        Duration::from_secs(120),
    )
}

#[test]
fn the_page_draws_the_map_the_scope_and_the_depth_in_headless_chromium() {
    let run = demo_run();
    let viewer = Viewer::start(run);
    let url = format!("http://{}/", viewer.addr);

    // The page says it drew every keyframe block, and no error. A Chromium started cold (its binary not yet in
    // the page cache, as on a fresh CI machine) was seen once to end its virtual-time budget before the page's
    // modules had run: the page is then loaded again, at most twice more; an error in the page fails at once.
    let blocks = decode_map(&http(&viewer.addr, "GET", "/api/map").2).2;
    let ready = format!("data-ready=\"{blocks}\"");
    let mut dom_text = String::new();
    for _ in 0..3 {
        dom_text = text(&headless(&url, &["--dump-dom"]).stdout);
        assert!(!dom_text.contains("data-error"), "{dom_text}");
        if dom_text.contains(&ready) {
            break;
        }
    }
    assert!(dom_text.contains(&ready), "the page did not finish: {dom_text}");

    let shot = TempDir::new("shot");
    let png = shot.path().join("view.png");
    let out = headless(&url, &[&format!("--screenshot={}", png.display())]);
    let image = image::open(&png).unwrap_or_else(|e| panic!("no screenshot ({e}): {}", text(&out.stderr))).to_rgb8();
    let (w, h) = image.dimensions();
    // The scene is everything left of the 380-pixel side panel.
    let scene_w = w - 380;
    let (mut tissue, mut frustum, mut drawn) = (0usize, 0usize, 0usize);
    for (x, y, p) in image.enumerate_pixels() {
        let [r, g, b] = p.0.map(i32::from);
        if x >= scene_w || y > h - 40 {
            continue;
        }
        let background = (r - 0x18).abs() < 6 && (g - 0x18).abs() < 6 && (b - 0x1c).abs() < 6;
        drawn += usize::from(!background);
        tissue += usize::from(!background && r > g + 25 && r > b + 20);
        frustum += usize::from(b > 200 && g > 150 && r < 150);
    }
    let scene_pixels = (scene_w * (h - 40)) as usize;
    assert!(drawn * 100 > scene_pixels * 3, "the map covers {drawn} of {scene_pixels} pixels");
    assert!(tissue * 2 > drawn, "{tissue} of {drawn} drawn pixels have the tissue's colour");
    assert!(frustum > 20, "the scope's frustum: {frustum} pixels");
    // The depth panel: the side panel shows the colour-coded depth (saturated blues and yellows).
    let vivid = image
        .enumerate_pixels()
        .filter(|(x, _, p)| *x >= scene_w && p.0.iter().max().unwrap() - p.0.iter().min().unwrap() > 120)
        .count();
    assert!(vivid > 2000, "the depth image: {vivid} vivid pixels in the side panel");
}

#[test]
fn a_folder_that_is_not_a_run_or_a_broken_map_is_one_clear_line() {
    let tmp = TempDir::new("viewbad");
    let out = run_with_timeout(Command::new(bdis_slam()).arg("view").arg(tmp.path()), Duration::from_secs(20));
    let stderr = text(&out.stderr);
    assert!(!out.status.success() && stderr.contains("nothing to show"), "{stderr}");
    std::fs::write(tmp.path().join("map.bin"), b"not a map").unwrap();
    let out = run_with_timeout(Command::new(bdis_slam()).arg("view").arg(tmp.path()), Duration::from_secs(20));
    let stderr = text(&out.stderr);
    assert!(!out.status.success() && stderr.contains("map.bin") && !stderr.contains("panicked"), "{stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
}

/// What a page holds of one keyframe after the messages so far.
struct HeldBlock {
    matrix: [f32; 16],
    camera_points: Vec<[f32; 3]>,
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap())
}

fn id_at(bytes: &[u8], at: usize) -> u64 {
    u64::from(u32_at(bytes, at)) | (u64::from(u32_at(bytes, at + 4)) << 32)
}

fn matrix_at(bytes: &[u8], at: usize) -> [f32; 16] {
    std::array::from_fn(|i| f32::from_le_bytes(bytes[at + 4 * i..at + 4 * i + 4].try_into().unwrap()))
}

fn rigid(m: &[f32; 16]) -> bool {
    let column = |c: usize| [m[4 * c], m[4 * c + 1], m[4 * c + 2]];
    let dot = |a: [f32; 3], b: [f32; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    (0..3).all(|i| (0..3).all(|j| (dot(column(i), column(j)) - f32::from(u8::from(i == j))).abs() < 1e-4))
        && m[3] == 0.0
        && m[7] == 0.0
        && m[11] == 0.0
        && m[15] == 1.0
}

#[test]
fn the_live_view_streams_the_run_once_and_ends_on_its_map() {
    let tmp = TempDir::new("viewlive");
    let sequence = tmp.path().join("colon");
    render_small_colon(&sequence, 48);
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}");
    let run_dir = tmp.path().join("run");
    // Paced like a slow camera, so the page watches the run as it happens.
    let run = Command::new(bdis_slam())
        .args(["run", "--track", "--sequence"])
        .arg(&sequence)
        .arg("--settings")
        .arg(sequence.join("settings.yaml"))
        .args(["--pacing", "on-demand:5hz", "--view", "--listen", &addr, "--ipc-prefix", &prefix("vlive"), "--out"])
        .arg(&run_dir)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();

    // The viewer comes up with the pipeline.
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    let (mut socket, _) = loop {
        match tungstenite::connect(format!("ws://{addr}/ws")) {
            Ok(connected) => break connected,
            Err(e) => {
                assert!(std::time::Instant::now() < deadline, "the live viewer never answered: {e}");
                std::thread::sleep(Duration::from_millis(100));
            }
        }
    };
    if let tungstenite::stream::MaybeTlsStream::Plain(tcp) = socket.get_ref() {
        tcp.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    }
    // A second watcher, a real browser, mid-run: it draws the map as it grows, without an error.
    let browser_url = format!("http://{addr}/");
    let browser = std::thread::spawn(move || watch_in_chromium(&browser_url));

    let mut held: std::collections::BTreeMap<u64, HeldBlock> = Default::default();
    let (mut blocks, mut trims, mut drops, mut moves, mut images, mut health) = (0, 0, 0, 0, 0, 0);
    let mut path: Vec<f64> = Vec::new();
    let mut processes_seen = std::collections::BTreeSet::new();
    loop {
        let message = match socket.read() {
            Ok(m) => m,
            Err(tungstenite::Error::ConnectionClosed | tungstenite::Error::AlreadyClosed) => break,
            Err(tungstenite::Error::Protocol(_)) | Err(tungstenite::Error::Io(_)) => break,
            Err(e) => panic!("the live stream: {e}"),
        };
        match message {
            tungstenite::Message::Binary(bytes) => {
                let tag = &bytes[..4];
                match tag {
                    b"BLK1" => {
                        let id = id_at(&bytes, 4);
                        let n = u32_at(&bytes, 12) as usize;
                        // Points arrive once: a keyframe's block comes once, later changes are trims.
                        assert!(!held.contains_key(&id), "keyframe {id} was sent whole twice");
                        let at = 4 + bdis_viewer::KEYFRAME_HEADER_BYTES;
                        let camera_points = (0..n)
                            .map(|i| {
                                std::array::from_fn(|k| {
                                    f32::from_le_bytes(bytes[at + 12 * i + 4 * k..][..4].try_into().unwrap())
                                })
                            })
                            .collect();
                        let matrix = matrix_at(&bytes, 4 + 4 * (4 + 6));
                        assert!(rigid(&matrix), "keyframe {id}: {matrix:?}");
                        held.insert(id, HeldBlock { matrix, camera_points });
                        blocks += 1;
                    }
                    b"TRM1" => {
                        let id = id_at(&bytes, 4);
                        let n = u32_at(&bytes, 12) as usize;
                        let block = held
                            .get_mut(&id)
                            .unwrap_or_else(|| panic!("a trim of keyframe {id}, which the page does not hold"));
                        assert_eq!(block.camera_points.len(), n, "keyframe {id}: a trim for another count");
                        let mut i = 0;
                        block.camera_points.retain(|_| {
                            i += 1;
                            bytes[16 + (i - 1) / 8] & (1 << ((i - 1) % 8)) != 0
                        });
                        assert!(block.camera_points.len() < n, "keyframe {id}: a trim that keeps everything");
                        trims += 1;
                    }
                    b"DEL1" => {
                        let id = id_at(&bytes, 4);
                        assert!(held.remove(&id).is_some(), "a drop of keyframe {id}, which the page does not hold");
                        drops += 1;
                    }
                    b"COR1" => {
                        let id = id_at(&bytes, 4);
                        let matrix = matrix_at(&bytes, 12);
                        assert!(rigid(&matrix), "correction of keyframe {id}: {matrix:?}");
                        held.get_mut(&id)
                            .unwrap_or_else(|| panic!("a correction of keyframe {id}, which the page does not hold"))
                            .matrix = matrix;
                        moves += 1;
                    }
                    b"IMG1" => {
                        let (w, h) = (u32_at(&bytes, 4) as usize, u32_at(&bytes, 8) as usize);
                        assert!(
                            w > 0 && w <= 480 && bytes.len() == 12 + 6 * w * h,
                            "image {w}x{h}, {} bytes",
                            bytes.len()
                        );
                        images += 1;
                    }
                    other => panic!("unknown message {:?}", String::from_utf8_lossy(other)),
                }
            }
            tungstenite::Message::Text(text) => {
                let value: serde_json::Value = serde_json::from_str(&text).unwrap();
                match value["type"].as_str() {
                    Some("poses") => {
                        for p in value["poses"].as_array().unwrap() {
                            let t = p["t_s"].as_f64().unwrap();
                            assert!(path.last().is_none_or(|&last| t > last), "poses out of order at {t}");
                            assert!(["ok", "uncertain", "lost"].contains(&p["state"].as_str().unwrap()), "{p}");
                            path.push(t);
                        }
                    }
                    Some("health") => {
                        for p in value["processes"].as_array().unwrap() {
                            processes_seen.insert(p["name"].as_str().unwrap().to_string());
                        }
                        health += 1;
                    }
                    other => panic!("unknown message {other:?}: {text}"),
                }
            }
            _ => {}
        }
    }
    let out = run.wait_with_output().unwrap();
    assert!(out.status.success(), "{}\n{}", text(&out.stdout), text(&out.stderr));
    let (blocks_drawn, screenshot) = browser.join().unwrap();
    assert!(blocks_drawn >= 1, "the live page drew no keyframe");
    // Kept with the run (BDIS_KEEP_TEST_DIRS=1 keeps the folder) for a person to look at.
    std::fs::write(tmp.path().join("live.png"), &screenshot).unwrap();
    let image = image::load_from_memory(&screenshot).unwrap().to_rgb8();
    let scene_w = image.width() - 380;
    let drawn = image.enumerate_pixels().filter(|(x, _, p)| *x < scene_w && p.0 != [0x18, 0x18, 0x1c]).count();
    assert!(drawn > 2000, "the live page's map covers {drawn} pixels");

    eprintln!(
        "live: {blocks} blocks, {trims} trims, {drops} drops, {moves} corrections, {images} images, {health} health, {} poses",
        path.len()
    );
    assert!(blocks >= 3 && images >= 1 && health >= 2, "{blocks} blocks, {images} images, {health} health reports");
    for name in ["acquisition", "tracking", "stereo", "mosaic"] {
        assert!(processes_seen.contains(name), "no health of {name}: {processes_seen:?}");
    }
    // Every pose the tracker published, in order.
    let trajectory = bdis_core::formats::trajectory::read_tum(&run_dir.join("trajectory.tum")).unwrap();
    assert_eq!(path.len(), trajectory.len());
    // The page ends holding exactly the run's map: map.ply's points, in order, placed by their keyframes'
    // last matrices.
    let ply = bdis_core::formats::ply::read(&run_dir.join("map.ply")).unwrap();
    let world: Vec<[f32; 3]> = held
        .values()
        .flat_map(|b| {
            b.camera_points.iter().map(|p| {
                let m = &b.matrix;
                [0, 1, 2].map(|r| m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r])
            })
        })
        .collect();
    assert_eq!(world.len(), ply.positions.len(), "points the page holds against map.ply");
    let scale = ply.positions.iter().map(|p| p[2].abs()).fold(0f32, f32::max);
    for (a, b) in world.iter().zip(&ply.positions) {
        for k in 0..3 {
            assert!((a[k] - b[k]).abs() <= 1e-4 * scale, "{a:?} against map.ply's {b:?}");
        }
    }
}

/// Standard base64 (the DevTools protocol sends screenshots in it).
fn base64(text: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        _ => 63,
    };
    let digits: Vec<u8> = text.bytes().filter(|c| *c != b'=' && !c.is_ascii_whitespace()).map(value).collect();
    digits
        .chunks(4)
        .flat_map(|c| {
            let n = c.iter().enumerate().fold(0u32, |n, (i, d)| n | (u32::from(*d) << (18 - 6 * i)));
            let bytes = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
            bytes.into_iter().take(c.len().saturating_sub(1))
        })
        .collect()
}

/// Opens `url` in headless Chromium and, through the DevTools protocol, waits (in real time, as a live page
/// needs) until the page has drawn keyframes, then takes a screenshot: (keyframes drawn, PNG). Fails on a page
/// error.
fn watch_in_chromium(url: &str) -> (u64, Vec<u8>) {
    let profile = TempDir::new("cdp");
    let mut chromium = Command::new(chromium())
        .args([
            "--headless",
            "--no-sandbox",
            "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader",
            "--no-first-run",
            "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
            "--window-size=1280,800",
            "--remote-debugging-port=0",
        ])
        .arg(format!("--user-data-dir={}", profile.path().display()))
        .arg(url)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // "DevTools listening on ws://127.0.0.1:PORT/devtools/browser/…"
    // Its stderr is read to the end on a thread of its own, so Chromium never blocks on a full pipe.
    let (port_tx, port_rx) = std::sync::mpsc::channel();
    let stderr = chromium.stderr.take().unwrap();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if let Some(rest) = line.split("DevTools listening on ws://127.0.0.1:").nth(1) {
                let _ = port_tx.send(rest.split('/').next().unwrap_or_default().to_string());
            }
        }
    });
    let port = port_rx.recv_timeout(Duration::from_secs(30)).expect("Chromium did not open the DevTools port");
    let devtools = format!("127.0.0.1:{port}");
    let targets: serde_json::Value = serde_json::from_slice(&http(&devtools, "GET", "/json/list").2).unwrap();
    let page = targets.as_array().unwrap().iter().find(|t| t["type"] == "page").expect("a page target");
    let (mut cdp, _) = tungstenite::connect(page["webSocketDebuggerUrl"].as_str().unwrap()).unwrap();
    let mut next_id = 0;
    let mut call = |method: &str, params: serde_json::Value| -> serde_json::Value {
        next_id += 1;
        let request = serde_json::json!({ "id": next_id, "method": method, "params": params });
        cdp.send(tungstenite::Message::text(request.to_string())).unwrap();
        loop {
            if let tungstenite::Message::Text(t) = cdp.read().unwrap() {
                let reply: serde_json::Value = serde_json::from_str(&t).unwrap();
                if reply["id"] == next_id {
                    return reply["result"].clone();
                }
            }
        }
    };
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    let mut drawn = 0;
    while std::time::Instant::now() < deadline {
        let state = call(
            "Runtime.evaluate",
            serde_json::json!({ "expression": "[document.body.dataset.ready || '0', document.body.dataset.error || ''].join('|')" }),
        );
        let value = state["result"]["value"].as_str().unwrap_or("0|").to_string();
        let (ready, error) = value.split_once('|').unwrap_or(("0", ""));
        assert!(error.is_empty(), "the live page: {error}");
        drawn = ready.parse().unwrap_or(0);
        if drawn >= 3 {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
    }
    // Two frames later the canvas shows what the page has.
    std::thread::sleep(Duration::from_millis(300));
    let shot = call("Page.captureScreenshot", serde_json::json!({ "format": "png" }));
    let png = base64(shot["data"].as_str().unwrap_or_default());
    chromium.kill().ok();
    chromium.wait().ok();
    (drawn, png)
}

#[test]
fn a_viewer_that_cannot_run_does_not_stop_the_run() {
    let tmp = TempDir::new("viewdead");
    let sequence = tmp.path().join("colon");
    render_small_colon(&sequence, 24);
    // Another program holds the port: every viewer instance fails at start.
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let run_dir = tmp.path().join("run");
    let out = run_with_timeout(
        Command::new(bdis_slam())
            .args(["run", "--track", "--sequence"])
            .arg(&sequence)
            .arg("--settings")
            .arg(sequence.join("settings.yaml"))
            .args(["--view", "--listen", &addr, "--ipc-prefix", &prefix("vdead"), "--out"])
            .arg(&run_dir),
        Duration::from_secs(180),
    );
    assert!(out.status.success(), "the run failed with its viewer: {}", text(&out.stderr));
    let latency: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("latency.json")).unwrap()).unwrap();
    let events = latency["events"].to_string();
    assert!(events.contains("viewer") && events.contains("not essential"), "{events}");
    // The map was made all the same.
    assert!(bdis_core::formats::ply::read(&run_dir.join("map.ply")).unwrap().positions.len() > 1000);
    drop(taken);
}
