//! Crossovers: where a survey line crosses another flown on a different
//! heading (a tie line across the traverse lines, as nearly every survey
//! flies), the aircraft measured the same ground twice on two headings.
//!
//! The difference between the two passes' compensated values there holds
//! what the compensation leaves that depends on heading (a level per
//! heading: the permanent and induced terms' errors on straight lines), the
//! external field's change between the passes, the sensor noise and what
//! the two passes' small offsets in position and height put between them.
//! With a base station the external field's change is taken out.
//! Tie-line levelling ([`Levelling`]) turns the differences into one level
//! per line; the levels' spread over the survey's rows is what the
//! compensation leaves for a geophysicist to level out. Level two
//! compensations of one channel at the same crossovers and everything but
//! their heading levels is common to both: which one's levels spread less
//! is survey-side evidence of which compensates the survey better,
//! something the calibration box cannot show ([`compare_levels`]).
//!
//! A crossover is found where the straight segment between two consecutive
//! samples of one line meets that of another line whose track differs by
//! at least [`CROSSING_DEG`]; each pass's value is interpolated along its
//! segment to the crossing point. A segment longer than [`LONGEST_SEGMENT_M`]
//! is a jump in the positions, not flight between two samples, and is not
//! searched.

use std::collections::HashMap;

use crate::ingest::flight_log::{ChannelRole, FlightLog};
use crate::quality::heading_error::{local_positions, survey_lines};

/// Lines whose tracks differ by less than this (either way round) are not
/// crossed: near-parallel lines meet over a long, ill-defined stretch.
pub const CROSSING_DEG: f64 = 30.0;

/// Smallest grid cell for the search, m; a cell is at least as wide as the
/// longest segment searched (70 m at 70 m/s and 1 Hz).
const CELL_M: f64 = 100.0;

/// Longest segment between two consecutive samples searched, m: 5 s at
/// 200 m/s.
pub const LONGEST_SEGMENT_M: f64 = 1000.0;

/// Where two lines cross: per pass, the row before the crossing point and
/// the fraction of the way to the next row.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crossover {
    /// The earlier pass and the later one: (row, fraction toward row + 1).
    pub passes: [(usize, f64); 2],
    /// Their line numbers.
    pub lines: [f64; 2],
}

impl Crossover {
    /// `values` interpolated at the crossing point on each pass.
    pub fn values(&self, values: &[f64]) -> [f64; 2] {
        self.passes
            .map(|(row, fraction)| values[row] + fraction * (values[row + 1] - values[row]))
    }

    /// Earlier pass less the later one of `values`.
    pub fn difference(&self, values: &[f64]) -> f64 {
        let [a, b] = self.values(values);
        a - b
    }
}

/// The crossovers of `log`'s survey lines (empty without positions or
/// lines), and the base station's column when the flight records one.
pub struct Crossovers<'a> {
    /// Each crossing, in the earlier pass's row order.
    pub points: Vec<Crossover>,
    base_station: Option<&'a [f64]>,
}

impl<'a> Crossovers<'a> {
    /// Finds the crossovers of `log`.
    pub fn of(log: &'a FlightLog) -> Self {
        let base_station = (log.channels().iter())
            .find(|c| c.role == ChannelRole::BaseStation)
            .map(|c| c.values.as_slice());
        let points = match local_positions(log) {
            Some(positions) => find(log, &positions),
            None => Vec::new(),
        };
        Crossovers { points, base_station }
    }

    /// Whether the external field's change between passes is taken out.
    pub fn external_field_removed(&self) -> bool {
        self.base_station.is_some()
    }

    /// The crossover differences of `values` (earlier pass less later),
    /// the base station's change taken out where there is one; a crossover
    /// with a missing value on either pass is left out (NaN).
    pub fn differences(&self, values: &[f64]) -> Vec<f64> {
        self.points
            .iter()
            .map(|point| {
                let external = self.base_station.map_or(0.0, |base| point.difference(base));
                point.difference(values) - external
            })
            .collect()
    }
}

/// Every crossing of two segments of different lines, each pair of rows
/// of a line being a segment.
fn find(log: &FlightLog, positions: &[[f64; 2]]) -> Vec<Crossover> {
    let lines: Vec<(f64, crate::quality::heading_error::SurveyLine)> = survey_lines(log, positions);
    let length =
        |row: usize| (positions[row + 1][0] - positions[row][0]).hypot(positions[row + 1][1] - positions[row][1]);
    let segments = |rows: &[usize]| -> Vec<usize> {
        rows.windows(2)
            .filter(|w| w[1] == w[0] + 1 && length(w[0]) <= LONGEST_SEGMENT_M)
            .map(|w| w[0])
            .collect()
    };
    let line_segments: Vec<Vec<usize>> = lines.iter().map(|(_, line)| segments(&line.rows)).collect();
    // A crossing lies within one segment's length of both segments' first
    // samples, so within the 3 × 3 cells around either when a cell is at
    // least that long.
    let longest = line_segments
        .iter()
        .flatten()
        .map(|&row| length(row))
        .fold(0.0, f64::max);
    let size = longest.max(CELL_M);
    let cell = |p: [f64; 2]| ((p[0] / size).floor() as i64, (p[1] / size).floor() as i64);
    // Segment (line index, row) by the cell of its first sample.
    let mut grid: HashMap<(i64, i64), Vec<(usize, usize)>> = HashMap::new();
    for (index, rows) in line_segments.iter().enumerate() {
        for &row in rows {
            grid.entry(cell(positions[row])).or_default().push((index, row));
        }
    }
    let mut points = Vec::new();
    for (index, rows) in line_segments.iter().enumerate() {
        for &row in rows {
            let (i, j) = cell(positions[row]);
            let near = (-1..=1)
                .flat_map(|di| (-1..=1).map(move |dj| (i + di, j + dj)))
                .filter_map(|key| grid.get(&key))
                .flatten();
            for &(other, other_row) in near {
                // Each pair once: from the earlier pass.
                if other_row <= row || other == index {
                    continue;
                }
                let crossing =
                    crate::calibration::headings::angle_apart(lines[index].1.track_deg, lines[other].1.track_deg);
                if !(CROSSING_DEG..=180.0 - CROSSING_DEG).contains(&crossing) {
                    continue;
                }
                let segment = |r: usize| (positions[r], positions[r + 1]);
                if let Some((t, u)) = intersection(segment(row), segment(other_row)) {
                    points.push(Crossover {
                        passes: [(row, t), (other_row, u)],
                        lines: [lines[index].0, lines[other].0],
                    });
                }
            }
        }
    }
    points.sort_by_key(|p| (p.passes[0].0, p.passes[1].0));
    points
}

/// Where segment `p` meets segment `q`: the fractions along each, both in
/// [0, 1) so that a crossing at a shared sample counts once.
fn intersection((p0, p1): ([f64; 2], [f64; 2]), (q0, q1): ([f64; 2], [f64; 2])) -> Option<(f64, f64)> {
    let r = [p1[0] - p0[0], p1[1] - p0[1]];
    let s = [q1[0] - q0[0], q1[1] - q0[1]];
    let cross = r[0] * s[1] - r[1] * s[0];
    if cross.abs() < 1e-12 {
        return None;
    }
    let w = [q0[0] - p0[0], q0[1] - p0[1]];
    let t = (w[0] * s[1] - w[1] * s[0]) / cross;
    let u = (w[0] * r[1] - w[1] * r[0]) / cross;
    ((0.0..1.0).contains(&t) && (0.0..1.0).contains(&u)).then_some((t, u))
}

/// Tie-line levelling of one series: the level of each line crossed, chosen
/// so that the differences between lines' levels best match the crossover
/// differences (least squares), each connected set of lines about its
/// row-weighted mean. A line's level is what the compensation leaves on it
/// as a whole (on straight lines, its heading's level), seen against the
/// lines it crosses; their spread over the survey's rows is what is left
/// for a geophysicist to level out afterwards.
pub struct Levelling {
    /// Line numbers with a crossover, ascending.
    pub lines: Vec<f64>,
    /// Each line's level, nT.
    pub levels: Vec<f64>,
    /// Each line's rows.
    pub rows: Vec<usize>,
    /// Crossovers used.
    pub crossovers: usize,
    /// RMS crossover misfit the levels leave, nT, on the degrees of
    /// freedom left (crossovers less lines plus connected sets); `None`
    /// when there are none to spare.
    pub misfit_nt: Option<f64>,
    normal: nalgebra::Cholesky<f64, nalgebra::Dyn>,
}

impl Levelling {
    /// Levels `values` at `crossovers`; `None` with fewer than two lines
    /// crossed.
    pub fn of(log: &FlightLog, crossovers: &Crossovers, values: &[f64]) -> Option<Levelling> {
        let differences = crossovers.differences(values);
        let used: Vec<(&Crossover, f64)> = (crossovers.points.iter())
            .zip(differences)
            .filter(|(_, d)| d.is_finite())
            .collect();
        let mut lines: Vec<f64> = used.iter().flat_map(|(p, _)| p.lines).collect();
        lines.sort_by(f64::total_cmp);
        lines.dedup();
        if lines.len() < 2 {
            return None;
        }
        let index = |line: f64| lines.binary_search_by(|n| n.total_cmp(&line)).ok();
        let mut rows = vec![0usize; lines.len()];
        for (number, line_rows) in log.survey_lines() {
            if let Some(i) = index(number) {
                rows[i] += line_rows.len();
            }
        }
        let m = lines.len();
        let total = rows.iter().sum::<usize>().max(1) as f64;
        // The crossover graph's Laplacian; a small pull toward a zero
        // row-weighted mean fixes each connected set's free level.
        let mut normal = nalgebra::DMatrix::<f64>::zeros(m, m);
        let mut right = nalgebra::DVector::<f64>::zeros(m);
        let pairs: Vec<(usize, usize, f64)> = (used.iter())
            .filter_map(|(p, d)| Some((index(p.lines[0])?, index(p.lines[1])?, *d)))
            .collect();
        for &(a, b, difference) in &pairs {
            normal[(a, a)] += 1.0;
            normal[(b, b)] += 1.0;
            normal[(a, b)] -= 1.0;
            normal[(b, a)] -= 1.0;
            right[a] += difference;
            right[b] -= difference;
        }
        for i in 0..m {
            for j in 0..m {
                normal[(i, j)] += 1e-6 * (rows[i] * rows[j]) as f64 / (total * total);
            }
            normal[(i, i)] += 1e-9;
        }
        let normal = normal.cholesky()?;
        let levels: Vec<f64> = normal.solve(&right).iter().copied().collect();
        let components = connected_sets(m, &pairs);
        let spare = pairs.len() as f64 - (m - components) as f64;
        let misfit: f64 = (pairs.iter())
            .map(|&(a, b, d)| (d - (levels[a] - levels[b])).powi(2))
            .sum();
        Some(Levelling {
            misfit_nt: (spare >= 1.0).then(|| (misfit / spare).sqrt()),
            crossovers: pairs.len(),
            lines,
            levels,
            rows,
            normal,
        })
    }

    /// The row-weighted standard deviation of the line levels, nT.
    pub fn spread_nt(&self) -> f64 {
        weighted_spread(&self.levels, &self.rows)
    }
}

/// The row-weighted standard deviation of `levels`.
fn weighted_spread(levels: &[f64], rows: &[usize]) -> f64 {
    let total: f64 = rows.iter().sum::<usize>().max(1) as f64;
    let mean = levels.iter().zip(rows).map(|(l, r)| l * *r as f64).sum::<f64>() / total;
    (levels
        .iter()
        .zip(rows)
        .map(|(l, r)| (l - mean).powi(2) * *r as f64)
        .sum::<f64>()
        / total)
        .sqrt()
}

/// How many connected sets `pairs` (edges) make of `m` lines.
fn connected_sets(m: usize, pairs: &[(usize, usize, f64)]) -> usize {
    let mut parent: Vec<usize> = (0..m).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for &(a, b, _) in pairs {
        let (ra, rb) = (root(&mut parent, a), root(&mut parent, b));
        parent[ra] = rb;
    }
    (0..m).filter(|&i| root(&mut parent, i) == i).count()
}

/// Two compensations of one channel levelled at the same crossovers: the
/// spread of each one's line levels over the survey's rows, and its
/// standard error.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct LevelComparison {
    /// Crossovers used.
    pub crossovers: usize,
    /// Lines levelled.
    pub lines: usize,
    /// Row-weighted spread of the first's (the reference's) line levels, nT.
    pub reference_nt: f64,
    /// The same of the second, nT.
    pub candidate_nt: f64,
    /// Standard error of the difference of the two spreads, nT, from the
    /// crossover misfit the levelling leaves (zero when none is spare).
    pub standard_error_nt: f64,
}

/// `reference` and `candidate` levelled at `crossovers`; `None` without a
/// base station (the external field's drift between passes would be
/// levelled as the lines' own, far above any compensation's heading
/// level), or with fewer than `least` crossovers or two lines.
pub fn compare_levels(
    log: &FlightLog,
    crossovers: &Crossovers,
    (reference, candidate): (&[f64], &[f64]),
    least: usize,
) -> Option<LevelComparison> {
    if !crossovers.external_field_removed() {
        return None;
    }
    let plain = Levelling::of(log, crossovers, reference)?;
    let other = Levelling::of(log, crossovers, candidate)?;
    if plain.crossovers < least.max(2) || plain.lines != other.lines {
        return None;
    }
    let (reference_nt, candidate_nt) = (plain.spread_nt(), other.spread_nt());
    // The candidate's levels are the reference's plus the levels of their
    // difference, which has no noise of its own: the noise is the
    // reference's. The squared spreads differ by 2·cov(L, δ) + var(δ),
    // whose gradient in the reference's levels L is g; its variance is
    // misfit² · gᵀ N⁻¹ g, and the spreads' difference is that over their
    // sum.
    let total = plain.rows.iter().sum::<usize>().max(1) as f64;
    let delta: Vec<f64> = other.levels.iter().zip(&plain.levels).map(|(o, p)| o - p).collect();
    let mean_delta = delta.iter().zip(&plain.rows).map(|(d, r)| d * *r as f64).sum::<f64>() / total;
    let gradient = nalgebra::DVector::from_iterator(
        delta.len(),
        (delta.iter().zip(&plain.rows)).map(|(d, r)| 2.0 * *r as f64 * (d - mean_delta) / total),
    );
    let variance = plain.misfit_nt.unwrap_or(0.0).powi(2) * gradient.dot(&plain.normal.solve(&gradient));
    let sum = reference_nt + candidate_nt;
    Some(LevelComparison {
        crossovers: plain.crossovers,
        lines: plain.lines.len(),
        reference_nt,
        candidate_nt,
        standard_error_nt: match sum > 0.0 {
            true => variance.max(0.0).sqrt() / sum,
            false => 0.0,
        },
    })
}

/// A channel's crossover differences before and after compensation: the
/// survey's own measure of what compensation leaves that depends on
/// heading.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CrossoverFigures {
    /// Crossovers with both values finite.
    pub crossovers: usize,
    /// RMS crossover difference uncompensated, nT.
    pub before_nt: f64,
    /// The same, compensated, nT.
    pub after_nt: f64,
    /// Whether the base station's change between passes was taken out.
    pub external_field_removed: bool,
}

/// The crossover figures of `before` (uncompensated) and `after`
/// (compensated) at `crossovers`; `None` without any.
pub fn figures(crossovers: &Crossovers, before: &[f64], after: &[f64]) -> Option<CrossoverFigures> {
    let pairs: Vec<(f64, f64)> = (crossovers.differences(before).into_iter())
        .zip(crossovers.differences(after))
        .filter(|(b, a)| b.is_finite() && a.is_finite())
        .collect();
    if pairs.is_empty() {
        return None;
    }
    let rms =
        |pick: fn(&(f64, f64)) -> f64| (pairs.iter().map(|p| pick(p).powi(2)).sum::<f64>() / pairs.len() as f64).sqrt();
    Some(CrossoverFigures {
        crossovers: pairs.len(),
        before_nt: rms(|p| p.0),
        after_nt: rms(|p| p.1),
        external_field_removed: crossovers.external_field_removed(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::flight_log::Channel;

    /// Three east-west lines 1 km apart and two north-south ties, sampled
    /// every 400 and 300 m (segments up to four times the smallest grid
    /// cell), each line
    /// carrying `level(line)` on top of a field that depends on position
    /// only; a base station reading zero.
    fn surveyed(level: impl Fn(f64) -> f64) -> FlightLog {
        let mut rows: Vec<(f64, f64, f64)> = Vec::new();
        for (k, north) in [0.0, 1000.0, 2000.0].into_iter().enumerate() {
            let mut easts: Vec<f64> = (0..=10).map(|i| 400.0 * i as f64).collect();
            if k % 2 == 1 {
                easts.reverse();
            }
            rows.extend(easts.into_iter().map(|east| (north, east, 1001.0 + k as f64)));
            rows.push((f64::NAN, f64::NAN, 0.0));
        }
        for (k, east) in [1500.0, 3300.0].into_iter().enumerate() {
            rows.extend((0..10).map(|i| (-500.0 + 300.0 * i as f64, east, 9001.0 + k as f64)));
        }
        let degrees = |m: f64| m / 111_195.0;
        let column = |name: &str, role: ChannelRole, values: Vec<f64>| Channel {
            name: name.into(),
            role,
            values,
        };
        let field = |(north, east, line): &(f64, f64, f64)| 0.001 * north + 0.002 * east + level(*line);
        let channels = vec![
            column(
                "lat",
                ChannelRole::Position,
                rows.iter().map(|r| degrees(r.0)).collect(),
            ),
            column(
                "lon",
                ChannelRole::Position,
                rows.iter().map(|r| degrees(r.1)).collect(),
            ),
            column("line", ChannelRole::Line, rows.iter().map(|r| r.2).collect()),
            column("diurnal", ChannelRole::BaseStation, vec![0.0; rows.len()]),
            column(
                "mag_1_uc",
                ChannelRole::ScalarMagnetometer,
                rows.iter().map(field).collect(),
            ),
        ];
        let time = (0..rows.len()).map(|k| k as f64).collect();
        FlightLog::new("survey.csv", "tt", time, channels).unwrap()
    }

    #[test]
    fn long_segments_are_crossed_and_levelling_recovers_each_line_s_level() {
        // 0.2 nT on the middle line, 0.1 nT on the ties.
        let level = |line: f64| match line {
            1002.0 => 0.2,
            l if l > 9000.0 => 0.1,
            _ => 0.0,
        };
        let log = surveyed(level);
        let crossovers = Crossovers::of(&log);
        assert_eq!(crossovers.points.len(), 6, "{:?}", crossovers.points);
        let values = &log.channel("mag_1_uc").unwrap().values;
        // The field is linear in position, so interpolation is exact and
        // each difference is the two lines' levels apart.
        for point in &crossovers.points {
            let expected = level(point.lines[0]) - level(point.lines[1]);
            assert!((point.difference(values) - expected).abs() < 1e-9, "{point:?}");
        }
        let levelling = Levelling::of(&log, &crossovers, values).unwrap();
        assert_eq!(levelling.lines, vec![1001.0, 1002.0, 1003.0, 9001.0, 9002.0]);
        assert!(levelling.misfit_nt.unwrap() < 1e-6, "{:?}", levelling.misfit_nt);
        for (line, found) in levelling.lines.iter().zip(&levelling.levels) {
            let relative = found - levelling.levels[0];
            assert!((relative - level(*line)).abs() < 1e-6, "line {line}: {relative}");
        }
        // Row-weighted: 11 of 53 rows at 0.2, 20 at 0.1, 22 at 0.
        let mean = (11.0 * 0.2 + 20.0 * 0.1) / 53.0;
        let spread =
            ((11.0 * (0.2f64 - mean).powi(2) + 20.0 * (0.1f64 - mean).powi(2) + 22.0 * mean * mean) / 53.0).sqrt();
        assert!(
            (levelling.spread_nt() - spread).abs() < 1e-6,
            "{} against {spread}",
            levelling.spread_nt()
        );
    }

    #[test]
    fn crossing_segments_meet_where_the_lines_cross_and_parallel_ones_do_not() {
        let (t, u) = intersection(([0.0, 0.0], [2.0, 0.0]), ([0.5, -1.0], [0.5, 3.0])).unwrap();
        assert!((t - 0.25).abs() < 1e-12 && (u - 0.25).abs() < 1e-12, "{t} {u}");
        assert_eq!(intersection(([0.0, 0.0], [2.0, 0.0]), ([0.0, 1.0], [2.0, 1.0])), None);
        assert_eq!(intersection(([0.0, 0.0], [2.0, 0.0]), ([3.0, -1.0], [3.0, 1.0])), None);
    }
}
