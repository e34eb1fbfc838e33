//! One flight through every stage: read, screen, detect, diagnose, fit,
//! compensate, assess. [`run`] writes nothing; [`crate::sink`] writes what
//! it produced.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::config::{FlightJob, Settings};
use crate::detect::Detection;
use crate::error::{Error, Result};
use crate::flight_log::FlightLog;
use crate::formats::added_column_names;
use crate::formats::align::AlignmentReport;
use crate::formats::read_flight_log;
use crate::model::{compare_estimators, fit, FittedModel, ModelSpec, SharedDesign};
use crate::numerics::stacked::StorePool;
use crate::quality::transfer::check_transfer;
use crate::quality::{assess_quality, ChannelQuality};
use rayon::prelude::*;

pub use crate::diagnose::AppliedFinding;

mod applied;
mod diagnosis;
mod prepared;
mod summary;
mod vector_stage;

pub use prepared::{
    calibration_windows, choose_channels, choose_vector_sensor, detection_notes, detection_warnings, diagnose_flight,
};
pub use summary::summary;

use applied::run_applied;
use diagnosis::{applied_findings, augmentation_plan, evidence_rule, next_step, ExtensionsPlan};
use prepared::refuse_dead_columns;
use vector_stage::{vector_stage, window_hulls};

/// What processing one flight produced.
#[derive(Debug, Clone, Serialize)]
pub struct FlightResult {
    /// Input file.
    pub flight: PathBuf,
    /// Rows read (and written).
    pub rows: usize,
    /// Columns magcomp added to the compensated CSV.
    pub added_columns: Vec<String>,
    /// Remarks for the user (renamed outputs and the like).
    pub notes: Vec<String>,
    /// The detected boxes and manoeuvres, when the flight gave no windows.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub detection: Option<Detection>,
    /// How multi-rate channels were placed on one time base (MCAP inputs).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub alignment: Option<AlignmentReport>,
    /// Quality figures per channel.
    pub channels: Vec<ChannelQuality>,
    /// The fluxgate calibration the fit used (`[vector_calibration]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vector_calibration: Option<crate::vector_calibration::VectorCalibration>,
    /// Whether the diagnosis was applied (`[diagnose] apply`, `--plain`).
    pub diagnosis_mode: crate::diagnose::ApplyDiagnosis,
    /// The diagnosed findings the fit applied, each with what it bought
    /// held out.
    pub applied_findings: Vec<AppliedFinding>,
    /// What the quality gate found wrong, each with the next step; also on
    /// stdout and in the report.
    pub warnings: Vec<String>,
    /// The diagnosis made before the fit (`[diagnose] apply`); its
    /// DIAGNOSIS.json is written beside the other outputs.
    #[serde(skip)]
    pub diagnosis: Option<crate::diagnose::Diagnosis>,
    /// The fitted models.
    #[serde(skip)]
    pub models: Vec<FittedModel>,
    /// The twelve-constant model of each vector-compensated fluxgate.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub vector_models: Vec<crate::vector::VectorModel>,
    /// Each compensated gradient: the method used, why, and both methods
    /// held out.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub gradients: Vec<crate::gradient::GradientResult>,
    /// The gradients' direct models (the model JSON holds them).
    #[serde(skip)]
    pub gradient_models: Vec<FittedModel>,
    /// The flight against the plan it was flown to (`--plan`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub plan: Option<crate::against_plan::PlanComparison>,
    /// The saved model the flight was compensated with (`--apply`),
    /// nothing refitted; `None` when it was fitted on its own calibration.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model: Option<crate::apply::AppliedModel>,
    /// The airframe, when the flight names it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub aircraft: Option<String>,
}

/// The flight's channels and manoeuvres set against `planned`: the FOM,
/// the survey uncertainty the excitation analysis states (with the noise
/// the sigma column takes) and the sigma column over the survey lines.
fn against_plan(
    planned: &crate::against_plan::PlanPrediction,
    log: &FlightLog,
    models: &[FittedModel],
    quality: &[ChannelQuality],
    compensation: &crate::compensate::Compensation,
) -> crate::against_plan::PlanComparison {
    let line = log.channel("line").map(|c| c.values.as_slice()).unwrap_or_default();
    let channels: Vec<crate::against_plan::FlownChannel> = (models.iter().zip(quality).zip(&compensation.channels))
        .map(|((model, quality), channel)| {
            let noise = quality.white_noise_nt();
            crate::against_plan::FlownChannel {
                channel: model.channel.clone(),
                fom_nt: quality.fom_after_nt,
                survey_sigma_nt: (model.excitation.as_ref())
                    .zip(noise)
                    .map(|(e, noise)| e.survey_sigma_nt.hypot(noise)),
                sigma_column_nt: (channel.sigma_nt.as_deref()).and_then(|s| crate::against_plan::survey_rms(s, line)),
            }
        })
        .collect();
    // The windows every channel was fitted on; labelled by kind and
    // heading when detected (or given so).
    let manoeuvres: Option<Vec<(crate::windows::ManoeuvreKind, f64)>> = (models.first()).and_then(|m| {
        m.windows
            .iter()
            .map(|w| w.window.kind.zip(w.window.heading_deg))
            .collect()
    });
    crate::against_plan::compare(planned, manoeuvres.as_deref(), &channels)
}

/// What a channel's estimator table leaves out, in words: the whole table
/// when the windows span fewer than three headings, or the families no
/// split could fit.
fn estimator_table_gap(model: &FittedModel) -> Option<String> {
    use crate::numerics::estimators::Family;
    let Some(table) = &model.estimators else {
        return Some(format!(
            "{}: no estimator table: the calibration windows do not give three headings (a window given by time that spans a turn has none), so no estimator can be held out by heading",
            model.channel
        ));
    };
    let missing: Vec<String> = Family::ALL
        .iter()
        .filter(|family| !table.iter().any(|s| s.family == **family))
        .map(|family| format!("{family:?}"))
        .collect();
    (!missing.is_empty()).then(|| {
        format!(
            "{}: the estimator table lacks {}: no split of the headings could be fitted by it",
            model.channel,
            missing.join(", ")
        )
    })
}

/// One flight through every stage: what [`run`] produced, for the sinks
/// ([`crate::sink`]) to write.
#[derive(Debug, Clone)]
pub struct FlightRun {
    /// The flight as recorded: the compensated output copies it.
    pub recorded: FlightLog,
    /// The samples no instrument can record, masked: what every stage
    /// worked on.
    pub screened: crate::screen::Screened,
    /// The compensated channels and row flags.
    pub compensation: crate::compensate::Compensation,
    /// Quality figures, notes, warnings, models and diagnosis.
    pub result: FlightResult,
}

impl FlightRun {
    /// The log the stages worked on (the screened samples).
    pub fn log(&self) -> &FlightLog {
        self.screened.log_or(&self.recorded)
    }
}

/// Reads, fits, compensates and assesses one flight; writes nothing.
/// `compensated` is where the compensated flight will go: its format
/// names the columns magcomp adds.
pub fn run(job: &FlightJob, options: &Settings, compensated: &Path) -> Result<FlightRun> {
    // A plan report or a saved model that cannot be read fails before the
    // flight's work.
    let planned = (job.plan.as_deref())
        .map(crate::against_plan::PlanPrediction::read)
        .transpose()?;
    let saved = (job.model.as_deref()).map(crate::apply::SavedModel::read).transpose()?;
    let ingest = crate::formats::IngestOptions {
        date: job.date.or(options.ingest.date),
        ..options.ingest.clone()
    };
    let recorded = read_flight_log(&job.input, &ingest)?;
    // Columns in units magcomp does not read (attitude in radians, time
    // in milliseconds) make every later stage fail in its own words: the
    // units are named first.
    let units = crate::formats::units::unit_warnings(&job.input.display().to_string(), &recorded);
    let run = match saved {
        Some(saved) => run_applied(job, options, compensated, &saved, recorded),
        None => run_fitted(job, options, compensated, planned, recorded),
    };
    run.map_err(|error| match units.is_empty() {
        true => error,
        false => Error::UnitsLookWrong {
            problems: units.join("; "),
            source: Box::new(error),
        },
    })
}

/// [`run`] for a flight fitted on its own calibration.
fn run_fitted(
    job: &FlightJob,
    options: &Settings,
    compensated: &Path,
    planned: Option<crate::against_plan::PlanPrediction>,
    recorded: FlightLog,
) -> Result<FlightRun> {
    // Every stage works on the screened samples; the output copies the
    // recorded ones.
    let screened = crate::screen::screen_samples(&recorded)?;
    let raw_log = screened.log_or(&recorded);
    let sensor = choose_vector_sensor(raw_log, job.vector.as_deref())?;
    refuse_dead_columns(raw_log, &screened.screening, &sensor, job.channels.as_deref())?;
    let channels = choose_channels(raw_log, job.channels.as_deref())?;
    let (windows, detected, headings_note) = calibration_windows(raw_log, job, options)?;
    // The fit (and everything after it) sees the calibrated fluxgate; the
    // compensated file keeps the recorded columns.
    let calibration =
        crate::vector_calibration::calibrate_stage(raw_log, &sensor, &channels, &windows, &options.vector_calibration)?;
    let calibrated = calibration.as_ref().map(|c| c.apply(raw_log, &sensor)).transpose()?;
    let log = calibrated.as_ref().unwrap_or(raw_log);
    let ExtensionsPlan {
        models: plan,
        mut diagnosis,
        mut warnings,
    } = augmentation_plan(
        job,
        (raw_log, log),
        &sensor,
        &channels,
        &windows,
        options,
        calibration.is_some(),
    )?;
    let (plan, departures) = match diagnosis.as_mut() {
        Some(diagnosis) => evidence_rule(log, &sensor, &windows, plan, diagnosis, options, &mut warnings)?,
        None => (plan, BTreeMap::new()),
    };
    warnings.splice(0..0, screened.warnings(&recorded));
    if let Some((path, detected_on)) = &job.windows_detected_on {
        warnings.extend(crate::windows::other_flight_warning(path, detected_on, &recorded)?);
    }
    warnings.extend(crate::formats::mcap::undated_warning(&recorded, compensated));
    warnings.extend(crate::formats::write::text_columns_warning(
        &recorded,
        compensated,
        true,
    ));
    // The channels' fits share their stores; the stores are freed before
    // compensating, which does not need them.
    let stores = StorePool::new();
    let fitted: Vec<FittedModel> = channels
        .par_iter()
        .map(|channel| {
            let spec = ModelSpec::of_channel(options.terms, &plan, channel);
            let mut model = fit(log, &sensor, channel, &windows, &spec, &options.fit, &stores)?;
            model.estimators = compare_estimators(log, &sensor, channel, &windows, &spec, &options.fit, &stores)?;
            Ok(model)
        })
        .collect::<Result<_>>()?;
    // The whole flight's terms, built once for every channel that uses
    // them: the analysis, the compensation and the sigma column read them.
    let shared = SharedDesign::of_models(log, &fitted);
    let fitted: Vec<(FittedModel, Option<String>)> = fitted
        .into_par_iter()
        .map(|mut model| {
            let channel = model.channel.clone();
            // The analysis informs; a flight it cannot analyse is still
            // compensated, and the run says why there is none.
            let excitation = crate::model::excitation::analyse(
                log,
                &sensor,
                &model,
                &windows,
                &options.fit,
                (&stores, &shared),
            );
            let note = match excitation {
                Ok(Some(analysis)) => {
                    model.excitation = Some(analysis);
                    None
                }
                Ok(None) => Some(format!(
                    "{channel}: no excitation analysis: a window's heading is unknown (none given and no INS yaw), or the windows leave the design singular"
                )),
                Err(e) => Some(format!("{channel}: no excitation analysis: {e}")),
            };
            Ok((model, note))
        })
        .collect::<Result<_>>()?;
    let (models, excitation_notes): (Vec<FittedModel>, Vec<Option<String>>) = fitted.into_iter().unzip();
    drop(stores);
    let mut compensation = crate::compensate::compensate_with(log, &models, options.level, &shared)?;
    let stores = StorePool::new();
    let boxes: Vec<(f64, f64)> = match &detected {
        Some(detection) => detection.boxes.iter().map(|b| (b.t_start, b.t_end)).collect(),
        None => window_hulls(&windows),
    };
    let transfer_notes = std::sync::Mutex::new(Vec::new());
    let assessed: Vec<(ChannelQuality, Vec<f64>)> = models
        .par_iter()
        .zip(compensation.channels.par_iter_mut())
        .map(|(model, channel)| {
            let (mut quality, jackknife_levels) = assess_with_sigma(log, model, channel, &shared)?;
            quality.transfer = check_transfer(
                log,
                &sensor,
                model,
                &windows,
                (&options.fit, &options.transfer),
                &stores,
            )?;
            let (transfers, notes) =
                crate::quality::transfer::box_transfer(log, &sensor, model, &windows, &boxes, &options.fit, &stores)?;
            quality.box_transfer = transfers;
            if let Ok(mut all) = transfer_notes.lock() {
                all.extend(notes);
            }
            Ok((quality, jackknife_levels))
        })
        .collect::<Result<_>>()?;
    drop(shared);
    // Each model keeps its level over this calibration, for the flights
    // it is applied to (the model JSON).
    let (quality, jackknife_levels): (Vec<ChannelQuality>, Vec<Vec<f64>>) = assessed.into_iter().unzip();
    let mut models = models;
    for ((model, jackknife_nt), channel) in models.iter_mut().zip(jackknife_levels).zip(&compensation.channels) {
        model.calibration_level = Some(crate::model::CalibrationLevel {
            interference_nt: channel.calibration_interference_nt,
            jackknife_nt,
        });
    }
    // The vector and the gradients read the compensated channels and not
    // each other: they run side by side.
    let (vector, gradients) = rayon::join(
        || vector_stage(log, (&windows, &boxes), &compensation, (&options.vector, &options.fit)),
        || {
            crate::gradient::compensate_gradients(
                &crate::gradient::GradientInputs {
                    log,
                    sensor: &sensor,
                    windows: &windows,
                    models: &models,
                    compensation: &compensation,
                    uncertain: &quality.iter().map(crate::quality::is_uncertain).collect::<Vec<_>>(),
                },
                &options.gradients,
                (options.terms, &options.fit, options.level),
            )
        },
    );
    for compensated in vector.compensated {
        compensation.add_vector(compensated);
    }
    compensation.gradients = gradients.compensated;
    let reduced_notes = crate::reduce::add_reduced(log, &mut compensation, options.reduced)?;
    warnings.extend(compensation.out_of_range_warnings(log.time_s()));
    let added_columns = added_column_names(log, compensated, &compensation)?;
    let mut notes = renaming_notes(&channels, &added_columns);
    notes.extend(reduced_notes);
    // In channel order, whatever order the threads finished in.
    let mut transfer_notes = transfer_notes.into_inner().unwrap_or_default();
    transfer_notes.sort();
    notes.extend(transfer_notes);
    notes.extend(headings_note);
    notes.extend(calibration.iter().map(|c| c.summary()));
    notes.extend(models.iter().filter_map(estimator_table_gap));
    notes.extend(excitation_notes.into_iter().flatten());
    // A gap in the box is a warning: the FOM lacks a manoeuvre and the
    // coefficients it pins are less certain.
    warnings.extend(models.iter().flat_map(|m| {
        let gaps = m.excitation.iter().flat_map(|e| e.gaps());
        gaps.map(|line| format!("{}: {line}", m.channel)).collect::<Vec<_>>()
    }));
    // A solver asked for and not used is a warning: the coefficients are
    // not what the settings say.
    warnings.extend(models.iter().filter_map(|m| {
        let solver = m.solver.as_ref()?;
        match solver.applied() {
            true => None,
            false => Some(format!("{}: {}", m.channel, solver.reason)),
        }
    }));

    notes.extend(models.iter().filter(|m| !m.spec.is_plain()).map(|m| {
        format!(
            "{}: fitted and compensated with the diagnosed model: {}",
            m.channel,
            m.spec.describe()
        )
    }));
    notes.extend(vector.notes);
    warnings.extend(vector.warnings);
    notes.extend(gradients.notes);
    warnings.extend(gradients.warnings);
    if let Some(detection) = &detected {
        notes.extend(detection_notes(detection));
        warnings.extend(detection_warnings(detection));
    }
    let mut quality = quality;
    for q in &mut quality {
        q.survey_departure_from_plain_nt = departures.get(&q.channel).copied();
        if let Some((departure, stated)) = q.unchecked_departure() {
            warnings.push(format!(
                "{}: the diagnosed findings move the survey {departure:.4} nT RMS from plain Tolles-Lawson, more than {}: the verdict is not a plain pass; compare with a plain run (--plain) before using this channel",
                q.channel,
                match stated {
                    Some(sigma) => format!("its stated uncertainty ({sigma:.4} nT)"),
                    None => "anything its uncertainty states (none is stated)".into(),
                }
            ));
        }
    }
    let next_step = next_step(options.diagnose.apply, job.diagnosis.is_some(), diagnosis.is_some());
    for ((q, model), channel) in quality.iter().zip(&models).zip(&compensation.channels) {
        warnings.extend(crate::quality::quality_warnings(q, options.fom_limit_nt, next_step));
        if q.uncertainty.is_some() && channel.sigma_nt.is_none() {
            warnings.push(format!(
                "{}: no sigma column: the compensated channel's noise cannot be measured (too few consecutive samples)",
                model.channel
            ));
        }
        if model.windows.len() < 3 {
            warnings.push(format!(
                "{}: fitted on {} calibration window(s), too few to leave one out: the compensation away from the calibration is not checked and has no uncertainty figure or sigma column. Give three or more windows, one per manoeuvre or leg (a window spanning a whole box is one window; `magcomp detect` finds the manoeuvres)",
                model.channel,
                model.windows.len()
            ));
        }
        if model.solution.jackknife.is_empty() && model.windows.len() >= 3 {
            let why = match model.solver.as_ref().filter(|s| s.applied()) {
                Some(solver) => format!(
                    "the blocked jackknife is computed for ridge and truncated SVD, not for [fit] solver = \"{}\"",
                    solver.requested.name()
                ),
                None => format!(
                    "with one of the {} windows left out a term is no longer pinned (that window alone carries it), so the compensation away from the calibration rests on that one window",
                    model.windows.len()
                ),
            };
            warnings.push(format!("{}: no uncertainty figure: {why}", model.channel));
        }
    }
    let plan = planned.map(|planned| against_plan(&planned, log, &models, &quality, &compensation));
    if let Some(plan) = &plan {
        notes.extend(plan.notes.iter().cloned());
        warnings.extend(plan.warnings.iter().cloned());
    }
    let applied_findings = diagnosis.as_ref().map(applied_findings).unwrap_or_default();
    let result = FlightResult {
        flight: job.input.clone(),
        rows: log.len(),
        added_columns,
        notes,
        detection: detected,
        alignment: log.alignment().cloned(),
        channels: quality,
        vector_calibration: calibration,
        diagnosis_mode: match job.diagnosis {
            Some(_) => crate::diagnose::ApplyDiagnosis::Always,
            None => options.diagnose.apply,
        },
        applied_findings,
        warnings,
        diagnosis,
        models,
        vector_models: vector.models,
        gradients: gradients.results,
        gradient_models: gradients.models,
        plan,
        model: None,
        aircraft: job.aircraft.clone(),
    };
    // The figures above are of the full values; the outputs are written
    // at the stated resolution.
    compensation.round_to(options.output_decimals);
    Ok(FlightRun {
        recorded,
        screened,
        compensation,
        result,
    })
}

/// A compensated channel's figures, its uncertainty and its sigma column
/// (set on `channel`; none without a jackknife or a noise figure, which
/// the run warns of), and each jackknife deviation's mean over the
/// calibration (empty without a jackknife): the level saved with the model.
fn assess_with_sigma(
    log: &FlightLog,
    model: &FittedModel,
    channel: &mut crate::compensate::CompensatedChannel,
    shared: &[SharedDesign],
) -> Result<(ChannelQuality, Vec<f64>)> {
    let mut quality = assess_quality(log, model, channel);
    let Some(prediction) = model.prediction_sigma_with(log, shared)? else {
        return Ok((quality, Vec::new()));
    };
    quality.uncertainty = crate::quality::uncertainty_of(log, model, &prediction);
    if let Some(noise) = quality.white_noise_nt() {
        channel.set_sigma(&prediction, noise);
    }
    Ok((quality, prediction.levels_nt))
}

pub(crate) fn renaming_notes(channels: &[String], added: &[String]) -> Vec<String> {
    channels
        .iter()
        .zip(added)
        .filter(|(_, column)| column.ends_with("_magcomp"))
        .map(|(channel, column)| {
            let original = column.trim_end_matches("_magcomp");
            format!("the input already has a '{original}' column (kept unchanged); magcomp's compensation of '{channel}' is in '{column}'")
        })
        .collect()
}
