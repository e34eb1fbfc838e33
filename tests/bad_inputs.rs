//! A seeded corpus of bad inputs for every reader (CSV, Geosoft
//! XYZ, MCAP, HDF5), each file run through `detect`, `compensate --plain`,
//! `diagnose` and `convert`.
//!
//! The corpus is derived from one small synthetic flight (seed [`SEED`]):
//! truncations, seeded byte flips, BOM and line-end variants, duplicate,
//! backwards and equal times, huge cells, poisoned samples (±1e308, the
//! smallest subnormal, 0, NaN, empty) inside and outside the calibration
//! box, empty, header-only and one-row files, and a CSV header of 200,000
//! columns. For every run the contract (docs/CONTRACT.md §2 and §3) asks:
//!
//! - no panic (no `panicked` on stderr, no death by a signal) and no hang
//!   (each run is killed after [`RUN_TIME_LIMIT`]);
//! - on failure, one paragraph that starts with `magcomp: error:` and
//!   names the bad file;
//! - on success of `compensate` or `convert`, every input row in the
//!   output (for a damaged MCAP or HDF5 file, every row the library's
//!   reader recovers, and when that is fewer than the intact file's, the
//!   reader's warnings repeated by the run); where a sample was poisoned or
//!   time went wrong, its row carries a flag and the compensated values of
//!   the rows around it stay finite and near the column's median (a bad
//!   sample never spreads into its neighbours);
//! - on the 200,000-column header, every command within [`WIDE_TIME_BOUND`].
//!
//! Every violation in the corpus is collected, then all are listed, after
//! a table of every run's outcome, before the test fails. The input of
//! each violating variant (of every variant with `BAD_INPUTS_KEEP_ALL`
//! set) is kept under `target/tmp/bad_inputs/` to reproduce it by hand.

use std::ffi::OsString;
use std::fs::File;
use std::io::Cursor;
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{mpsc, Mutex};
use std::time::{Duration, Instant};

use magcomp::config::Settings;
use magcomp::formats::read_flight_log;
use magcomp::formats::write_flight_log;
use magcomp::ingest::flight_log::{Channel, FlightLog};
use magcomp::simulate::sample_flight::{generate, write, SampleFlightSpec};

/// Seed of the flight and of every random choice in the corpus.
const SEED: u64 = 19;
/// A run still going after this long is a hang: it is killed and reported.
const RUN_TIME_LIMIT: Duration = Duration::from_secs(60);
/// Columns of the wide-header CSV.
const WIDE_COLUMNS: usize = 200_000;
/// Data rows of the wide-header CSV.
const WIDE_ROWS: usize = 20;
/// Time any command may take on the wide-header CSV. This is a guard
/// against quadratic behaviour in the header's width (200,000² steps take
/// minutes), not a benchmark: a linear reader needs well under a second.
const WIDE_TIME_BOUND: Duration = Duration::from_secs(20);
/// Byte-flip variants per format with one flipped byte, and with many.
const SINGLE_FLIPS: usize = 4;
const MULTI_FLIPS: usize = 2;
const FLIPS_PER_MULTI: usize = 64;
/// Jump forced before the last row by the `time-far-last` variants, s
/// (about 32 years): gaps are allowed, but nothing may size a buffer by it.
const FAR_JUMP_S: f64 = 1e9;
/// Size of a huge cell, bytes.
const HUGE_CELL_BYTES: usize = 1_500_000;
/// Rows on each side of a poisoned row whose compensated values must stay
/// sane.
const NEIGHBOURS: usize = 10;
/// How far a neighbour's compensated value may sit from its column's
/// median, nT. The sample flight's compensated field varies by tens of nT
/// (anomalies of buried dipoles); 1e4 nT only catches a poisoned fit or a
/// spike spread by a filter.
const NEIGHBOUR_TOLERANCE_NT: f64 = 1e4;
/// Child processes run at once (the test machine has two cores).
const WORKERS: usize = 2;

// ---------------------------------------------------------------------------
// Seeded randomness.

/// SplitMix64 (Steele, Lea & Flood 2014): enough for choosing byte offsets.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn below(&mut self, bound: usize) -> usize {
        (self.next_u64() % bound as u64) as usize
    }
}

/// `bytes` with `count` bytes at seeded positions XORed with a non-zero mask.
fn flip_bytes(bytes: &[u8], count: usize, random: &mut SplitMix64) -> Vec<u8> {
    let mut flipped = bytes.to_vec();
    for _ in 0..count {
        let at = random.below(flipped.len());
        flipped[at] ^= (random.next_u64() as u8) | 1;
    }
    flipped
}

// ---------------------------------------------------------------------------
// The corpus.

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Format {
    Csv,
    Xyz,
    Mcap,
    Hdf5,
}

impl Format {
    fn extension(self) -> &'static str {
        match self {
            Format::Csv => "csv",
            Format::Xyz => "xyz",
            Format::Mcap => "mcap",
            Format::Hdf5 => "h5",
        }
    }
}

/// How many data rows a successful `compensate` or `convert` must write.
#[derive(Debug, Clone, Copy)]
enum Rows {
    Exact(usize),
    AtLeast(usize),
    /// As many as the library's reader returns (damaged binary files, whose
    /// row count cannot be told from the bytes); when that is fewer than
    /// the `intact` file's, the run must pass on the reader's warnings.
    AsTheReaderSees {
        intact: usize,
    },
}

/// A row to look at in the compensated output: where a sample was
/// poisoned or time went wrong.
#[derive(Debug, Clone)]
struct Watch {
    /// Times (s, the file's `tt`) of the row or rows concerned.
    times_s: Vec<f64>,
    /// What was done there, for the report.
    what: String,
    /// The row must carry a non-empty `flags` cell.
    must_flag: bool,
}

struct Variant {
    /// File name, e.g. `csv-mag_1_uc-box-1e308.csv`.
    name: String,
    bytes: Vec<u8>,
    rows: Rows,
    watch: Option<Watch>,
    /// An undamaged file: every command must succeed.
    control: bool,
    /// Each command must finish within this time.
    time_bound: Option<Duration>,
}

impl Variant {
    fn new(format: Format, label: &str, bytes: Vec<u8>, rows: Rows) -> Self {
        Variant {
            name: format!("{}-{label}.{}", format.extension(), format.extension()),
            bytes,
            rows,
            watch: None,
            control: false,
            time_bound: None,
        }
    }

    /// A text variant: its rows are counted from its lines.
    fn text(format: Format, label: &str, bytes: Vec<u8>) -> Self {
        let rows = Rows::Exact(count_text_rows(format, &bytes));
        Variant::new(format, label, bytes, rows)
    }

    fn watching(mut self, times_s: Vec<f64>, what: String, must_flag: bool) -> Self {
        self.watch = Some(Watch {
            times_s,
            what,
            must_flag,
        });
        self
    }
}

/// The good flight, in every format.
struct GoodFlight {
    log: FlightLog,
    time_s: Vec<f64>,
    /// A row inside the calibration box, in a roll manoeuvre.
    in_box: usize,
    /// A row in the middle of the survey line.
    in_survey: usize,
    csv: String,
    xyz: String,
    mcap: Vec<u8>,
    h5: Vec<u8>,
    /// A folder for writing poisoned binary variants.
    scratch: PathBuf,
}

fn good_flight(folder: &Path) -> GoodFlight {
    let spec = SampleFlightSpec {
        line_count: 1,
        line_duration_s: 60.0,
        ..SampleFlightSpec::default()
    };
    let flight = generate(&spec, SEED);
    let csv_path = folder.join("good.csv");
    write(&flight, &csv_path, &folder.join("good.windows.json")).unwrap();
    let log = read_flight_log(&csv_path, &Settings::default().ingest).unwrap();
    let written = |extension: &str| {
        let path = folder.join(format!("good.{extension}"));
        write_flight_log(&log, &path).unwrap();
        std::fs::read(path).unwrap()
    };
    let roll = &flight.manoeuvres[1];
    let roll_middle_s = 0.5 * (roll.t_start + roll.t_end);
    let time_s = flight.time_s.clone();
    let in_box = nearest_row(&time_s, roll_middle_s);
    let in_survey = time_s.len() - 300;
    assert!(time_s[in_box] > flight.calibration_box.0 && time_s[in_box] < flight.calibration_box.1);
    assert!(time_s[in_survey] > flight.calibration_box.1);
    let scratch = folder.join("scratch");
    std::fs::create_dir_all(&scratch).unwrap();
    GoodFlight {
        xyz: String::from_utf8(written("xyz")).unwrap(),
        mcap: written("mcap"),
        h5: written("h5"),
        csv: std::fs::read_to_string(&csv_path).unwrap(),
        log,
        time_s,
        in_box,
        in_survey,
        scratch,
    }
}

fn nearest_row(time_s: &[f64], t: f64) -> usize {
    (0..time_s.len())
        .min_by(|&a, &b| (time_s[a] - t).abs().total_cmp(&(time_s[b] - t).abs()))
        .unwrap()
}

/// A poisoned sample: `text` in a text file, `value` in a binary one.
struct Poison {
    column: &'static str,
    in_box: bool,
    label: &'static str,
    text: &'static str,
    value: f64,
}

fn poisons() -> Vec<Poison> {
    let values: [(&str, &str, f64); 6] = [
        ("1e308", "1e308", 1e308),
        ("minus-1e308", "-1e308", -1e308),
        ("subnormal", "4.9e-324", f64::from_bits(1)),
        ("zero", "0", 0.0),
        ("nan", "NaN", f64::NAN),
        ("empty", "", f64::NAN),
    ];
    let mut poisons = Vec::new();
    let mut add = |column, in_box, labels: &[&str]| {
        for &(label, text, value) in values.iter().filter(|v| labels.contains(&v.0)) {
            poisons.push(Poison {
                column,
                in_box,
                label,
                text,
                value,
            });
        }
    };
    let all = ["1e308", "minus-1e308", "subnormal", "zero", "nan", "empty"];
    add("mag_1_uc", true, &all);
    add("mag_1_uc", false, &all);
    add("flux_a_x", true, &["1e308", "zero", "nan"]);
    add("flux_a_x", false, &["1e308", "subnormal", "zero", "nan"]);
    add("ins_roll", true, &["zero", "nan"]);
    add("ins_roll", false, &["zero", "1e308"]);
    poisons
}

impl Poison {
    fn label(&self) -> String {
        let place = if self.in_box { "box" } else { "survey" };
        format!("{}-{place}-{}", self.column, self.label)
    }

    fn row(&self, good: &GoodFlight) -> usize {
        if self.in_box {
            good.in_box
        } else {
            good.in_survey
        }
    }

    /// Magnetometer and fluxgate samples must be flagged; an attitude angle
    /// is only checked for spreading.
    fn must_flag(&self) -> bool {
        self.column.starts_with("mag_") || self.column.starts_with("flux_")
    }
}

// ---------------------------------------------------------------------------
// Text variants (CSV and XYZ).

/// A text flight as lines, to edit cell by cell.
#[derive(Clone)]
struct TextDoc {
    format: Format,
    lines: Vec<String>,
}

impl TextDoc {
    fn parse(format: Format, text: &str) -> Self {
        let lines = text.lines().map(String::from).collect();
        TextDoc { format, lines }
    }

    fn header(&self) -> Vec<String> {
        match self.format {
            Format::Csv => self.lines[0].split(',').map(String::from).collect(),
            _ => {
                let line = self
                    .lines
                    .iter()
                    .find(|l| l.starts_with('/') && l.split_whitespace().any(|w| w == "tt"))
                    .unwrap();
                line.split_whitespace().skip(1).map(String::from).collect()
            }
        }
    }

    fn column(&self, name: &str) -> usize {
        self.header().iter().position(|c| c == name).unwrap()
    }

    /// Line indices of the data rows, in order.
    fn data_lines(&self) -> Vec<usize> {
        let skip = usize::from(self.format == Format::Csv);
        (skip..self.lines.len())
            .filter(|&i| is_data_line(self.format, &self.lines[i]))
            .collect()
    }

    fn set_cell(&mut self, row: usize, column: usize, value: &str) {
        let line = self.data_lines()[row];
        self.set_line_cell(line, column, value);
    }

    fn set_line_cell(&mut self, line: usize, column: usize, value: &str) {
        let (separator, mut cells): (&str, Vec<String>) = match self.format {
            Format::Csv => (",", self.lines[line].split(',').map(String::from).collect()),
            _ => (" ", self.lines[line].split_whitespace().map(String::from).collect()),
        };
        cells[column] = value.to_string();
        self.lines[line] = cells.join(separator);
    }

    fn joined(&self, line_end: &str) -> Vec<u8> {
        let mut text = self.lines.join(line_end);
        text.push_str(line_end);
        text.into_bytes()
    }

    fn bytes(&self) -> Vec<u8> {
        self.joined("\n")
    }
}

fn is_data_line(format: Format, line: &str) -> bool {
    let line = line.trim();
    match format {
        Format::Csv => !line.is_empty(),
        _ => {
            let first = line.split_whitespace().next().unwrap_or("");
            !line.is_empty()
                && !line.starts_with('/')
                && !line.starts_with('[')
                && !first.eq_ignore_ascii_case("line")
                && !first.eq_ignore_ascii_case("tie")
        }
    }
}

/// Data rows of a text file as a person counts them: non-blank lines after
/// the header (CSV) or that are not comments or line headers (XYZ), with
/// `\n`, `\r\n` or `\r` ending a line. A truncated last row counts.
fn count_text_rows(format: Format, bytes: &[u8]) -> usize {
    let text = String::from_utf8_lossy(bytes);
    let text = text
        .trim_start_matches('\u{feff}')
        .replace("\r\n", "\n")
        .replace('\r', "\n");
    let mut lines = text.split('\n').filter(|l| !l.trim().is_empty());
    if format == Format::Csv {
        lines.next();
    }
    lines.filter(|l| is_data_line(format, l)).count()
}

fn truncations(bytes: &[u8], middle_of_row: Option<usize>) -> Vec<(String, Vec<u8>)> {
    let mut cuts: Vec<(String, usize)> = [10, 50, 99]
        .iter()
        .map(|percent| (format!("truncated-{percent}pct"), bytes.len() * percent / 100))
        .collect();
    match middle_of_row {
        Some(at) => cuts.push(("truncated-mid-row".into(), at)),
        None => cuts.push(("truncated-last-byte".into(), bytes.len() - 1)),
    }
    cuts.into_iter()
        .map(|(label, at)| (label, bytes[..at].to_vec()))
        .collect()
}

fn flips(bytes: &[u8], random: &mut SplitMix64) -> Vec<(String, Vec<u8>)> {
    let mut variants = Vec::new();
    for i in 0..SINGLE_FLIPS {
        variants.push((format!("flip-1x-{i}"), flip_bytes(bytes, 1, random)));
    }
    for i in 0..MULTI_FLIPS {
        variants.push((
            format!("flip-{FLIPS_PER_MULTI}x-{i}"),
            flip_bytes(bytes, FLIPS_PER_MULTI, random),
        ));
    }
    variants
}

fn text_variants(format: Format, text: &str, good: &GoodFlight, random: &mut SplitMix64) -> Vec<Variant> {
    let doc = TextDoc::parse(format, text);
    let bytes = doc.bytes();
    let data = doc.data_lines();
    let mut variants = vec![Variant::text(format, "good", bytes.clone())];
    variants[0].control = true;
    let middle_line = data[data.len() * 7 / 10];
    let middle_of_row =
        doc.lines[..middle_line].iter().map(|l| l.len() + 1).sum::<usize>() + doc.lines[middle_line].len() / 2;
    for (label, cut) in truncations(&bytes, Some(middle_of_row)) {
        variants.push(Variant::text(format, &label, cut));
    }
    for (label, flipped) in flips(&bytes, random) {
        variants.push(Variant::text(format, &label, flipped));
    }
    variants.extend(text_shapes(format, &doc));
    variants.extend(time_faults(format, &doc, good));
    variants.extend(huge_cells(format, &doc, good));
    for poison in poisons() {
        let mut edited = doc.clone();
        let row = poison.row(good);
        let text = match (format, poison.text) {
            (Format::Xyz, "") => "*",
            (_, text) => text,
        };
        edited.set_cell(row, doc.column(poison.column), text);
        let what = format!("{} = {text:?} at row {row}", poison.column);
        variants.push(Variant::text(format, &poison.label(), edited.bytes()).watching(
            vec![good.time_s[row]],
            what,
            poison.must_flag(),
        ));
    }
    variants
}

/// Empty, header-only, one-row, BOM and line-end variants, equal times.
fn text_shapes(format: Format, doc: &TextDoc) -> Vec<Variant> {
    let data = doc.data_lines();
    let header_only = TextDoc {
        format,
        lines: doc.lines[..data[0]].to_vec(),
    };
    let one_row = TextDoc {
        format,
        lines: doc.lines[..=data[0]].to_vec(),
    };
    let mut equal_times = doc.clone();
    let first_time = good_cell(doc, 0, 0);
    for &line in &data {
        equal_times.set_line_cell(line, 0, &first_time);
    }
    let mut bom = "\u{feff}".as_bytes().to_vec();
    bom.extend(doc.bytes());
    vec![
        Variant::text(format, "empty", Vec::new()),
        Variant::text(format, "header-only", header_only.bytes()),
        Variant::text(format, "one-row", one_row.bytes()),
        Variant::text(format, "equal-times", equal_times.bytes()),
        Variant::text(format, "bom", bom),
        Variant::text(format, "cr-only", doc.joined("\r")),
        Variant::text(format, "crlf", doc.joined("\r\n")),
    ]
}

fn good_cell(doc: &TextDoc, row: usize, column: usize) -> String {
    let line = &doc.lines[doc.data_lines()[row]];
    match doc.format {
        Format::Csv => line.split(',').nth(column).unwrap().to_string(),
        _ => line.split_whitespace().nth(column).unwrap().to_string(),
    }
}

/// A duplicated row and a backwards time step, both in the survey; a NaN
/// time; a last row 1e9 s or 1e308 s after the one before.
fn time_faults(format: Format, doc: &TextDoc, good: &GoodFlight) -> Vec<Variant> {
    let row = good.in_survey;
    let t = &good.time_s;
    let mut duplicated = doc.clone();
    let line = doc.data_lines()[row];
    duplicated.lines.insert(line + 1, doc.lines[line].clone());
    let mut backwards = doc.clone();
    let stepped_back_s = t[row - 1] - 0.05;
    backwards.set_cell(row, 0, &format!("{stepped_back_s:.2}"));
    let edited_time = |row: usize, text: &str| {
        let mut edited = doc.clone();
        edited.set_cell(row, 0, text);
        edited.bytes()
    };
    let last = t.len() - 1;
    vec![
        Variant::text(format, "time-nan", edited_time(row, "NaN")),
        Variant::text(
            format,
            "time-far-last",
            edited_time(last, &format!("{:.1}", t[last] + FAR_JUMP_S)),
        ),
        Variant::text(format, "time-1e308-last", edited_time(last, "1e308")),
        Variant::text(format, "duplicate-row", duplicated.bytes()).watching(
            vec![t[row]],
            format!("row {row} (t = {}) written twice", t[row]),
            true,
        ),
        Variant::text(format, "backwards-time", backwards.bytes()).watching(
            vec![stepped_back_s],
            format!(
                "row {row}: t = {stepped_back_s:.2}, before row {} (t = {})",
                row - 1,
                t[row - 1]
            ),
            true,
        ),
    ]
}

/// A 1.5 MB text cell in an auxiliary column and a 1.5 MB number in a
/// magnetometer column.
fn huge_cells(format: Format, doc: &TextDoc, good: &GoodFlight) -> Vec<Variant> {
    let row = good.in_survey;
    let mut text_cell = doc.clone();
    text_cell.set_cell(row, doc.column("vol_bus"), &"A".repeat(HUGE_CELL_BYTES));
    let mut number_cell = doc.clone();
    number_cell.set_cell(
        row,
        doc.column("mag_1_uc"),
        &format!("5{}", "0".repeat(HUGE_CELL_BYTES)),
    );
    vec![
        Variant::text(format, "huge-text-cell", text_cell.bytes()),
        Variant::text(format, "huge-number-cell", number_cell.bytes()).watching(
            vec![good.time_s[row]],
            format!("mag_1_uc = 5e{HUGE_CELL_BYTES} (a {HUGE_CELL_BYTES}-byte cell) at row {row}"),
            true,
        ),
    ]
}

/// A CSV header of [`WIDE_COLUMNS`] extra auxiliary columns over the first
/// [`WIDE_ROWS`] rows of the flight.
fn wide_header(good: &GoodFlight) -> Variant {
    let doc = TextDoc::parse(Format::Csv, &good.csv);
    let mut text = doc.lines[0].clone();
    for i in 0..WIDE_COLUMNS {
        text.push_str(&format!(",aux_{i}"));
    }
    text.push('\n');
    let cells = ",0".repeat(WIDE_COLUMNS);
    for line in &doc.lines[1..=WIDE_ROWS] {
        text.push_str(line);
        text.push_str(&cells);
        text.push('\n');
    }
    let mut variant = Variant::text(
        Format::Csv,
        &format!("header-{WIDE_COLUMNS}-columns"),
        text.into_bytes(),
    );
    variant.time_bound = Some(WIDE_TIME_BOUND);
    variant
}

// ---------------------------------------------------------------------------
// Binary variants (MCAP and HDF5).

fn binary_variants(format: Format, bytes: &[u8], good: &GoodFlight, random: &mut SplitMix64) -> Vec<Variant> {
    let n = good.time_s.len();
    let mut variants = vec![Variant::new(format, "good", bytes.to_vec(), Rows::Exact(n))];
    variants[0].control = true;
    for (label, cut) in truncations(bytes, None) {
        variants.push(Variant::new(format, &label, cut, Rows::AsTheReaderSees { intact: n }));
    }
    for (label, flipped) in flips(bytes, random) {
        variants.push(Variant::new(
            format,
            &label,
            flipped,
            Rows::AsTheReaderSees { intact: n },
        ));
    }
    variants.push(Variant::new(format, "empty", Vec::new(), Rows::Exact(0)));
    variants.extend(short_logs(format, good));
    variants.extend(match format {
        Format::Mcap => mcap_time_faults(bytes, good),
        _ => h5_time_faults(bytes, good),
    });
    for poison in poisons().into_iter().filter(|p| p.label != "empty") {
        let row = poison.row(good);
        let mut values = good.log.channel(poison.column).unwrap().values.clone();
        values[row] = poison.value;
        let log = good.log.with_values(poison.column, values).unwrap();
        let bytes = written_bytes(&log, good, format, &poison.label());
        let what = format!("{} = {:e} at row {row}", poison.column, poison.value);
        variants.push(Variant::new(format, &poison.label(), bytes, Rows::Exact(n)).watching(
            vec![good.time_s[row]],
            what,
            poison.must_flag(),
        ));
    }
    variants
}

fn written_bytes(log: &FlightLog, good: &GoodFlight, format: Format, label: &str) -> Vec<u8> {
    let path = good.scratch.join(format!("{label}.{}", format.extension()));
    write_flight_log(log, &path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    std::fs::remove_file(&path).unwrap();
    bytes
}

/// A one-row flight, and a zero-row one when the library builds it.
fn short_logs(format: Format, good: &GoodFlight) -> Vec<Variant> {
    let mut variants = Vec::new();
    for rows in [1, 0] {
        let channels: Vec<Channel> = good
            .log
            .channels()
            .iter()
            .map(|c| Channel {
                name: c.name.clone(),
                role: c.role.clone(),
                values: c.values[..rows].to_vec(),
            })
            .collect();
        let Ok(log) = FlightLog::new("short", good.log.time_column(), good.time_s[..rows].to_vec(), channels) else {
            continue;
        };
        let label = if rows == 1 { "one-row" } else { "zero-rows" };
        let path = good.scratch.join(format!("{label}.{}", format.extension()));
        if write_flight_log(&log, &path).is_ok() {
            let bytes = std::fs::read(&path).unwrap();
            variants.push(Variant::new(format, label, bytes, Rows::Exact(rows)));
        }
    }
    variants
}

/// Duplicated, backwards and all-equal `tt` in the HDF5 file, patched in
/// place in its contiguous `tt` dataset.
fn h5_time_faults(bytes: &[u8], good: &GoodFlight) -> Vec<Variant> {
    let t = &good.time_s;
    let needle: Vec<u8> = t[..3].iter().flat_map(|v| v.to_le_bytes()).collect();
    let start = bytes
        .windows(needle.len())
        .position(|w| w == needle)
        .expect("the tt dataset in the HDF5 file");
    let patched = |edits: &[(usize, f64)]| {
        let mut copy = bytes.to_vec();
        for &(row, value) in edits {
            copy[start + 8 * row..start + 8 * row + 8].copy_from_slice(&value.to_le_bytes());
        }
        copy
    };
    let row = good.in_survey;
    let n = t.len();
    let stepped_back_s = t[row - 1] - 0.05;
    let equal: Vec<(usize, f64)> = (0..n).map(|i| (i, t[0])).collect();
    vec![
        Variant::new(
            Format::Hdf5,
            "duplicate-time",
            patched(&[(row, t[row - 1])]),
            Rows::Exact(n),
        )
        .watching(
            vec![t[row - 1]],
            format!("tt[{row}] = tt[{}] = {}", row - 1, t[row - 1]),
            true,
        ),
        Variant::new(
            Format::Hdf5,
            "backwards-time",
            patched(&[(row, stepped_back_s)]),
            Rows::Exact(n),
        )
        .watching(
            vec![stepped_back_s],
            format!(
                "tt[{row}] = {stepped_back_s:.2}, before tt[{}] = {}",
                row - 1,
                t[row - 1]
            ),
            true,
        ),
        Variant::new(Format::Hdf5, "equal-times", patched(&equal), Rows::Exact(n)),
        Variant::new(Format::Hdf5, "time-nan", patched(&[(row, f64::NAN)]), Rows::Exact(n)),
        Variant::new(
            Format::Hdf5,
            "time-far-last",
            patched(&[(n - 1, t[n - 1] + FAR_JUMP_S)]),
            Rows::Exact(n),
        ),
        Variant::new(
            Format::Hdf5,
            "time-1e308-last",
            patched(&[(n - 1, 1e308)]),
            Rows::Exact(n),
        ),
    ]
}

/// The good MCAP file's messages, rewritten after `edit`.
fn rewrite_mcap(bytes: &[u8], edit: impl FnOnce(&mut Vec<mcap::Message<'_>>)) -> Vec<u8> {
    let mut messages: Vec<mcap::Message<'_>> = mcap::MessageStream::new(bytes).unwrap().map(Result::unwrap).collect();
    edit(&mut messages);
    let mut writer = mcap::Writer::new(Cursor::new(Vec::new())).unwrap();
    for message in &messages {
        writer.write(message).unwrap();
    }
    writer.finish().unwrap();
    writer.into_inner().into_inner()
}

/// Indices of the `/mag/1/scalar` messages in time order.
fn scalar_messages(messages: &[mcap::Message<'_>]) -> Vec<usize> {
    let mut indices: Vec<usize> = (0..messages.len())
        .filter(|&i| messages[i].channel.topic == "/mag/1/scalar")
        .collect();
    indices.sort_by_key(|&i| messages[i].log_time);
    indices
}

/// A `/mag/1/scalar` message repeated, one moved back onto an earlier
/// message's `log_time`, and every message at one `log_time`.
fn mcap_time_faults(bytes: &[u8], good: &GoodFlight) -> Vec<Variant> {
    let t = &good.time_s;
    let n = t.len();
    let row = good.in_survey;
    let duplicated = rewrite_mcap(bytes, |messages| {
        let at = scalar_messages(messages)[row];
        let copy = messages[at].clone();
        messages.insert(at + 1, copy);
    });
    let backwards = rewrite_mcap(bytes, |messages| {
        let scalar = scalar_messages(messages);
        messages[scalar[row]].log_time = messages[scalar[row - 2]].log_time;
    });
    let equal = rewrite_mcap(bytes, |messages| {
        let first = messages.iter().map(|m| m.log_time).min().unwrap();
        for message in messages.iter_mut() {
            message.log_time = first;
        }
    });
    let far_last = rewrite_mcap(bytes, |messages| {
        let last = messages.iter().map(|m| m.log_time).max().unwrap();
        for message in messages.iter_mut().filter(|m| m.log_time == last) {
            message.log_time += (FAR_JUMP_S * 1e9) as u64;
        }
    });
    vec![
        Variant::new(Format::Mcap, "time-far-last", far_last, Rows::Exact(n)),
        Variant::new(Format::Mcap, "duplicate-message", duplicated, Rows::AtLeast(n)).watching(
            vec![t[row]],
            format!("/mag/1/scalar message of row {row} (t = {}) written twice", t[row]),
            true,
        ),
        Variant::new(Format::Mcap, "backwards-time", backwards, Rows::AtLeast(n)).watching(
            vec![t[row - 2]],
            format!(
                "/mag/1/scalar message of row {row} moved back onto row {}'s log_time (t = {})",
                row - 2,
                t[row - 2]
            ),
            true,
        ),
        Variant::new(Format::Mcap, "equal-times", equal, Rows::AtLeast(n)),
    ]
}

fn corpus(good: &GoodFlight) -> Vec<Variant> {
    let mut random = SplitMix64(SEED);
    let mut variants = text_variants(Format::Csv, &good.csv, good, &mut random);
    variants.push(wide_header(good));
    variants.extend(text_variants(Format::Xyz, &good.xyz, good, &mut random));
    variants.extend(binary_variants(Format::Mcap, &good.mcap, good, &mut random));
    variants.extend(binary_variants(Format::Hdf5, &good.h5, good, &mut random));
    variants
}

// ---------------------------------------------------------------------------
// Running magcomp.

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Kind {
    Panic,
    Hang,
    Slow,
    UnnamedFile,
    NotOneParagraph,
    LostRows,
    UnflaggedRow,
    SpreadIntoNeighbours,
    BadOutput,
    ControlFailed,
}

struct Violation {
    kind: Kind,
    variant: String,
    command: String,
    detail: String,
    message: String,
}

impl std::fmt::Display for Violation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "[{:?}] {} / {}: {}",
            self.kind, self.variant, self.command, self.detail
        )?;
        if !self.message.is_empty() {
            write!(f, "\n      message: {}", self.message)?;
        }
        Ok(())
    }
}

struct Outcome {
    /// `None` when the run was killed at [`RUN_TIME_LIMIT`].
    status: Option<ExitStatus>,
    stdout: String,
    stderr: String,
    elapsed: Duration,
}

struct Subcommand {
    name: &'static str,
    output: &'static str,
    extra: &'static [&'static str],
}

const SUBCOMMANDS: [Subcommand; 4] = [
    Subcommand {
        name: "detect",
        output: "D.json",
        extra: &[],
    },
    Subcommand {
        name: "compensate",
        output: "O.csv",
        extra: &["--plain"],
    },
    Subcommand {
        name: "diagnose",
        output: "G.json",
        extra: &[],
    },
    Subcommand {
        name: "convert",
        output: "C.csv",
        extra: &[],
    },
];

/// A copy of the magcomp binary cargo built for this test, so that every
/// run of the corpus uses one build even when another build replaces
/// `target/*/magcomp` meanwhile.
fn frozen_binary(root: &Path) -> PathBuf {
    let copy = root.join("magcomp-under-test");
    std::fs::copy(env!("CARGO_BIN_EXE_magcomp"), &copy).unwrap();
    copy
}

/// Runs `binary` in `folder`, its output going to files there; a run
/// still going after [`RUN_TIME_LIMIT`] is killed.
fn run_magcomp(binary: &Path, args: &[OsString], folder: &Path) -> Outcome {
    let stderr_path = folder.join("stderr.txt");
    let start = Instant::now();
    let mut child = Command::new(binary)
        .args(args)
        .current_dir(folder)
        .stdin(Stdio::null())
        .stdout(File::create(folder.join("stdout.txt")).unwrap())
        .stderr(File::create(&stderr_path).unwrap())
        .spawn()
        .unwrap();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break Some(status);
        }
        if start.elapsed() > RUN_TIME_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let elapsed = start.elapsed();
    let text = |path: PathBuf| String::from_utf8_lossy(&std::fs::read(path).unwrap_or_default()).into_owned();
    Outcome {
        status,
        stdout: text(folder.join("stdout.txt")),
        stderr: text(stderr_path),
        elapsed,
    }
}

fn excerpt(text: &str) -> String {
    text.trim().chars().take(300).collect::<String>().replace('\n', "⏎")
}

#[cfg(unix)]
fn killed_by_signal(status: &ExitStatus) -> Option<i32> {
    use std::os::unix::process::ExitStatusExt;
    status.signal()
}

#[cfg(not(unix))]
fn killed_by_signal(_status: &ExitStatus) -> Option<i32> {
    None
}

/// What a successful `compensate` or `convert` must write.
struct Expectation {
    rows: Option<Rows>,
    /// Rows the reader left out of a damaged file: `(read, intact, the
    /// reader's warnings)`. A run that writes the shortened flight must say so.
    left_out: Option<(usize, usize, Vec<String>)>,
}

/// The expectation for `variant`, asking the library's reader when the
/// bytes cannot tell, and any panic or hang of that reader.
fn expectation(variant: &Variant, input: &Path) -> (Expectation, Option<(Kind, String)>) {
    let Rows::AsTheReaderSees { intact } = variant.rows else {
        return (
            Expectation {
                rows: Some(variant.rows),
                left_out: None,
            },
            None,
        );
    };
    let mut expectation = Expectation {
        rows: None,
        left_out: None,
    };
    match read_in_process(input) {
        Ok(Some((read, warnings))) => {
            expectation.rows = Some(Rows::Exact(read));
            expectation.left_out = (read < intact).then_some((read, intact, warnings));
            (expectation, None)
        }
        Ok(None) => (expectation, None),
        Err(problem) => (expectation, Some(problem)),
    }
}

/// Rows read and the reader's warnings (what reading lost).
type ReaderView = (usize, Vec<String>);

/// `read_flight_log(input)`'s row count and warnings (what reading lost),
/// in a thread of its own so that a panic or a hang in the library is
/// reported instead of ending the test; `None` when the reader refuses the
/// file.
fn read_in_process(input: &Path) -> Result<Option<ReaderView>, (Kind, String)> {
    let (sender, receiver) = mpsc::channel();
    let path = input.to_path_buf();
    std::thread::spawn(move || {
        let read = read_flight_log(&path, &Settings::default().ingest).ok().map(|log| {
            let warnings = (log.alignment())
                .map(|a| a.warnings.iter().map(ToString::to_string).collect())
                .unwrap_or_default();
            (log.len(), warnings)
        });
        let _ = sender.send(read);
    });
    match receiver.recv_timeout(RUN_TIME_LIMIT) {
        Ok(read) => Ok(read),
        Err(mpsc::RecvTimeoutError::Timeout) => Err((Kind::Hang, "read_flight_log did not return".into())),
        Err(mpsc::RecvTimeoutError::Disconnected) => Err((Kind::Panic, "read_flight_log panicked".into())),
    }
}

/// One cell of the outcome table: `ok`, `ok:<rows>` (rows of an output
/// CSV), `err`, `HANG` or `SIGNAL`, with the time taken when 2 s or more.
fn outcome_cell(outcome: &Outcome, out: &Path) -> String {
    let cell = outcome_word(outcome, out);
    match outcome.elapsed.as_secs_f64() {
        seconds if seconds >= 2.0 => format!("{cell}({seconds:.0}s)"),
        _ => cell,
    }
}

fn outcome_word(outcome: &Outcome, out: &Path) -> String {
    match outcome.status {
        None => "HANG".into(),
        Some(status) if killed_by_signal(&status).is_some() => "SIGNAL".into(),
        Some(status) if !status.success() => "err".into(),
        Some(_) if out.extension().is_some_and(|e| e == "csv") => {
            let lines = std::fs::read(out).map_or(0, |b| b.iter().filter(|&&c| c == b'\n').count());
            format!("ok:{}", lines.saturating_sub(1))
        }
        Some(_) => "ok".into(),
    }
}

/// Runs every subcommand on `variant` and returns what broke the contract,
/// and a line of the outcome table.
fn examine(binary: &Path, variant: &Variant, root: &Path) -> (Vec<Violation>, String) {
    let folder = root.join(&variant.name).with_extension("d");
    std::fs::create_dir_all(&folder).unwrap();
    let input = folder.join(&variant.name);
    std::fs::write(&input, &variant.bytes).unwrap();
    let mut violations = Vec::new();
    let mut report = |kind, command: &str, detail: String, message: &str| {
        violations.push(Violation {
            kind,
            variant: variant.name.clone(),
            command: command.to_string(),
            detail,
            message: excerpt(message),
        })
    };
    let (expectation, problem) = expectation(variant, &input);
    if let Some((kind, detail)) = problem {
        report(kind, "read_flight_log (library)", detail, "");
    }
    let expected = match expectation.rows {
        Some(Rows::Exact(n)) => format!("{n}"),
        Some(Rows::AtLeast(n)) => format!(">={n}"),
        _ => "?".into(),
    };
    let mut line = format!("{:<40} rows {expected:>6}:", variant.name);
    for subcommand in &SUBCOMMANDS {
        // A poisoned sample reaches the diagnosis through the same screened
        // flight log whatever the format, and a diagnosis is the slowest
        // command: it runs on the CSV copies of those variants only.
        if subcommand.name == "diagnose" && variant.watch.is_some() && !variant.name.starts_with("csv-") {
            line.push_str(&format!(" {} {:<9}", subcommand.name, "(csv)"));
            continue;
        }
        let run_folder = folder.join(subcommand.name);
        std::fs::create_dir_all(&run_folder).unwrap();
        let out = run_folder.join(subcommand.output);
        let mut args: Vec<OsString> = vec![
            subcommand.name.into(),
            input.clone().into(),
            "--out".into(),
            out.clone().into(),
        ];
        args.extend(subcommand.extra.iter().map(OsString::from));
        let outcome = run_magcomp(binary, &args, &run_folder);
        line.push_str(&format!(" {} {:<9}", subcommand.name, outcome_cell(&outcome, &out)));
        for (kind, detail) in check_run(variant, subcommand, &outcome, &out, &expectation) {
            report(kind, subcommand.name, detail, &outcome.stderr);
        }
        let _ = std::fs::remove_dir_all(&run_folder);
    }
    if violations.is_empty() && std::env::var_os("BAD_INPUTS_KEEP_ALL").is_none() {
        let _ = std::fs::remove_dir_all(&folder);
    } else {
        keep_for_reproduction(&input);
    }
    (violations, line)
}

fn kept_folder() -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("bad_inputs")
}

fn keep_for_reproduction(input: &Path) {
    let _ = std::fs::create_dir_all(kept_folder());
    let kept = kept_folder().join(input.file_name().unwrap());
    // A rename fails across file systems (the temporary folder may be one).
    let _ = std::fs::rename(input, &kept).or_else(|_| std::fs::copy(input, &kept).map(drop));
    let _ = std::fs::remove_dir_all(input.parent().unwrap());
}

// ---------------------------------------------------------------------------
// Checks.

fn check_run(
    variant: &Variant,
    subcommand: &Subcommand,
    outcome: &Outcome,
    out: &Path,
    expectation: &Expectation,
) -> Vec<(Kind, String)> {
    let mut problems = Vec::new();
    if let Some(bound) = variant.time_bound {
        if outcome.elapsed > bound {
            problems.push((
                Kind::Slow,
                format!(
                    "took {:.1} s, more than the {} s bound",
                    outcome.elapsed.as_secs_f64(),
                    bound.as_secs()
                ),
            ));
        }
    }
    let Some(status) = outcome.status else {
        problems.push((
            Kind::Hang,
            format!("still running after {} s; killed", RUN_TIME_LIMIT.as_secs()),
        ));
        return problems;
    };
    if let Some(signal) = killed_by_signal(&status) {
        problems.push((Kind::Panic, format!("killed by signal {signal}")));
    }
    if outcome.stderr.contains("panicked") || status.code() == Some(101) {
        problems.push((Kind::Panic, format!("panicked (exit {status})")));
    }
    if !status.success() {
        if variant.control {
            problems.push((Kind::ControlFailed, "the undamaged file failed".into()));
        }
        problems.extend(check_error_paragraph(&variant.name, &outcome.stderr));
        return problems;
    }
    match subcommand.name {
        "detect" | "diagnose" => problems.extend(check_json(out)),
        _ => {
            problems.extend(check_table(variant, subcommand, out, expectation.rows));
            problems.extend(check_left_out_said(outcome, expectation));
        }
    }
    problems
}

/// A failure is one paragraph, starting `magcomp: error:`, naming the file.
fn check_error_paragraph(name: &str, stderr: &str) -> Vec<(Kind, String)> {
    let mut problems = Vec::new();
    let trimmed = stderr.trim();
    if !trimmed.starts_with("magcomp: error:") {
        problems.push((
            Kind::NotOneParagraph,
            "stderr does not start with 'magcomp: error:'".into(),
        ));
    }
    if trimmed.contains("\n\n") {
        problems.push((Kind::NotOneParagraph, "the error is more than one paragraph".into()));
    }
    if !stderr.contains(name) {
        problems.push((Kind::UnnamedFile, format!("the error does not name '{name}'")));
    }
    problems
}

fn check_json(out: &Path) -> Vec<(Kind, String)> {
    let text = match std::fs::read_to_string(out) {
        Ok(text) => text,
        Err(error) => return vec![(Kind::BadOutput, format!("exit 0 but {}: {error}", out.display()))],
    };
    match serde_json::from_str::<serde_json::Value>(&text) {
        Ok(_) => Vec::new(),
        Err(error) => vec![(Kind::BadOutput, format!("exit 0 but the JSON does not parse: {error}"))],
    }
}

fn check_table(variant: &Variant, subcommand: &Subcommand, out: &Path, rows: Option<Rows>) -> Vec<(Kind, String)> {
    let table = match Table::read(out) {
        Ok(table) => table,
        Err(error) => return vec![(Kind::BadOutput, format!("exit 0 but {}: {error}", out.display()))],
    };
    let mut problems = Vec::new();
    let written = table.times.len();
    let row_problem = match rows {
        Some(Rows::Exact(expected)) if written != expected => {
            Some(format!("{written} data rows written, the input has {expected}"))
        }
        Some(Rows::AtLeast(expected)) if written < expected => Some(format!(
            "{written} data rows written, the input has at least {expected}"
        )),
        _ => None,
    };
    problems.extend(row_problem.map(|detail| (Kind::LostRows, detail)));
    if let (Some(watch), "compensate") = (&variant.watch, subcommand.name) {
        problems.extend(check_watch(watch, &table));
    }
    problems
}

/// Rows the reader left out of a damaged file are lost unless the run
/// passes on the reader's warnings about them.
fn check_left_out_said(outcome: &Outcome, expectation: &Expectation) -> Option<(Kind, String)> {
    let (read, intact, warnings) = expectation.left_out.as_ref()?;
    let said = format!("{}{}", outcome.stdout, outcome.stderr);
    let detail = match warnings.iter().find(|warning| !said.contains(warning.as_str())) {
        _ if warnings.is_empty() => "the reader gives no warning about the rest".to_string(),
        Some(unsaid) => format!("the run does not pass on the reader's warning '{unsaid}'"),
        None => return None,
    };
    Some((
        Kind::LostRows,
        format!("{read} of the intact file's {intact} rows written; {detail}"),
    ))
}

/// The parts of an output CSV the checks need.
struct Table {
    times: Vec<Option<f64>>,
    flags: Option<Vec<String>>,
    /// Compensated columns (`*_c`, `*_c_magcomp`); `None` where empty or not a number.
    compensated: Vec<(String, Vec<Option<f64>>)>,
}

impl Table {
    fn read(path: &Path) -> Result<Table, String> {
        let mut reader = csv::ReaderBuilder::new()
            .flexible(true)
            .from_path(path)
            .map_err(|e| e.to_string())?;
        let header: Vec<String> = reader
            .byte_headers()
            .map_err(|e| e.to_string())?
            .iter()
            .map(|c| String::from_utf8_lossy(c).into_owned())
            .collect();
        let time = header.iter().position(|c| c == "tt").unwrap_or(0);
        let flags = header.iter().rposition(|c| c.starts_with("flags"));
        let compensated: Vec<usize> = (0..header.len())
            .filter(|&i| {
                (header[i].ends_with("_c") || header[i].ends_with("_c_magcomp")) && header[i].starts_with("mag_")
            })
            .collect();
        let mut table = Table {
            times: Vec::new(),
            flags: flags.map(|_| Vec::new()),
            compensated: compensated.iter().map(|&i| (header[i].clone(), Vec::new())).collect(),
        };
        for record in reader.byte_records() {
            let record = record.map_err(|e| e.to_string())?;
            let number = |i: usize| {
                record
                    .get(i)
                    .and_then(|c| std::str::from_utf8(c).ok())
                    .and_then(|c| c.trim().parse::<f64>().ok())
            };
            table.times.push(number(time));
            if let (Some(column), Some(cells)) = (flags, table.flags.as_mut()) {
                cells.push(String::from_utf8_lossy(record.get(column).unwrap_or_default()).into_owned());
            }
            for (slot, &column) in compensated.iter().enumerate() {
                table.compensated[slot].1.push(number(column));
            }
        }
        Ok(table)
    }
}

fn median(values: &[Option<f64>]) -> f64 {
    let mut finite: Vec<f64> = values.iter().flatten().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return f64::NAN;
    }
    finite.sort_by(f64::total_cmp);
    finite[finite.len() / 2]
}

/// The watched row is in the output, flagged when it must be, and the
/// compensated values of its neighbours are finite and near their median.
fn check_watch(watch: &Watch, table: &Table) -> Vec<(Kind, String)> {
    let rows: Vec<usize> = (0..table.times.len())
        .filter(|&i| table.times[i].is_some_and(|t| watch.times_s.iter().any(|w| (t - w).abs() < 1e-3)))
        .collect();
    if rows.is_empty() {
        return vec![(
            Kind::LostRows,
            format!("no output row at t = {:?} ({})", watch.times_s, watch.what),
        )];
    }
    let mut problems = Vec::new();
    let flagged = |r: &usize| table.flags.as_ref().is_some_and(|f| !f[*r].trim().is_empty());
    if watch.must_flag && !rows.iter().any(flagged) {
        let written: Vec<String> = table
            .compensated
            .iter()
            .map(|(name, values)| {
                format!(
                    "{name} = {}",
                    values[rows[0]].map_or("empty".into(), |v| format!("{v:e}"))
                )
            })
            .collect();
        problems.push((
            Kind::UnflaggedRow,
            format!(
                "{}: output row {:?} has an empty flags cell ({})",
                watch.what,
                rows,
                written.join(", ")
            ),
        ));
    }
    problems.extend(check_neighbours(watch, table, &rows));
    problems
}

fn check_neighbours(watch: &Watch, table: &Table, rows: &[usize]) -> Option<(Kind, String)> {
    let mut bad = Vec::new();
    for (name, values) in &table.compensated {
        let middle = median(values);
        for &row in rows {
            let lower = row.saturating_sub(NEIGHBOURS);
            let upper = (row + NEIGHBOURS).min(values.len() - 1);
            for neighbour in (lower..=upper).filter(|i| !rows.contains(i)) {
                let sane =
                    values[neighbour].is_some_and(|v| v.is_finite() && (v - middle).abs() < NEIGHBOUR_TOLERANCE_NT);
                if !sane {
                    let shown = values[neighbour].map_or("empty".to_string(), |v| format!("{v:e}"));
                    bad.push(format!(
                        "{name}[{neighbour}] = {shown} ({:+} rows; median {middle:.1})",
                        neighbour as i64 - row as i64
                    ));
                }
            }
        }
    }
    if bad.is_empty() {
        return None;
    }
    Some((
        Kind::SpreadIntoNeighbours,
        format!(
            "{}: {} neighbour values off, e.g. {}",
            watch.what,
            bad.len(),
            bad[..bad.len().min(3)].join("; ")
        ),
    ))
}

// ---------------------------------------------------------------------------

#[test]
fn every_bad_input_is_refused_by_name_or_kept_row_for_row() {
    let started = Instant::now();
    let root = tempfile::tempdir().unwrap();
    let binary = frozen_binary(root.path());
    let good = good_flight(root.path());
    let variants = corpus(&good);
    let _ = std::fs::remove_dir_all(kept_folder());
    let next = AtomicUsize::new(0);
    let violations = Mutex::new(Vec::new());
    let table = Mutex::new(Vec::new());
    std::thread::scope(|scope| {
        for _ in 0..WORKERS {
            scope.spawn(|| loop {
                let index = next.fetch_add(1, Ordering::SeqCst);
                let Some(variant) = variants.get(index) else { break };
                let (found, line) = examine(&binary, variant, root.path());
                violations.lock().unwrap().extend(found);
                table.lock().unwrap().push((index, line));
            });
        }
    });
    let mut table = table.into_inner().unwrap();
    table.sort();
    eprintln!("outcomes (ok:<rows> = data rows of the output CSV):");
    for (_, line) in &table {
        eprintln!("  {line}");
    }
    let mut violations = violations.into_inner().unwrap();
    violations.sort_by(|a, b| (a.kind, &a.variant, &a.command).cmp(&(b.kind, &b.variant, &b.command)));
    eprintln!(
        "bad_inputs: {} variants × {} commands in {:.0} s ({} rows in the good flight); {} violations",
        variants.len(),
        SUBCOMMANDS.len(),
        started.elapsed().as_secs_f64(),
        good.time_s.len(),
        violations.len()
    );
    let listing: Vec<String> = violations.iter().map(|v| format!("  {v}")).collect();
    assert!(
        violations.is_empty(),
        "{} violations of the bad-input contract (inputs kept in {}):\n{}",
        violations.len(),
        kept_folder().display(),
        listing.join("\n")
    );
}

/// A named pipe given wherever magcomp reads a file: as the settings
/// (`--config`), a model (`--apply`), windows (`--windows-file`), the
/// `run` pipeline, a `[[flight]] input` and a flight's `_status.json`.
/// Reading one would block until something wrote to it; each is refused
/// at once, naming the path and saying it is not a regular file.
#[cfg(unix)]
#[test]
fn a_named_pipe_is_refused_wherever_a_file_is_read() {
    let folder = tempfile::tempdir().unwrap();
    let folder = folder.path();
    good_flight(folder);
    let pipe = folder.join("settings.fifo");
    assert!(Command::new("mkfifo").arg(&pipe).status().unwrap().success());
    let binary = Path::new(env!("CARGO_BIN_EXE_magcomp"));
    std::fs::write(
        folder.join("pipe.toml"),
        "[quality]\nexit_zero_on_fail = true\n[[flight]]\ninput = \"settings.fifo\"\n",
    )
    .unwrap();
    let args = |words: &[&str]| words.iter().map(OsString::from).collect::<Vec<_>>();
    let cases = [
        args(&["compensate", "good.csv", "--out", "a.csv", "--config", "settings.fifo"]),
        args(&["compensate", "good.csv", "--out", "b.csv", "--apply", "settings.fifo"]),
        args(&[
            "compensate",
            "good.csv",
            "--out",
            "c.csv",
            "--windows-file",
            "settings.fifo",
        ]),
        args(&["run", "settings.fifo"]),
        args(&["run", "pipe.toml"]),
    ];
    for case in &cases {
        let outcome = run_magcomp(binary, case, folder);
        assert!(outcome.elapsed < WIDE_TIME_BOUND, "{case:?} took {:?}", outcome.elapsed);
        assert!(
            outcome.status.is_some_and(|s| !s.success()),
            "{case:?}: {}",
            outcome.stderr
        );
        assert!(
            outcome.stderr.contains("settings.fifo") && outcome.stderr.contains("not a regular file"),
            "{case:?}: {}",
            outcome.stderr
        );
    }
    // A status file that is a pipe is no status: the flight is done again.
    std::fs::write(folder.join("good.toml"), "[[flight]]\ninput = \"good.csv\"\n").unwrap();
    let first = run_magcomp(binary, &args(&["run", "good.toml", "--exit-zero-on-fail"]), folder);
    assert!(first.status.is_some_and(|s| s.success()), "{}", first.stderr);
    let status = std::fs::read_dir(folder.join("out"))
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .find(|path| path.to_string_lossy().ends_with("_status.json"))
        .expect("run writes a status");
    std::fs::remove_file(&status).unwrap();
    assert!(Command::new("mkfifo").arg(&status).status().unwrap().success());
    let again = run_magcomp(binary, &args(&["run", "good.toml", "--exit-zero-on-fail"]), folder);
    assert!(
        again.elapsed < WIDE_TIME_BOUND,
        "a status pipe took {:?}",
        again.elapsed
    );
    assert!(again.status.is_some(), "a status pipe: killed");
}
