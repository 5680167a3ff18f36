//! What the service binaries' own tests share: a run that must be refused before shared memory exists, the one
//! clear line it must print, the run's files in `/dev/shm`, and a Python with a cross-checking package.

use std::process::Command;

/// The files of the run `prefix` in `/dev/shm`.
pub fn shm_files(prefix: &str) -> Vec<String> {
    std::fs::read_dir("/dev/shm")
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(prefix))
        .collect()
}

/// Removes the run's files from `/dev/shm` and returns those other than iceoryx2's global management file (which
/// outlives the last node of a run; the launcher removes it after a run): what a stopped service left behind.
pub fn take_shm_leftovers(prefix: &str) -> Vec<String> {
    let files = shm_files(prefix);
    for name in &files {
        let _ = std::fs::remove_file(std::path::Path::new("/dev/shm").join(name));
    }
    files.into_iter().filter(|n| !n.ends_with("global_mgmt")).collect()
}

/// Runs `binary args` under the run prefix `prefix`, which must leave nothing in shared memory (it is refused
/// input): its exit code and standard error.
#[allow(clippy::expect_used)] // test support: a panic is the failure report
pub fn refused(binary: &str, prefix: &str, args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(binary).args(args).env("BDIS_IPC_PREFIX", prefix).output().expect("start the binary");
    let left = shm_files(prefix);
    assert!(left.is_empty(), "refused input must not touch shared memory: {left:?}");
    (out.status.code(), String::from_utf8_lossy(&out.stderr).trim().to_string())
}

/// The bad-input contract: exit code 1, one line `PROGRAM: error: …` that names `names`, no panic.
pub fn assert_one_clear_line(program: &str, code: Option<i32>, err: &str, names: &str) {
    assert_eq!(code, Some(1), "{err}");
    assert!(err.starts_with(&format!("{program}: error: ")), "{err}");
    assert!(err.contains(names), "the line names `{names}`: {err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// Whether `python3` can import `package` (a CI-only cross-check: `.ci/run` installs it). With `CI` set its
/// absence fails the test; elsewhere the test says it skipped.
pub fn python_with(package: &str) -> bool {
    let ok =
        Command::new("python3").args(["-c", &format!("import {package}")]).output().is_ok_and(|o| o.status.success());
    if !ok {
        assert!(std::env::var_os("CI").is_none(), "CI must have python3 with {package}");
        eprintln!("skipped: python3 with {package} is not available (python3 -m pip install {package})");
    }
    ok
}
