#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! The `bdis-tracking` service binary refuses bad input with one line before it touches shared memory. (Its
//! pipeline behaviour is tested end to end in the workspace's tests/tracking.rs.)

use std::process::Command;

fn run(args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_bdis-tracking"))
        .args(args)
        .env("BDIS_IPC_PREFIX", format!("btrkcli{}_", std::process::id()))
        .output()
        .unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).trim().to_string())
}

#[test]
fn bad_settings_are_one_line_and_exit_1() {
    let dir = std::env::temp_dir().join(format!("bdis-tracking-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (code, err) = run(&["--settings", "/nonexistent/s.yaml"]);
    assert_eq!(code, Some(1));
    assert!(err.starts_with("bdis-tracking: error: /nonexistent/s.yaml: cannot read settings"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");

    let camera = "%YAML:1.0\nCamera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\nCamera.bf: 2500\n";
    let no_size = dir.join("s.yaml");
    std::fs::write(&no_size, camera).unwrap();
    let (code, err) = run(&["--settings", no_size.to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert!(err.contains("needs `Camera.width` and `Camera.height`"), "{err}");

    // An image too small for the pyramid: the ORB settings are named.
    let tiny = dir.join("tiny.yaml");
    std::fs::write(&tiny, format!("{camera}Camera.width: 64\nCamera.height: 48\n")).unwrap();
    let (code, err) = run(&["--settings", tiny.to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert!(err.contains("too small for 8 levels"), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");

    let distorted = dir.join("k1.yaml");
    std::fs::write(&distorted, format!("{camera}Camera.width: 640\nCamera.height: 480\nCamera.k1: 0.1\n")).unwrap();
    let (code, err) = run(&["--settings", distorted.to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert!(err.contains("rectified"), "{err}");
    assert!(!err.contains("panicked"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn help_names_the_settings() {
    let out = Command::new(env!("CARGO_BIN_EXE_bdis-tracking")).arg("--help").output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("--settings") && text.contains("poses"), "{text}");
}
