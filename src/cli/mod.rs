//! The subcommands of the `magcomp` command line, one module each, and
//! what they share: reading a flight, naming outputs, printing notes and
//! the spinner.

use std::path::{Path, PathBuf};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use magcomp::config::{FlightJob, Pipeline};
use magcomp::formats::prepare;
use magcomp::output::sink::FlightOutputs;

pub mod compensate;
pub mod convert;
pub mod detect;
pub mod diagnose;
pub mod plan;
pub mod progress;
pub mod run;
pub mod sample_flight;
pub mod simulate;
pub mod summarize;

/// `--date`: a day as YYYY-MM-DD.
/// How a command that compensates ended, for its exit code: 0 when every
/// channel is PASS or CHECK, 3 when one is FAIL (docs/CONTRACT.md §2).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// Done; no channel at FAIL, or FAIL allowed (`--exit-zero-on-fail`).
    Done,
    /// Done, the outputs written, with at least one channel at FAIL.
    ChannelFailed,
}

impl Outcome {
    /// [`Outcome::ChannelFailed`] when `failed` and FAIL is not to exit 0.
    pub fn of(failed: bool, exit_zero_on_fail: bool) -> Self {
        match failed && !exit_zero_on_fail {
            true => Outcome::ChannelFailed,
            false => Outcome::Done,
        }
    }
}

/// The line on stderr for a run that ends with a channel at FAIL.
pub const FAIL_EXIT_LINE: &str = "magcomp: at least one channel's verdict is FAIL (its reasons are printed above and in the report); the outputs were written; exit code 3 (--exit-zero-on-fail, or [quality] exit_zero_on_fail = true, exits 0)";

pub fn parse_date(text: &str) -> Result<magcomp::ingest::flight_date::FlightDate, String> {
    magcomp::ingest::flight_date::FlightDate::parse(text)
        .ok_or_else(|| format!("'{text}' is not a day; write it as YYYY-MM-DD, e.g. 2020-06-20"))
}

/// Reads a flight and screens its samples, printing what was masked.
pub fn read_screened(
    flight: &Path,
    pipeline: &Pipeline,
) -> magcomp::error::Result<magcomp::ingest::flight_log::FlightLog> {
    let recorded = magcomp::formats::read_flight_log(flight, &pipeline.settings.ingest)?;
    let screened = magcomp::ingest::screen::screen_samples(&recorded)?;
    for warning in screened.warnings(&recorded) {
        println!("  warning: {warning}");
    }
    Ok(screened.log.unwrap_or(recorded))
}

/// Reads `job`'s flight and prepares it for the stages (screened, its
/// sensor, channels and windows chosen), printing what screening masked.
pub fn read_prepared(
    job: &FlightJob,
    pipeline: &Pipeline,
) -> magcomp::error::Result<magcomp::pipeline::PreparedFlight> {
    let recorded = magcomp::formats::read_flight_log(&job.input, &pipeline.settings.ingest)?;
    let prepared = magcomp::pipeline::PreparedFlight::new(recorded, job, &pipeline.settings)?;
    for warning in prepared.warnings() {
        println!("  warning: {warning}");
    }
    Ok(prepared)
}

/// `<stem of path><suffix>` in `path`'s folder.
pub fn beside(path: &Path, suffix: &str) -> PathBuf {
    let stem = path
        .file_stem()
        .map_or("flight".into(), |s| s.to_string_lossy().into_owned());
    path.with_file_name(format!("{stem}{suffix}"))
}

/// Prints each note on its own indented line.
pub fn print_notes(notes: &[impl std::fmt::Display]) {
    for note in notes {
        println!("  note: {note}");
    }
}

/// "40 s", "3 min", "1 h 20 min": a time left, as a person says it.
pub fn duration_words(duration: Duration) -> String {
    let seconds = duration.as_secs();
    match seconds {
        0..=59 => format!("{seconds} s"),
        60..=3599 => format!("{} min", seconds.div_ceil(60)),
        _ => format!("{} h {} min", seconds / 3600, (seconds % 3600) / 60),
    }
}

/// A spinner on stderr with `message` and the time elapsed; indicatif
/// draws nothing when stderr is not a terminal (piped or redirected).
pub fn spinner(message: String) -> ProgressBar {
    let bar = ProgressBar::new_spinner().with_message(message);
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg} [{elapsed}]")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(Duration::from_millis(120));
    bar
}

/// Makes the folders of a flight's outputs; what it made, as notes.
pub fn prepare_flight_outputs(
    job: &FlightJob,
    outputs: &FlightOutputs,
) -> magcomp::error::Result<Vec<magcomp::messages::Setup>> {
    let inputs: Vec<&Path> = std::iter::once(job.input.as_path())
        .chain(job.diagnosis.as_deref())
        .chain(job.plan.as_deref())
        .chain(job.model.as_deref())
        .collect();
    prepare(&inputs, &outputs.destinations())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_left_reads_as_a_person_says_it() {
        assert_eq!(duration_words(Duration::from_secs(40)), "40 s");
        assert_eq!(duration_words(Duration::from_secs(61)), "2 min");
        assert_eq!(duration_words(Duration::from_secs(4_800)), "1 h 20 min");
    }
}
