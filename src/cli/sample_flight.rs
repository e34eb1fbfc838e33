//! `magcomp sample-flight`: a small flight with its calibration windows.

use std::path::Path;

use magcomp::formats::{prepare, Destination, OutputKind};
use magcomp::simulate::sample_flight;

use super::print_notes;

/// Writes a sample flight to `out` and its calibration windows to `windows`.
pub fn sample_flight(out: &Path, windows: &Path, seed: u64) -> anyhow::Result<()> {
    print_notes(&prepare(
        &[],
        &[
            Destination::new(out, OutputKind::Csv, "--out"),
            Destination::new(windows, OutputKind::Json, "--windows"),
        ],
    )?);
    let flight = sample_flight::generate(&sample_flight::SampleFlightSpec::default(), seed);
    sample_flight::write(&flight, out, windows)?;
    println!(
        "wrote {} ({} rows) and {}",
        out.display(),
        flight.time_s.len(),
        windows.display()
    );
    Ok(())
}
