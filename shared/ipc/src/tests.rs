use super::*;

#[test]
fn topics_parse_by_short_and_service_name() {
    for t in Topic::ALL {
        assert_eq!(Topic::parse(t.short_name()), Some(t));
        assert_eq!(Topic::parse(t.service_name()), Some(t));
    }
    assert_eq!(Topic::parse("nope"), None);
}

#[test]
#[allow(clippy::unwrap_used)]
fn no_file_of_a_run_is_accessible_by_other_users() {
    use std::os::unix::fs::PermissionsExt;
    let prefix = format!("bipcperm{}_", std::process::id());
    let ipc = Ipc::open("perm-test", &prefix).unwrap();
    let frames = ipc.frames().unwrap();
    let _publisher = ipc.frame_publisher(&frames, 1024).unwrap();
    let _events = ipc.events(Topic::Frames).unwrap();
    let files: Vec<_> = std::fs::read_dir("/dev/shm")
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with(prefix.as_str()))
        .collect();
    assert!(files.iter().any(|e| e.file_name().to_string_lossy().ends_with("global_mgmt")), "{files:?}");
    for e in &files {
        let mode = e.metadata().unwrap().permissions().mode();
        assert_eq!(mode & 0o077, 0, "{:?}: mode {mode:o}", e.path());
    }
    drop(ipc);
    // iceoryx2 keeps the global management file after the last node; a test leaves nothing behind.
    crate::remove_run_files(&prefix);
}
