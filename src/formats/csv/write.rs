//! Writing comma-separated text: the compensated copy of a CSV input, and
//! any flight log as CSV.
//!
//! A comma-separated input whose row offsets are known is copied byte for
//! byte, so text columns and number formatting survive, each row followed
//! by magcomp's cells (CONTRACT §3).

use std::fs::File;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;

use rayon::prelude::*;

use crate::compensate::Compensation;
use crate::error::Result;
use crate::formats::columns::ColumnNames;
use crate::formats::destination::{stage, Staged};
use crate::formats::write::{added_column_units, row_count_changed, write_cell, ExtraColumns};
use crate::ingest::flight_log::FlightLog;

use super::{delimited_reader, read_header, read_units_row, Separator};

/// Stages the compensated CSV: every input row and column, then one column
/// per compensated channel and the flags column.
///
/// A comma-separated input whose row offsets are known (`row_offsets`, from
/// the reader) is copied byte for byte, each row's text followed by the new
/// cells; other inputs are re-read and written as comma-separated records.
/// An input's row of units under its header is kept, with the added
/// columns' units.
pub fn stage_compensated_csv(
    (input, roles): (&Path, &ColumnNames),
    row_offsets: Option<&[u64]>,
    output: &Path,
    compensation: &Compensation,
    added: &[String],
) -> Result<Staged> {
    let (separator, header) = read_header(input)?;
    let units = read_units_row(input, separator, &header, roles)?;
    let added_units = added_column_units(compensation);
    let rows = compensation.flags.len();
    if let (Separator::Byte(b','), Some(offsets)) = (separator, row_offsets) {
        if offsets.len() == rows {
            return stage(output, |writer| {
                let head = Head {
                    added,
                    added_units: &added_units,
                };
                copy_verbatim(input, offsets, head, writer, &ExtraColumns::new(compensation))
            });
        }
    }
    stage(output, |writer| {
        let mut csv = csv::Writer::from_writer(writer);
        csv.write_record(header.iter().chain(added))?;
        if let Some(units) = &units {
            csv.write_record(units.iter().map(String::as_str).chain(added_units.iter().copied()))?;
        }
        let mut extra = ExtraColumns::new(compensation);
        let skip = 1 + usize::from(units.is_some());
        match separator {
            Separator::Byte(delimiter) => copy_delimited(input, (delimiter, skip), &mut csv, &mut extra, rows)?,
            Separator::Whitespace => copy_whitespace(input, skip, &mut csv, &mut extra, rows)?,
        }
        csv.flush()
    })
}

/// What the copy adds to the lines above the data: the added columns'
/// names, and their units for a row of units.
struct Head<'a> {
    added: &'a [String],
    added_units: &'a [&'static str],
}

/// Copies the header (and the units row under it, if any) and every row of
/// a comma-separated `input` verbatim (without its line terminator),
/// appending the added cells to each.
fn copy_verbatim<W: Write>(
    input: &Path,
    offsets: &[u64],
    head: Head,
    out: &mut W,
    extra: &ExtraColumns,
) -> std::io::Result<()> {
    let mut file = BufReader::with_capacity(1 << 20, File::open(input)?);
    copy_head(&mut file, offsets.first().copied().unwrap_or(0), head, out)?;
    // Rows go in waves: each wave's text is read whole, its chunks of rows
    // get their cells side by side, and the chunks are written in order, so
    // the bytes are the same whatever the thread count and at most a wave
    // is in memory.
    let wave_rows = COPY_CHUNK_ROWS * 2 * rayon::current_num_threads();
    let mut text = Vec::new();
    for wave in (0..offsets.len()).step_by(wave_rows) {
        let end = (wave + wave_rows).min(offsets.len());
        let length = offsets.get(end).map(|next| next - offsets[wave]);
        read_span(&mut file, length, &mut text)?;
        let rows = Wave {
            text: &text,
            offsets: &offsets[wave..end],
            first_row: wave,
        };
        let chunks: Vec<std::io::Result<Vec<u8>>> = (wave..end)
            .step_by(COPY_CHUNK_ROWS)
            .collect::<Vec<_>>()
            .into_par_iter()
            .map(|start| rows.chunk(start..(start + COPY_CHUNK_ROWS).min(end), extra))
            .collect();
        for chunk in chunks {
            out.write_all(&chunk?)?;
        }
    }
    Ok(())
}

/// Copies the input's first `header_length` bytes, its header and the
/// units row under it when there is one, with the added columns' names
/// and units appended.
fn copy_head<W: Write>(file: &mut impl Read, header_length: u64, head: Head, out: &mut W) -> std::io::Result<()> {
    let mut text = Vec::new();
    read_span(file, Some(header_length), &mut text)?;
    // The span before the first row: the header, then the units row when
    // the reader found one (any other line there would have been a row).
    let text = without_terminator(&text);
    let (header, units) = match text.iter().position(|&b| b == b'\n') {
        Some(end) => (&text[..end], Some(without_terminator(&text[end..]))),
        None => (text, None),
    };
    out.write_all(without_terminator(header))?;
    for name in head.added {
        out.write_all(b",")?;
        write_cell(out, name.as_bytes())?;
    }
    out.write_all(b"\n")?;
    if let Some(units) = units {
        out.write_all(units)?;
        for unit in head.added_units {
            out.write_all(b",")?;
            write_cell(out, unit.as_bytes())?;
        }
        out.write_all(b"\n")?;
    }
    Ok(())
}

/// Rows a task of the verbatim copy gives its cells.
const COPY_CHUNK_ROWS: usize = 2048;

/// The text of consecutive rows of the input, read whole.
struct Wave<'a> {
    text: &'a [u8],
    /// The rows' offsets in the file; the first is the text's start.
    offsets: &'a [u64],
    /// The index of the first row.
    first_row: usize,
}

impl Wave<'_> {
    /// The rows `rows` (indices in the file) as the output has them: each
    /// row's text without its terminator, then magcomp's cells.
    fn chunk(&self, rows: std::ops::Range<usize>, extra: &ExtraColumns) -> std::io::Result<Vec<u8>> {
        let base = self.offsets[0];
        let span = |row: usize| {
            let local = row - self.first_row;
            let start = (self.offsets[local] - base) as usize;
            let end = self
                .offsets
                .get(local + 1)
                .map_or(self.text.len(), |next| (next - base) as usize);
            &self.text[start..end]
        };
        let mut out = Vec::with_capacity(rows.len() * (span(rows.start).len() + 16 * extra.width()));
        let mut cells = extra.at(rows.start);
        for row in rows {
            out.extend_from_slice(without_terminator(span(row)));
            cells.write_cells(&mut out)?;
            out.push(b'\n');
        }
        Ok(out)
    }
}

/// Reads the next `length` bytes, or up to the end when `None`.
fn read_span(file: &mut impl Read, length: Option<u64>, text: &mut Vec<u8>) -> std::io::Result<()> {
    text.clear();
    match length {
        Some(length) => {
            text.resize(length as usize, 0);
            file.read_exact(text).map_err(|e| match e.kind() {
                std::io::ErrorKind::UnexpectedEof => {
                    std::io::Error::other("the input is shorter than when it was read; was it modified during the run?")
                }
                _ => e,
            })
        }
        None => file.read_to_end(text).map(|_| ()),
    }
}

/// A record's text without the line terminators (and blank lines) around it.
fn without_terminator(text: &[u8]) -> &[u8] {
    let is_text = |b: &u8| *b != b'\n' && *b != b'\r';
    let start = text.iter().position(is_text).unwrap_or(text.len());
    let end = text.iter().rposition(is_text).map_or(start, |p| p + 1);
    &text[start..end]
}

/// Copies the records of a delimited `input` after its first `skip` lines
/// (the header, and the units row when there is one).
fn copy_delimited<W: Write>(
    input: &Path,
    (delimiter, skip): (u8, usize),
    csv: &mut csv::Writer<W>,
    extra: &mut ExtraColumns,
    rows: usize,
) -> std::io::Result<()> {
    let mut reader = delimited_reader(BufReader::with_capacity(1 << 20, File::open(input)?), delimiter);
    let mut record = csv::ByteRecord::new();
    for _ in 1..skip {
        reader.read_byte_record(&mut record)?;
    }
    while reader.read_byte_record(&mut record)? {
        if extra.row >= rows {
            return Err(row_count_changed(rows));
        }
        extra.append_to(&mut record);
        csv.write_byte_record(&record)?;
    }
    match extra.row == rows {
        true => Ok(()),
        false => Err(row_count_changed(rows)),
    }
}

/// Copies the rows of a whitespace-aligned `input` after its first `skip`
/// lines (the header, and the units row when there is one).
fn copy_whitespace<W: Write>(
    input: &Path,
    skip: usize,
    csv: &mut csv::Writer<W>,
    extra: &mut ExtraColumns,
    rows: usize,
) -> std::io::Result<()> {
    let reader = BufReader::with_capacity(1 << 20, File::open(input)?);
    let mut record = csv::ByteRecord::new();
    for line in reader.split(b'\n').skip(skip) {
        let line = line?;
        if line.iter().all(u8::is_ascii_whitespace) {
            continue;
        }
        if extra.row >= rows {
            return Err(row_count_changed(rows));
        }
        record.clear();
        line.split(u8::is_ascii_whitespace)
            .filter(|f| !f.is_empty())
            .for_each(|f| record.push_field(f));
        extra.append_to(&mut record);
        csv.write_byte_record(&record)?;
    }
    match extra.row == rows {
        true => Ok(()),
        false => Err(row_count_changed(rows)),
    }
}

/// Stages the flight log and the added columns as comma-separated text.
pub fn stage_log_csv(
    log: &FlightLog,
    added: &[String],
    output: &Path,
    compensation: Option<&Compensation>,
) -> Result<Staged> {
    stage(output, |out| {
        let names = std::iter::once(log.time_column())
            .chain(log.channels().iter().map(|c| c.name.as_str()))
            .chain(added.iter().map(String::as_str));
        for (k, name) in names.enumerate() {
            if k > 0 {
                out.write_all(b",")?;
            }
            write_cell(out, name.as_bytes())?;
        }
        out.write_all(b"\n")?;
        let added_units = match compensation {
            Some(compensation) => added_column_units(compensation),
            None => vec![""; added.len()],
        };
        write_declared_units(log, &added_units, out)?;
        let mut extra = compensation.map(ExtraColumns::new);
        let mut number = ryu::Buffer::new();
        for row in 0..log.len() {
            out.write_all(number.format(log.time_s()[row]).as_bytes())?;
            for channel in log.channels() {
                let value = channel.values[row];
                out.write_all(b",")?;
                if value.is_finite() {
                    out.write_all(number.format(value).as_bytes())?;
                }
            }
            if let Some(extra) = &mut extra {
                extra.write_cells(out)?;
            }
            out.write_all(b"\n")?;
        }
        Ok(())
    })
}

/// The row of units of a log read with one, under the header of its
/// written columns (time, then the channels), then the added columns'
/// units. Nothing when the input had no row of units.
fn write_declared_units(log: &FlightLog, added: &[&str], out: &mut impl Write) -> std::io::Result<()> {
    let declared = log.declared_units();
    if declared.is_empty() {
        return Ok(());
    }
    let unit_of = |name: &str| {
        (declared.iter())
            .find(|(column, _)| column == name)
            .map_or("", |(_, unit)| unit.as_str())
    };
    let columns = std::iter::once(log.time_column()).chain(log.channels().iter().map(|c| c.name.as_str()));
    for (k, name) in columns.enumerate() {
        if k > 0 {
            out.write_all(b",")?;
        }
        write_cell(out, unit_of(name).as_bytes())?;
    }
    for unit in added {
        out.write_all(b",")?;
        write_cell(out, unit.as_bytes())?;
    }
    out.write_all(b"\n")
}
