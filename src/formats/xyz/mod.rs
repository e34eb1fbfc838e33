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

mod write;

pub use write::{stage_log_xyz, stage_xyz_copy};

use super::columns::{sgl_uppercase_alias, ColumnNames};
use super::csv::{part_starts, ColumnBuilder, PARALLEL_MIN_BYTES};
use crate::error::{Error, Result};
use crate::ingest::flight_log::FlightLog;

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
    // A byte-order mark may open the file (editors on Windows write one).
    let trimmed = line.trim_start_matches('\u{feff}').trim();
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
    /// Byte offset just after the header line.
    pub(crate) body_start: u64,
    /// Whether the `line` column comes from line records (appended last).
    pub(crate) line_from_records: bool,
}

/// Finds the header among the comment lines before the first data row.
pub(crate) fn find_header(path: &Path, names: &ColumnNames) -> Result<Header> {
    let file = File::open(path).map_err(|e| Error::io(path, "opening", e))?;
    let mut comments: Vec<(usize, String, u64)> = Vec::new();
    let mut saw_line_record = false;
    let mut reader = BufReader::new(file);
    let mut line = String::new();
    let mut offset = 0u64;
    for index in 0.. {
        line.clear();
        let read = reader.read_line(&mut line).map_err(|e| Error::io(path, "reading", e))?;
        if read == 0 {
            break;
        }
        offset += read as u64;
        match classify(&line) {
            XyzLine::Blank => {}
            XyzLine::Comment(text) => comments.push((index, text.to_string(), offset)),
            XyzLine::LineRecord(_) => saw_line_record = true,
            XyzLine::Data => {
                let fields = line.split_ascii_whitespace().count();
                return header_of(path, &comments, fields, (names, saw_line_record));
            }
        }
    }
    Err(Error::NoData {
        path: path.to_path_buf(),
        problem: "the XYZ file has no data rows".into(),
    })
}

/// The header: the last of the `comments` (line index, text, offset after
/// it) with as many names as the first data row has `fields`, the names
/// made canonical, and `line` appended when the line number comes only
/// from line records.
fn header_of(
    path: &Path,
    comments: &[(usize, String, u64)],
    fields: usize,
    (names, saw_line_record): (&ColumnNames, bool),
) -> Result<Header> {
    let (line_index, header, body_start) = comments
        .iter()
        .rev()
        .find(|(_, c, _)| c.split_ascii_whitespace().count() == fields)
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
    Ok(Header {
        names: column_names,
        line_index: *line_index,
        body_start: *body_start,
        line_from_records,
    })
}

/// The name a column gets in the flight log.
fn canonical_name(name: &str, names: &ColumnNames) -> String {
    if names.is_required_numeric(name) {
        return name.to_string();
    }
    sgl_uppercase_alias(name).unwrap_or_else(|| name.to_string())
}

/// Reads a Geosoft XYZ flight log. Large files are read in parts in
/// parallel, split at line ends; a part's rows before its first line record
/// take the line number the previous part ended on.
pub fn read_xyz(path: &Path, names: &ColumnNames) -> Result<FlightLog> {
    let header = find_header(path, names)?;
    let template = ColumnBuilder::new(path, header.names.clone(), names)?;
    let size = std::fs::metadata(path)
        .map_err(|e| Error::io(path, "reading", e))?
        .len();
    let mut builder = match read_parallel(path, &header, &template, size)? {
        Some(builder) => builder,
        None => {
            let mut builder = template;
            read_range(
                path,
                &header,
                &mut builder,
                header.body_start,
                size,
                header.line_index as u64 + 2,
            )?;
            builder
        }
    };
    let offsets = std::mem::take(&mut builder.row_offsets);
    Ok(builder.finish(names)?.with_source_row_offsets(offsets))
}

/// Where a part of the file left the line number.
struct PartEnd {
    /// Rows read before the part's first line record.
    unresolved: usize,
    /// The last line record's number, if the part had one.
    last_line: Option<f64>,
}

/// Reads bytes `start..end` (whole lines) into `builder`; `first_line` is
/// the line number of `start`, for errors.
fn read_range(
    path: &Path,
    header: &Header,
    builder: &mut ColumnBuilder,
    start: u64,
    end: u64,
    first_line: u64,
) -> Result<PartEnd> {
    use std::io::{Read, Seek, SeekFrom};
    let io = |e| Error::io(path, "reading", e);
    let mut file = File::open(path).map_err(io)?;
    file.seek(SeekFrom::Start(start)).map_err(io)?;
    let mut reader = BufReader::with_capacity(1 << 18, file.take(end - start));
    let mut text = Vec::new();
    let (mut line_number, mut offset) = (first_line, start);
    let mut lines = LineRecords::default();
    loop {
        text.clear();
        let read = reader.read_until(b'\n', &mut text).map_err(io)?;
        if read == 0 {
            break;
        }
        let row_start = offset;
        offset += read as u64;
        let this_line = line_number;
        line_number += 1;
        let Ok(line) = std::str::from_utf8(&text) else {
            return Err(Error::NotText {
                path: path.to_path_buf(),
                line: this_line,
                byte: Some(row_start),
            });
        };
        match classify(line) {
            XyzLine::Blank | XyzLine::Comment(_) => {}
            XyzLine::LineRecord(number) => lines.enter(number),
            XyzLine::Data => {
                lines.push_row(builder, header, line, this_line)?;
                builder.row_offsets.push(row_start);
            }
        }
    }
    Ok(PartEnd {
        unresolved: lines.unresolved,
        last_line: lines.current,
    })
}

/// The line number a part of the file is on, from its line records.
#[derive(Default)]
struct LineRecords {
    /// The last line record's number, if the part has had one.
    current: Option<f64>,
    /// That number as the `line` cell of the rows under it.
    cell: Vec<u8>,
    /// Rows read before the part's first line record.
    unresolved: usize,
}

impl LineRecords {
    /// A line record: the rows after it are on line `number`.
    fn enter(&mut self, number: f64) {
        self.current = Some(number);
        self.cell.clear();
        if number.is_finite() {
            self.cell
                .extend_from_slice(ryu::Buffer::new().format(number).as_bytes());
        }
    }

    /// Pushes the data row `line` (file line `this_line`) into `builder`,
    /// with the line number's cell when the header takes it from records.
    fn push_row(&mut self, builder: &mut ColumnBuilder, header: &Header, line: &str, this_line: u64) -> Result<()> {
        let fields = line.split_ascii_whitespace().map(str::as_bytes);
        if header.line_from_records {
            self.unresolved += usize::from(self.current.is_none());
            builder.push_row(fields.chain(std::iter::once(self.cell.as_slice())), this_line)
        } else {
            builder.push_row(fields, this_line)
        }
    }
}

fn read_parallel<'a>(
    path: &'a Path,
    header: &Header,
    template: &ColumnBuilder<'a>,
    size: u64,
) -> Result<Option<ColumnBuilder<'a>>> {
    use rayon::prelude::*;
    let parts_wanted = rayon::current_num_threads().max(1) as u64 * 4;
    if size < PARALLEL_MIN_BYTES as u64 || parts_wanted < 2 {
        return Ok(None);
    }
    let io = |e| Error::io(path, "reading", e);
    let mut file = File::open(path).map_err(io)?;
    let starts = part_starts(&mut file, (header.body_start, size), parts_wanted as usize).map_err(io)?;
    let ends: Vec<u64> = starts.iter().skip(1).copied().chain(std::iter::once(size)).collect();
    let parts: Vec<Option<(ColumnBuilder, PartEnd)>> = starts
        .par_iter()
        .zip(&ends)
        .map(|(&start, &end)| {
            let mut part = template.empty_copy_with_capacity(((end - start) / 64) as usize);
            // Errors are reported by the sequential reader, with exact lines.
            let state = read_range(path, header, &mut part, start, end, 0).ok()?;
            Some((part, state))
        })
        .collect();
    let Some(parts) = parts.into_iter().collect::<Option<Vec<_>>>() else {
        return Ok(None);
    };
    Ok(merged_parts(parts, header))
}

/// The parts read in parallel joined in order into one, each part's rows
/// before its first line record given the line the part before ended on;
/// `None` when they disagree (a column's kind, time not increasing).
fn merged_parts<'a>(parts: Vec<(ColumnBuilder<'a>, PartEnd)>, header: &Header) -> Option<ColumnBuilder<'a>> {
    let total: usize = parts.iter().map(|(p, _)| p.row_offsets.len()).sum();
    let line_column = header.line_from_records.then(|| header.names.len() - 1);
    let mut carried: Option<f64> = None;
    let mut merged: Option<ColumnBuilder> = None;
    for (mut part, state) in parts {
        if let (Some(column), Some(line)) = (line_column, carried) {
            part.set_leading(column, state.unresolved, line);
        }
        carried = state.last_line.or(carried);
        match &mut merged {
            None => {
                part.reserve(total);
                merged = Some(part);
            }
            Some(merged) => {
                if !merged.absorb(part) {
                    return None;
                }
            }
        }
    }
    merged
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
    use crate::ingest::flight_log::ChannelRole;
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
    fn parallel_parts_inherit_the_line_number() {
        let mut text = String::from("/ big export\n/ TIME UNCOMPMAG1 FLUXB_X FLUXB_Y FLUXB_Z CUR_STRB\n");
        for k in 0..150_000 {
            if k % 7_000 == 0 {
                text += &format!("Line {}.01\n", 1000 + k / 7_000);
            }
            text += &format!(
                "{:.1} {:.3} {}.125 {}.5 4{}000.25 {}\n",
                100.0 + k as f64 * 0.1,
                50_000.0 + (k % 997) as f64 * 0.01,
                k % 11,
                k % 13,
                k % 17,
                if k % 5 == 0 {
                    "*".to_string()
                } else {
                    format!("{}", k % 3)
                }
            );
        }
        let file = write_temp(&text);
        assert!(text.len() > PARALLEL_MIN_BYTES);
        let names = ColumnNames::default();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
        let header = find_header(file.path(), &names).unwrap();
        let template = ColumnBuilder::new(file.path(), header.names.clone(), &names).unwrap();
        let size = text.len() as u64;
        let parallel = pool
            .install(|| read_parallel(file.path(), &header, &template, size))
            .unwrap();
        assert!(parallel.is_some(), "this file takes the parallel path");
        let log = pool.install(|| read_xyz(file.path(), &names)).unwrap();
        assert_eq!(log.len(), 150_000);
        let line = &log.channel("line").unwrap().values;
        for (k, value) in line.iter().enumerate() {
            assert_eq!(*value, 1000.01 + (k / 7_000) as f64, "row {k}");
        }
        let mut sequential = ColumnBuilder::new(file.path(), header.names.clone(), &names).unwrap();
        read_range(file.path(), &header, &mut sequential, header.body_start, size, 3).unwrap();
        assert_eq!(sequential.row_offsets, log.source_row_offsets().unwrap());
        let current = &log.channel("cur_strb").unwrap().values;
        assert!(current[0].is_nan() && current[1] == 1.0);
    }

    #[test]
    fn sniffing_recognises_comments_and_line_records() {
        assert!(looks_like_xyz(b"\n/ TIME MAG\n1 2\n"));
        assert!(looks_like_xyz(b"Line 10\n1 2\n"));
        assert!(!looks_like_xyz(b"tt,mag_1_uc\n1,2\n"));
    }
}
