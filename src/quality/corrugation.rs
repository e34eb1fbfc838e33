//! The survey's heading level where no ties cross its lines: the level
//! by which neighbouring parallel lines flown in opposite directions
//! alternate.
//!
//! A block of parallel lines is flown back and forth, so a compensation
//! that leaves a level per heading shifts every other line by the same
//! amount and the block comes out corrugated. The Earth's field varies
//! smoothly from one line to the next, so a line's value less what its
//! two neighbours interpolate to its offset (matched along the track over
//! the stretch the three share) keeps little of the geology, none of a
//! gradient across the lines, and about twice the heading level, signed by
//! the line's direction against its neighbours'. The heading level is the
//! least-squares fit of those second differences, beside a constant for
//! the geology's curvature across the lines, with the fit's scatter as its
//! standard error. The external field's change between lines is
//! taken out with the base station where the flight records one; without
//! one, its steady drift cancels in the second differences.

use crate::calibration::headings::angle_apart;
use crate::ingest::flight_log::{ChannelRole, FlightLog};
use crate::quality::heading_error::{local_positions, survey_lines, SurveyLine};

/// Lines whose tracks lie within this of the block's direction, or of its
/// reciprocal, are the block's, degrees (ties across it are not).
pub const PARALLEL_WITHIN_DEG: f64 = 20.0;

/// Points along the shared stretch at which three neighbouring lines are
/// compared.
const POINTS: usize = 64;

/// Three neighbours are compared only when they share at least this part
/// of the shortest one's length.
const SHARED_FRACTION: f64 = 0.5;

/// Three neighbours are compared only when one gap between them is at
/// most this many times the other: the geology's curvature across an
/// uneven triple is no longer small.
const UNEVEN_GAPS: f64 = 4.0;

/// A line's values at one point along the track: two rows and the weight
/// of the second.
type Between = (usize, usize, f64);

/// Three neighbouring lines of the block and where they are compared.
struct Triple {
    /// What the heading level contributes to the second difference: the
    /// middle line's direction (+1 or −1) less its neighbours',
    /// interpolated to its offset.
    sign_factor: f64,
    /// Neighbours' interpolation weights (before, after).
    weights: [f64; 2],
    /// Per point, the three lines' values (before, middle, after).
    points: Vec<[Between; 3]>,
}

/// The block of parallel lines of `log`'s survey and its triples of
/// neighbours.
pub struct Corrugation<'a> {
    triples: Vec<Triple>,
    lines: usize,
    base_station: Option<&'a [f64]>,
}

/// A block line: its direction, offset across the block and its rows in
/// order along the track.
struct BlockLine {
    sign: f64,
    offset_m: f64,
    along: Vec<f64>,
    rows: Vec<usize>,
}

impl BlockLine {
    /// Where `along_m` lies between the line's rows; `None` outside it.
    fn between(&self, along_m: f64) -> Option<Between> {
        let upper = self.along.partition_point(|&a| a < along_m);
        if upper == 0 || upper >= self.along.len() {
            return (upper < self.along.len() && self.along[upper] == along_m).then_some((
                self.rows[upper],
                self.rows[upper],
                0.0,
            ));
        }
        let (a0, a1) = (self.along[upper - 1], self.along[upper]);
        let weight = if a1 > a0 { (along_m - a0) / (a1 - a0) } else { 0.0 };
        Some((self.rows[upper - 1], self.rows[upper], weight))
    }

    fn length_m(&self) -> f64 {
        self.along.last().unwrap_or(&0.0) - self.along.first().unwrap_or(&0.0)
    }
}

impl<'a> Corrugation<'a> {
    /// The block of `log`: the lines within [`PARALLEL_WITHIN_DEG`] of one
    /// line's track or its reciprocal, that line the first flown of those
    /// with the most rows so; its track is the block's direction. No
    /// triples without positions or three such lines.
    pub fn of(log: &'a FlightLog) -> Self {
        let base_station = (log.channels().iter())
            .find(|c| c.role == ChannelRole::BaseStation)
            .map(|c| c.values.as_slice());
        let (triples, lines) = match local_positions(log) {
            Some(positions) => triples(&positions, survey_lines(log, &positions)),
            None => (Vec::new(), 0),
        };
        Corrugation {
            triples,
            lines,
            base_station,
        }
    }

    /// Triples of neighbouring lines that share enough of the track.
    pub fn triples(&self) -> usize {
        self.triples.len()
    }

    /// Whether the triples' directions tell a heading level from the
    /// geology's curvature: at least two, not all alike.
    pub fn tells_heading_level(&self) -> bool {
        let factors: Vec<f64> = self.triples.iter().map(|t| t.sign_factor).collect();
        separable(&factors)
    }

    /// Whether the external field's change between lines is taken out.
    pub fn external_field_removed(&self) -> bool {
        self.base_station.is_some()
    }

    /// The heading level of `values`: a line flown along the block's
    /// direction less the same ground flown the other way, nT. `None` with
    /// fewer than two triples of finite values, or triples whose
    /// directions cannot tell the level from the curvature.
    pub fn heading_level(&self, values: &[f64]) -> Option<HeadingLevel> {
        let value = |(a, b, w): Between| {
            let external = self.base_station.map_or(0.0, |base| base[a] + w * (base[b] - base[a]));
            values[a] + w * (values[b] - values[a]) - external
        };
        let fitted: Vec<(f64, f64)> = (self.triples.iter())
            .filter_map(|triple| {
                let [before, after] = triple.weights;
                let differences: Vec<f64> = (triple.points.iter())
                    .map(|[b, m, a]| value(*m) - before * value(*b) - after * value(*a))
                    .filter(|d| d.is_finite())
                    .collect();
                (!differences.is_empty()).then(|| {
                    let mean = differences.iter().sum::<f64>() / differences.len() as f64;
                    (triple.sign_factor, mean)
                })
            })
            .collect();
        // sd = κ + c·h by least squares: κ the geology's curvature across
        // the lines, the same on every triple to first order.
        let count = fitted.len() as f64;
        let sum = |f: &dyn Fn(&(f64, f64)) -> f64| fitted.iter().map(f).sum::<f64>();
        let (sc, scc, sd, scd) = (sum(&|p| p.0), sum(&|p| p.0 * p.0), sum(&|p| p.1), sum(&|p| p.0 * p.1));
        let determinant = count * scc - sc * sc;
        if !separable(&fitted.iter().map(|p| p.0).collect::<Vec<_>>()) {
            return None;
        }
        let half = (count * scd - sc * sd) / determinant;
        let curvature = (sd - sc * half) / count;
        let residual = sum(&|(c, d)| (d - curvature - c * half).powi(2));
        let standard_error = match fitted.len() {
            0..=2 => 0.0,
            m => (residual / (m - 2) as f64 * count / determinant).sqrt(),
        };
        Some(HeadingLevel {
            level_nt: 2.0 * half,
            standard_error_nt: 2.0 * standard_error,
            triples: fitted.len(),
            lines: self.lines,
        })
    }
}

/// Whether sign factors `c` fit beside a constant: the normal equations'
/// determinant n·Σc² − (Σc)² is not negligible against n·Σc².
fn separable(factors: &[f64]) -> bool {
    let count = factors.len() as f64;
    let (sc, scc) = (factors.iter().sum::<f64>(), factors.iter().map(|c| c * c).sum::<f64>());
    let determinant = count * scc - sc * sc;
    factors.len() >= 2 && determinant > 1e-9 * count * scc
}

/// The block's lines in order across it, and the triples of neighbours
/// that share enough of their length; the count of lines in the block.
fn triples(positions: &[[f64; 2]], lines: Vec<(f64, SurveyLine)>) -> (Vec<Triple>, usize) {
    let parallel =
        |a: f64, b: f64| angle_apart(a, b) < PARALLEL_WITHIN_DEG || angle_apart(a, b + 180.0) < PARALLEL_WITHIN_DEG;
    let rows_parallel_to = |track: f64| -> usize {
        (lines.iter())
            .filter(|(_, l)| parallel(l.track_deg, track))
            .map(|(_, l)| l.rows.len())
            .sum()
    };
    let counts: Vec<usize> = lines.iter().map(|(_, l)| rows_parallel_to(l.track_deg)).collect();
    let most = counts.iter().copied().max().unwrap_or(0);
    let Some(direction) = (lines.iter().zip(&counts))
        .find(|(_, count)| **count == most)
        .map(|((_, l), _)| l.track_deg)
    else {
        return (Vec::new(), 0);
    };
    let (sin, cos) = direction.to_radians().sin_cos();
    // Positions are [north, east]; a track of θ runs along (cos θ, sin θ).
    let along = |p: [f64; 2]| p[0] * cos + p[1] * sin;
    let across = |p: [f64; 2]| -p[0] * sin + p[1] * cos;
    let mut block: Vec<BlockLine> = (lines.into_iter())
        .filter(|(_, l)| parallel(l.track_deg, direction))
        .map(|(_, line)| {
            let mut rows = line.rows;
            rows.sort_by(|a, b| along(positions[*a]).total_cmp(&along(positions[*b])));
            let mut offsets: Vec<f64> = rows.iter().map(|&r| across(positions[r])).collect();
            let middle = offsets.len() / 2;
            let offset_m = *offsets.select_nth_unstable_by(middle, f64::total_cmp).1;
            BlockLine {
                sign: if angle_apart(line.track_deg, direction) < PARALLEL_WITHIN_DEG {
                    1.0
                } else {
                    -1.0
                },
                offset_m,
                along: rows.iter().map(|&r| along(positions[r])).collect(),
                rows,
            }
        })
        .collect();
    block.sort_by(|a, b| a.offset_m.total_cmp(&b.offset_m));
    let found = (block.windows(3)).filter_map(triple).collect();
    (found, block.len())
}

/// Three neighbouring lines compared where they share the track; `None`
/// when their gaps are uneven or they share too little of it.
fn triple(three: &[BlockLine]) -> Option<Triple> {
    let [before, middle, after] = three else {
        return None;
    };
    let gaps = [middle.offset_m - before.offset_m, after.offset_m - middle.offset_m];
    if gaps[0] <= 0.0 || gaps[1] <= 0.0 || gaps[0].max(gaps[1]) > UNEVEN_GAPS * gaps[0].min(gaps[1]) {
        return None;
    }
    let start = three.iter().map(|l| l.along[0]).fold(f64::MIN, f64::max);
    let end = (three.iter())
        .map(|l| *l.along.last().unwrap_or(&f64::MIN))
        .fold(f64::MAX, f64::min);
    let shortest = three.iter().map(BlockLine::length_m).fold(f64::MAX, f64::min);
    if !(end - start >= SHARED_FRACTION * shortest && shortest > 0.0) {
        return None;
    }
    let weights = [gaps[1] / (gaps[0] + gaps[1]), gaps[0] / (gaps[0] + gaps[1])];
    let points = (0..POINTS)
        .filter_map(|k| {
            let along_m = start + (end - start) * (k as f64 + 0.5) / POINTS as f64;
            Some([
                before.between(along_m)?,
                middle.between(along_m)?,
                after.between(along_m)?,
            ])
        })
        .collect();
    Some(Triple {
        sign_factor: middle.sign - weights[0] * before.sign - weights[1] * after.sign,
        weights,
        points,
    })
}

/// A compensation's heading level on the survey's block of lines.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HeadingLevel {
    /// A line flown along the block's direction less the same ground flown
    /// the other way, nT.
    pub level_nt: f64,
    /// Its standard error from the second differences' scatter about the
    /// fit (zero with two triples or fewer: none to spare), nT.
    pub standard_error_nt: f64,
    /// Triples of neighbouring lines compared.
    pub triples: usize,
    /// Lines in the block.
    pub lines: usize,
}

/// Two compensations of one channel set against each other on the
/// block's lines.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HeadingLevelComparison {
    /// Triples of neighbouring lines compared.
    pub triples: usize,
    /// Lines in the block.
    pub lines: usize,
    /// The first's (the reference's) heading level, signed as
    /// [`HeadingLevel::level_nt`], nT.
    pub reference_nt: f64,
    /// The same of the second, nT.
    pub candidate_nt: f64,
    /// Standard error of the heading level, nT: the geology and the
    /// external field left in the second differences, common to both (the
    /// candidate's level is the reference's plus that of their
    /// difference, which has no noise of its own).
    pub standard_error_nt: f64,
}

/// `reference` and `candidate` on `corrugation`'s block; `None` with fewer
/// than `least` triples (a heading level needs two: one cannot tell it
/// from the geology's curvature).
pub fn compare_heading_levels(
    corrugation: &Corrugation,
    (reference, candidate): (&[f64], &[f64]),
    least: usize,
) -> Option<HeadingLevelComparison> {
    let plain = corrugation.heading_level(reference)?;
    let other = corrugation.heading_level(candidate)?;
    if plain.triples < least.max(2) || plain.triples != other.triples {
        return None;
    }
    Some(HeadingLevelComparison {
        triples: plain.triples,
        lines: plain.lines,
        reference_nt: plain.level_nt,
        candidate_nt: other.level_nt,
        standard_error_nt: plain.standard_error_nt,
    })
}

/// A channel's heading level between neighbouring lines before and after
/// compensation: the survey's own measure of what compensation leaves per
/// heading where no ties cross its lines.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct HeadingLevelFigures {
    /// Lines in the block.
    pub lines: usize,
    /// Triples of neighbouring lines compared.
    pub triples: usize,
    /// A line flown one way less the same ground flown the other way,
    /// uncompensated, its size, nT.
    pub before_nt: f64,
    /// The same, compensated, nT.
    pub after_nt: f64,
    /// The compensated level's standard error (zero with two triples), nT.
    pub standard_error_nt: f64,
    /// Whether the base station's change between lines was taken out.
    pub external_field_removed: bool,
}

/// The heading level of `before` (uncompensated) and `after`
/// (compensated) on `corrugation`'s block; `None` where it cannot tell one.
pub fn figures(corrugation: &Corrugation, before: &[f64], after: &[f64]) -> Option<HeadingLevelFigures> {
    let (plain, compensated) = (corrugation.heading_level(before)?, corrugation.heading_level(after)?);
    Some(HeadingLevelFigures {
        lines: compensated.lines,
        triples: compensated.triples,
        before_nt: plain.level_nt.abs(),
        after_nt: compensated.level_nt.abs(),
        standard_error_nt: compensated.standard_error_nt,
        external_field_removed: corrugation.external_field_removed(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::flight_log::Channel;

    /// `count` lines 500 m apart flown back and forth along 30°, sampled
    /// every 50 m, each over `field(along, across)` plus `heading` on the
    /// lines flown along 30° and less it on the others; two ties across
    /// them; a base station reading `external(row)`.
    fn block(
        count: usize,
        heading: f64,
        field: impl Fn(f64, f64) -> f64,
        external: impl Fn(usize) -> f64,
    ) -> FlightLog {
        let (sin, cos) = 30f64.to_radians().sin_cos();
        let mut rows: Vec<(f64, f64, f64, f64)> = Vec::new();
        for k in 0..count {
            let across = 500.0 * k as f64;
            let mut along: Vec<f64> = (0..=80).map(|i| 50.0 * i as f64 + 7.0 * k as f64).collect();
            let sign = if k % 2 == 0 { 1.0 } else { -1.0 };
            if sign < 0.0 {
                along.reverse();
            }
            rows.extend(
                along
                    .into_iter()
                    .map(|a| (a, across, 1001.0 + k as f64, field(a, across) + sign * heading / 2.0)),
            );
        }
        for (k, a) in [1000.0, 3000.0].into_iter().enumerate() {
            rows.extend((0..40).map(|i| {
                (
                    a,
                    -200.0 + 100.0 * i as f64,
                    9001.0 + k as f64,
                    field(a, -200.0 + 100.0 * i as f64) + 5.0,
                )
            }));
        }
        let degrees = |m: f64| m / 111_195.0;
        let north = |(a, c, _, _): &(f64, f64, f64, f64)| a * cos - c * sin;
        let east = |(a, c, _, _): &(f64, f64, f64, f64)| a * sin + c * cos;
        let column = |name: &str, role: ChannelRole, values: Vec<f64>| Channel {
            name: name.into(),
            role,
            values,
        };
        let channels = vec![
            column(
                "lat",
                ChannelRole::Position,
                rows.iter().map(|r| degrees(north(r))).collect(),
            ),
            column(
                "lon",
                ChannelRole::Position,
                rows.iter().map(|r| degrees(east(r))).collect(),
            ),
            column("line", ChannelRole::Line, rows.iter().map(|r| r.2).collect()),
            column(
                "diurnal",
                ChannelRole::BaseStation,
                (0..rows.len()).map(&external).collect(),
            ),
            column(
                "mag_1_uc",
                ChannelRole::ScalarMagnetometer,
                rows.iter().enumerate().map(|(k, r)| r.3 + external(k)).collect(),
            ),
        ];
        let time = (0..rows.len()).map(|k| k as f64).collect();
        FlightLog::new("block.csv", "tt", time, channels).unwrap()
    }

    #[test]
    fn a_field_linear_across_the_lines_leaves_the_heading_level_alone() {
        // A gradient along and across, an external field drifting by
        // 30 nT with a swing: the heading level of 0.4 nT is found exactly.
        let log = block(
            8,
            0.4,
            |along, across| 0.003 * along - 0.02 * across,
            |row| 0.01 * row as f64 + 3.0 * (row as f64 / 90.0).sin(),
        );
        let corrugation = Corrugation::of(&log);
        let values = &log.channel("mag_1_uc").unwrap().values;
        let level = corrugation.heading_level(values).unwrap();
        assert_eq!((level.triples, level.lines), (6, 8), "{level:?}");
        assert!((level.level_nt - 0.4).abs() < 1e-9, "{level:?}");
        assert!(level.standard_error_nt < 1e-9, "{level:?}");
        // The other way round it is the reciprocal's level.
        let log = block(8, -0.25, |along, _| 0.003 * along, |_| 0.0);
        let level = Corrugation::of(&log)
            .heading_level(&log.channel("mag_1_uc").unwrap().values)
            .unwrap();
        assert!((level.level_nt + 0.25).abs() < 1e-9, "{level:?}");
    }

    #[test]
    fn curvature_across_the_lines_is_fitted_and_a_bump_sets_the_standard_error() {
        // A field curved across the lines adds the same second difference
        // to each triple, 1e-6 × 500² = 0.25 nT: the fit's constant takes
        // it, and the level of 0.4 nT is found exactly with nothing to
        // spare.
        let log = block(8, 0.4, |_, across| 1e-6 * across * across, |_| 0.0);
        let values = &log.channel("mag_1_uc").unwrap().values;
        let level = Corrugation::of(&log).heading_level(values).unwrap();
        assert!((level.level_nt - 0.4).abs() < 1e-9, "{level:?}");
        assert!(level.standard_error_nt < 1e-9, "{level:?}");
        // A bump of g = 0.3 nT on the fifth line (offset 2 km) gives the
        // six triples' second differences 0, 0, −g/2, g, −g/2, 0 with
        // factors −2, 2, −2, 2, −2, 2: the fit takes h = g/6 from it (the
        // level rises by g/3 = 0.1 nT), leaves residuals whose squares sum
        // to 5g²/6 over 4 degrees of freedom, and the level's standard
        // error is 2·√(5g²/24 · 6/144) = g·√5/12.
        let bump = |_: f64, across: f64| if (across - 2000.0).abs() < 1.0 { 0.3 } else { 0.0 };
        let log = block(8, 0.4, |a, c| 1e-6 * c * c + bump(a, c), |_| 0.0);
        let values = &log.channel("mag_1_uc").unwrap().values;
        let level = Corrugation::of(&log).heading_level(values).unwrap();
        assert!((level.level_nt - 0.5).abs() < 1e-9, "{level:?}");
        let expected = 0.3 * 5f64.sqrt() / 12.0;
        assert!(
            (level.standard_error_nt - expected).abs() < 1e-9,
            "{level:?} against {expected}"
        );
        // Compared with a candidate whose lines alternate 0.3 nT less:
        // the same standard error, the levels of both.
        let candidate: Vec<f64> = (values.iter().zip(&log.channel("line").unwrap().values))
            .map(|(v, line)| match *line as i64 {
                l if l > 9000 => *v,
                l if l % 2 == 1 => v - 0.15,
                _ => v + 0.15,
            })
            .collect();
        let compared = compare_heading_levels(&Corrugation::of(&log), (values, &candidate), 2).unwrap();
        assert!((compared.reference_nt - 0.5).abs() < 1e-9, "{compared:?}");
        assert!((compared.candidate_nt - 0.2).abs() < 1e-9, "{compared:?}");
        assert!((compared.standard_error_nt - expected).abs() < 1e-9, "{compared:?}");
        let shown = figures(&Corrugation::of(&log), values, &candidate).unwrap();
        assert_eq!((shown.lines, shown.triples, shown.external_field_removed), (8, 6, true));
        assert!(
            (shown.before_nt - 0.5).abs() < 1e-9 && (shown.after_nt - 0.2).abs() < 1e-9,
            "{shown:?}"
        );
        assert!((shown.standard_error_nt - expected).abs() < 1e-9, "{shown:?}");
    }

    #[test]
    fn three_lines_or_fewer_give_no_heading_level_and_four_give_one_with_nothing_to_spare() {
        for count in [2, 3] {
            let log = block(count, 0.4, |_, _| 0.0, |_| 0.0);
            let values = &log.channel("mag_1_uc").unwrap().values;
            assert!(Corrugation::of(&log).heading_level(values).is_none(), "{count} lines");
            assert!(!Corrugation::of(&log).tells_heading_level(), "{count} lines");
        }
        let log = block(4, 0.4, |_, across| 1e-6 * across * across, |_| 0.0);
        let values = &log.channel("mag_1_uc").unwrap().values;
        let level = Corrugation::of(&log).heading_level(values).unwrap();
        assert_eq!((level.triples, level.lines), (2, 4), "{level:?}");
        assert!(
            (level.level_nt - 0.4).abs() < 1e-9 && level.standard_error_nt == 0.0,
            "{level:?}"
        );
        assert!(Corrugation::of(&log).tells_heading_level());
        assert!(compare_heading_levels(&Corrugation::of(&log), (values, values), 2).is_some());
        assert!(compare_heading_levels(&Corrugation::of(&log), (values, values), 3).is_none());
    }
}
