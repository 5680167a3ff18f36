#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| bdis_fuzz::bridge_snapshot(data));
