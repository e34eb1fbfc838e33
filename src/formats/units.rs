//! Units a flight's columns are read in, checked against what they hold.
//!
//! magcomp reads time in seconds and the INS attitude in degrees
//! (CONTRACT §1). A file in other units reads without error and then fails
//! far from the cause: time in milliseconds makes a 10 Hz flight's
//! samples 100 s apart, and attitude in radians leaves every manoeuvre a
//! few hundredths of a degree. Each check here looks for a sign no flight
//! in the right units shows and returns a warning that says what to
//! convert.

use std::f64::consts::FRAC_PI_2;
use std::path::Path;

use crate::ingest::flight_log::{AttitudeAngle, ChannelRole, FlightLog};
use crate::messages::{Reading, Warning};

/// A median step above this, s, is no survey recording: calibration needs
/// several samples per manoeuvre period (5–20 s), and magnetometers and
/// fluxgates record at 1–1,000 Hz.
pub const MAX_MEDIAN_INTERVAL_S: f64 = 5.0;

/// The fluxgate's horizontal field turning through more than this, °, is a
/// flight that turned.
const TURNED_DEG: f64 = 60.0;

/// Warnings for columns whose values show they are not in the units
/// magcomp reads; `file` names the flight in them.
pub fn unit_warnings(file: &Path, log: &FlightLog) -> Vec<Warning> {
    let mut warnings = Vec::new();
    let step_s = log.median_interval_s();
    if step_s > MAX_MEDIAN_INTERVAL_S {
        warnings.push(
            Reading::TimeNotInSeconds {
                file: file.to_path_buf(),
                column: log.time_column().to_string(),
                step: step_s,
            }
            .into(),
        );
    }
    if let Some(warning) = attitude_in_radians(file, log) {
        warnings.push(warning.into());
    }
    warnings.extend(declared_unit_warnings(file, log));
    warnings
}

/// What a column of each kind is read in, and the ways a row of units
/// writes that unit (compared without case).
fn read_in(role: Option<&ChannelRole>) -> Option<(&'static str, &'static [&'static str])> {
    match role {
        None => Some(("seconds", &["s", "sec", "secs", "second", "seconds"])),
        Some(ChannelRole::Attitude(_)) => Some(("degrees", &["deg", "degs", "degree", "degrees", "°"])),
        Some(
            ChannelRole::ScalarMagnetometer
            | ChannelRole::VectorMagnetometer { .. }
            | ChannelRole::VectorTotal { .. }
            | ChannelRole::BaseStation,
        ) => Some(("nT", &["nt", "nanotesla", "gamma"])),
        _ => None,
    }
}

/// A warning for each column whose unit, in the input's row of units, is
/// not the one magcomp reads it in (time in ms, attitude in radians, a
/// field in µT); an empty cell says nothing.
fn declared_unit_warnings(file: &Path, log: &FlightLog) -> Vec<Warning> {
    log.declared_units()
        .iter()
        .filter_map(|(column, unit)| {
            let role = match column == log.time_column() {
                true => None,
                false => Some(&log.channel(column)?.role),
            };
            let (wanted, spellings) = read_in(role)?;
            let given = unit
                .trim()
                .trim_matches(|c| matches!(c, '(' | ')' | '[' | ']'))
                .to_lowercase();
            (!given.is_empty() && !spellings.contains(&given.as_str())).then(|| {
                Reading::UnitNotRead {
                    file: file.to_path_buf(),
                    unit: unit.clone(),
                    column: column.clone(),
                    read_in: wanted.to_string(),
                }
                .into()
            })
        })
        .collect()
}

/// A warning when pitch and roll never leave ±π/2 although the aircraft
/// turned: through more than [`TURNED_DEG`] of yaw read as degrees (pitch
/// and roll in radians beside a yaw in degrees), or through more than 1
/// of yaw read as radians while the fluxgate's field turned more than
/// [`TURNED_DEG`] in the aircraft's axes (all three in radians). Any turn
/// of that size banks the aircraft beyond 1.6°; a calm straight line under
/// a near-vertical field, where roll alone swings the horizontal field,
/// turns its yaw by neither.
fn attitude_in_radians(file: &Path, log: &FlightLog) -> Option<Reading> {
    let angle = |wanted: AttitudeAngle| {
        let channel = (log.channels().iter()).find(|c| c.role == ChannelRole::Attitude(wanted))?;
        let finite: Vec<f64> = channel.values.iter().copied().filter(|v| v.is_finite()).collect();
        (!finite.is_empty()).then_some(finite)
    };
    let (pitch, roll, yaw) = (
        angle(AttitudeAngle::Pitch)?,
        angle(AttitudeAngle::Roll)?,
        angle(AttitudeAngle::Yaw)?,
    );
    let within = |values: &[f64], limit: f64| values.iter().all(|v| v.abs() <= limit + 1e-6);
    if !(within(&pitch, FRAC_PI_2) && within(&roll, FRAC_PI_2)) {
        return None;
    }
    let yaw_turn_deg = unwrapped_range(yaw.iter().copied(), 360.0);
    if yaw_turn_deg > TURNED_DEG {
        return Some(Reading::PitchRollInRadians {
            file: file.to_path_buf(),
            yaw_turn_deg,
        });
    }
    let yaw_range =
        yaw.iter().copied().fold(f64::NEG_INFINITY, f64::max) - yaw.iter().copied().fold(f64::INFINITY, f64::min);
    let field_turn_deg = (log.vector_sensors().iter())
        .map(|sensor| horizontal_turn_deg(sensor.axes.map(|axis| log.channels()[axis].values.as_slice())))
        .fold(0.0, f64::max);
    (yaw_range > 1.0 && field_turn_deg > TURNED_DEG).then(|| Reading::AttitudeInRadians {
        file: file.to_path_buf(),
        yaw_span: yaw_range,
        field_turn_deg,
    })
}

/// The range of `values` unwrapped with period `period` (a step larger
/// than half a period is taken the short way round).
fn unwrapped_range(values: impl Iterator<Item = f64>, period: f64) -> f64 {
    let half = period / 2.0;
    let mut values = values;
    let Some(first) = values.next() else {
        return 0.0;
    };
    let (mut previous, mut unwrapped, mut low, mut high) = (first, first, first, first);
    for value in values {
        unwrapped += (value - previous + period + half).rem_euclid(period) - half;
        previous = value;
        low = low.min(unwrapped);
        high = high.max(unwrapped);
    }
    high - low
}

/// The range, °, through which the field's direction in the sensor's x-y
/// plane turns over the flight, unwrapped across ±180°.
fn horizontal_turn_deg([x, y, _]: [&[f64]; 3]) -> f64 {
    let angles = x
        .iter()
        .zip(y)
        .filter(|(x, y)| x.is_finite() && y.is_finite() && x.hypot(**y) > 0.0)
        .map(|(x, y)| y.atan2(*x).to_degrees());
    unwrapped_range(angles, 360.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::flight_log::{Channel, VectorAxis};

    /// A flight turning once through 360° at 10 Hz: the fluxgate's
    /// horizontal field turns with it, and the attitude is written in
    /// degrees, or in radians when `radians`.
    fn turning_flight(radians: bool, step_s: f64) -> FlightLog {
        let rows = 600;
        let heading_deg: Vec<f64> = (0..rows).map(|i| i as f64 * 360.0 / rows as f64).collect();
        let unit = if radians { 1f64.to_radians() } else { 1.0 };
        let attitude = |angle, values: Vec<f64>| Channel {
            name: format!("{angle:?}"),
            role: ChannelRole::Attitude(angle),
            values: values.into_iter().map(|v| v * unit).collect(),
        };
        let vector = |axis, values: Vec<f64>| Channel {
            name: format!("flux_a_{axis:?}"),
            role: ChannelRole::VectorMagnetometer {
                sensor: "flux_a".into(),
                axis,
            },
            values,
        };
        let north_nt = 20_000.0;
        let channels = vec![
            attitude(AttitudeAngle::Pitch, vec![2.0; rows]),
            attitude(
                AttitudeAngle::Roll,
                (0..rows).map(|i| 10.0 * (i as f64 * 0.1).sin()).collect(),
            ),
            attitude(AttitudeAngle::Yaw, heading_deg.iter().map(|h| h - 180.0).collect()),
            vector(
                VectorAxis::X,
                heading_deg.iter().map(|h| north_nt * h.to_radians().cos()).collect(),
            ),
            vector(
                VectorAxis::Y,
                heading_deg.iter().map(|h| -north_nt * h.to_radians().sin()).collect(),
            ),
            vector(VectorAxis::Z, vec![45_000.0; rows]),
        ];
        let time_s = (0..rows).map(|i| i as f64 * step_s).collect();
        FlightLog::new("turn.csv", "tt", time_s, channels).unwrap()
    }

    #[test]
    fn attitude_in_radians_through_a_turn_is_named() {
        let warnings = unit_warnings(Path::new("turn.csv"), &turning_flight(true, 0.1));
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        // The fluxgate turned through the whole circle: 359.4° of 600 steps.
        let Warning::Reading(Reading::AttitudeInRadians { field_turn_deg, .. }) = warnings[0] else {
            panic!("{warnings:?}")
        };
        assert!((field_turn_deg - 359.4).abs() < 0.05, "{field_turn_deg}");
        assert!(
            warnings[0].to_string().contains("looks like radians"),
            "{}",
            warnings[0]
        );
    }

    #[test]
    fn attitude_in_degrees_is_not_named() {
        assert!(unit_warnings(Path::new("turn.csv"), &turning_flight(false, 0.1)).is_empty());
    }

    /// `log` with the attitude channel `name` set to `value(row)`.
    fn with_angle(log: FlightLog, name: &str, value: impl Fn(usize) -> f64) -> FlightLog {
        log.with_values(name, (0..log.len()).map(value).collect()).unwrap()
    }

    #[test]
    fn pitch_and_roll_in_radians_beside_a_yaw_in_degrees_are_named() {
        let log = turning_flight(false, 0.1);
        let log = with_angle(log, "Pitch", |_| 2f64.to_radians());
        let log = with_angle(log, "Roll", |i| (10.0 * (i as f64 * 0.1).sin()).to_radians());
        let warnings = unit_warnings(Path::new("turn.csv"), &log);
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        let Warning::Reading(Reading::PitchRollInRadians { yaw_turn_deg, .. }) = warnings[0] else {
            panic!("{warnings:?}")
        };
        assert!((yaw_turn_deg - 359.4).abs() < 0.05, "{yaw_turn_deg}");
        assert!(
            (warnings[0].to_string())
                .contains("pitch and roll never exceed π/2 in size although the yaw turned through 359°"),
            "{}",
            warnings[0]
        );
    }

    /// Near a dip pole the horizontal field is small and roll alone swings
    /// its direction: a calm straight line in degrees (yaw within ±0.4° in
    /// the ±180° convention, roll within ±0.8°) under a field that turns
    /// through the whole circle in the aircraft's axes is not named.
    #[test]
    fn a_calm_straight_line_under_a_steep_field_is_not_named() {
        let log = turning_flight(false, 0.1);
        let log = with_angle(log, "Yaw", |i| 0.4 * (i as f64 * 0.01).sin());
        let log = with_angle(log, "Roll", |i| 0.8 * (i as f64 * 0.1).sin());
        let log = with_angle(log, "Pitch", |_| 0.5);
        assert!(unit_warnings(Path::new("line.csv"), &log).is_empty());
    }

    #[test]
    fn time_in_milliseconds_is_named() {
        let warnings = unit_warnings(Path::new("turn.csv"), &turning_flight(false, 100.0));
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        let Warning::Reading(Reading::TimeNotInSeconds { step, .. }) = warnings[0] else {
            panic!("{warnings:?}")
        };
        assert_eq!(step, 100.0);
        assert!(
            warnings[0].to_string().contains("steps 100 between samples"),
            "{}",
            warnings[0]
        );
    }

    #[test]
    fn the_turn_is_unwrapped_across_the_date_line_of_angles() {
        // 170° to -170° is a 20° turn, not 340°.
        let z = [0.0; 3];
        let angles_deg = [170.0f64, 180.0, -170.0];
        let cos: Vec<f64> = angles_deg.iter().map(|a| a.to_radians().cos()).collect();
        let sin: Vec<f64> = angles_deg.iter().map(|a| a.to_radians().sin()).collect();
        let turn = horizontal_turn_deg([&cos, &sin, &z]);
        assert!((turn - 20.0).abs() < 1e-9, "{turn}");
    }
}
