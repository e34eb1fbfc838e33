//! One row per file format: its extensions, how its files begin, and the
//! functions that read it and stage it. The reader, the writers and the
//! format detection all go through this table, so a new format is one
//! row here and its module.

use std::path::Path;

use super::mcap::McapExtras;
use super::{ColumnNames, Format, IngestOptions, Staged};
use crate::compensate::Compensation;
use crate::error::Result;
use crate::ingest::flight_log::FlightLog;

/// What is staged: the columns magcomp adds (from
/// [`super::added_column_names`]), the compensation they hold (none for a
/// flight log written as it is) and what an MCAP output also stores.
pub struct StageRequest<'a> {
    /// The added columns' names.
    pub added: &'a [String],
    /// Where the output goes.
    pub output: &'a Path,
    /// The compensation, when the flight is written compensated.
    pub compensation: Option<&'a Compensation>,
    /// The models and quality an MCAP output stores.
    pub extras: &'a McapExtras,
}

/// A compensated copy of an input of the format's own kind, its lines kept
/// as they are and the added columns appended.
pub type StageCopy = fn(&FlightLog, &ColumnNames, &StageRequest, &Compensation) -> Result<Staged>;

/// A file format: how it is recognised, read and written.
pub struct FormatRow {
    /// The format.
    pub format: Format,
    /// The extensions that name it, in lowercase without the dot.
    pub extensions: &'static [&'static str],
    /// The bytes its files begin with, when it has such a signature.
    pub magic: Option<&'static [u8]>,
    /// Reads a file of the format.
    pub read: fn(&Path, &IngestOptions) -> Result<FlightLog>,
    /// Stages a flight log in the format, from the log's columns.
    pub stage: fn(&FlightLog, &StageRequest) -> Result<Staged>,
    /// Stages a compensated copy of an input of this format, keeping its
    /// lines (and so its text columns); `None` where the format is always
    /// written from the log.
    pub copy: Option<StageCopy>,
}

/// Every format magcomp reads and writes. Delimited text comes first: an
/// output whose extension names no format is written as comma-separated
/// text.
pub const FORMATS: [FormatRow; 4] = [
    FormatRow {
        format: Format::DelimitedText,
        extensions: &["csv", "txt", "tsv", "dat"],
        magic: None,
        read: |path, options| super::csv::read_csv(path, &options.columns),
        stage: |log, request| super::csv::stage_log_csv(log, request.added, request.output, request.compensation),
        copy: Some(|log, names, request, compensation| {
            super::csv::stage_compensated_csv(
                (log.source(), names),
                log.source_row_offsets(),
                request.output,
                compensation,
                request.added,
            )
        }),
    },
    FormatRow {
        format: Format::Xyz,
        extensions: &["xyz"],
        magic: None,
        read: |path, options| super::xyz::read_xyz(path, &options.columns),
        stage: |log, request| super::xyz::stage_log_xyz(log, request.added, request.output, request.compensation),
        copy: Some(|log, names, request, compensation| {
            super::xyz::stage_xyz_copy(log, names, request.added, request.output, compensation)
        }),
    },
    FormatRow {
        format: Format::Mcap,
        extensions: &["mcap"],
        magic: Some(b"\x89MCAP"),
        read: super::mcap::read_mcap,
        stage: |log, request| super::mcap::stage_mcap(log, request.output, request.compensation, request.extras),
        copy: None,
    },
    FormatRow {
        format: Format::Hdf5,
        extensions: &["h5", "hdf5"],
        magic: Some(b"\x89HDF\r\n\x1a\n"),
        #[cfg(feature = "hdf5")]
        read: |path, options| super::hdf5::read_hdf5(path, &options.columns),
        #[cfg(not(feature = "hdf5"))]
        read: |path, _| Err(super::unsupported(path, "hdf5 (this build has the 'hdf5' feature off)")),
        #[cfg(feature = "hdf5")]
        stage: |log, request| super::hdf5::stage_hdf5(log, request.added, request.output, request.compensation),
        #[cfg(not(feature = "hdf5"))]
        stage: |_, request| {
            Err(super::unsupported(
                request.output,
                "hdf5 (this build has the 'hdf5' feature off)",
            ))
        },
        copy: None,
    },
];

impl Format {
    /// The format's row of [`FORMATS`].
    pub fn row(self) -> &'static FormatRow {
        // In the table's order (the test below checks each row's format).
        match self {
            Format::DelimitedText => &FORMATS[0],
            Format::Xyz => &FORMATS[1],
            Format::Mcap => &FORMATS[2],
            Format::Hdf5 => &FORMATS[3],
        }
    }

    /// The format an extension (lowercase, without the dot) names.
    pub fn of_extension(extension: &str) -> Option<Format> {
        (FORMATS.iter())
            .find(|row| row.extensions.contains(&extension))
            .map(|row| row.format)
    }

    /// The format whose signature `head` (a file's first bytes) begins with.
    pub fn of_magic(head: &[u8]) -> Option<Format> {
        (FORMATS.iter())
            .find(|row| row.magic.is_some_and(|magic| head.starts_with(magic)))
            .map(|row| row.format)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_format_has_one_row_and_no_extension_names_two() {
        for format in [Format::DelimitedText, Format::Xyz, Format::Mcap, Format::Hdf5] {
            assert_eq!(
                FORMATS.iter().filter(|row| row.format == format).count(),
                1,
                "{format:?}"
            );
            assert_eq!(format.row().format, format);
        }
        let mut extensions: Vec<&str> = FORMATS.iter().flat_map(|row| row.extensions.iter().copied()).collect();
        let all = extensions.len();
        extensions.sort();
        extensions.dedup();
        assert_eq!(extensions.len(), all, "an extension names two formats");
        assert_eq!(Format::of_extension("hdf5"), Some(Format::Hdf5));
        assert_eq!(Format::of_extension("las"), None);
        assert_eq!(Format::of_magic(b"\x89MCAP0\r\n"), Some(Format::Mcap));
        assert_eq!(Format::of_magic(b"time,mag_1_uc"), None);
    }
}
