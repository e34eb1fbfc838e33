//! What every fuzz target does with its bytes, and what `cargo test`
//! replays on stable Rust over the kept corpora (`tests/fuzz_corpus.rs`):
//! the bytes become a flight file, which goes through the whole of
//! `process_flight` (reading, screening, detection, the fit, compensation,
//! quality and the HTML report, written to a temporary folder) twice: with
//! the windows detected, and with one window given over the middle 80 % of
//! whatever the file holds, so that a flight without a calibration box
//! still reaches the fit. Any result is fine; a panic or an abort is the
//! failure.

use std::path::Path;

use magcomp::calibration::windows::CalibrationWindow;
use magcomp::config::{FlightJob, Settings};
use magcomp::diagnose::ApplyDiagnosis;
use magcomp::formats::read_flight_log;
use magcomp::output::sink::{process_flight, FlightOutputs};

/// Runs the bytes of a `.<extension>` flight file through every stage;
/// returns whether a run got to the end (the report written).
pub fn exercise(bytes: &[u8], extension: &str) -> bool {
    let folder = tempfile::tempdir().expect("a temporary folder");
    let path = folder.path().join(format!("input.{extension}"));
    std::fs::write(&path, bytes).expect("writing the input");
    run_every_stage(&path, &folder.path().join("out"))
}

fn run_every_stage(input: &Path, out: &Path) -> bool {
    let mut options = Settings::default();
    // Plain Tolles-Lawson keeps one input to a second or two; the
    // diagnosis's own readers and fits are the same code.
    options.diagnose.apply = ApplyDiagnosis::Never;
    let outputs = FlightOutputs::in_directory(out, input);
    let detected = process_flight(&FlightJob::new(input), &options, &outputs).is_ok();
    let Ok(log) = read_flight_log(input, &options.ingest) else {
        return detected;
    };
    let (Some(&first), Some(&last)) = (log.time_s().first(), log.time_s().last()) else {
        return detected;
    };
    let margin = (last - first) / 10.0;
    let windows: Vec<CalibrationWindow> = CalibrationWindow::parse(&format!("{}:{}", first + margin, last - margin))
        .into_iter()
        .collect();
    let job = FlightJob {
        windows,
        ..FlightJob::new(input)
    };
    let given = process_flight(&job, &options, &outputs).is_ok();
    detected || given
}
