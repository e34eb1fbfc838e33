//! `magcomp run`: every flight of a pipeline.toml, several at once.

use std::path::Path;

use anyhow::Context as _;
use magcomp::campaign::{run_flights, CampaignFlight, FinishedFlight, FlightState, FlightsAtOnce, Progress, Shard};
use magcomp::config::{FlightJob, Pipeline};
use magcomp::diagnose::ApplyDiagnosis;
use magcomp::messages::progress::Meter;
use magcomp::output::sink::FlightOutputs;
use magcomp::pipeline::summary;

use super::progress::{CampaignBar, FlightBar};
use super::{prepare_flight_outputs, print_notes};

/// Creates the run's output `folder` (named in `config`) when it does not
/// exist yet, saying so.
fn create_output_folder(config: &Path, folder: &Path) -> anyhow::Result<()> {
    if !folder.as_os_str().is_empty() && !folder.is_dir() {
        std::fs::create_dir_all(folder)
            .with_context(|| format!("{}: creating the output folder {}", config.display(), folder.display()))?;
        println!("created the output folder {}", folder.display());
    }
    Ok(())
}

/// The flights of `shard`, indices into the pipeline's, in the order they
/// run; said when the campaign is split into shards.
fn shard_flights(pipeline: &Pipeline, shard: Shard) -> Vec<usize> {
    // A flight compensated with the model another flight of this run
    // writes (a survey flight and its calibration flight) comes after it.
    let mine = magcomp::campaign::dependency_order(pipeline, shard.select(&pipeline.flights));
    if shard.count > 1 {
        println!(
            "shard {shard}: {} of the campaign's {} flights",
            mine.len(),
            pipeline.flights.len()
        );
    }
    mine
}

/// Runs every flight of the pipeline file `config` (this shard's), prints
/// each as it finishes and the status table, and fails when any flight did.
pub fn run(
    config: &Path,
    (plain, force, verbose, exit_zero_on_fail): (bool, bool, bool, bool),
    shard: Option<&str>,
) -> anyhow::Result<super::Outcome> {
    let mut pipeline = load(config, (plain, force))?;
    pipeline.settings.exit_zero_on_fail |= exit_zero_on_fail;
    let shard = match shard {
        Some(text) => Shard::parse(text, |name| std::env::var(name).ok())?,
        None => Shard::default(),
    };
    let mine = shard_flights(&pipeline, shard);
    let folder = &pipeline.output_directory;
    create_output_folder(config, folder)?;
    let jobs: Vec<&FlightJob> = mine.iter().map(|&i| &pipeline.flights[i]).collect();
    let at_once = FlightsAtOnce::for_jobs(&jobs);
    if mine.len() > 1 {
        println!("{} flights, {} at once: {}", mine.len(), at_once.count, at_once.reason);
    }
    let display = CampaignBar::new(mine.len());
    // Outputs that cannot be written fail the flight, with the same error,
    // in its status like any other failure.
    let prepare_outputs =
        |job: &FlightJob, outputs: &FlightOutputs| prepare_flight_outputs(job, outputs).unwrap_or_default();
    let started = |job: &FlightJob, progress: Progress| -> Box<dyn Meter> {
        display.show(progress);
        // A flight given another's model may wait for it before it starts.
        let first = match job.model {
            Some(_) => "waiting for its model",
            None => "starting",
        };
        Box::new(FlightBar::in_campaign(&display, &job.input, first))
    };
    let finished = |done: &FinishedFlight, progress: Progress| {
        display.show(progress);
        let limit = pipeline.settings.fom_limit_nt;
        display.suspend(|| print_finished(&pipeline.flights[done.index], done, folder, (limit, verbose)));
    };
    let mut flights = run_flights(
        &pipeline,
        &mine,
        (shard, force, at_once.count),
        &prepare_outputs,
        &started,
        &finished,
    );
    display.clear();
    // The table in the campaign's order, whatever order the flights ran in
    // (a flight given another's model runs after it).
    flights.sort_by_key(|done| done.index);
    report_statuses(config, &pipeline, &flights)
}

/// Prints the status table of the `flights` run and fails, naming the
/// pipeline file `config`, when any of them did; else whether a channel's
/// verdict is FAIL.
fn report_statuses(config: &Path, pipeline: &Pipeline, flights: &[FinishedFlight]) -> anyhow::Result<super::Outcome> {
    let statuses = statuses(pipeline, flights);
    print!("{}", status_table(&statuses));
    let failed = statuses
        .iter()
        .filter(|(_, state, _)| *state == FlightState::Failed)
        .count();
    anyhow::ensure!(
        failed == 0,
        "{}: {failed} of {} flights failed; each error is printed above and in its <flight>_status.json, and the other flights' outputs were written; run again to redo only the failed flights",
        config.display(),
        statuses.len()
    );
    let channel_failed = (flights.iter())
        .filter_map(|done| done.flight.as_ref().ok())
        .any(|flight| flight.status().verdict() == Some(magcomp::quality::verdict::Verdict::Fail));
    Ok(super::Outcome::of(channel_failed, pipeline.settings.exit_zero_on_fail))
}

/// The pipeline file `config`, its notes printed, with `--plain` and
/// `--force` set on it; an error when it names no flight.
fn load(config: &Path, (plain, force): (bool, bool)) -> anyhow::Result<Pipeline> {
    let mut pipeline = Pipeline::load(config)?;
    print_notes(&pipeline.notes);
    if plain {
        pipeline.settings.diagnose.apply = ApplyDiagnosis::Never;
    }
    for job in &mut pipeline.flights {
        job.force_diagnosis = force;
    }
    anyhow::ensure!(
        !pipeline.flights.is_empty(),
        "{}: no flights; add a [[flight]] with input = \"path/to/flight.csv\", or a [campaign] with inputs = [\"flights/*.csv\"] or a manifest",
        config.display()
    );
    Ok(pipeline)
}

/// Each finished flight's input, state and outcome in words, for the
/// status table.
fn statuses(pipeline: &Pipeline, flights: &[FinishedFlight]) -> Vec<(String, FlightState, String)> {
    flights
        .iter()
        .map(|done| {
            let job = &pipeline.flights[done.index];
            let (state, outcome) = match &done.flight {
                Ok(CampaignFlight::UpToDate(status)) => (status.state, "up to date, skipped".to_string()),
                Ok(CampaignFlight::Processed { status, .. }) => (status.state, status.outcome()),
                Err(_) => (
                    FlightState::Failed,
                    "failed, and its status could not be written".to_string(),
                ),
            };
            (job.input.display().to_string(), state, outcome)
        })
        .collect()
}

/// Prints what became of a flight of a run: its notes, its summary and
/// the files written, or why it failed; `limit` is the FOM limit.
fn print_finished(job: &FlightJob, done: &FinishedFlight, folder: &Path, (limit, verbose): (f64, bool)) {
    for note in &done.notes {
        println!("  note: {note}");
    }
    match &done.flight {
        // A flight whose status cannot be written fails alone: the others
        // are still processed and the table still comes.
        Err(error) => eprintln!(
            "magcomp: error: {}: writing the flight's status: {error}",
            job.input.display()
        ),
        Ok(CampaignFlight::UpToDate(_)) => println!(
            "{}: outputs current (same input and settings), skipped; --force redoes it",
            job.input.display()
        ),
        Ok(CampaignFlight::Processed { status, result }) => match result.as_ref() {
            Ok(result) => {
                print!("{}", summary(result, limit, verbose));
                println!("  wrote {}: {}", folder.display(), status.outputs.join(", "));
            }
            Err(error) => eprintln!("magcomp: error: processing {}: {error}", job.input.display()),
        },
    }
}

/// Widest the status table's flight column is padded to, characters: a
/// longer name runs on past it (a padding beyond 65,535 cannot be
/// formatted).
const MOST_FLIGHT_COLUMN: usize = 120;

/// The run's per-flight status table: flight, and how it ended.
fn status_table(statuses: &[(String, FlightState, String)]) -> String {
    let width = statuses
        .iter()
        .map(|(flight, _, _)| flight.chars().count())
        .max()
        .unwrap_or(0)
        .clamp(6, MOST_FLIGHT_COLUMN);
    let mut table = format!("\n{:<width$}  status\n", "flight");
    for (flight, _, outcome) in statuses {
        table += &format!("{flight:<width$}  {outcome}\n");
    }
    table
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flight_name_longer_than_any_padding_is_printed_whole() {
        let long = "a".repeat(70_000);
        let table = status_table(&[
            (long.clone(), FlightState::Failed, "FAILED: no such file".into()),
            ("short.csv".into(), FlightState::Done, "PASS".into()),
        ]);
        assert!(table.contains(&format!("{long}  FAILED: no such file")));
        let padded = format!("{:<width$}  PASS", "short.csv", width = MOST_FLIGHT_COLUMN);
        assert!(table.contains(&padded), "{}", &table[..200]);
    }
}
