//! Writes `pattern_table.rs`, the stored rBRIEF pattern, from `bdis_orb::pattern::generate()`. Run it after a
//! deliberate change of the method or the seed; the descriptor space (and any vocabulary) changes with it.

use std::path::PathBuf;
use std::process::ExitCode;

fn main() -> ExitCode {
    let path = std::env::args_os()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/src/pattern_table.rs")));
    if path.as_os_str() == "--help" || path.as_os_str() == "-h" {
        println!("bdis-orb-pattern [FILE]: write the rBRIEF pattern table (default: shared/orb/src/pattern_table.rs)");
        return ExitCode::SUCCESS;
    }
    let pattern = bdis_orb::pattern::generate();
    match std::fs::write(&path, bdis_orb::pattern::table_source(&pattern)) {
        Ok(()) => {
            println!(
                "{}: {} pairs, pattern hash {:#018x}",
                path.display(),
                pattern.len(),
                bdis_orb::pattern::pattern_hash(&pattern)
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("bdis-orb-pattern: error: {}: {e}", path.display());
            ExitCode::FAILURE
        }
    }
}
