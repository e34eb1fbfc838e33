//! A flight compensated with a model saved from another flight.

use std::path::Path;

use rayon::prelude::*;

use super::prepared::{calibration_windows, choose_channels, choose_vector_sensor, refuse_dead_columns};
use super::{assess_with_sigma, renaming_notes, units_row_note, FlightResult, FlightRun};
use crate::config::{FlightJob, Settings};
use crate::error::Result;
use crate::formats::added_column_names;
use crate::ingest::flight_log::FlightLog;
use crate::messages::progress::{Meter, Stage};
use crate::messages::{Note, Warning};
use crate::model::SharedDesign;
use crate::quality::ChannelQuality;

/// Compensates `job`'s flight with the saved model at `model_path`,
/// nothing refitted; `compensated` is where the output will go (for the
/// warnings that depend on its format). The flight's own windows or lines,
/// when given, hold the model out.
pub(super) fn run_applied(
    job: &FlightJob,
    options: &Settings,
    compensated: &Path,
    saved: &crate::pipeline::apply::SavedModel,
    recorded: FlightLog,
    meter: &dyn Meter,
) -> Result<FlightRun> {
    let (renamed, renaming) = renamed_model(saved, &recorded, options)?;
    let saved = renamed.as_ref().unwrap_or(saved);
    meter.begin(Stage::Preparing, 0);
    let screened = crate::ingest::screen::screen_samples(&recorded)?;
    let raw_log = screened.log_or(&recorded);
    let (mut models, sensor, channels) = models_on_flight(saved, job, (raw_log, &screened.screening))?;
    let applied = saved.applied(raw_log.date(), &recorded)?;
    let (model_said, model_notes) = model_words(job, options, saved, (&applied, &channels), raw_log);
    let mut notes = model_notes;
    let mut warnings: Vec<Warning> = screened.warnings(&recorded);
    warnings.extend(model_said);
    let calibrated = saved
        .vector_calibration()
        .map(|c| c.apply(raw_log, &sensor))
        .transpose()?;
    let log = calibrated.as_ref().unwrap_or(raw_log);
    let flight = (job, raw_log, log);
    hold_out_on_own_windows(flight, (&sensor, &mut models), (options, &applied), &mut notes)?;
    let (mut compensation, quality) = compensate_applied(log, &models, (options, meter), &mut warnings)?;
    notes.extend(job.assigned_model.clone());
    notes.extend(renaming);
    let said = Said { warnings, notes };
    let said = beside_the_scalars(
        (log, &recorded, compensated),
        saved,
        (&models, &mut compensation),
        options,
        said,
    )?;
    let added_columns = added_column_names(log, compensated, &compensation)?;
    let notes = applied_notes((&recorded, &channels, &added_columns), &models, said.notes);
    let result = FlightResult {
        flight: job.input.clone(),
        rows: log.len(),
        added_columns,
        notes,
        detection: None,
        alignment: log.alignment().cloned(),
        channels: quality,
        vector_calibration: saved.vector_calibration().cloned(),
        diagnosis_mode: crate::diagnose::ApplyDiagnosis::Never,
        applied_findings: saved.applied_findings(&channels),
        warnings: said.warnings,
        diagnosis: None,
        models,
        vector_models: Vec::new(),
        gradients: Vec::new(),
        gradient_models: Vec::new(),
        plan: None,
        model: Some(applied),
        aircraft: job.aircraft.clone(),
    };
    Ok(FlightRun::finished((recorded, screened), compensation, result, options))
}

/// The saved model's models of the channels `job` asks for (every one by
/// default), their fluxgate and channels, checked against the flight
/// `raw_log` and its `screening`: an error for a column it lacks or that
/// carries no reading.
fn models_on_flight(
    saved: &crate::pipeline::apply::SavedModel,
    job: &FlightJob,
    (raw_log, screening): (&FlightLog, &crate::ingest::screen::Screening),
) -> Result<(
    Vec<crate::model::FittedModel>,
    crate::ingest::flight_log::VectorSensor,
    Vec<String>,
)> {
    let models = saved.models_for(raw_log, job.channels.as_deref(), job.vector.as_deref())?;
    let sensor = choose_vector_sensor(raw_log, Some(&models[0].vector_sensor))?;
    let channels: Vec<String> = models.iter().map(|m| m.channel.clone()).collect();
    choose_channels(raw_log, Some(&channels))?;
    refuse_dead_columns(raw_log, screening, &sensor, Some(&channels))?;
    Ok((models, sensor, channels))
}

/// `log` compensated with the saved `models`, and each channel's figures
/// (its warnings added to `warnings`).
fn compensate_applied(
    log: &FlightLog,
    models: &[crate::model::FittedModel],
    (options, meter): (&Settings, &dyn Meter),
    warnings: &mut Vec<Warning>,
) -> Result<(crate::compensate::Compensation, Vec<ChannelQuality>)> {
    let shared = SharedDesign::of_models(log, models);
    meter.begin(Stage::Assessing, models.len() as u64);
    let mut compensation = crate::compensate::compensate_with(log, models, options.level, &shared)?;
    let quality = assess_applied(log, models, &mut compensation, (options, meter), &shared, warnings)?;
    Ok((compensation, quality))
}

/// The saved model with its channels under this flight's names
/// (`[model] channels`), and the notes saying so; `None` when the names
/// are the same.
fn renamed_model(
    saved: &crate::pipeline::apply::SavedModel,
    recorded: &FlightLog,
    options: &Settings,
) -> Result<(Option<crate::pipeline::apply::SavedModel>, Vec<Note>)> {
    if options.model_channels.is_empty() {
        return Ok((None, Vec::new()));
    }
    let (renamed, notes) = saved.renamed_for(recorded, &options.model_channels)?;
    Ok((Some(renamed), notes))
}

/// The flight's own manoeuvres, when it names them (windows or lines):
/// each model, which never saw them, is held out there, on `log` (the
/// fluxgate calibrated as the model says; `raw_log` gives the windows).
fn hold_out_on_own_windows(
    (job, raw_log, log): (&FlightJob, &FlightLog, &FlightLog),
    (sensor, models): (
        &crate::ingest::flight_log::VectorSensor,
        &mut [crate::model::FittedModel],
    ),
    (options, applied): (&Settings, &crate::pipeline::apply::AppliedModel),
    notes: &mut Vec<Note>,
) -> Result<()> {
    if job.windows.is_empty() && job.lines.is_empty() {
        return Ok(());
    }
    let (windows, _, heading_note) = calibration_windows(raw_log, job, options)?;
    notes.extend(heading_note);
    for model in models {
        model.windows = model.held_out(log, sensor, &windows, &options.fit)?;
    }
    notes.push(Note::ModelHeldOut {
        windows: windows.len(),
        own_flight: applied.fitted_on_this_flight,
    });
    Ok(())
}

/// Warnings and notes gathered along the way.
struct Said {
    warnings: Vec<Warning>,
    notes: Vec<Note>,
}

/// What the compensated channels carry beside themselves on a flight given
/// a saved model: the fluxgates' vector compensation, the gradients, the
/// reduced columns, and the warnings on the output's format and range.
/// `log` is the flight as compensated (its fluxgate calibrated as the
/// model's), `recorded` as read, `compensated` where the output goes.
fn beside_the_scalars(
    (log, recorded, compensated): (&FlightLog, &FlightLog, &Path),
    saved: &crate::pipeline::apply::SavedModel,
    (models, compensation): (&[crate::model::FittedModel], &mut crate::compensate::Compensation),
    options: &Settings,
    mut said: Said,
) -> Result<Said> {
    if options.vector.enabled && log.attitude().is_some() {
        let (vectors, vector_warnings) = saved.vector_compensations(log);
        for vector in vectors {
            compensation.add_vector(vector);
        }
        said.warnings.extend(vector_warnings);
    }
    said.notes.extend(vector_not_run(options, saved, log));
    let gradients = crate::compensate::gradient::gradients_from_saved_model(models, compensation, &options.gradients);
    compensation.gradients = gradients.compensated;
    said.notes.extend(gradients.notes);
    said.warnings.extend(gradients.warnings);
    said.warnings
        .extend(crate::formats::mcap::undated_warning(recorded, compensated));
    said.warnings
        .extend(crate::formats::write::text_columns_warning(recorded, compensated, true));
    let reduced = crate::compensate::reduce::add_reduced(log, compensation, options.reduced)?;
    said.notes.extend(reduced);
    said.warnings.extend(compensation.out_of_range_warnings(log.time_s()));
    Ok(said)
}

/// The flight's notes: the units row skipped, the output's renamed
/// columns, what was said along the way, and the findings each saved
/// model carries.
fn applied_notes(
    (recorded, channels, added_columns): (&FlightLog, &[String], &[String]),
    models: &[crate::model::FittedModel],
    notes: Vec<Note>,
) -> Vec<Note> {
    let mut said: Vec<Note> = units_row_note(recorded).into_iter().collect();
    said.extend(renaming_notes(channels, added_columns));
    said.extend(notes);
    said.extend(
        models
            .iter()
            .filter(|m| !m.spec.is_plain())
            .map(|m| Note::SavedFindings {
                channel: m.channel.clone(),
                model: m.spec.describe(),
            }),
    );
    said
}

/// What the saved model says of itself on this flight: its age and
/// airframe, its calibration's figures, and the magnetometers it holds no
/// model of (written uncompensated), as (warnings, notes).
fn model_words(
    job: &FlightJob,
    options: &Settings,
    saved: &crate::pipeline::apply::SavedModel,
    (applied, channels): (&crate::pipeline::apply::AppliedModel, &[String]),
    raw_log: &FlightLog,
) -> (Vec<Warning>, Vec<Note>) {
    let (mut warnings, mut notes) =
        saved.age_and_aircraft(applied, job.aircraft.as_deref(), options.model_max_age_days);
    if applied.fitted_on_this_flight {
        notes.push(Note::ModelOnItsOwnFlight);
    }
    warnings.extend(saved.calibration_warnings(channels, options.fom_limit_nt));
    let vector = options.vector.enabled && raw_log.attitude().is_some();
    warnings.extend(saved.rate_warning(raw_log, (channels, vector)));
    if job.channels.is_none() {
        // A magnetometer the model does not hold is written uncompensated.
        let left: Vec<&str> = (raw_log.scalar_channels().into_iter())
            .filter(|c| !channels.iter().any(|m| m == c))
            .collect();
        if !left.is_empty() {
            warnings.push(Warning::ModelLacksChannels {
                model: saved.path().to_path_buf(),
                channels: left.iter().map(|c| c.to_string()).collect(),
            });
        }
    }
    (warnings, notes)
}

/// Each compensated channel's figures and sigma column, with the
/// quality warnings and a warning where a channel has no sigma column.
fn assess_applied(
    log: &FlightLog,
    models: &[crate::model::FittedModel],
    compensation: &mut crate::compensate::Compensation,
    (options, meter): (&Settings, &dyn Meter),
    shared: &[SharedDesign],
    warnings: &mut Vec<Warning>,
) -> Result<Vec<ChannelQuality>> {
    let geometry = crate::quality::SurveyGeometry::of(log);
    let mut quality: Vec<ChannelQuality> = models
        .par_iter()
        .zip(compensation.channels.par_iter_mut())
        .map(|(model, channel)| {
            let assessed = assess_with_sigma((log, &geometry), model, channel, shared);
            meter.step();
            assessed.map(|(quality, _)| quality)
        })
        .collect::<Result<_>>()?;
    if models.iter().all(|m| m.windows.is_empty()) {
        // No calibration windows here: no band figures (the model's are
        // its calibration flight's, in the model section).
        for q in &mut quality {
            q.improvement_ratio = f64::NAN;
            q.band_std_before_nt = f64::NAN;
            q.band_std_after_nt = f64::NAN;
        }
    }
    let next_step = "The model is its calibration flight's: fly a new calibration box and apply its model, or compare with the calibration flight's report";
    for (q, channel) in quality.iter().zip(&compensation.channels) {
        // Nothing is refitted: no solver to suggest.
        warnings.extend(crate::quality::quality_warnings(
            q,
            options.fom_limit_nt,
            (next_step, false),
        ));
        if channel.sigma_nt.is_none() {
            let channel = q.channel.clone();
            warnings.push(match q.uncertainty {
                None => Warning::SavedWithoutJackknife { channel },
                Some(_) => Warning::NoSigmaColumn { channel },
            });
        }
    }
    Ok(quality)
}

/// The note on the vector compensation a saved model cannot run (it holds
/// no vector model), when the settings ask for it and the flight records a
/// fluxgate.
fn vector_not_run(options: &Settings, saved: &crate::pipeline::apply::SavedModel, log: &FlightLog) -> Option<Note> {
    if !options.vector.enabled || log.vector_sensors().is_empty() {
        return None;
    }
    match (log.attitude().is_some(), saved.has_vector_models()) {
        (false, _) => Some(Note::NoSavedVectorCompensation { attitude: false }),
        (true, false) => Some(Note::NoSavedVectorCompensation { attitude: true }),
        (true, true) => None,
    }
}
