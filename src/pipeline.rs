//! One flight through every stage: read, screen, detect, diagnose, fit,
//! compensate, assess. [`run`] writes nothing; [`crate::sink`] writes what
//! it produced.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::config::{FlightJob, Settings};
use crate::detect::{detect_manoeuvres, Detection};
use crate::diagnose::EffectKind;
use crate::error::{Error, Result};
use crate::flight_log::{FlightLog, VectorSensor};
use crate::formats::added_column_names;
use crate::formats::align::AlignmentReport;
use crate::formats::read_flight_log;
use crate::model::{compare_estimators, fit, Extensions, FitOptions, FittedModel, ModelSpec, SharedDesign};
use crate::numerics::stacked::StorePool;
use crate::quality::transfer::check_transfer;
use crate::quality::{assess_quality, ChannelQuality};
use rayon::prelude::*;

pub use crate::diagnose::AppliedFinding;

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

/// What the vector stage produced: models, compensated vectors, words.
struct VectorStage {
    models: Vec<crate::vector::VectorModel>,
    compensated: Vec<crate::vector::CompensatedVector>,
    notes: Vec<String>,
    warnings: Vec<String>,
}

/// Fitted direction further than this from IGRF's, degrees: a warning (a
/// wrong attitude convention, date or position, a box without pitches and
/// rolls, or a fluxgate the twelve constants do not describe). IGRF's
/// direction at survey height is good to about 0.1° away from strong
/// anomalies, and on simulated flights the fit lands within 0.2° of it;
/// 0.5° is F·sin 0.5° ≈ 450 nT across the field at 50 000 nT.
const VECTOR_DIRECTION_WARNING_DEG: f64 = 0.5;

/// The reference channel's aircraft field swinging by more than this over
/// the box (RMS, nT) is a warning: the vector's scale rests on its level.
const VECTOR_SWING_WARNING_NT: f64 = 10.0;

/// Vector-compensates every fluxgate of `log` with the twelve-constant
/// model fitted on `windows`, the field's size from the scalar channel
/// with the least aircraft field over the box: when `[vector] enabled` and the flight records an
/// INS attitude. A fluxgate whose fit fails is a warning, not an error:
/// the scalar outputs stand.
fn vector_stage(
    log: &FlightLog,
    (windows, boxes): (&[crate::windows::CalibrationWindow], &[(f64, f64)]),
    compensation: &crate::compensate::Compensation,
    (options, fit_options): (&crate::vector::VectorOptions, &FitOptions),
) -> VectorStage {
    let mut stage = VectorStage {
        models: Vec::new(),
        compensated: Vec::new(),
        notes: Vec::new(),
        warnings: Vec::new(),
    };
    if !options.enabled {
        return stage;
    }
    if log.attitude().is_none() {
        stage
            .notes
            .push("no vector compensation: the flight records no INS attitude (roll, pitch and yaw)".into());
        return stage;
    }
    // The reference is the channel with the least aircraft field over the
    // box: its level, which the vector's scale rests on, is the surest.
    let reference = compensation
        .channels
        .iter()
        .filter_map(|c| {
            let recorded = log.channel(&c.channel)?.values.as_slice();
            crate::vector::Reference::levelled(log, &c.channel, (recorded, &c.interference_nt), (windows, boxes))
        })
        .filter(|r| r.swing_nt.is_finite())
        .min_by(|a, b| a.swing_nt.total_cmp(&b.swing_nt));
    let Some(reference) = reference else {
        stage.warnings.push(
            "no vector compensation: no compensated scalar channel has a reading on the calibration box to give the field's size"
                .into(),
        );
        return stage;
    };
    for sensor in log.vector_sensors() {
        let stage_options = options.tolles_lawson.then_some(fit_options);
        let fitted = crate::vector::fit(
            log,
            &sensor,
            (windows, boxes),
            &reference,
            (options.site.as_ref(), stage_options),
        )
        .and_then(|model| Ok((model.compensate(log)?, model)));
        match fitted {
            Ok((compensated, model)) => {
                stage.notes.push(vector_note(&model));
                if model.reference_swing_nt > VECTOR_SWING_WARNING_NT {
                    stage.warnings.push(format!(
                        "{}: the vector's scale rests on {}'s level over the box, where the aircraft's modelled field swings by {:.1} nT RMS: its mean there, which no manoeuvre pins, may be as large and is an error of up to that size on each vector component (a scalar sensor on a tail stinger gives a surer level)",
                        model.sensor, model.reference, model.reference_swing_nt
                    ));
                }
                if let Some(warning) = vector_direction_warning(&model) {
                    stage.warnings.push(warning);
                }
                stage.warnings.extend(vector_sign_warning(&model));
                if model.held_out.is_none() {
                    stage.warnings.push(format!(
                        "{}: the twelve-constant fit's windows do not give three headings (a window given by time that spans a turn has none), so no heading is held out and the vector's accuracy away from them is not checked; give the box's manoeuvres or legs as windows",
                        model.sensor
                    ));
                }
                if let Some(reason) = &model.tolles_lawson_warning {
                    stage
                        .warnings
                        .push(format!("{}: vector Tolles-Lawson: {reason}", model.sensor));
                }
                stage.compensated.push(compensated);
                stage.models.push(model);
            }
            Err(e) => stage
                .warnings
                .push(format!("{}: no vector compensation: {e}", sensor.prefix)),
        }
    }
    stage
}

/// Windows closer than this are taken as one box's, and the flight
/// between them (the turns between legs) as the box's too, s.
const BOX_GAP_S: f64 = 150.0;

/// The spans of given windows (no detection): windows less than
/// [`BOX_GAP_S`] apart joined, the flight between them included.
fn window_hulls(windows: &[crate::windows::CalibrationWindow]) -> Vec<(f64, f64)> {
    let mut spans: Vec<(f64, f64)> = windows.iter().map(|w| (w.t_start, w.t_end)).collect();
    spans.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut hulls: Vec<(f64, f64)> = Vec::new();
    for (t0, t1) in spans {
        match hulls.last_mut() {
            Some(last) if t0 - last.1 <= BOX_GAP_S => last.1 = last.1.max(t1),
            _ => hulls.push((t0, t1)),
        }
    }
    hulls
}

/// One line on a vector model.
fn vector_note(model: &crate::vector::VectorModel) -> String {
    let [x, y, z] = model.residual_rms_nt;
    let mut text = format!(
        "{}: vector-compensated with the twelve-constant model on {} calibration rows, the field's size from {} levelled at its recorded mean over the box (the aircraft's mean field at that sensor, which no manoeuvre pins, scales the vector: δ nT there is up to δ nT on a component; its modelled interference swings by {:.2} nT RMS over the box): residual x/y/z {x:.2}/{y:.2}/{z:.2} nT",
        model.sensor, model.rows, model.reference, model.reference_swing_nt
    );
    if let Some(held) = &model.held_out {
        let [x, y, z] = held.rms_nt;
        text += &format!(
            ", held out by heading ({} headings) {x:.2}/{y:.2}/{z:.2} nT",
            held.headings
        );
    }
    text += &format!(
        "; Earth field inclination {:.3}°, declination {:.3}°",
        model.inclination_deg, model.declination_deg
    );
    if let crate::vector::FieldStart::Igrf {
        inclination_deg,
        declination_deg,
        position,
        ..
    } = model.start
    {
        let at = match position {
            crate::vector::PositionSource::Recorded => "",
            crate::vector::PositionSource::Site => " at the [site]",
        };
        text += &format!(" (IGRF-14{at}: {inclination_deg:.3}°, {declination_deg:.3}°)");
    }
    text += &format!("; {}", model.mounting.describe());
    if let Some(stage) = &model.tolles_lawson {
        let axes = |v: [f64; 3]| format!("{:.2}/{:.2}/{:.2}", v[0], v[1], v[2]);
        text += &format!(
            "; vector Tolles-Lawson (eddy currents, per axis): band-passed residual x/y/z {} → {} nT",
            axes(stage.band_rms_before_nt),
            axes(stage.band_rms_after_nt)
        );
        if let Some(held) = &stage.held_out {
            text += &format!(
                ", held out by heading {} → {} nT",
                axes(held.before_nt),
                axes(held.after_nt)
            );
        }
    }
    text
}

/// A warning when the field's sign could not be checked (no position, no
/// `[site]`), or when IGRF-14 fixed it and the fluxgate's axes came out
/// left-handed.
fn vector_sign_warning(model: &crate::vector::VectorModel) -> Option<String> {
    use crate::vector::FieldSign;
    match model.field_sign {
        FieldSign::RightHandedAxes => Some(format!(
            "{}: the Earth field's direction is unverified: the flight records no position (lat, lon) and pipeline.toml sets no [site], and the data fix the direction only up to its sign (a fluxgate reading reversed on all three axes under a field pointing up reads as this one does); it is taken so that the fluxgate's axes are right-handed: inclination {:.2}°, declination {:.2}°, {}. Set [site] latitude, longitude and date to check it against IGRF-14. Without a position the field's turn across the box (about 0.01° a km) is not modelled either: expect tens of nT on each component",
            model.sensor,
            model.inclination_deg,
            model.declination_deg,
            model.mounting.describe()
        )),
        FieldSign::Igrf if !model.mounting.right_handed => Some(format!(
            "{}: with the field's sign from IGRF-14, the fluxgate's axes are left-handed (det K < 0): one axis, or all three, read reversed (the wiring, or a sign in the file); the vector output is in the INS's body axes as fitted, but check the fluxgate's axis signs, and the position and date if its axes are known to be right-handed",
            model.sensor
        )),
        FieldSign::Igrf => match model.start {
            crate::vector::FieldStart::Igrf {
                position: crate::vector::PositionSource::Site,
                ..
            } => Some(format!(
                "{}: the flight records no position: the field's sign and direction are checked against IGRF-14 at the [site], but the field's turn across the box (about 0.01° a km) is not modelled: expect tens of nT on each component (a few with lat and lon columns)",
                model.sensor
            )),
            _ => None,
        },
    }
}

/// A warning when the fitted field direction is further than
/// [`VECTOR_DIRECTION_WARNING_DEG`] from IGRF's (the angle between them).
fn vector_direction_warning(model: &crate::vector::VectorModel) -> Option<String> {
    let crate::vector::FieldStart::Igrf {
        inclination_deg,
        declination_deg,
        dated,
        total_nt,
        ..
    } = model.start
    else {
        return None;
    };
    let unit = |inclination: f64, declination: f64| {
        let (i, d) = (inclination.to_radians(), declination.to_radians());
        nalgebra::Vector3::new(i.cos() * d.cos(), i.cos() * d.sin(), i.sin())
    };
    let angle = unit(model.inclination_deg, model.declination_deg)
        .angle(&unit(inclination_deg, declination_deg))
        .to_degrees();
    let d_incl = model.inclination_deg - inclination_deg;
    let d_decl = (model.declination_deg - declination_deg + 540.0).rem_euclid(360.0) - 180.0;
    (angle > VECTOR_DIRECTION_WARNING_DEG).then(|| {
        format!(
            "{}: the vector-compensated field's direction is {angle:.2}° from IGRF-14's ({d_incl:.2}° in inclination, {d_decl:.2}° in declination; more than {VECTOR_DIRECTION_WARNING_DEG}°){}: check the INS attitude convention (CONTRACT §1), the position columns and the flight's date; the vector may be rotated by as much, {:.0} nT across the field",
            model.sensor,
            if dated { "" } else { " with no flight date (IGRF taken at 2025.0)" },
            total_nt * angle.to_radians().sin()
        )
    })
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

/// The findings of `diagnosis` that change the model of a channel whose
/// diagnosed model is not plain (an `unexplained` finding changes none).
fn applied_findings(diagnosis: &crate::diagnose::Diagnosis) -> Vec<AppliedFinding> {
    let changed = |channel: &str| {
        diagnosis
            .channels
            .iter()
            .any(|c| c.channel == channel && !c.model.is_plain())
    };
    let calibrated_channels: Vec<&str> = diagnosis
        .channels
        .iter()
        .filter(|c| c.model.vector_calibration.is_some())
        .map(|c| c.channel.as_str())
        .collect();
    diagnosis
        .findings
        .iter()
        .filter(|f| f.effect.kind() != EffectKind::Unexplained && f.not_applied.is_none())
        .filter(|f| f.effect.kind() == EffectKind::VectorCalibration || changed(&f.channel))
        .filter(|f| f.effect.kind() != EffectKind::VectorCalibration || !calibrated_channels.is_empty())
        .map(|f| AppliedFinding {
            channel: match f.effect.kind() {
                EffectKind::VectorCalibration => format!("{} (for {})", f.channel, calibrated_channels.join(", ")),
                _ => f.channel.clone(),
            },
            effect: f.effect.kind(),
            source: f.source.clone(),
            heldout_rms_before_nt: f.heldout_rms_before_nt,
            heldout_rms_after_nt: f.heldout_rms_after_nt,
        })
        .collect()
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

/// Compensates `job`'s flight with the saved model at `model_path`,
/// nothing refitted; `compensated` is where the output will go (for the
/// warnings that depend on its format). The flight's own windows or lines,
/// when given, hold the model out.
fn run_applied(
    job: &FlightJob,
    options: &Settings,
    compensated: &Path,
    saved: &crate::apply::SavedModel,
    recorded: FlightLog,
) -> Result<FlightRun> {
    let screened = crate::screen::screen_samples(&recorded)?;
    let raw_log = screened.log_or(&recorded);
    let mut models = saved.models_for(raw_log, job.channels.as_deref(), job.vector.as_deref())?;
    let sensor = choose_vector_sensor(raw_log, Some(&models[0].vector_sensor))?;
    let channels: Vec<String> = models.iter().map(|m| m.channel.clone()).collect();
    choose_channels(raw_log, Some(&channels))?;
    refuse_dead_columns(raw_log, &screened.screening, &sensor, Some(&channels))?;
    let applied = saved.applied(raw_log.date(), &recorded)?;
    let (mut warnings, mut notes) =
        saved.age_and_aircraft(&applied, job.aircraft.as_deref(), options.model_max_age_days);
    if applied.fitted_on_this_flight {
        notes.push("the model was fitted on this very flight: its compensation is that of the calibration run".into());
    }
    warnings.extend(saved.calibration_warnings(&channels, options.fom_limit_nt));
    if job.channels.is_none() {
        // A magnetometer the model does not hold is written uncompensated.
        let left: Vec<&str> = (raw_log.scalar_channels().into_iter())
            .filter(|c| !channels.iter().any(|m| m == c))
            .collect();
        if !left.is_empty() {
            let them = if left.len() == 1 { "it" } else { "them" };
            warnings.push(format!(
                "{} not compensated: the model {} holds no model of {them}; calibrate {them} on a flight with a box, or name this flight's channels with --channels",
                left.join(", "),
                saved.path().display(),
            ));
        }
    }
    warnings.splice(0..0, screened.warnings(&recorded));
    let calibrated = saved
        .vector_calibration()
        .map(|c| c.apply(raw_log, &sensor))
        .transpose()?;
    let log = calibrated.as_ref().unwrap_or(raw_log);
    // The flight's own manoeuvres, when it names them: the model, which
    // never saw them, is held out there.
    if !job.windows.is_empty() || !job.lines.is_empty() {
        let (windows, _, heading_note) = calibration_windows(raw_log, job, options)?;
        notes.extend(heading_note);
        for model in &mut models {
            model.windows = model.held_out(log, &sensor, &windows, &options.fit)?;
        }
        notes.push(match applied.fitted_on_this_flight {
            true => format!(
                "the model is set against {} calibration window(s) of the flight it was fitted on: its FOM and IR here are in sample",
                windows.len()
            ),
            false => format!(
                "the model is held out on this flight's {} calibration window(s): its FOM and IR here are of a model fitted on another flight",
                windows.len()
            ),
        });
    }
    let shared = SharedDesign::of_models(log, &models);
    let mut compensation = crate::compensate::compensate_with(log, &models, options.level, &shared)?;
    let mut quality: Vec<ChannelQuality> = models
        .par_iter()
        .zip(compensation.channels.par_iter_mut())
        .map(|(model, channel)| assess_with_sigma(log, model, channel, &shared).map(|(quality, _)| quality))
        .collect::<Result<_>>()?;
    drop(shared);
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
        warnings.extend(crate::quality::quality_warnings(q, options.fom_limit_nt, next_step));
        if channel.sigma_nt.is_none() {
            warnings.push(format!(
                "{}: no sigma column: {}",
                q.channel,
                match q.uncertainty {
                    None => "the model was saved without a jackknife (fitted on fewer than three windows, or with another solver)",
                    Some(_) => "the compensated channel's noise cannot be measured (too few consecutive samples)",
                }
            ));
        }
    }
    if options.vector.enabled {
        notes.push("no vector compensation: its twelve constants are fitted on a calibration box, and the model holds the scalar models".into());
    }
    if !options.gradients.is_empty() {
        warnings.push("the gradients asked for are not compensated: they are fitted on a calibration box, and the model holds the scalar models; compensate the gradients on a flight with its box".into());
    }
    warnings.extend(crate::formats::mcap::undated_warning(&recorded, compensated));
    warnings.extend(crate::formats::write::text_columns_warning(
        &recorded,
        compensated,
        true,
    ));
    notes.extend(crate::reduce::add_reduced(log, &mut compensation, options.reduced)?);
    warnings.extend(compensation.out_of_range_warnings(log.time_s()));
    let added_columns = added_column_names(log, compensated, &compensation)?;
    notes.splice(0..0, renaming_notes(&channels, &added_columns));
    notes.extend(models.iter().filter(|m| !m.spec.is_plain()).map(|m| {
        format!(
            "{}: compensated with the saved model's findings: {}",
            m.channel,
            m.spec.describe()
        )
    }));
    let applied_findings = saved.applied_findings(&channels);
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
        applied_findings,
        warnings,
        diagnosis: None,
        models,
        vector_models: Vec::new(),
        gradients: Vec::new(),
        gradient_models: Vec::new(),
        plan: None,
        model: Some(applied),
        aircraft: job.aircraft.clone(),
    };
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

/// What the fit takes from a diagnosis.
struct ExtensionsPlan {
    /// Each channel's diagnosed model (plain when absent).
    models: BTreeMap<String, Extensions>,
    /// The diagnosis made now, if one was.
    diagnosis: Option<crate::diagnose::Diagnosis>,
    /// What the user must know: a diagnosis that could not be made or
    /// checked.
    warnings: Vec<String>,
}

/// The diagnosed model of each channel to fit with: from the flight's
/// DIAGNOSIS.json (refused when made on another flight, unless forced), or
/// from a diagnosis made now (`[diagnose] apply`, then returned too); empty
/// otherwise. A saved diagnosis that calibrates the fluxgate while the
/// `[vector_calibration]` stage already has is refused. `logs` are the
/// flight as read and as fitted (fluxgate calibrated by the stage).
fn augmentation_plan(
    job: &FlightJob,
    (raw_log, log): (&FlightLog, &FlightLog),
    sensor: &VectorSensor,
    channels: &[String],
    windows: &[crate::windows::CalibrationWindow],
    options: &Settings,
    stage_calibrated: bool,
) -> Result<ExtensionsPlan> {
    use crate::diagnose::ApplyDiagnosis;
    if let Some(path) = &job.diagnosis {
        let (models, remark) = crate::diagnose::read_saved(path)?.models_for(path, raw_log, job.force_diagnosis)?;
        if stage_calibrated && models.values().any(|m| m.vector_calibration.is_some()) {
            return Err(Error::Config {
                source_name: path.display().to_string(),
                message: "the diagnosis calibrates the fluxgate and so does the [vector_calibration] stage; turn the stage off (enabled = false) or diagnose the calibrated flight".into(),
            });
        }
        return Ok(ExtensionsPlan {
            models,
            diagnosis: None,
            warnings: remark.into_iter().collect(),
        });
    }
    let plain = |warnings| ExtensionsPlan {
        models: BTreeMap::new(),
        diagnosis: None,
        warnings,
    };
    if options.diagnose.apply == ApplyDiagnosis::Never {
        return Ok(plain(Vec::new()));
    }
    match crate::diagnose::diagnose(
        log,
        sensor,
        channels,
        windows,
        &options.terms,
        &options.fit,
        &options.diagnose,
    ) {
        Ok(mut diagnosis) => {
            diagnosis.flight = Some(crate::flight_identity::FlightIdentity::of(raw_log)?);
            Ok(ExtensionsPlan {
                models: diagnosis.models(),
                warnings: unexplained_warnings(&diagnosis),
                diagnosis: Some(diagnosis),
            })
        }
        // Under "auto" a flight that cannot be diagnosed is fitted plain,
        // loudly; the plain fit then reports any fault of the data itself.
        Err(error) if options.diagnose.apply == ApplyDiagnosis::Auto => Ok(plain(vec![format!(
            "not diagnosed, so compensated with plain Tolles-Lawson: {error}"
        )])),
        Err(error) => Err(error),
    }
}

/// Applies the evidence rule ([`crate::diagnose::evidence`]) to a fresh
/// diagnosis's plan. A channel's findings are held back (fitted plain
/// under `apply = "auto"`, its findings marked not applied with the
/// reason, and a warning; only warned of under `"always"`) when
///
/// - with λ picked as compensation picks it, they do not lower the
///   held-out RMS of plain Tolles-Lawson: the search may have measured
///   them from the other criterion's fit, and what is applied is this one
///   (on clean simulated flights, two sensor lags that made the survey
///   three times worse held out 4–8 % worse this way); or
/// - they would act on the survey beyond what the calibration saw.
///
/// Returns the plan and, per channel whose findings are applied, how far
/// they move the survey from plain Tolles-Lawson (nT RMS).
fn evidence_rule(
    log: &FlightLog,
    sensor: &VectorSensor,
    windows: &[crate::windows::CalibrationWindow],
    mut plan: BTreeMap<String, Extensions>,
    diagnosis: &mut crate::diagnose::Diagnosis,
    options: &Settings,
    warnings: &mut Vec<String>,
) -> Result<(BTreeMap<String, Extensions>, BTreeMap<String, f64>)> {
    use crate::diagnose::evidence::{departures, plain_of};
    let mut refused: Vec<(String, String)> = (diagnosis.channels.iter())
        .filter(|c| plan.get(&c.channel).is_some_and(|m| *m != plain_of(m)))
        .filter(|c| c.heldout_rms_final_nt >= c.heldout_rms_baseline_nt)
        .map(|c| {
            (
                c.channel.clone(),
                format!(
                    "with λ as compensation picks it{}, the findings do not lower the held-out RMS of plain Tolles-Lawson ({:.4} → {:.4} nT), so the channel is compensated with plain Tolles-Lawson",
                    match options.fit.solve.lambda {
                        crate::numerics::solve::LambdaChoice::Select => format!(" (by {})", options.fit.solve.criterion.describe()),
                        _ => String::new(),
                    },
                    c.heldout_rms_baseline_nt,
                    c.heldout_rms_final_nt
                ),
            )
        })
        .collect();
    let measured = departures(log, sensor, windows, &plan, (options.terms, &options.fit))?;
    let mut applied = BTreeMap::new();
    for (channel, departure) in measured {
        let Some(departure) = departure else {
            continue;
        };
        applied.insert(channel.clone(), departure.survey_departure_nt);
        if !departure.holds() && !refused.iter().any(|(c, _)| *c == channel) {
            refused.push((channel, departure.reason()));
        }
    }
    for (channel, reason) in refused {
        let named: Vec<String> = (diagnosis.findings.iter())
            .filter(|f| f.channel == channel && applies_to_model(f.effect.kind()))
            .map(|f| {
                format!(
                    "{}{}",
                    f.effect,
                    f.source.as_ref().map(|s| format!(" from {s}")).unwrap_or_default()
                )
            })
            .collect();
        if options.diagnose.apply == crate::diagnose::ApplyDiagnosis::Always {
            warnings.push(format!(
                "{channel}: the diagnosis's {} applied as [diagnose] apply = \"always\" asks, though {}",
                named.join(", "),
                reason.replace(", so the channel is compensated with plain Tolles-Lawson", "")
            ));
            continue;
        }
        applied.remove(&channel);
        for finding in
            (diagnosis.findings.iter_mut()).filter(|f| f.channel == channel && applies_to_model(f.effect.kind()))
        {
            finding.not_applied = Some(reason.clone());
        }
        if let Some(model) = plan.get_mut(&channel) {
            *model = plain_of(model);
        }
        if let Some(entry) = diagnosis.channels.iter_mut().find(|c| c.channel == channel) {
            entry.model = plain_of(&entry.model);
        }
        warnings.push(format!(
            "{channel}: the diagnosis's {} not applied: {reason}",
            named.join(", ")
        ));
    }
    Ok((plan, applied))
}

/// Whether a finding of `kind` changes a channel's own model (a fluxgate
/// calibration is the flight's, an `unexplained` residual changes none).
fn applies_to_model(kind: EffectKind) -> bool {
    !matches!(
        kind,
        EffectKind::Unexplained | EffectKind::VectorCalibration | EffectKind::ExternalField
    )
}

/// One warning per channel the diagnosis left with an `unexplained`
/// residual: its compensation is not to be trusted to the noise level.
fn unexplained_warnings(diagnosis: &crate::diagnose::Diagnosis) -> Vec<String> {
    (diagnosis.findings.iter())
        .filter_map(|f| match &f.effect {
            crate::diagnose::Effect::Unexplained(u) => Some(format!(
                "{}: the diagnosis leaves an unexplained residual of {:.4} nT held out, {:.0} times the sensor noise in the band, largest on {}: the compensation of this channel is not good to the noise level; see the diagnosis's unexplained finding",
                f.channel,
                f.heldout_rms_after_nt,
                u.residual_to_noise,
                f.located.iter().map(|l| l.label.as_str()).collect::<Vec<_>>().join(", ")
            )),
            _ => None,
        })
        .collect()
}

/// What a user can do about a failed quality check, given how the flight
/// was fitted.
fn next_step(apply: crate::diagnose::ApplyDiagnosis, saved: bool, diagnosed: bool) -> &'static str {
    match (saved || diagnosed, apply) {
        (true, _) => "Look at the report's worst manoeuvres and the diagnosis's unexplained residual; refly the box if a manoeuvre is poor.",
        (false, crate::diagnose::ApplyDiagnosis::Never) => "Fit with the diagnosis (drop --plain, or [diagnose] apply = \"auto\") to model the physics plain Tolles-Lawson leaves out, or run `magcomp diagnose` to see it.",
        (false, _) => "The flight could not be diagnosed; fly a complete box (four headings, each with pitch, roll and yaw) to let the diagnosis model what plain Tolles-Lawson leaves out.",
    }
}

/// Warnings from detection: every incomplete box, and every leg whose
/// pitch and yaw the fluxgate could not tell apart.
pub fn detection_warnings(detection: &Detection) -> Vec<String> {
    let mut warnings: Vec<String> = detection
        .boxes
        .iter()
        .enumerate()
        .filter(|(_, b)| !b.missing.is_empty())
        .map(|(index, b)| {
            format!(
                "box {} ({:.1}–{:.1}) is incomplete: {}; its FOM sums fewer than 12 manoeuvres",
                index + 1,
                b.t_start,
                b.t_end,
                b.missing.join(", ")
            )
        })
        .collect();
    warnings.extend(crate::detect::uncertain_kinds(detection));
    warnings.extend(detection.steep_field_warning());
    warnings.extend(detection.attitude_gap_warning());
    warnings
}

/// The windows a flight is calibrated on, with the detection that gave
/// them and a note on their headings: the windows given; else the
/// manoeuvres detected (on the calibration lines only, when the job names
/// lines); else, on lines where none is detected, each line's whole span.
pub fn calibration_windows(
    log: &FlightLog,
    job: &FlightJob,
    options: &Settings,
) -> Result<(
    Vec<crate::windows::CalibrationWindow>,
    Option<Detection>,
    Option<String>,
)> {
    let tolerance = options.detect.heading_tolerance_deg;
    if !job.windows.is_empty() {
        let (windows, note) = crate::windows::headings_from_ins(log, &job.windows, tolerance);
        return Ok((windows, None, note));
    }
    let detection = detect_manoeuvres(log, &options.detect)?;
    if job.lines.is_empty() {
        return Ok((
            detection.calibration_windows(options.detect.window_margin_s),
            Some(detection),
            None,
        ));
    }
    let spans = crate::windows::line_spans(log, &job.lines)?;
    let detection = detection.on_lines(&spans);
    if !detection.manoeuvres.is_empty() {
        return Ok((
            detection.calibration_windows(options.detect.window_margin_s),
            Some(detection),
            None,
        ));
    }
    // No manoeuvre seen on the lines: each line's span is a window, its
    // heading from the INS where it holds one.
    let whole: Vec<crate::windows::CalibrationWindow> = (spans.iter())
        .filter(|(_, start, end)| start < end)
        .map(|(line, start, end)| crate::windows::CalibrationWindow {
            label: format!("line {line}"),
            ..crate::windows::CalibrationWindow::new(*start, *end)
        })
        .collect();
    let (windows, note) = crate::windows::headings_from_ins(log, &whole, tolerance);
    let said = format!(
        "no calibration manoeuvre was detected on line(s) {}: each line's whole span is a calibration window",
        job.lines.iter().map(|l| l.to_string()).collect::<Vec<_>>().join(", ")
    );
    Ok((
        windows,
        None,
        Some(note.map_or(said.clone(), |n| format!("{said}; {n}"))),
    ))
}

/// Diagnoses a flight: its windows (given, or detected), its vector
/// sensor and channels, then [`crate::diagnose::diagnose`].
pub fn diagnose_flight(
    log: &FlightLog,
    job: &FlightJob,
    options: &Settings,
    settings: &crate::diagnose::DiagnoseOptions,
) -> Result<crate::diagnose::Diagnosis> {
    let sensor = choose_vector_sensor(log, job.vector.as_deref())?;
    let channels = choose_channels(log, job.channels.as_deref())?;
    let (windows, _, _) = calibration_windows(log, job, options)?;
    let mut diagnosis = crate::diagnose::diagnose(
        log,
        &sensor,
        &channels,
        &windows,
        &options.terms,
        &options.fit,
        settings,
    )?;
    diagnosis.flight = Some(crate::flight_identity::FlightIdentity::of(log)?);
    Ok(diagnosis)
}

/// What detection found, in a sentence per box and per lack.
pub fn detection_notes(detection: &Detection) -> Vec<String> {
    let mut notes = vec![format!(
        "calibration windows detected: {} manoeuvres in {} box(es), attitude from {}",
        detection.manoeuvres.len(),
        detection.boxes.len(),
        match detection.attitude_source {
            crate::detect::AttitudeSource::Ins => "the INS",
            crate::detect::AttitudeSource::Fluxgate => "the fluxgate",
        }
    )];
    notes.extend(detection.notes.iter().cloned());
    notes
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

/// An error naming what screening found when it masked every sample of
/// an axis of `sensor` or of a scalar channel to compensate (`wanted`, or
/// every scalar channel): a dead axis or a stuck sensor is named as such,
/// not as an empty column or a calibration window without samples.
pub(crate) fn refuse_dead_columns(
    log: &FlightLog,
    screening: &crate::screen::Screening,
    sensor: &VectorSensor,
    wanted: Option<&[String]>,
) -> Result<()> {
    let fluxgate_hint = format!(
        "No Tolles-Lawson term can be built from '{}' without it. Repair the sensor or its export, or choose another fluxgate with --vector.",
        sensor.prefix
    );
    let scalar_hint = "Leave the channel out with --channels (or [columns] in pipeline.toml) to compensate the others.";
    let axes = sensor.axes.map(|axis| log.channels()[axis].name.clone());
    let scalars: Vec<String> = match wanted {
        Some(list) => list.to_vec(),
        None => log.scalar_channels().into_iter().map(String::from).collect(),
    };
    let needed = (axes.iter().map(|c| (c, fluxgate_hint.as_str()))).chain(scalars.iter().map(|c| (c, scalar_hint)));
    for (column, hint) in needed {
        if let Some(reason) = screening.took_all(log, column) {
            return Err(Error::AllMasked {
                path: log.source().to_path_buf(),
                column: column.clone(),
                reason,
                hint: hint.into(),
            });
        }
    }
    Ok(())
}

/// The vector magnetometer called `wanted`, or the first one found.
pub fn choose_vector_sensor(log: &FlightLog, wanted: Option<&str>) -> Result<VectorSensor> {
    let sensors = log.vector_sensors();
    let found = match wanted {
        Some(prefix) => sensors.iter().find(|s| s.prefix == prefix),
        None => sensors.first(),
    };
    found.cloned().ok_or_else(|| Error::MissingColumn {
        path: log.source().to_path_buf(),
        role: "vector magnetometer",
        looked_for: match wanted {
            Some(prefix) => format!("{prefix}_x, {prefix}_y and {prefix}_z"),
            None => "flux_<s>_x, flux_<s>_y and flux_<s>_z".into(),
        },
        hint: format!(
            "The Tolles-Lawson terms are built from a 3-axis fluxgate. {} Choose one with --vector, or map its columns in [[columns.vector]] in pipeline.toml.",
            match sensors.is_empty() {
                true => format!(
                    "The flight has no fluxgate of three such columns; its columns are {}.",
                    column_list(log)
                ),
                false => format!(
                    "Fluxgates found: {}.",
                    sensors.iter().map(|s| s.prefix.as_str()).collect::<Vec<_>>().join(", ")
                ),
            }
        ),
    })
}

/// The flight's column names for a message: the first
/// [`LISTED_COLUMNS`], then how many more.
fn column_list(log: &FlightLog) -> String {
    let names: Vec<&str> = std::iter::once(log.time_column())
        .chain(log.channels().iter().map(|c| c.name.as_str()))
        .collect();
    let shown: Vec<String> = names.iter().take(LISTED_COLUMNS).map(|n| format!("'{n}'")).collect();
    match names.len() > LISTED_COLUMNS {
        true => format!("{} and {} more", shown.join(", "), names.len() - LISTED_COLUMNS),
        false => shown.join(", "),
    }
}

/// Columns a message lists before "and N more".
const LISTED_COLUMNS: usize = 20;

/// The scalar channels to compensate: `wanted`, or every scalar channel.
/// Channels with no valid sample are an error.
pub fn choose_channels(log: &FlightLog, wanted: Option<&[String]>) -> Result<Vec<String>> {
    let channels: Vec<String> = match wanted {
        Some(list) => list.to_vec(),
        None => log.scalar_channels().into_iter().map(String::from).collect(),
    };
    if let Some(twice) = (channels.iter().enumerate()).find_map(|(i, c)| channels[..i].contains(c).then_some(c)) {
        return Err(Error::Config {
            source_name: log.source().display().to_string(),
            message: format!("the channel '{twice}' is asked for twice; name each channel to compensate once"),
        });
    }
    if channels.is_empty() {
        return Err(Error::MissingColumn {
            path: log.source().to_path_buf(),
            role: "scalar magnetometer",
            looked_for: "mag_<n>_uc".into(),
            hint: "Name your scalar channels with --channels or [columns] scalar = [...] in pipeline.toml.".into(),
        });
    }
    for name in &channels {
        let channel = log.channel(name).ok_or_else(|| Error::MissingColumn {
            path: log.source().to_path_buf(),
            role: "scalar magnetometer",
            looked_for: format!("'{name}'"),
            hint: "Check the name given with --channels or in pipeline.toml.".into(),
        })?;
        if channel.values.iter().all(|v| v.is_nan()) {
            return Err(Error::AllMissing {
                path: log.source().to_path_buf(),
                column: name.clone(),
            });
        }
    }
    Ok(channels)
}

/// The lines of [`summary`] for a flight compensated with a saved model:
/// the model, then per channel its calibration figures and this flight's.
fn applied_summary(result: &FlightResult, applied: &crate::apply::AppliedModel) -> String {
    let mut text = format!(
        "  compensated with the saved model {} (fitted on {}{}{}{}); nothing refitted\n",
        applied.file.display(),
        applied.fitted_on.display(),
        applied.date.map(|d| format!(", {d}")).unwrap_or_default(),
        applied
            .aircraft
            .as_ref()
            .map(|a| format!(", aircraft {a}"))
            .unwrap_or_default(),
        applied
            .age_days
            .map(|d| format!(", {}", crate::apply::days_from(d)))
            .unwrap_or_default(),
    );
    for (quality, model) in result.channels.iter().zip(&result.models) {
        let calibration = (applied.calibration.iter())
            .find(|c| c.channel == quality.channel)
            .map_or("no calibration figures saved".into(), |c| c.describe());
        text += &format!(
            "  {} vs {}: on its calibration {calibration}; here 4th-difference noise {:.4} → {:.4} nT",
            quality.channel,
            model.vector_sensor,
            quality.noise_4th_difference_before_nt,
            quality.noise_4th_difference_after_nt
        );
        if !model.windows.is_empty() {
            let how = match applied.fitted_on_this_flight {
                true => "on the windows it was fitted on",
                false => "held out on this flight's windows",
            };
            text += &format!(
                "; {how}: band std {:.3} → {:.3} nT, IR {:.2}",
                quality.band_std_before_nt, quality.band_std_after_nt, quality.improvement_ratio
            );
            if let (Some(before), Some(after)) = (quality.fom_before_nt, quality.fom_after_nt) {
                text += &format!(", FOM {before:.2} → {after:.2} nT ({} of 12)", quality.fom_manoeuvres);
            }
        }
        text += "\n";
        if let Some(error) = &quality.heading_error {
            text += &format!(
                "    heading error ({} matched samples on reciprocal lines): {:.3} → {:.3} nT\n",
                error.pairs, error.before_nt, error.after_nt
            );
        }
    }
    text
}

/// A few lines per channel for the terminal, and the warnings; the notes
/// with `verbose`, else their count (the quality JSON and the report hold
/// them all).
pub fn summary(result: &FlightResult, verbose: bool) -> String {
    let mut text = format!("{}: {} rows\n", result.flight.display(), result.rows);
    if let Some(applied) = &result.model {
        text += &applied_summary(result, applied);
    }
    for (quality, model) in result.channels.iter().zip(&result.models) {
        if result.model.is_some() {
            break;
        }
        let solution = &model.solution;
        let regulariser = match (
            model.solver.as_ref().and_then(|s| s.estimator),
            solution.lambda,
            solution.rank,
        ) {
            (Some(estimator), _, _) => estimator.describe(),
            (None, Some(lambda), _) => format!("ridge λ={lambda:.3e}"),
            (None, _, Some(rank)) => format!("TSVD rank {rank}"),
            _ => String::new(),
        };
        text += &format!(
            "  {} vs {}: {} ({} samples, cond {:.2e}); band std {:.3} → {:.3} nT, IR {:.2}",
            quality.channel,
            model.vector_sensor,
            regulariser,
            solution.samples,
            solution.condition_number,
            quality.band_std_before_nt,
            quality.band_std_after_nt,
            quality.improvement_ratio
        );
        if let (Some(before), Some(after)) = (quality.fom_before_nt, quality.fom_after_nt) {
            text += &format!(
                "; FOM {before:.2} → {after:.2} nT ({} of 12 manoeuvres)",
                quality.fom_manoeuvres
            );
        }
        text += &format!("\n    {}\n", solution.reason);
        if let Some(error) = &quality.heading_error {
            text += &format!(
                "    heading error ({} matched samples on reciprocal lines): {:.3} → {:.3} nT\n",
                error.pairs, error.before_nt, error.after_nt
            );
        }
        if let Some(check) = &quality.transfer {
            let how = match check.method {
                crate::quality::transfer::TransferMethod::SecondBox => "second box",
                crate::quality::transfer::TransferMethod::LeaveOneHeadingOut => "leave one heading out",
            };
            text += &format!(
                "    held-out FOM ({how}): {:.2} nT against {:.2} nT in sample ({:.1}×)\n",
                check.held_out_fom_nt, check.in_sample_fom_nt, check.ratio
            );
        }
        for transfer in &quality.box_transfer {
            text += &format!(
                "    box transfer: fitted on {}, {} residual {:.3} nT (fitted on itself {:.3} nT)\n",
                transfer.fit, transfer.test, transfer.band_std_nt, transfer.own_fit_band_std_nt
            );
        }
    }
    text += &match (result.diagnosis_mode, result.applied_findings.is_empty()) {
        _ if result.model.is_some() => match result.applied_findings.is_empty() {
            true => String::new(),
            false => "  the model's findings (from its calibration flight):\n".to_string(),
        },
        (crate::diagnose::ApplyDiagnosis::Never, _) => "  diagnosis: not applied (plain Tolles-Lawson)\n".to_string(),
        (_, true) if result.diagnosis.is_some() => {
            "  diagnosis: no finding changes the model; plain Tolles-Lawson\n".to_string()
        }
        (_, true) => String::new(),
        (_, false) => "  diagnosis applied:\n".to_string(),
    };
    for applied in &result.applied_findings {
        text += &format!("    {}\n", applied.describe());
    }
    match (verbose, result.notes.len()) {
        (_, 0) => {}
        (true, _) => {
            for note in &result.notes {
                text += &format!("  note: {note}\n");
            }
        }
        (false, count) => {
            text += &format!(
                "  {count} note{} in the report (-v prints them)\n",
                if count == 1 { "" } else { "s" }
            )
        }
    }
    for warning in &result.warnings {
        text += &format!("  warning: {warning}\n");
    }
    text
}
