#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! The `bdis-viewer` service binary on its own: bad options and an address it cannot have are one line and exit 1
//! before shared memory is touched; started with no pipeline it serves its page read-only, loads nothing from
//! elsewhere, and stops cleanly on the launcher's SIGTERM. (Its live behaviour inside a run — the stream checked
//! message by message, the page in headless Chromium — is tested end to end in the workspace's tests/viewer.rs.)

use std::io::{BufRead, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::process::{Command, Stdio};
use std::time::Duration;

use bdis_testkit::service::{assert_one_clear_line, refused, take_shm_leftovers};

fn prefix(tag: &str) -> String {
    format!("bviewcli{tag}{}_", std::process::id())
}

fn run(tag: &str, args: &[&str]) -> (Option<i32>, String) {
    refused(env!("CARGO_BIN_EXE_bdis-viewer"), &prefix(tag), args)
}

fn one_clear_line(code: Option<i32>, err: &str, names: &str) {
    assert_one_clear_line("bdis-viewer", code, err, names);
}

#[test]
fn bad_options_and_a_taken_port_are_one_line_and_exit_1() {
    let (code, err) = run("addr", &["--listen", "nowhere"]);
    one_clear_line(code, &err, "nowhere");

    let (code, err) = run("period", &["--image-period", "0"]);
    one_clear_line(code, &err, "--image-period");

    let (code, err) = run("param", &["--map-param", "gap=3"]);
    one_clear_line(code, &err, "--map-param");

    // Another program has the port: the viewer says which address, and leaves nothing behind.
    let taken = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let (code, err) = run("taken", &["--listen", &addr]);
    one_clear_line(code, &err, &addr);
}

/// One HTTP/1.1 exchange over a fresh connection: the status code and the whole response.
fn http(addr: &str, method: &str, path: &str) -> (u16, String) {
    let mut stream = TcpStream::connect(addr).unwrap();
    stream.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    write!(stream, "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Length: 0\r\n\r\n")
        .unwrap();
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw).unwrap();
    let text = String::from_utf8_lossy(&raw).into_owned();
    let status = text.split(' ').nth(1).and_then(|s| s.parse().ok()).unwrap_or(0);
    (status, text)
}

#[test]
fn alone_it_serves_its_page_read_only_and_stops_cleanly_on_sigterm() {
    let run_prefix = prefix("serve");
    let mut child = Command::new(env!("CARGO_BIN_EXE_bdis-viewer"))
        .args(["--listen", "127.0.0.1:0"])
        .env("BDIS_IPC_PREFIX", &run_prefix)
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Its log line gives the address it took (port 0: the system's choice).
    let mut log = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    let addr = loop {
        let mut line = String::new();
        assert!(log.read_line(&mut line).unwrap() > 0, "the viewer ended before it served:\n{seen}");
        seen += &line;
        if let Some(at) = line.find("viewer at http://") {
            break line[at + "viewer at http://".len()..].trim().trim_end_matches('/').to_string();
        }
    };

    let (status, page) = http(&addr, "GET", "/");
    assert_eq!(status, 200, "{page}");
    assert!(page.contains("<title>bdis-slam viewer</title>"), "{page}");
    let csp = page
        .lines()
        .find(|l| l.to_ascii_lowercase().starts_with("content-security-policy:"))
        .unwrap_or_else(|| panic!("the page has a content security policy: {page}"));
    assert!(csp.contains("default-src 'self'"), "nothing may load from elsewhere: {csp}");
    let (status, script) = http(&addr, "GET", "/viewer.js");
    assert_eq!(status, 200);
    assert!(!script.contains("http://") && !script.contains("https://"), "the page's code reaches off the machine");
    // Read-only: nothing that could change anything is accepted.
    for method in ["POST", "PUT", "DELETE"] {
        let (status, _) = http(&addr, method, "/");
        assert_eq!(status, 405, "{method} /");
    }
    let (status, _) = http(&addr, "GET", "/../Cargo.toml");
    assert!(status == 404 || status == 400, "a path outside the page: {status}");

    Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    let mut rest = String::new();
    log.read_to_string(&mut rest).unwrap();
    let status = child.wait().unwrap();
    let left = take_shm_leftovers(&run_prefix);
    assert!(status.success(), "{status}: {seen}{rest}");
    assert!(rest.contains("viewer done"), "{seen}{rest}");
    assert!(left.is_empty(), "the stopped viewer left shared memory behind: {left:?}");
}

#[test]
fn help_says_where_it_listens() {
    let out = Command::new(env!("CARGO_BIN_EXE_bdis-viewer")).arg("--help").output().unwrap();
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(help.contains("--listen") && help.contains("127.0.0.1:8470"), "{help}");
}
