//! The prediction over realisations: each simulated flight of the plan
//! fitted and measured as `compensate` would, and each channel's figures
//! gathered over them.

use std::collections::BTreeMap;

use rayon::prelude::*;

use super::warnings::gap_words;
use super::{ChannelPrediction, PlannedManoeuvre, Spread};
use crate::config::Settings;
use crate::error::Result;
use crate::model::excitation::{analyse_design, Design, Excitation};
use crate::model::{fit, FittedModel, ModelSpec, SharedDesign};
use crate::numerics::stacked::StorePool;
use crate::simulate::scenario::Scenario;
use crate::simulate::{simulate, SimulatedFlight};

/// One channel of one realisation.
pub(super) struct Outcome {
    pub(super) channel: String,
    pub(super) fom: Option<(f64, f64, usize)>,
    pub(super) coefficient_sigma_nt: f64,
    pub(super) noise_nt: f64,
    pub(super) survey_error_nt: f64,
    /// The blocked jackknife's uncertainty away from the calibration, nT.
    pub(super) jackknife_sigma_nt: f64,
    /// RMS of the sigma column over the survey lines, nT.
    pub(super) sigma_column_nt: f64,
    pub(super) poorly_pinned: Vec<String>,
    /// The box's gaps the analysis names.
    pub(super) gaps: Vec<crate::model::excitation::Candidate>,
    pub(super) design: Option<Design>,
}

/// One simulated flight of the plan.
pub(super) struct Realisation {
    /// The manoeuvres flown, in order.
    pub(super) flown: Vec<PlannedManoeuvre>,
    pub(super) outcomes: Vec<Outcome>,
    pub(super) manoeuvres: usize,
    pub(super) calibration_s: f64,
}

/// Simulates and fits `scenario` once per seed, in parallel, in order.
pub(super) fn realise_all(scenario: &Scenario, seeds: &[u64], settings: &Settings) -> Result<Vec<Realisation>> {
    seeds
        .par_iter()
        .map(|&seed| {
            let mut scenario = scenario.clone();
            scenario.raw.seed = seed;
            let flight = simulate(&scenario)?;
            realise(&flight, settings)
        })
        .collect()
}

/// What `model` states of its compensation on `log`: the jackknife's
/// sigma outside the calibration, and the sigma column's RMS over the
/// survey lines (rows whose `line` is positive, the white noise
/// `noise_nt` added), nT; NaN for both without a jackknife.
fn stated_sigmas(
    log: &crate::ingest::flight_log::FlightLog,
    model: &FittedModel,
    (shared, line): (&[SharedDesign], &[f64]),
    noise_nt: f64,
) -> Result<(f64, f64)> {
    let Some(prediction) = model.prediction_sigma_with(log, shared)? else {
        return Ok((f64::NAN, f64::NAN));
    };
    let column: Vec<f64> = (0..line.len())
        .filter(|&i| line[i] > 0.0)
        .map(|i| prediction.relative_nt[i].hypot(noise_nt))
        .filter(|v| v.is_finite())
        .collect();
    Ok((
        crate::quality::uncertainty_of(log, model, &prediction).map_or(f64::NAN, |u| u.outside_calibration_sigma_nt),
        (column.iter().map(|v| v * v).sum::<f64>() / column.len() as f64).sqrt(),
    ))
}

/// One channel's outcome on a simulated flight: its quality figures, its
/// excitation analysis and the error of its compensated survey lines
/// against the flight's truth.
fn outcome(
    flight: &SimulatedFlight,
    (model, compensated): (&FittedModel, &crate::compensate::CompensatedChannel),
    design: Option<(Excitation, Design)>,
    (shared, line): (&[SharedDesign], &[f64]),
) -> Result<Outcome> {
    let log = &flight.log;
    let quality = crate::quality::assess_quality(log, model, compensated);
    let noise_nt = quality.white_noise_nt().unwrap_or(f64::NAN);
    let truth = flight.truth.earth_total_nt(&model.channel).unwrap_or_default();
    let (excitation, design) = design.unzip();
    let (jackknife_sigma_nt, sigma_column_nt) = stated_sigmas(log, model, (shared, line), noise_nt)?;
    Ok(Outcome {
        channel: model.channel.clone(),
        fom: quality
            .fom_before_nt
            .zip(quality.fom_after_nt)
            .map(|(b, a)| (b, a, quality.fom_manoeuvres)),
        coefficient_sigma_nt: excitation.as_ref().map_or(f64::NAN, |e| e.survey_sigma_nt),
        noise_nt,
        survey_error_nt: error_from_calibration_level(model, &compensated.values, truth, line),
        poorly_pinned: (excitation.iter())
            .flat_map(|e| e.terms.iter().filter(|t| t.poorly_pinned).map(|t| t.term.clone()))
            .collect(),
        gaps: (excitation.iter())
            .flat_map(|e| e.additions.iter().filter(|c| c.gap).cloned())
            .collect(),
        jackknife_sigma_nt,
        sigma_column_nt,
        design,
    })
}

/// Fits and measures one simulated flight as `compensate --plain` would,
/// on its planned manoeuvres.
fn realise(flight: &SimulatedFlight, settings: &Settings) -> Result<Realisation> {
    let log = &flight.log;
    let sensor = crate::pipeline::choose_vector_sensor(log, None)?;
    let windows = flight.truth.calibration_windows(settings.detect.window_margin_s);
    let stores = StorePool::new();
    let spec = ModelSpec::plain(settings.terms);
    let channels: Vec<String> = flight.truth.sensors.iter().map(|s| s.channel.clone()).collect();
    let models: Vec<FittedModel> = (channels.iter())
        .map(|channel| fit(log, &sensor, channel, &windows, &spec, &settings.fit, &stores))
        .collect::<Result<_>>()?;
    let shared = SharedDesign::of_models(log, &models);
    let designs: Vec<Option<(Excitation, Design)>> = (models.iter())
        .map(|model| analyse_design(log, &sensor, model, &windows, &settings.fit, (&stores, &shared)))
        .collect::<Result<_>>()?;
    let compensation = crate::compensate::compensate_with(log, &models, settings.level, &shared)?;
    let line = log.channel("line").map(|c| c.values.as_slice()).unwrap_or_default();
    let outcomes = (models.iter().zip(&compensation.channels).zip(designs))
        .map(|((model, compensated), design)| outcome(flight, (model, compensated), design, (&shared, line)))
        .collect::<Result<_>>()?;
    let manoeuvres = &flight.truth.manoeuvres;
    let calibration_s = match (manoeuvres.first(), manoeuvres.last()) {
        (Some(first), Some(last)) => last.t_end - first.t_start,
        _ => 0.0,
    };
    Ok(Realisation {
        outcomes,
        manoeuvres: manoeuvres.len(),
        flown: (manoeuvres.iter())
            .map(|m| PlannedManoeuvre {
                kind: m.kind,
                heading_deg: m.heading_deg,
            })
            .collect(),
        calibration_s,
    })
}

/// RMS over the survey lines (rows whose `line` is positive) of the
/// compensated value's error against the truth, less its mean over the
/// calibration windows' rows (the band-passed fit does not pin the
/// level), nT; NaN without such rows.
pub fn error_from_calibration_level(model: &FittedModel, compensated: &[f64], truth: &[f64], line: &[f64]) -> f64 {
    let error = |i: usize| match (compensated.get(i), truth.get(i)) {
        (Some(c), Some(t)) => c - t,
        _ => f64::NAN,
    };
    let calibration: Vec<f64> = (model.windows.iter())
        .flat_map(|w| w.flight_rows.iter().cloned().flatten())
        .map(error)
        .filter(|e| e.is_finite())
        .collect();
    let level = calibration.iter().sum::<f64>() / calibration.len() as f64;
    let survey: Vec<f64> = (0..line.len())
        .filter(|&i| line[i] > 0.0)
        .map(|i| error(i) - level)
        .filter(|e| e.is_finite())
        .collect();
    (survey.iter().map(|e| e * e).sum::<f64>() / survey.len() as f64).sqrt()
}

/// The predictions of every channel, from the realisations.
pub(super) fn predictions(
    realisations: &[Realisation],
    target_survey: Option<f64>,
    target_fom: Option<f64>,
) -> Vec<ChannelPrediction> {
    let Some(first) = realisations.first() else {
        return Vec::new();
    };
    (first.outcomes.iter().enumerate())
        .map(|(c, outcome)| channel_prediction(realisations, (c, outcome), (target_survey, target_fom)))
        .collect()
}

/// The words of each item `list` gives channel `c` on at least half the
/// realisations (items keyed, the words of the first kept), in key order.
fn held_by_most(
    realisations: &[Realisation],
    c: usize,
    list: &dyn Fn(&Outcome) -> Vec<(String, String)>,
) -> Vec<String> {
    let half = realisations.len().div_ceil(2);
    let mut counts: BTreeMap<String, (usize, String)> = BTreeMap::new();
    for r in realisations {
        for (key, words) in list(&r.outcomes[c]) {
            counts.entry(key).or_insert((0, words)).0 += 1;
        }
    }
    (counts.into_values())
        .filter(|(n, _)| *n >= half)
        .map(|(_, words)| words)
        .collect()
}

/// Channel `c`'s prediction (its `outcome` on the first realisation names
/// it): each figure's spread over the realisations, what most of them
/// leave poorly pinned or missing, and the targets met.
fn channel_prediction(
    realisations: &[Realisation],
    (c, outcome): (usize, &Outcome),
    (target_survey, target_fom): (Option<f64>, Option<f64>),
) -> ChannelPrediction {
    let figure = |f: &dyn Fn(&Outcome) -> f64| Spread::of(realisations.iter().map(|r| f(&r.outcomes[c])));
    let majority = |list: &dyn Fn(&Outcome) -> Vec<(String, String)>| held_by_most(realisations, c, list);
    let uncertain_flights = (realisations.iter())
        .filter(|r| r.outcomes[c].jackknife_sigma_nt > crate::quality::UNCERTAINTY_WARNING_NT)
        .count();
    let gap_labels = majority(&|o| o.gaps.iter().map(|g| (g.label(), g.label())).collect());
    let fom_nt = figure(&|o| o.fom.map_or(f64::NAN, |f| f.1));
    let survey_sigma_nt = figure(&|o| o.coefficient_sigma_nt.hypot(o.noise_nt));
    ChannelPrediction {
        channel: outcome.channel.clone(),
        fom_before_nt: figure(&|o| o.fom.map_or(f64::NAN, |f| f.0)),
        fom_nt,
        fom_manoeuvres: median_of(
            realisations
                .iter()
                .map(|r| r.outcomes[c].fom.map_or(0.0, |f| f.2 as f64)),
        ) as usize,
        survey_sigma_nt,
        coefficient_sigma_nt: figure(&|o| o.coefficient_sigma_nt),
        noise_nt: figure(&|o| o.noise_nt),
        survey_error_nt: figure(&|o| o.survey_error_nt),
        jackknife_sigma_nt: figure(&|o| o.jackknife_sigma_nt),
        sigma_column_nt: figure(&|o| o.sigma_column_nt),
        uncertain_flights,
        poorly_pinned: majority(&|o| o.poorly_pinned.iter().map(|t| (t.clone(), t.clone())).collect()),
        gaps: gap_labels
            .iter()
            .map(|label| gap_words(realisations, c, label))
            .collect(),
        gap_labels,
        meets_fom_target: target_fom.map(|t| fom_nt.median <= t),
        meets_survey_target: target_survey.map(|t| survey_sigma_nt.median <= t),
    }
}

/// The median of the finite values; NaN without one.
pub(super) fn median_of(values: impl IntoIterator<Item = f64>) -> f64 {
    Spread::of(values.into_iter().filter(|v| v.is_finite())).median
}

/// Channel `channel`'s noise in realisation `r`.
pub(super) fn noise_of(r: &Realisation, channel: &str) -> f64 {
    r.outcomes
        .iter()
        .find(|o| o.channel == channel)
        .map_or(f64::NAN, |o| o.noise_nt)
}
