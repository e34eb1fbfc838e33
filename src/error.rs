//! The library's error type.
//!
//! Every variant carries what a user needs to find and fix the problem: the
//! file, the line or time, the column and the offending value, and a sentence
//! saying what to do. The binary prints the `Display` text as one paragraph.

use std::path::PathBuf;

/// Result alias used across the library.
pub type Result<T> = std::result::Result<T, Error>;

/// Everything that can go wrong between reading a flight log and writing
/// compensated data.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A file could not be opened, read or written.
    #[error("{path}: {action} failed: {source}. Check that the path exists and is accessible.")]
    Io {
        /// The file concerned.
        path: PathBuf,
        /// What was being done ("reading", "writing", ...).
        action: &'static str,
        /// The operating system's error.
        source: std::io::Error,
    },

    /// A CSV record could not be split into fields.
    #[error("{path}, line {line}: {message}. Fix the row so that it has one field per header column.")]
    MalformedRow {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number in the file.
        line: u64,
        /// What was wrong.
        message: String,
    },

    /// A cell in a numeric column holds something that is not a number.
    #[error("{path}, line {line}, column '{column}': '{value}' is not a number. Correct the cell, or leave it empty (or write NaN or *) to mark the sample missing.")]
    MalformedNumber {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number in the file.
        line: u64,
        /// Column name from the header.
        column: String,
        /// The cell text.
        value: String,
    },

    /// The time column is missing, non-finite or not strictly increasing.
    #[error("{path}, {location}: time column '{column}' {problem}. Time must be finite and strictly increasing; sort the file by time and remove duplicated rows.")]
    BadTime {
        /// The file concerned.
        path: PathBuf,
        /// Where: "line 12" for text files, "sample 10" otherwise.
        location: String,
        /// Time column name.
        column: String,
        /// What is wrong with it.
        problem: String,
    },

    /// A column the pipeline needs is not in the file.
    #[error("{path}: no {role} column found (looked for {looked_for}). {hint}")]
    MissingColumn {
        /// The file concerned.
        path: PathBuf,
        /// The role that could not be filled.
        role: &'static str,
        /// The names that were looked for.
        looked_for: String,
        /// What the user can do.
        hint: String,
    },

    /// A required channel has no valid sample at all.
    #[error("{path}: column '{column}' has no valid sample (every cell is empty, NaN or *). Check the export, or exclude the channel with --channels or [columns] in pipeline.toml.")]
    AllMissing {
        /// The file concerned.
        path: PathBuf,
        /// Column name.
        column: String,
    },

    /// Channels of a flight log have different lengths.
    #[error("flight log: channel '{column}' has {found} samples but the time base has {expected}. Every channel must have one value per time sample.")]
    LengthMismatch {
        /// Channel name.
        column: String,
        /// Samples in the channel.
        found: usize,
        /// Samples in the time base.
        expected: usize,
    },

    /// A calibration window is unusable.
    #[error("calibration window '{label}' ({t_start} to {t_end} s): {problem}. {hint}")]
    BadWindow {
        /// Window label.
        label: String,
        /// Window start, in the file's time unit.
        t_start: f64,
        /// Window end, in the file's time unit.
        t_end: f64,
        /// What is wrong.
        problem: String,
        /// What to do.
        hint: String,
    },

    /// A configuration value is invalid.
    #[error("{source_name}: {message}")]
    Config {
        /// Where the configuration came from (file path or "command line").
        source_name: String,
        /// What is wrong and how to fix it.
        message: String,
    },

    /// The fit could not be computed.
    #[error("fitting channel '{channel}': {message}")]
    Fit {
        /// Scalar channel being fitted.
        channel: String,
        /// What went wrong and what to try.
        message: String,
    },

    /// The calibration data cannot support what was asked of it: too few
    /// windows, headings or samples to hold any of them out.
    #[error("{path}: {task} needs calibration manoeuvres to hold out, and {problem}. {hint}")]
    NotEnoughCalibration {
        /// The flight concerned.
        path: PathBuf,
        /// What could not be done ("the diagnosis").
        task: &'static str,
        /// What the flight lacks.
        problem: String,
        /// What to do.
        hint: String,
    },

    /// A saved result belongs to another flight than the one it is applied to.
    #[error("{path}: {what} was made on {made_on}, not on {applied_to} ({difference}). Diagnose this flight with `magcomp diagnose`, or pass --force to apply it anyway.")]
    OtherFlight {
        /// The saved file.
        path: PathBuf,
        /// What the file holds ("this diagnosis").
        what: &'static str,
        /// The flight it was made on.
        made_on: String,
        /// The flight it was to be applied to.
        applied_to: String,
        /// What differs (rows, time span, content hash).
        difference: String,
    },

    /// The format of an input file is not supported.
    #[error("{path}: {message}")]
    UnsupportedFormat {
        /// The file concerned.
        path: PathBuf,
        /// What was expected.
        message: String,
    },

    /// An output cannot be written where it was asked for.
    #[error("{path}: {problem}. {hint}")]
    Output {
        /// The destination.
        path: PathBuf,
        /// What is wrong with it.
        problem: String,
        /// What to do.
        hint: String,
    },

    /// Serialising an output failed.
    #[error("{path}: could not serialise {what}: {message}")]
    Serialise {
        /// The output file.
        path: PathBuf,
        /// What was being written.
        what: &'static str,
        /// The serialiser's message.
        message: String,
    },
}

impl Error {
    /// Builds an [`Error::Io`] for `path`.
    pub fn io(path: impl Into<PathBuf>, action: &'static str, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            action,
            source,
        }
    }
}
