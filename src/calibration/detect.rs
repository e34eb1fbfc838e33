//! Automatic detection of calibration boxes and their manoeuvres.
//!
//! A calibration box is a sequence of straight legs on different headings,
//! each carrying pitch, roll and yaw oscillations. Detection works in four
//! steps, every threshold in [`DetectOptions`]:
//!
//! 1. **Legs.** The heading is smoothed by a centred circular mean over
//!    `heading_smoothing_s` (long enough to average a yaw manoeuvre away);
//!    samples whose smoothed heading turns slower than `straight_rate_deg_s`
//!    are straight. Straight runs on one heading, joined across short
//!    interruptions, lasting at least `min_leg_s`, are legs.
//! 2. **Activity.** On each leg, each axis's deviation from level flight
//!    (pitch and roll from the leg's median, yaw from the smoothed heading,
//!    so a wandering track does not count) gives a centred RMS envelope.
//!    Where it exceeds both an absolute floor per axis and a multiple of the
//!    leg's own turbulence level, the axis is active. Where two axes are
//!    active together, the one larger against its nominal amplitude wins.
//! 3. **Refinement.** Each active region is measured against a baseline
//!    interpolated from the level flight on either side. The oscillation runs
//!    from the zero crossing before its first strong half-cycle to the zero
//!    crossing after its last. Half-cycles give the cycle count, period and
//!    amplitude. A region with fewer than three strong half-cycles, or with
//!    irregular half-cycles, is not a manoeuvre: it is dropped, never
//!    reported as a fragment.
//! 4. **Boxes.** Consecutive legs carrying manoeuvres form a box; a heading
//!    flown again starts the next box. Each box reports which manoeuvres it
//!    lacks ("no yaw on heading 290").
//!
//! Without INS attitude the fluxgate stands in: the magnetic heading from
//! the horizontal field in body axes, and for each leg the small rotation
//! $u_{ref} \times u$ of the field direction, whose direction tells which
//! axis turned (a rotation about the field itself is invisible).

use std::ops::{Range, RangeInclusive};

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use serde::Serialize;

use crate::calibration::headings::heading_difference;
use crate::calibration::windows::{CalibrationWindow, ManoeuvreKind};
use crate::error::{Error, Result};
use crate::ingest::flight_log::{AttitudeAngle, ChannelRole, FlightLog};
use crate::messages::{Note, Warning};

/// Detection thresholds (`[detect]` in pipeline.toml).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DetectOptions {
    /// Window of the circular mean that smooths the heading, s.
    pub heading_smoothing_s: f64,
    /// Largest smoothed turn rate of a straight leg, degrees/s.
    pub straight_rate_deg_s: f64,
    /// Shortest leg, s.
    pub min_leg_s: f64,
    /// Straight runs this close in time and heading join into one leg (s, degrees).
    pub join_gap_s: f64,
    /// Heading difference that separates two legs, degrees.
    pub heading_tolerance_deg: f64,
    /// A leg's ends are cut where the heading leaves its centre by more than this, degrees.
    pub turn_heading_deg: f64,
    /// ... or where the bank exceeds this, degrees.
    pub turn_bank_deg: f64,
    /// Window of the RMS envelope, s.
    pub envelope_s: f64,
    /// Smallest RMS deviation of an active pitch, roll and yaw, degrees.
    pub min_rms_deg: [f64; 3],
    /// Smallest RMS rotation of the field direction that counts as active
    /// when the fluxgate stands in for the INS, degrees.
    pub fluxgate_min_rms_deg: f64,
    /// Activity must also exceed this multiple of the leg's turbulence level.
    pub turbulence_factor: f64,
    /// Nominal amplitudes of pitch, roll and yaw manoeuvres, degrees (to
    /// compare axes when the fluxgate stands in for the INS).
    pub nominal_amplitude_deg: [f64; 3],
    /// What each axis's activity is divided by, degrees, to tell which one
    /// the pilot drove where several move together. An airframe answers a
    /// roll with adverse yaw (0.25–0.3× the roll on a real survey aircraft)
    /// and a yaw with roll (0.4–0.46× the yaw): a roll over 6/5 of the yaw
    /// it carries is a roll, so a roll with up to 0.8× adverse yaw and a yaw
    /// with up to 1.2× roll are named right.
    pub dominance_deg: [f64; 3],
    /// A stretch where one axis dominates for less than this, s, belongs to
    /// its neighbour (a manoeuvre is at least two cycles of 3 s).
    pub min_dominance_s: f64,
    /// Smallest peak of a pitch, roll and yaw manoeuvre, degrees.
    pub min_amplitude_deg: [f64; 3],
    /// Active stretches closer than this join, s.
    pub join_activity_s: f64,
    /// Fewest strong half-cycles of a manoeuvre (4: two cycles).
    pub min_half_cycles: usize,
    /// Largest spread of half-cycle durations (standard deviation / mean).
    pub max_half_cycle_spread: f64,
    /// Largest spread of half-cycle peaks (standard deviation / mean).
    pub max_peak_spread: f64,
    /// Longest pause between two legs of one box, s.
    pub max_turn_s: f64,
    /// A leg that runs on straight for longer than this before its first
    /// or after its last manoeuvre (a climb before it, a descent or a
    /// survey line on the same heading after it) is cut this far from the
    /// manoeuvre; the rest becomes a leg of its own, s.
    pub leg_run_on_s: f64,
    /// Level flight kept on each side of a detected manoeuvre when it becomes
    /// a calibration window, s.
    pub window_margin_s: f64,
}

impl Default for DetectOptions {
    fn default() -> Self {
        DetectOptions {
            heading_smoothing_s: 20.0,
            straight_rate_deg_s: 1.0,
            min_leg_s: 18.0,
            join_gap_s: 15.0,
            heading_tolerance_deg: 15.0,
            turn_heading_deg: 9.0,
            turn_bank_deg: 15.0,
            envelope_s: 3.0,
            min_rms_deg: [1.2, 2.5, 1.2],
            fluxgate_min_rms_deg: 0.5,
            turbulence_factor: 3.0,
            nominal_amplitude_deg: [5.0, 10.0, 5.0],
            dominance_deg: [5.0, 6.0, 5.0],
            min_dominance_s: 3.0,
            min_amplitude_deg: [2.0, 4.0, 2.0],
            join_activity_s: 2.0,
            min_half_cycles: 4,
            max_half_cycle_spread: 0.4,
            max_peak_spread: 0.3,
            max_turn_s: 300.0,
            leg_run_on_s: 30.0,
            window_margin_s: 5.0,
        }
    }
}

/// Where the attitude came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum AttitudeSource {
    /// INS roll, pitch and yaw.
    Ins,
    /// Fluxgate direction cosines (no INS in the file).
    Fluxgate,
}

/// One detected manoeuvre (CONTRACT §3 fields, then measurements).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DetectedManoeuvre {
    /// Pitch, roll or yaw.
    pub kind: ManoeuvreKind,
    /// Heading of the leg, degrees (magnetic when from the fluxgate).
    pub heading_deg: f64,
    /// First sample of the oscillation.
    pub t_start: f64,
    /// Last sample of the oscillation.
    pub t_end: f64,
    /// Whole cycles.
    pub cycles: f64,
    /// Median peak deviation, degrees.
    pub amplitude_deg: f64,
    /// Mean period, s.
    pub period_s: f64,
    /// The other kind this manoeuvre may be. With the fluxgate alone, two
    /// rotations turn the field direction alike when the field lies near
    /// the plane of their axes (pitch and yaw on east and west headings,
    /// roll and yaw on north and south, at high inclination): there they
    /// are told apart by their size only, and the name is uncertain.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub could_be: Option<ManoeuvreKind>,
}

/// A straight leg.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Leg {
    /// Heading, degrees.
    pub heading_deg: f64,
    /// Start time.
    pub t_start: f64,
    /// End time.
    pub t_end: f64,
    /// Rows of the flight.
    #[serde(skip)]
    pub rows: Range<usize>,
}

/// One calibration box.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DetectedBox {
    /// Start of its first leg.
    pub t_start: f64,
    /// End of its last leg.
    pub t_end: f64,
    /// Headings of its legs, in flying order.
    pub headings_deg: Vec<f64>,
    /// Manoeuvres expected but not found, e.g. "no yaw on heading 290".
    pub missing: Vec<String>,
}

/// What detection found (DETECT.json).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Detection {
    /// Manoeuvres in time order.
    pub manoeuvres: Vec<DetectedManoeuvre>,
    /// Calibration boxes.
    pub boxes: Vec<DetectedBox>,
    /// Where the attitude came from.
    pub attitude_source: AttitudeSource,
    /// Every straight leg, with or without manoeuvres.
    pub legs: Vec<Leg>,
    /// Remarks for the user.
    pub notes: Vec<Note>,
    /// With the fluxgate standing in for the INS: the median angle, °, by
    /// which the field dips below the aircraft's x-y plane (the
    /// inclination, in level flight).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fluxgate_dip_deg: Option<f64>,
    /// Spans (start, end) of at least [`ATTITUDE_GAP_S`] where the INS
    /// attitude is missing: legs and manoeuvres there cannot be seen.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub attitude_gaps: Vec<(f64, f64)>,
    /// Manoeuvres found whose windows gaps in the fluxgate or scalar
    /// readings leave too short to band-pass: left out of the fit (their
    /// labels).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub left_out_in_gaps: Vec<String>,
}

/// A stretch without INS attitude this long, s, can hide a manoeuvre
/// (two cycles of a 5 s period).
pub const ATTITUDE_GAP_S: f64 = 10.0;

/// How far before or after an incomplete box, s, an attitude gap can hide
/// a leg of it (a turn and a leg).
const GAP_REACH_S: f64 = 300.0;

/// A field dipping more than this, °, leaves the fluxgate a horizontal
/// part too small to give the heading well, and a yaw (a turn about the
/// near-vertical field) turns the field direction by under
/// cos(75°) = 0.26 of its angle: manoeuvres may be flown and not seen.
pub const STEEP_DIP_DEG: f64 = 75.0;

impl Detection {
    /// A warning when the INS attitude has gaps and the detection found
    /// manoeuvres missing (or none): what was flown in a gap is not seen.
    pub fn attitude_gap_warning(&self) -> Option<Warning> {
        // A gap can hide what an incomplete box lacks when it lies in the
        // box or the turns around it; with no manoeuvre found, anywhere.
        let near = |&&(start, end): &&(f64, f64)| {
            self.manoeuvres.is_empty()
                || (self.boxes.iter())
                    .any(|b| !b.missing.is_empty() && start <= b.t_end + GAP_REACH_S && end >= b.t_start - GAP_REACH_S)
        };
        let spans: Vec<(f64, f64)> = self.attitude_gaps.iter().filter(near).copied().collect();
        (!spans.is_empty()).then_some(Warning::AttitudeGaps { spans })
    }

    /// A warning when the fluxgate stood in for the INS under a steep field
    /// and the detection found manoeuvres missing (or none): they may have
    /// been flown and not seen.
    pub fn steep_field_warning(&self) -> Option<Warning> {
        let dip_deg = self.fluxgate_dip_deg?;
        let incomplete = self.manoeuvres.is_empty() || self.boxes.iter().any(|b| !b.missing.is_empty());
        (dip_deg.abs() > STEEP_DIP_DEG && incomplete).then(|| Warning::SteepField { dip_deg: dip_deg.abs() })
    }

    /// What was found on the calibration lines `spans` (line, start, end)
    /// only: the manoeuvres within one, and the legs and boxes that reach
    /// into one; a note says which lines gave how many.
    pub fn on_lines(mut self, spans: &[(f64, f64, f64)]) -> Detection {
        let inside = |start: f64, end: f64| spans.iter().any(|(_, a, b)| start >= *a && end <= *b);
        let touches = |start: f64, end: f64| spans.iter().any(|(_, a, b)| start <= *b && end >= *a);
        self.manoeuvres.retain(|m| inside(m.t_start, m.t_end));
        self.legs.retain(|leg| touches(leg.t_start, leg.t_end));
        self.boxes.retain(|b| touches(b.t_start, b.t_end));
        let mut lines: Vec<f64> = spans.iter().map(|s| s.0).collect();
        lines.dedup();
        let counts: Vec<(f64, usize)> = (lines.iter())
            .map(|&line| {
                let on_line = (self.manoeuvres.iter())
                    .filter(|m| {
                        spans
                            .iter()
                            .any(|(l, a, b)| *l == line && m.t_start >= *a && m.t_end <= *b)
                    })
                    .count();
                (line, on_line)
            })
            .collect();
        self.notes.push(Note::ManoeuvresByLine { counts });
        self
    }

    /// The manoeuvres as calibration windows, each with `margin_s` of level
    /// flight on both sides.
    pub fn calibration_windows(&self, margin_s: f64) -> Vec<CalibrationWindow> {
        self.manoeuvres
            .iter()
            .map(|m| CalibrationWindow::manoeuvre(m.kind, m.heading_deg, m.t_start, m.t_end, margin_s))
            .collect()
    }
}

/// Per-sample attitude, degrees, NaN where unknown.
struct Attitude {
    /// Pitch, roll and yaw deviations usable for activity (for the fluxgate:
    /// filled per leg).
    angles: [Vec<f64>; 3],
    heading_deg: Vec<f64>,
    source: AttitudeSource,
    /// Unit field direction in body axes (fluxgate fallback only).
    field_unit: Option<Vec<Vector3<f64>>>,
}

/// The calibration `piece` of a leg (of rows `leg_rows`) widened by one
/// manoeuvre and its pause (60 s) each way, within the leg.
fn widened(log: &FlightLog, piece: &Leg, leg_rows: &Range<usize>) -> Leg {
    let time = log.time_s();
    let reach = samples(60.0, log.median_interval_s());
    let rows = piece.rows.start.saturating_sub(reach).max(leg_rows.start)..(piece.rows.end + reach).min(leg_rows.end);
    Leg {
        heading_deg: piece.heading_deg,
        t_start: time[rows.start],
        t_end: time[rows.end - 1],
        rows,
    }
}

/// Finds the calibration boxes and manoeuvres of a flight.
pub fn detect_manoeuvres(log: &FlightLog, options: &DetectOptions) -> Result<Detection> {
    let attitude = read_attitude(log)?;
    let dt = log.median_interval_s();
    let smoothed = smooth_heading(&attitude.heading_deg, samples(options.heading_smoothing_s, dt));
    let roll = (attitude.source == AttitudeSource::Ins).then_some(attitude.angles[1].as_slice());
    let mut legs = Vec::new();
    let mut manoeuvres = Vec::new();
    for leg in find_legs(log, &attitude.heading_deg, &smoothed, roll, options) {
        let mut found = leg_manoeuvres(log, &attitude, &leg, options);
        let leg_rows = leg.rows.clone();
        let pieces = cut_run_on(log.time_s(), &attitude.heading_deg, leg, &found, options.leg_run_on_s);
        // Once a climb or a line is cut off, the manoeuvres are looked for
        // again on the calibration piece alone, whose level flight is now
        // the only reference (the fluxgate's leans with a climbing nose).
        // The piece is widened by one manoeuvre and its pause (60 s), for
        // one the first look missed beside a climb.
        if pieces.len() > 1 && attitude.source == AttitudeSource::Fluxgate {
            if let Some(piece) = pieces
                .iter()
                .find(|p| found.iter().any(|m| m.t_start >= p.t_start && m.t_end <= p.t_end))
            {
                let again = leg_manoeuvres(log, &attitude, &widened(log, piece, &leg_rows), options);
                if again.len() > found.len() {
                    found = again;
                }
            }
        }
        // A manoeuvre's heading is its piece's: a climb or a line cut off
        // the leg no longer pulls it (the fluxgate's magnetic heading
        // leans with the nose).
        for manoeuvre in &mut found {
            if let Some(piece) = pieces
                .iter()
                .find(|p| manoeuvre.t_start >= p.t_start && manoeuvre.t_end <= p.t_end)
            {
                manoeuvre.heading_deg = piece.heading_deg;
            }
        }
        legs.extend(pieces);
        manoeuvres.extend(found);
    }
    manoeuvres.sort_by(|a, b| a.t_start.total_cmp(&b.t_start));
    let boxes = group_boxes(&legs, &manoeuvres, options);
    let mut notes = Vec::new();
    if attitude.source == AttitudeSource::Fluxgate {
        notes.push(Note::AttitudeFromFluxgate);
    }
    if manoeuvres.is_empty() {
        notes.push(Note::NoManoeuvres);
    }
    Ok(Detection {
        manoeuvres,
        boxes,
        attitude_source: attitude.source,
        legs,
        notes,
        fluxgate_dip_deg: attitude.field_unit.as_deref().and_then(median_dip_deg),
        attitude_gaps: match attitude.source {
            AttitudeSource::Ins => missing_spans(log.time_s(), &attitude.angles, ATTITUDE_GAP_S),
            AttitudeSource::Fluxgate => Vec::new(),
        },
        left_out_in_gaps: Vec::new(),
    })
}

/// Longest run of missing attitude samples detection bridges, s: glitches
/// screened out of the INS record (`crate::ingest::screen`) leave holes of a
/// sample or three, which would otherwise cut every manoeuvre they fall
/// in.
pub const BRIDGED_ATTITUDE_GAP_S: f64 = 1.0;

/// `values` with each run of missing samples no longer than
/// [`BRIDGED_ATTITUDE_GAP_S`] between two finite ones filled by linear
/// interpolation in time; a heading (`wraps`) is interpolated across
/// north (the shorter way round). Longer runs stay missing.
fn bridged(values: &[f64], time_s: &[f64], wraps: bool) -> Vec<f64> {
    let mut out = values.to_vec();
    let mut row = 0;
    while row < values.len() {
        if values[row].is_finite() {
            row += 1;
            continue;
        }
        let start = row;
        while row < values.len() && !values[row].is_finite() {
            row += 1;
        }
        let (Some(before), true) = (start.checked_sub(1), row < values.len()) else {
            continue;
        };
        let span = time_s[row] - time_s[before];
        if !(span > 0.0 && span <= BRIDGED_ATTITUDE_GAP_S + 1e-9) {
            continue;
        }
        let step = match wraps {
            true => (values[row] - values[before] + 180.0).rem_euclid(360.0) - 180.0,
            false => values[row] - values[before],
        };
        for k in start..row {
            out[k] = values[before] + step * (time_s[k] - time_s[before]) / span;
        }
    }
    out
}

/// The spans (first and last time) of at least `min_s` where a row lacks
/// one of `angles`.
fn missing_spans(time_s: &[f64], angles: &[Vec<f64>; 3], min_s: f64) -> Vec<(f64, f64)> {
    let missing = |row: usize| angles.iter().any(|a| !a[row].is_finite());
    let mut spans = Vec::new();
    let mut row = 0;
    while row < time_s.len() {
        if !missing(row) {
            row += 1;
            continue;
        }
        let start = row;
        while row < time_s.len() && missing(row) {
            row += 1;
        }
        let (first, last) = (time_s[start], time_s[row - 1]);
        if last - first >= min_s {
            spans.push((first, last));
        }
    }
    spans
}

/// The median angle, °, of the field below the x-y plane of its unit
/// directions `unit` (body z down); `None` without a finite one.
fn median_dip_deg(unit: &[Vector3<f64>]) -> Option<f64> {
    let mut dips: Vec<f64> = (unit.iter())
        .filter(|u| u.iter().all(|c| c.is_finite()))
        .map(|u| u.z.atan2(u.x.hypot(u.y)).to_degrees())
        .collect();
    (!dips.is_empty()).then(|| {
        let middle = dips.len() / 2;
        *dips.select_nth_unstable_by(middle, f64::total_cmp).1
    })
}

fn samples(seconds: f64, dt: f64) -> usize {
    (seconds / dt).round().max(1.0) as usize
}

fn read_attitude(log: &FlightLog) -> Result<Attitude> {
    let angle = |wanted: AttitudeAngle| {
        log.channels()
            .iter()
            .find(|c| c.role == ChannelRole::Attitude(wanted))
            .filter(|c| c.values.iter().filter(|v| v.is_finite()).count() * 2 > c.values.len())
            .map(|c| c.values.clone())
    };
    if let (Some(pitch), Some(roll), Some(yaw)) = (
        angle(AttitudeAngle::Pitch),
        angle(AttitudeAngle::Roll),
        angle(AttitudeAngle::Yaw),
    ) {
        let time = log.time_s();
        let (pitch, roll) = (bridged(&pitch, time, false), bridged(&roll, time, false));
        let yaw = bridged(&yaw, time, true);
        return Ok(Attitude {
            angles: [pitch, roll, yaw.clone()],
            heading_deg: yaw,
            source: AttitudeSource::Ins,
            field_unit: None,
        });
    }
    let sensor = log.vector_sensors().into_iter().next().ok_or_else(|| Error::MissingColumn {
        path: log.source().to_path_buf(),
        role: "attitude (ins_pitch, ins_roll, ins_yaw) or a vector magnetometer",
        looked_for: "ins_pitch, ins_roll, ins_yaw or flux_<s>_x/y/z".into(),
        hint: "Detection needs the aircraft's attitude; map your columns in [columns] of pipeline.toml, or give the windows with --window.".into(),
    })?;
    let [x, y, z] = log.vector_components(&sensor);
    let unit: Vec<Vector3<f64>> = (0..log.len())
        .map(|k| {
            let field = Vector3::new(x[k], y[k], z[k]);
            field / field.norm()
        })
        .collect();
    // Level flight: body x = H cos(D − ψ), y = H sin(D − ψ), so the
    // magnetic heading is −atan2(y, x).
    let heading_deg = (0..log.len())
        .map(|k| (-y[k].atan2(x[k])).to_degrees().rem_euclid(360.0))
        .collect();
    let nan = vec![f64::NAN; log.len()];
    Ok(Attitude {
        angles: [nan.clone(), nan.clone(), nan],
        heading_deg,
        source: AttitudeSource::Fluxgate,
        field_unit: Some(unit),
    })
}

/// Centred circular mean of the heading over `window` samples (NaN where
/// the window holds no finite sample).
fn smooth_heading(heading_deg: &[f64], window: usize) -> Vec<f64> {
    let n = heading_deg.len();
    let mut sums = vec![(0.0, 0.0, 0usize); n + 1];
    for (k, h) in heading_deg.iter().enumerate() {
        let (s, c) = if h.is_finite() {
            h.to_radians().sin_cos()
        } else {
            (0.0, 0.0)
        };
        let previous = sums[k];
        sums[k + 1] = (previous.0 + s, previous.1 + c, previous.2 + usize::from(h.is_finite()));
    }
    let half = window / 2;
    (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(half), (k + half + 1).min(n));
            let (s, c, count) = (sums[b].0 - sums[a].0, sums[b].1 - sums[a].1, sums[b].2 - sums[a].2);
            if count == 0 {
                f64::NAN
            } else {
                s.atan2(c).to_degrees().rem_euclid(360.0)
            }
        })
        .collect()
}

/// Circular median-like centre of headings: the circular mean, refined by
/// the median of the deviations from it.
fn heading_centre(headings: impl Iterator<Item = f64> + Clone) -> f64 {
    let (s, c) = headings
        .clone()
        .filter(|h| h.is_finite())
        .fold((0.0, 0.0), |(s, c), h| {
            (s + h.to_radians().sin(), c + h.to_radians().cos())
        });
    let mean = s.atan2(c).to_degrees();
    let mut deviations: Vec<f64> = headings
        .filter(|h| h.is_finite())
        .map(|h| heading_difference(h, mean))
        .collect();
    (mean + median(&mut deviations).unwrap_or(0.0)).rem_euclid(360.0)
}

fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let middle = values.len() / 2;
    Some(if values.len().is_multiple_of(2) {
        0.5 * (values[middle - 1] + values[middle])
    } else {
        values[middle]
    })
}

fn find_legs(
    log: &FlightLog,
    heading: &[f64],
    smoothed: &[f64],
    roll: Option<&[f64]>,
    options: &DetectOptions,
) -> Vec<Leg> {
    let time = log.time_s();
    let dt = log.median_interval_s();
    let reach = samples(5.0, dt);
    let n = heading.len();
    let straight: Vec<bool> = (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(reach), (k + reach).min(n - 1));
            let rate = heading_difference(smoothed[b], smoothed[a]) / (time[b] - time[a]).max(dt);
            rate.is_finite() && rate.abs() < options.straight_rate_deg_s
        })
        .collect();
    let mut runs: Vec<Range<usize>> = Vec::new();
    let mut k = 0;
    while k < n {
        if !straight[k] {
            k += 1;
            continue;
        }
        let start = k;
        while k < n && straight[k] {
            k += 1;
        }
        runs.push(start..k);
    }
    let centre = |r: &Range<usize>| heading_centre(heading[r.clone()].iter().copied());
    let mut joined: Vec<Range<usize>> = Vec::new();
    for run in runs {
        if let Some(last) = joined.last_mut() {
            let close = time[run.start] - time[last.end - 1] <= options.join_gap_s;
            let same = heading_difference(centre(&run), centre(last)).abs() < options.heading_tolerance_deg;
            if close && same {
                last.end = run.end;
                continue;
            }
        }
        joined.push(run);
    }
    joined
        .into_iter()
        .map(|rows| trim_turns(rows, heading, roll, options, dt))
        .filter(|r| !r.is_empty() && time[r.end - 1] - time[r.start] >= options.min_leg_s)
        .map(|rows| Leg {
            heading_deg: ((centre(&rows) * 10.0).round() / 10.0).rem_euclid(360.0),
            t_start: time[rows.start],
            t_end: time[rows.end - 1],
            rows,
        })
        .collect()
}

/// A leg with manoeuvres that runs on straight for more than `run_on_s`
/// beyond them, cut `run_on_s` from its first and last manoeuvre: the
/// calibration leg, and the stretches before and after it as legs of
/// their own (without manoeuvres, so no box counts them).
fn cut_run_on(time: &[f64], heading: &[f64], leg: Leg, found: &[DetectedManoeuvre], run_on_s: f64) -> Vec<Leg> {
    let (Some(first), Some(last)) = (
        found.iter().map(|m| m.t_start).min_by(f64::total_cmp),
        found.iter().map(|m| m.t_end).max_by(f64::total_cmp),
    ) else {
        return vec![leg];
    };
    let row = |t: f64| time.partition_point(|&x| x < t);
    let start = match first - leg.t_start > run_on_s {
        true => row(first - run_on_s).max(leg.rows.start),
        false => leg.rows.start,
    };
    let end = match leg.t_end - last > run_on_s {
        true => row(last + run_on_s).min(leg.rows.end),
        false => leg.rows.end,
    };
    if start == leg.rows.start && end == leg.rows.end {
        return vec![leg];
    }
    [leg.rows.start..start, start..end, end..leg.rows.end]
        .into_iter()
        .filter(|rows| !rows.is_empty())
        .map(|rows| Leg {
            heading_deg: ((heading_centre(heading[rows.clone()].iter().copied()) * 10.0).round() / 10.0)
                .rem_euclid(360.0),
            t_start: time[rows.start],
            t_end: time[rows.end - 1],
            rows,
        })
        .collect()
}

/// Heading rate below which a turn counts as rolled out (or not yet
/// rolled in), degrees/s: at 70 m/s it banks the aircraft 1.4°, and a
/// raised-cosine roll-out turns less than a tenth of a degree below it.
const TURN_SETTLED_DEG_S: f64 = 0.2;

/// Roll rate below which a turn's bank counts as rolled out, degrees/s
/// (a roll-out takes the bank off at 5–10°/s).
const ROLL_SETTLED_DEG_S: f64 = 0.5;

/// Moves the ends of a straight run to where the aircraft starts (or
/// stops) turning: heading off the run's centre by more than
/// `turn_heading_deg`, or bank beyond `turn_bank_deg`. The smoothed heading
/// that found the run blurs a turn's start and end by a few seconds.
fn trim_turns(
    rows: Range<usize>,
    heading: &[f64],
    roll: Option<&[f64]>,
    options: &DetectOptions,
    dt: f64,
) -> Range<usize> {
    let step = samples(0.5, dt);
    let centre = heading_centre(heading[rows.clone()].iter().copied());
    let turning = |k: usize| {
        let off = heading_difference(heading[k], centre).abs() > options.turn_heading_deg;
        let banked = roll.is_some_and(|r| r[k].abs() > options.turn_bank_deg);
        off || banked
    };
    let (mut start, mut end) = (rows.start, rows.end);
    while start < end && turning(start) {
        start += 1;
    }
    while end > start && turning(end - 1) {
        end -= 1;
    }
    // The smoothing also ends a run a few seconds before the turn starts:
    // carry the leg on to the turn itself.
    let steady = |k: usize| heading[k].is_finite() && !turning(k);
    while start > 0 && start < end && steady(start - 1) {
        start -= 1;
    }
    while end < heading.len() && end > start && steady(end) {
        end += 1;
    }
    // A turn is under way before its heading is `turn_heading_deg` off:
    // back to where the heading began to move monotonically into it (and,
    // at the start, on to where it stopped coming out of the previous
    // one), so the leg's level flight holds none of it.
    // Moving means turning by more than `TURN_SETTLED_DEG_S`: the last
    // fractions of a degree of a roll-out die away slowly, and the
    // turbulence on them would otherwise carry the leg's start into a
    // manoeuvre flown at once after the roll-out.
    let deviation = |k: usize| heading_difference(heading[k], centre);
    let least = TURN_SETTLED_DEG_S * step as f64 * dt;
    let moving = |later: usize, earlier: usize, sign: f64| {
        let (a, b) = (deviation(later) * sign, deviation(earlier) * sign);
        a.is_finite() && b.is_finite() && a - b > least
    };
    if end < heading.len() && end > start + step {
        let sign = deviation(end).signum();
        while end > start + step && moving(end - 1, end - 1 - step, sign) {
            end -= 1;
        }
    }
    if start > 0 && start + step < end {
        let sign = deviation(start - 1).signum();
        while start + step < end && moving(start, start + step, sign) {
            start += 1;
        }
    }
    // The bank rolls out after the heading has settled: on to where the
    // roll stops falling back to level, so a manoeuvre flown at once after
    // the roll-out does not begin with the turn's last degrees of bank.
    if let (Some(roll), true) = (roll, start > 0) {
        let least = ROLL_SETTLED_DEG_S * step as f64 * dt;
        let falling = |k: usize| {
            let (a, b) = (roll[k].abs(), roll[k + step].abs());
            a.is_finite() && b.is_finite() && a - b > least
        };
        while start + step < end && falling(start) {
            start += 1;
        }
    }
    start..end
}

/// Deviation of `axis` from level flight over the leg's rows, for the
/// activity envelope. The baseline is the angle smoothed within the leg
/// over `window` samples (a circular mean for the yaw), long enough to
/// average a manoeuvre's cycles away: a wandering track, a climb or a
/// descent on the leg's heading (a steady pitch of a few degrees for
/// minutes) are followed and do not count as activity, and the turns
/// either side are not seen.
fn deviation(attitude: &Attitude, window: usize, leg: &Leg, axis: usize) -> Vec<f64> {
    let values = &attitude.angles[axis][leg.rows.clone()];
    if axis == 2 && attitude.source == AttitudeSource::Ins {
        let smoothed = smooth_heading(values, window);
        return values
            .iter()
            .zip(&smoothed)
            .map(|(h, s)| heading_difference(*h, *s))
            .collect();
    }
    let smoothed = centred_mean(values, window);
    values.iter().zip(&smoothed).map(|(v, s)| v - s).collect()
}

/// Deviation of `axis` from the leg's median, the series a manoeuvre is
/// measured on ([`measure`] draws its own baseline between the level
/// flight either side).
fn offset_from_median(attitude: &Attitude, leg: &Leg, axis: usize) -> Vec<f64> {
    let values = &attitude.angles[axis][leg.rows.clone()];
    let mut finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    let level = median(&mut finite).unwrap_or(0.0);
    values.iter().map(|v| v - level).collect()
}

/// Centred mean over `window` samples, NaN samples skipped (NaN where the
/// window holds none).
fn centred_mean(values: &[f64], window: usize) -> Vec<f64> {
    let n = values.len();
    let mut sums = vec![(0.0, 0usize); n + 1];
    for (k, v) in values.iter().enumerate() {
        let previous = sums[k];
        sums[k + 1] = match v.is_finite() {
            true => (previous.0 + v, previous.1 + 1),
            false => previous,
        };
    }
    let half = window / 2;
    (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(half), (k + half + 1).min(n));
            match sums[b].1 - sums[a].1 {
                0 => f64::NAN,
                count => (sums[b].0 - sums[a].0) / count as f64,
            }
        })
        .collect()
}

/// What a yaw is measured on: the heading less the leg's heading. The
/// measurement's baseline, drawn between the level flight either side,
/// then follows a wandering track through the manoeuvre.
fn heading_deviation(attitude: &Attitude, leg: &Leg) -> Vec<f64> {
    attitude.heading_deg[leg.rows.clone()]
        .iter()
        .map(|h| heading_difference(*h, leg.heading_deg))
        .collect()
}

/// Centred RMS over `window` samples, NaN samples skipped (0 where the
/// window holds none).
fn rms_envelope(values: &[f64], window: usize) -> Vec<f64> {
    let squares: Vec<f64> = values.iter().map(|v| v * v).collect();
    centred_mean(&squares, window)
        .into_iter()
        .map(|mean| if mean.is_nan() { 0.0 } else { mean.sqrt() })
        .collect()
}

fn percentile(values: &[f64], fraction: f64) -> f64 {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if sorted.is_empty() {
        return 0.0;
    }
    sorted.sort_by(f64::total_cmp);
    sorted[((sorted.len() - 1) as f64 * fraction).round() as usize]
}

/// Active stretches (leg-relative rows) of one axis, with their strength
/// relative to the nominal amplitude.
fn active_regions(envelope: &[f64], threshold: f64, join: usize, shortest: usize) -> Vec<Range<usize>> {
    let mut regions: Vec<Range<usize>> = Vec::new();
    for (k, e) in envelope.iter().enumerate() {
        if *e <= threshold {
            continue;
        }
        match regions.last_mut() {
            Some(last) if k <= last.end + join => last.end = k + 1,
            _ => regions.push(k..k + 1),
        }
    }
    regions.retain(|r| r.len() >= shortest);
    regions
}

/// An active stretch of a leg: the axis it belongs to, the leg-relative
/// rows, its strength against the nominal amplitude and the attitude series
/// (degrees) to measure it on.
struct Candidate {
    axis: usize,
    /// The other axis it may be (fluxgate fallback, axes alike).
    could_be: Option<usize>,
    region: Range<usize>,
    /// Where its strong half-cycles may lie (leg-relative rows); `None`:
    /// anywhere in the measured span.
    core: Option<Range<usize>>,
    /// Another manoeuvre follows on directly before it, after it.
    joined: [bool; 2],
    strength: f64,
    series: std::rc::Rc<Vec<f64>>,
}

/// The INS path: each axis's activity as an RMS envelope, then every
/// active sample named by the axis strongest against its dominance weight,
/// so a stretch where the pilot flies pitch, roll and yaw back to back
/// splits where the driven axis changes, and the coupled motion of the
/// others (adverse yaw in a roll, roll in a yaw) never names a manoeuvre
/// of its own. Each stretch is a candidate on its axis.
fn ins_candidates(attitude: &Attitude, leg: &Leg, options: &DetectOptions, dt: f64) -> Vec<Candidate> {
    let window = samples(options.envelope_s, dt);
    let n = leg.rows.len();
    let mut weighted: [Vec<f64>; 3] = Default::default();
    let mut active: [Vec<bool>; 3] = Default::default();
    let mut series: [std::rc::Rc<Vec<f64>>; 3] = Default::default();
    for axis in 0..3 {
        let activity = deviation(attitude, samples(options.heading_smoothing_s, dt), leg, axis);
        let envelope = rms_envelope(&activity, window);
        let threshold = options.min_rms_deg[axis].max(options.turbulence_factor * percentile(&envelope, 0.1));
        active[axis] = vec![false; n];
        for region in active_regions(
            &envelope,
            threshold,
            samples(options.join_activity_s, dt),
            samples(2.0, dt),
        ) {
            active[axis][region].fill(true);
        }
        weighted[axis] = envelope.iter().map(|e| e / options.dominance_deg[axis]).collect();
        series[axis] = std::rc::Rc::new(if axis == 2 {
            heading_deviation(attitude, leg)
        } else {
            offset_from_median(attitude, leg, axis)
        });
    }
    let labels: Vec<Option<usize>> = (0..n)
        .map(|k| {
            (0..3)
                .filter(|axis| active[*axis][k])
                .max_by(|a, b| weighted[*a][k].total_cmp(&weighted[*b][k]).then(b.cmp(a)))
        })
        .collect();
    let runs = dominant_runs(labels, &weighted, samples(options.min_dominance_s, dt));
    let pad = samples(MEASURE_PAD_S, dt);
    (0..runs.len())
        .map(|i| {
            let (axis, region) = runs[i].clone();
            // Where another manoeuvre follows on directly, its motion on
            // this axis is not this one's: the strong half-cycles are
            // looked for up to the shared boundary only.
            // (A pause shorter than the level flight measure() looks at
            // either side joins them too: the boundary is then taken in
            // the middle of the pause.)
            let joined_before = i > 0 && region.start - runs[i - 1].1.end < pad;
            let joined_after = i + 1 < runs.len() && runs[i + 1].1.start - region.end < pad;
            let core = match joined_before {
                true => region.start - (region.start - runs[i - 1].1.end) / 2,
                false => region.start.saturating_sub(pad),
            }..match joined_after {
                true => region.end + (runs[i + 1].1.start - region.end) / 2,
                false => (region.end + pad).min(n),
            };
            let strength = region.clone().map(|k| weighted[axis][k]).fold(0.0, f64::max);
            Candidate {
                axis,
                could_be: None,
                region,
                core: Some(core),
                joined: [joined_before, joined_after],
                strength,
                series: series[axis].clone(),
            }
        })
        .collect()
}

/// Runs of samples named by one axis (`None`: no axis active), the runs
/// shorter than `shortest` given to the neighbour whose axis is the
/// stronger over them, until none is left: a dominance that flickers for
/// a moment at a manoeuvre's edge or a zero crossing does not split it.
fn dominant_runs(
    mut labels: Vec<Option<usize>>,
    weighted: &[Vec<f64>; 3],
    shortest: usize,
) -> Vec<(usize, Range<usize>)> {
    loop {
        let runs = label_runs(&labels);
        // The shortest run that touches a run of another axis.
        let short = (0..runs.len())
            .filter(|&i| runs[i].0.is_some() && runs[i].1.len() < shortest)
            .filter_map(|i| {
                let neighbours: Vec<usize> = [i.checked_sub(1), Some(i + 1)]
                    .into_iter()
                    .flatten()
                    .filter(|&j| j < runs.len() && runs[j].0.is_some())
                    .filter_map(|j| runs[j].0)
                    .collect();
                (!neighbours.is_empty()).then_some((i, neighbours))
            })
            .min_by_key(|(i, _)| (runs[*i].1.len(), *i));
        let Some((i, neighbours)) = short else {
            return runs
                .into_iter()
                .filter_map(|(label, range)| label.map(|axis| (axis, range)))
                .collect();
        };
        let range = runs[i].1.clone();
        let mean = |axis: usize| range.clone().map(|k| weighted[axis][k]).sum::<f64>();
        let to = neighbours
            .into_iter()
            .max_by(|a, b| mean(*a).total_cmp(&mean(*b)).then(b.cmp(a)))
            .unwrap_or(0);
        labels[range].fill(Some(to));
    }
}

/// Maximal runs of equal labels.
fn label_runs(labels: &[Option<usize>]) -> Vec<(Option<usize>, Range<usize>)> {
    let mut runs: Vec<(Option<usize>, Range<usize>)> = Vec::new();
    for (k, label) in labels.iter().enumerate() {
        match runs.last_mut() {
            Some((last, range)) if last == label => range.end = k + 1,
            _ => runs.push((*label, k..k + 1)),
        }
    }
    runs
}

/// Level flight looked at on either side of an active stretch, s.
const MEASURE_PAD_S: f64 = 4.0;

/// Principal direction of a cloud of 3-vectors: the eigenvector of the
/// largest eigenvalue of their covariance, signed to lean towards
/// (0.6, 0.5, 0.62) so the same cloud always gives the same vector.
fn principal_direction(points: &[Vector3<f64>]) -> Vector3<f64> {
    let finite: Vec<&Vector3<f64>> = points.iter().filter(|p| p.iter().all(|c| c.is_finite())).collect();
    let count = finite.len().max(1) as f64;
    let mean = finite.iter().fold(Vector3::zeros(), |sum, p| sum + *p) / count;
    let covariance = finite.iter().fold(Matrix3::zeros(), |sum, p| {
        let centred = *p - mean;
        sum + centred * centred.transpose()
    });
    let eigen = SymmetricEigen::new(covariance);
    let largest = eigen.eigenvalues.imax();
    let direction: Vector3<f64> = eigen.eigenvectors.column(largest).into_owned();
    if direction.dot(&Vector3::new(0.6, 0.5, 0.62)) < 0.0 {
        -direction
    } else {
        direction
    }
}

/// A leg flies one manoeuvre about each axis: two uncertain candidates
/// between the same two axes are told apart by size, the larger rotation
/// on the axis that turns the field more for its nominal amplitude
/// (`expected`, by axis).
fn tell_alike_apart(candidates: &mut [Candidate], expected: impl Fn(usize) -> f64) {
    let pair = |c: &Candidate| c.could_be.map(|other| (c.axis.min(other), c.axis.max(other)));
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        let members: Vec<usize> = (0..candidates.len())
            .filter(|i| pair(&candidates[*i]) == Some((a, b)))
            .collect();
        let [first, second] = members[..] else {
            continue;
        };
        let (larger, smaller) = match candidates[first].strength >= candidates[second].strength {
            true => (first, second),
            false => (second, first),
        };
        let (big, small) = match expected(a) >= expected(b) {
            true => (a, b),
            false => (b, a),
        };
        for (index, axis, other) in [(larger, big, small), (smaller, small, big)] {
            candidates[index].axis = axis;
            candidates[index].could_be = Some(other);
        }
    }
}

/// Level flight's field direction over a leg's `unit` directions: their
/// component-wise median (manoeuvres swing both ways about it), normalised.
fn level_direction(unit: &[Vector3<f64>]) -> Vector3<f64> {
    let median_of = |i: usize| {
        let mut values: Vec<f64> = unit.iter().map(|u| u[i]).filter(|v| v.is_finite()).collect();
        median(&mut values).unwrap_or(0.0)
    };
    let level = Vector3::new(median_of(0), median_of(1), median_of(2));
    level / level.norm()
}

/// Fluxgate fallback: the small rotation $u_{ref} \times u$ of the field
/// direction from the leg's mean direction, in degrees. A rotation θ about
/// body axis a gives $-θ\,(a - (a\cdot u)u)$: the direction of the
/// rotation vector tells the axis, its size over $|a - (a\cdot u)u|$ the angle.
fn fluxgate_candidates(unit: &[Vector3<f64>], leg: &Leg, options: &DetectOptions, dt: f64) -> Vec<Candidate> {
    let reference = level_direction(&unit[leg.rows.clone()]);
    let rotation: Vec<Vector3<f64>> = unit[leg.rows.clone()]
        .iter()
        .map(|u| reference.cross(u).map(f64::to_degrees))
        .collect();

    // Pitch turns about body y, roll about x, yaw about z.
    let visible = [Vector3::y(), Vector3::x(), Vector3::z()].map(|axis| axis - reference * axis.dot(&reference));
    let size: Vec<f64> = rotation.iter().map(|w| w.norm()).collect();
    // The rotation seen of a yaw is a third of the yaw: a longer envelope
    // keeps it above threshold through its zero crossings.
    let envelope = rms_envelope(&size, samples(1.7 * options.envelope_s, dt));
    let threshold = options
        .fluxgate_min_rms_deg
        .max(options.turbulence_factor * percentile(&envelope, 0.1));
    let (mut candidates, directions): (Vec<Candidate>, Vec<Vector3<f64>>) = active_regions(
        &envelope,
        threshold,
        samples(options.join_activity_s, dt),
        samples(2.0, dt),
    )
    .into_iter()
    .map(|region| {
        let direction = principal_direction(&rotation[region.clone()]);
        let score = |v: &Vector3<f64>| direction.dot(v).abs() / v.norm();
        let scores = [0, 1, 2].map(|axis| score(&visible[axis]));
        let best = (0..3).max_by(|a, b| scores[*a].total_cmp(&scores[*b])).unwrap_or(0);
        // Axes whose rotations lie along the same line as the best one's:
        // the direction cannot choose among them, the size (against each
        // axis's nominal amplitude) does, and the name is flagged.
        let alike: Vec<usize> = (0..3)
            .filter(|axis| *axis == best || scores[*axis] >= AXES_ALIKE)
            .collect();
        let size = region.clone().map(|k| envelope[k]).fold(0.0, f64::max);
        let mut by_size = alike.clone();
        by_size.sort_by(|a, b| {
            size_misfit(size, &visible[*a], options.nominal_amplitude_deg[*a]).total_cmp(&size_misfit(
                size,
                &visible[*b],
                options.nominal_amplitude_deg[*b],
            ))
        });
        let candidate = Candidate {
            axis: by_size[0],
            could_be: by_size.get(1).copied(),
            core: None,
            joined: [false; 2],
            region,
            strength: size,
            series: std::rc::Rc::new(Vec::new()),
        };
        (candidate, direction)
    })
    .unzip();
    let expected = |axis: usize| visible[axis].norm() * options.nominal_amplitude_deg[axis];
    tell_alike_apart(&mut candidates, expected);
    for (candidate, direction) in candidates.iter_mut().zip(&directions) {
        let scale = visible[candidate.axis].norm().max(1e-3);
        candidate.series = std::rc::Rc::new(rotation.iter().map(|w| w.dot(direction) / scale).collect());
        candidate.strength = 1.0;
    }
    candidates
}

/// Two axes are alike to the fluxgate when the rotation's direction lies
/// this close to both (the cosine of the angle to each axis's visible
/// rotation): within about 18°. Pitch and yaw are alike where the field
/// lies near the plane of the lateral and vertical axes (east and west
/// headings at high inclination), roll and yaw near the plane of the
/// longitudinal and vertical axes (north and south).
const AXES_ALIKE: f64 = 0.95;

/// How far a rotation of RMS `size` degrees is from what the nominal
/// amplitude about an axis with visible rotation `visible` would give, as
/// the absolute log ratio.
fn size_misfit(size: f64, visible: &Vector3<f64>, nominal_deg: f64) -> f64 {
    let turned = visible.norm().max(1e-3) * nominal_deg / std::f64::consts::SQRT_2;
    (size.max(1e-12) / turned).ln().abs()
}

fn leg_manoeuvres(log: &FlightLog, attitude: &Attitude, leg: &Leg, options: &DetectOptions) -> Vec<DetectedManoeuvre> {
    let dt = log.median_interval_s();
    let kinds = [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw];
    let candidates = match &attitude.field_unit {
        Some(unit) => fluxgate_candidates(unit, leg, options, dt),
        None => ins_candidates(attitude, leg, options, dt),
    };
    // Where axes overlap, the one strongest against its nominal amplitude wins.
    let beaten = |c: &Candidate| {
        candidates.iter().any(|o| {
            o.axis != c.axis
                && o.region.start < c.region.end
                && c.region.start < o.region.end
                && (o.strength > c.strength || (o.strength == c.strength && o.axis < c.axis))
        })
    };
    candidates
        .iter()
        .filter(|c| !beaten(c))
        .filter_map(
            |Candidate {
                 axis,
                 could_be,
                 region,
                 core,
                 joined,
                 series,
                 ..
             }| {
                let found = measure(series, region.clone(), core.clone(), *joined, dt)?;
                check_regular(&found, options)?;
                (found.amplitude_deg >= options.min_amplitude_deg[*axis]).then_some(())?;
                let time = log.time_s();
                let rows = leg.rows.start + found.start..leg.rows.start + found.end;
                Some(DetectedManoeuvre {
                    kind: kinds[*axis],
                    heading_deg: leg.heading_deg,
                    t_start: time[rows.start],
                    t_end: time[rows.end - 1],
                    cycles: (found.half_cycles.len() as f64 / 2.0).round(),
                    amplitude_deg: found.amplitude_deg,
                    period_s: found.period_s,
                    could_be: could_be.map(|other| kinds[other]),
                })
            },
        )
        .collect()
}

/// Fraction of the largest peak that makes a half-cycle count.
const STRONG: f64 = 0.4;

/// An oscillation measured in leg-relative rows.
struct Oscillation {
    start: usize,
    end: usize,
    /// Lengths of the strong half-cycles, samples.
    half_cycles: Vec<usize>,
    /// Their peak deviations, degrees.
    peaks: Vec<f64>,
    amplitude_deg: f64,
    period_s: f64,
}

/// Standard deviation over mean.
fn relative_spread(values: &[f64]) -> f64 {
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt() / mean
}

/// A manoeuvre is a regular oscillation: enough strong half-cycles, of
/// similar lengths and similar peaks. Turbulence seldom is.
fn check_regular(found: &Oscillation, options: &DetectOptions) -> Option<()> {
    if found.half_cycles.len() < options.min_half_cycles {
        return None;
    }
    let lengths: Vec<f64> = found.half_cycles.iter().map(|&l| l as f64).collect();
    let regular = relative_spread(&lengths) <= options.max_half_cycle_spread
        && relative_spread(&found.peaks) <= options.max_peak_spread;
    regular.then_some(())
}

/// The median of the finite values in `range` and their scatter (1.4826 ×
/// the median absolute deviation, a robust standard deviation), or `None`.
fn level_in(values: &[f64], range: Range<usize>) -> Option<(f64, f64)> {
    let mut finite: Vec<f64> = values[range].iter().copied().filter(|v| v.is_finite()).collect();
    let level = median(&mut finite)?;
    let mut deviations: Vec<f64> = finite.iter().map(|v| (v - level).abs()).collect();
    Some((level, 1.4826 * median(&mut deviations)?))
}

/// Measures the oscillation around an active region against a baseline
/// interpolated between the level flight on either side.
///
/// A manoeuvre `joined` to another on either side has no level flight
/// there to draw the baseline to: it is measured against the median of
/// its own core instead (an oscillation swings evenly about its level).
fn measure(
    values: &[f64],
    region: Range<usize>,
    core: Option<Range<usize>>,
    joined: [bool; 2],
    dt: f64,
) -> Option<Oscillation> {
    let n = values.len();
    let pad = samples(MEASURE_PAD_S, dt);
    let outer = region.start.saturating_sub(pad)..(region.end + pad).min(n);
    if let (true, Some(core)) = (joined[0] || joined[1], &core) {
        // Into a neighbouring manoeuvre the oscillation may reach only as
        // far as the boundary between the two can be off: its coupled
        // motion on this axis is not this manoeuvre's.
        let slack = samples(JOINED_SLACK_S, dt);
        let outer = match joined[0] {
            true => core.start.saturating_sub(slack),
            false => core.start,
        }..match joined[1] {
            true => (core.end + slack).min(n),
            false => core.end,
        };
        let levelled = less_level(values, outer.clone(), core.clone());
        let core = core.start.clamp(outer.start, outer.end) - outer.start
            ..core.end.clamp(outer.start, outer.end) - outer.start;
        let rough = measure_between(&levelled, outer.clone(), core.clone(), 0..0, 0..0, dt)?;
        // The core reaches into the level flight beside the manoeuvre, or
        // into a turn it runs on into, whose heading need not be the
        // oscillation's, and a pilot lets the heading drift as he yaws:
        // levelled again at the mean over one period about each sample
        // (which holds a sine's centre and follows a drift), kept within
        // the cycles found.
        let period = (rough.period_s / dt).round() as usize;
        let levelled = less_running_level(values, outer.clone(), rough.start..rough.end, period);
        return measure_between(&levelled, outer, core, 0..0, 0..0, dt);
    }
    // First against the level flight a few seconds either side of the
    // active stretch, then again against the level flight right next to
    // the oscillation found, so a drifting heading is followed closely.
    let before = region.start.saturating_sub(2 * pad)..region.start.saturating_sub(pad / 2).max(1);
    let after = (region.end + pad / 2).min(n - 1)..(region.end + 2 * pad).min(n);
    // The strong half-cycles are looked for in the core only, in
    // outer-relative rows.
    let core = core.map_or(0..outer.len(), |c| {
        c.start.clamp(outer.start, outer.end) - outer.start..c.end.clamp(outer.start, outer.end) - outer.start
    });
    let rough = measure_between(values, outer.clone(), core.clone(), before, after, dt)?;
    let near = samples(3.0, dt);
    let gap = samples(0.3, dt);
    let before = rough.start.saturating_sub(near)..rough.start.saturating_sub(gap).max(1);
    let after = (rough.end + gap).min(n - 1)..(rough.end + near).min(n);
    measure_between(values, outer, core, before, after, dt)
}

/// How far, s, the boundary between two manoeuvres flown back to back may
/// lie from where the envelopes of their axes cross (half the envelope's
/// window).
const JOINED_SLACK_S: f64 = 1.5;

/// `values` over `outer` less the median of its finite values in `fit`
/// (NaN elsewhere). A sloping line would not do: fitted to an oscillation
/// of N cycles, it tilts by 3/(πN) of the amplitude at the ends.
fn less_level(values: &[f64], outer: Range<usize>, fit: Range<usize>) -> Vec<f64> {
    let mut finite: Vec<f64> = values[fit].iter().copied().filter(|v| v.is_finite()).collect();
    let level = median(&mut finite).unwrap_or(0.0);
    let mut levelled = vec![f64::NAN; values.len()];
    for k in outer {
        levelled[k] = values[k] - level;
    }
    levelled
}

/// `values` over `outer` less their mean over the `period` samples about
/// each row, the window slid to lie within `cycles` (NaN outside `outer`).
/// Falls back to [`less_level`] where the cycles are shorter than a
/// period, and a row whose window holds no finite value is NaN.
fn less_running_level(values: &[f64], outer: Range<usize>, cycles: Range<usize>, period: usize) -> Vec<f64> {
    if period == 0 || cycles.len() < period {
        return less_level(values, outer, cycles);
    }
    // Prefix sums of the finite values and of their count.
    let mut sums = vec![(0.0, 0usize); cycles.len() + 1];
    for (i, v) in values[cycles.clone()].iter().enumerate() {
        let (sum, count) = sums[i];
        sums[i + 1] = match v.is_finite() {
            true => (sum + v, count + 1),
            false => (sum, count),
        };
    }
    let mut levelled = vec![f64::NAN; values.len()];
    for k in outer {
        let first = k.saturating_sub(period / 2).clamp(cycles.start, cycles.end - period) - cycles.start;
        let (high, low) = (sums[first + period], sums[first]);
        let count = high.1 - low.1;
        if count > 0 {
            levelled[k] = values[k] - (high.0 - low.0) / count as f64;
        }
    }
    levelled
}

/// Measures the oscillation in `outer` against a baseline drawn between
/// the medians of the level flight in `before` and `after`; its peak and
/// strong half-cycles are looked for in `core` (rows of `outer`), and its
/// ends may reach beyond, out to where those half-cycles cross zero.
fn measure_between(
    values: &[f64],
    outer: Range<usize>,
    core: Range<usize>,
    before: Range<usize>,
    after: Range<usize>,
    dt: f64,
) -> Option<Oscillation> {
    let (outer_start, outer_end) = (outer.start, outer.end);
    // Level flight cut short by the leg's end (a turn, a climb) is no
    // level to draw the baseline to: a second of it at least.
    let level = |range: Range<usize>| match range.len() >= samples(1.0, dt) {
        true => level_in(values, range),
        false => None,
    };
    let (before, after) = (level(before), level(after));
    let (first, last) = match (before, after) {
        (Some((a, _)), Some((b, _))) => (a, b),
        (Some((a, _)), None) | (None, Some((a, _))) => (a, a),
        (None, None) => (0.0, 0.0),
    };
    let noise = before
        .iter()
        .chain(&after)
        .map(|(_, spread)| *spread)
        .fold(0.0, f64::max);
    let span = (outer_end - outer_start).max(1) as f64;
    let centred: Vec<f64> = (outer_start..outer_end)
        .map(|k| values[k] - (first + (last - first) * (k - outer_start) as f64 / span))
        .collect();
    let core = core.start.min(centred.len())..core.end.min(centred.len());
    let peak = centred[core.clone()]
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    if peak == 0.0 {
        return None;
    }
    // A half-cycle is strong when it reaches 40 % of the largest: a
    // wandering heading or turbulence can shift single peaks by a third.
    let strong = |v: f64| v.is_finite() && v.abs() >= STRONG * peak;
    let first_strong = core.start + centred[core.clone()].iter().position(|v| strong(*v))?;
    let last_strong = core.start + centred[core.clone()].iter().rposition(|v| strong(*v))?;
    // The oscillation leaves level flight where it first passes a tenth of
    // its peak, or three times the level flight's own scatter if that is
    // larger: turbulence alone rarely gets that far.
    let edge = (0.1 * peak).max(3.0 * noise).min(0.45 * peak);
    let beyond = |v: f64, like: f64| v.is_finite() && v.abs() > edge && (v > 0.0) == (like > 0.0);
    let mut start = first_strong;
    while start > 0 && beyond(centred[start - 1], centred[first_strong]) {
        start -= 1;
    }
    let mut end = last_strong;
    while end + 1 < centred.len() && beyond(centred[end + 1], centred[last_strong]) {
        end += 1;
    }
    let (start, end, runs) = oscillation_runs(&centred, start..=end, STRONG * peak);
    let half_cycles: Vec<usize> = runs.iter().map(|r| r.end - r.start).collect();
    let peaks: Vec<f64> = runs.iter().map(|r| r.peak).collect();
    let amplitude_deg = median(&mut peaks.clone())?;
    let mean_half = half_cycles.iter().sum::<usize>() as f64 / half_cycles.len().max(1) as f64;
    // A sine passes a fraction f of its peak asin(f)/2π of a period after
    // its zero crossing: step back to the crossings.
    let lead = ((edge / amplitude_deg).min(1.0).asin() / std::f64::consts::PI * mean_half).round() as usize;
    let (start, end) = (start.saturating_sub(lead), (end + lead).min(centred.len() - 1));
    let duration_s = (end + 1 - start) as f64 * dt;
    Some(Oscillation {
        start: outer_start + start,
        end: outer_start + end + 1,
        period_s: duration_s / (half_cycles.len() as f64 / 2.0).max(0.5),
        half_cycles,
        peaks,
        amplitude_deg,
    })
}

/// The strong half-cycles of `centred` over `rows`, with the rows cut
/// where a first or last half-cycle runs on ([`drifting_ends`]): the
/// rows' first and last (inclusive) and the runs (relative to the first).
fn oscillation_runs(centred: &[f64], rows: RangeInclusive<usize>, strong: f64) -> (usize, usize, Vec<HalfCycle>) {
    let (start, end) = (*rows.start(), *rows.end());
    let runs = half_cycles(&centred[start..=end], strong);
    match drifting_ends(&runs, end + 1 - start) {
        Some((from, to)) => {
            let (start, end) = (start + from, start + to - 1);
            (start, end, half_cycles(&centred[start..=end], strong))
        }
        None => (start, end, runs),
    }
}

/// Longest first or last half-cycle, as a multiple of the others' median,
/// that is taken as the oscillation's own.
const LONGEST_END_HALF_CYCLE: f64 = 1.5;

/// Where an oscillation's first or last half-cycle runs on far longer
/// than the others, the rows (relative to the runs) it is cut to: the
/// oscillation ends the others' median length after its last crossing
/// (and begins as long before its first). Level flight off the
/// oscillation's own level, where the pilot let the heading drift or
/// rolled into a turn at once, keeps the sign of the half-cycle next to
/// it for seconds. `None` where neither end runs on, or with fewer than
/// three half-cycles to compare; `len` is the length of the rows the runs
/// were found in.
fn drifting_ends(runs: &[HalfCycle], len: usize) -> Option<(usize, usize)> {
    let (first, last) = (runs.first()?, runs.last()?);
    let mut inner: Vec<f64> = runs
        .get(1..runs.len().checked_sub(1)?)?
        .iter()
        .map(|r| (r.end - r.start) as f64)
        .collect();
    let typical = median(&mut inner)?;
    let longest = LONGEST_END_HALF_CYCLE * typical;
    let from = match ((first.end - first.start) as f64) > longest {
        true => first.end - typical.round() as usize,
        false => 0,
    };
    let to = match ((last.end - last.start) as f64) > longest {
        true => last.start + typical.round() as usize,
        false => len,
    };
    (from > 0 || to < len).then_some((from, to))
}

/// One sign run of an oscillation: its samples and its peak deviation.
#[derive(Debug, Clone, PartialEq)]
struct HalfCycle {
    start: usize,
    end: usize,
    peak: f64,
}

/// The sign runs of `values` that reach `strong`.
fn half_cycles(values: &[f64], strong: f64) -> Vec<HalfCycle> {
    let mut runs = Vec::new();
    let mut k = 0;
    while k < values.len() {
        let positive = values[k] > 0.0;
        let start = k;
        let mut peak = 0.0f64;
        while k < values.len() && (values[k] > 0.0) == positive {
            peak = peak.max(values[k].abs());
            k += 1;
        }
        if peak >= strong {
            runs.push(HalfCycle { start, end: k, peak });
        }
    }
    runs
}

fn group_boxes(legs: &[Leg], manoeuvres: &[DetectedManoeuvre], options: &DetectOptions) -> Vec<DetectedBox> {
    let busy: Vec<&Leg> = legs
        .iter()
        .filter(|leg| {
            manoeuvres
                .iter()
                .any(|m| m.t_start >= leg.t_start && m.t_end <= leg.t_end)
        })
        .collect();
    let mut boxes: Vec<Vec<&Leg>> = Vec::new();
    for leg in busy {
        let joins = boxes.last().is_some_and(|current| {
            let previous = current[current.len() - 1];
            let repeated = current
                .iter()
                .any(|l| heading_difference(l.heading_deg, leg.heading_deg).abs() < options.heading_tolerance_deg);
            leg.t_start - previous.t_end <= options.max_turn_s && !repeated
        });
        match boxes.last_mut() {
            Some(current) if joins => current.push(leg),
            _ => boxes.push(vec![leg]),
        }
    }
    boxes
        .into_iter()
        .map(|legs| DetectedBox {
            t_start: legs[0].t_start,
            t_end: legs[legs.len() - 1].t_end,
            headings_deg: legs.iter().map(|l| l.heading_deg).collect(),
            missing: missing_headings(&legs, options.heading_tolerance_deg)
                .into_iter()
                .chain(missing_manoeuvres(&legs, manoeuvres))
                .collect(),
        })
        .collect()
}

/// The headings of a four-heading box that no leg was flown on, e.g.
/// "no leg near 270°". The box's headings are taken 90° apart from the
/// circular mean of its legs' headings modulo 90° (the angle of the mean
/// of $e^{4ih}$, divided by four), so any one leg's heading error and any
/// flying order count alike. Legs off that pattern by the heading
/// tolerance or more (three headings 120° apart; legs crabbed into a
/// strong wind; eight headings) name no heading: four legs or more are a
/// box, fewer are said to be fewer.
fn missing_headings(legs: &[&Leg], tolerance_deg: f64) -> Vec<String> {
    let (sin, cos) = legs.iter().fold((0.0, 0.0), |(s, c), leg| {
        let angle = 4.0 * leg.heading_deg.to_radians();
        (s + angle.sin(), c + angle.cos())
    });
    let base = sin.atan2(cos).to_degrees() / 4.0;
    let off_pattern = |heading_deg: f64| {
        let from_pattern_deg = (heading_difference(heading_deg, base) + 45.0).rem_euclid(90.0) - 45.0;
        from_pattern_deg.abs() >= tolerance_deg
    };
    if legs.iter().any(|leg| off_pattern(leg.heading_deg)) {
        let headings: Vec<String> = legs.iter().map(|leg| format!("{:.0}°", leg.heading_deg)).collect();
        return match legs.len() {
            4.. => Vec::new(),
            n => vec![format!(
                "it has {n} legs ({}), not four headings, and they are not 90° apart, so no heading can be named as missing",
                headings.join(", ")
            )],
        };
    }
    (0..4)
        .map(|k| (base + 90.0 * k as f64).rem_euclid(360.0))
        .filter(|expected| {
            !legs
                .iter()
                .any(|leg| heading_difference(leg.heading_deg, *expected).abs() < tolerance_deg)
        })
        .map(|expected| format!("no leg near {:.0}°", expected.round().rem_euclid(360.0)))
        .collect()
}

fn kind_name(kind: ManoeuvreKind) -> String {
    format!("{kind:?}").to_lowercase()
}

/// The pairs of kinds the fluxgate could not tell apart among `manoeuvres`,
/// each in pitch, roll, yaw order, once.
fn alike_pairs(manoeuvres: &[&DetectedManoeuvre]) -> Vec<(ManoeuvreKind, ManoeuvreKind)> {
    let order = |kind: ManoeuvreKind| {
        [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw]
            .iter()
            .position(|k| *k == kind)
    };
    let mut pairs: Vec<(ManoeuvreKind, ManoeuvreKind)> = manoeuvres
        .iter()
        .filter_map(|m| {
            let other = m.could_be?;
            Some(match order(m.kind) < order(other) {
                true => (m.kind, other),
                false => (other, m.kind),
            })
        })
        .collect();
    pairs.sort_by_key(|(a, b)| (order(*a), order(*b)));
    pairs.dedup();
    pairs
}

/// The manoeuvres a box's legs lack, e.g. "no yaw on heading 290". On a
/// leg where the fluxgate could not tell two kinds apart, they are counted
/// together: "one of pitch and yaw missing on heading 90" when only one of
/// the two was found.
fn missing_manoeuvres(legs: &[&Leg], manoeuvres: &[DetectedManoeuvre]) -> Vec<String> {
    let mut missing = Vec::new();
    for leg in legs {
        let on_leg: Vec<&DetectedManoeuvre> = manoeuvres
            .iter()
            .filter(|m| m.t_start >= leg.t_start && m.t_end <= leg.t_end)
            .collect();
        let heading = leg.heading_deg.round();
        let pairs = alike_pairs(&on_leg);
        for kind in [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw] {
            let paired = pairs.iter().any(|(a, b)| *a == kind || *b == kind);
            if !paired && !on_leg.iter().any(|m| m.kind == kind) {
                missing.push(format!("no {} on heading {heading}", kind_name(kind)));
            }
        }
        for (a, b) in pairs {
            if on_leg.iter().filter(|m| m.kind == a || m.kind == b).count() < 2 {
                missing.push(format!(
                    "one of {} and {} missing on heading {heading}",
                    kind_name(a),
                    kind_name(b)
                ));
            }
        }
    }
    missing
}

/// One sentence per leg whose manoeuvres the fluxgate could not tell apart.
pub fn uncertain_kinds(detection: &Detection) -> Vec<Warning> {
    detection
        .legs
        .iter()
        .filter_map(|leg| {
            let uncertain: Vec<&DetectedManoeuvre> = detection
                .manoeuvres
                .iter()
                .filter(|m| m.could_be.is_some() && m.t_start >= leg.t_start && m.t_end <= leg.t_end)
                .collect();
            let alike = (alike_pairs(&uncertain).into_iter())
                .map(|(a, b)| (kind_name(a), kind_name(b)))
                .collect();
            let manoeuvres: Vec<(f64, f64, String)> = (uncertain.iter())
                .map(|m| (m.t_start, m.t_end, kind_name(m.kind)))
                .collect();
            (!manoeuvres.is_empty()).then_some(Warning::NamedBySize {
                heading_deg: leg.heading_deg,
                alike,
                manoeuvres,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn headings_wrap_through_north() {
        assert_eq!(heading_difference(350.0, 10.0), -20.0);
        let centre = heading_centre([355.0, 359.0, 1.0, 5.0].into_iter());
        assert!(heading_difference(centre, 0.0).abs() < 1e-9, "{centre}");
    }

    #[test]
    fn a_clean_sine_measures_its_cycles_period_and_amplitude() {
        // 3 cycles of 6 s at 10 Hz, amplitude 5°, with 10 s of level flight around.
        let mut values = vec![0.0; 100];
        values.extend((1..=180).map(|k| 5.0 * (2.0 * std::f64::consts::PI * k as f64 * 0.1 / 6.0).sin()));
        values.extend(vec![0.0; 100]);
        let found = measure(&values, 105..275, None, [false; 2], 0.1).unwrap();
        assert_eq!(found.half_cycles.len(), 6);
        assert!((found.amplitude_deg - 5.0).abs() < 0.01);
        assert!((found.period_s - 6.0).abs() < 0.15, "{}", found.period_s);
        assert!(
            (found.start as i64 - 100).abs() <= 1 && (found.end as i64 - 280).abs() <= 1,
            "{}..{}",
            found.start,
            found.end
        );
    }
}
