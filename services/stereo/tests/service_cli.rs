#![allow(clippy::unwrap_used, clippy::expect_used)] // test code: a panic is the failure report
//! The `bdis-stereo` service binary refuses bad input before it touches shared memory.

use std::process::Command;

fn run(args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_bdis-stereo"))
        .args(args)
        .env("BDIS_IPC_PREFIX", format!("btstcli{}_", std::process::id()))
        .output()
        .unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).trim().to_string())
}

#[test]
fn bad_settings_and_arguments_are_one_line_and_exit_1() {
    let dir = std::env::temp_dir().join(format!("bdis-stereo-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (code, err) = run(&["--settings", "/nonexistent/s.yaml"]);
    assert_eq!(code, Some(1));
    assert!(err.starts_with("bdis-stereo: error: /nonexistent/s.yaml: cannot read settings"), "{err}");

    let no_size = dir.join("s.yaml");
    std::fs::write(
        &no_size,
        "%YAML:1.0\nCamera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\nCamera.bf: 2500\n",
    )
    .unwrap();
    let (code, err) = run(&["--settings", no_size.to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert!(err.contains("needs `Camera.width` and `Camera.height`"), "{err}");

    let sized = dir.join("ok.yaml");
    std::fs::write(&sized, "%YAML:1.0\nCamera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\nCamera.bf: 2500\nCamera.width: 640\nCamera.height: 480\nBDISparam.patchsz: 0\n").unwrap();
    let (code, err) = run(&["--settings", sized.to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert_eq!(err, "bdis-stereo: error: BDISparam.patchsz: must be even and in 2..=64, found 0");
    assert_eq!(err.lines().count(), 1);
    std::fs::remove_dir_all(&dir).unwrap();
}
