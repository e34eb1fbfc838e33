//! `magcomp simulate`: a flight from a scenario, or a recorded flight
//! flown again (`--replay`).

use std::path::Path;

use magcomp::calibration::windows::CalibrationWindow;
use magcomp::config::{FlightJob, Pipeline};
use magcomp::formats::{prepare, Destination, OutputKind, OutputSet};

use super::{beside, print_notes, read_prepared, spinner};

/// `simulate --replay`: the recorded flight flown again with plain
/// Tolles-Lawson and with the diagnosed models.
pub fn replay_flight(
    flight: &Path,
    out: &Path,
    diagnosis: Option<&Path>,
    windows: &[String],
    config: Option<&Path>,
) -> anyhow::Result<()> {
    let pipeline = Pipeline::load_or_default(config)?;
    let report = beside(out, "_replay.json");
    let inputs: Vec<&Path> = [Some(flight), diagnosis, config].into_iter().flatten().collect();
    print_notes(&prepare(
        &inputs,
        &[
            Destination::new(out, OutputKind::Flight, "--out"),
            Destination::new(&report, OutputKind::Json, "the replay figures beside --out"),
        ],
    )?);
    let job = FlightJob {
        windows: (windows.iter())
            .map(|w| CalibrationWindow::parse(w))
            .collect::<Result<_, _>>()?,
        ..FlightJob::new(flight)
    };
    let prepared = read_prepared(&job, &pipeline)?;
    let bar = spinner(format!("replaying {}", flight.display()));
    let plan = replay_plan(&prepared, diagnosis, &pipeline);
    let replayed = plan.and_then(|plan| {
        magcomp::simulate::replay::replay(
            &prepared.calibration(),
            &pipeline.settings.terms,
            &pipeline.settings.fit,
            &plan,
        )
    });
    bar.finish_and_clear();
    let replayed = replayed?;
    let mut set = OutputSet::new();
    set.add(magcomp::formats::stage_flight_log(&replayed.log, out)?);
    set.add(magcomp::formats::stage_json(
        &report,
        "the replay figures",
        &replayed.channels,
    )?);
    set.commit()?;
    print_replayed(&replayed.channels);
    println!("wrote {} and {}", out.display(), report.display());
    Ok(())
}

/// Each replayed channel on the terminal: the recording less the replay in
/// band over the calibration manoeuvres and elsewhere, plain and with the
/// diagnosed model, nT.
fn print_replayed(channels: &[magcomp::simulate::replay::ReplayedChannel]) {
    for channel in channels {
        println!(
            "  {}: recording − replay in band, over the calibration manoeuvres {:.4} nT with plain Tolles-Lawson, {:.4} nT with {}; elsewhere {:.4} → {:.4} nT",
            channel.channel,
            channel.calibration_rms_plain_nt,
            channel.calibration_rms_diagnosed_nt,
            channel.model,
            channel.elsewhere_rms_plain_nt,
            channel.elsewhere_rms_diagnosed_nt
        );
    }
}

/// The models to replay the flight with: each channel's in the saved
/// `diagnosis` (its remark said as a warning), or from diagnosing it.
fn replay_plan(
    prepared: &magcomp::pipeline::PreparedFlight,
    diagnosis: Option<&Path>,
    pipeline: &Pipeline,
) -> magcomp::error::Result<std::collections::BTreeMap<String, magcomp::model::Extensions>> {
    let log = prepared.log();
    match diagnosis {
        Some(path) => magcomp::diagnose::read_saved(path)
            .and_then(|saved| saved.models_for(path, log, false))
            .map(|(models, remark)| {
                if let Some(remark) = remark {
                    println!("  warning: {remark}");
                }
                models
            }),
        None => magcomp::diagnose::diagnose(
            &prepared.calibration(),
            &pipeline.settings.terms,
            &pipeline.settings.fit,
            &pipeline.settings.diagnose,
        )
        .map(|d| d.models()),
    }
}

/// Simulates the scenario and writes the flight, its truth and its windows.
pub fn simulate(scenario_path: &Path, out: &Path, seed: Option<u64>) -> anyhow::Result<()> {
    let mut scenario = magcomp::simulate::scenario::Scenario::load(scenario_path)?;
    if let Some(seed) = seed {
        scenario.raw.seed = seed;
    }
    let [truth, truth_csv, windows] = magcomp::simulate::truth::Truth::paths_beside(out);
    print_notes(&prepare(
        &[scenario_path],
        &[
            Destination::new(out, OutputKind::Flight, "--out"),
            Destination::new(&truth, OutputKind::Json, "the truth JSON beside --out"),
            Destination::new(&truth_csv, OutputKind::Csv, "the truth CSV beside --out"),
            Destination::new(&windows, OutputKind::Json, "the windows JSON beside --out"),
        ],
    )?);
    let bar = spinner(format!("simulating {}", out.display()));
    let flight = magcomp::simulate::simulate(&scenario);
    bar.finish_and_clear();
    let flight = flight?;
    let mut set = OutputSet::new();
    set.add(magcomp::formats::stage_flight_log(&flight.log, out)?);
    for staged in flight.truth.stage_beside(out)? {
        set.add(staged);
    }
    set.commit()?;
    println!(
        "wrote {} ({} rows, {} channels), {}, {} and {}",
        out.display(),
        flight.log.len(),
        flight.log.channels().len(),
        truth.display(),
        truth_csv.display(),
        windows.display()
    );
    Ok(())
}
