//! Where a flight's results go: the compensated flight, the model and
//! quality JSON, DIAGNOSIS.json and the HTML report, written from a
//! [`FlightRun`] after every stage has run.
//!
//! The outputs are checked before any work ([`crate::formats::prepare`])
//! and committed together at the end, the report last: a flight that fails
//! leaves the previous run's files as they were.

use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::config::FlightJob;
use crate::config::Settings;
use crate::error::{Error, Result};
use crate::formats::mcap::McapExtras;
use crate::formats::{
    detect_format, detect_output_format, stage, stage_compensated, Destination, Format, OutputKind, OutputSet,
};
use crate::model::FittedModel;
use crate::pipeline::{FlightResult, FlightRun};

/// Where one flight's outputs go.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FlightOutputs {
    /// Compensated flight (CSV, or XYZ / MCAP for such inputs).
    pub compensated: PathBuf,
    /// Model JSON, if wanted.
    pub model_json: Option<PathBuf>,
    /// Quality JSON, if wanted.
    pub quality_json: Option<PathBuf>,
    /// HTML quality report (and its figures as JSON beside it), if wanted.
    pub report_html: Option<PathBuf>,
    /// DIAGNOSIS.json of the diagnosis made when `[diagnose] apply` is on.
    pub diagnosis_json: Option<PathBuf>,
}

impl FlightOutputs {
    /// `<dir>/<stem>_compensated.csv`, `_model.json`, `_quality.json` and
    /// `_report.html`.
    pub fn in_directory(directory: &Path, input: &Path) -> Self {
        let stem = input
            .file_stem()
            .map_or("flight".into(), |s| s.to_string_lossy().into_owned());
        FlightOutputs::named(directory, &stem, input)
    }

    /// The outputs of a campaign's flight: `<dir>/<output name>_…`.
    pub fn for_job(directory: &Path, job: &FlightJob) -> Self {
        FlightOutputs::named(directory, &job.output_name, &job.input)
    }

    /// `<dir>/<stem>_compensated.<csv, xyz or mcap as the input>` and the
    /// JSON and HTML beside it.
    fn named(directory: &Path, stem: &str, input: &Path) -> Self {
        // Geosoft and MCAP users get their format back; everything else CSV.
        let extension = match detect_format(input) {
            Ok(Format::Xyz) => "xyz",
            Ok(Format::Mcap) => "mcap",
            _ => "csv",
        };
        FlightOutputs {
            compensated: directory.join(format!("{stem}_compensated.{extension}")),
            model_json: Some(crate::config::model_json_path(directory, stem)),
            quality_json: Some(directory.join(format!("{stem}_quality.json"))),
            report_html: Some(directory.join(format!("{stem}_report.html"))),
            diagnosis_json: Some(directory.join(format!("{stem}_diagnosis.json"))),
        }
    }

    /// Every file these outputs write, each with what it is.
    pub fn destinations(&self) -> Vec<Destination> {
        let mut destinations = vec![Destination::new(
            &self.compensated,
            OutputKind::Flight,
            "the compensated flight",
        )];
        let optional = [
            (&self.model_json, OutputKind::Json, "the model JSON"),
            (&self.quality_json, OutputKind::Json, "the quality JSON"),
            (&self.diagnosis_json, OutputKind::Json, "the diagnosis JSON"),
            (&self.report_html, OutputKind::Html, "the HTML report"),
        ];
        for (path, kind, named_by) in optional {
            if let Some(path) = path {
                destinations.push(Destination::new(path, kind, named_by));
            }
        }
        if let Some(path) = &self.report_html {
            destinations.push(Destination::new(
                crate::output::report::figures_path(path),
                OutputKind::Json,
                "the HTML report's figures JSON",
            ));
        }
        destinations
    }
}

/// Reads, fits, compensates and assesses one flight
/// ([`crate::pipeline::run`]) and writes
/// its outputs ([`write()`]).
pub fn process_flight(job: &FlightJob, options: &Settings, outputs: &FlightOutputs) -> Result<FlightResult> {
    process_flight_listing(job, options, outputs, &crate::messages::progress::Silent).map(|(result, _)| result)
}

/// [`process_flight`], also returning the files written, telling `meter`
/// as each stage begins ([`crate::pipeline::run_metered`]).
pub fn process_flight_listing(
    job: &FlightJob,
    options: &Settings,
    outputs: &FlightOutputs,
    meter: &dyn crate::messages::progress::Meter,
) -> Result<(FlightResult, Vec<PathBuf>)> {
    let inputs: Vec<&Path> = std::iter::once(job.input.as_path())
        .chain(job.diagnosis.as_deref())
        .chain(job.plan.as_deref())
        .chain(job.model.as_deref())
        .collect();
    // Folders created here are not noted in the outputs: a caller that
    // tells its user calls `prepare` first.
    crate::formats::prepare(&inputs, &outputs.destinations())?;
    let flight = crate::pipeline::run_metered(job, options, &outputs.compensated, meter).map_err(|error| {
        match (error, &job.no_calibration_because) {
            (crate::error::Error::NoCalibrationWindows { path }, Some(why)) => {
                crate::error::Error::NoCampaignCalibration { path, why: why.clone() }
            }
            (error, _) => error,
        }
    })?;
    meter.begin(crate::messages::progress::Stage::Writing, 0);
    let written = write(&flight, options, outputs)?;
    Ok((flight.result, written))
}

/// Writes every output of `flight`, all committed together, the report
/// last; returns the files written.
pub fn write(flight: &FlightRun, options: &Settings, outputs: &FlightOutputs) -> Result<Vec<PathBuf>> {
    let result = &flight.result;
    let mut written = OutputSet::new();
    if let (Some(diagnosis), Some(path)) = (&result.diagnosis, &outputs.diagnosis_json) {
        written.add(crate::formats::stage_json(path, "the diagnosis", diagnosis)?);
    }
    // A flight compensated with a saved model fitted nothing: the model
    // is the file it was given, and its MCAP holds that model's name.
    let model_json = outputs.model_json.as_ref().filter(|_| result.model.is_none());
    let texts = || -> Result<(String, String)> {
        let model_text = match &result.model {
            Some(applied) => to_json(None, "the applied model", applied)?,
            None => to_json(
                model_json.map(PathBuf::as_path),
                "the fitted models",
                &ModelFile::new(flight)?,
            )?,
        };
        let quality_text = to_json(outputs.quality_json.as_deref(), "the quality figures", result)?;
        Ok((model_text, quality_text))
    };
    let compensated = |extras: &McapExtras| {
        stage_compensated(
            &flight.recorded,
            &options.ingest.columns,
            &outputs.compensated,
            &flight.compensation,
            &result.added_columns,
            extras,
        )
    };
    // An MCAP output holds the model and quality documents; any other is
    // written beside them (the model's text hashes the input, which then
    // takes a core the copy's writes leave idle).
    let ((model_text, quality_text), staged) = match detect_output_format(&outputs.compensated) {
        Format::Mcap => {
            let (model_text, quality_text) = texts()?;
            let extras = McapExtras {
                documents: vec![
                    ("model".into(), model_text.clone()),
                    ("quality".into(), quality_text.clone()),
                ],
            };
            let staged = compensated(&extras)?;
            ((model_text, quality_text), staged)
        }
        _ => {
            let (texts, staged) = rayon::join(texts, || compensated(&McapExtras::default()));
            (texts?, staged?)
        }
    };
    written.add(staged);
    for (path, text) in [
        (&model_json.cloned(), model_text),
        (&outputs.quality_json, quality_text),
    ] {
        if let Some(path) = path {
            written.add(stage(path, |w| std::io::Write::write_all(w, text.as_bytes()))?);
        }
    }
    if let Some(path) = &outputs.report_html {
        let report = crate::output::report::stage_report(path, flight, options.fom_limit_nt)?;
        written.add(report.figures_json);
        written.add_last(report.page);
    }
    written.commit()
}

/// Pretty JSON text of `value`; `path` only names the file in an error.
fn to_json<T: Serialize>(path: Option<&Path>, what: &'static str, value: &T) -> Result<String> {
    serde_json::to_string_pretty(value).map_err(|e| Error::Serialise {
        path: path.map(Path::to_path_buf).unwrap_or_default(),
        what,
        source: Box::new(e),
    })
}

/// The model JSON: the flight and its fitted models, with what applying
/// them to another flight needs ([`crate::pipeline::apply`]): the
/// calibration flight's identity, day and aircraft, each channel's figures
/// on it, and the findings its models carry.
#[derive(Serialize)]
struct ModelFile<'a> {
    /// "magcomp 1.2.3".
    written_by: String,
    flight: &'a Path,
    flight_identity: crate::ingest::flight_identity::FlightIdentity,
    #[serde(skip_serializing_if = "Option::is_none")]
    date: Option<crate::ingest::flight_date::FlightDate>,
    #[serde(skip_serializing_if = "Option::is_none")]
    aircraft: Option<&'a str>,
    calibration: Vec<crate::pipeline::apply::CalibrationFigures>,
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    applied_findings: &'a [crate::pipeline::AppliedFinding],
    #[serde(skip_serializing_if = "Option::is_none")]
    vector_calibration: Option<&'a crate::calibration::fluxgate::VectorCalibration>,
    models: &'a [FittedModel],
    /// The fluxgates' vector models: the twelve constants and the vector
    /// Tolles-Lawson stage.
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    vector_models: &'a [crate::vector::VectorModel],
    /// The direct models of the compensated gradients.
    #[serde(skip_serializing_if = "<[_]>::is_empty")]
    gradient_models: &'a [FittedModel],
}

impl<'a> ModelFile<'a> {
    fn new(flight: &'a FlightRun) -> Result<Self> {
        let result = &flight.result;
        Ok(ModelFile {
            written_by: format!("magcomp {}", env!("CARGO_PKG_VERSION")),
            flight: &result.flight,
            flight_identity: crate::ingest::flight_identity::FlightIdentity::of(&flight.recorded)?,
            date: flight.recorded.date(),
            aircraft: result.aircraft.as_deref(),
            calibration: result
                .channels
                .iter()
                .map(crate::pipeline::apply::CalibrationFigures::of)
                .collect(),
            applied_findings: &result.applied_findings,
            vector_calibration: result.vector_calibration.as_ref(),
            models: &result.models,
            vector_models: &result.vector_models,
            gradient_models: &result.gradient_models,
        })
    }
}
