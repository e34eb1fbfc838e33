//! A small physics-based sample flight: a calibration box and survey lines.
//!
//! `magcomp sample-flight` writes it, and examples and tests use it where a
//! quick flight will do; the sample flights in `sample_flights/` come from
//! the full simulator ([`crate::simulate`]: IGRF, concealed effects,
//! sensor models). It simulates fields, not Tolles-Lawson regressors, so
//! the fit is not trivially perfect:
//!
//! - Earth's field: a uniform main field (total `earth_total_nt`, given
//!   inclination and declination) in north-east-down axes, plus buried
//!   magnetic dipoles (Blakely 1995, eq. 4.13) evaluated exactly at the
//!   aircraft, plus a slow diurnal variation recorded by a base station.
//! - Attitude: a four-heading FOM box at altitude with pitch ±5°, roll ±10°
//!   and yaw ±5° manoeuvres whose periods, amplitudes and cycle counts vary
//!   like a pilot's, coordinated turns between legs, then survey lines in
//!   alternating directions at low altitude with turbulence. The body field
//!   is $B_b = R^\top B_{NED}$ with $R = R_z(\psi) R_y(\theta) R_x(\phi)$ (yaw
//!   clockwise from north, pitch nose up, roll right wing down).
//! - Aircraft: per-sensor permanent vector P, induced tensor A and
//!   eddy tensor E (s), giving $P + A B_b + E\, dB_b/dt$ at the sensor.
//!   The scalar magnetometers read the norm $|B_b + B_{aircraft}|$ plus
//!   white noise; the fluxgate reads $B_b$ plus its own small aircraft field
//!   and noise.
//! - Auxiliary channels: a strobe current near 1 Hz and an avionics bus
//!   voltage, not coupled into the sensors in this clean flight.

use std::f64::consts::PI;
use std::io::Write;
use std::path::Path;

use crate::calibration::windows::{CalibrationWindow, ManoeuvreKind};
use crate::error::Result;
use crate::formats::stage_detect_json;
use crate::formats::{stage, OutputSet};
use crate::simulate::physics::{dipole_field_nt, Vector};
use crate::simulate::random::Random;

/// What to fly.
#[derive(Debug, Clone, PartialEq)]
pub struct SampleFlightSpec {
    /// First sample time, seconds past midnight.
    pub start_time_s: f64,
    /// Sample rate, Hz.
    pub sample_rate_hz: f64,
    /// Headings of the four box legs, degrees clockwise from north.
    pub box_headings_deg: [f64; 4],
    /// Survey line heading, degrees; lines alternate with its reciprocal.
    pub line_heading_deg: f64,
    /// Number of survey lines.
    pub line_count: usize,
    /// Duration of one survey line, s.
    pub line_duration_s: f64,
    /// Ground speed, m/s.
    pub speed_m_s: f64,
    /// Box altitude above ground, m.
    pub box_altitude_m: f64,
    /// Survey altitude above ground, m.
    pub survey_altitude_m: f64,
    /// Main-field magnitude, nT.
    pub earth_total_nt: f64,
    /// Main-field inclination, degrees (down positive).
    pub inclination_deg: f64,
    /// Main-field declination, degrees (east positive).
    pub declination_deg: f64,
}

impl Default for SampleFlightSpec {
    fn default() -> Self {
        SampleFlightSpec {
            start_time_s: 46_000.0,
            sample_rate_hz: 10.0,
            box_headings_deg: [20.0, 110.0, 200.0, 290.0],
            line_heading_deg: 0.0,
            line_count: 4,
            line_duration_s: 150.0,
            speed_m_s: 60.0,
            box_altitude_m: 3000.0,
            survey_altitude_m: 300.0,
            earth_total_nt: 52_000.0,
            inclination_deg: 68.0,
            declination_deg: -12.0,
        }
    }
}

/// A generated flight.
#[derive(Debug, Clone, PartialEq)]
pub struct SampleFlight {
    /// Sample times, s.
    pub time_s: Vec<f64>,
    /// Columns in output order (SGL names).
    pub columns: Vec<(String, Vec<f64>)>,
    /// The manoeuvre windows (the oscillations; a fit widens them).
    pub manoeuvres: Vec<CalibrationWindow>,
    /// Start and end of the box, s.
    pub calibration_box: (f64, f64),
}

/// Attitude and flight state of one sample.
#[derive(Debug, Clone, Copy, Default)]
struct State {
    roll_deg: f64,
    pitch_deg: f64,
    yaw_deg: f64,
    altitude_m: f64,
    line: f64,
}

/// Builds the attitude timeline: box with manoeuvres, turns, survey lines.
struct Timeline<'a> {
    spec: &'a SampleFlightSpec,
    random: &'a mut Random,
    states: Vec<State>,
    manoeuvres: Vec<CalibrationWindow>,
}

impl Timeline<'_> {
    fn dt(&self) -> f64 {
        1.0 / self.spec.sample_rate_hz
    }

    fn now(&self) -> f64 {
        self.spec.start_time_s + self.states.len() as f64 * self.dt()
    }

    fn level(&mut self, seconds: f64, heading: f64, altitude: f64, line: f64, turbulence_deg: f64) {
        let samples = (seconds * self.spec.sample_rate_hz).round() as usize;
        let (mut roll, mut pitch, mut yaw) = (0.0, 0.0, 0.0);
        let smoothing: f64 = 0.97;
        for _ in 0..samples {
            let kick = (1.0 - smoothing * smoothing).sqrt() * turbulence_deg;
            roll = smoothing * roll + kick * self.random.normal();
            pitch = smoothing * pitch + 0.6 * kick * self.random.normal();
            yaw = smoothing * yaw + 0.4 * kick * self.random.normal();
            self.states.push(State {
                roll_deg: roll,
                pitch_deg: pitch,
                yaw_deg: heading + yaw,
                altitude_m: altitude,
                line,
            });
        }
    }

    fn manoeuvre(&mut self, kind: ManoeuvreKind, heading: f64, altitude: f64) {
        let cycles = 3.0;
        let period = self.random.uniform(4.5, 8.0);
        let nominal = match kind {
            ManoeuvreKind::Pitch => 5.0,
            ManoeuvreKind::Roll => 10.0,
            ManoeuvreKind::Yaw => 5.0,
        };
        let amplitude = nominal * self.random.uniform(0.8, 1.2);
        self.level(5.0, heading, altitude, 0.0, 0.05);
        let t_start = self.now();
        let samples = (cycles * period * self.spec.sample_rate_hz).round() as usize;
        for k in 0..samples {
            let angle = amplitude * (2.0 * PI * k as f64 * self.dt() / period).sin();
            let mut state = State {
                yaw_deg: heading,
                altitude_m: altitude,
                ..State::default()
            };
            match kind {
                ManoeuvreKind::Pitch => state.pitch_deg = angle,
                ManoeuvreKind::Roll => state.roll_deg = angle,
                ManoeuvreKind::Yaw => state.yaw_deg += angle,
            }
            self.states.push(state);
        }
        let t_end = self.now() - self.dt();
        self.level(5.0, heading, altitude, 0.0, 0.05);
        self.manoeuvres.push(CalibrationWindow {
            t_start,
            t_end,
            label: String::new(),
            kind: Some(kind),
            heading_deg: Some(heading),
        });
    }

    /// A coordinated turn at 3°/s with 20° of bank, rolled in and out.
    fn turn(&mut self, from: f64, to: f64, altitude: f64) {
        let change = (to - from + 540.0).rem_euclid(360.0) - 180.0;
        let seconds = change.abs() / 3.0;
        let samples = (seconds * self.spec.sample_rate_hz).round().max(1.0) as usize;
        for k in 0..samples {
            let fraction = k as f64 / samples as f64;
            let bank = 20.0 * change.signum() * (PI * fraction).sin().powf(0.5);
            self.states.push(State {
                roll_deg: bank,
                yaw_deg: (from + change * fraction).rem_euclid(360.0),
                altitude_m: altitude,
                ..State::default()
            });
        }
    }
}

/// Generates the sample flight for `spec` and `seed`; the same inputs give
/// bit-identical output.
pub fn generate(spec: &SampleFlightSpec, seed: u64) -> SampleFlight {
    let mut random = Random::new(seed);
    let mut timeline = Timeline {
        spec,
        random: &mut random,
        states: Vec::new(),
        manoeuvres: Vec::new(),
    };
    let box_start = timeline.now();
    for (leg, &heading) in spec.box_headings_deg.iter().enumerate() {
        timeline.level(15.0, heading, spec.box_altitude_m, 0.0, 0.05);
        for kind in [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw] {
            timeline.manoeuvre(kind, heading, spec.box_altitude_m);
        }
        timeline.level(10.0, heading, spec.box_altitude_m, 0.0, 0.05);
        let next = spec
            .box_headings_deg
            .get(leg + 1)
            .copied()
            .unwrap_or(spec.line_heading_deg);
        timeline.turn(heading, next, spec.box_altitude_m);
    }
    let box_end = timeline.now();
    timeline.level(60.0, spec.line_heading_deg, spec.survey_altitude_m, 0.0, 0.3);
    for line in 0..spec.line_count {
        let heading = (spec.line_heading_deg + 180.0 * (line % 2) as f64).rem_euclid(360.0);
        timeline.level(
            spec.line_duration_s,
            heading,
            spec.survey_altitude_m,
            1001.0 + line as f64,
            0.8,
        );
        timeline.turn(heading, heading + 180.0, spec.survey_altitude_m);
    }
    let states = std::mem::take(&mut timeline.states);
    let manoeuvres = std::mem::take(&mut timeline.manoeuvres);
    let columns = sensor_columns(spec, &states, &mut random);
    let time_s = (0..states.len())
        .map(|k| spec.start_time_s + k as f64 / spec.sample_rate_hz)
        .collect();
    SampleFlight {
        time_s,
        columns,
        manoeuvres,
        calibration_box: (box_start, box_end),
    }
}

/// Rotates a north-east-down vector into body axes at `state`'s attitude.
fn to_body(v: Vector, state: &State) -> Vector {
    crate::simulate::physics::to_body(v, state.roll_deg, state.pitch_deg, state.yaw_deg)
}

/// An aircraft's field model at one sensor: P (nT), A (dimensionless), E (s).
struct AircraftField {
    permanent_nt: Vector,
    induced: [Vector; 3],
    eddy_s: [Vector; 3],
}

impl AircraftField {
    fn random(random: &mut Random, permanent_nt: f64, induced: f64, eddy_s: f64) -> Self {
        let mut draw = |scale: f64| [0, 1, 2].map(|_| scale * random.uniform(-1.0, 1.0));
        AircraftField {
            permanent_nt: draw(permanent_nt),
            induced: [draw(induced), draw(induced), draw(induced)],
            eddy_s: [draw(eddy_s), draw(eddy_s), draw(eddy_s)],
        }
    }

    fn at(&self, field: Vector, rate: Vector) -> Vector {
        [0, 1, 2].map(|i| {
            self.permanent_nt[i]
                + (0..3)
                    .map(|j| self.induced[i][j] * field[j] + self.eddy_s[i][j] * rate[j])
                    .sum::<f64>()
        })
    }
}

/// The sample flight's columns, in the order [`sensor_columns`] fills
/// them.
const SAMPLE_COLUMNS: [&str; 15] = [
    "mag_1_uc",
    "mag_2_uc",
    "flux_a_x",
    "flux_a_y",
    "flux_a_z",
    "ins_pitch",
    "ins_roll",
    "ins_yaw",
    "lat",
    "lon",
    "msl",
    "line",
    "diurnal",
    "cur_strb",
    "vol_bus",
];

fn sensor_columns(spec: &SampleFlightSpec, states: &[State], random: &mut Random) -> Vec<(String, Vec<f64>)> {
    let n = states.len();
    let dt = 1.0 / spec.sample_rate_hz;
    let (inc, dec) = (spec.inclination_deg.to_radians(), spec.declination_deg.to_radians());
    let main = [inc.cos() * dec.cos(), inc.cos() * dec.sin(), inc.sin()].map(|c| c * spec.earth_total_nt);
    let dipoles = random_dipoles(random);
    let tail = AircraftField::random(random, 3.0, 6e-5, 3e-5);
    let cabin = AircraftField::random(random, 120.0, 2e-3, 5e-4);
    let fluxgate_own = AircraftField::random(random, 2.0, 5e-5, 0.0);
    let diurnal_phase = random.uniform(0.0, 2.0 * PI);
    let heading_path = path_positions(spec, states);
    let mut columns: Vec<(String, Vec<f64>)> = (SAMPLE_COLUMNS.iter())
        .map(|name| (name.to_string(), Vec::with_capacity(n)))
        .collect();
    let body_fields = earth_field_in_body(spec, states, (&main, &dipoles), (&heading_path, diurnal_phase));
    let body: Vec<Vector> = body_fields.iter().map(|(b, _)| *b).collect();
    let rate = rates(&body, dt);
    for k in 0..n {
        let (b, diurnal) = body_fields[k];
        let state = &states[k];
        let scalar = |field: &AircraftField, noise: f64, random: &mut Random| {
            let total = field.at(b, rate[k]);
            let sum = [0, 1, 2].map(|i| b[i] + total[i]);
            (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]).sqrt() + noise * random.normal()
        };
        let own = fluxgate_own.at(b, rate[k]);
        let (north, east, _) = heading_path[k];
        let t = k as f64 * dt;
        let strobe = if (t * 1.05).fract() < 0.08 { 2.5 } else { 0.1 };
        let values = [
            scalar(&tail, 0.01, random),
            scalar(&cabin, 0.02, random),
            b[0] + own[0] + 0.3 * random.normal(),
            b[1] + own[1] + 0.3 * random.normal(),
            b[2] + own[2] + 0.3 * random.normal(),
            state.pitch_deg,
            state.roll_deg,
            state.yaw_deg.rem_euclid(360.0),
            45.0 + north / 111_320.0,
            -75.0 + east / (111_320.0 * 45f64.to_radians().cos()),
            state.altitude_m + 80.0,
            state.line,
            diurnal + 0.05 * random.normal(),
            strobe + 0.01 * random.normal(),
            28.0 + 0.05 * random.normal(),
        ];
        for (column, value) in columns.iter_mut().zip(values) {
            column.1.push(value);
        }
    }
    columns
}

/// Six crustal dipoles below the sample flight's area: position (m, north
/// east down) and moment.
fn random_dipoles(random: &mut Random) -> Vec<(Vector, Vector)> {
    (0..6)
        .map(|_| {
            let position = [
                random.uniform(-2000.0, 10_000.0),
                random.uniform(-3000.0, 3000.0),
                random.uniform(400.0, 900.0),
            ];
            let moment = [
                random.uniform(-1.0, 1.0),
                random.uniform(-1.0, 1.0),
                random.uniform(0.5, 1.5),
            ]
            .map(|c| c * 2e8);
            (position, moment)
        })
        .collect()
}

/// The Earth's field (main, crust and diurnal variation) in the body
/// frame at each state, with the diurnal variation, nT.
fn earth_field_in_body(
    spec: &SampleFlightSpec,
    states: &[State],
    (main, dipoles): (&Vector, &[(Vector, Vector)]),
    (heading_path, diurnal_phase): (&[(f64, f64, f64)], f64),
) -> Vec<(Vector, f64)> {
    let dt = 1.0 / spec.sample_rate_hz;
    states
        .iter()
        .enumerate()
        .map(|(k, state)| {
            let (north, east, _) = heading_path[k];
            let observer = [north, east, -state.altitude_m];
            let crust = dipoles.iter().fold([0.0; 3], |acc, (position, moment)| {
                let b = dipole_field_nt(*moment, [0, 1, 2].map(|i| observer[i] - position[i]));
                [acc[0] + b[0], acc[1] + b[1], acc[2] + b[2]]
            });
            let t = k as f64 * dt;
            let diurnal = 8.0 * (2.0 * PI * t / 3600.0 + diurnal_phase).sin() + 1.5 * (2.0 * PI * t / 600.0).sin();
            let unit_main = main.map(|c| c / spec.earth_total_nt);
            let ned = [0, 1, 2].map(|i| main[i] + crust[i] + diurnal * unit_main[i]);
            (to_body(ned, state), diurnal)
        })
        .collect()
}

/// The rate of change of each body-frame field by central differences
/// (one-sided at the ends), nT/s.
fn rates(body: &[Vector], dt: f64) -> Vec<Vector> {
    let n = body.len();
    (0..n)
        .map(|k| {
            let (a, b) = (body[k.saturating_sub(1)], body[(k + 1).min(n - 1)]);
            let span = ((k + 1).min(n - 1) - k.saturating_sub(1)) as f64 * dt;
            [0, 1, 2].map(|i| (b[i] - a[i]) / span)
        })
        .collect()
}

/// North and east positions (m) integrated from heading and speed.
fn path_positions(spec: &SampleFlightSpec, states: &[State]) -> Vec<(f64, f64, f64)> {
    let dt = 1.0 / spec.sample_rate_hz;
    let (mut north, mut east) = (-4000.0, -1500.0);
    states
        .iter()
        .map(|state| {
            let heading = state.yaw_deg.to_radians();
            north += spec.speed_m_s * dt * heading.cos();
            east += spec.speed_m_s * dt * heading.sin();
            (north, east, state.altitude_m)
        })
        .collect()
}

/// Writes the flight as CSV and its manoeuvre windows as DETECT.json.
pub fn write(flight: &SampleFlight, csv_path: &Path, windows_path: &Path) -> Result<()> {
    let csv = stage(csv_path, |w| {
        let names: Vec<&str> = flight.columns.iter().map(|(n, _)| n.as_str()).collect();
        writeln!(w, "tt,{}", names.join(","))?;
        for (k, t) in flight.time_s.iter().enumerate() {
            write!(w, "{t:.1}")?;
            for (name, values) in &flight.columns {
                let decimals = if name.starts_with("mag_") || name == "diurnal" {
                    3
                } else if name.starts_with("lat") || name.starts_with("lon") {
                    7
                } else {
                    3
                };
                write!(w, ",{:.*}", decimals, values[k])?;
            }
            writeln!(w)?;
        }
        Ok(())
    })?;
    let windows = stage_detect_json(windows_path, &flight.manoeuvres, &[flight.calibration_box])?;
    let mut set = OutputSet::new();
    set.add(csv);
    set.add(windows);
    set.commit().map(drop)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_seed_gives_the_same_flight() {
        let spec = SampleFlightSpec {
            line_count: 1,
            line_duration_s: 20.0,
            ..SampleFlightSpec::default()
        };
        assert_eq!(generate(&spec, 7), generate(&spec, 7));
        assert_ne!(generate(&spec, 7).columns[0].1, generate(&spec, 8).columns[0].1);
    }
}
