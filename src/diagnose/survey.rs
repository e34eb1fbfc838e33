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
//! so the survey's word is not the default's.

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
