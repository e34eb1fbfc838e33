//! The model of one scalar channel's aircraft interference, and its one
//! fit path.
//!
//! A [`ModelSpec`] says what is fitted: the Tolles-Lawson terms
//! ([`TermSet`]) and the physics a diagnosis adds to them ([`Extensions`]:
//! fluxgate calibration, sensor lag, eddy time constant, the total field's
//! second-order term, source columns). Plain Tolles-Lawson is
//! [`ModelSpec::default`], or [`ModelSpec::plain`] with other terms.
//!
//! [`fit`] fits a spec on calibration windows. For every window, the rows
//! where the scalar, the vector magnetometer and every extension column
//! are valid are split into contiguous runs; each run's design columns and
//! scalar are band-passed on their own and trimmed, and the runs stacked
//! ([`band`]). The regularised solve ([`crate::numerics::solve`]) picks λ by PRESS,
//! each window one fold of the blocked PRESS:
//!
//! $$ \hat\beta = \arg\min_\beta \|y - A\beta\|^2 + \lambda \|\beta\|^2 $$
//!
//! with A the band-passed terms and extension columns and y the
//! band-passed scalar (nT). With the second-order term the scalar less the
//! term of one fit is fitted again, [`SECOND_ORDER_PASSES`] times.
//!
//! The [`FittedModel`] predicts the interference $A\beta$ on every row of a
//! flight with the same columns ([`FittedModel::predict`]): compensation
//! subtracts it. It also gives its band-passed residual on windows it was
//! not fitted on ([`FittedModel::held_out`]): the transfer check and the
//! diagnosis score models by it. Diagnosis, transfer check, replay and
//! compensation all go through these three functions.
//!
//! The Earth's own main field, which the aircraft's interference rides
//! on, is modelled by the IGRF ([`igrf`]): the IGRF-reduced columns, the
//! fluxgate's orientation and the simulated flights take it from there.

pub mod anomaly_gain;
pub mod band;
pub mod cross_sensor;
pub mod excitation;
pub mod extensions;
pub mod igrf;
mod prepared;
pub mod station;
pub mod terms;

use std::borrow::Cow;
use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::calibration::windows::CalibrationWindow;
use crate::error::{Error, Result};
use crate::ingest::flight_log::{FlightLog, VectorSensor};
use crate::model::terms::{DesignMatrix, EddyTerms, TermSet};
use crate::numerics::estimators::{Estimator, Family, Solver};
use crate::numerics::segments::valid_runs;
use crate::numerics::solve::{Solution, SolveOptions};
use crate::numerics::stacked::StorePool;

pub use crate::calibration::windows::Calibration;
pub use anomaly_gain::{AnomalyGain, GainRows, ANOMALY_GAIN_TOLERANCE};
pub use band::{design_filter, window_filterable, FilterSettings, FitMagnitude, FitOptions, WindowFit, CUT_BY_GAPS};
pub use extensions::{
    advanced, column_level, field_directions, rate_of_change, second_order_term, Extensions, SourceTerm,
    SECOND_ORDER_PASSES,
};
pub(crate) use prepared::{ExtraColumn, Prepared};

/// What is fitted for one scalar channel: the Tolles-Lawson terms and the
/// physics added to them.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ModelSpec {
    /// Tolles-Lawson terms (`[fit] terms`).
    pub terms: TermSet,
    /// Physics added to the terms (a diagnosis); default: none.
    #[serde(skip_serializing_if = "Extensions::is_plain", default)]
    pub extensions: Extensions,
}

impl ModelSpec {
    /// Plain Tolles-Lawson on `terms`.
    pub fn plain(terms: TermSet) -> Self {
        ModelSpec {
            terms,
            extensions: Extensions::default(),
        }
    }

    /// `terms` with `extensions`.
    pub fn new(terms: TermSet, extensions: Extensions) -> Self {
        ModelSpec { terms, extensions }
    }

    /// The model of `channel`: `terms` with the channel's extensions in
    /// `plan`, plain Tolles-Lawson where the plan has none.
    pub fn of_channel(terms: TermSet, plan: &BTreeMap<String, Extensions>, channel: &str) -> Self {
        ModelSpec::new(terms, plan.get(channel).cloned().unwrap_or_default())
    }

    /// Plain Tolles-Lawson: nothing added to the terms.
    pub fn is_plain(&self) -> bool {
        self.extensions.is_plain()
    }

    /// The Tolles-Lawson terms fitted: with an eddy time constant, the nine
    /// instantaneous eddy terms give way to their lagged versions, which
    /// are extension columns.
    pub fn fitted_terms(&self) -> TermSet {
        let mut terms = self.terms;
        if self.extensions.eddy_tau_s > 0.0 {
            terms.eddy = EddyTerms::None;
        }
        terms
    }

    /// The solve settings: `solve` with λ picked by the model's own
    /// criterion when it has one.
    pub fn solve_options(&self, solve: &SolveOptions) -> SolveOptions {
        let mut solve = solve.clone();
        if let Some(criterion) = self.extensions.lambda_criterion {
            solve.criterion = criterion;
        }
        solve
    }

    /// One line for people: what the model adds to Tolles-Lawson.
    pub fn describe(&self) -> String {
        self.extensions.describe()
    }
}

/// How uncertain a model's prediction is, row by row, from the blocked
/// jackknife of its coefficients ([`FittedModel::prediction_sigma`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PredictionSigma {
    /// One sigma of the prediction relative to its mean over the
    /// calibration windows, per row, nT.
    pub relative_nt: Vec<f64>,
    /// One sigma of the prediction's mean over the calibration windows, nT.
    pub level_nt: f64,
    /// Each jackknife deviation's prediction, mean over the calibration
    /// windows' rows, nT ([`CalibrationLevel::jackknife_nt`]).
    pub levels_nt: Vec<f64>,
}

/// A model's level over the calibration it was fitted on, kept with it so
/// that a flight without that calibration (a survey flight given the
/// model with `--apply`) is compensated to the same level, with the same
/// sigma column, as the calibration flight itself.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationLevel {
    /// Mean of the predicted interference $A\beta$ over the calibration
    /// windows' rows, nT: the level offset δ of
    /// [`crate::compensate::LevelConvention::CalibrationMean`].
    pub interference_nt: f64,
    /// Each jackknife deviation's prediction $a_i \cdot d_f$, mean over
    /// the rows the fit used, nT: the level the sigma column's spread is
    /// measured from ([`FittedModel::prediction_sigma`]); empty without a
    /// jackknife.
    pub jackknife_nt: Vec<f64>,
}

/// A fitted model of one scalar channel; it predicts the interference.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FittedModel {
    /// Scalar channel the model compensates.
    pub channel: String,
    /// Vector magnetometer prefix the terms are built from.
    pub vector_sensor: String,
    /// What was fitted.
    pub spec: ModelSpec,
    /// Term names, one per coefficient: the fitted terms, then the
    /// extension columns.
    pub term_names: Vec<String>,
    /// Coefficients, nT per unit term.
    pub coefficients: Vec<f64>,
    /// Filter applied before fitting.
    pub filter: FilterSettings,
    /// Sample rate used to design the filter, Hz.
    pub sample_rate_hz: f64,
    /// Solver diagnostics: method, λ, PRESS curves, singular values.
    pub solution: Solution,
    /// One-sigma uncertainty of each coefficient: the solver's white-noise
    /// standard error times $\sqrt{f_s / 2B}$, because a residual of
    /// bandwidth B holds only 2B independent samples a second (Nyquist).
    pub coefficient_uncertainty: Vec<f64>,
    /// Per-window use of the data.
    pub windows: Vec<WindowFit>,
    /// Every estimator of the family on the same design and windows, each
    /// held out heading by heading ([`compare_estimators`]); set by the
    /// pipeline for the models it compensates with, `None` elsewhere or
    /// with fewer than three headings.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estimators: Option<Vec<crate::numerics::estimators::Scored>>,
    /// How well the manoeuvres flown pin each coefficient, and which
    /// manoeuvre would pin them better ([`excitation::analyse`]); set by
    /// the pipeline for the models it compensates with.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub excitation: Option<excitation::Excitation>,
    /// The estimator the coefficients come from when `[fit] solver` is not
    /// ridge; `None` with ridge (the solution says which λ or rank).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub solver: Option<SolverUse>,
    /// The model's level over its calibration; set by the pipeline once
    /// the flight is compensated, and read from the model JSON with the
    /// model (`--apply`), when the calibration windows are another
    /// flight's. `None`: measured on [`Self::windows`] of the flight given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration_level: Option<CalibrationLevel>,
}

/// How a model fitted with a `[fit] solver` other than ridge was solved.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SolverUse {
    /// The solver asked for.
    pub requested: Solver,
    /// The family used; `None` when the fit fell back to ridge.
    pub family: Option<Family>,
    /// Its setting, chosen leaving one heading out.
    pub estimator: Option<Estimator>,
    /// Its held-out RMS leaving one heading out, nT.
    pub heldout_rms: Option<f64>,
    /// In words: what was used and why.
    pub reason: String,
}

impl SolverUse {
    /// Whether the requested solver was used (not the ridge fallback).
    pub fn applied(&self) -> bool {
        self.estimator.is_some()
    }
}

/// Every estimator of the family (least squares, ridge, TSVD, damped
/// TSVD, TLS, truncated TLS) on the design of `spec` over `windows`, each
/// with its rank or λ chosen and scored by leaving one heading out, so a
/// user sees which the data favour. `None` when the windows span fewer
/// than three headings.
pub fn compare_estimators(
    log: &FlightLog,
    sensor: &VectorSensor,
    channel: &str,
    windows: &[CalibrationWindow],
    spec: &ModelSpec,
    options: &FitOptions,
    stores: &StorePool,
) -> Result<Option<Vec<crate::numerics::estimators::Scored>>> {
    Prepared::new(log, sensor, channel, spec)?.compare_estimators(windows, options, stores)
}

/// Fits `spec` to scalar `channel` on `windows`, the terms built from
/// `sensor`. The one fit of every model kind. The stacked data's memory
/// comes from and goes back to `stores`: fits that share a pool (the
/// channels of a flight, the folds of a check) reuse it instead of
/// touching fresh pages each time.
pub fn fit(
    log: &FlightLog,
    sensor: &VectorSensor,
    channel: &str,
    windows: &[CalibrationWindow],
    spec: &ModelSpec,
    options: &FitOptions,
    stores: &StorePool,
) -> Result<FittedModel> {
    Prepared::new(log, sensor, channel, spec)?.fit(windows, options, stores)
}

/// The term names a model of `spec` for `channel` fits, in coefficient
/// order: the Tolles-Lawson terms, then the extension columns; an error
/// when `log` lacks a column the spec takes.
pub fn term_names(log: &FlightLog, sensor: &VectorSensor, channel: &str, spec: &ModelSpec) -> Result<Vec<String>> {
    let prepared = Prepared::new(log, sensor, channel, spec)?;
    Ok((spec.fitted_terms().names().into_iter())
        .chain(prepared.extra.iter().map(|c| c.name.clone()))
        .collect())
}

/// Which of the columns of a model of `spec` are per sample, in
/// coefficient order: a central difference per sample (the eddy-current
/// terms, lagged or not, and the field's derivative), whose coefficient
/// holds the sample rate it was fitted at; at another rate the same
/// physics takes the coefficient times the rates' ratio. Decided from the
/// spec, not from the names, which a source column's name could mimic;
/// the source columns after them are not per sample.
pub fn per_sample_columns(spec: &ModelSpec) -> Vec<bool> {
    use crate::model::terms::{EddyTerms, TermSet};
    let terms = spec.fitted_terms();
    let without = |t: TermSet| t.len();
    let (eddy, derivative) = (terms.eddy != EddyTerms::None, terms.field_derivative);
    // The terms in their order: permanent, induced, eddy, derivative, bias.
    let before_eddy = without(TermSet {
        eddy: EddyTerms::None,
        field_derivative: false,
        bias: false,
        ..terms
    });
    let eddy_count = without(TermSet {
        field_derivative: false,
        bias: false,
        ..terms
    }) - before_eddy;
    let derivative_count = if derivative { 3 } else { 0 };
    let mut columns = vec![false; before_eddy];
    columns.extend(std::iter::repeat_n(eddy, eddy_count));
    columns.extend(std::iter::repeat_n(true, derivative_count));
    columns.extend(std::iter::repeat_n(false, terms.len() - columns.len()));
    if spec.extensions.eddy_tau_s > 0.0 {
        columns.extend([true; 9]);
    }
    columns
}

/// A model's prediction over a whole flight.
#[derive(Debug, Clone, PartialEq)]
pub struct Prediction<'a> {
    /// The scalar as the model reads it: the record, read `lag_s` earlier
    /// when the sensor lags, nT.
    pub scalar_nt: Cow<'a, [f64]>,
    /// The aircraft's interference $A\beta$ on every row, nT (`NaN` where
    /// an input is missing). A base station's variation is not part of
    /// it (see [`FittedModel::predict`]).
    pub interference_nt: Vec<f64>,
}

impl FittedModel {
    /// The band-passed residual of the model on `windows`, which it need
    /// not have been fitted on: held-out figures for the transfer check
    /// and the diagnosis.
    pub fn held_out(
        &self,
        log: &FlightLog,
        sensor: &VectorSensor,
        windows: &[CalibrationWindow],
        options: &FitOptions,
    ) -> Result<Vec<WindowFit>> {
        Prepared::new(log, sensor, &self.channel, &self.spec)?.held_out(self, windows, options, &StorePool::new())
    }

    /// The interference on every row of `log`, with the terms' time
    /// derivatives taken inside contiguous runs of valid vector samples.
    /// A base station's variation is subtracted before the fit (so it
    /// does not bias the aircraft's coefficients) but not predicted: it is
    /// the Earth's field, which the compensated channel keeps. A flight that lacks the model's channel, vector sensor or
    /// source columns (a model fitted on another flight) is an error.
    pub fn predict<'a>(&self, log: &'a FlightLog) -> Result<Prediction<'a>> {
        self.predict_with(log, &[])
    }

    /// [`Self::predict`], taking the terms from `shared` when it holds
    /// this model's (vector sensor, fitted terms) and the model does not
    /// recalibrate the fluxgate.
    pub(crate) fn predict_with<'a>(&self, log: &'a FlightLog, shared: &[SharedDesign]) -> Result<Prediction<'a>> {
        let sensor = self.sensor_in(log)?;
        let prepared = Prepared::new(log, &sensor, &self.channel, &self.spec)?;
        // The record as the model reads it, the base station's variation
        // kept (the fit's target is without it).
        let scalar_nt = match self.spec.extensions.lag_s {
            0.0 => Cow::Borrowed(prepared::scalar_values(log, &self.channel)?),
            lag_s => Cow::Owned(crate::model::extensions::advanced(
                prepared::scalar_values(log, &self.channel)?,
                log.time_s(),
                lag_s,
            )),
        };
        let terms = self.spec.fitted_terms();
        let design = self.terms_design(shared, &prepared.log, &sensor);
        let (term_part, extra_part) = self
            .coefficients
            .split_at(design.columns.len().min(self.coefficients.len()));
        let aircraft: Vec<(&[f64], f64)> = (prepared.extra.iter().zip(extra_part))
            .map(|(c, b)| (c.values.as_slice(), *b))
            .collect();
        let mut interference_nt: Vec<f64> = (0..log.len())
            .map(|row| design.predict_row(row, term_part) + aircraft.iter().map(|(c, b)| c[row] * b).sum::<f64>())
            .collect();
        if self.spec.extensions.second_order {
            let term = second_order_term(prepared.log.vector_components(&sensor), &terms, &self.coefficients);
            for (h, q) in interference_nt.iter_mut().zip(&term) {
                *h += q;
            }
        }
        // A survey-fitted cross-sensor term is the aircraft's, unlike a
        // base station's record.
        if let Some(part) = prepared::survey_fitted_part(&prepared.log, &self.spec.extensions.sources)? {
            for (h, p) in interference_nt.iter_mut().zip(&part) {
                *h += p;
            }
        }
        Ok(Prediction {
            scalar_nt,
            interference_nt,
        })
    }

    /// The uncertainty of the predicted interference, from the blocked
    /// jackknife of the coefficients
    /// ([`crate::numerics::solve::Solution::jackknife`]); `None` without one
    /// (fewer than three windows). For each deviation $d_f$ the prediction
    /// $p_f(i) = a_i \cdot d_f$ ($a_i$ the row's design: terms and aircraft
    /// source columns) splits into its mean over the calibration windows'
    /// rows, $\bar p_f$ (the level, which the band-passed fit does not pin),
    /// and the rest:
    /// - per row, $\sqrt{\sum_f (p_f(i) - \bar p_f)^2}$: one sigma of the
    ///   compensated value relative to its level over the calibration, nT
    ///   (`NaN` where the prediction is missing);
    /// - $\sqrt{\sum_f \bar p_f^2}$: one sigma of that level, nT.
    ///
    /// The second-order term's share is left out.
    pub fn prediction_sigma(&self, log: &FlightLog) -> Result<Option<PredictionSigma>> {
        self.prediction_sigma_with(log, &[])
    }

    /// Each jackknife deviation's mean change over the calibration
    /// windows' rows (its level there), `predict(row, deviation)` its
    /// change on a row; rows where it is not finite left out.
    fn calibration_levels(&self, predict: &dyn Fn(usize, &[f64]) -> f64) -> Vec<f64> {
        let calibration: Vec<usize> = (self.windows.iter())
            .flat_map(|w| w.flight_rows.iter().cloned().flatten())
            .collect();
        (self.solution.jackknife.iter())
            .map(|d| {
                let (sum, n) = (calibration.iter())
                    .map(|&row| predict(row, d))
                    .filter(|v| v.is_finite())
                    .fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
                sum / n.max(1) as f64
            })
            .collect()
    }

    /// [`Self::prediction_sigma`], taking the terms from `shared` when it
    /// holds this model's (see [`SharedDesign`]).
    pub fn prediction_sigma_with(&self, log: &FlightLog, shared: &[SharedDesign]) -> Result<Option<PredictionSigma>> {
        let deviations = &self.solution.jackknife;
        if deviations.is_empty() {
            return Ok(None);
        }
        let columns = self.flight_columns(log, shared)?;
        let aircraft: Vec<(usize, &[f64])> = (columns.iter().enumerate()).map(|(k, c)| (k, c.as_ref())).collect();
        let predict = |row: usize, d: &[f64]| aircraft.iter().map(|(k, c)| c[row] * d[*k]).sum::<f64>();
        let levels: Vec<f64> = match &self.calibration_level {
            Some(saved) => saved.jackknife_nt.clone(),
            None => self.calibration_levels(&predict),
        };
        if levels.len() != deviations.len() {
            return Err(Error::ModelMismatch {
                model: format!("the model of '{}'", self.channel).into(),
                flight: log.source().to_path_buf(),
                problem: format!(
                    "it holds {} jackknife deviations and {} calibration levels for them",
                    deviations.len(),
                    levels.len()
                ),
                hint: "Save the model again from its calibration flight (--model)".into(),
            });
        }
        // Row blocks, a column at a time: the columns are read in order,
        // not across 18 arrays a row.
        let mut relative_nt = Vec::with_capacity(log.len());
        let mut predicted = vec![0.0; deviations.len() * SIGMA_BLOCK_ROWS];
        for start in (0..log.len()).step_by(SIGMA_BLOCK_ROWS) {
            let len = SIGMA_BLOCK_ROWS.min(log.len() - start);
            predicted.fill(0.0);
            for (k, column) in &aircraft {
                let column = &column[start..start + len];
                for (f, d) in deviations.iter().enumerate() {
                    let slot = &mut predicted[f * SIGMA_BLOCK_ROWS..f * SIGMA_BLOCK_ROWS + len];
                    let weight = d[*k];
                    for (p, c) in slot.iter_mut().zip(column) {
                        *p += c * weight;
                    }
                }
            }
            relative_nt.extend((0..len).map(|i| {
                (levels.iter().enumerate())
                    .map(|(f, level)| (predicted[f * SIGMA_BLOCK_ROWS + i] - level).powi(2))
                    .sum::<f64>()
                    .sqrt()
            }));
        }
        Ok(Some(PredictionSigma {
            relative_nt,
            level_nt: levels.iter().map(|l| l * l).sum::<f64>().sqrt(),
            levels_nt: levels,
        }))
    }

    /// The columns the model predicts from over the whole of `log`, one
    /// per coefficient: the fitted terms (derivatives inside runs of valid
    /// vector samples; borrowed from `shared` when it holds them), then
    /// the extension columns.
    pub(crate) fn flight_columns<'s>(
        &self,
        log: &FlightLog,
        shared: &'s [SharedDesign],
    ) -> Result<Vec<Cow<'s, [f64]>>> {
        let sensor = self.sensor_in(log)?;
        let prepared = Prepared::new(log, &sensor, &self.channel, &self.spec)?;
        let terms = self.spec.fitted_terms();
        let design: Vec<Cow<'s, [f64]>> = match self.shared_design(shared, &terms) {
            Some(design) => design.columns.iter().map(|c| Cow::Borrowed(c.as_slice())).collect(),
            None => (design_matrix(&prepared.log, &sensor, &terms).columns.into_iter())
                .map(Cow::Owned)
                .collect(),
        };
        Ok((design.into_iter())
            .chain(prepared.extra.into_iter().map(|c| Cow::Owned(c.values)))
            .collect())
    }

    /// The design in `shared` of this model's (vector sensor, fitted
    /// `terms`), when it has one and the model does not recalibrate the
    /// fluxgate (its terms are then of the calibrated field).
    fn shared_design<'s>(&self, shared: &'s [SharedDesign], terms: &TermSet) -> Option<&'s DesignMatrix> {
        let reusable = self.spec.extensions.vector_calibration.is_none();
        (shared.iter())
            .find(|s| reusable && s.sensor == self.vector_sensor && s.terms == *terms)
            .map(|s| &s.design)
    }

    /// The model's fitted terms on every row of `log` (the flight as its
    /// preparation made it): `shared`'s where it holds them, else built.
    fn terms_design<'s>(
        &self,
        shared: &'s [SharedDesign],
        log: &FlightLog,
        sensor: &VectorSensor,
    ) -> Cow<'s, DesignMatrix> {
        let terms = self.spec.fitted_terms();
        match self.shared_design(shared, &terms) {
            Some(design) => Cow::Borrowed(design),
            None => Cow::Owned(design_matrix(log, sensor, &terms)),
        }
    }

    /// The model's vector sensor in `log`; an error when `log` lacks it
    /// or the scalar channel.
    fn sensor_in(&self, log: &FlightLog) -> Result<VectorSensor> {
        let sensor = log.vector_sensor(&self.vector_sensor);
        let missing = match (log.channel(&self.channel), &sensor) {
            (None, _) => ("scalar magnetometer", &self.channel),
            (_, None) => ("vector magnetometer", &self.vector_sensor),
            (Some(_), Some(sensor)) => return Ok(sensor.clone()),
        };
        Err(Error::MissingColumn {
            path: log.source().to_path_buf(),
            role: missing.0,
            looked_for: format!("'{}', which the model of '{}' uses", missing.1, self.channel),
            hint: "Compensate with models fitted on this flight's own channels.".into(),
        })
    }
}

/// Rows of the sigma column computed at a time.
const SIGMA_BLOCK_ROWS: usize = 256;

/// The Tolles-Lawson columns of one (vector sensor, terms) over a whole
/// flight, built once for every model that uses them: the excitation
/// analysis, the compensation and the sigma column of every channel read
/// the same columns.
#[derive(Debug, Clone)]
pub struct SharedDesign {
    sensor: String,
    terms: TermSet,
    design: DesignMatrix,
}

impl SharedDesign {
    /// One design per distinct (vector sensor, fitted terms) of the
    /// models that read the recorded fluxgate.
    pub fn of_models(log: &FlightLog, models: &[FittedModel]) -> Vec<SharedDesign> {
        let mut shared: Vec<SharedDesign> = Vec::new();
        for model in models.iter().filter(|m| m.spec.extensions.vector_calibration.is_none()) {
            let terms = model.spec.fitted_terms();
            if shared
                .iter()
                .any(|s| s.sensor == model.vector_sensor && s.terms == terms)
            {
                continue;
            }
            let Some(sensor) = log.vector_sensor(&model.vector_sensor) else {
                continue;
            };
            shared.push(SharedDesign {
                design: design_matrix(log, &sensor, &terms),
                sensor: model.vector_sensor.clone(),
                terms,
            });
        }
        shared
    }
}

/// `terms` over the whole flight, derivatives taken inside runs of valid
/// vector samples.
fn design_matrix(log: &FlightLog, sensor: &VectorSensor, terms: &TermSet) -> DesignMatrix {
    let field = log.vector_components(sensor);
    let valid: Vec<bool> = (0..log.len()).map(|i| field.iter().all(|c| c[i].is_finite())).collect();
    let runs = valid_runs(log.time_s(), &valid, 0..log.len(), log.median_interval_s());
    terms.design_matrix(field, &runs)
}
