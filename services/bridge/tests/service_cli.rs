#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! The `bdis-bridge` service binary on its own: bad options are one line and exit 1 before shared memory is
//! touched, and the help says what an open port carries. (Carrying a run between two iceoryx2 systems, and a
//! `kill -9` of either side, is tested end to end in the workspace's tests/bridge.rs.)

use std::net::TcpListener;
use std::process::Command;

use bdis_testkit::service::{assert_one_clear_line, refused};

fn run(tag: &str, args: &[&str]) -> (Option<i32>, String) {
    refused(env!("CARGO_BIN_EXE_bdis-bridge"), &format!("bbridgecli{tag}{}_", std::process::id()), args)
}

#[test]
fn bad_options_and_a_taken_port_are_one_line_and_exit_1() {
    let (code, err) = run("topic", &["receive", "--topics", "depth,frames"]);
    assert_one_clear_line("bdis-bridge", code, &err, "`frames`");
    let (code, err) = run("to", &["send", "--to", "nowhere"]);
    assert_one_clear_line("bdis-bridge", code, &err, "--to nowhere");
    let taken = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let (code, err) = run("taken", &["receive", "--listen", &addr]);
    assert_one_clear_line("bdis-bridge", code, &err, &addr);
}

#[test]
fn help_says_what_an_open_port_carries() {
    let out = Command::new(env!("CARGO_BIN_EXE_bdis-bridge")).args(["receive", "--help"]).output().unwrap();
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    assert!(help.contains("127.0.0.1:18960") && help.contains("patient"), "{help}");
}
