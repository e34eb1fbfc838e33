//! The sections of pipeline.toml as written, and their checks.
//!
//! Each raw section mirrors the file: every field optional, unknown fields
//! rejected so that a typo names itself. A field left out takes the
//! validated section's default; [`TryFrom`] fills those in and checks
//! values and combinations, naming the section and field of any that is
//! wrong. The validated types (`DetectOptions`, `DiagnoseOptions`, …) live
//! beside the stages that use them and cannot be read from a file without
//! passing through here.

use serde::Deserialize;

use crate::calibration::detect::DetectOptions;
use crate::calibration::fluxgate::VectorCalibrationOptions;
use crate::diagnose::{ApplyDiagnosis, DiagnoseOptions};
use crate::formats::align::AlignmentOptions;
use crate::formats::{ColumnNames, GivenColumn, TopicMapping, VectorColumns};
use crate::quality::transfer::TransferOptions;
use crate::vector::VectorOptions;

/// A section as written: one optional field per field of the validated
/// section `$validated`, which fills in its defaults for the absent ones.
macro_rules! raw_section {
    ($(#[$meta:meta])* $raw:ident => $validated:ident { $($(#[$field_meta:meta])* $field:ident: $ty:ty),* $(,)? }) => {
        $(#[$meta])*
        #[derive(Debug, Clone, Default, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub(crate) struct $raw {
            $($(#[$field_meta])* #[serde(default)] $field: Option<$ty>,)*
        }

        impl $raw {
            /// The section with every absent field at its default, not yet
            /// checked; fields the section does not set (none, or what is
            /// derived from it) keep their defaults.
            #[allow(clippy::needless_update)]
            fn over_defaults(self) -> $validated {
                let defaults = $validated::default();
                $validated {
                    $($field: self.$field.unwrap_or(defaults.$field),)*
                    ..defaults
                }
            }
        }
    };
}

raw_section! {
    /// `[detect]` as written.
    RawDetect => DetectOptions {
        heading_smoothing_s: f64,
        straight_rate_deg_s: f64,
        min_leg_s: f64,
        join_gap_s: f64,
        heading_tolerance_deg: f64,
        turn_heading_deg: f64,
        turn_bank_deg: f64,
        envelope_s: f64,
        #[serde(deserialize_with = "three_values")]
        min_rms_deg: [f64; 3],
        fluxgate_min_rms_deg: f64,
        turbulence_factor: f64,
        #[serde(deserialize_with = "three_values")]
        nominal_amplitude_deg: [f64; 3],
        #[serde(deserialize_with = "three_values")]
        dominance_deg: [f64; 3],
        min_dominance_s: f64,
        #[serde(deserialize_with = "three_values")]
        min_amplitude_deg: [f64; 3],
        join_activity_s: f64,
        min_half_cycles: usize,
        max_half_cycle_spread: f64,
        max_peak_spread: f64,
        max_turn_s: f64,
        leg_run_on_s: f64,
        window_margin_s: f64,
    }
}

raw_section! {
    /// `[diagnose]` as written.
    RawDiagnose => DiagnoseOptions {
        min_improvement: f64,
        max_lag_s: f64,
        max_findings: usize,
        vector_mismatch_nt: f64,
        apply: ApplyDiagnosis,
        cross_sensor: crate::diagnose::CrossSensorUse,
    }
}

raw_section! {
    /// `[vector_calibration]` as written.
    RawVectorCalibration => VectorCalibrationOptions {
        enabled: bool,
        reference: Option<String>,
        whole_flight: bool,
        max_iterations: usize,
    }
}

raw_section! {
    /// `[vector]` as written.
    RawVector => VectorOptions {
        enabled: bool,
        tolles_lawson: bool,
    }
}

impl From<RawVector> for VectorOptions {
    fn from(raw: RawVector) -> Self {
        raw.over_defaults()
    }
}

/// `[site]` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawSite {
    latitude: f64,
    longitude: f64,
    #[serde(default)]
    height_m: f64,
    #[serde(default)]
    date: Option<String>,
}

impl TryFrom<RawSite> for crate::vector::Site {
    type Error = String;

    fn try_from(raw: RawSite) -> Result<Self, String> {
        if !(raw.latitude.is_finite() && raw.latitude.abs() <= 90.0) {
            return Err(format!(
                "[site] latitude = {}: give degrees north, from -90 to 90",
                raw.latitude
            ));
        }
        if !(raw.longitude.is_finite() && (-180.0..=360.0).contains(&raw.longitude)) {
            return Err(format!(
                "[site] longitude = {}: give degrees east, from -180 to 360",
                raw.longitude
            ));
        }
        if !(raw.height_m.is_finite() && raw.height_m.abs() < 100_000.0) {
            return Err(format!(
                "[site] height_m = {}: give metres above mean sea level",
                raw.height_m
            ));
        }
        let date = match raw.date {
            None => None,
            Some(text) => Some(
                crate::ingest::flight_date::FlightDate::parse(&text)
                    .ok_or_else(|| format!("[site] date = {text:?}: write the survey's date as YYYY-MM-DD"))?,
            ),
        };
        Ok(crate::vector::Site {
            latitude_deg: raw.latitude,
            longitude_deg: raw.longitude,
            height_m: raw.height_m,
            date,
        })
    }
}

raw_section! {
    /// `[quality.transfer]` as written.
    RawTransfer => TransferOptions {
        warning_factor: f64,
    }
}

raw_section! {
    /// `[alignment]` as written.
    RawAlignment => AlignmentOptions {
        time_base: Option<String>,
        gap_tolerance_s: Option<f64>,
    }
}

raw_section! {
    /// `[columns]` as written.
    RawColumns => ColumnNames {
        time: String,
        line: String,
        scalar: Option<Vec<String>>,
        vector: Vec<VectorColumns>,
        pitch: String,
        roll: String,
        yaw: String,
        position: Vec<String>,
        base_station: String,
    }
}

/// One `[[topic]]` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawTopic {
    topic: String,
    #[serde(default)]
    vector: Option<String>,
    #[serde(default)]
    scalar: Option<String>,
}

/// `name = value` must be positive and finite.
fn positive(section: &str, name: &str, value: f64) -> Result<f64, String> {
    match value.is_finite() && value > 0.0 {
        true => Ok(value),
        false => Err(format!("[{section}] {name} = {value}: give a positive number")),
    }
}

/// A setting of three values (pitch, roll, yaw), refused with any other
/// count: a fourth value would otherwise be dropped without a word.
fn three_values<'de, D: serde::Deserializer<'de>>(deserializer: D) -> Result<Option<[f64; 3]>, D::Error> {
    let values: Vec<f64> = Deserialize::deserialize(deserializer)?;
    <[f64; 3]>::try_from(values.as_slice())
        .map(Some)
        .map_err(|_| serde::de::Error::custom(format!("give three values (pitch, roll, yaw), not {}", values.len())))
}

/// A number as a setting's error shows it: 1e308, not 309 digits.
fn shown(value: f64) -> String {
    match value != 0.0 && !(1e-3..1e6).contains(&value.abs()) {
        true => format!("{value:e}"),
        false => format!("{value}"),
    }
}

/// `value` within `low..=high` (finite), or an error naming the setting
/// and the range: a setting far outside what a flight can mean (a margin of
/// 1e308 s) would run for ever rather than fail.
fn within(section: &str, name: &str, value: f64, (low, high): (f64, f64)) -> Result<f64, String> {
    match value.is_finite() && (low..=high).contains(&value) {
        true => Ok(value),
        false if low == f64::MIN_POSITIVE => Err(format!(
            "[{section}] {name} = {}: give a number above 0, up to {high}",
            shown(value)
        )),
        false => Err(format!(
            "[{section}] {name} = {}: give a number from {low} to {high}",
            shown(value)
        )),
    }
}

/// The longest span a `[detect]` time may cover, s: a day.
const LONGEST_DETECT_S: f64 = 86_400.0;

impl TryFrom<RawDetect> for DetectOptions {
    type Error = String;

    fn try_from(raw: RawDetect) -> Result<Self, String> {
        let detect = raw.over_defaults();
        let tiny = f64::MIN_POSITIVE;
        let seconds = (tiny, LONGEST_DETECT_S);
        let ranges = [
            ("heading_smoothing_s", detect.heading_smoothing_s, seconds),
            ("straight_rate_deg_s", detect.straight_rate_deg_s, (tiny, 360.0)),
            ("min_leg_s", detect.min_leg_s, seconds),
            ("join_gap_s", detect.join_gap_s, (0.0, LONGEST_DETECT_S)),
            ("heading_tolerance_deg", detect.heading_tolerance_deg, (tiny, 180.0)),
            ("turn_heading_deg", detect.turn_heading_deg, (tiny, 180.0)),
            ("turn_bank_deg", detect.turn_bank_deg, (tiny, 90.0)),
            ("envelope_s", detect.envelope_s, seconds),
            ("fluxgate_min_rms_deg", detect.fluxgate_min_rms_deg, (tiny, 90.0)),
            ("turbulence_factor", detect.turbulence_factor, (tiny, 1e6)),
            ("min_dominance_s", detect.min_dominance_s, seconds),
            ("join_activity_s", detect.join_activity_s, (0.0, LONGEST_DETECT_S)),
            ("max_half_cycle_spread", detect.max_half_cycle_spread, (tiny, 1e6)),
            ("max_peak_spread", detect.max_peak_spread, (tiny, 1e6)),
            ("max_turn_s", detect.max_turn_s, seconds),
            ("leg_run_on_s", detect.leg_run_on_s, seconds),
            ("window_margin_s", detect.window_margin_s, (0.0, 600.0)),
        ];
        for (name, value, range) in ranges {
            within("detect", name, value, range)?;
        }
        let degrees = [
            ("min_rms_deg", detect.min_rms_deg, (0.0, 90.0)),
            ("nominal_amplitude_deg", detect.nominal_amplitude_deg, (0.0, 90.0)),
            ("dominance_deg", detect.dominance_deg, (tiny, 90.0)),
            ("min_amplitude_deg", detect.min_amplitude_deg, (0.0, 90.0)),
        ];
        for (name, values, range) in degrees {
            for (axis, value) in ["pitch", "roll", "yaw"].iter().zip(values) {
                within("detect", &format!("{name} ({axis})"), value, range)?;
            }
        }
        if !(1..=1000).contains(&detect.min_half_cycles) {
            return Err(format!(
                "[detect] min_half_cycles = {}: give a count from 1 to 1000 (4 is usual: two cycles)",
                detect.min_half_cycles
            ));
        }
        Ok(detect)
    }
}

impl TryFrom<RawDiagnose> for DiagnoseOptions {
    type Error = String;

    fn try_from(raw: RawDiagnose) -> Result<Self, String> {
        let diagnose = raw.over_defaults();
        if !(diagnose.min_improvement.is_finite() && diagnose.min_improvement > 0.0 && diagnose.min_improvement < 1.0) {
            return Err(format!(
                "[diagnose] min_improvement = {}: give a fraction between 0 and 1 (0.3 is usual: a 30 % lower held-out RMS)",
                diagnose.min_improvement
            ));
        }
        if !(diagnose.max_lag_s.is_finite() && diagnose.max_lag_s > 0.0 && diagnose.max_lag_s <= 60.0) {
            return Err(format!(
                "[diagnose] max_lag_s = {}: give a positive number of seconds up to 60",
                diagnose.max_lag_s
            ));
        }
        if !(1..=100).contains(&diagnose.max_findings) {
            return Err(format!(
                "[diagnose] max_findings = {}: give 1 to 100",
                diagnose.max_findings
            ));
        }
        if !(diagnose.vector_mismatch_nt.is_finite() && diagnose.vector_mismatch_nt > 0.0) {
            return Err(format!(
                "[diagnose] vector_mismatch_nt = {}: give a positive number of nT",
                diagnose.vector_mismatch_nt
            ));
        }
        Ok(diagnose)
    }
}

impl TryFrom<RawVectorCalibration> for VectorCalibrationOptions {
    type Error = String;

    fn try_from(raw: RawVectorCalibration) -> Result<Self, String> {
        let calibration = raw.over_defaults();
        if !(1..=100_000).contains(&calibration.max_iterations) {
            return Err(format!(
                "[vector_calibration] max_iterations = {}: give 1 to 100000 (100 is usual)",
                calibration.max_iterations
            ));
        }
        if calibration.reference.as_deref().is_some_and(|r| r.trim().is_empty()) {
            return Err(
                "[vector_calibration] reference = \"\": name a scalar channel, or leave it out for the quietest".into(),
            );
        }
        Ok(calibration)
    }
}

impl TryFrom<RawTransfer> for TransferOptions {
    type Error = String;

    fn try_from(raw: RawTransfer) -> Result<Self, String> {
        let transfer = raw.over_defaults();
        let factor = transfer.warning_factor;
        if !(factor.is_finite() && factor >= 1.0) {
            return Err(format!(
                "[quality.transfer] warning_factor = {factor}: give a factor of 1 or more (2 is usual)"
            ));
        }
        Ok(transfer)
    }
}

impl TryFrom<RawAlignment> for AlignmentOptions {
    type Error = String;

    fn try_from(raw: RawAlignment) -> Result<Self, String> {
        let alignment = raw.over_defaults();
        if let Some(tolerance) = alignment.gap_tolerance_s {
            positive("alignment", "gap_tolerance_s", tolerance)
                .map_err(|_| format!("[alignment] gap_tolerance_s = {tolerance}: give a positive number of seconds"))?;
        }
        if alignment.time_base.as_deref().is_some_and(|t| t.trim().is_empty()) {
            return Err(
                "[alignment] time_base = \"\": name a channel, or leave it out for the first scalar magnetometer"
                    .into(),
            );
        }
        Ok(alignment)
    }
}

impl RawColumns {
    /// The columns named, as against left at their defaults.
    fn given(&self) -> Vec<GivenColumn> {
        fn one(setting: &'static str, column: &Option<String>) -> Option<GivenColumn> {
            column.clone().map(|column| GivenColumn { setting, column })
        }
        let vectors = self.vector.iter().flatten().flat_map(|v| [&v.x, &v.y, &v.z]);
        (self.scalar.iter().flatten().flatten().map(|c| GivenColumn {
            setting: "scalar",
            column: c.clone(),
        }))
        .chain(vectors.map(|c| GivenColumn {
            setting: "vector",
            column: c.clone(),
        }))
        .chain(one("pitch", &self.pitch))
        .chain(one("roll", &self.roll))
        .chain(one("yaw", &self.yaw))
        .chain(one("line", &self.line))
        .chain(one("base_station", &self.base_station))
        .chain(self.position.iter().flatten().map(|c| GivenColumn {
            setting: "position",
            column: c.clone(),
        }))
        .collect()
    }
}

impl TryFrom<RawColumns> for ColumnNames {
    type Error = String;

    fn try_from(raw: RawColumns) -> Result<Self, String> {
        let given = raw.given();
        let mut columns = raw.over_defaults();
        columns.given = given;
        let named = [
            ("time", &columns.time),
            ("line", &columns.line),
            ("pitch", &columns.pitch),
            ("roll", &columns.roll),
            ("yaw", &columns.yaw),
            ("base_station", &columns.base_station),
        ];
        if let Some((name, _)) = named.iter().find(|(_, column)| column.trim().is_empty()) {
            return Err(format!("[columns] {name} = \"\": name the column"));
        }
        let single = named.iter().map(|(setting, column)| (*setting, column.as_str()));
        let listed = (columns.given.iter())
            .filter(|g| matches!(g.setting, "scalar" | "vector" | "position"))
            .map(|g| (g.setting, g.column.as_str()));
        let mut roles: Vec<(&str, &str)> = single.chain(listed).collect();
        roles.sort_by(|a, b| a.1.cmp(b.1));
        if let Some(pair) = roles.windows(2).find(|pair| pair[0].1 == pair[1].1) {
            return Err(format!(
                "[columns] {} and {} both name the column '{}': a column plays one role; name each its own",
                pair[0].0, pair[1].0, pair[0].1
            ));
        }
        if let Some(message) = columns.role_taken_by_name() {
            return Err(message);
        }
        for v in &columns.vector {
            if [&v.prefix, &v.x, &v.y, &v.z].iter().any(|c| c.trim().is_empty()) {
                return Err(format!(
                    "[[columns.vector]] prefix = {:?}: give the prefix and all three columns x, y, z",
                    v.prefix
                ));
            }
        }
        Ok(columns)
    }
}

impl TryFrom<RawTopic> for TopicMapping {
    type Error = String;

    fn try_from(raw: RawTopic) -> Result<Self, String> {
        if raw.vector.is_some() && raw.scalar.is_some() {
            return Err(format!(
                "[[topic]] topic = {:?}: give vector (the three components) or scalar (their magnitude), not both",
                raw.topic
            ));
        }
        Ok(TopicMapping {
            topic: raw.topic,
            vector: raw.vector,
            scalar: raw.scalar,
        })
    }
}

/// The `[[topic]]` list, checked: each topic mapped once.
pub(crate) fn topics(raw: Vec<RawTopic>) -> Result<Vec<TopicMapping>, String> {
    let topics: Vec<TopicMapping> = raw.into_iter().map(TopicMapping::try_from).collect::<Result<_, _>>()?;
    for (i, mapping) in topics.iter().enumerate() {
        if topics[..i].iter().any(|m| m.topic == mapping.topic) {
            return Err(format!(
                "[[topic]] topic = {:?} is mapped twice; keep one entry",
                mapping.topic
            ));
        }
    }
    Ok(topics)
}
