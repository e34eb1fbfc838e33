//! The file formats: reading a flight log into a
//! [`FlightLog`] and writing it back with
//! magcomp's columns, one module per format that does both.
//!
//! - [`csv`]: delimited text (CSV, `;`, tab, whitespace-aligned);
//! - [`xyz`]: Geosoft XYZ;
//! - [`mcap`]: MCAP recordings (protobuf, JSON and ROS 2 messages), with
//!   [`align`] putting multi-rate topics onto one time base;
//! - `hdf5`: the MagNav.jl HDF5 layout.
//!
//! The input format is chosen from the file extension, with a look at the
//! content as a fallback; the output format from the output path's
//! extension ([`mod@write`]). [`table::FORMATS`] holds a row per format (its
//! extensions, its signature, its reader and writers): a new format is a
//! row there and its module. Every output is staged and renamed into place
//! ([`destination`]), never over an input.

pub mod align;
pub mod columns;
pub mod csv;
pub mod destination;
#[cfg(feature = "hdf5")]
pub mod hdf5;
pub mod mcap;
pub mod ros;
pub mod table;
pub mod units;
pub mod write;
pub mod xyz;

pub use destination::{prepare, stage, Destination, OutputKind, OutputSet, Staged};
pub use write::{
    added_column_names, detect_output_format, flags_column_name, output_column_name, stage_compensated,
    stage_detect_json, stage_flight_log, stage_json, write_atomic, write_flight_log, write_json,
};

use std::io::Read;
use std::path::Path;

pub use columns::{ColumnNames, GivenColumn, VectorColumns};

use crate::error::{Error, Result};
use crate::ingest::flight_log::FlightLog;
use crate::messages::{Reading, Warning};

/// Options for reading a flight log.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IngestOptions {
    /// Which column plays which role.
    pub columns: ColumnNames,
    /// How multi-rate channels (MCAP) go onto one time base.
    pub alignment: align::AlignmentOptions,
    /// What ROS 2 topics of an MCAP recording become (`[[topic]]`).
    pub topics: Vec<TopicMapping>,
    /// The day the flight was flown (`--date`), over what the file says.
    pub date: Option<crate::ingest::flight_date::FlightDate>,
}

/// A `[[topic]]` entry: what a ROS 2 `sensor_msgs/msg/MagneticField` topic
/// becomes. Without one, a MagneticField topic is a vector magnetometer
/// named `flux_<topic>`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicMapping {
    /// The topic, e.g. `/imu/mag`.
    pub topic: String,
    /// Vector magnetometer prefix: channels `<prefix>_x|y|z`, nT.
    pub vector: Option<String>,
    /// Scalar magnetometer channel name: the field's magnitude, nT.
    pub scalar: Option<String>,
}

/// The file formats magcomp reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// CSV and other delimited text with a header row.
    DelimitedText,
    /// Geosoft XYZ.
    Xyz,
    /// MCAP container.
    Mcap,
    /// HDF5 (MagNav challenge layout).
    Hdf5,
}

/// The extension of `path` in lowercase, without the dot (empty when it
/// has none or it is not UTF-8).
pub fn lowercase_extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default()
}

/// Chooses the format of `path` from its extension, or from its first bytes
/// when the extension says nothing.
pub fn detect_format(path: &Path) -> Result<Format> {
    if let Some(format) = Format::of_extension(&lowercase_extension(path)) {
        return Ok(format);
    }
    // Sniffing a named pipe would block until something wrote to it.
    check_not_empty(path)?;
    let mut head = [0u8; 512];
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, "opening", e))?;
    let read = file.read(&mut head).map_err(|e| Error::io(path, "reading", e))?;
    let head = &head[..read];
    if let Some(format) = Format::of_magic(head) {
        return Ok(format);
    }
    let head = head.strip_prefix(b"\xef\xbb\xbf").unwrap_or(head);
    let looks_textual = !head.is_empty() && head.iter().all(|b| b.is_ascii_graphic() || b.is_ascii_whitespace());
    match (looks_textual, xyz::looks_like_xyz(head)) {
        (true, true) => Ok(Format::Xyz),
        (true, false) => Ok(Format::DelimitedText),
        _ => Err(unsupported(path, "unknown")),
    }
}

/// Longest step between consecutive times that a flight can hold without
/// a word: a day. Beyond it the time column is most likely damaged, or two
/// flights were joined.
pub const LONGEST_TIME_STEP_S: f64 = 86_400.0;

/// A warning for each step of the time column longer than
/// [`LONGEST_TIME_STEP_S`] (the first three, then their count). The rows
/// are kept: the step splits the flight as any gap does.
fn time_jumps(path: &Path, log: &FlightLog) -> Vec<Warning> {
    let time = log.time_s();
    let jumps: Vec<usize> = (1..time.len())
        .filter(|&k| time[k] - time[k - 1] > LONGEST_TIME_STEP_S)
        .collect();
    let mut warnings: Vec<Warning> = (jumps.iter().take(3))
        .map(|&k| {
            Reading::TimeJump {
                file: path.to_path_buf(),
                column: log.time_column().to_string(),
                from_s: time[k - 1],
                to_s: time[k],
                row: k + 1,
            }
            .into()
        })
        .collect();
    if jumps.len() > 3 {
        warnings.push(
            Reading::TimeJumps {
                file: path.to_path_buf(),
                column: log.time_column().to_string(),
                count: jumps.len(),
            }
            .into(),
        );
    }
    warnings
}

/// Reads the flight log at `path`, choosing the reader by extension or content.
pub fn read_flight_log(path: &Path, options: &IngestOptions) -> Result<FlightLog> {
    let format = detect_format(path)?;
    check_not_empty(path)?;
    if matches!(format, Format::DelimitedText | Format::Xyz) {
        check_line_ends(path)?;
    }
    let log = (format.row().read)(path, options)?;
    let recorded = log.date().or_else(|| date_from_columns(&log));
    let mut warnings = log.reading_warnings().to_vec();
    warnings.extend(options.columns.check_given(path, &log)?);
    warnings.extend(units::unit_warnings(path, &log));
    warnings.extend(time_jumps(path, &log));
    if let (Some(given), Some(recorded)) = (options.date, recorded) {
        if given != recorded {
            warnings.push(
                Reading::DayGivenOverRecorded {
                    file: path.to_path_buf(),
                    given: given.to_string(),
                    recorded: recorded.to_string(),
                }
                .into(),
            );
        }
    }
    Ok(log.with_date(options.date.or(recorded)).with_reading_warnings(warnings))
}

/// The flight's day from SGL's `year` and `doy` (day of year) columns: the
/// first row where both hold a valid day.
fn date_from_columns(log: &FlightLog) -> Option<crate::ingest::flight_date::FlightDate> {
    let (year, doy) = (log.channel("year")?, log.channel("doy")?);
    year.values.iter().zip(&doy.values).find_map(|(&year, &day)| {
        let whole = |v: f64| (v.is_finite() && v.fract() == 0.0 && (1.0..1e4).contains(&v)).then_some(v as u32);
        crate::ingest::flight_date::FlightDate::from_day_of_year(whole(year)? as i32, whole(day)?)
    })
}

/// Refuses a file of no bytes at all, or one that is not a regular file,
/// with a message that says so.
fn check_not_empty(path: &Path) -> Result<()> {
    let metadata = std::fs::metadata(path).map_err(|e| Error::io(path, "opening", e))?;
    // A named pipe or a device reports no length, and a flight is read
    // more than once (its format sniffed, then read).
    if !metadata.is_file() {
        return Err(Error::UnsupportedFormat {
            path: path.to_path_buf(),
            message: "not a regular file (a named pipe, a device or a folder): magcomp reads a flight log more than once, so write it to a file first and give that file".into(),
        });
    }
    match metadata.len() {
        0 => Err(Error::NoData {
            path: path.to_path_buf(),
            problem: "the file is empty (0 bytes)".into(),
        }),
        _ => Ok(()),
    }
}

/// Refuses text whose lines end in a carriage return alone (classic Mac OS
/// line ends): the readers split lines at line feeds, and would see one
/// line. CRLF and LF are both read.
fn check_line_ends(path: &Path) -> Result<()> {
    let mut head = vec![0u8; 1 << 16];
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, "opening", e))?;
    let read = file.read(&mut head).map_err(|e| Error::io(path, "reading", e))?;
    let head = &head[..read];
    match head.contains(&b'\r') && !head.contains(&b'\n') {
        true => Err(Error::UnsupportedFormat {
            path: path.to_path_buf(),
            message:
                "its lines end in a carriage return alone (classic Mac OS line ends), which magcomp does not read. \
                      Convert them to line feeds, e.g. `tr '\\r' '\\n' < FILE > FIXED`, and read the converted file"
                    .into(),
        }),
        false => Ok(()),
    }
}

pub(crate) fn unsupported(path: &Path, kind: &str) -> Error {
    Error::UnsupportedFormat {
        path: path.to_path_buf(),
        message: format!(
            "this build reads delimited text flight logs (CSV with a header row; ',', ';', tab or \
             whitespace separated), Geosoft XYZ, MCAP and HDF5 (MagNav layout). The '{kind}' format is not readable here; export the \
             flight as CSV with SGL field names (tt, mag_1_uc, flux_a_x, ...)."
        ),
    }
}
