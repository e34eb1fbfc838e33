//! Many flights, one command: a campaign split into shards for a
//! scheduler's job array, resumed flight by flight, and summarised.
//!
//! A scheduler (Slurm, Kubernetes Indexed Jobs, AWS Batch) starts N copies
//! of one command, each with its index K. `magcomp run pipeline.toml
//! --shard K/N` processes the flights [`Shard::select`] gives shard K, the
//! same split in every copy since it depends only on the campaign's list.
//! Each flight ends with a small status JSON ([`FlightStatus`]) beside its
//! outputs; a flight whose status says done, with the same input bytes and
//! settings, is skipped ([`FlightStatus::is_current`]), so an array
//! re-submitted after a failure or a kill redoes only what is unfinished.
//! `magcomp summarize OUTDIR` ([`summary`]) merges the statuses and the
//! quality and model JSONs into a campaign table.

pub mod drift;
mod runner;
mod shard;
mod status;
pub mod summary;

pub use runner::{dependency_order, run_flights, FinishedFlight, FlightsAtOnce, Progress};
pub use shard::{Shard, SCHEDULER_INDEX_VARIABLES};
pub use status::{settings_sha256, status_path, ChannelVerdict, FlightState, FlightStatus};

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::config::{FlightJob, Settings};
use crate::error::{Error, Result};
use crate::output::sink::{process_flight_listing, FlightOutputs};
use crate::pipeline::FlightResult;

/// What became of one flight of a campaign run.
#[derive(Debug)]
pub enum CampaignFlight {
    /// Its outputs were current (same input bytes and settings); nothing
    /// was done.
    UpToDate(FlightStatus),
    /// It was processed; the status says how it ended and is written.
    Processed {
        /// The status written.
        status: FlightStatus,
        /// What processing produced, or why it failed.
        result: Box<Result<FlightResult>>,
    },
}

impl CampaignFlight {
    /// The status of the flight, written now or found current.
    pub fn status(&self) -> &FlightStatus {
        match self {
            CampaignFlight::UpToDate(status) | CampaignFlight::Processed { status, .. } => status,
        }
    }
}

/// Processes `job` into `folder` unless its outputs are current (or
/// `force`), then writes its status. A flight that fails is a failed
/// status, not an error; the error is for a status that cannot be written.
/// `meter` hears each stage begin.
pub fn process_campaign_flight(
    job: &FlightJob,
    settings: &Settings,
    folder: &Path,
    (shard, force): (Shard, bool),
    meter: &dyn crate::messages::progress::Meter,
) -> Result<CampaignFlight> {
    let started = Instant::now();
    meter.begin(crate::messages::progress::Stage::Reading, 0);
    let path = status_path(folder, &job.output_name);
    let hashes = crate::ingest::flight_identity::hash_file(&job.input)
        .and_then(|input| Ok((input, settings_sha256(job, settings)?)));
    let mut status = failed_status(job, shard);
    let result = match hashes {
        Ok((input_sha256, settings_sha256)) => {
            if let Some(previous) = FlightStatus::read(&path) {
                if !force && previous.is_current(folder, &input_sha256, &settings_sha256) {
                    return Ok(CampaignFlight::UpToDate(previous));
                }
            }
            (status.input_sha256, status.settings_sha256) = (input_sha256, settings_sha256);
            process_flight_listing(job, settings, &FlightOutputs::for_job(folder, job), meter)
        }
        Err(error) => Err(error),
    };
    let result = match result {
        Ok((result, written)) => {
            status.state = FlightState::Done;
            status.rows = Some(result.rows);
            status.warnings = result.warnings.iter().map(ToString::to_string).collect();
            status.verdicts = (result.channels.iter())
                .map(|c| ChannelVerdict {
                    channel: c.channel.clone(),
                    verdict: c.verdict,
                })
                .collect();
            status.outputs = file_names(&written);
            Ok(result)
        }
        Err(error) => {
            status.error = Some(error.to_string());
            Err(error)
        }
    };
    status.elapsed_s = started.elapsed().as_secs_f64();
    status.write(&path)?;
    Ok(CampaignFlight::Processed {
        status,
        result: Box::new(result),
    })
}

/// A flight of the campaign that cannot be processed for `error` (its
/// calibration flight failed in this run, say): its status is written
/// as failed, with the error, like any failure.
pub fn fail_campaign_flight(job: &FlightJob, folder: &Path, shard: Shard, error: Error) -> Result<CampaignFlight> {
    let mut status = failed_status(job, shard);
    status.error = Some(error.to_string());
    status.write(&status_path(folder, &job.output_name))?;
    Ok(CampaignFlight::Processed {
        status,
        result: Box::new(Err(error)),
    })
}

/// The status of `job` before its work: failed, with nothing written.
fn failed_status(job: &FlightJob, shard: Shard) -> FlightStatus {
    FlightStatus {
        flight: job.output_name.clone(),
        input: job.input.clone(),
        input_sha256: String::new(),
        settings_sha256: String::new(),
        magcomp_version: env!("CARGO_PKG_VERSION").into(),
        state: FlightState::Failed,
        error: None,
        outputs: Vec::new(),
        rows: None,
        warnings: Vec::new(),
        verdicts: Vec::new(),
        aircraft: job.aircraft.clone(),
        date: job.date.map(|d| d.to_string()),
        elapsed_s: 0.0,
        shard: shard.to_string(),
    }
}

fn file_names(paths: &[PathBuf]) -> Vec<String> {
    let mut names: Vec<String> = paths
        .iter()
        .filter_map(|p| p.file_name())
        .map(|n| n.to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}
