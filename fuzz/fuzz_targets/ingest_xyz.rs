//! Any bytes given to the xyz reader give a flight log or an error, never a
//! panic or an abort.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let folder = tempfile::tempdir().unwrap();
    let path = folder.path().join("input.xyz");
    std::fs::write(&path, data).unwrap();
    let _ = magcomp::ingest::read_flight_log(&path, &magcomp::ingest::IngestOptions::default());
});
