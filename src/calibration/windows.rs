//! Calibration windows: the stretches of a flight the model is fitted on.
//!
//! Windows come from pipeline.toml, from `--window T0:T1` flags, or from a
//! DETECT.json file (CONTRACT §3); automatic detection produces the same
//! type. A window labelled with its manoeuvre kind and heading takes part in
//! the classic figure of merit.

use std::ops::Range;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::ingest::flight_identity::FlightIdentity;
use crate::ingest::flight_log::{FlightLog, VectorSensor};
use crate::messages::Note;

/// The three manoeuvres of the FOM box.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ManoeuvreKind {
    /// Pitch oscillation.
    Pitch,
    /// Roll oscillation.
    Roll,
    /// Yaw oscillation.
    Yaw,
}

impl ManoeuvreKind {
    /// The manoeuvre's name as users and the JSON files write it.
    pub fn name(self) -> &'static str {
        match self {
            ManoeuvreKind::Pitch => "pitch",
            ManoeuvreKind::Roll => "roll",
            ManoeuvreKind::Yaw => "yaw",
        }
    }

    /// The attitude offset (roll, pitch, yaw), degrees, of this manoeuvre
    /// swung `angle_deg` from level: the simulator's pilot and the
    /// excitation analysis's candidate manoeuvres both fly it, as a sine.
    pub fn attitude_offset(self, angle_deg: f64) -> [f64; 3] {
        match self {
            ManoeuvreKind::Roll => [angle_deg, 0.0, 0.0],
            ManoeuvreKind::Pitch => [0.0, angle_deg, 0.0],
            ManoeuvreKind::Yaw => [0.0, 0.0, angle_deg],
        }
    }
}

/// One calibration window, in the flight log's own time unit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationWindow {
    /// Start time, inclusive.
    pub t_start: f64,
    /// End time, inclusive.
    pub t_end: f64,
    /// Human label, e.g. "roll, heading 90".
    #[serde(default)]
    pub label: String,
    /// Manoeuvre kind, when known.
    #[serde(default)]
    pub kind: Option<ManoeuvreKind>,
    /// Leg heading, degrees clockwise from north, when known.
    #[serde(default)]
    pub heading_deg: Option<f64>,
}

impl CalibrationWindow {
    /// A plain window with a label made from its times.
    pub fn new(t_start: f64, t_end: f64) -> Self {
        CalibrationWindow {
            t_start,
            t_end,
            label: format!("{t_start}:{t_end}"),
            kind: None,
            heading_deg: None,
        }
    }

    /// The label, or one made from kind and heading when no label was given.
    pub fn display_label(&self) -> String {
        match (&self.label, self.kind, self.heading_deg) {
            (label, _, _) if !label.is_empty() => label.clone(),
            (_, Some(kind), Some(heading)) => format!("{kind:?}, heading {heading}").to_lowercase(),
            _ => format!("{}:{}", self.t_start, self.t_end),
        }
    }

    /// A manoeuvre's window widened by `margin_s` of level flight on both
    /// sides, labelled with its kind and heading.
    pub fn manoeuvre(kind: ManoeuvreKind, heading_deg: f64, t_start: f64, t_end: f64, margin_s: f64) -> Self {
        CalibrationWindow {
            t_start: t_start - margin_s,
            t_end: t_end + margin_s,
            label: String::new(),
            kind: Some(kind),
            heading_deg: Some(heading_deg),
        }
    }

    /// Parses `T0:T1` as given to `--window`.
    pub fn parse(text: &str) -> Result<Self> {
        let bad = |message: String| Error::Config {
            source_name: "command line".into(),
            message,
        };
        let (start, end) = text.split_once(':').ok_or_else(|| {
            bad(format!(
                "--window '{text}': write the window as T0:T1, e.g. --window 46000:46120"
            ))
        })?;
        let parse = |s: &str| {
            s.trim()
                .parse::<f64>()
                .map_err(|_| bad(format!("--window '{text}': '{s}' is not a number")))
        };
        let window = CalibrationWindow::new(parse(start)?, parse(end)?);
        window.validate("command line")?;
        Ok(window)
    }

    /// Checks the window is finite and not reversed.
    pub fn validate(&self, source_name: &str) -> Result<()> {
        if !(self.t_start.is_finite() && self.t_end.is_finite() && self.t_start < self.t_end) {
            return Err(Error::Config {
                source_name: source_name.into(),
                message: format!(
                    "calibration window '{}' runs from {} to {}: the start must be before the end",
                    self.display_label(),
                    self.t_start,
                    self.t_end
                ),
            });
        }
        Ok(())
    }

    /// Sample indices whose time lies in the window.
    pub fn rows(&self, time_s: &[f64]) -> Range<usize> {
        let start = time_s.partition_point(|&t| t < self.t_start);
        let end = time_s.partition_point(|&t| t <= self.t_end);
        start..end.max(start)
    }
}

/// The rows of all `windows` in `time_s` as stretches in order, those
/// that overlap or touch merged into one.
pub fn merged_rows(windows: &[CalibrationWindow], time_s: &[f64]) -> Vec<Range<usize>> {
    let mut stretches: Vec<Range<usize>> = windows.iter().map(|w| w.rows(time_s)).collect();
    stretches.sort_by_key(|r| r.start);
    let mut merged: Vec<Range<usize>> = Vec::with_capacity(stretches.len());
    for stretch in stretches.into_iter().filter(|r| !r.is_empty()) {
        match merged.last_mut() {
            Some(last) if stretch.start <= last.end => last.end = last.end.max(stretch.end),
            _ => merged.push(stretch),
        }
    }
    merged
}

/// The manoeuvre list of a DETECT.json file (CONTRACT §3).
#[derive(Debug, Deserialize, Serialize)]
pub struct DetectFile {
    manoeuvres: Vec<DetectedManoeuvre>,
    #[serde(default)]
    boxes: Vec<BoxSpan>,
    /// The flight the manoeuvres were detected on (`magcomp detect`
    /// writes it; a hand-made file may leave it out).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    flight: Option<FlightIdentity>,
}

/// The calibration windows of a DETECT.json file and the flight they were
/// detected on, when the file says.
#[derive(Debug, Clone, PartialEq)]
pub struct DetectedWindows {
    /// The manoeuvres, widened for the band-pass.
    pub windows: Vec<CalibrationWindow>,
    /// The flight `magcomp detect` found them on.
    pub flight: Option<FlightIdentity>,
}

#[derive(Debug, Deserialize, Serialize)]
struct BoxSpan {
    t_start: f64,
    t_end: f64,
}

#[derive(Debug, Deserialize, Serialize)]
struct DetectedManoeuvre {
    kind: ManoeuvreKind,
    heading_deg: f64,
    t_start: f64,
    t_end: f64,
}

impl DetectFile {
    /// DETECT.json (CONTRACT §3) of labelled manoeuvre windows and boxes
    /// (start, end); unlabelled windows are left out.
    pub fn new(manoeuvres: &[CalibrationWindow], boxes: &[(f64, f64)]) -> Self {
        DetectFile {
            manoeuvres: manoeuvres
                .iter()
                .filter_map(|w| {
                    Some(DetectedManoeuvre {
                        kind: w.kind?,
                        heading_deg: w.heading_deg?,
                        t_start: w.t_start,
                        t_end: w.t_end,
                    })
                })
                .collect(),
            boxes: boxes
                .iter()
                .map(|&(t_start, t_end)| BoxSpan { t_start, t_end })
                .collect(),
            flight: None,
        }
    }
}

/// Reads the manoeuvres of a DETECT.json file as calibration windows, each
/// widened by `margin_s` of level flight on both sides (the fit's band-pass
/// and trimming need it).
pub fn read_detect_json(path: &Path, margin_s: f64) -> Result<Vec<CalibrationWindow>> {
    read_detect_file(path, margin_s).map(|file| file.windows)
}

/// [`read_detect_json`]'s windows with the flight they were detected on.
pub fn read_detect_file(path: &Path, margin_s: f64) -> Result<DetectedWindows> {
    let text = crate::ingest::read_text(path).map_err(|e| Error::io(path, "reading", e))?;
    let file: DetectFile = serde_json::from_str(&text).map_err(|e| Error::NotOurFile {
        path: path.to_path_buf(),
        expected: "a DETECT.json manoeuvre list",
        problem: e.to_string(),
        hint: "Give the file `magcomp detect FLIGHT --out DETECT.json` writes, or a JSON object with a \"manoeuvres\" list of kind, heading_deg, t_start and t_end.",
    })?;
    let windows: Vec<CalibrationWindow> = file
        .manoeuvres
        .into_iter()
        .map(|m| CalibrationWindow::manoeuvre(m.kind, m.heading_deg, m.t_start, m.t_end, margin_s))
        .collect();
    windows
        .iter()
        .try_for_each(|w| w.validate(&path.display().to_string()))?;
    Ok(DetectedWindows {
        windows,
        flight: file.flight,
    })
}

/// `windows` with each window given by time (no heading) given its leg's
/// heading from the INS yaw: the circular mean over its rows, kept only
/// where every row's yaw lies within `tolerance_deg` of it (a window
/// across a turn keeps none). The heading lets the fit hold a heading out
/// as it does for detected manoeuvres. Returns the windows and a note of
/// what was labelled; a flight without INS attitude keeps its windows.
pub fn headings_from_ins(
    log: &FlightLog,
    windows: &[CalibrationWindow],
    tolerance_deg: f64,
) -> (Vec<CalibrationWindow>, Option<Note>) {
    let Some([_, _, yaw]) = log.attitude() else {
        return (windows.to_vec(), None);
    };
    let (mut labelled, mut across) = (Vec::new(), 0);
    let windows = (windows.iter())
        .map(|window| {
            let mut window = window.clone();
            if window.heading_deg.is_none() {
                let rows = window.rows(log.time_s());
                match steady_heading_deg(&yaw[rows], tolerance_deg) {
                    Some(heading) => {
                        window.heading_deg = Some(heading);
                        labelled.push(heading.round().rem_euclid(360.0));
                    }
                    None => across += 1,
                }
            }
            window
        })
        .collect();
    let note = (!labelled.is_empty() || across > 0).then_some(Note::WindowHeadings {
        headings_deg: labelled,
        without: across,
    });
    (windows, note)
}

/// The circular mean of `yaw_deg`, when every finite sample lies within
/// `tolerance_deg` of it.
fn steady_heading_deg(yaw_deg: &[f64], tolerance_deg: f64) -> Option<f64> {
    let finite = || yaw_deg.iter().filter(|y| y.is_finite());
    finite().next()?;
    let (sin, cos) = finite().fold((0.0, 0.0), |(s, c), y| {
        (s + y.to_radians().sin(), c + y.to_radians().cos())
    });
    let mean = sin.atan2(cos).to_degrees().rem_euclid(360.0);
    let apart = |y: &f64| ((y - mean + 540.0).rem_euclid(360.0) - 180.0).abs();
    finite().all(|y| apart(y) < tolerance_deg).then_some(mean)
}

/// A warning when `windows`, read from `path`, were detected on another
/// flight than `log`: they still set the fit, but may not lie on its
/// manoeuvres. The same rows over the same times are the same flight
/// (another format or a re-saved copy of it), whatever its bytes.
pub fn other_flight_warning(
    path: &Path,
    detected_on: &FlightIdentity,
    log: &FlightLog,
) -> Result<Option<crate::messages::Warning>> {
    let flight = FlightIdentity::of(log)?;
    let same_rows = flight.rows == detected_on.rows
        && flight.t_start.to_bits() == detected_on.t_start.to_bits()
        && flight.t_end.to_bits() == detected_on.t_end.to_bits();
    if same_rows {
        return Ok(None);
    }
    Ok(detected_on
        .difference(&flight)
        .map(|difference| crate::messages::Warning::WindowsFromOtherFlight {
            windows_file: path.to_path_buf(),
            detected_on: detected_on.describe(),
            flight: flight.describe(),
            difference,
        }))
}

/// The calibration data a flight's `lines` select: per line number given,
/// every run of rows carrying it, as (line, first time, last time).
///
/// An error names what is wrong and the fix: a flight without a line
/// column, or a line number it does not hold (with the lines it does).
pub fn line_spans(log: &FlightLog, lines: &[f64]) -> Result<Vec<(f64, f64, f64)>> {
    let source_name = log.source().display().to_string();
    let flown = log.survey_lines();
    if flown.is_empty() {
        return Err(Error::Config {
            source_name,
            message: format!(
                "calibration lines {} were asked for, but the flight has no line column (or no non-zero line number in it): name it in [columns] line, or give the calibration windows by time with --window",
                list_lines(lines)
            ),
        });
    }
    let time = log.time_s();
    let mut spans = Vec::new();
    for &line in lines {
        let runs: Vec<(f64, f64, f64)> = (flown.iter())
            .filter(|(number, _)| same_line(*number, line))
            .filter_map(|(number, rows)| Some((*number, time[*rows.first()?], time[*rows.last()?])))
            .collect();
        if runs.is_empty() {
            let mut present: Vec<f64> = flown.iter().map(|(number, _)| *number).collect();
            present.sort_by(f64::total_cmp);
            present.dedup();
            return Err(Error::Config {
                source_name,
                message: format!(
                    "calibration line {line} is not in the flight; its lines are {}. Give one of them with --lines (or [[flight]] lines)",
                    list_lines(&present)
                ),
            });
        }
        spans.extend(runs);
    }
    spans.sort_by(|a, b| a.1.total_cmp(&b.1));
    Ok(spans)
}

/// Line numbers as written (1002.2 for 1002.20): equal to a millionth,
/// since a CSV's text and a float's digits may differ in the last place.
fn same_line(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-6 * a.abs().max(1.0)
}

fn list_lines(lines: &[f64]) -> String {
    let shown: Vec<String> = lines.iter().take(20).map(|l| l.to_string()).collect();
    match lines.len() > 20 {
        true => format!("{}, … ({} in all)", shown.join(", "), lines.len()),
        false => shown.join(", "),
    }
}

/// Parses `--lines 1002.20,1002.21` into line numbers.
pub fn parse_lines(text: &str) -> Result<Vec<f64>> {
    text.split([',', ';', ' '])
        .filter(|part| !part.trim().is_empty())
        .map(|part| {
            part.trim().parse::<f64>().ok().filter(|v| v.is_finite() && *v != 0.0).ok_or_else(|| Error::Config {
                source_name: "command line".into(),
                message: format!(
                    "--lines '{text}': '{part}' is not a line number; write the calibration lines as numbers separated by commas, e.g. --lines 1002.20,1002.21"
                ),
            })
        })
        .collect()
}

/// The calibration a model is fitted on, what every fit of a flight
/// shares: the log (with the fluxgate as the fit reads it), the vector sensor whose direction cosines make the
/// terms, the scalar channels to fit and the windows fitted on. Built once
/// per flight ([`crate::pipeline::PreparedFlight::calibration`]) and handed
/// to each stage instead of its four parts.
#[derive(Debug, Clone, Copy)]
pub struct Calibration<'a> {
    /// The flight log the fits read.
    pub log: &'a FlightLog,
    /// The vector magnetometer of the direction cosines.
    pub sensor: &'a VectorSensor,
    /// The scalar channels to fit.
    pub channels: &'a [String],
    /// The calibration windows.
    pub windows: &'a [CalibrationWindow],
}

impl<'a> Calibration<'a> {
    /// The same calibration read from `log` instead (the flight with its
    /// fluxgate calibrated, say).
    pub fn on(self, log: &'a FlightLog) -> Self {
        Calibration { log, ..self }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_command_line_windows() {
        let w = CalibrationWindow::parse("46000.5:46120").unwrap();
        assert_eq!((w.t_start, w.t_end), (46000.5, 46120.0));
        assert!(CalibrationWindow::parse("46120:46000").is_err());
        assert!(CalibrationWindow::parse("46000").is_err());
    }

    #[test]
    fn rows_are_inclusive_of_both_ends() {
        let time = [0.0, 0.1, 0.2, 0.3, 0.4];
        assert_eq!(CalibrationWindow::new(0.1, 0.3).rows(&time), 1..4);
        assert_eq!(CalibrationWindow::new(5.0, 6.0).rows(&time), 5..5);
    }
}
