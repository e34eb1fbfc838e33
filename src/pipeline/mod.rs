//! One flight through every stage: read, screen, detect, diagnose, fit,
//! compensate, assess. [`run`] writes nothing; [`crate::output::sink`] writes what
//! it produced.
//!
//! A flight that flies no calibration of its own is compensated with a
//! model saved from one that did ([`apply`]: the saved model read, checked
//! against the flight and applied, nothing refitted).

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::calibration::detect::Detection;
use crate::config::{FlightJob, Settings};
use crate::error::{Error, Result};
use crate::formats::align::AlignmentReport;
use crate::formats::read_flight_log;
use crate::ingest::flight_log::FlightLog;
use crate::messages::progress::{Meter, Stage};
use crate::model::{FittedModel, SharedDesign};
use crate::quality::ChannelQuality;

pub use crate::diagnose::AppliedFinding;

mod applied;
pub mod apply;
mod diagnosis;
mod fitted;
mod prepared;
mod summary;
mod vector_stage;

pub use prepared::{
    calibration_windows, choose_channels, choose_vector_sensor, detection_notes, detection_warnings, diagnose_flight,
    PreparedFlight,
};
pub use summary::summary;

use applied::run_applied;
use fitted::run_fitted;

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
    pub notes: Vec<crate::messages::Note>,
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
    pub vector_calibration: Option<crate::calibration::fluxgate::VectorCalibration>,
    /// Whether the diagnosis was applied (`[diagnose] apply`, `--plain`).
    pub diagnosis_mode: crate::diagnose::ApplyDiagnosis,
    /// The diagnosed findings the fit applied, each with what it bought
    /// held out.
    pub applied_findings: Vec<AppliedFinding>,
    /// What the quality gate found wrong, each with the next step; also on
    /// stdout and in the report.
    pub warnings: Vec<crate::messages::Warning>,
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
    pub gradients: Vec<crate::compensate::gradient::GradientResult>,
    /// The gradients' direct models (the model JSON holds them).
    #[serde(skip)]
    pub gradient_models: Vec<FittedModel>,
    /// The flight against the plan it was flown to (`--plan`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub plan: Option<crate::quality::against_plan::PlanComparison>,
    /// The saved model the flight was compensated with (`--apply`),
    /// nothing refitted; `None` when it was fitted on its own calibration.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub model: Option<crate::pipeline::apply::AppliedModel>,
    /// The airframe, when the flight names it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub aircraft: Option<String>,
}

/// The flight's channels and manoeuvres set against `planned`: the FOM,
/// the survey uncertainty the excitation analysis states (with the noise
/// the sigma column takes) and the sigma column over the survey lines.
fn against_plan(
    planned: &crate::quality::against_plan::PlanPrediction,
    log: &FlightLog,
    models: &[FittedModel],
    quality: &[ChannelQuality],
    compensation: &crate::compensate::Compensation,
) -> crate::quality::against_plan::PlanComparison {
    let line = log.channel("line").map(|c| c.values.as_slice()).unwrap_or_default();
    let channels: Vec<crate::quality::against_plan::FlownChannel> =
        (models.iter().zip(quality).zip(&compensation.channels))
            .map(|((model, quality), channel)| {
                let noise = quality.white_noise_nt();
                crate::quality::against_plan::FlownChannel {
                    channel: model.channel.clone(),
                    fom_nt: quality.fom_after_nt,
                    survey_sigma_nt: (model.excitation.as_ref())
                        .zip(noise)
                        .map(|(e, noise)| e.survey_sigma_nt.hypot(noise)),
                    sigma_column_nt: (channel.sigma_nt.as_deref())
                        .and_then(|s| crate::quality::against_plan::survey_rms(s, line)),
                }
            })
            .collect();
    // The windows every channel was fitted on; labelled by kind and
    // heading when detected (or given so).
    let manoeuvres: Option<Vec<(crate::calibration::windows::ManoeuvreKind, f64)>> = (models.first()).and_then(|m| {
        m.windows
            .iter()
            .map(|w| w.window.kind.zip(w.window.heading_deg))
            .collect()
    });
    crate::quality::against_plan::compare(planned, manoeuvres.as_deref(), &channels)
}

/// What a channel's estimator table leaves out, in words: the whole table
/// when the windows span fewer than three headings, or the families no
/// split could fit.
fn estimator_table_gap(model: &FittedModel) -> Option<crate::messages::Note> {
    use crate::numerics::estimators::Family;
    let Some(table) = &model.estimators else {
        return Some(crate::messages::Note::NoEstimatorTable {
            channel: model.channel.clone(),
        });
    };
    let missing: Vec<String> = Family::ALL
        .iter()
        .filter(|family| !table.iter().any(|s| s.family == **family))
        .map(|family| format!("{family:?}"))
        .collect();
    (!missing.is_empty()).then(|| crate::messages::Note::EstimatorTableLacks {
        channel: model.channel.clone(),
        families: missing,
    })
}

/// Judges every channel of `result` ([`crate::quality::verdict`]) against
/// the limits of `options`, once its figures are final.
fn judge_channels(result: &mut FlightResult, options: &Settings) {
    let limits = verdict_limits(options);
    for quality in &mut result.channels {
        let calibration = (result.model.as_ref()).map(|applied| {
            let figures = applied.calibration.iter().find(|c| c.channel == quality.channel);
            crate::quality::verdict::CalibrationVerdict {
                fom_after_nt: figures.and_then(|c| c.fom_after_nt),
            }
        });
        crate::quality::verdict::judge(quality, &limits, calibration);
    }
}

/// The limits of `options` a verdict is judged against.
pub fn verdict_limits(options: &Settings) -> crate::quality::verdict::VerdictLimits {
    crate::quality::verdict::VerdictLimits {
        fom_limit_nt: options.fom_limit_nt,
        anomaly_gain_tolerance: options.anomaly_gain_tolerance,
    }
}

/// One flight through every stage: what [`run`] produced, for the sinks
/// ([`crate::output::sink`]) to write.
#[derive(Debug, Clone)]
pub struct FlightRun {
    /// The flight as recorded: the compensated output copies it.
    pub recorded: FlightLog,
    /// The samples no instrument can record, masked: what every stage
    /// worked on.
    pub screened: crate::ingest::screen::Screened,
    /// The compensated channels and row flags.
    pub compensation: crate::compensate::Compensation,
    /// Quality figures, notes, warnings, models and diagnosis.
    pub result: FlightResult,
}

impl FlightRun {
    /// A finished run: each channel judged ([`judge_channels`]) against
    /// `options`' limits. The figures in `result` are of the full values;
    /// the compensation's outputs are rounded here to the stated
    /// resolution (`[output] decimals`), once for every format.
    fn finished(
        (recorded, screened): (FlightLog, crate::ingest::screen::Screened),
        mut compensation: crate::compensate::Compensation,
        mut result: FlightResult,
        options: &Settings,
    ) -> FlightRun {
        judge_channels(&mut result, options);
        compensation.round_to(options.output_decimals);
        FlightRun {
            recorded,
            screened,
            compensation,
            result,
        }
    }

    /// The log the stages worked on (the screened samples).
    pub fn log(&self) -> &FlightLog {
        self.screened.log_or(&self.recorded)
    }
}

/// Reads, fits, compensates and assesses one flight; writes nothing.
/// `compensated` is where the compensated flight will go: its format
/// names the columns magcomp adds.
pub fn run(job: &FlightJob, options: &Settings, compensated: &Path) -> Result<FlightRun> {
    run_metered(job, options, compensated, &crate::messages::progress::Silent)
}

/// [`run`], telling `meter` as each stage begins and each channel of a
/// long stage is done.
pub fn run_metered(job: &FlightJob, options: &Settings, compensated: &Path, meter: &dyn Meter) -> Result<FlightRun> {
    meter.begin(Stage::Reading, 0);
    // A plan report or a saved model that cannot be read fails before the
    // flight's work.
    let planned = (job.plan.as_deref())
        .map(crate::quality::against_plan::PlanPrediction::read)
        .transpose()?;
    let saved = (job.model.as_deref())
        .map(crate::pipeline::apply::SavedModel::read)
        .transpose()?;
    let ingest = crate::formats::IngestOptions {
        date: job.date.or(options.ingest.date),
        ..options.ingest.clone()
    };
    let recorded = read_flight_log(&job.input, &ingest)?;
    // Columns in units magcomp does not read (attitude in radians, time
    // in milliseconds) make every later stage fail in its own words: the
    // units are named first.
    let units = crate::formats::units::unit_warnings(&job.input, &recorded);
    let run = match saved {
        Some(saved) => run_applied(job, options, compensated, &saved, recorded, meter),
        None => run_fitted(job, options, compensated, planned, recorded, meter),
    };
    run.map_err(|error| match units.is_empty() {
        true => error,
        false => Error::UnitsLookWrong {
            problems: (units.iter().map(crate::messages::Warning::to_string))
                .collect::<Vec<_>>()
                .join("; "),
            source: Box::new(error),
        },
    })
}

/// A compensated channel's figures, its uncertainty and its sigma column
/// (set on `channel`; none without a jackknife or a noise figure, which
/// the run warns of), and each jackknife deviation's mean over the
/// calibration (empty without a jackknife): the level saved with the model.
/// `geometry` is the flight's survey lines', found once for all its
/// channels.
fn assess_with_sigma(
    (log, geometry): (&FlightLog, &crate::quality::SurveyGeometry),
    model: &FittedModel,
    channel: &mut crate::compensate::CompensatedChannel,
    shared: &[SharedDesign],
) -> Result<(ChannelQuality, Vec<f64>)> {
    let mut quality = crate::quality::assess_quality_at(log, geometry, model, channel);
    if let Some(gain) = model.anomaly_gain(log, shared)? {
        quality.anomaly_gain = Some(gain.median);
        quality.anomaly_gain_range = Some([gain.min, gain.max]);
    }
    let Some(prediction) = model.prediction_sigma_with(log, shared)? else {
        return Ok((quality, Vec::new()));
    };
    quality.uncertainty = crate::quality::uncertainty_of(log, model, &prediction);
    if let Some(noise) = quality.white_noise_nt() {
        channel.set_sigma(&prediction, noise);
    }
    Ok((quality, prediction.levels_nt))
}

/// The note saying the input's line under its header is a row of units.
pub(crate) fn units_row_note(recorded: &FlightLog) -> Option<crate::messages::Note> {
    (!recorded.declared_units().is_empty()).then(|| crate::messages::Note::UnitsRow {
        path: recorded.source().to_path_buf(),
        units: recorded.declared_units().to_vec(),
    })
}

pub(crate) fn renaming_notes(channels: &[String], added: &[String]) -> Vec<crate::messages::Note> {
    channels
        .iter()
        .zip(added)
        .filter(|(_, column)| column.ends_with("_magcomp"))
        .map(|(channel, column)| crate::messages::Note::Renamed {
            channel: channel.clone(),
            original: column.trim_end_matches("_magcomp").to_string(),
            column: column.clone(),
        })
        .collect()
}
