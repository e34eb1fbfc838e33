//! The truth of a simulated flight, kept apart from the recording.
//!
//! `<flight>.truth.json` holds the manoeuvres as flown (DETECT.json shape
//! plus cycles, amplitude and period), the boxes, the survey lines, the
//! concealed effects with their parameters and each sensor's aircraft
//! field. `<flight>.truth.csv` holds, per output sample, the true Earth
//! field magnitude at every scalar sensor (`<channel>_earth_nt`), the true
//! Earth field at every fluxgate in INS body axes (`<sensor>_earth_x/y/z`)
//! and in north-east-down (`<sensor>_earth_n/e/d`), the true gradient
//! between every two scalar sensors at least 0.1 m apart
//! (`grad_<a>_<b>_true`, nT/m: the difference of their true Earth fields
//! over their separation, a before b in the scenario's order), and the
//! external variation along the main field (`external_nt`).

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::calibration::windows::{CalibrationWindow, ManoeuvreKind};
use crate::error::Result;
use crate::formats::stage_detect_json;
use crate::formats::{stage, stage_json, OutputSet, Staged};
use crate::simulate::physics::{AircraftField, FluxgateCalibration};
use crate::simulate::scenario::{Effect, Scenario, SensorLocation};
use crate::simulate::trajectory::FlightPath;

/// What one scalar sensor would have read without the aircraft.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SensorTruth {
    /// Scalar channel.
    pub channel: String,
    /// Where it sits.
    pub location: SensorLocation,
    /// Its position in body axes (forward, right, down), m.
    pub position_m: [f64; 3],
    /// The aircraft's field at the sensor.
    pub aircraft: AircraftField,
    /// True Earth field magnitude at the sensor, nT, per output sample.
    #[serde(skip)]
    pub earth_total_nt: Vec<f64>,
}

/// What one fluxgate would have read without the aircraft or its own errors.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FluxgateTruth {
    /// Fluxgate prefix.
    pub sensor: String,
    /// Its calibration errors (the residual ones, or the concealed effect's).
    pub calibration: FluxgateCalibration,
    /// The aircraft's field at the fluxgate.
    pub aircraft: AircraftField,
    /// How it is mounted: its reading per body-axis field (rows: its
    /// axes), before its calibration errors.
    pub mounting: [[f64; 3]; 3],
    /// True Earth field in body axes at the fluxgate, nT, per output sample.
    #[serde(skip)]
    pub earth_body_nt: [Vec<f64>; 3],
    /// True Earth field in north-east-down at the fluxgate, nT, per output
    /// sample.
    #[serde(skip)]
    pub earth_ned_nt: [Vec<f64>; 3],
}

/// The true gradient between two scalar sensors.
#[derive(Debug, Clone, PartialEq)]
pub struct TrueGradient {
    /// `grad_<a>_<b>`.
    pub name: String,
    /// The first sensor's channel.
    pub a: String,
    /// The second sensor's channel.
    pub b: String,
    /// Their distance, m.
    pub separation_m: f64,
    /// (Earth field at a − at b)/separation, nT/m, per output sample.
    pub values_nt_per_m: Vec<f64>,
}

/// One manoeuvre as flown, in the flight's time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrueManoeuvre {
    /// Pitch, roll or yaw.
    pub kind: ManoeuvreKind,
    /// Leg heading, degrees.
    pub heading_deg: f64,
    /// First sample of the oscillation.
    pub t_start: f64,
    /// Last sample of the oscillation.
    pub t_end: f64,
    /// Whole cycles flown.
    pub cycles: usize,
    /// Peak angle, degrees.
    pub amplitude_deg: f64,
    /// Period, s.
    pub period_s: f64,
}

/// A stretch of flight time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TimeSpan {
    /// Start, in the flight's time.
    pub t_start: f64,
    /// End, in the flight's time.
    pub t_end: f64,
}

/// One survey line.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TrueLine {
    /// Line number, as in the `line` column.
    pub line: f64,
    /// Heading, degrees.
    pub heading_deg: f64,
    /// Start, in the flight's time.
    pub t_start: f64,
    /// End, in the flight's time.
    pub t_end: f64,
}

/// Everything the recording conceals.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Truth {
    /// The scenario's seed.
    pub seed: u64,
    /// Manoeuvres as flown.
    pub manoeuvres: Vec<TrueManoeuvre>,
    /// Calibration boxes.
    pub boxes: Vec<TimeSpan>,
    /// Survey lines.
    pub lines: Vec<TrueLine>,
    /// The concealed effects and their parameters.
    pub effects: Vec<Effect>,
    /// Per scalar sensor: its aircraft field (and, in the CSV, the Earth field).
    pub sensors: Vec<SensorTruth>,
    /// Per fluxgate: its errors and aircraft field (and, in the CSV, the
    /// Earth field in body axes).
    pub fluxgates: Vec<FluxgateTruth>,
    /// Output sample times.
    #[serde(skip)]
    pub time_s: Vec<f64>,
    /// External variation along the main field, nT, per output sample.
    #[serde(skip)]
    pub external_nt: Vec<f64>,
}

impl Truth {
    /// Collects the truth of a flown path.
    pub fn new(
        scenario: &Scenario,
        path: &FlightPath,
        time_s: Vec<f64>,
        (sensors, fluxgates): (Vec<SensorTruth>, Vec<FluxgateTruth>),
        external_nt: Vec<f64>,
    ) -> Truth {
        let t0 = scenario.raw.start_time_s;
        // Times on the output grid, as the recording prints them.
        let at = |seconds: f64| {
            let ticks = (seconds * scenario.raw.sample_rate_hz * 1e6).round() / 1e6;
            t0 + ticks / scenario.raw.sample_rate_hz
        };
        Truth {
            seed: scenario.raw.seed,
            manoeuvres: path
                .manoeuvres
                .iter()
                .map(|m| TrueManoeuvre {
                    kind: m.kind,
                    heading_deg: m.heading_deg,
                    t_start: at(m.t_start_s),
                    t_end: at(m.t_end_s),
                    cycles: m.cycles,
                    amplitude_deg: m.amplitude_deg,
                    period_s: m.period_s,
                })
                .collect(),
            boxes: path
                .boxes
                .iter()
                .map(|b| TimeSpan {
                    t_start: at(b.t_start_s),
                    t_end: at(b.t_end_s),
                })
                .collect(),
            lines: path
                .lines
                .iter()
                .map(|(line, heading_deg, s)| TrueLine {
                    line: *line,
                    heading_deg: *heading_deg,
                    t_start: at(s.t_start_s),
                    t_end: at(s.t_end_s),
                })
                .collect(),
            effects: scenario.raw.effect.clone(),
            sensors,
            fluxgates,
            time_s,
            external_nt,
        }
    }

    /// Calibration windows for fitting: each manoeuvre with `margin_s` of
    /// the level flight around it, labelled with kind and heading.
    pub fn calibration_windows(&self, margin_s: f64) -> Vec<CalibrationWindow> {
        self.manoeuvres
            .iter()
            .map(|m| CalibrationWindow::manoeuvre(m.kind, m.heading_deg, m.t_start, m.t_end, margin_s))
            .collect()
    }

    /// The true gradient between every two scalar sensors at least
    /// [`crate::compensate::gradient::LEAST_SEPARATION_M`] apart, a before
    /// b in the scenario's order: the difference of their true Earth fields
    /// over their separation, nT/m, per output sample.
    pub fn gradients(&self) -> Vec<TrueGradient> {
        let mut gradients = Vec::new();
        for (i, a) in self.sensors.iter().enumerate() {
            for b in &self.sensors[i + 1..] {
                let separation_m = (0..3)
                    .map(|k| (a.position_m[k] - b.position_m[k]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                if separation_m < crate::compensate::gradient::LEAST_SEPARATION_M {
                    continue;
                }
                gradients.push(TrueGradient {
                    name: crate::compensate::gradient::gradient_name(&a.channel, &b.channel),
                    a: a.channel.clone(),
                    b: b.channel.clone(),
                    separation_m,
                    values_nt_per_m: a
                        .earth_total_nt
                        .iter()
                        .zip(&b.earth_total_nt)
                        .map(|(x, y)| (x - y) / separation_m)
                        .collect(),
                });
            }
        }
        gradients
    }

    /// The true Earth field at `channel`'s sensor, per output sample.
    pub fn earth_total_nt(&self, channel: &str) -> Option<&[f64]> {
        self.sensors
            .iter()
            .find(|s| s.channel == channel)
            .map(|s| s.earth_total_nt.as_slice())
    }

    /// The paths of `<stem>.truth.json`, `<stem>.truth.csv` and
    /// `<stem>.windows.json` beside `flight`.
    pub fn paths_beside(flight: &Path) -> [PathBuf; 3] {
        let stem = flight.with_extension("");
        ["truth.json", "truth.csv", "windows.json"].map(|suffix| stem.with_extension(suffix))
    }

    /// Writes `<stem>.truth.json` and `<stem>.truth.csv` beside `flight`,
    /// and `<stem>.windows.json` (DETECT.json shape: the manoeuvres as flown,
    /// which a fit widens by its window margin). Returns the three paths.
    pub fn write_beside(&self, flight: &Path) -> Result<[PathBuf; 3]> {
        let mut set = OutputSet::new();
        for staged in self.stage_beside(flight)? {
            set.add(staged);
        }
        set.commit()?;
        Ok(Self::paths_beside(flight))
    }

    /// Stages the three files of [`Truth::write_beside`].
    pub fn stage_beside(&self, flight: &Path) -> Result<[Staged; 3]> {
        let [json, csv, windows] = Self::paths_beside(flight);
        let boxes: Vec<(f64, f64)> = self.boxes.iter().map(|b| (b.t_start, b.t_end)).collect();
        Ok([
            stage_json(&json, "the simulation truth", self)?,
            stage(&csv, |out| self.write_csv(out))?,
            stage_detect_json(&windows, &self.calibration_windows(0.0), &boxes)?,
        ])
    }

    fn write_csv(&self, out: &mut impl Write) -> std::io::Result<()> {
        let mut names: Vec<String> = self.sensors.iter().map(|s| format!("{}_earth_nt", s.channel)).collect();
        for fluxgate in &self.fluxgates {
            names.extend(["x", "y", "z", "n", "e", "d"].map(|axis| format!("{}_earth_{axis}", fluxgate.sensor)));
        }
        let gradients = self.gradients();
        names.extend(gradients.iter().map(|g| format!("{}_true", g.name)));
        writeln!(out, "tt,{},external_nt", names.join(","))?;
        let mut number = ryu::Buffer::new();
        for (row, t) in self.time_s.iter().enumerate() {
            out.write_all(number.format(*t).as_bytes())?;
            for sensor in &self.sensors {
                write!(out, ",{:.4}", sensor.earth_total_nt[row])?;
            }
            for fluxgate in &self.fluxgates {
                for axis in fluxgate.earth_body_nt.iter().chain(&fluxgate.earth_ned_nt) {
                    write!(out, ",{:.4}", axis[row])?;
                }
            }
            for gradient in &gradients {
                write!(out, ",{:.6}", gradient.values_nt_per_m[row])?;
            }
            writeln!(out, ",{:.4}", self.external_nt[row])?;
        }
        Ok(())
    }
}

/// Standard deviation of (compensated − true Earth field) over the survey
/// lines' rows where both are finite, nT: the survey-line error after one
/// overall level shift. Line rows are those whose `line` value is non-zero.
pub fn survey_line_error_nt(compensated: &[f64], truth: &[f64], line: &[f64]) -> f64 {
    let errors: Vec<f64> = (0..compensated.len())
        .filter(|&k| line[k] != 0.0 && line[k].is_finite() && compensated[k].is_finite())
        .map(|k| compensated[k] - truth[k])
        .collect();
    crate::quality::standard_deviation(&errors)
}
