//! Delimited-text flight logs: `,`, `;`, tab or whitespace-aligned columns.
//!
//! The separator is chosen from the header line. Cells are parsed straight
//! into per-column vectors through one reused record, so reading allocates
//! per column, not per row. An empty cell, `*`, `NaN` or `nan` is a missing
//! sample. A column whose name gives it a role must be numeric; any other
//! column whose first non-missing cell is not a number is kept as text: it is
//! not a channel, but it still reaches the compensated output unchanged
//! because outputs copy the input rows.

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;

mod write;

pub use write::{stage_compensated_csv, stage_log_csv};

use super::columns::ColumnNames;
use crate::error::{Error, Result};
use crate::ingest::flight_log::{Channel, FlightLog};

/// How the fields of a row are separated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Separator {
    /// One delimiter byte: `,`, `;` or tab.
    Byte(u8),
    /// Runs of spaces or tabs (whitespace-aligned columns).
    Whitespace,
}

/// Picks the separator from the header line: `,` then `;` then tab, else
/// whitespace.
pub fn sniff_separator(header_line: &str) -> Separator {
    [b',', b';', b'\t']
        .into_iter()
        .find(|&d| header_line.as_bytes().contains(&d))
        .map_or(Separator::Whitespace, Separator::Byte)
}

/// Reads the header line of a delimited file: its separator and column names.
pub fn read_header(path: &Path) -> Result<(Separator, Vec<String>)> {
    let file = File::open(path).map_err(|e| Error::io(path, "opening", e))?;
    let mut line = String::new();
    BufReader::new(file).read_line(&mut line).map_err(|e| match e.kind() {
        std::io::ErrorKind::InvalidData => Error::NotText {
            path: path.to_path_buf(),
            line: 1,
            byte: Some(0),
        },
        _ => Error::io(path, "reading the header", e),
    })?;
    let line = line.trim_start_matches('\u{feff}').trim_end_matches(['\r', '\n']);
    let separator = sniff_separator(line);
    // Split as the rows are, so a quoted name ("tt") is read without its
    // quotes and a quoted separator stays in its name.
    let names = line_cells(line.as_bytes(), separator).unwrap_or_default();
    Ok((separator, names))
}

/// Reads a delimited-text flight log, assigning roles from `names`.
pub fn read_csv(path: &Path, names: &ColumnNames) -> Result<FlightLog> {
    read_csv_with(path, names, true)
}

/// [`read_csv`], with the parallel path allowed or not.
fn read_csv_with(path: &Path, names: &ColumnNames, allow_parallel: bool) -> Result<FlightLog> {
    let (separator, header) = read_header(path)?;
    let units = read_units_row(path, separator, &header, names)?;
    let declared: Vec<(String, String)> = match &units {
        Some(cells) => header.iter().cloned().zip(cells.iter().cloned()).collect(),
        None => Vec::new(),
    };
    let lines_before_data = 1 + usize::from(units.is_some());
    let mut builder = ColumnBuilder::new(path, header, names)?;
    let read = |builder: ColumnBuilder| -> Result<FlightLog> {
        let mut builder = builder;
        let offsets = std::mem::take(&mut builder.row_offsets);
        Ok(builder
            .finish(names)?
            .with_source_row_offsets(offsets)
            .with_declared_units(declared.clone()))
    };
    if let (Separator::Byte(delimiter), true) = (separator, allow_parallel) {
        if let Some(parallel) = read_delimited_parallel(path, delimiter, &builder, lines_before_data)? {
            return read(parallel);
        }
    }
    let file = File::open(path).map_err(|e| Error::io(path, "opening", e))?;
    match separator {
        Separator::Byte(delimiter) => read_delimited(path, file, delimiter, &mut builder, lines_before_data)?,
        Separator::Whitespace => read_whitespace(path, file, &mut builder, lines_before_data)?,
    }
    read(builder)
}

/// The cells of one `line`, trimmed, split as the file is; `None` where
/// the CSV reader reads no record from it.
fn line_cells(line: &[u8], separator: Separator) -> Option<Vec<String>> {
    Some(match separator {
        Separator::Byte(delimiter) => {
            let mut reader = csv::ReaderBuilder::new()
                .delimiter(delimiter)
                .has_headers(false)
                .from_reader(line);
            let mut record = csv::ByteRecord::new();
            match reader.read_byte_record(&mut record) {
                Ok(true) => record
                    .iter()
                    .map(|c| String::from_utf8_lossy(c).trim().to_string())
                    .collect(),
                _ => return None,
            }
        }
        Separator::Whitespace => (line.split(u8::is_ascii_whitespace))
            .filter(|f| !f.is_empty())
            .map(|c| String::from_utf8_lossy(c).into_owned())
            .collect(),
    })
}

/// The cells of the line under the header when that line is a row of
/// units (`s,nT,nT,deg`), one per header column; `None` when it is not.
///
/// It is one when its time cell reads as a unit (or is empty beside a unit
/// elsewhere) and no cell is a number, with one cell per column. A line
/// whose time cell reads as a unit but that holds a number, or another
/// count of cells, is [`Error::UnitsRow`], naming the cell; any other line
/// is the reader's (a data row).
pub fn read_units_row(
    path: &Path,
    separator: Separator,
    header: &[String],
    roles: &ColumnNames,
) -> Result<Option<Vec<String>>> {
    let Some(time_index) = header.iter().position(|n| *n == roles.time) else {
        return Ok(None);
    };
    let Some(cells) = second_line_cells(path, separator)? else {
        return Ok(None);
    };
    // The time cell a unit; or empty, with no number on the line and a
    // unit elsewhere (a data row missing its time is the reader's to name).
    let time_cell = cells.get(time_index).map_or("", |c| c.trim());
    let numeric = cells
        .iter()
        .position(|c| parse_cell(c.as_bytes()).is_some_and(|v| !v.is_nan()));
    let unit_like = match time_cell.is_empty() {
        false => looks_like_a_unit(time_cell),
        true => numeric.is_none() && cells.iter().any(|c| looks_like_a_unit(c)),
    };
    if !unit_like {
        return Ok(None);
    }
    let units_row_error = |column: usize, value: &str, problem: String| Error::UnitsRow {
        path: path.to_path_buf(),
        line: 2,
        column: header.get(column).cloned().unwrap_or_default(),
        value: value.to_string(),
        problem,
    };
    if let Some(k) = numeric {
        return Err(units_row_error(k, &cells[k], "is a number".into()));
    }
    if cells.len() != header.len() {
        return Err(units_row_error(
            time_index,
            time_cell,
            format!(
                "reads as a unit, but the line has {} cells and the header {} columns",
                cells.len(),
                header.len()
            ),
        ));
    }
    Ok(Some(cells))
}

/// The cells of the file's second line (the one after the header), or
/// `None` when it has none or they cannot be split.
fn second_line_cells(path: &Path, separator: Separator) -> Result<Option<Vec<String>>> {
    let file = File::open(path).map_err(|e| Error::io(path, "opening", e))?;
    let mut lines = BufReader::new(file).split(b'\n');
    let line = match (lines.next(), lines.next()) {
        (Some(_), Some(Ok(line))) => line,
        _ => return Ok(None),
    };
    Ok(line_cells(&line, separator))
}

/// Opens a `csv` reader over a delimited file with magcomp's settings.
/// Cells are not trimmed here; [`parse_cell`] ignores surrounding spaces.
pub fn delimited_reader<R: Read>(reader: R, delimiter: u8) -> csv::Reader<R> {
    csv::ReaderBuilder::new()
        .delimiter(delimiter)
        .has_headers(true)
        .from_reader(reader)
}

fn read_delimited(
    path: &Path,
    file: File,
    delimiter: u8,
    builder: &mut ColumnBuilder,
    lines_before_data: usize,
) -> Result<()> {
    let mut reader = delimited_reader(BufReader::with_capacity(1 << 20, file), delimiter);
    let mut record = csv::ByteRecord::new();
    // The units row, when there is one, is not data.
    for _ in 1..lines_before_data {
        reader.read_byte_record(&mut record).map_err(|e| csv_error(path, e))?;
    }
    loop {
        match reader.read_byte_record(&mut record) {
            Ok(false) => return Ok(()),
            Ok(true) => {
                let position = record.position();
                let line = position.map_or(0, |p| p.line());
                builder.push_row(record.iter(), line)?;
                builder.row_offsets.push(position.map_or(0, |p| p.byte()));
            }
            Err(error) => return Err(csv_error(path, error)),
        }
    }
}

/// Smallest file worth splitting across threads, bytes.
pub(crate) const PARALLEL_MIN_BYTES: usize = 4 << 20;

/// Reads a large delimited file in parts, one per thread, split at line
/// ends. Only for files without quotes (so a line end always ends a record).
/// Returns `None` whenever the parts might disagree with a sequential read
/// (a quote anywhere, any error, a column whose kind the parts decide
/// differently, time not increasing across a part boundary); the caller
/// then reads sequentially, which also gives the exact error.
fn read_delimited_parallel<'a>(
    path: &'a Path,
    delimiter: u8,
    template: &ColumnBuilder<'a>,
    lines_before_data: usize,
) -> Result<Option<ColumnBuilder<'a>>> {
    let io = |e| Error::io(path, "reading", e);
    let parts_wanted = rayon::current_num_threads().max(1) * 4;
    let size = std::fs::metadata(path).map_err(io)?.len();
    if size < PARALLEL_MIN_BYTES as u64 || parts_wanted < 2 {
        return Ok(None);
    }
    let mut file = File::open(path).map_err(io)?;
    let mut head = vec![0u8; 1 << 16];
    let read = read_up_to(&mut file, &mut head).map_err(io)?;
    head.truncate(read);
    // The header (and the units row, when there is one) ends here.
    let line_ends = head.iter().enumerate().filter(|(_, &b)| b == b'\n');
    let Some(header_end) = line_ends.map(|(p, _)| p as u64 + 1).nth(lines_before_data - 1) else {
        return Ok(None);
    };
    if head.contains(&b'"') {
        return Ok(None);
    }
    let sample_rows = head[header_end as usize..]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        .max(1);
    let bytes_per_row = (head.len() as u64 - header_end) as f64 / sample_rows as f64;
    let starts = part_starts(&mut file, (header_end, size), parts_wanted).map_err(io)?;
    let ends: Vec<u64> = starts.iter().skip(1).copied().chain(std::iter::once(size)).collect();
    use rayon::prelude::*;
    let parts: Vec<Option<ColumnBuilder>> = starts
        .par_iter()
        .zip(&ends)
        .map(|(&start, &end)| {
            let rows = ((end - start) as f64 / bytes_per_row * 1.05) as usize + 16;
            read_part(path, delimiter, template.empty_copy_with_capacity(rows), start, end).ok()?
        })
        .collect();
    let Some(parts) = parts.into_iter().collect::<Option<Vec<ColumnBuilder>>>() else {
        return Ok(None);
    };
    Ok(merged_parts(parts))
}

/// Where each of up to `parts_wanted` parts of the data (from `header_end`
/// to `size`, bytes) starts: at the first line start after an even split.
pub(crate) fn part_starts(
    file: &mut File,
    (header_end, size): (u64, u64),
    parts_wanted: usize,
) -> std::io::Result<Vec<u64>> {
    let mut starts = vec![header_end];
    for k in 1..parts_wanted as u64 {
        let guess = header_end + (size - header_end) * k / parts_wanted as u64;
        let Some(start) = next_line_start(file, guess)? else {
            break;
        };
        if start > *starts.last().unwrap_or(&0) && start < size {
            starts.push(start);
        }
    }
    Ok(starts)
}

/// The parts read in parallel joined in order into one, or `None` when
/// they disagree (a column's kind, time not increasing across a boundary).
fn merged_parts(parts: Vec<ColumnBuilder>) -> Option<ColumnBuilder> {
    let total: usize = parts.iter().map(|p| p.row_offsets.len()).sum();
    let mut parts = parts.into_iter();
    let mut merged = parts.next()?;
    merged.reserve(total);
    for part in parts {
        if !merged.absorb(part) {
            return None;
        }
    }
    Some(merged)
}

/// Reads as much of `buffer` as the file holds.
pub(crate) fn read_up_to(file: &mut File, buffer: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < buffer.len() {
        match file.read(&mut buffer[filled..])? {
            0 => break,
            n => filled += n,
        }
    }
    Ok(filled)
}

/// The offset just after the first line end at or after `from`.
pub(crate) fn next_line_start(file: &mut File, from: u64) -> std::io::Result<Option<u64>> {
    use std::io::{Seek, SeekFrom};
    file.seek(SeekFrom::Start(from))?;
    let mut block = vec![0u8; 1 << 16];
    let mut at = from;
    loop {
        let read = read_up_to(file, &mut block)?;
        if read == 0 {
            return Ok(None);
        }
        if let Some(p) = block[..read].iter().position(|&b| b == b'\n') {
            return Ok(Some(at + p as u64 + 1));
        }
        at += read as u64;
    }
}

/// A reader that notes whether a quote character passed through it.
struct QuoteGuard<R> {
    inner: R,
    quoted: bool,
}

impl<R: Read> Read for QuoteGuard<R> {
    fn read(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
        let read = self.inner.read(buffer)?;
        self.quoted |= buffer[..read].contains(&b'"');
        Ok(read)
    }
}

/// Parses bytes `start..end` (whole lines) into `part`. `Ok(None)` when the
/// part cannot be read on its own: it holds a quote, or a row fails (the
/// sequential reader then reports the exact error). Line numbers inside a
/// part are relative; they only matter for errors, which are re-read.
fn read_part<'a>(
    path: &'a Path,
    delimiter: u8,
    mut part: ColumnBuilder<'a>,
    start: u64,
    end: u64,
) -> std::io::Result<Option<ColumnBuilder<'a>>> {
    use std::io::{Seek, SeekFrom};
    let mut file = File::open(path)?;
    file.seek(SeekFrom::Start(start))?;
    let guard = QuoteGuard {
        inner: file.take(end - start),
        quoted: false,
    };
    let mut reader = csv::ReaderBuilder::new()
        .delimiter(delimiter)
        .has_headers(false)
        .buffer_capacity(1 << 17)
        .from_reader(guard);
    let mut record = csv::ByteRecord::new();
    loop {
        match reader.read_byte_record(&mut record) {
            Ok(false) => break,
            Ok(true) => {
                let Some(position) = record.position() else {
                    return Ok(None);
                };
                if part.push_row(record.iter(), position.line() + 1).is_err() {
                    return Ok(None);
                }
                part.row_offsets.push(start + position.byte());
            }
            Err(_) => return Ok(None),
        }
    }
    Ok((!reader.into_inner().quoted).then_some(part))
}

fn read_whitespace(path: &Path, file: File, builder: &mut ColumnBuilder, lines_before_data: usize) -> Result<()> {
    let mut reader = BufReader::with_capacity(1 << 20, file);
    let mut line = Vec::new();
    let mut line_number = 0u64;
    let mut offset = 0u64;
    loop {
        line.clear();
        let read = reader
            .read_until(b'\n', &mut line)
            .map_err(|e| Error::io(path, "reading", e))?;
        if read == 0 {
            return Ok(());
        }
        line_number += 1;
        let start = offset;
        offset += read as u64;
        if line_number <= lines_before_data as u64 || line.iter().all(u8::is_ascii_whitespace) {
            continue;
        }
        let fields = line.split(u8::is_ascii_whitespace).filter(|f| !f.is_empty());
        builder.push_row(fields, line_number)?;
        builder.row_offsets.push(start);
    }
}

fn csv_error(path: &Path, error: csv::Error) -> Error {
    let line = error.position().map_or(0, |p| p.line());
    match error.into_kind() {
        csv::ErrorKind::Io(e) => Error::io(path, "reading", e),
        csv::ErrorKind::UnequalLengths { expected_len, len, .. } => Error::MalformedRow {
            path: path.to_path_buf(),
            line,
            message: format!("the row has {len} fields but the header has {expected_len}"),
        },
        csv::ErrorKind::Utf8 { pos, .. } => Error::NotText {
            path: path.to_path_buf(),
            line: pos.as_ref().map_or(line, |p| p.line()),
            byte: pos.as_ref().map(|p| p.byte()),
        },
        other => Error::MalformedRow {
            path: path.to_path_buf(),
            line,
            message: format!("{other:?}"),
        },
    }
}

/// Whether a column holds numbers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ColumnKind {
    /// Must be numeric (time or a named role).
    Numeric,
    /// Auxiliary column whose first non-missing cell has not been seen yet.
    Undecided,
    /// Auxiliary column of text; not a channel.
    Text,
}

/// Accumulates parsed cells column by column.
pub(crate) struct ColumnBuilder<'a> {
    path: &'a Path,
    names: Vec<String>,
    kinds: Vec<ColumnKind>,
    values: Vec<Vec<f64>>,
    time_index: usize,
    previous_time: f64,
    /// The line and row where time first goes back.
    backward: Option<(u64, usize)>,
    /// Byte offset of each data row's record.
    pub(crate) row_offsets: Vec<u64>,
}

impl<'a> ColumnBuilder<'a> {
    pub(crate) fn new(path: &'a Path, names: Vec<String>, roles: &ColumnNames) -> Result<Self> {
        let time_index = names
            .iter()
            .position(|n| *n == roles.time)
            .ok_or_else(|| Error::MissingColumn {
                path: path.to_path_buf(),
                role: "time",
                looked_for: format!("'{}'", roles.time),
                hint: "Name the time column in [columns] time = \"...\" in pipeline.toml.".into(),
            })?;
        let mut seen = std::collections::HashMap::with_capacity(names.len());
        for (index, name) in names.iter().enumerate() {
            if let Some(first) = seen.insert(name.as_str(), index) {
                return Err(Error::DuplicateColumn {
                    path: path.to_path_buf(),
                    line: 1,
                    column: name.clone(),
                    first: first + 1,
                    second: index + 1,
                });
            }
        }
        let kinds = names
            .iter()
            .map(|n| match roles.is_required_numeric(n) {
                true => ColumnKind::Numeric,
                false => ColumnKind::Undecided,
            })
            .collect();
        let values = vec![Vec::new(); names.len()];
        Ok(ColumnBuilder {
            path,
            names,
            kinds,
            values,
            time_index,
            previous_time: f64::NEG_INFINITY,
            backward: None,
            row_offsets: Vec::new(),
        })
    }

    pub(crate) fn push_row<'f>(&mut self, fields: impl Iterator<Item = &'f [u8]>, line: u64) -> Result<()> {
        let mut count = 0;
        for cell in fields {
            if count < self.names.len() {
                self.push_cell(count, cell, line)?;
            }
            count += 1;
        }
        if count != self.names.len() {
            return Err(self.ragged(line, count));
        }
        self.check_row_time(line)
    }

    fn push_cell(&mut self, column: usize, cell: &[u8], line: u64) -> Result<()> {
        if self.kinds[column] == ColumnKind::Text {
            return Ok(());
        }
        match parse_cell(cell) {
            Some(value) => {
                if self.kinds[column] == ColumnKind::Undecided && !value.is_nan() {
                    self.kinds[column] = ColumnKind::Numeric;
                }
                self.values[column].push(value);
            }
            None if self.kinds[column] == ColumnKind::Undecided => {
                self.kinds[column] = ColumnKind::Text;
                self.values[column] = Vec::new();
            }
            None => return Err(self.malformed(column, cell, line)),
        }
        Ok(())
    }

    /// The same columns and kinds, with no rows and room for `rows`.
    pub(crate) fn empty_copy_with_capacity(&self, rows: usize) -> Self {
        ColumnBuilder {
            path: self.path,
            names: self.names.clone(),
            kinds: self.kinds.clone(),
            values: (0..self.names.len()).map(|_| Vec::with_capacity(rows)).collect(),
            time_index: self.time_index,
            previous_time: f64::NEG_INFINITY,
            backward: None,
            row_offsets: Vec::with_capacity(rows),
        }
    }

    /// Sets the first `rows` values of `column` to `value` (a line number
    /// a part inherits from the part before it).
    pub(crate) fn set_leading(&mut self, column: usize, rows: usize, value: f64) {
        if let Some(values) = self.values.get_mut(column) {
            values.iter_mut().take(rows).for_each(|v| *v = value);
        }
    }

    /// Makes room for `rows` rows in total.
    pub(crate) fn reserve(&mut self, rows: usize) {
        let more = rows.saturating_sub(self.row_offsets.len());
        self.values.iter_mut().for_each(|v| v.reserve(more));
        self.row_offsets.reserve(more);
    }

    /// Appends the rows of `later`, read from the next part of the file.
    /// False when the result could differ from reading both parts in one
    /// go: a column numeric in one part and text in a later one, or time
    /// not increasing across the boundary.
    pub(crate) fn absorb(&mut self, later: ColumnBuilder) -> bool {
        let first_time = later.values[self.time_index].first().copied();
        if self.backward.is_some() || later.backward.is_some() || first_time.is_some_and(|t| t <= self.previous_time) {
            return false;
        }
        let rows = self.row_offsets.len();
        for (column, (kind, values)) in later.kinds.into_iter().zip(later.values).enumerate() {
            match (self.kinds[column], kind) {
                (ColumnKind::Text, _) => {}
                (ColumnKind::Numeric, ColumnKind::Text) => return false,
                (ColumnKind::Undecided, ColumnKind::Text) => {
                    self.kinds[column] = ColumnKind::Text;
                    self.values[column] = Vec::new();
                }
                (ColumnKind::Undecided, ColumnKind::Numeric) => {
                    self.kinds[column] = ColumnKind::Numeric;
                    self.values[column].extend(values);
                }
                _ => self.values[column].extend(values),
            }
        }
        self.previous_time = later.previous_time.max(self.previous_time);
        self.row_offsets.extend(later.row_offsets);
        debug_assert!(self.row_offsets.len() >= rows);
        true
    }

    /// Checks the time of the row just pushed (on `line`). A time that is
    /// not finite is an error at once; the first time that goes back is
    /// kept and the reading goes on, so that [`Self::finish`] can tell its
    /// cause from the whole column (one damaged stamp, a data column
    /// named as time, an unsorted file).
    fn check_row_time(&mut self, line: u64) -> Result<()> {
        let times = &self.values[self.time_index];
        let time = *times.last().unwrap_or(&f64::NAN);
        if !time.is_finite() {
            return Err(Error::BadTime {
                path: self.path.to_path_buf(),
                location: format!("line {line}"),
                column: self.names[self.time_index].clone(),
                problem: "is missing or not finite".to_string(),
                fix: "repair that row's time, or drop the row".into(),
            });
        }
        if time <= self.previous_time && self.backward.is_none() {
            self.backward = Some((line, times.len() - 1));
        }
        self.previous_time = time;
        Ok(())
    }

    /// The error for the first time that goes back, when one does, with
    /// the fix its cause calls for.
    fn backward_error(&self) -> Option<Error> {
        let (line, row) = self.backward?;
        let times = &self.values[self.time_index];
        // Rows are lines from the first that went back (a quoted cell
        // holding a line end would shift the count before it).
        let locate = |k: usize| format!("line {}", (line + k as u64).saturating_sub(row as u64));
        let (problem, fix) = crate::ingest::flight_log::backward_time(&self.names[self.time_index], times, row, locate);
        Some(Error::BadTime {
            path: self.path.to_path_buf(),
            location: format!("line {line}"),
            column: self.names[self.time_index].clone(),
            problem,
            fix,
        })
    }

    fn ragged(&self, line: u64, found: usize) -> Error {
        Error::MalformedRow {
            path: self.path.to_path_buf(),
            line,
            message: format!("the row has {found} fields but the header has {}", self.names.len()),
        }
    }

    fn malformed(&self, index: usize, cell: &[u8], line: u64) -> Error {
        let (path, column, value) = (
            self.path.to_path_buf(),
            self.names[index].clone(),
            String::from_utf8_lossy(cell).into_owned(),
        );
        // The time cell of the line under the header reads as a unit: the
        // line holds the columns' units.
        match line == 2 && index == self.time_index && looks_like_a_unit(&value) {
            true => Error::UnitsRow {
                path,
                line,
                column,
                value,
                problem: "is not a number".into(),
            },
            false => Error::MalformedNumber {
                path,
                line,
                column,
                value,
            },
        }
    }

    pub(crate) fn finish(self, roles: &ColumnNames) -> Result<FlightLog> {
        if let Some(error) = self.backward_error() {
            return Err(error);
        }
        let rows = self.values[self.time_index].len();
        if rows == 0 {
            return Err(Error::NoData {
                path: self.path.to_path_buf(),
                problem: "the file has a header line but no data rows".into(),
            });
        }
        let mut time_s = Vec::new();
        let (mut channels, mut text) = (Vec::new(), Vec::new());
        for ((name, kind), values) in self.names.into_iter().zip(self.kinds).zip(self.values) {
            match roles.role_of(&name) {
                None => time_s = values,
                Some(_) if kind == ColumnKind::Text => text.push(name),
                Some(role) => channels.push(Channel { name, role, values }),
            }
        }
        Ok(FlightLog::new(self.path, roles.time.clone(), time_s, channels)?.with_text_columns(text))
    }
}

/// Whether `cell` reads as a unit ("s", "nT", "deg", "m/s", "°", "%"):
/// short, and letters or unit signs only.
fn looks_like_a_unit(cell: &str) -> bool {
    let cell = cell.trim().trim_matches(|c| matches!(c, '(' | ')' | '[' | ']'));
    !cell.is_empty()
        && cell.chars().count() <= 16
        && cell.chars().any(|c| c.is_alphabetic() || matches!(c, '°' | '%'))
        && (cell.chars()).all(|c| {
            c.is_alphanumeric()
                || matches!(
                    c,
                    '°' | '%' | '/' | '^' | '*' | '.' | '-' | '_' | 'µ' | ' ' | '(' | ')' | '[' | ']'
                )
        })
}

/// Parses one cell: `Some(NaN)` for a missing marker, `Some(value)` for a
/// finite number, `None` for anything else.
pub fn parse_cell(cell: &[u8]) -> Option<f64> {
    let cell = cell.trim_ascii();
    if cell.is_empty() || cell == b"*" || cell.eq_ignore_ascii_case(b"nan") {
        return Some(f64::NAN);
    }
    match fast_float2::parse::<f64, _>(cell) {
        Ok(value) if value.is_finite() => Some(value),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn write_temp(text: &str) -> tempfile::NamedTempFile {
        let mut file = tempfile::Builder::new().suffix(".csv").tempfile().unwrap();
        file.write_all(text.as_bytes()).unwrap();
        file
    }

    #[test]
    fn quoted_header_and_cells_are_read_without_their_quotes() {
        let file =
            write_temp("\"tt\",\"mag_1_uc\",\"note, free\"\n\"0.0\",\"52000.5\",\"1\"\n\"0.1\",\"52000.75\",\"2\"\n");
        let (separator, names) = read_header(file.path()).unwrap();
        assert_eq!(separator, Separator::Byte(b','));
        assert_eq!(names, ["tt", "mag_1_uc", "note, free"]);
        let log = read_csv(file.path(), &ColumnNames::default()).unwrap();
        assert_eq!(log.time_s(), [0.0, 0.1]);
        assert_eq!(log.channel("mag_1_uc").unwrap().values, [52000.5, 52000.75]);
    }

    #[test]
    fn separators_are_sniffed() {
        assert_eq!(sniff_separator("tt,mag_1_uc"), Separator::Byte(b','));
        assert_eq!(sniff_separator("tt;mag_1_uc"), Separator::Byte(b';'));
        assert_eq!(sniff_separator("tt\tmag_1_uc"), Separator::Byte(b'\t'));
        assert_eq!(sniff_separator("tt   mag_1_uc"), Separator::Whitespace);
    }

    #[test]
    fn missing_markers_parse_as_nan_and_text_is_rejected() {
        for missing in ["", " ", "*", "NaN", "nan"] {
            assert!(parse_cell(missing.as_bytes()).unwrap().is_nan(), "{missing:?}");
        }
        assert_eq!(parse_cell(b" -12.5e3 "), Some(-12500.0));
        assert_eq!(parse_cell(b"12,5"), None);
        assert_eq!(parse_cell(b"inf"), None);
    }

    #[test]
    fn reads_every_separator_to_the_same_values() {
        let rows = [
            ("tt", "mag_1_uc", "cur_strb"),
            ("0.0", "50000.5", "*"),
            ("0.1", "50001.25", "1.5"),
        ];
        for sep in [",", ";", "\t", "   "] {
            let text: String = rows.iter().map(|(a, b, c)| format!("{a}{sep}{b}{sep}{c}\n")).collect();
            let file = write_temp(&text);
            let log = read_csv(file.path(), &ColumnNames::default()).unwrap();
            assert_eq!(log.time_s(), &[0.0, 0.1], "separator {sep:?}");
            assert_eq!(log.channel("mag_1_uc").unwrap().values, vec![50000.5, 50001.25]);
            let current = &log.channel("cur_strb").unwrap().values;
            assert!(current[0].is_nan() && current[1] == 1.5);
        }
    }

    #[test]
    fn a_row_of_units_is_read_as_units_for_every_separator() {
        for sep in [",", ";", "\t", "   "] {
            let text = [
                ["tt", "mag_1_uc", "cur_strb"],
                ["s", "nT", "A"],
                ["0.0", "50000.5", "*"],
                ["0.1", "50001.25", "1.5"],
            ]
            .map(|row| row.join(sep) + "\n")
            .concat();
            let file = write_temp(&text);
            let log = read_csv(file.path(), &ColumnNames::default()).unwrap();
            assert_eq!(log.time_s(), &[0.0, 0.1], "separator {sep:?}");
            assert_eq!(log.channel("mag_1_uc").unwrap().values, vec![50000.5, 50001.25]);
            let units: Vec<(&str, &str)> = (log.declared_units().iter())
                .map(|(c, u)| (c.as_str(), u.as_str()))
                .collect();
            assert_eq!(units, [("tt", "s"), ("mag_1_uc", "nT"), ("cur_strb", "A")], "{sep:?}");
            let first_row = text.find("0.0").unwrap() as u64;
            assert_eq!(log.source_row_offsets().unwrap()[0], first_row, "{sep:?}");
        }
        // A unit with words and brackets, and an empty time cell beside
        // units: still a row of units.
        for units in ["seconds (UTC),nT,A", ",nT,A"] {
            let file = write_temp(&format!("tt,mag_1_uc,cur_strb\n{units}\n0,1,2\n1,2,3\n"));
            let log = read_csv(file.path(), &ColumnNames::default()).unwrap();
            assert_eq!(log.len(), 2, "{units}");
            assert_eq!(log.declared_units()[1].1, "nT", "{units}");
        }
        // Not one: the cell that holds a number is named; so is a count of
        // cells the header does not have.
        let file = write_temp("tt,mag_1_uc,cur_strb\ns,nT,5\n0,1,2\n");
        let text = read_csv(file.path(), &ColumnNames::default()).unwrap_err().to_string();
        assert!(text.contains("line 2, column 'cur_strb': '5' is a number"), "{text}");
        let file = write_temp("tt,mag_1_uc,cur_strb\ns,nT\n0,1,2\n");
        let text = read_csv(file.path(), &ColumnNames::default()).unwrap_err().to_string();
        assert!(text.contains("the line has 2 cells and the header 3 columns"), "{text}");
        // A data row missing its time, beside a text cell, is not units.
        let file = write_temp("tt,mag_1_uc,note\n,1,leg\n1,2,leg\n");
        let text = read_csv(file.path(), &ColumnNames::default()).unwrap_err().to_string();
        assert!(!text.contains("row of units"), "{text}");
        // No units row: nothing declared.
        let file = write_temp("tt,mag_1_uc\n0,1\n1,2\n");
        assert!(read_csv(file.path(), &ColumnNames::default())
            .unwrap()
            .declared_units()
            .is_empty());
    }

    /// A file big enough for the parallel path: `rows` rows, a text column
    /// that turns numeric-looking late, and a column empty in its first half.
    fn big_file(rows: usize, bad_row: Option<usize>) -> tempfile::NamedTempFile {
        big_file_under(
            "tt,mag_1_uc,note,late,cur_a,flux_a_x,flux_a_y,flux_a_z\n",
            rows,
            bad_row,
        )
    }

    /// [`big_file`]'s rows under `head` (the header, and a row of units).
    fn big_file_under(head: &str, rows: usize, bad_row: Option<usize>) -> tempfile::NamedTempFile {
        let mut text = String::from(head);
        for k in 0..rows {
            let t = 1000.0 + k as f64 * 0.1;
            let mag = if Some(k) == bad_row {
                "5x1".to_string()
            } else {
                format!("{:.3}", 50_000.0 + (k % 997) as f64 * 0.013)
            };
            let note = if k < 10 { "leg".to_string() } else { format!("{k}") };
            let late = if k < rows / 2 {
                String::new()
            } else {
                format!("{}", k % 13)
            };
            text += &format!(
                "{t:.1},{mag},{note},{late},{},{},{},{}\n",
                (k % 7) as f64 * 0.5,
                k % 101,
                k % 103,
                k % 107
            );
        }
        write_temp(&text)
    }

    #[test]
    fn parallel_read_equals_sequential_read() {
        let file = big_file(160_000, None);
        assert!(std::fs::metadata(file.path()).unwrap().len() as usize > PARALLEL_MIN_BYTES);
        let names = ColumnNames::default();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
        let header = read_header(file.path()).unwrap().1;
        let template = ColumnBuilder::new(file.path(), header, &names).unwrap();
        let split = pool
            .install(|| read_delimited_parallel(file.path(), b',', &template, 1))
            .unwrap();
        assert!(split.is_some(), "this file takes the parallel path");
        let parallel = pool.install(|| read_csv_with(file.path(), &names, true)).unwrap();
        let sequential = read_csv_with(file.path(), &names, false).unwrap();
        assert_eq!(parallel.time_s(), sequential.time_s());
        assert_eq!(parallel.source_row_offsets(), sequential.source_row_offsets());
        assert!(parallel.channel("note").is_none(), "a text column stays text");
        assert_eq!(parallel.channels().len(), sequential.channels().len());
        for (a, b) in parallel.channels().iter().zip(sequential.channels()) {
            assert_eq!(a.name, b.name);
            assert!(
                a.values.iter().zip(&b.values).all(|(x, y)| x.to_bits() == y.to_bits()),
                "{}",
                a.name
            );
        }
        let late = &parallel.channel("late").unwrap().values;
        assert!(late[0].is_nan() && late[159_999] == (159_999 % 13) as f64);
    }

    #[test]
    fn parallel_read_skips_a_row_of_units_as_the_sequential_read_does() {
        let head = "tt,mag_1_uc,note,late,cur_a,flux_a_x,flux_a_y,flux_a_z\ns,nT,,,A,nT,nT,nT\n";
        let file = big_file_under(head, 160_000, None);
        let names = ColumnNames::default();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(3).build().unwrap();
        let header = read_header(file.path()).unwrap().1;
        let template = ColumnBuilder::new(file.path(), header, &names).unwrap();
        let split = pool
            .install(|| read_delimited_parallel(file.path(), b',', &template, 2))
            .unwrap();
        assert!(split.is_some(), "this file takes the parallel path");
        let parallel = pool.install(|| read_csv_with(file.path(), &names, true)).unwrap();
        let sequential = read_csv_with(file.path(), &names, false).unwrap();
        assert_eq!(parallel.len(), 160_000);
        assert_eq!(parallel.time_s()[0], 1000.0);
        assert_eq!(parallel.time_s(), sequential.time_s());
        assert_eq!(parallel.source_row_offsets(), sequential.source_row_offsets());
        assert_eq!(parallel.source_row_offsets().unwrap()[0], head.len() as u64);
        assert_eq!(parallel.declared_units(), sequential.declared_units());
        assert_eq!(parallel.declared_units()[4], ("cur_a".to_string(), "A".to_string()));
        // A bad cell far down is named at its line, the units row counted.
        let bad = big_file_under(head, 160_000, Some(150_000));
        let text = read_csv(bad.path(), &names).unwrap_err().to_string();
        assert!(text.contains("line 150003") && text.contains("'5x1'"), "{text}");
    }

    #[test]
    fn parallel_read_reports_the_same_error_line() {
        let file = big_file(160_000, Some(150_000));
        let text = read_csv(file.path(), &ColumnNames::default()).unwrap_err().to_string();
        assert!(text.contains("line 150002") && text.contains("'5x1'"), "{text}");
    }

    #[test]
    fn text_auxiliary_column_is_not_a_channel() {
        let file = write_temp("tt,flight,mag_1_uc\n0,Flt1002,1\n1,Flt1002,2\n");
        let log = read_csv(file.path(), &ColumnNames::default()).unwrap();
        assert!(log.channel("flight").is_none());
        assert_eq!(log.channels().len(), 1);
    }

    #[test]
    fn malformed_number_names_line_column_and_value() {
        let file = write_temp("tt,mag_1_uc\n0,1\n1,2x\n");
        let text = read_csv(file.path(), &ColumnNames::default()).unwrap_err().to_string();
        assert!(
            text.contains("line 3") && text.contains("'mag_1_uc'") && text.contains("'2x'"),
            "{text}"
        );
    }
}
