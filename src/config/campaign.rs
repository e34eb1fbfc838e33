//! `[campaign]`: the flights of a season named by glob patterns or by a
//! manifest, besides `[[flight]]` tables.
//!
//! ```toml
//! [campaign]
//! inputs = ["flights/*.csv", "archive/**/*.mcap"]   # glob patterns
//! manifest = "flights.csv"                          # or flights.jsonl
//! ```
//!
//! A manifest is CSV (a header row naming its columns) or JSON lines (one
//! object a line). Its fields are those of a `[[flight]]`: `input` (the
//! only one required), `windows`, `diagnosis`, `plan` (the PLAN_REPORT.json
//! of the plan the flight was flown to), `model` (a MODEL.json saved from a
//! calibration flight, applied to this one: [`crate::pipeline::apply`]),
//! `lines`, `vector`, `channels`, `date`, `aircraft`, the airframe a
//! calibration belongs to (the campaign summary follows each aircraft's
//! coefficients over time), and `calibration`, true for an aircraft's
//! calibration flight, whose model compensates its other flights
//! (`super::calibrations`). In CSV,
//! `windows` is a DETECT.json path or `T0:T1` windows separated by spaces
//! or `;`, and `channels` are names separated by spaces or `;`. In JSON
//! lines, `windows` is a DETECT.json path or a list of `"T0:T1"` strings or
//! `{"t_start": …, "t_end": …}` objects, and `channels` a list of names.
//!
//! Every relative path, in pipeline.toml and in the manifest alike,
//! resolves against the folder of pipeline.toml.
//!
//! The flights are the `[[flight]]` tables, then the manifest's rows, then
//! the files the patterns match (each pattern's matches in path order). A
//! file named twice by tables or manifest rows is an error (its settings
//! would be ambiguous); a file a pattern matches that a table or row
//! already names is taken from the table or row, so a pattern can sweep a
//! folder while a few flights get their own windows. Files in the output
//! folder are outputs of earlier runs, never flights.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::RawFlight;
use crate::calibration::windows::CalibrationWindow;
use crate::error::{Error, Result};

/// `[campaign]` as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RawCampaign {
    /// Glob patterns of flight files, relative to pipeline.toml.
    pub inputs: Vec<String>,
    /// A manifest of flights: CSV, or JSON lines (`.jsonl`, `.ndjson`,
    /// `.json`; a `.json` file may also hold one array of objects).
    pub manifest: Option<PathBuf>,
}

/// The calibration windows of a manifest row as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(
    untagged,
    expecting = "give `windows` as a DETECT.json path, or a list of windows each \"T0:T1\" or {\"t_start\": T0, \"t_end\": T1} (seconds of the flight's time column)"
)]
enum ManifestWindows {
    /// A DETECT.json file.
    File(PathBuf),
    /// Windows given inline.
    List(Vec<ManifestWindow>),
}

/// One inline window: `"T0:T1"` or a window object.
#[derive(Debug, Clone, Deserialize)]
#[serde(
    untagged,
    expecting = "give a window as \"T0:T1\" or {\"t_start\": T0, \"t_end\": T1} (seconds of the flight's time column)"
)]
enum ManifestWindow {
    /// `"T0:T1"`.
    Text(String),
    /// `{"t_start": …, "t_end": …}` with an optional label.
    Window(CalibrationWindow),
}

/// The channels of a manifest row: a list, or names in one string.
#[derive(Debug, Clone, Deserialize)]
#[serde(
    untagged,
    expecting = "give `channels` as a list of scalar channel names, or one string of them separated by spaces, ';' or ','"
)]
enum ManifestChannels {
    /// `["mag_1_uc", "mag_2_uc"]`.
    List(Vec<String>),
    /// `"mag_1_uc mag_2_uc"` (spaces, `;` or `,` between names).
    Text(String),
}

/// One JSON-lines manifest row as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct ManifestRow {
    input: PathBuf,
    #[serde(default)]
    windows: Option<ManifestWindows>,
    #[serde(default)]
    diagnosis: Option<PathBuf>,
    #[serde(default)]
    plan: Option<PathBuf>,
    #[serde(default)]
    model: Option<PathBuf>,
    #[serde(default)]
    vector: Option<String>,
    #[serde(default)]
    channels: Option<ManifestChannels>,
    #[serde(default)]
    date: Option<String>,
    #[serde(default)]
    aircraft: Option<String>,
    #[serde(default)]
    lines: Option<ManifestLines>,
    #[serde(default)]
    calibration: Option<ManifestFlag>,
}

/// A yes-or-no field of a manifest row: a JSON boolean, or in CSV `true`,
/// `yes` or `1` against `false`, `no`, `0` or an empty cell.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
enum ManifestFlag {
    Bool(bool),
    Text(String),
}

/// The calibration lines of a manifest row: numbers, or one string of
/// them (spaces, `;` or `,` between).
#[derive(Debug, Clone, Deserialize)]
#[serde(
    untagged,
    expecting = "give `lines` as a list of calibration line numbers, or one string of them separated by spaces or ';'"
)]
enum ManifestLines {
    /// `[1002.2, 1002.21]`.
    List(Vec<f64>),
    /// `"1002.20 1002.21"`.
    Text(String),
}

/// The columns a CSV manifest may have.
const MANIFEST_COLUMNS: [&str; 11] = [
    "input",
    "windows",
    "diagnosis",
    "plan",
    "model",
    "vector",
    "channels",
    "date",
    "aircraft",
    "lines",
    "calibration",
];

/// The flights `campaign` names, after the `explicit` ones: the manifest's
/// rows, then each pattern's matches not already named; and a note for
/// each pattern that matched files in the output folder, which are left
/// out. Reads the manifest and lists folders; `base` is pipeline.toml's
/// folder.
pub(crate) fn campaign_flights(
    campaign: &RawCampaign,
    explicit: &[RawFlight],
    (base, output_directory): (&Path, &Path),
    source_name: &str,
) -> Result<(Vec<RawFlight>, Vec<crate::messages::Setup>)> {
    // A pattern such as "**/*.csv" also matches the compensated files of
    // earlier runs when the output folder lies below; they are outputs,
    // not flights.
    let outputs = std::fs::canonicalize(base.join(output_directory)).ok();
    let mut flights = explicit.to_vec();
    if let Some(manifest) = &campaign.manifest {
        flights.extend(read_manifest(&base.join(manifest))?);
    }
    let mut named: std::collections::HashSet<PathBuf> = std::collections::HashSet::with_capacity(flights.len());
    for flight in &flights {
        let key = path_key(&base.join(&flight.input));
        if named.contains(&key) {
            return Err(Error::Config {
                source_name: source_name.into(),
                message: format!(
                    "the flight {} is named twice (by [[flight]] tables or manifest rows); name each flight once, with all its settings",
                    flight.input.display()
                ),
            });
        }
        named.insert(key);
    }
    // A pattern such as "*" matches the pipeline file and the manifest
    // too: they are the run's settings, not flights.
    let settings: Vec<PathBuf> = std::iter::once(Path::new(source_name).to_path_buf())
        .chain(campaign.manifest.as_ref().map(|m| base.join(m)))
        .map(|p| path_key(&p))
        .collect();
    let mut notes = Vec::new();
    for pattern in &campaign.inputs {
        let mut left_out = 0;
        let mut settings_matched = Vec::new();
        for path in glob_matches(pattern, base, source_name)? {
            let key = path_key(&base.join(&path));
            if outputs.as_ref().is_some_and(|folder| key.starts_with(folder)) {
                left_out += 1;
            } else if settings.contains(&key) {
                settings_matched.push(path);
            } else if named.insert(key) {
                flights.push(raw_flight(path));
            }
        }
        if !settings_matched.is_empty() {
            notes.push(crate::messages::Setup::SettingsMatched {
                pattern: pattern.clone(),
                files: settings_matched,
            });
        }
        if left_out > 0 {
            notes.push(crate::messages::Setup::InputsInOutputFolder {
                pattern: pattern.clone(),
                files: left_out,
                folder: output_directory.to_path_buf(),
            });
        }
    }
    Ok((flights, notes))
}

/// A path to compare flights by: the file itself when it exists (so
/// `a/../b.csv` and `b.csv` are one flight), else the path as written.
fn path_key(path: &Path) -> PathBuf {
    std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf())
}

/// The files `pattern` matches, in path order: relative to `base` as
/// written for a relative pattern (flights' inputs are resolved against
/// it), absolute for an absolute one. A pattern that matches nothing is an
/// error: a campaign that silently processes no flights of a folder is
/// worse than none.
fn glob_matches(pattern: &str, base: &Path, source_name: &str) -> Result<Vec<PathBuf>> {
    let bad = |message: String| Error::Config {
        source_name: source_name.into(),
        message,
    };
    let absolute = Path::new(pattern).is_absolute();
    let parts: Vec<&str> = pattern.split('/').filter(|p| !p.is_empty()).collect();
    let mut components = Vec::with_capacity(parts.len());
    for part in parts {
        components.push(match part {
            "**" => Component::AnyFolders,
            _ if !part.contains(['*', '?', '[']) => Component::Literal(part.to_string()),
            _ => Component::Pattern(glob::Pattern::new(part).map_err(|e| {
                bad(format!(
                    "[campaign] inputs: {pattern:?} is not a glob pattern ({e}); write e.g. \"flights/*.csv\" or \"archive/**/*.mcap\""
                ))
            })?),
        });
    }
    let root = match (absolute, base.as_os_str().is_empty()) {
        (true, _) => PathBuf::from("/"),
        (false, true) => PathBuf::from("."),
        (false, false) => base.to_path_buf(),
    };
    let mut walk = Walk {
        root: &root,
        seen: std::collections::HashSet::new(),
        matches: Vec::new(),
    };
    walk.from(
        &match absolute {
            true => PathBuf::from("/"),
            false => PathBuf::new(),
        },
        &components,
    )?;
    let mut matches = walk.matches;
    if matches.is_empty() {
        return Err(bad(format!(
            "[campaign] inputs: {pattern:?} matches no file (looked under {}); check the pattern, or remove it",
            root.display()
        )));
    }
    matches.sort();
    matches.dedup();
    Ok(matches)
}

/// One `/`-separated part of a glob pattern.
enum Component {
    /// `**`: this folder and every folder below it.
    AnyFolders,
    /// A name without wildcards, taken as written.
    Literal(String),
    /// A name with `*`, `?` or `[…]`.
    Pattern(glob::Pattern),
}

/// A glob's walk through the folders. Symbolic links are followed, but a
/// folder `**` reaches twice (by a link back up, a loop, or two links to
/// one place) is walked once: a loop would otherwise list without end.
struct Walk<'a> {
    /// The folder relative paths are read from.
    root: &'a Path,
    /// The folders (resolved) `**` has walked.
    seen: std::collections::HashSet<PathBuf>,
    matches: Vec<PathBuf>,
}

impl Walk<'_> {
    /// Matches `components` below `folder` (relative to the root, or
    /// absolute).
    fn from(&mut self, folder: &Path, components: &[Component]) -> Result<()> {
        let Some((first, rest)) = components.split_first() else {
            return Ok(());
        };
        match first {
            Component::AnyFolders => {
                let resolved = std::fs::canonicalize(self.root.join(folder));
                if !resolved.is_ok_and(|r| self.seen.insert(r)) {
                    return Ok(());
                }
                self.from(folder, rest)?;
                for name in self.names(folder)? {
                    let below = folder.join(&name);
                    if self.root.join(&below).is_dir() {
                        self.from(&below, components)?;
                    }
                }
            }
            Component::Literal(name) => self.take(folder.join(name), rest)?,
            Component::Pattern(pattern) => {
                for name in self.names(folder)? {
                    let matched = name.to_str().is_some_and(|n| pattern.matches(n));
                    if matched {
                        self.take(folder.join(&name), rest)?;
                    }
                }
            }
        }
        Ok(())
    }

    /// A path the pattern's part reached: a file when it was the last
    /// part, else a folder to go on in.
    fn take(&mut self, path: PathBuf, rest: &[Component]) -> Result<()> {
        let on_disk = self.root.join(&path);
        match rest.is_empty() {
            true if on_disk.is_file() => self.matches.push(path),
            true => {}
            false if on_disk.is_dir() => self.from(&path, rest)?,
            false => {}
        }
        Ok(())
    }

    /// The names in `folder`, sorted; a folder that cannot be listed is an
    /// error naming it.
    fn names(&self, folder: &Path) -> Result<Vec<std::ffi::OsString>> {
        let on_disk = self.root.join(folder);
        let listing = std::fs::read_dir(&on_disk).map_err(|e| Error::io(&on_disk, "listing", e))?;
        let mut names = Vec::new();
        for entry in listing {
            names.push(entry.map_err(|e| Error::io(&on_disk, "listing", e))?.file_name());
        }
        names.sort();
        Ok(names)
    }
}

fn raw_flight(input: PathBuf) -> RawFlight {
    RawFlight {
        input,
        vector: None,
        channels: None,
        windows: Vec::new(),
        windows_file: None,
        lines: Vec::new(),
        diagnosis: None,
        plan: None,
        model: None,
        date: None,
        aircraft: None,
        calibration: false,
    }
}

/// The flights of a manifest file: JSON by its extension (`.jsonl`,
/// `.ndjson`, `.json`: one object a line, or in `.json` one array), CSV
/// otherwise.
fn read_manifest(path: &Path) -> Result<Vec<RawFlight>> {
    let text = crate::ingest::read_text(path).map_err(|e| Error::io(path, "reading", e))?;
    let extension = crate::formats::lowercase_extension(path);
    match extension.as_str() {
        "json" if text.trim_start().starts_with('[') => read_json_array(path, &text),
        "jsonl" | "ndjson" | "json" => read_json_lines(path, &text),
        _ => read_manifest_csv(path, &text),
    }
}

/// A `.json` manifest holding one array of flight objects.
fn read_json_array(path: &Path, text: &str) -> Result<Vec<RawFlight>> {
    let rows: Vec<ManifestRow> = serde_json::from_str(text).map_err(|e| {
        manifest_error(
            path,
            e.line(),
            format!("{e}; give an array of objects such as [{{\"input\": \"flight.csv\"}}], or one object a line"),
        )
    })?;
    rows.into_iter()
        .enumerate()
        .map(|(index, row)| {
            from_row(row).map_err(|m| manifest_error(path, index + 1, format!("flight {}: {m}", index + 1)))
        })
        .collect()
}

fn manifest_error(path: &Path, line: usize, problem: String) -> Error {
    Error::Config {
        source_name: format!("{} line {line}", path.display()),
        message: problem,
    }
}

fn read_json_lines(path: &Path, text: &str) -> Result<Vec<RawFlight>> {
    let mut flights = Vec::new();
    for (index, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let row: ManifestRow = serde_json::from_str(line).map_err(|e| {
            manifest_error(
                path,
                index + 1,
                format!("{e}; each line is one JSON object such as {{\"input\": \"flight.csv\"}}"),
            )
        })?;
        flights.push(from_row(row).map_err(|message| manifest_error(path, index + 1, message))?);
    }
    Ok(flights)
}

fn read_manifest_csv(path: &Path, text: &str) -> Result<Vec<RawFlight>> {
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .comment(Some(b'#'))
        .from_reader(text.as_bytes());
    let header: Vec<String> = reader
        .headers()
        .map_err(|e| manifest_error(path, 1, format!("the header row cannot be read: {e}")))?
        .iter()
        .map(str::to_string)
        .collect();
    if let Some(unknown) = header.iter().find(|h| !MANIFEST_COLUMNS.contains(&h.as_str())) {
        return Err(manifest_error(
            path,
            1,
            format!(
                "column {unknown:?} is not a manifest column; use {}",
                MANIFEST_COLUMNS.join(", ")
            ),
        ));
    }
    if !header.iter().any(|h| h == "input") {
        return Err(manifest_error(
            path,
            1,
            "the header has no \"input\" column; name each flight's file in one".into(),
        ));
    }
    let mut flights = Vec::new();
    for record in reader.records() {
        let record = record.map_err(|e| {
            let line = e.position().map_or(0, |p| p.line() as usize);
            manifest_error(path, line, e.to_string())
        })?;
        let line = record.position().map_or(0, |p| p.line() as usize);
        let cell = |name: &str| {
            let index = header.iter().position(|h| h == name)?;
            record.get(index).filter(|v| !v.is_empty()).map(str::to_string)
        };
        let row = ManifestRow {
            input: cell("input")
                .map(PathBuf::from)
                .ok_or_else(|| manifest_error(path, line, "the input cell is empty".into()))?,
            windows: cell("windows").map(csv_windows),
            diagnosis: cell("diagnosis").map(PathBuf::from),
            plan: cell("plan").map(PathBuf::from),
            model: cell("model").map(PathBuf::from),
            vector: cell("vector"),
            channels: cell("channels").map(ManifestChannels::Text),
            date: cell("date"),
            aircraft: cell("aircraft"),
            lines: cell("lines").map(ManifestLines::Text),
            calibration: cell("calibration").map(ManifestFlag::Text),
        };
        flights.push(from_row(row).map_err(|message| manifest_error(path, line, message))?);
    }
    Ok(flights)
}

/// A CSV `windows` cell: a `.json` path, or `T0:T1` windows.
fn csv_windows(cell: String) -> ManifestWindows {
    match cell.to_ascii_lowercase().ends_with(".json") {
        true => ManifestWindows::File(cell.into()),
        false => ManifestWindows::List(
            cell.split(|c: char| c == ';' || c.is_whitespace())
                .filter(|w| !w.is_empty())
                .map(|w| ManifestWindow::Text(w.into()))
                .collect(),
        ),
    }
}

fn from_row(row: ManifestRow) -> std::result::Result<RawFlight, String> {
    let mut flight = raw_flight(row.input);
    // A JSON string that is not a `.json` path holds windows, as a CSV
    // cell does ("46000:46120" reads as a window, not a missing file).
    let windows = match row.windows {
        Some(ManifestWindows::File(file)) => Some(csv_windows(file.to_string_lossy().into_owned())),
        windows => windows,
    };
    match windows {
        Some(ManifestWindows::File(file)) => flight.windows_file = Some(file),
        Some(ManifestWindows::List(list)) => {
            for window in list {
                flight.windows.push(match window {
                    ManifestWindow::Window(window) => window,
                    ManifestWindow::Text(text) => CalibrationWindow::parse(&text).map_err(|_| {
                        format!(
                            "windows: {text:?} is not a window: write each as T0:T1 in seconds of the flight's time column, separated by spaces or ';', e.g. 46000:46120;46200:46300"
                        )
                    })?,
                });
            }
        }
        None => {}
    }
    flight.lines = match row.lines {
        Some(ManifestLines::List(list)) => list,
        Some(ManifestLines::Text(text)) => crate::calibration::windows::parse_lines(&text).map_err(|_| {
            format!(
                "lines = {text:?}: give the calibration line numbers separated by spaces or ';', e.g. 1002.20;1002.21"
            )
        })?,
        None => Vec::new(),
    };
    flight.diagnosis = row.diagnosis;
    flight.plan = row.plan;
    flight.model = row.model;
    flight.vector = row.vector;
    flight.channels = row.channels.map(|channels| match channels {
        ManifestChannels::List(list) => list,
        ManifestChannels::Text(text) => text
            .split(|c: char| c == ';' || c == ',' || c.is_whitespace())
            .filter(|c| !c.is_empty())
            .map(str::to_string)
            .collect(),
    });
    flight.date = row.date;
    flight.aircraft = row.aircraft;
    flight.calibration = match row.calibration {
        None => false,
        Some(ManifestFlag::Bool(flag)) => flag,
        Some(ManifestFlag::Text(text)) => match text.trim().to_lowercase().as_str() {
            "true" | "yes" | "1" => true,
            "false" | "no" | "0" | "" => false,
            _ => {
                return Err(format!(
                    "calibration = {text:?}: give true (the aircraft's calibration flight) or false"
                ))
            }
        },
    };
    Ok(flight)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(folder: &Path, name: &str, text: &str) -> PathBuf {
        let path = folder.join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn csv_and_json_lines_manifests_name_the_same_flights() {
        let folder = tempfile::tempdir().unwrap();
        let csv = write(
            folder.path(),
            "m.csv",
            "input,windows,channels,date,aircraft\n\
             a.csv,100:200;300:400,mag_1_uc mag_2_uc,2020-06-20,C-FTLL\n\
             # a comment\n\
             b.csv,b.windows.json,,,\n",
        );
        let jsonl = write(
            folder.path(),
            "m.jsonl",
            "{\"input\": \"a.csv\", \"windows\": [\"100:200\", {\"t_start\": 300, \"t_end\": 400}], \
              \"channels\": [\"mag_1_uc\", \"mag_2_uc\"], \"date\": \"2020-06-20\", \"aircraft\": \"C-FTLL\"}\n\
             \n\
             {\"input\": \"b.csv\", \"windows\": \"b.windows.json\"}\n",
        );
        let array = write(
            folder.path(),
            "m.json",
            "[{\"input\": \"a.csv\", \"windows\": [\"100:200\", \"300:400\"], \"channels\": \"mag_1_uc;mag_2_uc\",\n \
               \"date\": \"2020-06-20\", \"aircraft\": \"C-FTLL\"},\n {\"input\": \"b.csv\", \"windows\": \"b.windows.json\"}]",
        );
        for path in [csv, jsonl, array] {
            let flights = read_manifest(&path).unwrap();
            assert_eq!(flights.len(), 2, "{}", path.display());
            assert_eq!(flights[0].input, PathBuf::from("a.csv"));
            let spans: Vec<(f64, f64)> = flights[0].windows.iter().map(|w| (w.t_start, w.t_end)).collect();
            assert_eq!(spans, [(100.0, 200.0), (300.0, 400.0)]);
            assert_eq!(flights[0].channels.as_deref().unwrap(), ["mag_1_uc", "mag_2_uc"]);
            assert_eq!(flights[0].date.as_deref(), Some("2020-06-20"));
            assert_eq!(flights[0].aircraft.as_deref(), Some("C-FTLL"));
            assert_eq!(flights[1].windows_file, Some(PathBuf::from("b.windows.json")));
            assert!(flights[1].windows.is_empty() && flights[1].channels.is_none());
        }
    }

    #[test]
    fn a_bad_manifest_names_the_file_line_and_field() {
        let folder = tempfile::tempdir().unwrap();
        let unknown = write(folder.path(), "u.csv", "input,window\na.csv,1:2\n");
        let text = read_manifest(&unknown).unwrap_err().to_string();
        assert!(text.contains("u.csv line 1") && text.contains("\"window\""), "{text}");
        let bad_window = write(folder.path(), "w.csv", "input,windows\na.csv,1:2\nb.csv,5-9\n");
        let text = read_manifest(&bad_window).unwrap_err().to_string();
        assert!(text.contains("w.csv line 3") && text.contains("5-9"), "{text}");
        assert!(
            text.contains("write each as T0:T1") && !text.contains("command line"),
            "{text}"
        );
        // A cell of the wrong shape says what shape it takes, not which
        // inner variant failed.
        for (cell, says) in [
            ("\"windows\": 5", "give `windows` as a DETECT.json path"),
            ("\"channels\": 5", "give `channels` as a list"),
            ("\"lines\": {}", "give `lines` as a list"),
        ] {
            let shape = write(folder.path(), "s.jsonl", &format!("{{\"input\": \"a.csv\", {cell}}}\n"));
            let text = read_manifest(&shape).unwrap_err().to_string();
            assert!(text.contains("s.jsonl line 1") && text.contains(says), "{text}");
            assert!(!text.contains("variant"), "{text}");
        }
        // A string that is no `.json` path holds windows, as a CSV cell.
        let text_windows = write(
            folder.path(),
            "x.jsonl",
            "{\"input\": \"a.csv\", \"windows\": \"x:y\"}\n",
        );
        let text = read_manifest(&text_windows).unwrap_err().to_string();
        assert!(
            text.contains("x.jsonl line 1") && text.contains("\"x:y\" is not a window") && !text.contains("reading"),
            "{text}"
        );
        let good = write(
            folder.path(),
            "g.jsonl",
            "{\"input\": \"a.csv\", \"windows\": \"5:9 12:20\"}\n",
        );
        let flights = read_manifest(&good).unwrap();
        assert_eq!(flights[0].windows.len(), 2);
        let typo = write(folder.path(), "t.jsonl", "{\"input\": \"a.csv\", \"chanels\": []}\n");
        let text = read_manifest(&typo).unwrap_err().to_string();
        assert!(text.contains("t.jsonl line 1") && text.contains("chanels"), "{text}");
    }

    #[test]
    fn a_pattern_that_matches_the_pipeline_file_or_manifest_leaves_them_out_and_says_so() {
        let folder = tempfile::tempdir().unwrap();
        write(folder.path(), "a.csv", "tt\n0\n");
        write(folder.path(), "flights.jsonl", "{\"input\": \"b.csv\"}\n");
        let pipeline = write(folder.path(), "p.toml", "");
        let campaign = RawCampaign {
            inputs: vec!["*".into()],
            manifest: Some("flights.jsonl".into()),
        };
        let source = pipeline.display().to_string();
        let (flights, notes) = campaign_flights(&campaign, &[], (folder.path(), Path::new("out")), &source).unwrap();
        let names: Vec<String> = (flights.iter())
            .map(|f| f.input.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["b.csv", "a.csv"]);
        let said = notes.iter().map(ToString::to_string).collect::<Vec<_>>().join("\n");
        assert!(
            said.contains("matches the run's own settings")
                && said.contains("p.toml")
                && said.contains("flights.jsonl"),
            "{said}"
        );
    }

    #[test]
    fn patterns_sweep_a_folder_and_tables_keep_their_own_settings() {
        let folder = tempfile::tempdir().unwrap();
        for name in ["f/2.csv", "f/1.csv", "f/sub/3.csv", "f/notes.txt"] {
            write(folder.path(), name, "tt\n0\n");
        }
        let mut own = raw_flight("f/2.csv".into());
        own.vector = Some("flux_b".into());
        for name in ["out/1_compensated.csv", "f/out/2_compensated.csv"] {
            write(folder.path(), name, "tt\n0\n");
        }
        let campaign = RawCampaign {
            inputs: vec!["f/**/*.csv".into(), "out/*.csv".into()],
            manifest: None,
        };
        let (flights, notes) =
            campaign_flights(&campaign, &[own], (folder.path(), Path::new("f/out")), "p.toml").unwrap();
        assert_eq!(notes.len(), 1, "{notes:?}");
        assert_eq!(
            notes[0],
            crate::messages::Setup::InputsInOutputFolder {
                pattern: "f/**/*.csv".into(),
                files: 1,
                folder: "f/out".into()
            }
        );
        let names: Vec<String> = flights
            .iter()
            .map(|f| {
                f.input
                    .strip_prefix(folder.path())
                    .unwrap_or(&f.input)
                    .display()
                    .to_string()
            })
            .collect();
        // The output folder's files are no flights; another folder's are.
        assert_eq!(names, ["f/2.csv", "f/1.csv", "f/sub/3.csv", "out/1_compensated.csv"]);
        assert_eq!(flights[0].vector.as_deref(), Some("flux_b"));

        let twice = [raw_flight("f/1.csv".into()), raw_flight("f/../f/1.csv".into())];
        let text = campaign_flights(
            &RawCampaign::default(),
            &twice,
            (folder.path(), Path::new("out")),
            "p.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(text.contains("named twice"), "{text}");

        let nothing = RawCampaign {
            inputs: vec!["g/*.csv".into()],
            manifest: None,
        };
        let text = campaign_flights(&nothing, &[], (folder.path(), Path::new("out")), "p.toml")
            .unwrap_err()
            .to_string();
        assert!(text.contains("matches no file"), "{text}");
    }
}
