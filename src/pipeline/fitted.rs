//! A flight fitted on its own calibration: [`super::run`]'s stages when no
//! saved model is applied. Prepare (screen, choose, windows); calibrate
//! the fluxgate; diagnose and judge the findings; fit every channel;
//! compensate; assess; the vector and gradient stages; the words.

use std::collections::BTreeMap;
use std::path::Path;

use rayon::prelude::*;

use super::diagnosis::{applied_findings, augmentation_plan, evidence_rule, next_step, Departures, ExtensionsPlan};
use super::prepared::{detection_notes, detection_warnings, PreparedFlight};
use super::vector_stage::{vector_fits, vector_reference, window_hulls, VectorStage};
use super::{
    against_plan, assess_with_sigma, estimator_table_gap, renaming_notes, units_row_note, FlightResult, FlightRun,
};
use crate::compensate::gradient::GradientStage;
use crate::config::{FlightJob, Settings};
use crate::error::Result;
use crate::formats::added_column_names;
use crate::ingest::flight_log::FlightLog;
use crate::messages::progress::{Meter, Stage};
use crate::messages::{Note, Warning};
use crate::model::{compare_estimators, fit, Calibration, Extensions, FittedModel, ModelSpec, SharedDesign};
use crate::numerics::stacked::StorePool;
use crate::quality::transfer::check_transfer;
use crate::quality::ChannelQuality;

/// [`super::run`] for a flight fitted on its own calibration: prepared,
/// its fluxgate calibrated, diagnosed, fitted, compensated and assessed,
/// then what it says gathered.
pub(super) fn run_fitted(
    job: &FlightJob,
    options: &Settings,
    compensated: &Path,
    planned: Option<crate::quality::against_plan::PlanPrediction>,
    recorded: FlightLog,
    meter: &dyn Meter,
) -> Result<FlightRun> {
    meter.begin(Stage::Preparing, 0);
    let flight = PreparedFlight::new(recorded, job, options)?;
    // The fit (and everything after it) sees the calibrated fluxgate; the
    // compensated file keeps the recorded columns.
    let fluxgate = crate::calibration::fluxgate::calibrate_stage(&flight.calibration(), &options.vector_calibration)?;
    let calibrated = (fluxgate.as_ref())
        .map(|c| c.apply(flight.log(), &flight.sensor))
        .transpose()?;
    let on = flight.calibration().on(calibrated.as_ref().unwrap_or(flight.log()));
    let mut warnings: Vec<Warning> = flight.warnings();
    let (plan, mut diagnosis, departures) =
        diagnosed_plan(job, (&flight, &on), (options, meter), fluxgate.is_some(), &mut warnings)?;
    warnings.extend(input_warnings(job, &flight.recorded, compensated)?);
    let fitted = fit_channels(&on, &plan, options, meter)?;
    let mut assessed = compensate_and_assess(&flight, &on, fitted, (options, meter))?;
    let added_columns = added_column_names(on.log, compensated, &assessed.compensation)?;
    let stage_notes: Vec<Note> = (flight.headings_note.iter().cloned())
        .chain(fluxgate.iter().map(|c| c.summary()))
        .collect();
    let next_step = next_step(options.diagnose.apply, job.diagnosis.is_some(), diagnosis.is_some());
    let mut notes = Vec::new();
    let flown = (&flight, on.log, added_columns.as_slice(), stage_notes);
    assessed.messages(flown, (&departures, next_step), options, (&mut notes, &mut warnings));
    let plan = planned.map(|planned| assessed.against(&planned, on.log, (&mut notes, &mut warnings)));
    let (rows, alignment) = (on.log.len(), on.log.alignment().cloned());
    let PreparedFlight {
        recorded,
        screened,
        detection,
        ..
    } = flight;
    let result = FlightResult {
        flight: job.input.clone(),
        rows,
        added_columns,
        notes,
        detection,
        alignment,
        channels: assessed.quality,
        vector_calibration: fluxgate,
        diagnosis_mode: match job.diagnosis {
            Some(_) => crate::diagnose::ApplyDiagnosis::Always,
            None => options.diagnose.apply,
        },
        applied_findings: diagnosis.as_mut().map(|d| applied_findings(d)).unwrap_or_default(),
        warnings,
        diagnosis,
        models: assessed.models,
        vector_models: assessed.vector.models,
        gradients: assessed.gradients.results,
        gradient_models: assessed.gradients.models,
        plan,
        model: None,
        aircraft: job.aircraft.clone(),
    };
    Ok(FlightRun::finished(
        (recorded, screened),
        assessed.compensation,
        result,
        options,
    ))
}

/// A fitted flight compensated and assessed: its channels, their figures,
/// the vector stage and the gradients, and what these stages said.
struct Assessed {
    models: Vec<FittedModel>,
    compensation: crate::compensate::Compensation,
    quality: Vec<ChannelQuality>,
    vector: VectorStage,
    gradients: GradientStage,
    /// The notes of the stages (reduced columns, transfer).
    notes: Vec<Note>,
    excitation_notes: Vec<Option<Note>>,
}

/// Compensates every row of every fitted channel and assesses each, the
/// vector stage beside it, then adds the gradients and the reduced columns.
fn compensate_and_assess(
    flight: &PreparedFlight,
    on: &Calibration,
    mut fitted: Fitted,
    (options, meter): (&Settings, &dyn Meter),
) -> Result<Assessed> {
    meter.begin(Stage::Assessing, fitted.models.len() as u64);
    let mut compensation = crate::compensate::compensate_with(on.log, &fitted.models, options.level, &fitted.shared)?;
    let boxes: Vec<(f64, f64)> = match &flight.detection {
        Some(detection) => detection.boxes.iter().map(|b| (b.t_start, b.t_end)).collect(),
        None => window_hulls(&flight.windows),
    };
    // The vector stage reads the channels' interference only: its fits run
    // beside the channels' assessment and the gradients.
    let reference = vector_reference(
        on.log,
        (on.windows, &boxes),
        (&compensation, &fitted.models),
        &options.vector,
    );
    let (assessed, mut vector) = rayon::join(
        || -> Result<_> {
            let (quality, transfer_notes) =
                assess_channels(on, &mut fitted, &mut compensation, &boxes, (options, meter))?;
            let gradients = gradient_stage(on, (&compensation, &fitted, &quality), options);
            Ok((quality, transfer_notes, gradients))
        },
        || match reference {
            Ok(reference) => vector_fits(
                on.log,
                (on.windows, &boxes),
                &reference,
                (&options.vector, &options.fit),
            ),
            Err(ended) => ended,
        },
    );
    let (quality, transfer_notes, mut gradients) = assessed?;
    let Fitted { models, shared, .. } = fitted;
    drop(shared);
    for compensated in std::mem::take(&mut vector.compensated) {
        compensation.add_vector(compensated);
    }
    compensation.gradients = std::mem::take(&mut gradients.compensated);
    let reduced_notes = crate::compensate::reduce::add_reduced(on.log, &mut compensation, options.reduced)?;
    Ok(Assessed {
        models,
        compensation,
        quality,
        vector,
        gradients,
        notes: reduced_notes.into_iter().chain(transfer_notes).collect(),
        excitation_notes: fitted.excitation_notes,
    })
}

impl Assessed {
    /// The flight set against the plan it was flown to ([`against_plan`]),
    /// with the comparison's notes and warnings added.
    fn against(
        &self,
        planned: &crate::quality::against_plan::PlanPrediction,
        log: &FlightLog,
        (notes, warnings): (&mut Vec<Note>, &mut Vec<Warning>),
    ) -> crate::quality::against_plan::PlanComparison {
        let plan = against_plan(planned, log, &self.models, &self.quality, &self.compensation);
        notes.extend(plan.notes.iter().cloned());
        warnings.extend(plan.warnings.iter().cloned());
        plan
    }

    /// Adds what the input's columns say (a row of units, the added
    /// columns' names), what the stages said (with `stage_notes`, the
    /// flight's own), the detection's words, and the warnings of each
    /// channel's figures (`departures`: how far its findings move the
    /// survey; `next_step`: what to do about a poor fit) to `notes` and
    /// `warnings`.
    fn messages(
        &mut self,
        (flight, log, added_columns, stage_notes): (&PreparedFlight, &FlightLog, &[String], Vec<Note>),
        (departures, next_step): (&Departures, &str),
        options: &Settings,
        (notes, warnings): (&mut Vec<Note>, &mut Vec<Warning>),
    ) {
        notes.extend(units_row_note(&flight.recorded));
        notes.extend(renaming_notes(&flight.channels, added_columns));
        warnings.extend(self.compensation.out_of_range_warnings(log.time_s()));
        notes.append(&mut self.notes);
        notes.extend(stage_notes);
        let excitation = std::mem::take(&mut self.excitation_notes);
        model_messages(&self.models, excitation, (notes, warnings));
        notes.extend(station_notes(log, &self.models));
        let (vector, gradients) = (&mut self.vector, &mut self.gradients);
        notes.append(&mut vector.notes);
        notes.append(&mut gradients.notes);
        warnings.append(&mut vector.warnings);
        warnings.append(&mut gradients.warnings);
        if let Some(detection) = &flight.detection {
            notes.extend(detection_notes(detection));
            warnings.extend(detection_warnings(detection));
        }
        warnings.extend(departure_warnings(log, &mut self.quality, departures));
        warnings.extend(channel_warnings(
            &self.quality,
            &self.models,
            &self.compensation,
            options,
            next_step,
        ));
    }
}

/// Each channel's model to fit: the saved diagnosis's, or a diagnosis's
/// made now and judged by the evidence rule (its warnings added to
/// `warnings`); with the diagnosis made now and how far each channel's
/// applied findings move the survey from plain Tolles-Lawson.
#[allow(clippy::type_complexity)]
fn diagnosed_plan(
    job: &FlightJob,
    (flight, on): (&PreparedFlight, &Calibration),
    (options, meter): (&Settings, &dyn Meter),
    stage_calibrated: bool,
    warnings: &mut Vec<Warning>,
) -> Result<(
    BTreeMap<String, Extensions>,
    Option<crate::diagnose::Diagnosis>,
    Departures,
)> {
    let ExtensionsPlan {
        models: plan,
        mut diagnosis,
        warnings: said,
    } = augmentation_plan(job, flight.log(), on, (options, meter), stage_calibrated)?;
    warnings.extend(said);
    let (plan, departures) = match diagnosis.as_mut() {
        Some(diagnosis) => {
            meter.begin(Stage::Checking, 0);
            evidence_rule(on, plan, diagnosis, options, warnings)?
        }
        None => (plan, BTreeMap::new()),
    };
    Ok((plan, diagnosis, departures))
}

/// Warnings about the input that depend on where the output goes: windows
/// detected on another flight, an MCAP output without a date, text
/// columns a format cannot hold.
fn input_warnings(job: &FlightJob, recorded: &FlightLog, compensated: &Path) -> Result<Vec<Warning>> {
    let mut warnings = Vec::new();
    if let Some((path, detected_on)) = &job.windows_detected_on {
        warnings.extend(crate::calibration::windows::other_flight_warning(
            path,
            detected_on,
            recorded,
        )?);
    }
    warnings.extend(crate::formats::mcap::undated_warning(recorded, compensated));
    warnings.extend(crate::formats::write::text_columns_warning(recorded, compensated, true));
    Ok(warnings)
}

/// Every channel's fitted model, the whole flight's terms they share, and
/// a note per channel whose excitation could not be analysed.
struct Fitted {
    models: Vec<FittedModel>,
    shared: Vec<SharedDesign>,
    excitation_notes: Vec<Option<Note>>,
}

/// Fits every channel of `on` with its model of `plan`, its estimator
/// table and its excitation analysis.
fn fit_channels(
    on: &Calibration,
    plan: &BTreeMap<String, Extensions>,
    options: &Settings,
    meter: &dyn Meter,
) -> Result<Fitted> {
    let Calibration {
        log,
        sensor,
        channels,
        windows,
    } = *on;
    // The channels' fits share their stores; the stores are freed before
    // compensating, which does not need them.
    let stores = StorePool::new();
    meter.begin(Stage::Fitting, channels.len() as u64);
    let fitted: Vec<FittedModel> = channels
        .par_iter()
        .map(|channel| {
            let spec = ModelSpec::of_channel(options.terms, plan, channel);
            let mut model = fit(log, sensor, channel, windows, &spec, &options.fit, &stores)?;
            model.estimators = compare_estimators(log, sensor, channel, windows, &spec, &options.fit, &stores)?;
            meter.step();
            Ok(model)
        })
        .collect::<Result<_>>()?;
    // The whole flight's terms, built once for every channel that uses
    // them: the analysis, the compensation and the sigma column read them.
    let shared = SharedDesign::of_models(log, &fitted);
    let fitted: Vec<(FittedModel, Option<Note>)> = fitted
        .into_par_iter()
        .map(|mut model| {
            let channel = model.channel.clone();
            // The analysis informs; a flight it cannot analyse is still
            // compensated, and the run says why there is none.
            let excitation =
                crate::model::excitation::analyse(log, sensor, &model, windows, &options.fit, (&stores, &shared));
            let note = match excitation {
                Ok(Some(analysis)) => {
                    model.excitation = Some(analysis);
                    None
                }
                Ok(None) => Some(Note::NoExcitationAnalysis {
                    channel,
                    why: "a window's heading is unknown (none given and no INS yaw), or the windows leave the design singular".into(),
                }),
                Err(e) => Some(Note::NoExcitationAnalysis {
                    channel,
                    why: e.to_string(),
                }),
            };
            Ok((model, note))
        })
        .collect::<Result<_>>()?;
    let (models, excitation_notes) = fitted.into_iter().unzip();
    Ok(Fitted {
        models,
        shared,
        excitation_notes,
    })
}

/// Each compensated channel's figures, its sigma column, its transfer
/// checks held out (by heading and box to box), with the transfer notes
/// in channel order; each model keeps its level over this calibration,
/// for the flights it is applied to (the model JSON).
fn assess_channels(
    on: &Calibration,
    fitted: &mut Fitted,
    compensation: &mut crate::compensate::Compensation,
    boxes: &[(f64, f64)],
    (options, meter): (&Settings, &dyn Meter),
) -> Result<(Vec<ChannelQuality>, Vec<Note>)> {
    let Calibration {
        log, sensor, windows, ..
    } = *on;
    let stores = StorePool::new();
    let shared = &fitted.shared;
    let geometry = crate::quality::SurveyGeometry::of(log);
    let assessed: Vec<(ChannelQuality, Vec<f64>, Vec<Note>)> = (fitted.models.par_iter())
        .zip(compensation.channels.par_iter_mut())
        .map(|(model, channel)| {
            let (mut quality, jackknife_levels) = assess_with_sigma((log, &geometry), model, channel, shared)?;
            quality.transfer = check_transfer(log, sensor, model, windows, (&options.fit, &options.transfer), &stores)?;
            quality.fluxgates = crate::quality::transfer::compare_fluxgates(
                log,
                (sensor, quality.transfer.as_ref()),
                model,
                windows,
                (&options.fit, &options.transfer),
                &stores,
            );
            let (transfers, notes) =
                crate::quality::transfer::box_transfer(log, sensor, model, windows, boxes, &options.fit, &stores)?;
            quality.box_transfer = transfers;
            meter.step();
            Ok((quality, jackknife_levels, notes))
        })
        .collect::<Result<_>>()?;
    let mut quality = Vec::with_capacity(assessed.len());
    let mut transfer_notes = Vec::new();
    for ((model, (q, jackknife_nt, notes)), channel) in
        (fitted.models.iter_mut()).zip(assessed).zip(&compensation.channels)
    {
        model.calibration_level = Some(crate::model::CalibrationLevel {
            interference_nt: channel.calibration_interference_nt,
            jackknife_nt,
        });
        quality.push(q);
        transfer_notes.extend(notes);
    }
    // In channel order, as they always were sorted.
    transfer_notes.sort_by_cached_key(Note::to_string);
    Ok((quality, transfer_notes))
}

/// The gradients of `options` from the fitted channels and their
/// compensation, assessed (`quality`).
fn gradient_stage(
    on: &Calibration,
    (compensation, fitted, quality): (&crate::compensate::Compensation, &Fitted, &[ChannelQuality]),
    options: &Settings,
) -> GradientStage {
    crate::compensate::gradient::compensate_gradients(
        &crate::compensate::gradient::GradientInputs {
            log: on.log,
            sensor: on.sensor,
            windows: on.windows,
            models: &fitted.models,
            compensation,
            shared: &fitted.shared,
            uncertain: &quality.iter().map(crate::quality::is_uncertain).collect::<Vec<_>>(),
        },
        &options.gradients,
        (options.terms, &options.fit, options.level),
    )
}

/// How each base station the models subtract was used: low-passed where
/// its own noise takes over, or as recorded ([`crate::model::station`]).
fn station_notes(log: &FlightLog, models: &[FittedModel]) -> Vec<Note> {
    let mut stations: Vec<(&str, Vec<String>)> = Vec::new();
    for model in models {
        for source in &model.spec.extensions.sources {
            if let crate::model::SourceTerm::ExternalField { column, .. } = source {
                match stations.iter_mut().find(|(c, _)| c == column) {
                    Some((_, channels)) => channels.push(model.channel.clone()),
                    None => stations.push((column, vec![model.channel.clone()])),
                }
            }
        }
    }
    (stations.into_iter())
        .filter_map(|(column, channels)| {
            let quiet = crate::model::station::shared_quiet_station(log, column)?;
            Some(Note::QuietStation {
                column: column.to_string(),
                filter: quiet.filter,
                noise_nt: quiet.noise_nt,
                channels,
            })
        })
        .collect()
}

/// What the models say of themselves: a missing estimator table, an
/// excitation not analysed and a diagnosed model, as notes; a gap in the
/// box and a solver asked for and not used, as warnings.
fn model_messages(
    models: &[FittedModel],
    excitation_notes: Vec<Option<Note>>,
    (notes, warnings): (&mut Vec<Note>, &mut Vec<Warning>),
) {
    notes.extend(models.iter().filter_map(estimator_table_gap));
    notes.extend(excitation_notes.into_iter().flatten());
    // A gap in the box is a warning: the FOM lacks a manoeuvre and the
    // coefficients it pins are less certain.
    warnings.extend(models.iter().flat_map(|m| {
        let gaps = m.excitation.iter().flat_map(|e| e.gaps());
        gaps.map(|gap| Warning::BoxGap {
            channel: m.channel.clone(),
            gap,
        })
        .collect::<Vec<_>>()
    }));
    // A manoeuvre cut by gaps is a warning: its FOM cell counts only what
    // was kept.
    warnings.extend(models.iter().filter_map(|m| {
        let manoeuvres: Vec<String> = (m.windows.iter().filter(|w| w.cut_by_gaps()))
            .map(|w| {
                format!(
                    "{}: {} of {} samples kept",
                    w.window.display_label(),
                    w.samples_in_window - w.samples_lost_to_gaps,
                    w.samples_in_window
                )
            })
            .collect();
        (!manoeuvres.is_empty()).then(|| Warning::ManoeuvresCut {
            channel: m.channel.clone(),
            manoeuvres,
        })
    }));
    // A solver asked for and not used is a warning: the coefficients are
    // not what the settings say.
    warnings.extend(models.iter().filter_map(|m| {
        let solver = m.solver.as_ref()?;
        match solver.applied() {
            true => None,
            false => Some(Warning::SolverNotUsed {
                channel: m.channel.clone(),
                reason: solver.reason.clone(),
            }),
        }
    }));
    notes.extend(
        models
            .iter()
            .filter(|m| !m.spec.is_plain())
            .map(|m| Note::DiagnosedModel {
                channel: m.channel.clone(),
                model: m.spec.describe(),
            }),
    );
}

/// Sets each channel's departure from plain Tolles-Lawson on the survey;
/// a warning for each that exceeds its stated uncertainty.
/// `log`'s survey figures of each departing channel are set against
/// plain Tolles-Lawson's ([`crate::quality::PlainSurvey`]).
fn departure_warnings(log: &FlightLog, quality: &mut [ChannelQuality], departures: &Departures) -> Vec<Warning> {
    let mut warnings = Vec::new();
    let geometry = (!departures.is_empty()).then(|| crate::quality::SurveyGeometry::of(log));
    for q in quality {
        let departure = departures.get(&q.channel);
        q.survey_departure_from_plain_nt = departure.map(|d| d.nt);
        if let (Some(departure), Some(geometry), Some(scalar)) = (departure, &geometry, log.channel(&q.channel)) {
            q.plain_survey = crate::quality::PlainSurvey::of(log, geometry, (&scalar.values, &departure.plain));
        }
        if let (Some((departure_nt, stated_nt)), Some(departure)) = (q.unchecked_departure(), departure) {
            warnings.push(Warning::SurveyDeparture {
                channel: q.channel.clone(),
                moved_by: departure.moved_by,
                departure_nt,
                stated_nt,
                advice: crate::quality::verdict::which_to_use(q),
            });
        }
    }
    warnings
}

/// Each channel's quality warnings, and a warning where it has no sigma
/// column, too few windows to leave one out, or no uncertainty figure.
fn channel_warnings(
    quality: &[ChannelQuality],
    models: &[FittedModel],
    compensation: &crate::compensate::Compensation,
    options: &Settings,
    next_step: &str,
) -> Vec<Warning> {
    let mut warnings = Vec::new();
    for ((q, model), channel) in quality.iter().zip(models).zip(&compensation.channels) {
        let suggest_solver = options.fit.solver != crate::numerics::estimators::Solver::Auto;
        warnings.extend(crate::quality::quality_warnings(
            q,
            options.fom_limit_nt,
            (next_step, suggest_solver),
        ));
        if q.uncertainty.is_some() && channel.sigma_nt.is_none() {
            warnings.push(Warning::NoSigmaColumn {
                channel: model.channel.clone(),
            });
        }
        if model.windows.len() < 3 {
            warnings.push(Warning::TooFewWindows {
                channel: model.channel.clone(),
                windows: model.windows.len(),
            });
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
            warnings.push(Warning::NoUncertainty {
                channel: model.channel.clone(),
                why,
            });
        }
    }
    warnings
}
