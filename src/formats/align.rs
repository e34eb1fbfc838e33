//! Placing channels recorded at different rates on one time base.
//!
//! Sensors are logged at their own rates and clocks (scalar 10–20 Hz,
//! fluxgate 10–100 Hz, INS 50 Hz, currents 1–10 Hz). The time base is the
//! timestamps of one channel: by default the first scalar magnetometer,
//! otherwise the one named in `[alignment] time_base`. Every other channel
//! is evaluated at those times:
//! - continuous channels by linear interpolation between the two samples
//!   that bracket the time; angles (attitude, heading) on the circle, so a
//!   heading between 359° and 1° is 0°, not 180°;
//! - counters and line numbers (integer fields, the line channel) by the
//!   previous value;
//! - when the bracketing samples are further apart than the gap tolerance
//!   (by default 2.5 of the channel's own median intervals), the row stays
//!   missing and gets a `gap:<channel>` flag;
//! - before a channel's first sample or after its last the row stays
//!   missing: nothing is extrapolated.
//!
//! - samples of one channel at the same time: exact repeats are kept once
//!   and the rows that use them flagged `duplicate_time:<channel>`;
//!   samples that disagree leave the rows that would use them missing,
//!   flagged the same way, and on the time base itself they are an error
//!   ([`ConflictingTimes`]).
//!
//! What was done to each channel is recorded in an [`AlignmentReport`].

use crate::ingest::flags::{FlagKind, RowFlags};
pub use crate::ingest::flight_log::{AlignmentReport, ResampledChannel};
use crate::messages::{Reading, Warning};

/// One recorded series before alignment.
#[derive(Debug, Clone)]
pub struct Stream {
    /// Channel name it becomes.
    pub name: String,
    /// Where it came from (topic and field).
    pub source: String,
    /// Hold the previous value instead of interpolating.
    pub hold: bool,
    /// An angle in degrees: interpolated on the circle.
    pub angle: bool,
    /// Role given by the source (e.g. a configured ROS topic); `None` to
    /// take it from the channel name.
    pub role: Option<crate::ingest::flight_log::ChannelRole>,
    /// Sample times, nanoseconds.
    pub times_ns: Vec<u64>,
    /// Sample values.
    pub values: Vec<f64>,
}

/// `[alignment]` settings.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AlignmentOptions {
    /// Channel whose timestamps are the time base; default the first scalar
    /// magnetometer.
    pub time_base: Option<String>,
    /// Longest interval, seconds, across which a channel is interpolated;
    /// default 2.5 of the channel's own median sample interval.
    pub gap_tolerance_s: Option<f64>,
}

/// Samples of the time-base channel at one time that disagree: which row
/// the time stands for cannot be decided.
#[derive(Debug, Clone, PartialEq)]
pub struct ConflictingTimes {
    /// The time-base channel.
    pub channel: String,
    /// Its topic and field.
    pub source: String,
    /// How many times carry disagreeing samples.
    pub times: usize,
    /// The first such time, seconds.
    pub first_time_s: f64,
}

/// Channels on one time base.
#[derive(Debug, Clone)]
pub struct Aligned {
    /// Time base, seconds.
    pub time_s: Vec<f64>,
    /// `(name, values)` per channel, in stream order, the base included.
    pub channels: Vec<(String, Vec<f64>)>,
    /// Per-row flags (`gap:<channel>`, `duplicate_time:<channel>`).
    pub row_flags: Vec<RowFlags>,
    /// What was done.
    pub report: AlignmentReport,
}

impl Stream {
    /// How the stream is resampled onto the time base, in words (it is the
    /// time base when `is_base`).
    fn method(&self, is_base: bool) -> &'static str {
        match (is_base, self.hold, self.angle) {
            (true, _, _) => "time base",
            (false, true, _) => "previous value",
            (false, false, true) => "linear on the circle",
            (false, false, false) => "linear",
        }
    }
}

/// Aligns `streams` on the timestamps of stream `base` (an index).
pub fn align(mut streams: Vec<Stream>, base: usize, options: &AlignmentOptions) -> Result<Aligned, ConflictingTimes> {
    streams.iter_mut().for_each(sort_by_time);
    let repeats: Vec<Repeats> = streams.iter_mut().map(collapse_repeats).collect();
    if let Some(&first) = repeats[base].conflicts.first() {
        return Err(ConflictingTimes {
            channel: streams[base].name.clone(),
            source: streams[base].source.clone(),
            times: repeats[base].conflicts.len(),
            first_time_s: streams[base].times_ns[first] as f64 / 1e9,
        });
    }
    let base_times = streams[base].times_ns.clone();
    let time_s: Vec<f64> = base_times.iter().map(|&t| t as f64 / 1e9).collect();
    let mut row_flags = vec![RowFlags::default(); base_times.len()];
    let mut channels = Vec::with_capacity(streams.len());
    let mut report = Vec::with_capacity(streams.len());
    let mut warnings = Vec::new();
    for (index, (stream, repeats)) in streams.into_iter().zip(repeats).enumerate() {
        let interval_s = median_interval_ns(&stream.times_ns) / 1e9;
        let tolerance_s = options.gap_tolerance_s.unwrap_or(2.5 * interval_s);
        let method = stream.method(index == base);
        let resampled = resample(&stream, &repeats, &base_times, (tolerance_s * 1e9) as u64);
        resampled.raise_flags(&mut row_flags, &stream.name);
        warnings.extend(repeat_warnings(&stream, &repeats, &resampled));
        report.push(resampled.report(&stream, &repeats, (interval_s, tolerance_s, method)));
        channels.push((stream.name, resampled.values));
    }
    let time_base = report[base].channel.clone();
    Ok(Aligned {
        report: AlignmentReport {
            time_base,
            rows: time_s.len(),
            duplicate_times_dropped: report[base].repeats_dropped,
            channels: report,
            notes: Vec::new(),
            warnings,
        },
        time_s,
        channels,
        row_flags,
    })
}

/// The warnings on a stream's repeated samples: exact repeats read once,
/// and times whose samples disagree, left missing.
fn repeat_warnings(stream: &Stream, repeats: &Repeats, resampled: &Resampled) -> Vec<Warning> {
    let mut warnings = Vec::new();
    if repeats.dropped > 0 {
        warnings.push(
            Reading::RepeatsReadOnce {
                source: stream.source.clone(),
                samples: repeats.dropped,
                rows: resampled.repeat_rows.len(),
                column: stream.name.clone(),
            }
            .into(),
        );
    }
    if !repeats.conflicts.is_empty() {
        warnings.push(
            Reading::RepeatsDisagree {
                source: stream.source.clone(),
                times: repeats.conflicts.len(),
                first_s: stream.times_ns[repeats.conflicts[0]] as f64 / 1e9,
                rows: resampled.conflict_rows.len(),
                column: stream.name.clone(),
            }
            .into(),
        );
    }
    warnings
}

/// What [`collapse_repeats`] found in one stream.
struct Repeats {
    /// Samples dropped as exact repeats.
    dropped: usize,
    /// Indices (after collapsing) of times whose samples disagreed.
    conflicts: Vec<usize>,
    /// Per sample (after collapsing): whether its time had disagreeing
    /// samples (its value is then NaN).
    conflicting: Vec<bool>,
    /// Per sample (after collapsing): whether it was repeated exactly.
    repeated: Vec<bool>,
}

/// Collapses samples of a time-sorted stream that share a time into one:
/// exact repeats to the value they repeat, disagreeing ones to NaN.
fn collapse_repeats(stream: &mut Stream) -> Repeats {
    let mut repeats = Repeats {
        dropped: 0,
        conflicts: Vec::new(),
        conflicting: Vec::with_capacity(stream.times_ns.len()),
        repeated: Vec::with_capacity(stream.times_ns.len()),
    };
    if stream.times_ns.windows(2).all(|w| w[0] < w[1]) {
        repeats.conflicting = vec![false; stream.times_ns.len()];
        repeats.repeated = vec![false; stream.times_ns.len()];
        return repeats;
    }
    let same = |a: f64, b: f64| a == b || (a.is_nan() && b.is_nan());
    let (mut times, mut values) = (Vec::new(), Vec::new());
    let mut start = 0;
    while start < stream.times_ns.len() {
        let time = stream.times_ns[start];
        let end = start + stream.times_ns[start..].iter().take_while(|&&t| t == time).count();
        let group = &stream.values[start..end];
        let agree = group.iter().all(|&v| same(v, group[0]));
        if agree {
            repeats.dropped += end - start - 1;
        } else {
            repeats.conflicts.push(times.len());
        }
        times.push(time);
        values.push(if agree { group[0] } else { f64::NAN });
        repeats.conflicting.push(!agree);
        repeats.repeated.push(agree && end - start > 1);
        start = end;
    }
    stream.times_ns = times;
    stream.values = values;
    repeats
}

fn sort_by_time(stream: &mut Stream) {
    if stream.times_ns.windows(2).all(|w| w[0] <= w[1]) {
        return;
    }
    let mut order: Vec<usize> = (0..stream.times_ns.len()).collect();
    order.sort_by_key(|&i| stream.times_ns[i]);
    stream.times_ns = order.iter().map(|&i| stream.times_ns[i]).collect();
    stream.values = order.iter().map(|&i| stream.values[i]).collect();
}

fn median_interval_ns(times: &[u64]) -> f64 {
    let mut steps: Vec<u64> = times.windows(2).map(|w| w[1] - w[0]).filter(|&s| s > 0).collect();
    if steps.is_empty() {
        return 0.0;
    }
    let middle = steps.len() / 2;
    *steps.select_nth_unstable(middle).1 as f64
}

struct Resampled {
    values: Vec<f64>,
    gap_rows: Vec<usize>,
    conflict_rows: Vec<usize>,
    repeat_rows: Vec<usize>,
    outside: usize,
}

impl Resampled {
    /// Raises the gap and duplicate-time flags of `name` on the rows that
    /// fell in its gaps or used its repeated or disagreeing samples.
    fn raise_flags(&self, row_flags: &mut [RowFlags], name: &str) {
        for (rows, flag) in [
            (&self.gap_rows, FlagKind::Gap),
            (&self.conflict_rows, FlagKind::DuplicateTime),
            (&self.repeat_rows, FlagKind::DuplicateTime),
        ] {
            for &row in rows {
                row_flags[row].raise(flag, name);
            }
        }
    }

    /// What the alignment did to `stream`, resampled at its median
    /// `interval_s` with gaps above `tolerance_s`, s, by `method`.
    fn report(
        &self,
        stream: &Stream,
        repeats: &Repeats,
        (interval_s, tolerance_s, method): (f64, f64, &'static str),
    ) -> ResampledChannel {
        ResampledChannel {
            channel: stream.name.clone(),
            source: stream.source.clone(),
            samples: stream.times_ns.len(),
            rate_hz: if interval_s > 0.0 { 1.0 / interval_s } else { 0.0 },
            method,
            gap_tolerance_s: tolerance_s,
            rows_in_gaps: self.gap_rows.len(),
            rows_outside: self.outside,
            repeats_dropped: repeats.dropped,
            conflicting_times: repeats.conflicts.len(),
            rows_conflicting: self.conflict_rows.len(),
        }
    }

    /// Row `row`, at time `t`, ns, between samples `j` and `j + 1` of
    /// `stream`: left missing in a gap longer than `tolerance_ns` or where
    /// it would use a disagreeing sample, else interpolated (or held).
    fn between_samples(
        &mut self,
        stream: &Stream,
        repeats: &Repeats,
        (row, t, j): (usize, u64, usize),
        tolerance_ns: u64,
    ) {
        let (times, values) = (&stream.times_ns, &stream.values);
        let (conflicting, repeated) = (&repeats.conflicting, &repeats.repeated);
        let (ta, tb) = (times[j], times[j + 1]);
        if tb - ta > tolerance_ns {
            self.gap_rows.push(row);
            return;
        }
        let used_conflict = conflicting[j] || (!stream.hold && conflicting[j + 1]);
        if used_conflict {
            self.conflict_rows.push(row);
            return;
        }
        if repeated[j] || (!stream.hold && repeated[j + 1]) {
            self.repeat_rows.push(row);
        }
        let fraction = (t - ta) as f64 / (tb - ta) as f64;
        self.values[row] = match (stream.hold, stream.angle) {
            (true, _) => values[j],
            (false, true) => angle_between(values[j], values[j + 1], fraction),
            (false, false) => values[j] + fraction * (values[j + 1] - values[j]),
        };
    }
}

/// Evaluates `stream` at the sorted `base` times; `repeats` marks its
/// samples whose time carried repeated or disagreeing values.
fn resample(stream: &Stream, repeats: &Repeats, base: &[u64], tolerance_ns: u64) -> Resampled {
    let (times, values) = (&stream.times_ns, &stream.values);
    let (conflicting, repeated) = (&repeats.conflicting, &repeats.repeated);
    let mut out = Resampled {
        values: vec![f64::NAN; base.len()],
        gap_rows: Vec::new(),
        conflict_rows: Vec::new(),
        repeat_rows: Vec::new(),
        outside: 0,
    };
    let (Some(&first), Some(&last)) = (times.first(), times.last()) else {
        out.outside = base.len();
        return out;
    };
    let mut j = 0;
    for (row, &t) in base.iter().enumerate() {
        if t < first || t > last {
            out.outside += 1;
            continue;
        }
        while j + 1 < times.len() && times[j + 1] <= t {
            j += 1;
        }
        if times[j] == t {
            if conflicting[j] {
                out.conflict_rows.push(row);
            } else if repeated[j] {
                out.repeat_rows.push(row);
            }
            out.values[row] = values[j];
            continue;
        }
        out.between_samples(stream, repeats, (row, t, j), tolerance_ns);
    }
    out
}

/// The angle `fraction` of the way from `a` to `b` degrees, the short way
/// round the circle. Angles less than half a turn apart (and unwrapped
/// headings) are interpolated as they are; across north the result is
/// given in the convention of the two ends: 0–360° when both are
/// non-negative, −180–180° otherwise.
fn angle_between(a: f64, b: f64, fraction: f64) -> f64 {
    if (b - a).abs() <= 180.0 {
        return a + fraction * (b - a);
    }
    let step = (b - a + 180.0).rem_euclid(360.0) - 180.0;
    let angle = a + fraction * step;
    match a >= 0.0 && b >= 0.0 {
        true => angle.rem_euclid(360.0),
        false => (angle + 180.0).rem_euclid(360.0) - 180.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stream(name: &str, hold: bool, times_s: &[f64], values: &[f64]) -> Stream {
        Stream {
            name: name.into(),
            source: format!("/test/{name}"),
            hold,
            angle: false,
            role: None,
            times_ns: times_s.iter().map(|t| (t * 1e9).round() as u64).collect(),
            values: values.to_vec(),
        }
    }

    #[test]
    fn interpolates_holds_and_never_extrapolates() {
        let base = stream("mag_1_uc", false, &[1.0, 1.1, 1.2, 1.3, 1.4, 1.5], &[0.0; 6]);
        let slope = stream("flux_a_x", false, &[1.05, 1.15, 1.25, 1.35], &[10.0, 20.0, 30.0, 40.0]);
        let line = stream("line", true, &[0.0, 1.22], &[7.0, 8.0]);
        let aligned = align(vec![base, slope, line], 0, &AlignmentOptions::default()).unwrap();
        let x = &aligned.channels[1].1;
        assert!(
            x[0].is_nan() && x[4].is_nan() && x[5].is_nan(),
            "outside the span: {x:?}"
        );
        for (got, want) in x[1..4].iter().zip([15.0, 25.0, 35.0]) {
            assert!((got - want).abs() < 1e-9, "{got} vs {want}");
        }
        assert_eq!(aligned.channels[2].1[..3], [7.0, 7.0, 7.0]);
        assert!(aligned.channels[2].1[3].is_nan(), "after the last sample");
        assert_eq!(aligned.report.channels[1].rows_outside, 3);
        assert_eq!(aligned.report.channels[2].method, "previous value");
    }

    #[test]
    fn gaps_stay_missing_and_are_flagged() {
        let base = stream("mag_1_uc", false, &[0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6], &[0.0; 7]);
        let current = stream("cur_a", false, &[0.0, 0.1, 0.2, 0.55, 0.6], &[1.0, 1.0, 1.0, 2.0, 2.0]);
        let aligned = align(vec![base, current], 0, &AlignmentOptions::default()).unwrap();
        let values = &aligned.channels[1].1;
        assert!(values[3].is_nan() && values[4].is_nan() && values[5].is_nan());
        assert_eq!(aligned.row_flags[4].to_string(), "gap:cur_a");
        assert_eq!(aligned.report.channels[1].rows_in_gaps, 3);
        let loose = AlignmentOptions {
            gap_tolerance_s: Some(1.0),
            ..AlignmentOptions::default()
        };
        let aligned = align(
            vec![
                stream("m", false, &[0.0, 0.3], &[0.0, 0.0]),
                stream("c", false, &[0.0, 0.6], &[0.0, 6.0]),
            ],
            0,
            &loose,
        )
        .unwrap();
        assert!((aligned.channels[1].1[1] - 3.0).abs() < 1e-12);
    }

    #[test]
    fn heading_is_interpolated_on_the_circle() {
        let base = stream("mag_1_uc", false, &[0.0, 0.1, 0.2, 0.3], &[0.0; 4]);
        let mut yaw = stream("ins_yaw", false, &[0.0, 0.2, 0.4], &[358.0, 4.0, 10.0]);
        yaw.angle = true;
        let mut signed = stream("heading", false, &[0.0, 0.2], &[-179.0, 177.0]);
        signed.angle = true;
        let aligned = align(vec![base, yaw, signed], 0, &AlignmentOptions::default()).unwrap();
        let yaw = &aligned.channels[1].1;
        assert!((yaw[1] - 1.0).abs() < 1e-9, "{yaw:?}");
        assert!((yaw[3] - 7.0).abs() < 1e-9, "{yaw:?}");
        let signed = &aligned.channels[2].1;
        assert!((signed[1] - 179.0).abs() < 1e-9, "{signed:?}");
        assert_eq!(aligned.report.channels[1].method, "linear on the circle");
        assert!((angle_between(350.0, 10.0, 0.75) - 5.0).abs() < 1e-12);
        assert!(
            (angle_between(725.0, 735.0, 0.5) - 730.0).abs() < 1e-12,
            "unwrapped headings stay unwrapped"
        );
    }

    #[test]
    fn repeated_times_are_dropped_or_flagged_never_merged() {
        let base = stream("mag_1_uc", false, &[0.0, 0.1, 0.2, 0.3, 0.4], &[1.0; 5]);
        let current = stream(
            "cur_a",
            false,
            &[0.0, 0.1, 0.1, 0.2, 0.3, 0.3, 0.4],
            &[1.0, 2.0, 2.0, 3.0, 4.0, 9.0, 5.0],
        );
        let aligned = align(vec![base, current], 0, &AlignmentOptions::default()).unwrap();
        let values = &aligned.channels[1].1;
        assert_eq!(values[..3], [1.0, 2.0, 3.0], "an exact repeat is read once");
        assert_eq!(
            aligned.row_flags[1].to_string(),
            "duplicate_time:cur_a",
            "and its row flagged"
        );
        assert!(values[3].is_nan(), "disagreeing samples leave the row missing");
        assert_eq!(aligned.row_flags[3].to_string(), "duplicate_time:cur_a");
        let channel = &aligned.report.channels[1];
        assert_eq!(
            (
                channel.repeats_dropped,
                channel.conflicting_times,
                channel.rows_conflicting
            ),
            (1, 1, 1)
        );
        assert_eq!(aligned.report.warnings.len(), 2, "{:?}", aligned.report.warnings);

        let base = stream("mag_1_uc", false, &[0.0, 0.1, 0.1, 0.2], &[1.0, 2.0, 3.0, 4.0]);
        let error = align(vec![base], 0, &AlignmentOptions::default()).unwrap_err();
        assert_eq!((error.times, error.first_time_s), (1, 0.1));
    }
}
