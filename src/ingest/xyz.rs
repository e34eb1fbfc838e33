//! Geosoft XYZ flight logs.
//!
//! An XYZ file is whitespace-separated text. Lines starting with `/` are
//! comments; the last comment line before the first data row that has as
//! many names as the data rows have fields is the header (`/ TIME LINE
//! UNCOMPMAG1 …`). A `Line 1002.02` (or `Tie …`, `Trend …`) record starts a
//! survey line; when the file has no LINE column those numbers become the
//! `line` channel. `*` is a null. Both the line-record form and the flat form
//! with a LINE column (as in SGL's deliveries) are read.
//!
//! Uppercase SGL names map onto the CONTRACT names (`UNCOMPMAG1` →
//! `mag_1_uc`, see [`sgl_uppercase_alias`]), unless pipeline.toml's
//! `[columns]` names the column as it is.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::Path;

use super::columns::{sgl_uppercase_alias, ColumnNames};
use super::csv::ColumnBuilder;
use crate::error::{Error, Result};
use crate::flight_log::FlightLog;

/// The kind of a line of an XYZ file.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum XyzLine<'a> {
    Blank,
    Comment(&'a str),
    /// `Line`, `Tie` or `Trend` record with its number.
    LineRecord(f64),
    Data,
}

pub(crate) fn classify(line: &str) -> XyzLine<'_> {
    let trimmed = line.trim();
    if trimmed.is_empty() {
        return XyzLine::Blank;
    }
    if let Some(comment) = trimmed.strip_prefix('/') {
        return XyzLine::Comment(comment);
    }
    let mut tokens = trimmed.split_ascii_whitespace();
    let first = tokens.next().unwrap_or_default();
    let is_record = ["line", "tie", "trend"].iter().any(|k| first.eq_ignore_ascii_case(k));
    if is_record {
        let number = tokens.next().and_then(|t| t.parse::<f64>().ok()).unwrap_or(f64::NAN);
        return XyzLine::LineRecord(number);
    }
    XyzLine::Data
}

/// The header: the names the log will use for the columns.
pub(crate) struct Header {
    /// Column names, canonical, in file order (then `line` when it comes
    /// from line records).
    pub(crate) names: Vec<String>,
    /// Zero-based index of the header line in the file.
    pub(crate) line_index: usize,
    /// Whether the `line` column comes from line records (appended last).
    pub(crate) line_from_records: bool,
}

/// Finds the header among the comment lines before the first data row.
pub(crate) fn find_header(path: &Path, names: &ColumnNames) -> Result<Header> {
    let file = File::open(path).map_err(|e| Error::io(path, "opening", e))?;
    let mut comments: Vec<(usize, String)> = Vec::new();
    let mut saw_line_record = false;
    for (index, line) in BufReader::new(file).lines().enumerate() {
        let line = line.map_err(|e| Error::io(path, "reading", e))?;
        match classify(&line) {
            XyzLine::Blank => {}
            XyzLine::Comment(text) => comments.push((index, text.to_string())),
            XyzLine::LineRecord(_) => saw_line_record = true,
            XyzLine::Data => {
                let fields = line.split_ascii_whitespace().count();
                let (line_index, header) = comments
                    .iter()
                    .rev()
                    .find(|(_, c)| c.split_ascii_whitespace().count() == fields)
                    .ok_or_else(|| Error::UnsupportedFormat {
                        path: path.to_path_buf(),
                        message: format!(
                            "no '/' header line with {fields} column names (as many as the first data row has \
                             fields) precedes the data; a Geosoft XYZ file needs a line such as '/ TIME LINE UNCOMPMAG1 FLUXB_X ...'"
                        ),
                    })?;
                let mut column_names: Vec<String> = header
                    .split_ascii_whitespace()
                    .map(|name| canonical_name(name, names))
                    .collect();
                let line_from_records = saw_line_record && !column_names.contains(&names.line);
                if line_from_records {
                    column_names.push(names.line.clone());
                }
                return Ok(Header {
                    names: column_names,
                    line_index: *line_index,
                    line_from_records,
                });
            }
        }
    }
    Err(Error::MalformedRow {
        path: path.to_path_buf(),
        line: 1,
        message: "the XYZ file has no data rows".into(),
    })
}

/// The name a column gets in the flight log.
fn canonical_name(name: &str, names: &ColumnNames) -> String {
    if names.is_required_numeric(name) {
        return name.to_string();
    }
    sgl_uppercase_alias(name).unwrap_or_else(|| name.to_string())
}

/// Reads a Geosoft XYZ flight log.
pub fn read_xyz(path: &Path, names: &ColumnNames) -> Result<FlightLog> {
    let header = find_header(path, names)?;
    let mut builder = ColumnBuilder::new(path, header.names, names)?;
    let file = File::open(path).map_err(|e| Error::io(path, "opening", e))?;
    let mut reader = BufReader::with_capacity(1 << 20, file);
    let mut text = String::new();
    let mut line_number = 0u64;
    let mut offset = 0u64;
    let mut current_line = f64::NAN;
    let mut line_cell = String::new();
    loop {
        text.clear();
        let read = reader.read_line(&mut text).map_err(|e| Error::io(path, "reading", e))?;
        if read == 0 {
            break;
        }
        line_number += 1;
        let start = offset;
        offset += read as u64;
        match classify(&text) {
            XyzLine::Blank | XyzLine::Comment(_) => {}
            XyzLine::LineRecord(number) => current_line = number,
            XyzLine::Data => {
                let fields = text.split_ascii_whitespace().map(str::as_bytes);
                if header.line_from_records {
                    line_cell.clear();
                    if current_line.is_finite() {
                        line_cell.push_str(&current_line.to_string());
                    }
                    builder.push_row(fields.chain(std::iter::once(line_cell.as_bytes())), line_number)?;
                } else {
                    builder.push_row(fields, line_number)?;
                }
                builder.row_offsets.push(start);
            }
        }
    }
    let offsets = std::mem::take(&mut builder.row_offsets);
    Ok(builder.finish(names)?.with_source_row_offsets(offsets))
}

/// True when the start of a file looks like Geosoft XYZ: its first non-blank
/// line is a `/` comment or a `Line` record.
pub fn looks_like_xyz(head: &[u8]) -> bool {
    let text = String::from_utf8_lossy(head);
    text.lines()
        .map(classify)
        .find(|kind| *kind != XyzLine::Blank)
        .is_some_and(|kind| matches!(kind, XyzLine::Comment(_) | XyzLine::LineRecord(_)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flight_log::ChannelRole;
    use std::io::Write;

    fn write_temp(text: &str) -> tempfile::NamedTempFile {
        let mut file = tempfile::Builder::new().suffix(".xyz").tempfile().unwrap();
        file.write_all(text.as_bytes()).unwrap();
        file
    }

    #[test]
    fn line_records_become_the_line_channel() {
        let text = "/ XYZ export\n/ flight 1002\n/ TIME UNCOMPMAG1 FLUXB_X FLUXB_Y FLUXB_Z CUR_STRB\n\
                    Line 1002.02\n 10.0 52000.5 1.0 2.0 3.0 *\n 10.1 52000.6 1.1 2.1 3.1 0.5\n\
                    Line 1003.01\n 10.2 * 1.2 2.2 3.2 0.4\n";
        let file = write_temp(text);
        let log = read_xyz(file.path(), &ColumnNames::default()).unwrap();
        assert_eq!(log.time_s(), &[10.0, 10.1, 10.2]);
        assert_eq!(log.channel("line").unwrap().values, vec![1002.02, 1002.02, 1003.01]);
        let mag = &log.channel("mag_1_uc").unwrap();
        assert_eq!(mag.role, ChannelRole::ScalarMagnetometer);
        assert_eq!(mag.values[..2], [52000.5, 52000.6]);
        assert!(mag.values[2].is_nan());
        assert_eq!(log.vector_sensors()[0].prefix, "flux_b");
        assert!(log.channel("cur_strb").unwrap().values[0].is_nan());
    }

    #[test]
    fn flat_form_with_a_line_column() {
        let text = "/ LINE TIME UNCOMPMAG2\n1002.02 5.0 100.0\n1002.02 5.1 101.0\n";
        let file = write_temp(text);
        let log = read_xyz(file.path(), &ColumnNames::default()).unwrap();
        assert_eq!(log.channel("line").unwrap().values, vec![1002.02, 1002.02]);
        assert_eq!(log.channel("mag_2_uc").unwrap().values, vec![100.0, 101.0]);
    }

    #[test]
    fn configured_names_are_kept_as_written() {
        let names = ColumnNames {
            time: "TIME".into(),
            ..ColumnNames::default()
        };
        let file = write_temp("/ TIME UNCOMPMAG1\n1 2\n2 3\n");
        let log = read_xyz(file.path(), &names).unwrap();
        assert_eq!(log.time_column(), "TIME");
        assert_eq!(log.channel("mag_1_uc").unwrap().values, vec![2.0, 3.0]);
    }

    #[test]
    fn a_header_that_does_not_fit_the_data_is_an_error() {
        let file = write_temp("/ TIME UNCOMPMAG1\n1 2 3\n");
        let text = read_xyz(file.path(), &ColumnNames::default()).unwrap_err().to_string();
        assert!(text.contains("3 column names"), "{text}");
    }

    #[test]
    fn sniffing_recognises_comments_and_line_records() {
        assert!(looks_like_xyz(b"\n/ TIME MAG\n1 2\n"));
        assert!(looks_like_xyz(b"Line 10\n1 2\n"));
        assert!(!looks_like_xyz(b"tt,mag_1_uc\n1,2\n"));
    }
}
