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
    #[error("{path}: {action} failed: {source}. {}", io_hint(.source))]
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

    /// A header names one column twice.
    #[error("{path}, line {line}: column '{}' appears twice in the header (fields {first} and {second}). Rename one of them: every column needs its own name, or no one can tell which holds the data.", Excerpt(.column))]
    DuplicateColumn {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number of the header.
        line: u64,
        /// The name given twice.
        column: String,
        /// 1-based position of its first field.
        first: usize,
        /// 1-based position of the second.
        second: usize,
    },

    /// A line of a text file is not text.
    #[error("{path}, line {line}: the line is not valid text (UTF-8){}. Export the file again as UTF-8 or ASCII text, or remove the stray bytes from that line.", .byte.map(|b| format!(", from byte {b} of the file")).unwrap_or_default())]
    NotText {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number in the file.
        line: u64,
        /// Offset of the line (or of the first bad byte) in the file,
        /// where known.
        byte: Option<u64>,
    },

    /// A cell in a numeric column holds something that is not a number.
    #[error("{path}, line {line}, column '{}': '{}' is not a number. Correct the cell, or leave it empty (or write NaN or *) to mark the sample missing.", Excerpt(.column), Excerpt(.value))]
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

    /// The line under the header gives time a unit but is not a row of
    /// units: it holds a number, or another count of cells.
    #[error("{path}, line {line}, column '{}': '{}' {problem}; the line under the header looks like a row of units but is not one. A row of units has one cell per column, each a unit or empty: correct that line, or delete it (for example `sed -i 2d FILE`).", Excerpt(.column), Excerpt(.value))]
    UnitsRow {
        /// The file concerned.
        path: PathBuf,
        /// 1-based line number in the file.
        line: u64,
        /// Column name from the header.
        column: String,
        /// The cell text.
        value: String,
        /// What is wrong with the cell or the line.
        problem: String,
    },

    /// The time column is missing, non-finite or not strictly increasing.
    /// (The fix for an unsorted file is [`SORT_BY_TIME`].)
    #[error(
        "{path}, {location}: time column '{column}' {problem}. Time must be finite and strictly increasing; {fix}."
    )]
    BadTime {
        /// The file concerned.
        path: PathBuf,
        /// Where: "line 12" for text files, "sample 10" otherwise.
        location: String,
        /// Time column name.
        column: String,
        /// What is wrong with it.
        problem: String,
        /// What to do about it, as the problem's cause suggests.
        fix: String,
    },

    /// A file holds no data to work on.
    #[error(
        "{path}: {problem}. Check that the export or copy of the flight finished; magcomp needs the recorded rows."
    )]
    NoData {
        /// The file concerned.
        path: PathBuf,
        /// What is missing.
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

    /// Screening masked every sample of a column the run needs.
    #[error("{path}: every sample of '{column}' was masked on screening: {reason}. {hint}")]
    AllMasked {
        /// The file concerned.
        path: PathBuf,
        /// Column name.
        column: String,
        /// What screening found, in words.
        reason: String,
        /// What to do.
        hint: String,
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
    #[error("calibration window '{label}' ({} to {} s): {problem}. {hint}", Number(*.t_start), Number(*.t_end))]
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

    /// A file given as one of magcomp's own JSON files is not one.
    #[error("{path}: not {expected}: {problem}. {hint}")]
    NotOurFile {
        /// The file.
        path: PathBuf,
        /// What it was given as ("a DETECT.json manoeuvre list").
        expected: &'static str,
        /// What the reader found wrong.
        problem: String,
        /// What to do.
        hint: &'static str,
    },

    /// A fit was asked for without any calibration window.
    #[error("{path}: no calibration windows to fit on: give them with --window T0:T1, in pipeline.toml, or as a DETECT.json file; or, for a survey flight without a box, compensate it with its aircraft's saved model (--apply MODEL.json, or [[flight]] model)")]
    NoCalibrationWindows {
        /// The flight.
        path: PathBuf,
    },

    /// A campaign's flight without a box of its own, given no calibration
    /// flight's model.
    #[error("{path}: no calibration windows to fit on, and the campaign gave it no calibration flight's model: {why}")]
    NoCampaignCalibration {
        /// The flight.
        path: PathBuf,
        /// Why none, what the campaign has, and what to do.
        why: String,
    },

    /// The band-pass filter cannot be designed for a flight's sample rate.
    #[error("{path}: the band-pass filter cannot be designed: {source}. {hint}")]
    FilterDesign {
        /// The flight.
        path: PathBuf,
        /// Why the design failed.
        source: crate::numerics::filter::FilterError,
        /// What to do.
        hint: String,
    },

    /// The vector compensation of a fluxgate could not be done.
    #[error("vector compensation of '{sensor}': {message}")]
    Vector {
        /// Fluxgate prefix.
        sensor: String,
        /// Why, in words.
        message: String,
    },

    /// The fit could not be computed.
    #[error("{path}: fitting channel '{channel}': {source}")]
    Fit {
        /// The flight.
        path: PathBuf,
        /// Scalar channel (or fluxgate) being fitted.
        channel: String,
        /// Why.
        source: FitFailure,
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

    /// A flight failed, and its columns are not in the units magcomp
    /// reads: the likely cause, named first.
    #[error("{problems}. That is the likely cause of what followed: {source}")]
    UnitsLookWrong {
        /// What the values show (`crate::formats::units`).
        problems: String,
        /// The error the stages raised.
        #[source]
        source: Box<Error>,
    },

    /// A flight's saved model is not there to apply, and why.
    #[error("{model}: {reason}")]
    ModelUnavailable {
        /// The model file the flight names.
        model: PathBuf,
        /// Why it is not (the flight that writes it failed, or none does).
        reason: String,
    },

    /// A saved model (`--apply`) cannot compensate the flight it is given.
    #[error("{model}: cannot be applied to {flight}: {problem}. {hint}")]
    ModelMismatch {
        /// The model file (MODEL.json).
        model: PathBuf,
        /// The flight it was to compensate.
        flight: PathBuf,
        /// What differs.
        problem: String,
        /// What to do.
        hint: String,
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
    #[error("{path}: could not serialise {what}: {source}")]
    Serialise {
        /// The output file.
        path: PathBuf,
        /// What was being written.
        what: &'static str,
        /// The serialiser's (or the plotting library's) own error.
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
}

/// Why a fit failed: the solver's or the filter's own error, or a
/// sentence where neither applies.
#[derive(Debug, thiserror::Error)]
pub enum FitFailure {
    /// The regression could not be solved.
    #[error(transparent)]
    Solve(#[from] crate::numerics::solve::SolveError),
    /// The calibration data could not be filtered.
    #[error(transparent)]
    Filter(#[from] crate::numerics::filter::FilterError),
    /// Anything else, in words.
    #[error("{0}")]
    Other(String),
}

/// What to do about an operating-system error, by its kind.
fn io_hint(error: &std::io::Error) -> &'static str {
    use std::io::ErrorKind;
    match error.kind() {
        ErrorKind::NotFound => "Check that the path exists.",
        ErrorKind::PermissionDenied => "Check the permissions of the file and its folder.",
        ErrorKind::UnexpectedEof => "The file ends early; check that it was copied or exported completely.",
        ErrorKind::InvalidData => "The file is not what its name says, or it is damaged.",
        ErrorKind::InvalidInput => "Copy what it holds to a file and give that file.",
        _ => "Check the file, its folder and the disk (space, permissions, a network drive that went away).",
    }
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

/// A number as an error message shows it: plain decimals for everyday
/// magnitudes, scientific notation beyond them (so 1e308 is not 309 digits).
#[derive(Debug, Clone, Copy)]
pub struct Number(pub f64);

impl std::fmt::Display for Number {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let magnitude = self.0.abs();
        match magnitude == 0.0 || !magnitude.is_finite() || (1e-4..1e15).contains(&magnitude) {
            true => write!(f, "{}", self.0),
            false => write!(f, "{:e}", self.0),
        }
    }
}

/// Text quoted in an error message, cut to its first 60 characters with
/// the length of the whole when longer (a 2 MB cell is not echoed).
#[derive(Debug, Clone, Copy)]
pub struct Excerpt<'a>(pub &'a str);

impl std::fmt::Display for Excerpt<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        const SHOWN: usize = 60;
        let (shown, whole) = match self.0.char_indices().nth(SHOWN) {
            None => (self.0, true),
            Some((end, _)) => (&self.0[..end], false),
        };
        // Control characters (a flipped byte) are shown escaped, not sent
        // to the terminal.
        for c in shown.chars() {
            match c.is_control() {
                true => write!(f, "{}", c.escape_default())?,
                false => write!(f, "{c}")?,
            }
        }
        match whole {
            true => Ok(()),
            false => write!(f, "… ({} bytes in all)", self.0.len()),
        }
    }
}

/// What to do about a time column that goes back: sort and deduplicate.
pub const SORT_BY_TIME: &str = "sort the file by time and remove duplicated rows";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_and_quoted_text_stay_short() {
        assert_eq!(Number(1e308).to_string(), "1e308");
        assert_eq!(Number(-4.9e-324).to_string(), "-5e-324");
        assert_eq!(Number(46012.3).to_string(), "46012.3");
        assert_eq!(Number(0.0).to_string(), "0");
        assert_eq!(Number(f64::NAN).to_string(), "NaN");
        let cell = "9".repeat(2_000_000);
        let quoted = Excerpt(&cell).to_string();
        assert!(
            quoted.len() < 100 && quoted.ends_with("(2000000 bytes in all)"),
            "{quoted}"
        );
        assert_eq!(Excerpt("5x1").to_string(), "5x1");
        assert_eq!(Excerpt("16519\u{15}581").to_string(), "16519\\u{15}581");
        assert_eq!(
            Excerpt(&"é".repeat(61)).to_string(),
            format!("{}… (122 bytes in all)", "é".repeat(60))
        );
    }
}
