//! Screening the samples before any stage uses them.
//!
//! A reading no instrument on a survey aircraft can make is masked: set
//! missing in the flight log the stages work on, with its row flagged
//! `<reason>:<column>`. The fit then leaves it out as it leaves out any
//! missing sample (a calibration window's run is split around it and the
//! fit still runs), the compensation leaves its row empty with the reason,
//! and no filter or derivative carries it into the neighbouring rows. The
//! recorded value itself is kept in every output's copy of the input.
//!
//! What is masked, by the channel's role:
//! - a scalar magnetometer outside 1,000–100,000 nT (the Earth's field is
//!   22,000–67,000 nT at the surface), a base station beyond ±100,000 nT,
//!   or in either an isolated spike: a sample that leaves both neighbours
//!   by more than the field can change in one sample interval while they
//!   agree with each other;
//! - a fluxgate whose magnitude is under 1,000 nT (a zero or subnormal
//!   reading: the sensor reported nothing; all three axes), an axis reading
//!   zero between neighbours 500 nT or more from zero, alone or in a run,
//!   or a subnormal anywhere (a dropout), a component beyond ±100,000 nT,
//!   or an isolated spike in one axis (that axis, which makes the row's
//!   vector missing);
//! - in a scalar or a fluxgate axis, a run of glitches: samples entered
//!   and left by jumps larger than the field can change in one interval,
//!   with the readings either side of the run agreeing (within what the
//!   field can change across it: the crust at 1,500 nT/s plus the
//!   aircraft's own swing of 4,000 nT for a scalar, up to 10 s; the
//!   Earth's field turning at 1 rad/s for a fluxgate axis, up to 2 s);
//! - a longer run in a scalar or a fluxgate axis, up to 600 s, where the
//!   scalar's departure from the fluxgate's magnitude steps out and back
//!   by more than the aircraft's own field can ([`super::magnitude`]);
//! - a scalar magnetometer or a fluxgate axis that repeats one reading
//!   for [`STUCK_S`] or longer (and at least [`STUCK_SAMPLES`] samples):
//!   a working sensor's noise and the aircraft's motion change every
//!   reading, so the sensor is stuck, or the axis dead (all zeros), or the
//!   logger held its last value;
//! - pitch beyond ±90°, roll beyond ±180°, heading beyond ±3,600° (ten
//!   turns, for headings recorded unwrapped), or a glitch: a sample
//!   further from most of its neighbours than the aircraft can turn in two
//!   intervals ([`FASTEST_ATTITUDE_DEG_S`], at least
//!   [`LEAST_ATTITUDE_GLITCH_DEG`] an interval), up to
//!   [`LONGEST_GLITCH_SAMPLES`] in a row; headings are compared across
//!   north (a heading set to 0 or 359.9 by a dropout is masked, the turn
//!   from 359.9° to 0.1° is not);
//! - latitude beyond ±90°, longitude beyond ±360°, other positions (heights,
//!   grid coordinates) beyond ±10,000 km;
//! - an auxiliary column beyond ±1e12 (no current, voltage or counter reads
//!   that; the value is a damaged cell).
//!
//! A missing or non-finite sample is not screened: it is already missing.

use crate::ingest::flags::{FlagKind, RowFlags};
use std::collections::BTreeMap;

use serde::Serialize;

use crate::error::Result;
use crate::ingest::flight_log::{AttitudeAngle, ChannelRole, FlightLog};
use crate::messages::Warning;

/// Lowest and highest total field a scalar magnetometer can read, nT.
pub const TOTAL_FIELD_RANGE_NT: (f64, f64) = (1_000.0, 100_000.0);

/// Largest fluxgate component, nT.
pub const MOST_VECTOR_COMPONENT_NT: f64 = 100_000.0;

/// Smallest fluxgate magnitude, nT: below it the sensor read nothing.
pub const LEAST_VECTOR_MAGNITUDE_NT: f64 = 1_000.0;

/// Fastest a total field can change, nT/s: a 10 nT/m gradient at 150 m/s,
/// with a margin for the aircraft's own field in a fast roll.
pub const FASTEST_TOTAL_FIELD_NT_S: f64 = 10_000.0;

/// Fastest a fluxgate component can change, nT/s: the Earth's field
/// turning at 1 rad/s (57°/s, twice a steep survey aircraft's roll rate).
pub const FASTEST_COMPONENT_NT_S: f64 = 50_000.0;

/// Fastest an attitude angle can change, °/s: three times a steep
/// survey aircraft's roll rate.
pub const FASTEST_ATTITUDE_DEG_S: f64 = 90.0;

/// Smallest attitude glitch masked, degrees: at high rates a smaller one
/// changes no stage's result.
pub const LEAST_ATTITUDE_GLITCH_DEG: f64 = 5.0;

/// Most samples in a row an attitude glitch spans, and the neighbours on
/// each side a sample is judged against.
pub const LONGEST_GLITCH_SAMPLES: usize = 3;

/// Fastest the crustal field changes under a survey aircraft, nT/s: a
/// 10 nT/m gradient at 150 m/s.
pub const GEOLOGY_NT_S: f64 = 1_500.0;

/// Largest swing of an aircraft's own field at a scalar sensor between
/// any two attitudes, nT: a cabin sensor's interference reaches a few
/// thousand nT at most, a tail sensor's a few hundred.
pub const AIRCRAFT_SWING_NT: f64 = 4_000.0;

/// Longest run of glitches looked for on a scalar, s.
pub const SCALAR_GLITCH_REACH_S: f64 = 10.0;

/// ... and on a fluxgate component, s: beyond it the Earth's field can
/// turn through any direction, so continuity tells nothing.
pub const COMPONENT_GLITCH_REACH_S: f64 = 2.0;

/// Longest run of glitches looked for, samples (10 s at 50 Hz).
const MOST_GLITCH_REACH_SAMPLES: usize = 500;

/// A magnetometer repeating one reading this long is stuck, s.
pub const STUCK_S: f64 = 5.0;

/// ... and for at least this many samples.
pub const STUCK_SAMPLES: usize = 20;

/// Below this a fluxgate axis reads nothing (a zero or subnormal dropout).
const DROPOUT_NT: f64 = 1e-300;

/// A dropout is masked when both neighbours are at least this far from
/// zero, nT: the axis was not crossing zero.
const DROPOUT_NEIGHBOUR_NT: f64 = 500.0;

/// Largest auxiliary value: beyond it a cell is damaged, not measured.
pub const MOST_AUXILIARY: f64 = 1e12;

/// Why a sample was masked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MaskReason {
    /// Outside what the instrument can read.
    OutOfRange,
    /// A fluxgate reading of (near) zero magnitude.
    ZeroVector,
    /// One sample far from both neighbours, which agree.
    Spike,
    /// A fluxgate axis reading zero between neighbours far from zero.
    Dropout,
    /// Attitude samples further from most of their neighbours than the
    /// aircraft can turn.
    Glitch,
    /// One reading repeated for [`STUCK_S`] or longer.
    Stuck,
    /// A run of magnetometer samples entered and left by jumps the field
    /// cannot make, the readings either side agreeing.
    Burst,
    /// A run in which the INS attitude and a fluxgate's field direction
    /// disagree abruptly ([`super::agreement`]).
    Disagreement,
    /// A run in which a scalar's departure from a fluxgate's magnitude
    /// steps out and back by more than the aircraft can make
    /// ([`super::magnitude`]).
    Departure,
    /// Rows after a step of one INS angle or fluxgate axis the other
    /// sensor does not see, held until it steps back or the record ends
    /// ([`super::agreement`]).
    HeldStep,
}

impl MaskReason {
    /// The flag the masked sample's row gets.
    pub fn flag(self) -> FlagKind {
        match self {
            MaskReason::OutOfRange => FlagKind::OutOfRange,
            MaskReason::ZeroVector => FlagKind::ZeroVector,
            MaskReason::Spike => FlagKind::Spike,
            MaskReason::Dropout => FlagKind::Dropout,
            MaskReason::Glitch => FlagKind::Spike,
            MaskReason::Stuck => FlagKind::Stuck,
            MaskReason::Burst => FlagKind::Spike,
            MaskReason::Disagreement => FlagKind::Spike,
            MaskReason::Departure => FlagKind::Spike,
            MaskReason::HeldStep => FlagKind::Step,
        }
    }

    fn describe(self) -> &'static str {
        match self {
            MaskReason::OutOfRange => "values beyond what the instrument can read",
            MaskReason::ZeroVector => "fluxgate readings under 1,000 nT in magnitude: the sensor read nothing",
            MaskReason::Spike => {
                "isolated spikes, further from both neighbours than the field can change in one sample"
            }
            MaskReason::Dropout => {
                "an axis reading zero (alone or in a run) between neighbours 500 nT or more from zero: a dropout"
            }
            MaskReason::Glitch => {
                "glitches: samples further from most of their neighbours than the aircraft can turn in two intervals (90°/s), up to 3 in a row"
            }
            MaskReason::Stuck => {
                "one reading repeated for 5 s or longer: the sensor is stuck or its axis dead, or the logger held its last value"
            }
            MaskReason::Burst => {
                "glitches lasting more than one sample: runs entered and left by jumps larger than the field can change in one interval, the readings either side agreeing (runs up to 10 s on a scalar, 2 s on a fluxgate axis)"
            }
            MaskReason::Disagreement => {
                "glitches the sensors' agreement shows: the turn the INS reports and the turn of the field the fluxgate sees part abruptly (by 1° or more, and 8 times the flight's median step) and agree again within 5 s; masked in the sensor whose reading, drawn across the run, restores the agreement (in the INS and the fluxgate both where neither alone does)"
            }
            MaskReason::HeldStep => {
                "a step the other sensor does not see, held: the INS attitude and the fluxgate's field direction part abruptly (by 1° or more, and 8 times the flight's median step) and stay parted, as one channel alone explains (a heading realigned by the INS); masked in that channel from the step until it steps back; a step that never steps back leaves two parts the agreement alone cannot tell apart, and the shorter is masked (the vector's direction check against IGRF-14 says where that is the wrong one)"
            }
            MaskReason::Departure => {
                "glitches held too long for continuity: the scalar's departure from the fluxgate's magnitude steps by more than 1,000 nT (and 8 times the flight's median step) while the other sensor holds still, and steps back within 600 s; masked in the sensor that stepped"
            }
        }
    }
}

/// The masked samples of one column for one reason.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MaskedSamples {
    /// Column name.
    pub column: String,
    /// Why.
    pub reason: MaskReason,
    /// How many samples.
    pub samples: usize,
    /// Time of the first, in the file's time unit.
    pub first_time_s: f64,
    /// The first masked value as recorded.
    pub first_value: f64,
}

impl MaskedSamples {
    /// The warning that says what was masked: "masked 2 samples of
    /// flux_a_x (…), the first at 46012.3 s (1e308); … their rows are
    /// flagged out_of_range:flux_a_x".
    pub fn warning(&self) -> Warning {
        Warning::Masked {
            column: self.column.clone(),
            samples: self.samples,
            reason: self.reason.describe().into(),
            first_time: self.first_time_s,
            first_value: self.first_value,
            flag: self.reason.flag().name().into(),
        }
    }
}

/// What screening masked, column by column.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Screening {
    /// Per column and reason, in column order.
    pub masked: Vec<MaskedSamples>,
}

impl Screening {
    /// Whether nothing was masked.
    pub fn is_clean(&self) -> bool {
        self.masked.is_empty()
    }

    /// What screening masked of `column` when it masked every finite
    /// sample of it in `screened` (the log the stages work on), in words;
    /// `None` when a sample is left or screening did not touch it.
    pub fn took_all(&self, screened: &FlightLog, column: &str) -> Option<String> {
        let left = screened.channel(column)?.values.iter().any(|v| v.is_finite());
        let reasons: Vec<&str> = (self.masked.iter())
            .filter(|m| m.column == column)
            .map(|m| m.reason.describe())
            .collect();
        (!left && !reasons.is_empty()).then(|| reasons.join("; "))
    }

    /// One warning per column and reason, for stdout and the report.
    pub fn warnings(&self) -> Vec<Warning> {
        self.masked.iter().map(MaskedSamples::warning).collect()
    }
}

/// A screened flight: the log the stages work on and what was masked.
#[derive(Debug, Clone)]
pub struct Screened {
    /// The log with the masked samples missing; `None` when nothing was
    /// masked (the input log is used as it is).
    pub log: Option<FlightLog>,
    /// What was masked.
    pub screening: Screening,
}

impl Screened {
    /// What reading `recorded` lost and what screening masked, one line
    /// each, for stdout and the report.
    pub fn warnings(&self, recorded: &FlightLog) -> Vec<Warning> {
        let reading = recorded.reading_warnings().iter().cloned();
        reading.chain(self.screening.warnings()).collect()
    }

    /// The log to work on: the screened one, or `input` when it was clean.
    pub fn log_or<'a>(&'a self, input: &'a FlightLog) -> &'a FlightLog {
        self.log.as_ref().unwrap_or(input)
    }
}

/// Masks the samples of `log` no instrument can record (see the module
/// documentation) and flags their rows.
pub fn screen_samples(log: &FlightLog) -> Result<Screened> {
    use rayon::prelude::*;
    let interval_s = log.median_interval_s();
    // Channel by channel in parallel; collected in channel order.
    let found: Vec<Vec<(usize, MaskReason)>> = log
        .channels()
        .par_iter()
        .map(|channel| screen_channel(&channel.name, &channel.role, &channel.values, interval_s))
        .collect();
    let mut masks: BTreeMap<usize, Vec<(usize, MaskReason)>> = found
        .into_iter()
        .enumerate()
        .filter(|(_, rows)| !rows.is_empty())
        .collect();
    for sensor in log.vector_sensors() {
        let [x, y, z] = sensor.axes.map(|axis| log.channels()[axis].values.as_slice());
        for row in 0..log.len() {
            let reason = vector_reason([x[row], y[row], z[row]]);
            let Some((reason, culprit)) = reason else { continue };
            // One bad axis makes the whole reading missing downstream.
            for (k, axis) in sensor.axes.iter().enumerate() {
                if culprit.is_none_or(|c| c == k) {
                    masks.entry(*axis).or_default().push((row, reason));
                }
            }
        }
    }
    // Glitches each channel's own screen cannot see: the INS attitude
    // against each fluxgate's field direction.
    for (channel, rows) in super::agreement::disagreements(log, &masks) {
        masks.entry(channel).or_default().extend(rows);
    }
    // Scalar glitches held too long for continuity to judge: each scalar
    // against the fluxgate's magnitude.
    for (channel, rows) in super::magnitude::departures(log, &masks) {
        masks.entry(channel).or_default().extend(rows);
    }
    if masks.is_empty() {
        return Ok(Screened {
            log: None,
            screening: Screening::default(),
        });
    }
    apply_masks(log, masks)
}

/// The samples of one channel to mask for its own values alone.
fn screen_channel(name: &str, role: &ChannelRole, values: &[f64], interval_s: f64) -> Vec<(usize, MaskReason)> {
    let range = |low: f64, high: f64| -> Vec<(usize, MaskReason)> {
        values
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_finite() && !(low..=high).contains(*v))
            .map(|(row, _)| (row, MaskReason::OutOfRange))
            .collect()
    };
    match role {
        ChannelRole::ScalarMagnetometer | ChannelRole::BaseStation => {
            // A base station records the variation or the total field.
            let (low, high) = match role {
                ChannelRole::BaseStation => (-TOTAL_FIELD_RANGE_NT.1, TOTAL_FIELD_RANGE_NT.1),
                _ => TOTAL_FIELD_RANGE_NT,
            };
            let mut found = range(low, high);
            let jump_nt = (FASTEST_TOTAL_FIELD_NT_S * interval_s).max(100.0);
            found.extend(spikes(values, jump_nt, &found));
            let most_change = |dt: f64| (FASTEST_TOTAL_FIELD_NT_S * dt).min(GEOLOGY_NT_S * dt + AIRCRAFT_SWING_NT);
            let reach = samples_within(SCALAR_GLITCH_REACH_S, interval_s);
            found.extend(bursts(values, (jump_nt, interval_s), reach, most_change, &found));
            // A base station may record at a minute's cadence, held.
            if matches!(role, ChannelRole::ScalarMagnetometer) {
                found.extend(stuck(values, interval_s));
            }
            found
        }
        ChannelRole::VectorTotal { .. } => range(0.0, MOST_VECTOR_COMPONENT_NT * 3f64.sqrt()),
        ChannelRole::VectorMagnetometer { .. } => {
            let jump_nt = (FASTEST_COMPONENT_NT_S * interval_s).max(1_000.0);
            let mut found = dropouts(values);
            found.extend(spikes(values, jump_nt, &found));
            let most_change = |dt: f64| FASTEST_COMPONENT_NT_S * dt;
            let reach = samples_within(COMPONENT_GLITCH_REACH_S, interval_s);
            found.extend(bursts(values, (jump_nt, interval_s), reach, most_change, &found));
            found.extend(stuck(values, interval_s));
            found
        }
        ChannelRole::Attitude(angle) => {
            let mut found = match angle {
                AttitudeAngle::Pitch => range(-90.0, 90.0),
                AttitudeAngle::Roll => range(-180.0, 180.0),
                AttitudeAngle::Yaw => range(-3_600.0, 3_600.0),
            };
            let jump_deg = (FASTEST_ATTITUDE_DEG_S * interval_s).max(LEAST_ATTITUDE_GLITCH_DEG);
            found.extend(glitches(values, jump_deg, *angle == AttitudeAngle::Yaw, &found));
            found
        }
        ChannelRole::Position => {
            let lowercase = name.to_ascii_lowercase();
            if lowercase.starts_with("lat") {
                range(-90.0, 90.0)
            } else if lowercase.starts_with("lon") {
                range(-360.0, 360.0)
            } else {
                range(-1e7, 1e7)
            }
        }
        _ => range(-MOST_AUXILIARY, MOST_AUXILIARY),
    }
}

/// Why a fluxgate row is masked, and which axis is to blame (`None`: the
/// whole reading).
fn vector_reason(components: [f64; 3]) -> Option<(MaskReason, Option<usize>)> {
    if let Some(k) = components
        .iter()
        .position(|c| c.is_finite() && c.abs() > MOST_VECTOR_COMPONENT_NT)
    {
        return Some((MaskReason::OutOfRange, Some(k)));
    }
    if components.iter().all(|c| c.is_finite()) {
        let magnitude = components.iter().map(|c| c * c).sum::<f64>().sqrt();
        if magnitude < LEAST_VECTOR_MAGNITUDE_NT {
            return Some((MaskReason::ZeroVector, None));
        }
    }
    None
}

/// Rows where a fluxgate axis reads zero (or a subnormal), alone or in a
/// run, between two neighbours well away from zero: a dropout, not a zero
/// crossing (an axis crossing zero passes it, it does not stay). A
/// subnormal is a dropout anywhere.
fn dropouts(values: &[f64]) -> Vec<(usize, MaskReason)> {
    let away = |v: f64| v.is_finite() && v.abs() >= DROPOUT_NEIGHBOUR_NT;
    let zero = |v: f64| v.abs() < DROPOUT_NT;
    let mut found = Vec::new();
    let mut row = 1;
    while row + 1 < values.len() {
        if !zero(values[row]) {
            row += 1;
            continue;
        }
        let start = row;
        while row < values.len() && zero(values[row]) {
            row += 1;
        }
        let between_readings = row < values.len() && away(values[start - 1]) && away(values[row]);
        // No instrument reads a subnormal: it is a damaged cell wherever it is.
        let subnormal = |r: &usize| values[*r] != 0.0;
        for r in (start..row).filter(|r| between_readings || subnormal(r)) {
            found.push((r, MaskReason::Dropout));
        }
    }
    found
}

/// Rows holding an isolated spike: a finite sample further than `jump`
/// from both its finite neighbours, which are within `jump / 2` of each
/// other. Rows already in `masked` are not neighbours.
fn spikes(values: &[f64], jump: f64, masked: &[(usize, MaskReason)]) -> Vec<(usize, MaskReason)> {
    let excluded: std::collections::HashSet<usize> = masked.iter().map(|(row, _)| *row).collect();
    let usable = |row: usize| values[row].is_finite() && !excluded.contains(&row);
    (1..values.len().saturating_sub(1))
        .filter(|&row| usable(row) && usable(row - 1) && usable(row + 1))
        .filter(|&row| {
            let (before, here, after) = (values[row - 1], values[row], values[row + 1]);
            (here - before).abs() > jump && (here - after).abs() > jump && (after - before).abs() < jump / 2.0
        })
        .map(|row| (row, MaskReason::Spike))
        .collect()
}

/// Samples within `seconds` of a row at `interval_s`, at least
/// [`LONGEST_GLITCH_SAMPLES`] and at most [`MOST_GLITCH_REACH_SAMPLES`].
fn samples_within(seconds: f64, interval_s: f64) -> usize {
    let samples = (seconds / interval_s.max(1e-9)).round();
    (samples.min(MOST_GLITCH_REACH_SAMPLES as f64) as usize).max(LONGEST_GLITCH_SAMPLES)
}

/// Rows of a magnetometer's glitches that last more than one sample: a
/// run of up to `reach` samples entered and left by jumps larger than the
/// field can change in their interval, whose readings either side agree
/// with each other within what the field can change across the run
/// (`most_change` of the time, at least `least.0`; `least.1` is the
/// sampling interval). A real change, however fast, makes no such jump,
/// so nothing the aircraft flies through is masked; a clean record costs
/// one pass. Rows already in `masked` are not read.
fn bursts(
    values: &[f64],
    least: (f64, f64),
    reach: usize,
    most_change: impl Fn(f64) -> f64,
    masked: &[(usize, MaskReason)],
) -> Vec<(usize, MaskReason)> {
    let (jump, interval_s) = least;
    let excluded: std::collections::HashSet<usize> = masked.iter().map(|(row, _)| *row).collect();
    let usable: Vec<usize> = (0..values.len())
        .filter(|row| values[*row].is_finite() && !excluded.contains(row))
        .collect();
    let allowed = |a: usize, b: usize| most_change(b.abs_diff(a) as f64 * interval_s).max(jump);
    let agree = |a: usize, b: usize| (values[b] - values[a]).abs() <= allowed(a, b);
    // Jumps between consecutive usable readings, as (before, after) rows.
    let jumps: Vec<(usize, usize)> = (usable.windows(2))
        .map(|pair| (pair[0], pair[1]))
        .filter(|&(a, b)| !agree(a, b))
        .collect();
    let mut found = Vec::new();
    let mut i = 0;
    while i < jumps.len() {
        let (before, first) = jumps[i];
        // The nearest later jump within reach that lands back where the
        // reading before the run would allow.
        let back = (jumps[i + 1..].iter().enumerate())
            .take_while(|(_, (last, _))| last - first < reach)
            .find(|(_, (_, after))| agree(before, *after));
        match back {
            Some((offset, &(last, _))) => {
                found.extend(
                    usable
                        .iter()
                        .filter(|&&r| r >= first && r <= last)
                        .map(|&r| (r, MaskReason::Burst)),
                );
                i += offset + 2;
            }
            None => i += 1,
        }
    }
    found
}

/// Rows of attitude glitches: a finite sample further than twice `jump`
/// (the most the aircraft turns in one interval) from more than half of
/// its usable neighbours, up to [`LONGEST_GLITCH_SAMPLES`] on each side and
/// at least three. At the fastest turn a good sample is within two
/// intervals' turn of the four nearest of its six neighbours, so no motion
/// the aircraft can make is masked; judged by majority, a good sample
/// between glitches stays, and runs of up to [`LONGEST_GLITCH_SAMPLES`]
/// glitches are found whatever their values. Differences of a heading
/// (`wraps`) are taken across north, within ±180°. Rows already in
/// `masked` are not neighbours.
fn glitches(values: &[f64], jump: f64, wraps: bool, masked: &[(usize, MaskReason)]) -> Vec<(usize, MaskReason)> {
    let excluded: std::collections::HashSet<usize> = masked.iter().map(|(row, _)| *row).collect();
    let usable = |row: usize| values[row].is_finite() && !excluded.contains(&row);
    let difference = |a: f64, b: f64| match wraps {
        true => (a - b + 180.0).rem_euclid(360.0) - 180.0,
        false => a - b,
    };
    let reach = LONGEST_GLITCH_SAMPLES;
    (0..values.len())
        .filter(|&row| usable(row))
        .filter(|&row| {
            let around = row.saturating_sub(reach)..=(row + reach).min(values.len() - 1);
            let neighbours: Vec<usize> = around.filter(|&j| j != row && usable(j)).collect();
            let far = (neighbours.iter())
                .filter(|&&j| difference(values[j], values[row]).abs() > 2.0 * jump)
                .count();
            neighbours.len() >= 3 && 2 * far > neighbours.len()
        })
        .map(|row| (row, MaskReason::Glitch))
        .collect()
}

/// Rows of runs of one repeated finite reading lasting [`STUCK_S`] or
/// longer and at least [`STUCK_SAMPLES`] samples (at the median
/// `interval_s`).
fn stuck(values: &[f64], interval_s: f64) -> Vec<(usize, MaskReason)> {
    let shortest = STUCK_SAMPLES.max((STUCK_S / interval_s).ceil() as usize);
    let mut found = Vec::new();
    let mut start = 0;
    for row in 1..=values.len() {
        let same = row < values.len() && values[row].is_finite() && values[row] == values[start];
        if same {
            continue;
        }
        if values[start].is_finite() && row - start >= shortest {
            found.extend((start..row).map(|r| (r, MaskReason::Stuck)));
        }
        start = row;
    }
    found
}

/// The log with the masked samples set missing and their rows flagged.
fn apply_masks(log: &FlightLog, masks: BTreeMap<usize, Vec<(usize, MaskReason)>>) -> Result<Screened> {
    let mut flags = match log.row_flags().len() == log.len() {
        true => log.row_flags().to_vec(),
        false => vec![RowFlags::default(); log.len()],
    };
    let mut masked_log = log.clone();
    let mut summary = Vec::new();
    for (index, mut rows) in masks {
        rows.sort();
        rows.dedup_by_key(|(row, _)| *row);
        let channel = &log.channels()[index];
        let mut values = channel.values.clone();
        let mut by_reason: BTreeMap<MaskReason, Vec<usize>> = BTreeMap::new();
        for (row, reason) in rows {
            values[row] = f64::NAN;
            by_reason.entry(reason).or_default().push(row);
            flags[row].raise(reason.flag(), &channel.name);
        }
        for (reason, rows) in by_reason {
            summary.push(MaskedSamples {
                column: channel.name.clone(),
                reason,
                samples: rows.len(),
                first_time_s: log.time_s()[rows[0]],
                first_value: channel.values[rows[0]],
            });
        }
        masked_log = masked_log.with_values(&channel.name, values)?;
    }
    Ok(Screened {
        log: Some(masked_log.with_row_flags(flags)),
        screening: Screening { masked: summary },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::flight_log::Channel;

    fn flight(scalar: Vec<f64>, fluxgate: [Vec<f64>; 3], roll: Vec<f64>) -> FlightLog {
        let rows = scalar.len();
        let time: Vec<f64> = (0..rows).map(|k| 100.0 + 0.1 * k as f64).collect();
        let [x, y, z] = fluxgate;
        let channels = vec![
            Channel {
                name: "mag_1_uc".into(),
                role: ChannelRole::ScalarMagnetometer,
                values: scalar,
            },
            Channel {
                name: "flux_a_x".into(),
                role: ChannelRole::VectorMagnetometer {
                    sensor: "flux_a".into(),
                    axis: crate::ingest::flight_log::VectorAxis::X,
                },
                values: x,
            },
            Channel {
                name: "flux_a_y".into(),
                role: ChannelRole::VectorMagnetometer {
                    sensor: "flux_a".into(),
                    axis: crate::ingest::flight_log::VectorAxis::Y,
                },
                values: y,
            },
            Channel {
                name: "flux_a_z".into(),
                role: ChannelRole::VectorMagnetometer {
                    sensor: "flux_a".into(),
                    axis: crate::ingest::flight_log::VectorAxis::Z,
                },
                values: z,
            },
            Channel {
                name: "ins_roll".into(),
                role: ChannelRole::Attitude(AttitudeAngle::Roll),
                values: roll,
            },
        ];
        FlightLog::new("flight.csv", "tt", time, channels).unwrap()
    }

    fn steady(rows: usize) -> FlightLog {
        let scalar: Vec<f64> = (0..rows).map(|k| 53_000.0 + (k as f64 * 0.3).sin()).collect();
        let x: Vec<f64> = (0..rows).map(|k| 18_000.0 + 300.0 * (k as f64 * 0.05).sin()).collect();
        let y: Vec<f64> = (0..rows).map(|k| -9_000.0 + 40.0 * (k as f64 * 0.07).cos()).collect();
        let z: Vec<f64> = (0..rows).map(|k| 49_000.0 + 20.0 * (k as f64 * 0.03).sin()).collect();
        flight(scalar, [x, y, z], vec![2.0; rows])
    }

    /// A heading turning steadily through north at 10 Hz.
    fn heading(rows: usize) -> Vec<f64> {
        (0..rows).map(|k| (340.0 + 0.4 * k as f64).rem_euclid(360.0)).collect()
    }

    fn with_heading(log: &FlightLog, yaw: Vec<f64>) -> FlightLog {
        let mut channels = log.channels().to_vec();
        channels.push(Channel {
            name: "ins_yaw".into(),
            role: ChannelRole::Attitude(AttitudeAngle::Yaw),
            values: yaw,
        });
        FlightLog::new("flight.csv", "tt", log.time_s().to_vec(), channels).unwrap()
    }

    /// Heading glitches (a dropout read as 0, 359.9, −180 or a subnormal,
    /// alone or two and three in a row) are masked as spikes; the turn
    /// through north (359.6° to 0.0°) and a roll at the fastest rate are
    /// not.
    #[test]
    fn attitude_glitches_are_masked_and_the_turn_through_north_is_not() {
        let rows = 500;
        let mut yaw = heading(rows);
        let glitches: [(usize, f64); 8] = [
            (150, 0.0),
            (100, 359.9),
            (160, -180.0),
            (220, 4.9e-324),
            (300, 0.0),
            (301, 0.0),
            (400, 359.9),
            (402, 5.0),
        ];
        yaw[401] = 180.0;
        for (row, value) in glitches {
            yaw[row] = value;
        }
        let mut log = with_heading(&steady(rows), yaw);
        // A roll swinging at 80°/s (the limit is 90°/s): no glitch.
        let roll: Vec<f64> = (0..rows).map(|k| 25.0 * (k as f64 * 0.32).sin()).collect();
        log = log.with_values("ins_roll", roll).unwrap();
        let screened = screen_samples(&log).unwrap();
        let flags = screened.log.as_ref().unwrap().row_flags();
        let flagged: Vec<usize> = (0..rows).filter(|&k| !flags[k].is_empty()).collect();
        let mut expected: Vec<usize> = glitches.iter().map(|(row, _)| *row).chain([401]).collect();
        expected.sort();
        assert_eq!(flagged, expected, "{:?}", screened.screening.warnings());
        assert!(flagged.iter().all(|&k| flags[k].to_string() == "spike:ins_yaw"));
        // The heading crosses north between rows 50 and 51 (359.6° to
        // 0.0°, then 0.4°): kept.
        let kept = &screened.log.as_ref().unwrap().channel("ins_yaw").unwrap().values;
        assert!(kept[49..53].iter().all(|v| v.is_finite()), "{:?}", &kept[49..53]);
        assert!(screened
            .screening
            .warnings()
            .iter()
            .any(|w| w.to_string().contains("masked 9 samples of ins_yaw")));
    }

    /// A fluxgate axis that reads 0 throughout and a scalar that repeats
    /// one value for 8 s are masked as stuck; a scalar held for 1 s (a
    /// slower instrument resampled) is not.
    #[test]
    fn a_dead_axis_and_a_stuck_scalar_are_masked() {
        let rows = 500;
        let log = steady(rows);
        let mut scalar = log.channel("mag_1_uc").unwrap().values.clone();
        scalar[100..180].fill(53_000.25);
        let held = scalar[300];
        scalar[300..310].fill(held);
        let log = log
            .with_values("mag_1_uc", scalar)
            .unwrap()
            .with_values("flux_a_y", vec![0.0; rows])
            .unwrap();
        let screened = screen_samples(&log).unwrap();
        let masked = screened.log.as_ref().unwrap();
        let flags = masked.row_flags();
        assert!((0..rows).all(|k| flags[k].has(FlagKind::Stuck, "flux_a_y")));
        let stuck_scalar: Vec<usize> = (0..rows)
            .filter(|&k| flags[k].has(FlagKind::Stuck, "mag_1_uc"))
            .collect();
        assert_eq!(stuck_scalar, (100..180).collect::<Vec<_>>());
        assert!(masked.channel("flux_a_y").unwrap().values.iter().all(|v| v.is_nan()));
        let warnings = screened.screening.warnings();
        assert!(
            warnings
                .iter()
                .map(ToString::to_string)
                .any(|w| w.contains("masked 500 samples of flux_a_y") && w.contains("stuck or its axis dead")),
            "{warnings:?}"
        );
        assert!(
            warnings
                .iter()
                .any(|w| w.to_string().contains("masked 80 samples of mag_1_uc")),
            "{warnings:?}"
        );
    }

    #[test]
    fn a_clean_flight_is_left_as_it_is() {
        let screened = screen_samples(&steady(500)).unwrap();
        assert!(screened.log.is_none() && screened.screening.is_clean());
    }

    #[test]
    fn impossible_readings_are_masked_and_flagged_and_nothing_else() {
        let log = steady(500);
        let mut scalar = log.channel("mag_1_uc").unwrap().values.clone();
        scalar[10] = 1e308;
        scalar[20] = 4.9e-324;
        scalar[30] = 60_000.0; // a spike of 7,000 nT in 0.1 s
        let mut x = log.channel("flux_a_x").unwrap().values.clone();
        let mut y = log.channel("flux_a_y").unwrap().values.clone();
        let mut z = log.channel("flux_a_z").unwrap().values.clone();
        for row in 100..110 {
            (x[row], y[row], z[row]) = (0.0, 0.0, 0.0);
        }
        x[200] = -1.5e308;
        x[250] = 0.0; // a dropout of one axis
        y[260] = 4.9e-324;
        let mut roll = vec![2.0; 500];
        roll[300] = 1.5e308;
        let bad = flight(scalar.clone(), [x, y, z], roll);
        let screened = screen_samples(&bad).unwrap();
        let masked = screened.log.as_ref().unwrap();
        let missing = |name: &str| -> Vec<usize> {
            let values = &masked.channel(name).unwrap().values;
            (0..values.len()).filter(|&k| values[k].is_nan()).collect()
        };
        assert_eq!(missing("mag_1_uc"), [10, 20, 30]);
        let zero_rows: Vec<usize> = (100..110).collect();
        assert_eq!(missing("flux_a_x"), [zero_rows.clone(), vec![200, 250]].concat());
        assert_eq!(missing("flux_a_y"), [zero_rows.clone(), vec![260]].concat());
        assert_eq!(missing("flux_a_z"), zero_rows);
        assert_eq!(missing("ins_roll"), [300]);
        let flags = masked.row_flags();
        assert_eq!(flags[10].to_string(), "out_of_range:mag_1_uc");
        assert_eq!(flags[30].to_string(), "spike:mag_1_uc");
        assert!(
            flags[105].to_string().contains("zero_vector:flux_a_x")
                && flags[105].to_string().contains("zero_vector:flux_a_z")
        );
        assert!(flags[200].to_string().contains("out_of_range:flux_a_x"));
        assert_eq!(flags[300].to_string(), "out_of_range:ins_roll");
        let flagged = flags.iter().filter(|f| !f.is_empty()).count();
        assert_eq!(
            flagged,
            3 + zero_rows.len() + 1 + 2 + 1,
            "only the bad rows are flagged"
        );
        assert_eq!(flags[250].to_string(), "dropout:flux_a_x");
        assert_eq!(flags[260].to_string(), "dropout:flux_a_y");
        // Every other sample is as recorded.
        let kept = &masked.channel("mag_1_uc").unwrap().values;
        assert!((0..500)
            .filter(|k| ![10, 20, 30].contains(k))
            .all(|k| kept[k] == scalar[k]));
        let warnings = screened.screening.warnings();
        assert!(
            warnings
                .iter()
                .map(ToString::to_string)
                .any(|w| w.contains("masked 10 samples of flux_a_x") && w.contains("110 s")),
            "{warnings:?}"
        );
        assert!(
            warnings.iter().any(|w| w.to_string().contains("(1e308)")),
            "{warnings:?}"
        );
    }

    #[test]
    fn a_fast_but_real_change_is_not_a_spike() {
        // A step of 800 nT (a sensor crossing a strong anomaly, or the
        // aircraft's field in a roll) that stays is not masked.
        let mut log = steady(200);
        let mut scalar = log.channel("mag_1_uc").unwrap().values.clone();
        for value in &mut scalar[100..] {
            *value += 800.0;
        }
        log = log.with_values("mag_1_uc", scalar).unwrap();
        assert!(screen_samples(&log).unwrap().screening.is_clean());
    }
}
