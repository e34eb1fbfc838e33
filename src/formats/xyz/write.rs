//! Writing Geosoft XYZ.
//!
//! An XYZ input written as XYZ is copied line by line: comments, line
//! records and data rows stay as they were, the header line gains the new
//! names and each data row its new values (`*` for a null). Any other
//! combination is written from the flight log itself: the time column and
//! every channel, then the added columns.

use std::io::{BufRead, BufReader, Write};
use std::path::Path;

use super::{classify, find_header, XyzLine};
use crate::compensate::Compensation;
use crate::error::Result;
use crate::formats::destination::{stage, Staged};
use crate::formats::write::ExtraColumns;
use crate::formats::ColumnNames;
use crate::ingest::flight_log::{ChannelRole, FlightLog};

/// Stages a copy of an XYZ input with the added columns appended. `names` are the column
/// names the input was read with.
pub fn stage_xyz_copy(
    log: &FlightLog,
    names: &ColumnNames,
    added: &[String],
    output: &Path,
    compensation: &Compensation,
) -> Result<Staged> {
    let input = log.source();
    let header = find_header(input, names)?;
    let rows = compensation.flags.len();
    stage(output, |out| {
        let reader = BufReader::with_capacity(1 << 20, std::fs::File::open(input)?);
        let mut extra = ExtraColumns::new(compensation);
        for (index, line) in reader.lines().enumerate() {
            let line = line?;
            let text = line.trim_end();
            if index == header.line_index {
                writeln!(out, "{text} {}", added.join(" "))?;
                continue;
            }
            match classify(text) {
                XyzLine::Data if extra.row < rows => {
                    out.write_all(text.as_bytes())?;
                    extra.write_xyz_cells(out)?;
                    out.write_all(b"\n")?;
                }
                XyzLine::Data => return Err(crate::formats::write::row_count_changed(rows)),
                _ => writeln!(out, "{text}")?,
            }
        }
        match extra.row == rows {
            true => Ok(()),
            false => Err(crate::formats::write::row_count_changed(rows)),
        }
    })
}

/// Stages the flight log and the added columns as Geosoft XYZ: a `/` header
/// line, a `Line` record whenever the line channel changes, `*` for nulls.
pub fn stage_log_xyz(
    log: &FlightLog,
    added: &[String],
    output: &Path,
    compensation: Option<&Compensation>,
) -> Result<Staged> {
    let line_channel = log.channels().iter().position(|c| c.role == ChannelRole::Line);
    stage(output, |out| {
        let names: Vec<&str> = std::iter::once(log.time_column())
            .chain(log.channels().iter().map(|c| c.name.as_str()))
            .chain(added.iter().map(String::as_str))
            .collect();
        let what = match compensation {
            Some(_) => "compensated flight",
            None => "flight",
        };
        writeln!(out, "/ magcomp {what}, from {}", log.source().display())?;
        writeln!(out, "/ {}", names.join(" "))?;
        let mut extra = compensation.map(ExtraColumns::new);
        let mut current_line = f64::NAN;
        let mut number = ryu::Buffer::new();
        for row in 0..log.len() {
            if let Some(index) = line_channel {
                let line = log.channels()[index].values[row];
                if line.is_finite() && line != current_line {
                    writeln!(out, "Line {}", number.format(line))?;
                    current_line = line;
                }
            }
            out.write_all(number.format(log.time_s()[row]).as_bytes())?;
            for channel in log.channels() {
                let value = channel.values[row];
                out.write_all(b" ")?;
                out.write_all(if value.is_finite() {
                    number.format(value).as_bytes()
                } else {
                    b"*"
                })?;
            }
            if let Some(extra) = &mut extra {
                extra.write_xyz_cells(out)?;
            }
            out.write_all(b"\n")?;
        }
        Ok(())
    })
}
