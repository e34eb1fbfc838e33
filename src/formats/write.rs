//! Writing: the compensated flight in the format its output path names,
//! a flight log as it is, and the JSON files.
//!
//! Every file is staged in the destination folder and renamed into place
//! ([`super::destination`]), so a reader never sees a half-written output.
//! The compensated output keeps every input row and column and appends
//! magcomp's columns (CONTRACT §3).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;

use serde::Serialize;

use super::csv::read_header;
use super::destination::{stage, Staged};
use super::table::StageRequest;
use super::{detect_format, mcap, ColumnNames, Format};
use crate::compensate::Compensation;
use crate::error::{Error, Result};
use crate::ingest::flight_log::FlightLog;

/// Writes one file atomically: staged beside `path` (whose folder must
/// exist), then renamed over it.
pub fn write_atomic(path: &Path, write: impl FnOnce(&mut BufWriter<&mut File>) -> std::io::Result<()>) -> Result<()> {
    stage(path, write)?.commit().map(drop)
}

/// Writes `value` as pretty JSON, atomically.
pub fn write_json<T: Serialize>(path: &Path, what: &'static str, value: &T) -> Result<()> {
    stage_json(path, what, value)?.commit().map(drop)
}

/// Stages DETECT.json (CONTRACT §3) of labelled manoeuvre windows and
/// boxes (start, end) for `path`; unlabelled windows are left out.
pub fn stage_detect_json(
    path: &Path,
    manoeuvres: &[crate::calibration::windows::CalibrationWindow],
    boxes: &[(f64, f64)],
) -> Result<Staged> {
    let file = crate::calibration::windows::DetectFile::new(manoeuvres, boxes);
    stage_json(path, "the calibration windows", &file)
}

/// Stages `value` as pretty JSON for `path`.
pub fn stage_json<T: Serialize>(path: &Path, what: &'static str, value: &T) -> Result<Staged> {
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::Serialise {
        path: path.to_path_buf(),
        what,
        source: Box::new(e),
    })?;
    stage(path, |w| w.write_all(text.as_bytes()))
}

/// The name of magcomp's output column for `channel`: `mag_<n>_c` for
/// `mag_<n>_uc`, `<name>_c` otherwise; `…_magcomp` appended when the input
/// already has a column of that name.
pub fn output_column_name(channel: &str, existing: &[String]) -> String {
    let base = match channel.strip_suffix("_uc") {
        Some(stem) if channel.starts_with("mag_") => format!("{stem}_c"),
        _ => format!("{channel}_c"),
    };
    match existing.contains(&base) {
        true => format!("{base}_magcomp"),
        false => base,
    }
}

/// The flags column name: `flags`, or `flags_magcomp` if taken.
pub fn flags_column_name(existing: &[String]) -> String {
    match existing.iter().any(|name| name == "flags") {
        true => "flags_magcomp".into(),
        false => "flags".into(),
    }
}

/// The names of the columns magcomp adds to the compensated output of
/// `log` at `output`: one per compensated channel, then the flags column,
/// renamed with `_magcomp` where the input already has the name.
pub fn added_column_names(log: &FlightLog, output: &Path, compensation: &Compensation) -> Result<Vec<String>> {
    let copies_csv = detect_output_format(output) == Format::DelimitedText
        && detect_format(log.source()).ok() == Some(Format::DelimitedText);
    let existing: Vec<String> = match copies_csv {
        true => read_header(log.source())?.1,
        false => std::iter::once(log.time_column().to_string())
            .chain(log.channels().iter().map(|c| c.name.clone()))
            .collect(),
    };
    Ok(new_column_names(&existing, compensation))
}

/// Stages the compensated flight for `output` in the format its extension
/// names: `.xyz` Geosoft XYZ, `.mcap` MCAP (with `extras` stored in it),
/// `.h5` HDF5, anything else comma-separated text. Every input row is
/// written, with the `added` columns (from [`added_column_names`]).
pub fn stage_compensated(
    log: &FlightLog,
    names: &ColumnNames,
    output: &Path,
    compensation: &Compensation,
    added: &[String],
    extras: &mcap::McapExtras,
) -> Result<Staged> {
    let format = detect_output_format(output);
    let request = StageRequest {
        added,
        output,
        compensation: Some(compensation),
        extras,
    };
    match format.row().copy {
        // An input of the output's own format is copied, its lines kept.
        Some(copy) if detect_format(log.source()).ok() == Some(format) => copy(log, names, &request, compensation),
        _ => (format.row().stage)(log, &request),
    }
}

/// A warning naming the input's text columns when `output` is written
/// from the flight log (which holds numbers only) rather than copied from
/// the input: a CSV input to a CSV output, or an XYZ input to an XYZ
/// output, of the compensated flight keeps them; `convert` never does.
pub fn text_columns_warning(log: &FlightLog, output: &Path, copies_input: bool) -> Option<crate::messages::Warning> {
    let format = detect_output_format(output);
    let copied = copies_input && format.row().copy.is_some() && detect_format(log.source()).ok() == Some(format);
    (!copied && !log.text_columns().is_empty()).then(|| crate::messages::Warning::TextColumnsNotWritten {
        input: log.source().to_path_buf(),
        columns: log.text_columns().to_vec(),
        output: output.to_path_buf(),
    })
}

/// Writes a flight log as it is, in the format `output`'s extension names
/// (see [`stage_flight_log`]).
pub fn write_flight_log(log: &FlightLog, output: &Path) -> Result<()> {
    stage_flight_log(log, output)?.commit().map(drop)
}

/// Stages a flight log as it is, in the format `output`'s extension names:
/// `.xyz` Geosoft XYZ, `.mcap` MCAP, `.h5` HDF5 in the MagNav layout,
/// anything else comma-separated text.
pub fn stage_flight_log(log: &FlightLog, output: &Path) -> Result<Staged> {
    let request = StageRequest {
        added: &[],
        output,
        compensation: None,
        extras: &mcap::McapExtras::default(),
    };
    (detect_output_format(output).row().stage)(log, &request)
}

/// The format an output path asks for, by extension (CSV by default).
pub fn detect_output_format(output: &Path) -> Format {
    Format::of_extension(&super::lowercase_extension(output)).unwrap_or(Format::DelimitedText)
}

/// Names of the columns magcomp adds after `existing`: one per compensated
/// channel, six per compensated fluxgate, one per gradient, then the flags
/// column.
/// The unit of each column [`new_column_names`] adds, in its order, for an
/// input with a row of units: nT, nT/m for a gradient, none for the flags.
pub(crate) fn added_column_units(compensation: &Compensation) -> Vec<&'static str> {
    let scalars: usize = compensation
        .channels
        .iter()
        .map(|c| 1 + usize::from(c.sigma_nt.is_some()))
        .sum();
    let vectors = 6 * compensation.vectors.len();
    std::iter::repeat_n("nT", scalars + vectors)
        .chain(std::iter::repeat_n("nT/m", compensation.gradients.len()))
        .chain(std::iter::repeat_n("nT", compensation.reduced.len()))
        .chain(std::iter::once(""))
        .collect()
}

fn new_column_names(existing: &[String], compensation: &Compensation) -> Vec<String> {
    let mut added: Vec<String> = Vec::new();
    for channel in &compensation.channels {
        let taken: Vec<String> = existing.iter().chain(&added).cloned().collect();
        let name = output_column_name(&channel.channel, &taken);
        if channel.sigma_nt.is_some() {
            // `mag_<n>_c_sigma` beside `mag_<n>_c` (CONTRACT §3).
            let sigma = format!("{name}_sigma");
            added.push(name);
            added.push(match existing.iter().chain(&added).any(|n| *n == sigma) {
                true => format!("{sigma}_magcomp"),
                false => sigma,
            });
        } else {
            added.push(name);
        }
    }
    for vector in &compensation.vectors {
        for axis in ["x", "y", "z", "n", "e", "d"] {
            let base = format!("{}_{axis}_c", vector.sensor);
            added.push(match existing.iter().chain(&added).any(|n| *n == base) {
                true => format!("{base}_magcomp"),
                false => base,
            });
        }
    }
    for gradient in &compensation.gradients {
        added.push(match existing.iter().chain(&added).any(|n| *n == gradient.column) {
            true => format!("{}_magcomp", gradient.column),
            false => gradient.column.clone(),
        });
    }
    for reduced in &compensation.reduced {
        added.push(match existing.iter().chain(&added).any(|n| *n == reduced.column) {
            true => format!("{}_magcomp", reduced.column),
            false => reduced.column.clone(),
        });
    }
    let taken: Vec<String> = existing.iter().chain(&added).cloned().collect();
    added.push(flags_column_name(&taken));
    added
}

/// Formats magcomp's cells for one row at a time.
pub(crate) struct ExtraColumns<'a> {
    compensation: &'a Compensation,
    /// The value columns, channels, vectors, then gradients.
    values: Vec<&'a [f64]>,
    /// The next row to write.
    pub(crate) row: usize,
    buffer: number_text::Buffer,
    /// The row's flags as text.
    flags: String,
}

impl<'a> ExtraColumns<'a> {
    pub(crate) fn new(compensation: &'a Compensation) -> Self {
        ExtraColumns {
            compensation,
            values: compensation.value_columns(),
            row: 0,
            buffer: number_text::Buffer::default(),
            flags: String::new(),
        }
    }

    /// The same columns, the next row `row`: for a part of the rows
    /// written apart.
    pub(crate) fn at(&self, row: usize) -> Self {
        ExtraColumns {
            compensation: self.compensation,
            values: self.values.clone(),
            row,
            buffer: number_text::Buffer::default(),
            flags: String::new(),
        }
    }

    /// Cells a row gets: the value columns and the flags.
    pub(crate) fn width(&self) -> usize {
        self.values.len() + 1
    }

    /// The flags cell of the next row (empty when it is fine).
    fn flags_text(&mut self) -> &[u8] {
        use std::fmt::Write as _;
        self.flags.clear();
        let flags = &self.compensation.flags[self.row];
        if !flags.is_empty() {
            let _ = write!(self.flags, "{flags}");
        }
        self.flags.as_bytes()
    }

    pub(crate) fn append_to(&mut self, record: &mut ::csv::ByteRecord) {
        for column in &self.values {
            record.push_field(self.buffer.format(column[self.row]));
        }
        record.push_field(self.flags_text());
        self.row += 1;
    }

    /// Writes ` value` per channel (`*` for a null) and ` flags` for the
    /// next row of an XYZ file.
    pub(crate) fn write_xyz_cells<W: Write>(&mut self, out: &mut W) -> std::io::Result<()> {
        for column in &self.values {
            out.write_all(b" ")?;
            let value = column[self.row];
            out.write_all(if value.is_finite() {
                self.buffer.format(value)
            } else {
                b"*"
            })?;
        }
        out.write_all(b" ")?;
        let flags = self.flags_text();
        out.write_all(if flags.is_empty() { b"*" } else { flags })?;
        self.row += 1;
        Ok(())
    }

    /// Writes `,value` per channel and `,flags` for the next row.
    pub(crate) fn write_cells<W: Write>(&mut self, out: &mut W) -> std::io::Result<()> {
        for column in &self.values {
            out.write_all(b",")?;
            out.write_all(self.buffer.format(column[self.row]))?;
        }
        out.write_all(b",")?;
        let flags = self.flags_text();
        write_cell(out, flags)?;
        self.row += 1;
        Ok(())
    }
}

/// Writes one comma-separated cell, quoted when it holds a comma, a quote
/// or a line break.
pub(crate) fn write_cell<W: Write>(out: &mut W, cell: &[u8]) -> std::io::Result<()> {
    if !cell.iter().any(|b| matches!(b, b',' | b'"' | b'\n' | b'\r')) {
        return out.write_all(cell);
    }
    out.write_all(b"\"")?;
    for part in cell.split_inclusive(|&b| b == b'"') {
        out.write_all(part)?;
        if part.ends_with(b"\"") {
            out.write_all(b"\"")?;
        }
    }
    out.write_all(b"\"")
}

pub(crate) fn row_count_changed(rows: usize) -> std::io::Error {
    std::io::Error::other(format!(
        "the input no longer has the {rows} data rows it had when it was read; was it modified during the run?"
    ))
}

/// Shortest round-trip text of an `f64` in `Display`'s layout (no
/// exponent), reusing one buffer. A value rounded to at most six places
/// (every added column is) is written from an integer, which gives Ryū's
/// text; Ryū finds the digits of any other several times faster than
/// `Display`, and its text is taken as is unless it has an exponent or a
/// `.0` that `Display` would not write. Where two shortest
/// texts lie equally near the value (it is exactly halfway, as
/// 573617812358680.25 is), Ryū takes the even last digit and `Display`
/// the upper one: either parses back to the same `f64`.
pub(crate) mod number_text {
    use std::io::Write;

    /// A reusable text buffer.
    #[derive(Default)]
    pub struct Buffer {
        text: Vec<u8>,
        digits: ryu::Buffer,
    }

    /// The most decimals [`decimal_text`] writes: the outputs' finest
    /// resolution (gradients, nT/m).
    const MOST_DECIMALS: i32 = 6;

    /// `value`'s shortest round-trip text written from an integer, when it
    /// is a decimal of at most [`MOST_DECIMALS`] places and 15 significant
    /// digits (as every rounded output is): `value` is then the `f64`
    /// nearest to `m / 10⁶` for the integer `m` (the division is correctly
    /// rounded), so that decimal parses back to it; and no other decimal
    /// of as few digits does, since two decimals of 15 significant digits
    /// lie further apart than an `f64`'s spacing. So the text is Ryū's,
    /// digit for digit, at a fraction of the work. `false` (nothing
    /// written) otherwise, and for zero, whose sign the integer loses.
    fn decimal_text(value: f64, text: &mut Vec<u8>) -> bool {
        const SCALE: f64 = 1e6;
        let scaled = (value * SCALE).round();
        if value == 0.0 || scaled.abs() >= 1e15 || scaled / SCALE != value {
            return false;
        }
        let mut digits = itoa::Buffer::new();
        let whole = digits.format(scaled.abs() as u64).as_bytes();
        if value < 0.0 {
            text.push(b'-');
        }
        let places = MOST_DECIMALS as usize;
        let (integer, fraction) = match whole.len() > places {
            true => whole.split_at(whole.len() - places),
            false => (&b""[..], whole),
        };
        match integer.is_empty() {
            true => text.push(b'0'),
            false => text.extend_from_slice(integer),
        }
        let fraction_zeros = places - fraction.len();
        let significant = fraction.iter().rposition(|&d| d != b'0').map_or(0, |p| p + 1);
        if significant > 0 {
            text.push(b'.');
            text.extend(std::iter::repeat_n(b'0', fraction_zeros));
            text.extend_from_slice(&fraction[..significant]);
        }
        true
    }

    impl Buffer {
        /// `value` as the shortest text that parses back to it; empty for NaN.
        pub fn format(&mut self, value: f64) -> &[u8] {
            self.text.clear();
            if value.is_finite() && !decimal_text(value, &mut self.text) {
                let digits = self.digits.format_finite(value).as_bytes();
                if digits.contains(&b'e') {
                    let _ = write!(self.text, "{value}");
                } else {
                    let digits = digits.strip_suffix(b".0").unwrap_or(digits);
                    self.text.extend_from_slice(digits);
                }
            }
            &self.text
        }
    }

    #[cfg(test)]
    mod tests {
        /// The text parses back to the value, bit for bit, has no
        /// exponent, and is `Display`'s but for the last digit of a tie: on
        /// values of every magnitude (round and fractional, tiny
        /// and huge, negative zero) and two million drawn at random.
        /// Ryū's shortest digits in `Display`'s layout: the text every
        /// value had before the decimal fast path.
        fn ryu_text(value: f64) -> String {
            let digits = ryu::Buffer::new().format_finite(value).to_string();
            match digits.contains('e') {
                true => format!("{value}"),
                false => digits.strip_suffix(".0").unwrap_or(&digits).to_string(),
            }
        }

        /// Values rounded as the outputs round them (0 to 6 places, every
        /// magnitude an output has, both signs), and values drawn at
        /// random: the decimal fast path writes Ryū's text, byte for byte,
        /// wherever it writes at all.
        #[test]
        fn the_decimal_path_writes_ryus_text() {
            let mut state = 0x9E37_79B9_7F4A_7C15u64;
            let mut next = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                state
            };
            let mut text = Vec::new();
            for k in 0..3_000_000u64 {
                let rounded = k % 3 != 0;
                let value = match rounded {
                    false => f64::from_bits(next()),
                    true => {
                        let places = (next() % 7) as i32;
                        let magnitude = 10f64.powi((next() % 15) as i32 - 4);
                        let raw = (next() as f64 / u64::MAX as f64 - 0.5) * 2.0 * magnitude;
                        let scale = 10f64.powi(places);
                        (raw * scale).round() / scale + 0.0
                    }
                };
                if !value.is_finite() {
                    continue;
                }
                text.clear();
                let written = super::decimal_text(value, &mut text);
                if written {
                    assert_eq!(std::str::from_utf8(&text).unwrap(), ryu_text(value), "{value:e}");
                }
                // Every rounded output below a billion but zero takes it.
                if rounded && value != 0.0 && value.abs() < 1e9 {
                    assert!(written, "{value:e}");
                }
            }
            for value in [
                0.0,
                -0.0,
                0.001,
                -0.001,
                0.1,
                1e-6,
                3080.0,
                -52003.467,
                999_999_999.999_999,
            ] {
                assert_eq!(
                    std::str::from_utf8(super::Buffer::default().format(value)).unwrap(),
                    ryu_text(value)
                );
            }
        }

        #[test]
        fn the_text_parses_back_in_the_layout_display_writes() {
            let mut buffer = super::Buffer::default();
            let mut check = |value: f64| {
                let text = std::str::from_utf8(buffer.format(value)).unwrap();
                if !value.is_finite() {
                    assert_eq!(text, "");
                    return;
                }
                let display = format!("{value}");
                assert_eq!(text.parse::<f64>().unwrap().to_bits(), value.to_bits(), "{text}");
                assert!(!text.contains('e'), "{text}");
                if text != display {
                    assert_eq!(text.len(), display.len(), "{text} against {display}");
                    assert_eq!(
                        text[..text.len() - 1],
                        display[..display.len() - 1],
                        "{text} against {display}"
                    );
                }
            };
            for value in [
                0.0,
                -0.0,
                1.0,
                -1.0,
                0.1,
                0.5,
                52003.467,
                1e15,
                1e16,
                1e17,
                1e-5,
                1e-6,
                1e-7,
                123456789012345680.0,
                f64::MAX,
                f64::MIN_POSITIVE,
                5e-324,
                f64::NAN,
                f64::INFINITY,
            ] {
                check(value);
            }
            let mut state = 0x2545_F491_4F6C_DD1Du64;
            for _ in 0..1_000_000 {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                check(f64::from_bits(state));
                // Survey-sized values: a few to 1e5 nT with a few decimals.
                check((state >> 11) as f64 / (1u64 << 53) as f64 * 1e5 - 5e4);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn output_names_follow_the_contract() {
        let header: Vec<String> = ["tt", "mag_1_uc", "mag_1_c", "tail"].map(String::from).to_vec();
        assert_eq!(output_column_name("mag_1_uc", &header), "mag_1_c_magcomp");
        assert_eq!(output_column_name("mag_3_uc", &header), "mag_3_c");
        assert_eq!(output_column_name("tail", &header), "tail_c");
        assert_eq!(flags_column_name(&header), "flags");
        assert_eq!(flags_column_name(&["flags".to_string()]), "flags_magcomp");
    }

    #[test]
    fn atomic_write_leaves_no_temporary_file() {
        let folder = tempfile::tempdir().unwrap();
        let path = folder.path().join("out.json");
        write_json(&path, "test", &vec![1.5, 2.0]).unwrap();
        let names: Vec<_> = std::fs::read_dir(folder.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("out.json")]);
        assert_eq!(
            std::fs::read_to_string(&path)
                .unwrap()
                .split_whitespace()
                .collect::<String>(),
            "[1.5,2.0]"
        );
    }
}
