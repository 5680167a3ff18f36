//! Where a pointer lives: proof that a consumer reads pixels in place, in a shared-memory mapping, not a copy.

use std::path::PathBuf;

/// The file backing the mapping that contains `addr`, read from `/proc/self/maps` (Linux). `None` when the
/// address is in an anonymous mapping (heap, stack) or the maps file cannot be read.
pub fn mapping_file_of(addr: *const u8) -> Option<PathBuf> {
    let addr = addr as usize;
    let maps = std::fs::read_to_string("/proc/self/maps").ok()?;
    for line in maps.lines() {
        let mut fields = line.split_whitespace();
        let range = fields.next()?;
        let (start, end) = range.split_once('-')?;
        let (start, end) = (usize::from_str_radix(start, 16).ok()?, usize::from_str_radix(end, 16).ok()?);
        if (start..end).contains(&addr) {
            // perms, offset, dev, inode, then the path (may be absent).
            let path: Vec<&str> = fields.skip(4).collect();
            return (!path.is_empty()).then(|| PathBuf::from(path.join(" ")));
        }
    }
    None
}

/// True when `addr` lies in a mapping of a file under `/dev/shm` whose name starts with the run's `prefix`.
pub fn is_in_run_shared_memory(addr: *const u8, prefix: &str) -> bool {
    mapping_file_of(addr).is_some_and(|p| {
        p.starts_with("/dev/shm") && p.file_name().is_some_and(|n| n.to_string_lossy().starts_with(prefix))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heap_memory_is_not_shared_memory() {
        let v = vec![0u8; 4096];
        assert!(!is_in_run_shared_memory(v.as_ptr(), ""));
    }
}
