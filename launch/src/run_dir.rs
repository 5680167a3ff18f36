//! The run folder (`runs/<UTC time>-<name>/`: the launch file, each process's log, `latency.json`) and the
//! run's shared-memory name prefix, which the launcher also cleans up after the run.

use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

/// `YYYYmmdd-HHMMSS` in UTC, from the system clock (no time-zone database needed).
pub fn utc_stamp(t: SystemTime) -> String {
    let secs = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil-from-days (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!("{year:04}{month:02}{day:02}-{:02}{:02}{:02}", rem / 3600, rem % 3600 / 60, rem % 60)
}

/// A fresh run folder under `base`; a numeric suffix keeps two runs in one second apart.
pub fn create_run_dir(base: &Path, name: &str) -> std::io::Result<PathBuf> {
    std::fs::create_dir_all(base)?;
    let stamp = utc_stamp(SystemTime::now());
    for n in 0..1000 {
        let dir = if n == 0 { base.join(format!("{stamp}-{name}")) } else { base.join(format!("{stamp}-{name}-{n}")) };
        match std::fs::create_dir(&dir) {
            Ok(()) => return Ok(dir),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
    Err(std::io::Error::other("too many runs in one second"))
}

/// The file in a run folder that names the run's shared-memory prefix while it runs, so tools can find the
/// pipeline by its folder (`bdis-slam swap stereo --run runs/…`).
pub const PREFIX_FILE: &str = "ipc-prefix";

/// The shared-memory prefix of the run in `dir` (written by the launcher when the run starts).
pub fn prefix_of_run(dir: &Path) -> Result<String, String> {
    let path = dir.join(PREFIX_FILE);
    let text = std::fs::read_to_string(&path)
        .map_err(|e| format!("{}: cannot read ({e}); is it a run folder of a running pipeline?", path.display()))?;
    let prefix = text.trim();
    if prefix.is_empty() || !prefix.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
        return Err(format!("{}: `{prefix}` is not a shared-memory prefix", path.display()));
    }
    Ok(prefix.to_string())
}

/// A prefix no other run on this machine uses: `bdis<pid><time>_` in hex, short enough for shm names.
pub fn unique_prefix() -> String {
    let nanos = SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
    format!("bdis{:x}{:05x}_", std::process::id(), nanos & 0xfffff)
}

/// Files a run with `prefix` left in `/dev/shm` and under iceoryx2's root (`/tmp/iceoryx2`).
pub fn leftovers(prefix: &str) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut visit = |dir: &Path, recurse: bool| {
        let mut stack = vec![dir.to_path_buf()];
        while let Some(d) = stack.pop() {
            let Ok(entries) = std::fs::read_dir(&d) else { continue };
            for e in entries.flatten() {
                let p = e.path();
                let named = e.file_name().to_string_lossy().starts_with(prefix);
                if named {
                    found.push(p);
                } else if recurse && p.is_dir() {
                    stack.push(p);
                }
            }
        }
    };
    visit(Path::new("/dev/shm"), false);
    visit(Path::new("/tmp/iceoryx2"), true);
    found
}

/// Removes a finished run's leftovers: first through iceoryx2 (dead nodes and their services), then the files
/// iceoryx2 keeps by design (its per-prefix management segment). Only call this when no process of the run lives.
pub fn remove_leftovers(prefix: &str) -> usize {
    let _ = bdis_ipc::cleanup_dead_nodes_of_run(prefix);
    let mut removed = 0;
    for p in leftovers(prefix) {
        let ok = if p.is_dir() { std::fs::remove_dir_all(&p) } else { std::fs::remove_file(&p) };
        if ok.is_ok() {
            removed += 1;
        }
    }
    removed
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn utc_stamps() {
        assert_eq!(utc_stamp(UNIX_EPOCH), "19700101-000000");
        assert_eq!(utc_stamp(UNIX_EPOCH + Duration::from_secs(1_795_000_000)), "20261118-110640");
        assert_eq!(utc_stamp(UNIX_EPOCH + Duration::from_secs(951_782_400)), "20000229-000000");
    }
}
