//! Calibrate once, apply everywhere: a model saved from the flight that
//! flew the calibration box (`--model MODEL.json`) compensates the survey
//! flights of the same aircraft, which fly no box (`--apply MODEL.json`,
//! `[[flight]] model`, a campaign manifest's `model` column).
//!
//! Nothing is refitted. Each channel's coefficients, extensions (lag,
//! eddy τ, sources, fluxgate calibration) and blocked jackknife come from
//! the file, and so does the model's level over its own calibration
//! ([`crate::model::CalibrationLevel`]): the survey flight is compensated
//! to the level the calibration flight would have given it, and its sigma
//! column spreads from the same level. Applied to the very flight it was
//! fitted on, a model gives that flight's compensated columns again, bit
//! for bit.
//!
//! A model is refused, with the reason, when the flight lacks one of its
//! channels, its fluxgate or a source column, or when the file is not a
//! magcomp model or predates the saved calibration level. It is applied
//! with a warning when it is older than `[model] max_age_days`, belongs to
//! another aircraft, or was fitted at another sample rate: its per-sample
//! coefficients (the eddy-current terms and the field's derivative, a
//! central difference per sample) then take the rates' ratio, the same
//! physics at the flight's rate.
//! When the flight names manoeuvres of its own (windows or calibration
//! lines), the model is held out on them: the FOM and improvement ratio are
//! then this flight's, of a model that never saw it.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::diagnose::AppliedFinding;
use crate::error::{Error, Result};
use crate::ingest::flight_date::FlightDate;
use crate::ingest::flight_identity::FlightIdentity;
use crate::ingest::flight_log::FlightLog;
use crate::messages::{Note, Warning};
use crate::model::{CalibrationLevel, FittedModel, ModelSpec};
use crate::numerics::solve::{Decomposition, Method, Solution};
use crate::quality::ChannelQuality;

/// "3 days before this flight": kept here for callers of
/// `pipeline::apply::days_from`; the sentences that use it are in
/// [`crate::messages`].
pub use crate::messages::days_from;

/// The sample rate of the flight may differ from the model's by this
/// fraction: clocks of one recorder differ by far less, and another rate
/// is another recorder setting.
const RATE_TOLERANCE: f64 = 0.01;

/// A channel's figures on the flight its model was fitted on, as the model
/// JSON keeps them: what the survey flights' quality JSON and report quote.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationFigures {
    /// Scalar channel.
    pub channel: String,
    /// FOM before compensation over the calibration box, nT.
    #[serde(default)]
    pub fom_before_nt: Option<f64>,
    /// FOM after compensation, nT.
    #[serde(default)]
    pub fom_after_nt: Option<f64>,
    /// Manoeuvres summed in the FOM (12 for a whole box).
    #[serde(default)]
    pub fom_manoeuvres: usize,
    /// Improvement ratio over the calibration windows.
    #[serde(default)]
    pub improvement_ratio: Option<f64>,
    /// The held-out FOM of the transfer check (second box or one heading
    /// left out), nT.
    #[serde(default)]
    pub held_out_fom_nt: Option<f64>,
    /// The compensation's uncertainty away from the calibration, nT.
    #[serde(default)]
    pub outside_calibration_sigma_nt: Option<f64>,
    /// How far the diagnosed findings or the base station's term moved the survey from plain
    /// Tolles-Lawson, when beyond the stated uncertainty: the calibration
    /// flight's verdict was CHECK, not PASS, nT.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unchecked_departure_nt: Option<f64>,
    /// The channel's verdict on its calibration flight.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub verdict: Option<crate::quality::verdict::Verdict>,
    /// How the model scaled a crustal anomaly on its calibration flight's
    /// survey rows (the median; [`crate::model::AnomalyGain`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub anomaly_gain: Option<f64>,
    /// The smallest and largest gain of a row there.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub anomaly_gain_range: Option<[f64; 2]>,
}

impl CalibrationFigures {
    /// The figures of one channel of a flight compensated on itself.
    pub fn of(quality: &ChannelQuality) -> Self {
        let finite = |v: f64| v.is_finite().then_some(v);
        CalibrationFigures {
            channel: quality.channel.clone(),
            fom_before_nt: quality.fom_before_nt,
            fom_after_nt: quality.fom_after_nt,
            fom_manoeuvres: quality.fom_manoeuvres,
            improvement_ratio: finite(quality.improvement_ratio),
            held_out_fom_nt: (quality.transfer.as_ref()).map(|t| t.held_out_fom_nt),
            outside_calibration_sigma_nt: (quality.uncertainty.as_ref()).map(|u| u.outside_calibration_sigma_nt),
            unchecked_departure_nt: quality.unchecked_departure().map(|(departure, _)| departure),
            verdict: Some(quality.verdict),
            anomaly_gain: quality.anomaly_gain,
            anomaly_gain_range: quality.anomaly_gain_range,
        }
    }

    /// "FOM 1.62 → 0.45 nT over 12 of 12 manoeuvres, IR 8.1".
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if let (Some(before), Some(after)) = (self.fom_before_nt, self.fom_after_nt) {
            parts.push(format!(
                "FOM {before:.2} → {after:.2} nT over {} of 12 manoeuvres",
                self.fom_manoeuvres
            ));
        }
        if let Some(ir) = self.improvement_ratio {
            parts.push(format!("IR {ir:.1}"));
        }
        if let Some(held_out) = self.held_out_fom_nt {
            parts.push(format!("held-out FOM {held_out:.2} nT"));
        }
        match parts.is_empty() {
            true => "no calibration figures saved".into(),
            false => parts.join(", "),
        }
    }
}

/// The saved model a flight was compensated with (the quality JSON's
/// `model`): its file, the flight it was fitted on and that flight's
/// figures.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AppliedModel {
    /// The model JSON.
    pub file: PathBuf,
    /// The calibration flight's input, as the model JSON names it.
    pub fitted_on: PathBuf,
    /// Its identity (file name, rows, time span, hash).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flight: Option<FlightIdentity>,
    /// The day it was flown.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub date: Option<FlightDate>,
    /// Days from the calibration flight to this one (negative: the
    /// calibration was flown later); absent when either day is unknown.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub age_days: Option<i64>,
    /// The model was fitted on this very flight (same content).
    pub fitted_on_this_flight: bool,
    /// The airframe it was flown on.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub aircraft: Option<String>,
    /// What magcomp wrote the model.
    pub written_by: String,
    /// Each channel's figures on the calibration flight.
    pub calibration: Vec<CalibrationFigures>,
}

/// A model JSON as read back: what applying it needs.
#[derive(Debug, Clone, Deserialize)]
struct SavedFile {
    #[serde(default)]
    written_by: Option<String>,
    flight: PathBuf,
    #[serde(default)]
    flight_identity: Option<FlightIdentity>,
    #[serde(default)]
    date: Option<FlightDate>,
    #[serde(default)]
    aircraft: Option<String>,
    #[serde(default)]
    calibration: Vec<CalibrationFigures>,
    #[serde(default)]
    applied_findings: Vec<AppliedFinding>,
    #[serde(default)]
    vector_calibration: Option<crate::calibration::fluxgate::VectorCalibration>,
    models: Vec<SavedFit>,
    #[serde(default)]
    vector_models: Vec<SavedVector>,
}

/// A fluxgate's vector model as the model JSON holds it: what its
/// compensation needs ([`crate::vector::compensate_with`]).
#[derive(Debug, Clone, Deserialize)]
struct SavedVector {
    sensor: String,
    soft_iron: [[f64; 3]; 3],
    hard_iron_nt: [f64; 3],
    #[serde(default)]
    tolles_lawson: Option<SavedVectorStage>,
}

/// The vector Tolles-Lawson stage: a model of each body axis's residual.
#[derive(Debug, Clone, Deserialize)]
struct SavedVectorStage {
    components: Vec<SavedFit>,
}

/// One channel's fitted model as the model JSON holds it.
#[derive(Debug, Clone, Deserialize)]
struct SavedFit {
    channel: String,
    vector_sensor: String,
    spec: ModelSpec,
    term_names: Vec<String>,
    coefficients: Vec<f64>,
    filter: crate::model::FilterSettings,
    #[serde(default)]
    coefficient_uncertainty: Vec<Option<f64>>,
    sample_rate_hz: f64,
    solution: SavedSolution,
    #[serde(default)]
    calibration_level: Option<CalibrationLevel>,
}

/// What of the solve a saved model keeps for its use: λ or rank, and the
/// jackknife the sigma column comes from.
#[derive(Debug, Clone, Deserialize)]
struct SavedSolution {
    #[serde(default)]
    lambda: Option<f64>,
    #[serde(default)]
    rank: Option<usize>,
    #[serde(default)]
    samples: usize,
    #[serde(default)]
    jackknife: Vec<Vec<f64>>,
}

/// A column's role, as a sentence names it.
fn role_words(role: &crate::ingest::flight_log::ChannelRole) -> &'static str {
    use crate::ingest::flight_log::ChannelRole;
    match role {
        ChannelRole::Line => "line column",
        ChannelRole::ScalarMagnetometer => "scalar magnetometer",
        ChannelRole::VectorMagnetometer { .. } => "fluxgate axis",
        ChannelRole::VectorTotal { .. } => "fluxgate's total field",
        ChannelRole::Attitude(_) => "attitude angle",
        ChannelRole::Position => "position",
        ChannelRole::BaseStation => "base station",
        ChannelRole::Auxiliary => "auxiliary column",
    }
}

/// A saved model, read and checked, ready to apply.
#[derive(Debug, Clone)]
pub struct SavedModel {
    path: PathBuf,
    file: SavedFile,
}

/// What makes a saved channel model unusable, if anything: no calibration
/// level, coefficients that do not match their terms or are not numbers,
/// an incomplete jackknife, no sample rate.
fn scalar_model_problem(fit: &SavedFit) -> Option<String> {
    let channel = &fit.channel;
    if fit.calibration_level.is_none() {
        return Some(format!(
            "the model of '{channel}' has no calibration level (a model JSON written before magcomp kept one): compensate the calibration flight again with --model to save it"
        ));
    }
    if fit.coefficients.len() != fit.term_names.len() {
        return Some(format!(
            "the model of '{channel}' has {} coefficients for {} term names",
            fit.coefficients.len(),
            fit.term_names.len()
        ));
    }
    if let Some(k) = fit.coefficients.iter().position(|c| !c.is_finite()) {
        return Some(format!(
            "the model of '{channel}' has no finite value for its coefficient '{}'",
            fit.term_names[k]
        ));
    }
    let jackknife = &fit.solution.jackknife;
    let levels = fit.calibration_level.as_ref().map_or(0, |l| l.jackknife_nt.len());
    let whole = jackknife.iter().flatten().all(|v| v.is_finite())
        && jackknife.iter().all(|d| d.len() == fit.coefficients.len());
    if !whole || levels != jackknife.len() {
        return Some(format!(
            "the jackknife of the model of '{channel}' is incomplete ({} deviations, {levels} levels for them)",
            jackknife.len()
        ));
    }
    if !(fit.sample_rate_hz.is_finite() && fit.sample_rate_hz > 0.0) {
        return Some(format!("the model of '{channel}' has no sample rate"));
    }
    None
}

/// What makes a saved vector model unusable, if anything: constants that
/// are not numbers, or a vector Tolles-Lawson stage that is not the one
/// magcomp fits (one model per body axis, each of the field-derivative
/// terms) or is incomplete.
fn vector_model_problem(vector: &SavedVector) -> Option<String> {
    let sensor = &vector.sensor;
    let constants = vector.soft_iron.iter().flatten().chain(&vector.hard_iron_nt);
    if !constants.into_iter().all(|v| v.is_finite()) {
        return Some(format!(
            "the vector model of '{sensor}' has constants that are not numbers"
        ));
    }
    let stage = vector.tolles_lawson.as_ref()?;
    if stage.components.len() != 3 {
        return Some(format!(
            "the vector Tolles-Lawson stage of '{sensor}' holds {} models, not one per body axis",
            stage.components.len()
        ));
    }
    let terms = crate::vector::tolles_lawson::terms();
    stage.components.iter().find_map(|fit| {
        let whole = fit.spec == ModelSpec::plain(terms)
            && fit.term_names == terms.names()
            && fit.coefficients.len() == fit.term_names.len()
            && fit.coefficients.iter().all(|c| c.is_finite())
            && fit.sample_rate_hz.is_finite()
            && fit.sample_rate_hz > 0.0;
        (!whole).then(|| {
            format!(
                "the vector Tolles-Lawson model of '{}' ({sensor}) is not the stage magcomp fits, or incomplete: terms {}, {} coefficients, sample rate {} Hz",
                fit.channel,
                fit.term_names.join(", "),
                fit.coefficients.len(),
                fit.sample_rate_hz
            )
        })
    })
}

impl SavedModel {
    /// Reads the model JSON at `path`; an error when it is not one, is
    /// damaged, or predates the saved calibration level.
    pub fn read(path: &Path) -> Result<Self> {
        let not_ours = |problem: String| {
            Error::NotOurFile {
            path: path.to_path_buf(),
            expected: "a model JSON written by magcomp (--model, or run's <flight>_model.json)",
            problem,
            hint: "Give the model JSON that `magcomp compensate --model` or `magcomp run` wrote for the calibration flight",
        }
        };
        let text = crate::ingest::read_text(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            action: "reading",
            source,
        })?;
        let file: SavedFile = serde_json::from_str(&text).map_err(|e| not_ours(e.to_string()))?;
        if file.models.is_empty() {
            return Err(not_ours("it holds no fitted model".into()));
        }
        if let Some(date) = file.date.filter(|d| FlightDate::parse(&d.to_string()).is_none()) {
            return Err(not_ours(format!("its calibration day {date} is not a day")));
        }
        let channels: Vec<&str> = file.models.iter().map(|m| m.channel.as_str()).collect();
        if let Some(twice) = (channels.iter().enumerate()).find_map(|(i, c)| channels[..i].contains(c).then_some(c)) {
            return Err(not_ours(format!("it holds two models of '{twice}'")));
        }
        let problem = (file.models.iter().find_map(scalar_model_problem))
            .or_else(|| file.vector_models.iter().find_map(vector_model_problem));
        if let Some(problem) = problem {
            return Err(not_ours(problem));
        }
        Ok(SavedModel {
            path: path.to_path_buf(),
            file,
        })
    }

    /// The fluxgate calibration the models' terms are built on, when the
    /// calibration flight's `[vector_calibration]` stage made one.
    pub fn vector_calibration(&self) -> Option<&crate::calibration::fluxgate::VectorCalibration> {
        self.file.vector_calibration.as_ref()
    }

    /// The findings the models carry, of `channels`.
    pub fn applied_findings(&self, channels: &[String]) -> Vec<AppliedFinding> {
        (self.file.applied_findings.iter())
            .filter(|f| channels.contains(&f.channel))
            .cloned()
            .collect()
    }

    /// The model file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Warnings for `channels` whose calibration did not pass: a FOM above
    /// `fom_limit_nt`, or findings that moved the survey beyond the stated
    /// uncertainty (the calibration flight's CHECK).
    pub fn calibration_warnings(&self, channels: &[String], fom_limit_nt: f64) -> Vec<Warning> {
        let model = &self.path;
        let mut warnings = Vec::new();
        for figures in self.file.calibration.iter().filter(|c| channels.contains(&c.channel)) {
            let channel = figures.channel.clone();
            match figures.fom_after_nt {
                Some(fom) if fom > fom_limit_nt => warnings.push(Warning::ModelCalibrationFailed {
                    channel: channel.clone(),
                    model: model.clone(),
                    fom_nt: fom,
                    limit_nt: fom_limit_nt,
                }),
                Some(_) => {}
                None => warnings.push(Warning::ModelCalibrationNoFom {
                    channel: channel.clone(),
                    model: model.clone(),
                }),
            }
            if let Some(departure_nt) = figures.unchecked_departure_nt {
                warnings.push(Warning::ModelCalibrationDeparted { channel, departure_nt });
            }
        }
        warnings
    }

    /// The channels the model compensates, in its order.
    pub fn channels(&self) -> Vec<&str> {
        self.file.models.iter().map(|m| m.channel.as_str()).collect()
    }

    /// [`SavedModel::renamed`] for `log`: each of the model's channels
    /// that `log` records under the name `names` gives it, and not under
    /// its own, is renamed (with a note); one it records under its own
    /// name only stays. Refused: a name the model does not hold, a column
    /// `log` does not record, a column that is not a scalar's (a fluxgate
    /// axis, attitude, position, line, base station or time), and a
    /// channel `log` records under both names.
    pub fn renamed_for(
        &self,
        log: &FlightLog,
        names: &std::collections::BTreeMap<String, String>,
    ) -> Result<(SavedModel, Vec<Note>)> {
        let refuse = |message: String| Error::Config {
            source_name: "[model] channels".into(),
            message,
        };
        let mut used = std::collections::BTreeMap::new();
        let mut notes = Vec::new();
        for (model, column) in names {
            let own = log.channel(model).is_some();
            if *column == log.time_column() {
                return Err(refuse(format!(
                    "'{model}' = '{column}': '{column}' is the flight's time column, not a scalar magnetometer"
                )));
            }
            let Some(target) = log.channel(column) else {
                if own && self.channels().contains(&model.as_str()) {
                    notes.push(Note::ModelChannelOwnName {
                        model: model.clone(),
                        column: column.clone(),
                    });
                }
                if own || !self.channels().contains(&model.as_str()) {
                    used.insert(model.clone(), column.clone());
                    continue;
                }
                return Err(refuse(format!(
                    "'{model}' = '{column}': the flight {} records no column '{column}' (its scalar channels: {})",
                    log.source().display(),
                    log.scalar_channels().join(", ")
                )));
            };
            use crate::ingest::flight_log::ChannelRole;
            if !matches!(target.role, ChannelRole::ScalarMagnetometer | ChannelRole::Auxiliary) {
                return Err(refuse(format!(
                    "'{model}' = '{column}': '{column}' is the flight's {}, not a scalar magnetometer",
                    role_words(&target.role)
                )));
            }
            if own {
                return Err(refuse(format!(
                    "'{model}' = '{column}': the flight records both '{model}' and '{column}', so which one the model compensates is not known; remove the line, or rename one column"
                )));
            }
            notes.push(Note::ModelChannelMapped {
                model: model.clone(),
                column: column.clone(),
            });
            used.insert(model.clone(), column.clone());
        }
        // Names of the model the flight records under their own name are
        // not renamed; the rest are, and an unknown one is refused.
        used.retain(|model, _| log.channel(model).is_none() || !self.channels().contains(&model.as_str()));
        Ok((self.renamed(&used)?, notes))
    }

    /// The same model with its scalar channels under the flight's names
    /// (`[model] channels`: model channel → the flight's column), in its
    /// fits, calibration figures and findings alike. A name the model does
    /// not hold is an error that lists those it does.
    pub fn renamed(&self, names: &std::collections::BTreeMap<String, String>) -> Result<SavedModel> {
        if let Some(unknown) = names.keys().find(|name| !self.channels().contains(&name.as_str())) {
            return Err(Error::Config {
                source_name: "[model] channels".into(),
                message: format!(
                    "'{unknown}' is not a channel of the model {} (it holds {}); give the model's channel names on the left",
                    self.path.display(),
                    self.channels().join(", ")
                ),
            });
        }
        let rename = |channel: &mut String| {
            if let Some(column) = names.get(channel.as_str()) {
                *channel = column.clone();
            }
        };
        let mut renamed = self.clone();
        renamed.file.models.iter_mut().for_each(|m| rename(&mut m.channel));
        renamed.file.calibration.iter_mut().for_each(|c| rename(&mut c.channel));
        renamed
            .file
            .applied_findings
            .iter_mut()
            .for_each(|f| rename(&mut f.channel));
        Ok(renamed)
    }

    /// A refusal: the model does not fit `log` because of `problem`.
    fn mismatch(&self, log: &FlightLog, problem: String, hint: &str) -> Error {
        Error::ModelMismatch {
            model: self.path.clone(),
            flight: log.source().to_path_buf(),
            problem,
            hint: hint.into(),
        }
    }

    /// The fitted models to compensate `log` with: those of the channels
    /// `wanted` (every channel of the model when `None`), at the flight's
    /// sample rate. Refused when the flight lacks a channel, the fluxgate
    /// or a source column, or a wanted channel has no model, or `vector`
    /// names another fluxgate.
    pub fn models_for(
        &self,
        log: &FlightLog,
        wanted: Option<&[String]>,
        vector: Option<&str>,
    ) -> Result<Vec<FittedModel>> {
        let chosen: Vec<&SavedFit> = match wanted {
            None => self.file.models.iter().collect(),
            Some(wanted) => (wanted.iter())
                .map(|channel| {
                    self.file.models.iter().find(|m| &m.channel == channel).ok_or_else(|| {
                        self.mismatch(
                            log,
                            format!(
                                "channel '{channel}' was asked for, and the model holds {}",
                                self.channels().join(", ")
                            ),
                            "Ask for the model's channels, or calibrate this channel on a flight with a box",
                        )
                    })
                })
                .collect::<Result<_>>()?,
        };
        let missing: Vec<&str> = (chosen.iter())
            .filter(|m| log.channel(&m.channel).is_none())
            .map(|m| m.channel.as_str())
            .collect();
        if !missing.is_empty() {
            return Err(self.mismatch(
                log,
                format!(
                    "the flight does not record {} (its scalar channels: {})",
                    missing.join(", "),
                    log.scalar_channels().join(", ")
                ),
                "Apply a model calibrated with this flight's magnetometers, choose the channels both hold with --channels, or, when this flight records them under other names, give them in [model] channels (model channel = this flight's column)",
            ));
        }
        for fit in &chosen {
            self.check_fit(log, fit, vector)?;
        }
        let rate = 1.0 / log.median_interval_s();
        Ok(chosen.into_iter().map(|fit| self.fitted(fit, rate)).collect())
    }

    /// Refuses `fit` on `log` when the flight cannot take it: another
    /// fluxgate asked for, its fluxgate or a source column not recorded,
    /// no sample rate, or a term list its spec does not build.
    fn check_fit(&self, log: &FlightLog, fit: &SavedFit, vector: Option<&str>) -> Result<()> {
        if let Some(wanted) = vector.filter(|v| *v != fit.vector_sensor) {
            return Err(self.mismatch(
                log,
                format!(
                    "the fluxgate '{wanted}' was asked for, and the model of '{}' is built on '{}'",
                    fit.channel, fit.vector_sensor
                ),
                "A model's terms are of the fluxgate it was fitted with: leave the fluxgate to the model",
            ));
        }
        if log.vector_sensor(&fit.vector_sensor).is_none() {
            return Err(self.mismatch(
                log,
                format!(
                    "the model of '{}' is built on the fluxgate '{}', which the flight does not record",
                    fit.channel, fit.vector_sensor
                ),
                "Apply a model calibrated with this flight's fluxgate, or name its columns in [columns]",
            ));
        }
        let rate = 1.0 / log.median_interval_s();
        if !(rate.is_finite() && rate > 0.0) {
            return Err(self.mismatch(
                log,
                format!("the flight's sample rate is {rate} Hz"),
                "Give the flight a time column that increases with every row",
            ));
        }
        self.check_terms(log, fit)?;
        // A cross-sensor signal reads sensors, not a column of its name:
        // rebuilding it says which is missing.
        let sources = (fit.spec.extensions.sources.iter())
            .filter(|s| !matches!(s, crate::model::SourceTerm::CrossSensor { .. }))
            .map(|s| s.column());
        if let Some(column) = sources.into_iter().find(|c| log.channel(c).is_none()) {
            return Err(self.mismatch(
                log,
                format!(
                    "the model of '{}' takes the column '{column}' (a finding of its calibration), which the flight does not record",
                    fit.channel
                ),
                "Record that column on the survey flights too, or save a plain model from the calibration flight (compensate it with --plain --model)",
            ));
        }
        Ok(())
    }

    /// The coefficients are read in the order of the terms the spec
    /// builds: a list that differs was edited, and would pair each
    /// coefficient with another term.
    fn check_terms(&self, log: &FlightLog, fit: &SavedFit) -> Result<()> {
        if let Some(sensor) = log.vector_sensor(&fit.vector_sensor) {
            let columns = crate::model::term_names(log, &sensor, &fit.channel, &fit.spec);
            if columns.as_ref().is_ok_and(|names| *names != fit.term_names) {
                let built = columns.unwrap_or_default();
                // An earlier magcomp fitted a base station's gain: one
                // more term, named after the station's column.
                let stations: Vec<&str> = (fit.spec.extensions.sources.iter())
                    .filter(|s| s.is_external_field())
                    .map(|s| s.column())
                    .collect();
                let fitted_gain = !stations.is_empty()
                    && fit.term_names.len() == built.len() + stations.len()
                    && (fit.term_names.iter())
                        .filter(|n| !stations.contains(&n.as_str()))
                        .eq(built.iter());
                let hint = match fitted_gain {
                    true => "The model was saved by an earlier magcomp, which fitted the base station's gain; this one subtracts the station's variation with gain 1: save the model again from its calibration flight (--model)",
                    false => "The file was edited or damaged: save the model again from its calibration flight (--model)",
                };
                return Err(self.mismatch(
                    log,
                    format!(
                        "the model of '{}' lists the terms {} where its spec builds {}",
                        fit.channel,
                        fit.term_names.join(", "),
                        built.join(", ")
                    ),
                    hint,
                ));
            }
        }
        Ok(())
    }

    /// A [`FittedModel`] of a saved fit for a flight recorded at
    /// `rate_hz`: the coefficients, the spec, the jackknife and the
    /// calibration level; no windows (they are the calibration flight's)
    /// and no curves. At another rate than the model's, its per-sample
    /// coefficients ([`crate::model::per_sample_columns`]), their jackknife and
    /// uncertainty take the rates' ratio.
    fn fitted(&self, fit: &SavedFit, rate_hz: f64) -> FittedModel {
        let reason = format!(
            "applied from {} (fitted on {}{}): nothing refitted",
            self.path.display(),
            self.file.flight.display(),
            self.file.date.map(|d| format!(", {d}")).unwrap_or_default()
        );
        let (factor, sample_rate_hz) = match same_rate(fit.sample_rate_hz, rate_hz) {
            true => (None, fit.sample_rate_hz),
            false => (Some(rate_hz / fit.sample_rate_hz), rate_hz),
        };
        let per_sample = crate::model::per_sample_columns(&fit.spec);
        let scaled = |values: &[f64]| -> Vec<f64> {
            (values.iter().enumerate())
                .map(|(k, v)| match factor {
                    Some(factor) if per_sample.get(k).copied().unwrap_or(false) => v * factor,
                    _ => *v,
                })
                .collect()
        };
        let coefficients = scaled(&fit.coefficients);
        let uncertainty: Vec<f64> = (fit.coefficient_uncertainty.iter())
            .map(|u| u.unwrap_or(f64::NAN))
            .collect();
        FittedModel {
            channel: fit.channel.clone(),
            vector_sensor: fit.vector_sensor.clone(),
            spec: fit.spec.clone(),
            term_names: fit.term_names.clone(),
            coefficients: coefficients.clone(),
            filter: fit.filter,
            sample_rate_hz,
            solution: saved_solution(
                fit,
                (coefficients, reason),
                fit.solution.jackknife.iter().map(|d| scaled(d)).collect(),
            ),
            coefficient_uncertainty: scaled(&uncertainty),
            windows: Vec::new(),
            estimators: None,
            excitation: None,
            solver: None,
            calibration_level: fit.calibration_level.clone(),
        }
    }

    /// What the quality JSON says of the model applied to the flight
    /// `log`, flown on `date`.
    pub fn applied(&self, date: Option<FlightDate>, log: &FlightLog) -> Result<AppliedModel> {
        let file = &self.file;
        // The input is hashed only when its rows and time span are the
        // calibration flight's: another flight is told apart for free.
        let time = log.time_s();
        let same_span = (file.flight_identity.as_ref()).is_some_and(|f| {
            f.rows == log.len()
                && time.first().is_some_and(|t| t.to_bits() == f.t_start.to_bits())
                && time.last().is_some_and(|t| t.to_bits() == f.t_end.to_bits())
        });
        let fitted_on_this_flight = match (same_span, &file.flight_identity) {
            (true, Some(saved)) => saved.difference(&FlightIdentity::of(log)?).is_none(),
            _ => false,
        };
        Ok(AppliedModel {
            fitted_on_this_flight,
            file: self.path.clone(),
            fitted_on: file.flight.clone(),
            flight: file.flight_identity.clone(),
            date: file.date,
            age_days: (file.date.zip(date))
                .map(|(made, used)| used.days_since_unix_epoch() - made.days_since_unix_epoch()),
            aircraft: file.aircraft.clone(),
            written_by: file.written_by.clone().unwrap_or_else(|| "an earlier magcomp".into()),
            calibration: file.calibration.clone(),
        })
    }

    /// Each saved fluxgate's vector compensation on `log` (its fluxgate
    /// calibrated as the model's was), at the flight's rate, and a warning
    /// for each the flight cannot take: none when the model holds no
    /// vector model.
    pub fn vector_compensations(&self, log: &FlightLog) -> (Vec<crate::vector::CompensatedVector>, Vec<Warning>) {
        let rate = 1.0 / log.median_interval_s();
        let (mut compensated, mut warnings) = (Vec::new(), Vec::new());
        for saved in &self.file.vector_models {
            let stage: Option<Vec<FittedModel>> = (saved.tolles_lawson.as_ref())
                .map(|stage| stage.components.iter().map(|fit| self.fitted(fit, rate)).collect());
            let iron = (&saved.soft_iron, &saved.hard_iron_nt);
            match crate::vector::compensate_with(log, &saved.sensor, iron, stage.as_deref()) {
                Ok(vector) => compensated.push(vector),
                Err(e) => warnings.push(Warning::VectorNotCompensated {
                    sensor: saved.sensor.clone(),
                    model: Some(self.path.clone()),
                    reason: e.to_string(),
                }),
            }
        }
        (compensated, warnings)
    }

    /// Whether the model holds a vector model of any fluxgate.
    pub fn has_vector_models(&self) -> bool {
        !self.file.vector_models.is_empty()
    }

    /// The warning for applying the models of `channels` to `log` when it
    /// records at another rate than they were fitted at: which terms were
    /// rescaled, and what that leaves unchecked.
    pub fn rate_warning(&self, log: &FlightLog, (channels, vector): (&[String], bool)) -> Option<Warning> {
        let rate = 1.0 / log.median_interval_s();
        let vector_stages = (self.file.vector_models.iter())
            .filter(|_| vector)
            .filter_map(|v| v.tolles_lawson.as_ref())
            .flat_map(|stage| &stage.components);
        let fits: Vec<&SavedFit> = (self.file.models.iter())
            .filter(|m| channels.contains(&m.channel))
            .chain(vector_stages)
            .filter(|m| !same_rate(m.sample_rate_hz, rate))
            .collect();
        let first = fits.first()?;
        let rescaled: Vec<String> = (fits.iter())
            .filter_map(|fit| {
                let per_sample = crate::model::per_sample_columns(&fit.spec);
                let terms: Vec<&str> = (fit.term_names.iter().enumerate())
                    .filter(|(k, _)| per_sample.get(*k).copied().unwrap_or(false))
                    .map(|(_, name)| name.as_str())
                    .collect();
                (!terms.is_empty()).then(|| format!("{} ({})", fit.channel, terms.join(", ")))
            })
            .collect();
        Some(Warning::ModelRateDiffers {
            model: self.path.clone(),
            fitted_hz: first.sample_rate_hz,
            flight_hz: rate,
            rescaled,
        })
    }

    /// Warnings and notes for applying the model to a flight of `date`
    /// flown by `aircraft`: age and airframe.
    pub fn age_and_aircraft(
        &self,
        applied: &AppliedModel,
        aircraft: Option<&str>,
        max_age_days: u32,
    ) -> (Vec<Warning>, Vec<Note>) {
        let (mut warnings, mut notes) = (Vec::new(), Vec::new());
        match applied.age_days {
            Some(age_days) if age_days.unsigned_abs() > u64::from(max_age_days) => {
                warnings.push(Warning::ModelTooOld {
                    model: self.path.clone(),
                    age_days,
                    max_age_days,
                })
            }
            Some(_) => {}
            // A model fitted on this very flight is of its day.
            None if applied.fitted_on_this_flight => {}
            None => warnings.push(Warning::ModelAgeUnknown {
                calibration_undated: applied.date.is_none(),
            }),
        }
        let same = |a: &str, b: &str| a.trim().eq_ignore_ascii_case(b.trim());
        match (applied.aircraft.as_deref(), aircraft) {
            (Some(made), Some(used)) if !same(made, used) => warnings.push(Warning::ModelOtherAircraft {
                model: self.path.clone(),
                made: made.to_string(),
                used: used.to_string(),
            }),
            (Some(_), Some(_)) => {}
            (made, used) => notes.push(Note::AircraftUnnamed {
                calibration_named: made.is_some(),
                flight_named: used.is_some(),
            }),
        }
        (warnings, notes)
    }
}

/// Whether a flight at `flight_hz` records at the rate of a model fitted
/// at `model_hz`, within [`RATE_TOLERANCE`].
fn same_rate(model_hz: f64, flight_hz: f64) -> bool {
    (flight_hz / model_hz - 1.0).abs() <= RATE_TOLERANCE
}

/// The solver's record of a saved fit: its λ or rank, rows and jackknife
/// (taken at this flight's rate), `coefficients` and `reason`; no curves,
/// and NaN for what a saved model does not keep.
fn saved_solution(fit: &SavedFit, (coefficients, reason): (Vec<f64>, String), jackknife: Vec<Vec<f64>>) -> Solution {
    Solution {
        coefficients,
        method: match fit.solution.rank {
            Some(_) => Method::TruncatedSvd,
            None => Method::Ridge,
        },
        reason,
        lambda: fit.solution.lambda,
        rank: fit.solution.rank,
        effective_dof: f64::NAN,
        lambda_by_press: f64::NAN,
        lambda_by_blocked_press: None,
        singular_values: Vec::new(),
        condition_number: f64::NAN,
        decomposition: Decomposition::CholeskyQr2,
        scaled_condition_number: f64::NAN,
        ridge_curve: Vec::new(),
        tsvd_curve: Vec::new(),
        samples: fit.solution.samples,
        residual_rms: f64::NAN,
        standard_errors: Vec::new(),
        fitted: Vec::new(),
        jackknife,
    }
}
