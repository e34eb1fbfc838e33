//! `magcomp convert`: a flight log rewritten in another format.

use std::path::Path;

use magcomp::config::Pipeline;
use magcomp::formats::{prepare, Destination, OutputKind};

use super::print_notes;

/// Reads `flight` and writes it to `out` in the format its extension names.
pub fn convert(
    flight: &Path,
    out: &Path,
    config: Option<&Path>,
    date: Option<magcomp::ingest::flight_date::FlightDate>,
) -> anyhow::Result<()> {
    let mut pipeline = Pipeline::load_or_default(config)?;
    pipeline.settings.ingest.date = date.or(pipeline.settings.ingest.date);
    let inputs: Vec<&Path> = std::iter::once(flight).chain(config).collect();
    print_notes(&prepare(
        &inputs,
        &[Destination::new(out, OutputKind::Flight, "--out")],
    )?);
    let log = magcomp::formats::read_flight_log(flight, &pipeline.settings.ingest)?;
    magcomp::formats::write_flight_log(&log, out)?;
    let warnings = (log.reading_warnings().iter().cloned())
        .chain(magcomp::formats::mcap::undated_warning(&log, out))
        .chain(magcomp::formats::write::text_columns_warning(&log, out, false));
    for warning in warnings {
        println!("  warning: {warning}");
    }
    if !log.declared_units().is_empty() {
        let kept = match magcomp::formats::write::detect_output_format(out) {
            magcomp::formats::Format::DelimitedText => "written under the header",
            _ => "not written: this format keeps no row of units",
        };
        println!(
            "  note: line 2 of {} is a row of units, read as units: {kept}",
            flight.display()
        );
    }
    println!(
        "wrote {} ({} rows, {} channels)",
        out.display(),
        log.len(),
        log.channels().len()
    );
    if let Some(report) = log.alignment() {
        println!("  time base: {} ({} rows)", report.time_base, report.rows);
        // The alignment's warnings are among the reading warnings above.
        for note in &report.notes {
            println!("  note: {note}");
        }
    }
    Ok(())
}
