//! magcomp's MCAP output checked by an independent reader: the official
//! Python `mcap` library with `mcap-protobuf-support`, decoding every message
//! from the descriptors embedded in the file.
//!
//! `.ci/run` installs both from PyPI into a virtualenv and points
//! `MAGCOMP_PYTHON` at its interpreter. Without that variable the test says
//! so and does nothing, so a bare `cargo test` works offline.

use std::path::Path;
use std::process::Command;

use magcomp::formats::{read_flight_log, IngestOptions};
use magcomp::simulate::sample_flight::{generate, write, SampleFlightSpec};

fn python() -> Option<String> {
    let python = std::env::var("MAGCOMP_PYTHON").ok();
    if python.is_none() {
        eprintln!("MAGCOMP_PYTHON is not set: skipping the independent MCAP reader check (.ci/run sets it)");
    }
    python
}

fn validate(python: &str, mcap: &Path) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/validate_mcap.py");
    let output = Command::new(python).arg(script).arg(mcap).output().unwrap();
    assert!(
        output.status.success(),
        "the Python MCAP reader failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).unwrap()
}

#[test]
fn compensated_mcap_decodes_with_the_official_python_reader() {
    let Some(python) = python() else { return };
    let folder = tempfile::tempdir().unwrap();
    let spec = SampleFlightSpec {
        line_count: 2,
        line_duration_s: 60.0,
        ..SampleFlightSpec::default()
    };
    let csv = folder.path().join("flight.csv");
    let windows = folder.path().join("flight.windows.json");
    write(&generate(&spec, 3), &csv, &windows).unwrap();
    let out = folder.path().join("compensated.mcap");
    let status = Command::new(env!("CARGO_BIN_EXE_magcomp"))
        .args(["compensate", csv.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .args(["--windows-file", windows.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));

    let summary = validate(&python, &out);
    let log = read_flight_log(&csv, &IngestOptions::default()).unwrap();
    let rows = log.len() as u64;
    for topic in [
        "/mag/1/scalar",
        "/mag/2/scalar",
        "/mag/a/vector",
        "/ins/attitude",
        "/gps/fix",
        "/aux/cur_strb",
        "/mag/1/compensated",
        "/mag/2/compensated",
        "/mag/1/compensated_sigma",
        "/mag/2/compensated_sigma",
        "/magcomp/flags",
    ] {
        assert_eq!(summary["counts"][topic].as_u64(), Some(rows), "{topic}");
    }
    assert_eq!(summary["schemas"]["/mag/a/vector"], "magcomp.VectorMag");
    assert_eq!(summary["schemas"]["/gps/fix"], "foxglove.LocationFix");
    assert_eq!(summary["schemas"]["/magcomp/flags"], "magcomp.RowFlags");
    assert_eq!(summary["schemas"]["/mag/1/compensated_sigma"], "magcomp.Sample");
    assert_eq!(summary["timestamps_match_log_time"], true);
    assert!(
        summary["chunk_indexes"].as_u64().unwrap() > 0,
        "the file is chunked and indexed"
    );
    let first_scalar = log.channel("mag_1_uc").unwrap().values[0];
    assert_eq!(
        summary["first"]["/mag/1/scalar"]["total_nt"].as_f64(),
        Some(first_scalar)
    );
    let first_x = log.channel("flux_a_x").unwrap().values[0];
    assert_eq!(summary["first"]["/mag/a/vector"]["x_nt"].as_f64(), Some(first_x));
    assert_eq!(
        summary["metadata"],
        serde_json::json!(["magcomp.model", "magcomp.quality"])
    );
    assert_eq!(
        summary["attachments"],
        serde_json::json!(["model.json", "quality.json"])
    );
}
