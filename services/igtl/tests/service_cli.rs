#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! The `bdis-igtl` service binary on its own: bad options and an address it cannot have are one line and exit 1
//! before shared memory is touched; started with no pipeline it takes receivers and stops cleanly on the
//! launcher's SIGTERM, closing their connections. (What it sends inside a run, read by pyigtl, is tested end to
//! end in the workspace's tests/igtl.rs.)

use std::io::{BufRead, Read};
use std::net::{TcpListener, TcpStream};
use std::process::{Command, Stdio};
use std::time::Duration;

use bdis_testkit::service::{assert_one_clear_line, refused, take_shm_leftovers};

fn prefix(tag: &str) -> String {
    format!("bigtlcli{tag}{}_", std::process::id())
}

fn run(tag: &str, args: &[&str]) -> (Option<i32>, String) {
    refused(env!("CARGO_BIN_EXE_bdis-igtl"), &prefix(tag), args)
}

fn one_clear_line(code: Option<i32>, err: &str, names: &str) {
    assert_one_clear_line("bdis-igtl", code, err, names);
}

#[test]
fn bad_options_and_a_taken_port_are_one_line_and_exit_1() {
    let (code, err) = run("addr", &["--listen", "nowhere"]);
    one_clear_line(code, &err, "nowhere");
    let (code, err) = run("period", &["--map-period=-1"]);
    one_clear_line(code, &err, "--map-period");
    let taken = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let (code, err) = run("taken", &["--listen", &addr]);
    one_clear_line(code, &err, &addr);
}

#[test]
fn alone_it_takes_receivers_and_closes_them_cleanly_on_sigterm() {
    let run_prefix = prefix("serve");
    let mut child = Command::new(env!("CARGO_BIN_EXE_bdis-igtl"))
        .args(["--listen", "127.0.0.1:0"])
        .env("BDIS_IPC_PREFIX", &run_prefix)
        .env("RUST_LOG", "info")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut log = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut seen = String::new();
    let addr = loop {
        let mut line = String::new();
        assert!(log.read_line(&mut line).unwrap() > 0, "the service ended before it listened:\n{seen}");
        seen += &line;
        if let Some(at) = line.find("OpenIGTLink at ") {
            break line[at + "OpenIGTLink at ".len()..].trim().to_string();
        }
    };
    // A receiver connects; with no pipeline nothing is sent, and the stop closes the connection in order (EOF,
    // not a reset).
    let mut receiver = TcpStream::connect(&addr).unwrap();
    receiver.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    let mut got = Vec::new();
    receiver.read_to_end(&mut got).unwrap();
    assert!(got.is_empty(), "{} bytes from a service with no pipeline", got.len());
    let mut rest = String::new();
    log.read_to_string(&mut rest).unwrap();
    let status = child.wait().unwrap();
    let left = take_shm_leftovers(&run_prefix);
    assert!(status.success(), "{status}: {seen}{rest}");
    assert!(rest.contains("OpenIGTLink done"), "{seen}{rest}");
    assert!(left.is_empty(), "the stopped service left shared memory behind: {left:?}");
}

#[test]
fn help_says_where_it_listens_and_what_an_open_port_shows() {
    let out = Command::new(env!("CARGO_BIN_EXE_bdis-igtl")).arg("--help").output().unwrap();
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(help.contains("127.0.0.1:18944") && help.contains("patient"), "{help}");
}
