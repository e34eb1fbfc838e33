//! Heading error on survey lines: the level difference between lines
//! flown in opposite directions over the same ground.
//!
//! Samples of a line are matched with the nearest sample of an
//! opposite-direction line within `match_distance_m`; the heading error is
//! the mean difference (first direction minus the opposite one) over the
//! matched pairs. Parallel lines a line spacing apart never match; a line
//! reflown both ways, or overlapping lines, do. Reported uncompensated and
//! compensated. The passes are flown minutes apart, so the external
//! field's change between them (diurnal variation) is taken out with the
//! base station where the flight records one; a pair without a base
//! station reading is left out.

use std::collections::HashMap;

use serde::Serialize;

use crate::ingest::flight_log::{ChannelRole, FlightLog};

/// Metres per degree of latitude (mean).
const METRES_PER_DEGREE: f64 = 111_195.0;
/// Lines within this of each other's reciprocal heading are opposite, degrees.
const OPPOSITE_WITHIN_DEG: f64 = 20.0;

/// The heading error of one channel.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HeadingError {
    /// Track of the first direction, degrees (the other is its reciprocal).
    pub direction_deg: f64,
    /// Matched sample pairs.
    pub pairs: usize,
    /// Mean difference, first direction minus the opposite, uncompensated, nT.
    pub before_nt: f64,
    /// The same, compensated, nT.
    pub after_nt: f64,
    /// Whether the base station's change between the matched samples was
    /// taken out of both differences (the external field's drift between
    /// two passes is no heading error); without a base station it is in
    /// them.
    pub external_field_removed: bool,
}

/// One survey line: its rows and its track.
pub(crate) struct SurveyLine {
    pub(crate) rows: Vec<usize>,
    pub(crate) track_deg: f64,
}

/// Local north and east, m, of every row (NaN where unknown).
pub(crate) fn local_positions(log: &FlightLog) -> Option<Vec<[f64; 2]>> {
    let latitude = &log.channel("lat")?.values;
    let longitude = &log.channel("lon")?.values;
    let origin = latitude
        .iter()
        .zip(longitude)
        .find(|(a, b)| a.is_finite() && b.is_finite())?;
    let east_scale = METRES_PER_DEGREE * origin.0.to_radians().cos();
    Some(
        latitude
            .iter()
            .zip(longitude)
            .map(|(lat, lon)| [(lat - origin.0) * METRES_PER_DEGREE, (lon - origin.1) * east_scale])
            .collect(),
    )
}

/// The survey lines with at least ten positioned rows: number and line.
pub(crate) fn survey_lines(log: &FlightLog, positions: &[[f64; 2]]) -> Vec<(f64, SurveyLine)> {
    log.survey_lines()
        .into_iter()
        .map(|(number, rows)| {
            (
                number,
                rows.into_iter()
                    .filter(|&row| positions[row][0].is_finite())
                    .collect::<Vec<_>>(),
            )
        })
        .filter(|(_, rows)| rows.len() >= 10)
        .map(|(number, rows)| {
            let (first, last) = (positions[rows[0]], positions[rows[rows.len() - 1]]);
            let track_deg = (last[1] - first[1])
                .atan2(last[0] - first[0])
                .to_degrees()
                .rem_euclid(360.0);
            (number, SurveyLine { rows, track_deg })
        })
        .collect()
}

/// The heading error of `before` (uncompensated) and `after`
/// (compensated), or `None` when no opposite-direction lines overlap.
pub fn heading_error(log: &FlightLog, before: &[f64], after: &[f64], match_distance_m: f64) -> Option<HeadingError> {
    let positions = local_positions(log)?;
    let lines: Vec<SurveyLine> = survey_lines(log, &positions)
        .into_iter()
        .map(|(_, line)| line)
        .collect();
    let direction_deg = lines.first()?.track_deg;
    let (forward, back): (Vec<&SurveyLine>, Vec<&SurveyLine>) = lines
        .iter()
        .filter(|l| {
            crate::calibration::headings::angle_apart(l.track_deg, direction_deg) < OPPOSITE_WITHIN_DEG
                || crate::calibration::headings::angle_apart(l.track_deg, direction_deg + 180.0) < OPPOSITE_WITHIN_DEG
        })
        .partition(|l| crate::calibration::headings::angle_apart(l.track_deg, direction_deg) < OPPOSITE_WITHIN_DEG);
    // The opposite direction's samples on a grid of cells one match
    // distance wide: a match lies in the 3 × 3 cells around a sample.
    let cell = |p: [f64; 2]| {
        (
            (p[0] / match_distance_m).floor() as i64,
            (p[1] / match_distance_m).floor() as i64,
        )
    };
    let mut grid: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    for row in back.iter().flat_map(|l| l.rows.iter().copied()) {
        grid.entry(cell(positions[row])).or_default().push(row);
    }
    let base_station = (log.channels().iter())
        .find(|c| c.role == ChannelRole::BaseStation)
        .map(|c| c.values.as_slice());
    let external = |row: usize, other: usize| base_station.map_or(0.0, |base| base[row] - base[other]);
    let (mut pairs, mut sum_before, mut sum_after) = (0usize, 0.0, 0.0);
    for row in forward.iter().flat_map(|l| l.rows.iter().copied()) {
        let (i, j) = cell(positions[row]);
        let distance =
            |other: usize| (positions[row][0] - positions[other][0]).hypot(positions[row][1] - positions[other][1]);
        let nearest = (-1..=1)
            .flat_map(|di| (-1..=1).map(move |dj| (i + di, j + dj)))
            .filter_map(|key| grid.get(&key))
            .flatten()
            .copied()
            .filter(|other| distance(*other) <= match_distance_m)
            .min_by(|a, b| distance(*a).total_cmp(&distance(*b)).then(a.cmp(b)));
        let Some(other) = nearest else { continue };
        let change = external(row, other);
        let (db, da) = (before[row] - before[other] - change, after[row] - after[other] - change);
        if db.is_finite() && da.is_finite() {
            (pairs, sum_before, sum_after) = (pairs + 1, sum_before + db, sum_after + da);
        }
    }
    (pairs > 0).then(|| HeadingError {
        direction_deg,
        pairs,
        before_nt: sum_before / pairs as f64,
        after_nt: sum_after / pairs as f64,
        external_field_removed: base_station.is_some(),
    })
}
