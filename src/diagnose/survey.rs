//! A cross-sensor signal judged on the survey, which its fit never saw.
//!
//! A current no column records is switched, ramped and cycled through the
//! whole flight. On the box it is one effect among the manoeuvres, and the
//! witness sensors see it through their own projection of its field: on
//! the unrecorded-current campaign (`tests/diagnose_campaign.rs`) the
//! best signal took 15–40 % of the held-out residual on most flights,
//! short of the 30 % a finding needs there, or none. On the survey lines
//! the same current leaves the channel 0.4–3.7 nT from a quiet scalar, on
//! every line. Every cross-sensor finding states what the survey says of
//! it ([`SurveyEvidence`]), and under `[diagnose] cross_sensor = "survey"`
//! a candidate that lowers the box's held-out residual at all and takes
//! [`SURVEY_CROSS_GAIN`] or more of the channel's survey difference from a
//! quiet scalar the signal does not read, on more than half the lines, is
//! a finding too.
//!
//! The difference holds the geology between the two sensors (the tail is
//! metres from the cabin, a real gradient at survey height), and the
//! signal none where its sensors sit side by side; a quiet scalar the
//! signal reads is never the one measured against, since the term would
//! then carry that sensor's share of the geology into the difference. A
//! signal whose own sensors are metres apart carries such a gradient too,
//! and can lower the difference by standing in for it. On the 300 clean
//! plans of the default's safety campaign, under `"survey"`, cross-sensor
//! terms moved 35 of 1,344 channels: none harmed against the truth, 32
//! helped by more than 10 % (the cabin sensors share a residual of their
//! fits, which the term takes out). No source on board is there to name,
//! so the survey's word on a box-fitted signal is not the default's.
//!
//! The default's is a signal whose gain the survey itself fits, each line
//! held out of the fit of its own ([`survey_fitted`], [`SurveyFit`]):
//! the current is most of what the cabin sensors differ by on the
//! survey, where the box sees it in a few manoeuvres.

use super::*;
use crate::model::cross_sensor::CROSS_COLUMN_PREFIX;

/// The survey evidence for `after`, the channel's model with the cross
/// column `column` added to `before`: the channel's difference from the
/// quietest scalar (of `problem.quietest`) that is not one of the
/// signal's sensors and is quieter than the channel (against a busier one
/// the difference is that sensor's own residual: on a clean flight a tail
/// sensor judged against a cabin one took the cabin's in). `None` where
/// there is no such scalar, no survey line, or `column` is not a cross
/// column.
pub(super) fn survey_evidence(
    problem: &Problem,
    (before, after): (&Model, &Model),
    column: &str,
) -> Result<Option<SurveyEvidence>> {
    let Some((minuend, reference)) = column.strip_prefix(CROSS_COLUMN_PREFIX).and_then(|n| n.split_once('|')) else {
        return Ok(None);
    };
    let quieter = (problem.quietest.iter()).take_while(|q| q.as_str() != problem.channel);
    let Some(quiet) = quieter
        .into_iter()
        .find(|q| ![minuend, reference].contains(&q.as_str()))
    else {
        return Ok(None);
    };
    let lines = survey_line_rows(problem.log, problem.windows);
    if lines.len() < 2 {
        return Ok(None);
    }
    let without = compensated(problem, problem.channel, before)?;
    let with = compensated(problem, problem.channel, after)?;
    let quiet_values = compensated(problem, quiet, &Model::default())?;
    let difference = |values: &[f64], row: usize| values[row] - quiet_values[row];
    let usable = |row: &usize| difference(&without, *row).is_finite() && difference(&with, *row).is_finite();
    let lines: Vec<Vec<usize>> = (lines.into_iter())
        .map(|rows| rows.into_iter().filter(usable).collect::<Vec<_>>())
        .filter(|rows| rows.len() >= LEAST_LINE_ROWS)
        .collect();
    let all: Vec<usize> = lines.iter().flatten().copied().collect();
    if lines.len() < 2 {
        return Ok(None);
    }
    let mean = |values: &[f64]| all.iter().map(|&r| difference(values, r)).sum::<f64>() / all.len() as f64;
    let (centre_without, centre_with) = (mean(&without), mean(&with));
    let rms = |values: &[f64], centre: f64, rows: &[usize]| {
        (rows
            .iter()
            .map(|&r| (difference(values, r) - centre).powi(2))
            .sum::<f64>()
            / rows.len() as f64)
            .sqrt()
    };
    let lines_lower = (lines.iter())
        .filter(|rows| rms(&with, centre_with, rows) < rms(&without, centre_without, rows))
        .count();
    Ok(Some(SurveyEvidence {
        reference: quiet.clone(),
        before_nt: rms(&without, centre_without, &all),
        after_nt: rms(&with, centre_with, &all),
        lines_lower,
        lines: lines.len(),
    }))
}

/// The fewest usable rows a survey line is measured on.
const LEAST_LINE_ROWS: usize = 20;

/// The rows of each survey line of `log` outside every calibration window.
fn survey_line_rows(log: &FlightLog, windows: &[CalibrationWindow]) -> Vec<Vec<usize>> {
    let time = log.time_s();
    let mut in_windows = vec![false; log.len()];
    for window in windows {
        in_windows[window.rows(time)].fill(true);
    }
    (log.survey_lines().into_iter())
        .map(|(_, rows)| rows.into_iter().filter(|r| !in_windows[*r]).collect())
        .collect()
}

/// `channel` compensated on every row of the problem's log with `model`
/// fitted on its calibration windows.
fn compensated(problem: &Problem, channel: &str, model: &Model) -> Result<Vec<f64>> {
    let spec = ModelSpec::new(problem.terms, model.clone());
    let fitted = fit(
        problem.log,
        problem.sensor,
        channel,
        problem.windows,
        &spec,
        problem.options,
        problem.stores,
    )?;
    let prediction = fitted.predict(problem.log)?;
    Ok((prediction.scalar_nt.iter())
        .zip(&prediction.interference_nt)
        .map(|(scalar, interference)| scalar - interference)
        .collect())
}

/// The best of the `scored` cross-sensor candidates (at most
/// [`SURVEY_CHECKS`], each lowering the box's held-out RMS below
/// `current_nt`) that the survey bears out, by its difference after, with
/// its evidence.
pub(super) fn survey_step(
    problem: &Problem,
    (model, current_nt): (&Model, f64),
    scored: &[(Model, Extension, HeldOut)],
) -> Result<Option<(usize, SurveyEvidence)>> {
    let candidates: Vec<(usize, &str)> = (scored.iter().enumerate())
        .filter(|(_, (_, _, h))| h.rms_nt < current_nt)
        .filter_map(|(i, (_, extension, _))| match extension {
            Extension::Coupling { source } if super::cross::is_cross_column(source) => Some((i, source.as_str())),
            _ => None,
        })
        .take(SURVEY_CHECKS)
        .collect();
    let judged: Vec<Option<(usize, SurveyEvidence)>> = candidates
        .par_iter()
        .map(|&(i, column)| {
            let evidence = survey_evidence(problem, (model, &scored[i].0), column)?;

            Ok(evidence.filter(SurveyEvidence::holds).map(|e| (i, e)))
        })
        .collect::<Result<_>>()?;
    Ok(judged
        .into_iter()
        .flatten()
        .min_by(|a, b| a.1.after_nt.total_cmp(&b.1.after_nt)))
}

/// Cross-sensor candidates, best on the box first, that a step judges on
/// the survey.
const SURVEY_CHECKS: usize = 4;

/// A cross-sensor signal whose gain the survey fits: the channel's model
/// with $g\,s$ added ([`SourceTerm::CrossSensor`] with `survey_gain`),
/// the gain, and the survey's held-out evidence for it.
pub(super) struct SurveyFitted {
    /// The model with the term.
    pub(super) model: Model,
    /// The signal's name, `flux_a|mag_3_uc`.
    pub(super) name: String,
    /// g, nT at the channel per nT of the signal.
    pub(super) gain: f64,
    /// The difference from the quiet scalar, without the term and with it
    /// held out line by line.
    pub(super) evidence: SurveyEvidence,
}

/// The cross-sensor signal of `problem` whose gain, fitted on the survey
/// lines, takes the most of the channel's difference from the quietest
/// scalar (which must be quieter than the channel and not read by the
/// signal), held out line by line: each line's difference less the gain
/// fitted on the other lines, every line's difference and signal about
/// their own mean. It is taken where it passes [`SurveyFit::holds`] and
/// the model it makes, fitted on the box with the term subtracted, bears
/// it out on the whole survey. `None` where nothing does, or there is no
/// such scalar or survey.
///
/// A current no column records is switched, ramped and cycled through
/// the whole flight; on the box it is one effect among the manoeuvres and
/// a coupling fitted there misses it (it took 15–40 % of the held-out
/// residual on most flights of the unrecorded-current campaign). On the
/// survey it is most of what the cabin sensors differ by.
///
/// With `scalars` false only a fluxgate's magnitude is taken as the
/// signal's minuend: on the 300 clean plans of the default's safety
/// campaign, the difference of two other scalars was fitted on 8 channels
/// (the cabin sensors share a residual of their fits), a fluxgate's on 1,
/// which the survey's crossovers then refused.
pub(super) fn survey_fitted(problem: &Problem, model: &Model, scalars: bool) -> Result<Option<SurveyFitted>> {
    let Some(quiet) = problem.quietest.first().filter(|q| q.as_str() != problem.channel) else {
        return Ok(None);
    };
    let lines = survey_line_rows(problem.log, problem.windows);
    if lines.len() < LEAST_FIT_LINES {
        return Ok(None);
    }
    let candidates = candidates(problem, (model, quiet), scalars);
    if candidates.is_empty() {
        return Ok(None);
    }
    let channel = compensated(problem, problem.channel, model)?;
    let reference = compensated(problem, quiet, &Model::default())?;
    let difference: Vec<f64> = channel.iter().zip(&reference).map(|(c, r)| c - r).collect();
    let rate = crate::model::extensions::rate_of_change(&reference, problem.log.time_s());
    let mut fits: Vec<(String, SurveyFit)> = (candidates.into_iter())
        .filter_map(|(values, signal)| {
            let fit = SurveyFit::of((&difference, values, &rate), &lines)?;
            fit.holds().then(|| (signal.name(), fit))
        })
        .collect();
    fits.sort_by(|a, b| a.1.after_nt.total_cmp(&b.1.after_nt));
    let Some((name, fit)) = fits.into_iter().next() else {
        return Ok(None);
    };
    let column = format!("{CROSS_COLUMN_PREFIX}{name}");
    let Some(signal) = problem.signals.get(&column) else {
        return Ok(None);
    };
    let mut next = model.clone();
    next.sources.push(SourceTerm::CrossSensor {
        name: name.clone(),
        signal: signal.clone(),
        survey_gain: Some(fit.gain),
    });
    // Fitted on the box with the term subtracted, the model must still
    // take the share from the whole survey.
    let with = compensated(problem, problem.channel, &next)?;
    let whole = |values: &[f64]| line_rms(values, &reference, &lines);
    if whole(&with) > (1.0 - SURVEY_FIT_SHARE) * whole(&channel) {
        return Ok(None);
    }
    Ok(Some(SurveyFitted {
        model: next,
        name,
        gain: fit.gain,
        evidence: SurveyEvidence {
            reference: quiet.clone(),
            before_nt: fit.before_nt,
            after_nt: fit.after_nt,
            lines_lower: fit.lines_lower,
            lines: fit.lines,
        },
    }))
}

/// The cross columns of `problem` a survey gain is fitted to, with their
/// recipes: those the channel may take that do not read the reference
/// `quiet` and that `model` does not couple already; with `scalars`
/// false, only a fluxgate's magnitude as the minuend.
fn candidates<'p>(
    problem: &'p Problem,
    (model, quiet): (&Model, &str),
    scalars: bool,
) -> Vec<(&'p [f64], &'p crate::model::cross_sensor::CrossSignal)> {
    let in_model = |column: &str| {
        let name = column.strip_prefix(CROSS_COLUMN_PREFIX).unwrap_or(column);
        (model.sources.iter()).any(|s| s.column() == column || s.column() == name)
    };
    (problem.levels.keys())
        .filter(|column| !reads(column, quiet) && !in_model(column))
        .filter_map(|column| {
            let signal = problem.signals.get(column.as_str())?;
            let fluxgate = !problem.quietest.contains(&signal.minuend);
            let values = problem.log.channel(column)?.values.as_slice();
            (scalars || fluxgate).then_some((values, signal))
        })
        .collect()
}

/// Whether the cross column `column` reads the scalar `sensor`.
fn reads(column: &str, sensor: &str) -> bool {
    let Some((minuend, reference)) = column.strip_prefix(CROSS_COLUMN_PREFIX).and_then(|n| n.split_once('|')) else {
        return true;
    };
    minuend == sensor || reference == sensor
}

/// RMS of `values` less `reference` about each line's own mean, over the
/// finite rows of `lines`.
fn line_rms(values: &[f64], reference: &[f64], lines: &[Vec<usize>]) -> f64 {
    let (mut sum, mut count) = (0.0, 0usize);
    for rows in lines {
        let d: Vec<f64> = (rows.iter())
            .map(|&r| values[r] - reference[r])
            .filter(|v| v.is_finite())
            .collect();
        if d.is_empty() {
            continue;
        }
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        sum += d.iter().map(|v| (v - mean).powi(2)).sum::<f64>();
        count += d.len();
    }
    (sum / count.max(1) as f64).sqrt()
}

/// A signal's gain fitted on the survey, held out line by line.
#[derive(Debug, Clone, PartialEq)]
pub(super) struct SurveyFit {
    /// g over every line.
    pub(super) gain: f64,
    /// The difference's RMS about each line's mean, nT.
    pub(super) before_nt: f64,
    /// Each line less the gain fitted on the others, nT.
    pub(super) after_nt: f64,
    /// Lines that fall.
    pub(super) lines_lower: usize,
    /// Lines measured.
    pub(super) lines: usize,
    /// The share of the signal's variance the reference's along-track
    /// rate explains: a geology gradient between the signal's sensors.
    pub(super) geology_share: f64,
}

impl SurveyFit {
    /// The fit of `signal` to `difference` on the rows of each of `lines`
    /// where both and the reference's `rate` are finite, each about its
    /// line's mean; `None` with fewer than [`LEAST_FIT_LINES`] lines of
    /// [`LEAST_LINE_ROWS`] such rows, or no signal.
    pub(super) fn of((difference, signal, rate): (&[f64], &[f64], &[f64]), lines: &[Vec<usize>]) -> Option<SurveyFit> {
        let centred: Vec<[Vec<f64>; 3]> = (lines.iter())
            .filter_map(|rows| {
                let usable: Vec<usize> = (rows.iter().copied())
                    .filter(|&r| difference[r].is_finite() && signal[r].is_finite() && rate[r].is_finite())
                    .collect();
                (usable.len() >= LEAST_LINE_ROWS).then(|| [difference, signal, rate].map(|v| about_mean(v, &usable)))
            })
            .collect();
        if centred.len() < LEAST_FIT_LINES {
            return None;
        }
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        let per_line: Vec<[f64; 3]> = (centred.iter())
            .map(|[d, s, _]| [dot(d, s), dot(s, s), dot(d, d)])
            .collect();
        let total = |i: usize| per_line.iter().map(|l| l[i]).sum::<f64>();
        let (ds, ss, dd) = (total(0), total(1), total(2));
        if ss.is_nan() || ss <= 0.0 {
            return None;
        }
        let (mut after, mut lower) = (0.0, 0usize);
        for line in &per_line {
            let gain = (ds - line[0]) / (ss - line[1]);
            let left = line[2] - 2.0 * gain * line[0] + gain * gain * line[1];
            after += left;
            lower += usize::from(left < line[2]);
        }
        let rows = centred.iter().map(|[d, _, _]| d.len()).sum::<usize>() as f64;
        let (sr, rr) = (centred.iter()).fold((0.0, 0.0), |(sr, rr), [_, s, r]| (sr + dot(s, r), rr + dot(r, r)));
        Some(SurveyFit {
            gain: ds / ss,
            before_nt: (dd / rows).sqrt(),
            after_nt: (after.max(0.0) / rows).sqrt(),
            lines_lower: lower,
            lines: per_line.len(),
            geology_share: match rr > 0.0 {
                true => sr * sr / (rr * ss),
                false => 0.0,
            },
        })
    }

    /// Whether the survey bears the gain out: held out line by line the
    /// difference falls by [`SURVEY_FIT_SHARE`] or more, and by
    /// [`SURVEY_FIT_FLOOR_NT`] (what it takes, √(before² − after²)), on
    /// more than half the lines; and the signal is no geology gradient
    /// (the reference's along-track rate explains under
    /// [`GEOLOGY_SHARE`] of it).
    pub(super) fn holds(&self) -> bool {
        let taken = (self.before_nt.powi(2) - self.after_nt.powi(2)).max(0.0).sqrt();
        self.after_nt <= (1.0 - SURVEY_FIT_SHARE) * self.before_nt
            && taken >= SURVEY_FIT_FLOOR_NT
            && 2 * self.lines_lower > self.lines
            && self.geology_share < GEOLOGY_SHARE
    }
}

/// `values` on `rows`, less their mean there.
fn about_mean(values: &[f64], rows: &[usize]) -> Vec<f64> {
    let mean = rows.iter().map(|&r| values[r]).sum::<f64>() / rows.len() as f64;
    rows.iter().map(|&r| values[r] - mean).collect()
}

/// The fewest survey lines a gain is fitted on: each held out against at
/// least two others.
const LEAST_FIT_LINES: usize = 3;

/// The share of the channel's survey difference a survey-fitted signal
/// must take, held out.
pub(super) const SURVEY_FIT_SHARE: f64 = 0.25;

/// What it must take at least, nT RMS: on clean flights the cabin
/// sensors' shared residuals are hundredths of a nT.
pub(super) const SURVEY_FIT_FLOOR_NT: f64 = 0.1;

/// The share of a signal's variance on the survey the reference's
/// along-track rate may explain.
pub(super) const GEOLOGY_SHARE: f64 = 0.1;

/// The `cross_sensor` finding of a survey-fitted signal, with the box's
/// held-out RMS without the term and with it (`before_nt`, `after_nt`):
/// the box is not its evidence, and is stated for what it is.
pub(super) fn fitted_finding(problem: &Problem, fitted: &SurveyFitted, (before_nt, after_nt): (f64, f64)) -> Finding {
    let channel = problem.channel;
    let e = &fitted.evidence;
    let (minuend, reference) = fitted.name.split_once('|').unwrap_or((fitted.name.as_str(), ""));
    let explanation = format!(
        "{channel} carries interference its attitude terms cannot hold, and {minuend} less {reference} (their attitude part taken out, the geology cancelling between sensors a metre or two apart) sees it too: a source on board that varies on its own, such as a current no column records. Its gain, {:.3} nT per nT, is fitted on the survey lines: {channel}'s difference from {} falls from {:.3} to {:.3} nT RMS ({:+.0} %) with each line held out of the fit, lower on {} of {} lines. The box held out goes from {before_nt:.3} to {after_nt:.3} nT with it; a source that varies through the flight shows on the survey more than in the manoeuvres.",
        fitted.gain,
        e.reference,
        e.before_nt,
        e.after_nt,
        100.0 * (e.after_nt / e.before_nt - 1.0),
        e.lines_lower,
        e.lines,
    );
    Finding {
        effect: Effect::CrossSensor(CrossSensor {
            k: [0.0; 3],
            survey: Some(e.clone()),
            survey_gain: Some(fitted.gain),
        }),
        channel: channel.to_string(),
        source: Some(fitted.name.clone()),
        explanation,
        located: Vec::new(),
        heldout_rms_before_nt: before_nt,
        heldout_rms_after_nt: after_nt,
        not_applied: None,
        anomaly_gain: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic draws in [−1, 1) (SplitMix64), for noise the fit
    /// cannot know.
    struct Draw(u64);

    impl Draw {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            2.0 * ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64 - 1.0
        }
    }

    /// Eight lines of 400 rows: a switched current `current` (steps every
    /// 37 rows, a ramp between), a geology gradient `rate` (slow sines),
    /// and noise of `noise_nt`.
    fn lines() -> Vec<Vec<usize>> {
        (0..8).map(|l| (l * 400..(l + 1) * 400).collect()).collect()
    }

    fn series(seed: u64) -> (Vec<f64>, Vec<f64>, Vec<Vec<f64>>) {
        let mut draw = Draw(seed);
        let n = 3200;
        let current: Vec<f64> = (0..n)
            .map(|k| ((k / 37) % 3) as f64 + 0.002 * (k % 400) as f64)
            .collect();
        let rate: Vec<f64> = (0..n)
            .map(|k| (k as f64 / 61.0).sin() + 0.5 * (k as f64 / 23.0).cos())
            .collect();
        let noise: Vec<Vec<f64>> = (0..2).map(|_| (0..n).map(|_| draw.next()).collect()).collect();
        (current, rate, noise)
    }

    #[test]
    fn a_gain_the_survey_holds_is_fitted_and_held_out_line_by_line() {
        let lines = lines();
        for seed in [3_u64, 17, 101] {
            let (current, rate, noise) = series(seed);
            // The channel sees the current at −2.2 nT per nT of the signal,
            // and a geology difference the signal does not read.
            let signal: Vec<f64> = current.iter().zip(&noise[0]).map(|(c, e)| 0.4 * c + 0.01 * e).collect();
            let difference: Vec<f64> = (0..current.len())
                .map(|k| -2.2 * 0.4 * current[k] + 0.3 * rate[k] + 0.02 * noise[1][k])
                .collect();
            let fit = SurveyFit::of((&difference, &signal, &rate), &lines).unwrap();
            // Within 5 %: the geology difference leans on the fit where it
            // happens to follow the current.
            assert!((fit.gain + 2.2).abs() < 0.11, "seed {seed}: gain {}", fit.gain);
            assert!(fit.after_nt < 0.5 * fit.before_nt, "{fit:?}");
            assert_eq!((fit.lines, fit.lines_lower), (8, 8));
            assert!(fit.holds(), "{fit:?}");
        }
    }

    #[test]
    fn noise_a_geology_gradient_or_too_few_lines_is_no_survey_gain() {
        let lines = lines();
        let (current, rate, noise) = series(7);
        // A signal of noise alone takes nothing held out.
        let difference: Vec<f64> = current.iter().zip(&rate).map(|(c, r)| -0.9 * c + 0.3 * r).collect();
        let fit = SurveyFit::of((&difference, &noise[0], &rate), &lines).unwrap();
        assert!(!fit.holds(), "{fit:?}");
        // A signal that is the geology gradient between its sensors takes
        // the channel's gradient out, and is refused as geology.
        let difference: Vec<f64> = rate.iter().zip(&noise[1]).map(|(r, e)| 0.8 * r + 0.01 * e).collect();
        let gradient: Vec<f64> = rate.iter().zip(&noise[0]).map(|(r, e)| 0.2 * r + 0.01 * e).collect();
        let fit = SurveyFit::of((&difference, &gradient, &rate), &lines).unwrap();
        assert!(fit.after_nt < 0.5 * fit.before_nt && fit.geology_share > 0.9, "{fit:?}");
        assert!(!fit.holds());
        // A share below the floor: hundredths of a nT are a clean flight's.
        let small: Vec<f64> = current.iter().map(|c| 0.01 * c).collect();
        let fit = SurveyFit::of((&small, &current, &rate), &lines).unwrap();
        assert!(fit.after_nt < 0.1 * fit.before_nt && !fit.holds(), "{fit:?}");
        // Two lines hold no gain held out against the others.
        assert!(SurveyFit::of((&difference, &gradient, &rate), &lines[..2]).is_none());
    }
}
