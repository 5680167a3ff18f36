#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! The `bdis-bridge` service binary on its own: bad options are one line and exit 1 before shared memory is
//! touched, the help says what an open port carries, and linked, the receiver is reachable only at the address it
//! was told and the sender nowhere. (Carrying a run between two iceoryx2 systems, and a
//! `kill -9` of either side, is tested end to end in the workspace's tests/bridge.rs.)

use std::io::{BufRead, BufReader, Read};
use std::net::TcpListener;
use std::process::{Command, Stdio};

use bdis_testkit::service::{assert_one_clear_line, refused, take_shm_leftovers};

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

/// The sockets of process `pid` that others can reach: TCP sockets listening and UDP sockets bound, as
/// (protocol, local address), from `/proc` (this machine's network namespace).
fn reachable_sockets(pid: u32) -> Vec<(String, String)> {
    let inodes: std::collections::HashSet<String> = std::fs::read_dir(format!("/proc/{pid}/fd"))
        .unwrap()
        .flatten()
        .filter_map(|fd| std::fs::read_link(fd.path()).ok())
        .filter_map(|target| {
            let target = target.to_string_lossy().into_owned();
            target.strip_prefix("socket:[").and_then(|s| s.strip_suffix(']')).map(str::to_string)
        })
        .collect();
    let address = |hex: &str| -> String {
        let (ip, port) = hex.split_once(':').unwrap();
        let port = u16::from_str_radix(port, 16).unwrap();
        // The kernel prints each 32-bit word of the address in host order (little-endian here).
        let words: Vec<[u8; 4]> =
            (0..ip.len() / 8).map(|i| u32::from_str_radix(&ip[8 * i..8 * i + 8], 16).unwrap().to_le_bytes()).collect();
        if words.len() == 1 {
            format!("{}:{port}", std::net::Ipv4Addr::from(words[0]))
        } else {
            let bytes: Vec<u8> = words.concat();
            format!("[{}]:{port}", std::net::Ipv6Addr::from(<[u8; 16]>::try_from(bytes).unwrap()))
        }
    };
    let mut found = Vec::new();
    for proto in ["tcp", "tcp6", "udp", "udp6"] {
        for line in std::fs::read_to_string(format!("/proc/net/{proto}")).unwrap().lines().skip(1) {
            let fields: Vec<&str> = line.split_whitespace().collect();
            let (local, state, inode) = (fields[1], fields[3], fields[9]);
            // TCP: LISTEN (0A); UDP: any bound socket takes datagrams.
            if inodes.contains(inode) && (proto.starts_with("udp") || state == "0A") {
                found.push((proto.to_string(), address(local)));
            }
        }
    }
    found
}

#[test]
fn linked_the_receiver_listens_only_where_told_and_the_sender_nowhere() {
    let port = TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}");
    let start = |prefix: &str, args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_bdis-bridge"))
            .args(args)
            .env("BDIS_IPC_PREFIX", prefix)
            .env("RUST_LOG", "info")
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (prefix_b, prefix_a) =
        (format!("bbridgelinkb{}_", std::process::id()), format!("bbridgelinka{}_", std::process::id()));
    let mut receiver = start(&prefix_b, &["receive", "--listen", &addr]);
    let mut sender = start(&prefix_a, &["send", "--to", &addr]);
    // The sender says where the receiver stands once they have begun a conversation.
    let mut log = BufReader::new(sender.stderr.take().unwrap());
    let mut seen = String::new();
    loop {
        let mut line = String::new();
        assert!(log.read_line(&mut line).unwrap() > 0, "the sender ended before the link was up:\n{seen}");
        seen += &line;
        if line.contains("sending depth, corrections, poses to") {
            break;
        }
    }
    let receiver_sockets = reachable_sockets(receiver.id());
    let sender_sockets = reachable_sockets(sender.id());
    for child in [&receiver, &sender] {
        Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    }
    let mut rest = String::new();
    log.read_to_string(&mut rest).unwrap();
    let (sender_status, receiver_status) = (sender.wait().unwrap(), receiver.wait().unwrap());
    let left: Vec<String> = [&prefix_a, &prefix_b].iter().flat_map(|p| take_shm_leftovers(p)).collect();
    assert_eq!(receiver_sockets, vec![("tcp".to_string(), addr.clone())], "the receiver is reachable elsewhere");
    assert!(sender_sockets.is_empty(), "the sender is reachable: {sender_sockets:?}");
    assert!(sender_status.success() && receiver_status.success(), "{sender_status} {receiver_status}: {seen}{rest}");
    assert!(left.is_empty(), "the stopped bridge left shared memory behind: {left:?}");
}
