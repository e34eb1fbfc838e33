//! The permutation guard: a source column must beat copies of itself
//! shifted in time by whole seconds, which keep its spectrum but not its
//! timing against the manoeuvres.

use super::*;
use crate::ingest::flight_log::Channel;

/// Circular time shifts of the source columns a source finding must beat.
pub(super) const SOURCE_SHIFTS: usize = 9;

/// Whether a source term (`aux_coupling`, `external_field`) that lowers
/// the held-out RMS of `model` to `rms_nt` is singled out by its recorded
/// timing. For k = 1…9, every candidate source column is shifted
/// circularly by k/10 of the flight together, and the best of them is
/// scored as a source of `model`; the real column must beat the best
/// shifted one every time. A shift keeps each column's spectrum and
/// levels and breaks only its alignment with the aircraft's field, so
/// this is a permutation test of the best of all the columns scanned, the
/// multiple comparison the scan makes: under the null that no column
/// causes the residual, the real best beats all nine with chance 1/10.
/// A slow column whose level differs from leg to leg acts as a permanent
/// field that changes with heading and can fit a cabin sensor's residual
/// by chance, and the more such columns a flight records, the likelier one
/// of them clears the threshold alone (measured figures:
/// docs/measurements.md, section diagnose::shifted). A current that causes
/// the residual loses it when shifted. The shifted candidates are of the
/// tested one's form (a column alone, or with its rate: with its rate, a
/// shifted pure sinusoid such as a fan's ripple takes any phase), and the
/// tested column's own shifted copy is left out at a shift that realigns it
/// (correlation above 0.5 with the original over the calibration
/// windows, as a periodic column is about every half-period). Other
/// effects always pass.
///
/// Each shift's candidates go through the search's own screen
/// ([`super::screen`], on the model's `ridge`) first, and only those it
/// keeps are scored in full, as in the search: the real column was chosen
/// from a screened list too, so both sides of the comparison are picked
/// alike.
pub(super) fn beats_shifted_sources(
    problem: &Problem,
    (model, ridge): (&Model, &[f64]),
    extension: &Extension,
    rms_nt: f64,
) -> bool {
    let (tested, with_rate) = match extension {
        // A rate refines a coupling whose timing already stood this test.
        // The second-order term has no source column to shift.
        Extension::Lag { .. } | Extension::Eddy { .. } | Extension::CouplingRate { .. } | Extension::SecondOrder => {
            return true
        }
        Extension::Coupling { source } | Extension::External { source } => (source, false),
        Extension::CouplingWithRate { source } => (source, true),
    };
    let scanned: Vec<&String> = (problem.levels.keys())
        .filter(|column| !model.sources.iter().any(|s| s.column() == column.as_str()))
        .collect();
    // A figure that is not a number beats nothing.
    if !rms_nt.is_finite() {
        return false;
    }
    let rows = problem.log.len();
    let in_windows = window_rows(problem.log.time_s(), problem.windows);
    // The model's columns are not shifted: one screen serves every shift.
    let screen = super::screen::Screen::new(problem, model, ridge);
    let stretches = crate::calibration::windows::merged_rows(problem.windows, problem.log.time_s());
    (1..=SOURCE_SHIFTS).all(|k| {
        let shift = k * rows / (SOURCE_SHIFTS + 1);
        let Ok(log) = shifted_flight(problem, &scanned, shift, &stretches) else {
            return true;
        };
        // A periodic column (a fan's ripple) shifted by about a whole
        // number of half-periods is itself again, not a surrogate.
        let realigned = match (problem.log.channel(tested), log.channel(tested)) {
            (Some(original), Some(moved)) => correlation(&original.values, &moved.values, &in_windows).abs() > 0.5,
            _ => false,
        };
        let shifted = Problem { log: &log, ..*problem };
        let surrogates: Vec<(Model, Extension)> = candidates(&shifted, model, &DiagnoseOptions::default())
            .into_iter()
            .filter(|(_, e)| {
                let itself_again = |source: &String| realigned && source == tested;
                match e {
                    Extension::Coupling { source } => !with_rate && !itself_again(source),
                    Extension::CouplingWithRate { source } => with_rate && !itself_again(source),
                    Extension::External { source } => !itself_again(source),
                    _ => false,
                }
            })
            .collect();
        let surrogates = match &screen {
            Some(screen) => screen.select(&shifted, surrogates),
            None => surrogates,
        };
        // The real column fails as soon as one surrogate explains as
        // much; the screen's order puts the likeliest first.
        !(surrogates.into_par_iter()).any(|(next, _)| held_out(&shifted, &next).is_ok_and(|h| h.rms_nt <= rms_nt))
    })
}

/// The problem's flight with each `scanned` column shifted circularly by
/// `shift` rows (as `rotate_right`), for scores that read the windows'
/// rows, `stretches`, alone: a scanned column is shifted on those rows
/// and one row either side (a rate's central difference reads them) and
/// zero elsewhere; every other column is copied whole (the model's lag,
/// eddy τ, rates and second-order term read the sensor, the channel and
/// its sources beyond the windows).
fn shifted_flight(
    problem: &Problem,
    scanned: &[&String],
    shift: usize,
    stretches: &[std::ops::Range<usize>],
) -> Result<FlightLog> {
    let rows = problem.log.len();
    let channels = problem.log.channels().iter().map(|channel| {
        if !scanned.contains(&&channel.name) {
            return channel.clone();
        }
        let mut values = vec![0.0; rows];
        for stretch in stretches {
            let from = stretch.start.saturating_sub(1);
            let to = (stretch.end + 1).min(rows);
            for (row, value) in (from..to).zip(&mut values[from..to]) {
                *value = channel.values[(row + rows - shift) % rows];
            }
        }
        Channel {
            name: channel.name.clone(),
            role: channel.role.clone(),
            values,
        }
    });
    FlightLog::new(
        problem.log.source(),
        problem.log.time_column(),
        problem.log.time_s().to_vec(),
        channels.collect(),
    )
}

/// The rows whose times fall in any of `windows`.
pub(super) fn window_rows(time_s: &[f64], windows: &[CalibrationWindow]) -> Vec<usize> {
    (0..time_s.len())
        .filter(|&k| windows.iter().any(|w| (w.t_start..=w.t_end).contains(&time_s[k])))
        .collect()
}

/// Pearson correlation of `a` and `b` over `rows` where both are finite
/// (0 when either is constant there).
pub(super) fn correlation(a: &[f64], b: &[f64], rows: &[usize]) -> f64 {
    let pairs: Vec<(f64, f64)> = (rows.iter())
        .map(|&k| (a[k], b[k]))
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    let count = pairs.len().max(1) as f64;
    let (mean_a, mean_b) = pairs.iter().fold((0.0, 0.0), |(sa, sb), (x, y)| (sa + x, sb + y));
    let (mean_a, mean_b) = (mean_a / count, mean_b / count);
    let (mut ab, mut aa, mut bb) = (0.0, 0.0, 0.0);
    for (x, y) in &pairs {
        ab += (x - mean_a) * (y - mean_b);
        aa += (x - mean_a).powi(2);
        bb += (y - mean_b).powi(2);
    }
    match aa > 0.0 && bb > 0.0 {
        true => ab / (aa * bb).sqrt(),
        false => 0.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::tests::TestFlight;
    use crate::model::SourceTerm;

    /// A surrogate scored on the shifted flight built for the windows'
    /// rows scores what it scores on the flight shifted whole, to the bit,
    /// with a model whose lag, eddy τ, source rate and second-order term
    /// read beyond the windows.
    #[test]
    fn a_flight_shifted_on_the_windows_rows_scores_as_one_shifted_whole() {
        let flight = TestFlight::new(&[("cur_one", 7.0), ("cur_two", 23.0)]);
        let problem = flight.problem();
        let (log, windows, levels) = (&flight.log, &flight.windows, &flight.levels);
        let model = Model {
            lag_s: 0.15,
            eddy_tau_s: 0.3,
            second_order: true,
            sources: vec![
                SourceTerm::AuxCoupling {
                    column: "cur_one".into(),
                    level: levels["cur_one"],
                },
                SourceTerm::AuxCouplingRate {
                    column: "cur_one".into(),
                },
            ],
            ..Model::default()
        };
        let mut surrogate = model.clone();
        surrogate.sources.push(SourceTerm::AuxCoupling {
            column: "cur_two".into(),
            level: levels["cur_two"],
        });
        surrogate.sources.push(SourceTerm::AuxCouplingRate {
            column: "cur_two".into(),
        });
        let scanned: Vec<&String> = levels.keys().filter(|c| c.as_str() != "cur_one").collect();
        let shift = 3 * log.len() / 10;
        let stretches = crate::calibration::windows::merged_rows(windows, log.time_s());
        let part = shifted_flight(&problem, &scanned, shift, &stretches).unwrap();
        let whole_channels = log.channels().iter().map(|c| {
            let mut c = c.clone();
            if scanned.contains(&&c.name) {
                c.values.rotate_right(shift);
            }
            c
        });
        let whole = FlightLog::new(
            log.source(),
            log.time_column(),
            log.time_s().to_vec(),
            whole_channels.collect(),
        )
        .unwrap();
        let score = |log: &FlightLog| {
            let shifted = Problem { log, ..problem };
            held_out(&shifted, &surrogate).unwrap().rms_nt
        };
        let (on_rows, shifted_whole) = (score(&part), score(&whole));
        assert!(on_rows.is_finite() && on_rows > 0.0, "{on_rows}");
        assert_eq!(
            on_rows.to_bits(),
            shifted_whole.to_bits(),
            "{on_rows} against {shifted_whole}"
        );
    }
}
