//! The flight-log data model shared by every stage.
//!
//! A [`FlightLog`] is one time base in seconds plus named `f64` channels stored
//! as columns. A missing sample is `NaN`. Every channel carries a
//! [`ChannelRole`] telling the pipeline what it measures. The invariants
//! (equal lengths, finite and strictly increasing time) are checked once, in
//! [`FlightLog::new`], so later stages can rely on them.

use crate::ingest::flags::RowFlags;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::error::{Error, Result};
use crate::messages::Warning;

/// The three body axes of a vector magnetometer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum VectorAxis {
    /// Body x (forward in the SGL installation).
    X,
    /// Body y.
    Y,
    /// Body z.
    Z,
}

/// The rotation from body axes (forward, right, down) to north-east-down:
/// $R_{nb} = R_z(\psi) R_y(\theta) R_x(\phi)$, yaw ψ clockwise from north,
/// pitch θ nose up, roll φ right wing down (CONTRACT §1).
pub fn body_to_ned(roll_deg: f64, pitch_deg: f64, yaw_deg: f64) -> nalgebra::Rotation3<f64> {
    nalgebra::Rotation3::from_euler_angles(roll_deg.to_radians(), pitch_deg.to_radians(), yaw_deg.to_radians())
}

/// The three INS attitude angles, in degrees (CONTRACT §1 conventions).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AttitudeAngle {
    /// Pitch, nose up positive.
    Pitch,
    /// Roll, right wing down positive.
    Roll,
    /// Yaw (heading), clockwise from north.
    Yaw,
}

/// What a channel measures.
#[derive(Debug, Clone, PartialEq)]
pub enum ChannelRole {
    /// Survey line number.
    Line,
    /// Uncompensated total-field magnetometer, nT.
    ScalarMagnetometer,
    /// One axis of a vector magnetometer, nT, identified by its sensor prefix.
    VectorMagnetometer {
        /// Sensor prefix, e.g. `flux_a`.
        sensor: String,
        /// The body axis.
        axis: VectorAxis,
    },
    /// Vector magnetometer's own total-field output, nT.
    VectorTotal {
        /// Sensor prefix, e.g. `flux_a`.
        sensor: String,
    },
    /// INS attitude angle, degrees.
    Attitude(AttitudeAngle),
    /// Latitude, longitude or height.
    Position,
    /// Ground base-station magnetometer variation, nT.
    BaseStation,
    /// Any other numeric channel (currents, voltages, ...).
    Auxiliary,
}

/// One named column of samples.
#[derive(Debug, Clone)]
pub struct Channel {
    /// Column name as in the input file.
    pub name: String,
    /// What the channel measures.
    pub role: ChannelRole,
    /// One value per time sample; `NaN` marks a missing sample.
    pub values: Vec<f64>,
}

/// The three columns of one vector magnetometer, as channel indices.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VectorSensor {
    /// Sensor prefix, e.g. `flux_a`.
    pub prefix: String,
    /// Channel indices of the x, y and z components.
    pub axes: [usize; 3],
}

/// A validated flight log: one time base and its channels.
#[derive(Debug, Clone)]
pub struct FlightLog {
    source: PathBuf,
    time_column: String,
    time_s: Vec<f64>,
    /// Median sample interval, s (computed once: time never changes).
    median_interval_s: f64,
    channels: Vec<Channel>,
    source_row_offsets: Option<Vec<u64>>,
    row_flags: Vec<RowFlags>,
    alignment: Option<AlignmentReport>,
    date: Option<crate::ingest::flight_date::FlightDate>,
    reading_warnings: Vec<Warning>,
    text_columns: Vec<String>,
    declared_units: Vec<(String, String)>,
    /// Series derived from one channel, computed once and shared by the
    /// log's clones (their channels are the same values).
    derived: Derived,
}

/// What was derived from a channel, each named by (channel, what it is).
type Derived = std::sync::Arc<std::sync::Mutex<DerivedList>>;

/// What was derived so far.
type DerivedList = Vec<((String, &'static str), std::sync::Arc<dyn std::any::Any + Send + Sync>)>;

impl FlightLog {
    /// Builds a flight log, checking that every channel has one value per
    /// time sample and that time is finite and strictly increasing.
    pub fn new(
        source: impl Into<PathBuf>,
        time_column: impl Into<String>,
        time_s: Vec<f64>,
        channels: Vec<Channel>,
    ) -> Result<Self> {
        let source = source.into();
        let time_column = time_column.into();
        check_time(&source, &time_column, &time_s, |i| format!("sample {i}"))?;
        if let Some(bad) = channels.iter().find(|c| c.values.len() != time_s.len()) {
            return Err(Error::LengthMismatch {
                column: bad.name.clone(),
                found: bad.values.len(),
                expected: time_s.len(),
            });
        }
        Ok(FlightLog {
            source,
            time_column,
            median_interval_s: median_step(&time_s),
            time_s,
            channels,
            source_row_offsets: None,
            row_flags: Vec::new(),
            alignment: None,
            date: None,
            reading_warnings: Vec::new(),
            text_columns: Vec::new(),
            declared_units: Vec::new(),
            derived: Derived::default(),
        })
    }

    /// The same flight with one channel's values replaced (same length),
    /// keeping the row flags, source offsets and alignment record.
    pub fn with_values(&self, name: &str, values: Vec<f64>) -> Result<Self> {
        if values.len() != self.time_s.len() {
            return Err(Error::LengthMismatch {
                column: name.to_string(),
                found: values.len(),
                expected: self.time_s.len(),
            });
        }
        let mut log = self.clone();
        if let Some(channel) = log.channels.iter_mut().find(|c| c.name == name) {
            channel.values = values;
        }
        // What was derived from the other channels still holds.
        let kept: Vec<_> = (self.derived_series().iter())
            .filter(|((channel, _), _)| channel != name)
            .cloned()
            .collect();
        log.derived = std::sync::Arc::new(std::sync::Mutex::new(kept));
        Ok(log)
    }

    /// The same rows (times, row flags, source and date) with only
    /// `channels`, each one value per row: the lean flight a derived fit
    /// reads (a gradient's difference, a fluxgate's body-axis residual).
    pub fn with_channels(&self, channels: Vec<Channel>) -> Result<Self> {
        if let Some(bad) = channels.iter().find(|c| c.values.len() != self.time_s.len()) {
            return Err(Error::LengthMismatch {
                column: bad.name.clone(),
                found: bad.values.len(),
                expected: self.time_s.len(),
            });
        }
        Ok(FlightLog {
            source: self.source.clone(),
            time_column: self.time_column.clone(),
            time_s: self.time_s.clone(),
            median_interval_s: self.median_interval_s,
            channels,
            source_row_offsets: self.source_row_offsets.clone(),
            row_flags: self.row_flags.clone(),
            alignment: None,
            date: self.date,
            reading_warnings: Vec::new(),
            text_columns: Vec::new(),
            declared_units: Vec::new(),
            derived: Derived::default(),
        })
    }

    /// `what` derived from channel `name` by `derive`, computed on the
    /// first call and shared from then on by this log and its clones;
    /// `None` without the channel. `what` names the derivation: one name,
    /// one function (a name asked for with another type is derived again).
    pub fn derived<T: std::any::Any + Send + Sync>(
        &self,
        name: &str,
        what: &'static str,
        derive: impl FnOnce(&Channel) -> T,
    ) -> Option<std::sync::Arc<T>> {
        let channel = self.channel(name)?;
        let mut series = self.derived_series();
        let found = (series.iter())
            .find(|((c, w), _)| c == name && *w == what)
            .and_then(|(_, found)| found.clone().downcast::<T>().ok());
        if found.is_some() {
            return found;
        }
        let value = std::sync::Arc::new(derive(channel));
        series.push(((name.to_string(), what), value.clone()));
        Some(value)
    }

    fn derived_series(&self) -> std::sync::MutexGuard<'_, DerivedList> {
        // A derivation that panicked left nothing half-written: the list
        // is pushed to only after it returns.
        self.derived.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Attaches per-row flags raised while reading (e.g. `gap:cur_a` where
    /// a channel had a gap); ignored unless there is one per row.
    pub fn with_row_flags(mut self, flags: Vec<RowFlags>) -> Self {
        if flags.len() == self.time_s.len() {
            self.row_flags = flags;
        }
        self
    }

    /// Per-row flags raised while reading; empty when there are none.
    pub fn row_flags(&self) -> &[RowFlags] {
        &self.row_flags
    }

    /// Records the input's columns of text (not numbers), which the log
    /// does not hold: only a copy of the input file keeps them.
    pub fn with_text_columns(mut self, names: Vec<String>) -> Self {
        self.text_columns = names;
        self
    }

    /// Records the units a row under the input's header gives, as (column,
    /// unit) in the header's order.
    pub fn with_declared_units(mut self, units: Vec<(String, String)>) -> Self {
        self.declared_units = units;
        self
    }

    /// The units the input's row under its header gives, as (column, unit);
    /// empty when the input has no such row.
    pub fn declared_units(&self) -> &[(String, String)] {
        &self.declared_units
    }

    /// The input's columns of text, left out of the log.
    pub fn text_columns(&self) -> &[String] {
        &self.text_columns
    }

    /// Records what the reader could not read or had to leave out.
    pub fn with_reading_warnings(mut self, warnings: Vec<Warning>) -> Self {
        self.reading_warnings = warnings;
        self
    }

    /// What the reader could not read or had to leave out (a file cut
    /// short, a dataset of another length, repeated times): each a line
    /// for stdout and the report.
    pub fn reading_warnings(&self) -> &[Warning] {
        &self.reading_warnings
    }

    /// Records the day the flight was flown (UTC).
    pub fn with_date(mut self, date: Option<crate::ingest::flight_date::FlightDate>) -> Self {
        self.date = date;
        self
    }

    /// The day the flight was flown, when known: its time column is then
    /// seconds of that day.
    pub fn date(&self) -> Option<crate::ingest::flight_date::FlightDate> {
        self.date
    }

    /// Records how multi-rate channels were placed on the time base.
    pub fn with_alignment(mut self, report: AlignmentReport) -> Self {
        self.alignment = Some(report);
        self
    }

    /// How multi-rate channels were placed on the time base, when they were.
    pub fn alignment(&self) -> Option<&AlignmentReport> {
        self.alignment.as_ref()
    }

    /// Records where each row's record starts in the source text file (byte
    /// offsets, one per row, increasing), so outputs can copy the rows
    /// verbatim. Ignored unless there is one offset per row.
    pub fn with_source_row_offsets(mut self, offsets: Vec<u64>) -> Self {
        let increasing = offsets.windows(2).all(|w| w[0] < w[1]);
        if offsets.len() == self.time_s.len() && increasing {
            self.source_row_offsets = Some(offsets);
        }
        self
    }

    /// Byte offset of each row's record in the source text file, when the
    /// reader recorded them.
    pub fn source_row_offsets(&self) -> Option<&[u64]> {
        self.source_row_offsets.as_deref()
    }

    /// Where the log was read from.
    pub fn source(&self) -> &Path {
        &self.source
    }

    /// The rows of each survey line: runs of one non-zero line number in
    /// the line column, in flight order (empty without a line column).
    pub fn survey_lines(&self) -> Vec<(f64, Vec<usize>)> {
        let Some(line) = self.channels.iter().find(|c| c.role == ChannelRole::Line) else {
            return Vec::new();
        };
        let mut lines: Vec<(f64, Vec<usize>)> = Vec::new();
        for (row, number) in line.values.iter().enumerate() {
            if !(number.is_finite() && *number != 0.0) {
                continue;
            }
            match lines.last_mut() {
                Some((last, rows)) if last == number => rows.push(row),
                _ => lines.push((*number, vec![row])),
            }
        }
        lines
    }

    /// Name of the time column in the source.
    pub fn time_column(&self) -> &str {
        &self.time_column
    }

    /// Sample times, seconds, strictly increasing.
    pub fn time_s(&self) -> &[f64] {
        &self.time_s
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.time_s.len()
    }

    /// True when the log holds no sample.
    pub fn is_empty(&self) -> bool {
        self.time_s.is_empty()
    }

    /// All channels, in input order.
    pub fn channels(&self) -> &[Channel] {
        &self.channels
    }

    /// The channel called `name`, if any.
    pub fn channel(&self, name: &str) -> Option<&Channel> {
        self.channels.iter().find(|c| c.name == name)
    }

    /// Names of the scalar magnetometer channels, in input order.
    pub fn scalar_channels(&self) -> Vec<&str> {
        self.channels
            .iter()
            .filter(|c| c.role == ChannelRole::ScalarMagnetometer)
            .map(|c| c.name.as_str())
            .collect()
    }

    /// The vector magnetometers that have all three axes, sorted by prefix.
    pub fn vector_sensors(&self) -> Vec<VectorSensor> {
        let mut found: std::collections::BTreeMap<&str, [Option<usize>; 3]> = Default::default();
        for (index, channel) in self.channels.iter().enumerate() {
            if let ChannelRole::VectorMagnetometer { sensor, axis } = &channel.role {
                found.entry(sensor.as_str()).or_default()[*axis as usize] = Some(index);
            }
        }
        found
            .into_iter()
            .filter_map(|(prefix, axes)| {
                Some(VectorSensor {
                    prefix: prefix.to_string(),
                    axes: [axes[0]?, axes[1]?, axes[2]?],
                })
            })
            .collect()
    }

    /// The vector magnetometer `prefix`, when the flight records its three
    /// axes.
    pub fn vector_sensor(&self, prefix: &str) -> Option<VectorSensor> {
        self.vector_sensors().into_iter().find(|s| s.prefix == prefix)
    }

    /// The INS attitude (roll, pitch, yaw) columns, degrees; `None`
    /// unless all three are recorded.
    pub fn attitude(&self) -> Option<[&[f64]; 3]> {
        let angle = |wanted: AttitudeAngle| {
            self.channels
                .iter()
                .find(|c| c.role == ChannelRole::Attitude(wanted))
                .map(|c| c.values.as_slice())
        };
        Some([
            angle(AttitudeAngle::Roll)?,
            angle(AttitudeAngle::Pitch)?,
            angle(AttitudeAngle::Yaw)?,
        ])
    }

    /// The x, y, z sample columns of `sensor`.
    pub fn vector_components(&self, sensor: &VectorSensor) -> [&[f64]; 3] {
        sensor.axes.map(|i| self.channels[i].values.as_slice())
    }

    /// The median sample interval, seconds (0 for fewer than two samples).
    pub fn median_interval_s(&self) -> f64 {
        self.median_interval_s
    }
}

/// Median of the steps between consecutive times; 0 with fewer than two.
fn median_step(time_s: &[f64]) -> f64 {
    let mut steps: Vec<f64> = time_s.windows(2).map(|w| w[1] - w[0]).collect();
    if steps.is_empty() {
        return 0.0;
    }
    let middle = steps.len() / 2;
    *steps.select_nth_unstable_by(middle, f64::total_cmp).1
}

/// Checks that `time_s` is finite and strictly increasing; `locate` turns a
/// sample index into a place the user can find ("line 12", "sample 10").
pub fn check_time(source: &Path, column: &str, time_s: &[f64], locate: impl Fn(usize) -> String) -> Result<()> {
    let bad = |index: usize, (problem, fix): (String, String)| Error::BadTime {
        path: source.to_path_buf(),
        location: locate(index),
        column: column.to_string(),
        problem,
        fix,
    };
    for (index, &t) in time_s.iter().enumerate() {
        if !t.is_finite() {
            let fix = "repair that sample's time, or drop the sample".to_string();
            return Err(bad(index, ("is missing or not finite".into(), fix)));
        }
        if index > 0 && t <= time_s[index - 1] {
            return Err(bad(index, backward_time(column, time_s, index, &locate)));
        }
    }
    Ok(())
}

/// What is wrong where `time_s` first goes back, at `index`, and the fix
/// its cause calls for (`locate` names a sample where the user can find
/// it): a column that goes back on a fifth of its steps or more is not a
/// time at all (a data column named as time); a few damaged stamps (at
/// most [`MOST_DAMAGED_STAMPS`], or a hundredth of the samples), each out
/// of line with the samples either side, are repaired or dropped;
/// anything else is an unsorted file.
pub(crate) fn backward_time(
    column: &str,
    time_s: &[f64],
    index: usize,
    locate: impl Fn(usize) -> String,
) -> (String, String) {
    use crate::error::Number;
    let moved = format!("goes from {} to {}", Number(time_s[index - 1]), Number(time_s[index]));
    let back = time_s.windows(2).filter(|w| w[1] <= w[0]).count();
    if 5 * back >= time_s.len().saturating_sub(1) && back > 2 {
        let problem = format!("{moved}, and goes back on {back} of its {} steps", time_s.len() - 1);
        let fix = format!("'{column}' is not a time column; name the file's time in [columns] time = \"...\"");
        return (problem, fix);
    }
    let damaged = damaged_stamps(time_s);
    let (Some(&first), Some(&last)) = (damaged.first(), damaged.last()) else {
        return (moved, crate::error::SORT_BY_TIME.to_string());
    };
    let in_order = |k: usize| {
        let before = (0..k).rev().find(|i| !damaged.contains(i));
        let after = (k + 1..time_s.len()).find(|i| !damaged.contains(i));
        match (before, after) {
            (Some(b), Some(a)) => format!(
                " between {} and {}, which are in order",
                Number(time_s[b]),
                Number(time_s[a])
            ),
            _ => String::new(),
        }
    };
    match damaged.len() {
        1 => (
            format!(
                "{moved}: the stamp {} lies out of line{}",
                Number(time_s[first]),
                in_order(first)
            ),
            format!(
                "one damaged time stamp ({}), not an unsorted file: repair it or drop that sample",
                locate(first)
            ),
        ),
        n if last - first + 1 == n => (
            format!(
                "{moved}: the {n} stamps from {} to {} lie out of line{}",
                locate(first),
                locate(last),
                in_order(first)
            ),
            format!("{n} damaged time stamps, not an unsorted file: repair them or drop those samples"),
        ),
        n => (
            format!(
                "{moved}: {n} stamps lie out of line with the samples either side, the first at {} and the last at {}",
                locate(first),
                locate(last)
            ),
            format!("{n} damaged time stamps, not an unsorted file: repair them or drop those samples"),
        ),
    }
}

/// Most damaged stamps told apart from an unsorted file, unless a
/// hundredth of the samples is more.
pub const MOST_DAMAGED_STAMPS: usize = 10;

/// The samples whose stamps lie out of line with the samples either side
/// (read in order: a stamp not after the last one kept, or one after it
/// but beyond the next, which is), when they are few enough
/// ([`MOST_DAMAGED_STAMPS`]) for the rest to be a time read in order;
/// none otherwise (an unsorted file).
fn damaged_stamps(time_s: &[f64]) -> Vec<usize> {
    let most = MOST_DAMAGED_STAMPS.max(time_s.len() / 100);
    let Some(&first) = time_s.first() else {
        return Vec::new();
    };
    let mut last = first;
    let mut damaged = Vec::new();
    for (i, &t) in time_s.iter().enumerate().skip(1) {
        let high = time_s.get(i + 1).is_some_and(|&next| next < t && next > last);
        match t <= last || high {
            true => damaged.push(i),
            false => last = t,
        }
        if damaged.len() > most {
            return Vec::new();
        }
    }
    damaged
}

/// How one channel was placed on the time base.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ResampledChannel {
    /// Channel name.
    pub channel: String,
    /// Topic and field it came from.
    pub source: String,
    /// Samples recorded.
    pub samples: usize,
    /// Median recorded rate, Hz.
    pub rate_hz: f64,
    /// `time base`, `linear` or `previous value`.
    pub method: &'static str,
    /// Gap tolerance used, seconds.
    pub gap_tolerance_s: f64,
    /// Rows left missing because they fall in a gap.
    pub rows_in_gaps: usize,
    /// Rows left missing because they are outside the channel's span.
    pub rows_outside: usize,
    /// Samples dropped because they repeat an earlier one exactly (time
    /// and value).
    pub repeats_dropped: usize,
    /// Times at which the channel has samples that disagree.
    pub conflicting_times: usize,
    /// Rows left missing because they would use such a sample.
    pub rows_conflicting: usize,
}

/// What alignment did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AlignmentReport {
    /// Channel whose timestamps are the time base.
    pub time_base: String,
    /// Rows of the time base.
    pub rows: usize,
    /// Duplicate time-base timestamps dropped.
    pub duplicate_times_dropped: usize,
    /// Every channel, in output order.
    pub channels: Vec<ResampledChannel>,
    /// Remarks from reading: topics skipped and why, how the file was read.
    pub notes: Vec<crate::messages::ReadNote>,
    /// What was lost or left missing while reading and aligning: a file
    /// cut short, damaged chunks, messages that failed to decode, repeated
    /// or disagreeing timestamps. Printed and shown in the report.
    pub warnings: Vec<Warning>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(name: &str, role: ChannelRole, values: Vec<f64>) -> Channel {
        Channel {
            name: name.into(),
            role,
            values,
        }
    }

    #[test]
    fn rejects_backwards_time_and_names_the_sample() {
        let err = FlightLog::new("f.csv", "tt", vec![0.0, 0.1, 0.05], vec![]).unwrap_err();
        let text = err.to_string();
        assert!(text.contains("sample 2") && text.contains("0.1 to 0.05"), "{text}");
    }

    /// Each way a time goes back gets the fix its cause calls for.
    #[test]
    fn a_backward_time_is_told_apart_by_its_cause() {
        let message = |time: Vec<f64>| FlightLog::new("f.h5", "tt", time, vec![]).unwrap_err().to_string();
        let steady: Vec<f64> = (0..100).map(|k| 100.0 + 0.1 * k as f64).collect();
        // One stamp damaged low, and one damaged high: repair that sample.
        for (k, value) in [(50, 20.0), (50, 900.0)] {
            let mut time = steady.clone();
            time[k] = value;
            let text = message(time);
            assert!(text.contains("one damaged time stamp (sample 50)"), "{text}");
            assert!(!text.contains("sort the file"), "{text}");
        }
        // A run of stamps zeroed, and stamps damaged here and there, on a
        // longer flight: repair or drop those samples.
        let long: Vec<f64> = (0..5_000).map(|k| 100.0 + 0.1 * k as f64).collect();
        let mut time = long.clone();
        time[2_000..2_040].fill(0.0);
        let text = message(time);
        assert!(
            text.contains("the 40 stamps from sample 2000 to sample 2039 lie out of line between 299.9 and 304")
                && text.contains("40 damaged time stamps, not an unsorted file"),
            "{text}"
        );
        let mut time = long.clone();
        for k in [250, 1_250, 3_000, 4_998] {
            time[k] -= 37.2;
        }
        time[4_000] = 1e9;
        let text = message(time);
        assert!(
            text.contains("sample 250")
                && text.contains("5 stamps lie out of line")
                && text.contains("the last at sample 4998"),
            "{text}"
        );
        assert!(!text.contains("sort the file"), "{text}");
        // A block flown twice: sort.
        let mut time = steady.clone();
        time.extend((0..50).map(|k| 105.0 + 0.1 * k as f64));
        let text = message(time);
        assert!(
            text.contains("sample 100") && text.contains("sort the file by time"),
            "{text}"
        );
        // A data column named as time goes back on about half its steps.
        let readings: Vec<f64> = (0..100).map(|k| 52_000.0 + (k as f64 * 1.7).sin()).collect();
        let text = message(readings);
        assert!(
            text.contains("'tt' is not a time column") && text.contains("[columns] time"),
            "{text}"
        );
    }

    #[test]
    fn rejects_channel_of_wrong_length() {
        let c = channel("mag_1_uc", ChannelRole::ScalarMagnetometer, vec![1.0]);
        let err = FlightLog::new("f.csv", "tt", vec![0.0, 0.1], vec![c]).unwrap_err();
        assert!(matches!(
            err,
            Error::LengthMismatch {
                found: 1,
                expected: 2,
                ..
            }
        ));
    }

    #[test]
    fn finds_complete_vector_sensors_only() {
        let v = |s: &str, axis| ChannelRole::VectorMagnetometer { sensor: s.into(), axis };
        let log = FlightLog::new(
            "f.csv",
            "tt",
            vec![0.0],
            vec![
                channel("flux_b_x", v("flux_b", VectorAxis::X), vec![1.0]),
                channel("flux_a_z", v("flux_a", VectorAxis::Z), vec![1.0]),
                channel("flux_a_x", v("flux_a", VectorAxis::X), vec![1.0]),
                channel("flux_a_y", v("flux_a", VectorAxis::Y), vec![1.0]),
            ],
        )
        .unwrap();
        let sensors = log.vector_sensors();
        assert_eq!(sensors.len(), 1);
        assert_eq!(sensors[0].prefix, "flux_a");
        assert_eq!(sensors[0].axes, [2, 3, 1]);
    }
}
