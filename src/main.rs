//! The `magcomp` command line: a thin layer over the library.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use anyhow::Context as _;
use magcomp::campaign::{run_flights, CampaignFlight, FinishedFlight, FlightState, FlightsAtOnce, Progress, Shard};
use magcomp::config::{FlightJob, Pipeline};
use magcomp::diagnose::ApplyDiagnosis;
use magcomp::formats::{prepare, Destination, OutputKind, OutputSet};
use magcomp::numerics::solve::LambdaChoice;
use magcomp::pipeline::summary;
use magcomp::sink::{process_flight_listing, FlightOutputs};
use magcomp::windows::CalibrationWindow;

/// Post-flight compensation of aeromagnetic surveys.
#[derive(Parser)]
#[command(name = "magcomp", version, about)]
struct Cli {
    /// Print every note of a flight (how it was read, detected and
    /// fitted) after its figures; without it only their count is printed,
    /// and the quality JSON and the report hold them.
    #[arg(short, long, global = true)]
    verbose: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Process every [[flight]] of a pipeline.toml.
    Run {
        /// The pipeline file.
        #[arg(default_value = "pipeline.toml")]
        config: PathBuf,
        /// Fit plain Tolles-Lawson only: no diagnosis is made or applied
        /// (overrides [diagnose] apply).
        #[arg(long)]
        plain: bool,
        /// Redo every flight, even those whose outputs are current (same
        /// input bytes and settings), and apply each flight's saved
        /// diagnosis even when it was made on another flight.
        #[arg(long)]
        force: bool,
        /// Process only shard K of N (K from 0): the flights at positions
        /// K, K+N, K+2N, … of the campaign sorted by output name. auto/N
        /// takes K from SLURM_ARRAY_TASK_ID (less SLURM_ARRAY_TASK_MIN),
        /// JOB_COMPLETION_INDEX or AWS_BATCH_JOB_ARRAY_INDEX.
        #[arg(long, value_name = "K/N")]
        shard: Option<String>,
    },
    /// Merge a run's per-flight statuses and quality and model JSONs into
    /// a campaign table: campaign_summary.csv and .html, and
    /// campaign_coefficients.csv when an aircraft recurs.
    Summarize {
        /// The [output] directory of a run.
        outdir: PathBuf,
    },
    /// Fit on calibration windows (detected unless given) and compensate
    /// every row of one flight.
    Compensate(Box<CompensateArgs>),
    /// Find where the model and the recording disagree, name the physics
    /// left out, model it and show the held-out fit; write DIAGNOSIS.json.
    Diagnose {
        /// The flight log.
        flight: PathBuf,
        /// DIAGNOSIS.json to write.
        #[arg(long)]
        out: PathBuf,
        /// HTML page of the findings and residuals (default: OUT with .html).
        #[arg(long)]
        html: Option<PathBuf>,
        /// Calibration window T0:T1; repeat for several (default: detected).
        #[arg(long = "window")]
        windows: Vec<String>,
        /// Settings file (flights in it are ignored).
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Find the calibration boxes and their manoeuvres; write DETECT.json.
    Detect {
        /// The flight log.
        flight: PathBuf,
        /// DETECT.json to write.
        #[arg(long)]
        out: PathBuf,
        /// Settings file for columns and [detect] thresholds (flights in it are ignored).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Keep only what was detected on these calibration lines (the line
        /// column), comma-separated, e.g. 1002.20,1002.21.
        #[arg(long)]
        lines: Option<String>,
    },
    /// Rewrite a flight log in another format (CSV, Geosoft XYZ, MCAP or
    /// HDF5, by the output's extension); MCAP inputs are aligned on one
    /// time base.
    Convert {
        /// The flight log to read (CSV or other delimited text, Geosoft XYZ,
        /// MCAP, HDF5).
        flight: PathBuf,
        /// Output file; its extension picks the format: .xyz Geosoft XYZ,
        /// .mcap MCAP, .h5 or .hdf5 HDF5, anything else (.csv) comma-separated
        /// text.
        #[arg(long)]
        out: PathBuf,
        /// Settings file for columns and alignment (flights in it are ignored).
        #[arg(long)]
        config: Option<PathBuf>,
        /// The day the flight was flown, YYYY-MM-DD (UTC), over what the
        /// file says; MCAP output's log times count from its midnight.
        #[arg(long, value_parser = parse_date)]
        date: Option<magcomp::flight_date::FlightDate>,
    },
    /// Simulate a flight from a scenario: the recording (CSV, MCAP, XYZ or
    /// HDF5 by extension), and beside it the truth and calibration windows.
    ///
    /// With --replay, fly a recorded flight again instead: each scalar
    /// sensor re-simulated from the recorded fluxgate and auxiliary
    /// columns with plain Tolles-Lawson and with the diagnosed model, and
    /// how closely each reproduces the recording.
    Simulate {
        /// The scenario file.
        #[arg(required_unless_present = "replay")]
        scenario: Option<PathBuf>,
        /// Output flight; its extension picks the format.
        #[arg(long)]
        out: PathBuf,
        /// Override the scenario's seed.
        #[arg(long, conflicts_with = "replay")]
        seed: Option<u64>,
        /// A recorded flight to replay.
        #[arg(long, conflicts_with = "scenario")]
        replay: Option<PathBuf>,
        /// The DIAGNOSIS.json whose models to replay with (default:
        /// diagnose the flight now).
        #[arg(long, requires = "replay")]
        diagnosis: Option<PathBuf>,
        /// Calibration window T0:T1 of the replayed flight; repeat for
        /// several (default: detected).
        #[arg(long = "window", requires = "replay")]
        windows: Vec<String>,
        /// Settings file (flights in it are ignored).
        #[arg(long, requires = "replay")]
        config: Option<PathBuf>,
    },
    /// Predict what a planned calibration would achieve before it is
    /// flown: the FOM and the survey uncertainty, from simulated flights of
    /// the plan, and the cheapest manoeuvres to add to meet a target.
    Plan {
        /// The plan: a scenario (SCENARIO.toml's tables) with a [plan] table.
        plan: PathBuf,
        /// PLAN_REPORT.json to write.
        #[arg(long)]
        out: PathBuf,
        /// Settings file for the fit (flights in it are ignored).
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Write a sample flight (box and survey lines) and its calibration windows.
    SampleFlight {
        /// Output CSV.
        #[arg(long)]
        out: PathBuf,
        /// Output DETECT.json-style window file.
        #[arg(long)]
        windows: PathBuf,
        /// Random seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

#[derive(clap::Args)]
struct CompensateArgs {
    /// The flight log.
    flight: PathBuf,
    /// Compensated flight to write, in the format its extension names:
    /// .xyz Geosoft XYZ, .mcap MCAP, .h5 or .hdf5 HDF5, anything else
    /// (.csv) comma-separated text. A CSV to a CSV, or an XYZ to an XYZ,
    /// keeps the input's lines as they are and adds the columns.
    #[arg(long)]
    out: PathBuf,
    /// Quality JSON to write.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Model JSON to write: the fitted models with what applying them to
    /// another flight (--apply) needs.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Compensate with a model saved from another flight (--model), e.g.
    /// the calibration flight of the same aircraft: nothing is refitted.
    /// Windows or --lines, when given, hold the model out on this flight's
    /// own manoeuvres.
    #[arg(long, value_name = "MODEL.json", conflicts_with_all = ["model", "diagnosis", "augment", "plain", "lambda", "plan"])]
    apply: Option<PathBuf>,
    /// The airframe (e.g. its registration): saved in the model JSON, and
    /// checked against the model's with --apply.
    #[arg(long)]
    aircraft: Option<String>,
    /// HTML quality report to write (default: OUT's name with _report.html).
    #[arg(long)]
    html: Option<PathBuf>,
    /// Calibration window T0:T1 in the file's time unit; repeat for several.
    /// Without windows, the manoeuvres are detected in the flight.
    #[arg(long = "window")]
    windows: Vec<String>,
    /// DETECT.json file whose manoeuvres are the calibration windows.
    #[arg(long)]
    windows_file: Option<PathBuf>,
    /// Calibration data by line number (the line column), comma-separated,
    /// e.g. 1002.20,1002.21: the manoeuvres detected on those lines (or,
    /// where none is, each line's whole span) are the calibration windows.
    #[arg(long, conflicts_with_all = ["windows", "windows_file"])]
    lines: Option<String>,
    /// Fix the ridge parameter instead of choosing it by PRESS.
    #[arg(long, allow_negative_numbers = true)]
    lambda: Option<f64>,
    /// Vector magnetometer prefix, e.g. flux_a.
    #[arg(long)]
    vector: Option<String>,
    /// Scalar channels to compensate, comma-separated.
    #[arg(long, value_delimiter = ',')]
    channels: Option<Vec<String>>,
    /// Settings file for columns, filter and fit (flights in it are ignored).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Accept a DIAGNOSIS.json: fit and compensate each channel it lists
    /// with the model its findings make.
    #[arg(long, conflicts_with = "augment")]
    diagnosis: Option<PathBuf>,
    /// Diagnose the flight first and compensate with the models found,
    /// and fail when it cannot be diagnosed ([diagnose] apply = "always");
    /// the diagnosis is written beside OUT (_diagnosis.json). By default
    /// ("auto") the flight is diagnosed too, and compensated plain when
    /// it cannot be.
    #[arg(long, conflicts_with = "plain")]
    augment: bool,
    /// Fit plain Tolles-Lawson only: no diagnosis is made or applied.
    #[arg(long, conflicts_with = "diagnosis")]
    plain: bool,
    /// Apply --diagnosis even when it was made on another flight.
    #[arg(long, requires = "diagnosis")]
    force: bool,
    /// The PLAN_REPORT.json of the plan this flight was flown to
    /// (`magcomp plan`): each channel's FOM and survey uncertainty are set
    /// against the plan's prediction, and a figure beyond the plan's
    /// stated factor is a warning.
    #[arg(long)]
    plan: Option<PathBuf>,
    /// The day the flight was flown, YYYY-MM-DD (UTC), over what the file
    /// says; MCAP output's log times count from its midnight.
    #[arg(long, value_parser = parse_date)]
    date: Option<magcomp::flight_date::FlightDate>,
    /// Also write mag_<n>_dc: each compensated channel less the base
    /// station's variation ([output] dc).
    #[arg(long)]
    dc: bool,
    /// Also write mag_<n>_igrf: each compensated channel less the base
    /// station's variation and IGRF-14 at the aircraft's position and the
    /// flight's date ([output] igrf).
    #[arg(long)]
    igrf: bool,
}

/// `--date`: a day as YYYY-MM-DD.
fn parse_date(text: &str) -> Result<magcomp::flight_date::FlightDate, String> {
    magcomp::flight_date::FlightDate::parse(text)
        .ok_or_else(|| format!("'{text}' is not a day; write it as YYYY-MM-DD, e.g. 2020-06-20"))
}

fn main() -> ExitCode {
    // Like other command-line tools, stop quietly when the reader of our
    // output goes away (`magcomp detect ... | head`) instead of failing to
    // print.
    #[cfg(unix)]
    // SAFETY: restoring the default action of SIGPIPE before any thread
    // starts; no handler of ours is involved.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    let outcome = match cli.command {
        Command::Run {
            config,
            plain,
            force,
            shard,
        } => run(&config, (plain, force, cli.verbose), shard.as_deref()),
        Command::Summarize { outdir } => summarize(&outdir),
        Command::Compensate(args) => compensate(*args, cli.verbose),
        Command::Detect {
            flight,
            out,
            config,
            lines,
        } => detect(&flight, &out, config.as_deref(), lines.as_deref()),
        Command::Diagnose {
            flight,
            out,
            html,
            windows,
            config,
        } => {
            let html = html.unwrap_or_else(|| out.with_extension("html"));
            diagnose(&flight, (&out, &html), &windows, config.as_deref())
        }
        Command::SampleFlight { out, windows, seed } => sample_flight(&out, &windows, seed),
        Command::Plan { plan, out, config } => plan_calibration(&plan, &out, config.as_deref()),
        Command::Convert {
            flight,
            out,
            config,
            date,
        } => convert(&flight, &out, config.as_deref(), date),
        Command::Simulate {
            scenario,
            out,
            seed,
            replay,
            diagnosis,
            windows,
            config,
        } => match (scenario, replay) {
            (_, Some(flight)) => replay_flight(&flight, &out, diagnosis.as_deref(), &windows, config.as_deref()),
            (Some(scenario), None) => simulate(&scenario, &out, seed),
            (None, None) => Err(anyhow::anyhow!("give a SCENARIO.toml to simulate, or --replay FLIGHT")),
        },
    };
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("magcomp: error: {}", error_paragraph(&error));
            ExitCode::FAILURE
        }
    }
}

/// An error and its causes as one paragraph; a cause whose text the
/// paragraph already holds (our errors quote their sources) is not repeated.
fn error_paragraph(error: &anyhow::Error) -> String {
    let mut paragraph = String::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if paragraph.contains(&text) {
            continue;
        }
        if !paragraph.is_empty() {
            paragraph += ": ";
        }
        paragraph += &text;
    }
    paragraph
}

/// Reads a flight and screens its samples, printing what was masked.
fn read_screened(flight: &Path, pipeline: &Pipeline) -> magcomp::error::Result<magcomp::flight_log::FlightLog> {
    let recorded = magcomp::formats::read_flight_log(flight, &pipeline.settings.ingest)?;
    let screened = magcomp::screen::screen_samples(&recorded)?;
    for warning in screened.warnings(&recorded) {
        println!("  warning: {warning}");
    }
    Ok(screened.log.unwrap_or(recorded))
}

/// `<stem of path><suffix>` in `path`'s folder.
fn beside(path: &Path, suffix: &str) -> PathBuf {
    let stem = path
        .file_stem()
        .map_or("flight".into(), |s| s.to_string_lossy().into_owned());
    path.with_file_name(format!("{stem}{suffix}"))
}

fn print_notes(notes: &[String]) {
    for note in notes {
        println!("  note: {note}");
    }
}

/// "40 s", "3 min", "1 h 20 min": a time left, as a person says it.
fn duration_words(duration: Duration) -> String {
    let seconds = duration.as_secs();
    match seconds {
        0..=59 => format!("{seconds} s"),
        60..=3599 => format!("{} min", seconds.div_ceil(60)),
        _ => format!("{} h {} min", seconds / 3600, (seconds % 3600) / 60),
    }
}

/// A spinner on stderr with `message` and the time elapsed; indicatif
/// draws nothing when stderr is not a terminal (piped or redirected).
fn spinner(message: String) -> ProgressBar {
    let bar = ProgressBar::new_spinner().with_message(message);
    bar.set_style(
        ProgressStyle::with_template("{spinner} {msg} [{elapsed}]")
            .unwrap_or_else(|_| ProgressStyle::default_spinner()),
    );
    bar.enable_steady_tick(Duration::from_millis(120));
    bar
}

fn run(config: &Path, (plain, force, verbose): (bool, bool, bool), shard: Option<&str>) -> anyhow::Result<()> {
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
    let shard = match shard {
        Some(text) => Shard::parse(text, |name| std::env::var(name).ok())?,
        None => Shard::default(),
    };
    // A flight compensated with the model another flight of this run
    // writes (a survey flight and its calibration flight) comes after it.
    let mine = magcomp::campaign::dependency_order(&pipeline, shard.select(&pipeline.flights));
    let folder = &pipeline.output_directory;
    if shard.count > 1 {
        println!(
            "shard {shard}: {} of the campaign's {} flights",
            mine.len(),
            pipeline.flights.len()
        );
    }
    if !folder.as_os_str().is_empty() && !folder.is_dir() {
        std::fs::create_dir_all(folder)
            .with_context(|| format!("{}: creating the output folder {}", config.display(), folder.display()))?;
        println!("created the output folder {}", folder.display());
    }
    let jobs: Vec<&FlightJob> = mine.iter().map(|&i| &pipeline.flights[i]).collect();
    let at_once = FlightsAtOnce::for_jobs(&jobs);
    if mine.len() > 1 {
        println!("{} flights, {} at once: {}", mine.len(), at_once.count, at_once.reason);
    }
    let bar = spinner(format!("compensating {} flights", mine.len()));
    let progress_words = |progress: Progress| {
        let left = progress
            .left
            .map_or(String::new(), |left| format!(", about {} left", duration_words(left)));
        format!(
            "{} of {} flights done, {} in progress{left}",
            progress.finished, progress.total, progress.running
        )
    };
    // Outputs that cannot be written fail the flight, with the same error,
    // in its status like any other failure.
    let prepare_outputs =
        |job: &FlightJob, outputs: &FlightOutputs| prepare_flight_outputs(job, outputs).unwrap_or_default();
    let started = |job: &FlightJob, progress: Progress| {
        bar.set_message(format!(
            "{}: compensating {}",
            progress_words(progress),
            job.input.display()
        ));
    };
    let finished = |done: &FinishedFlight, progress: Progress| {
        bar.set_message(progress_words(progress));
        bar.suspend(|| print_finished(&pipeline.flights[done.index], done, folder, verbose));
    };
    let flights = run_flights(
        &pipeline,
        &mine,
        (shard, force, at_once.count),
        &prepare_outputs,
        &started,
        &finished,
    );
    bar.finish_and_clear();
    let statuses: Vec<(String, FlightState, String)> = flights
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
        .collect();
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
    Ok(())
}

/// Prints what became of a flight of a run: its notes, its summary and
/// the files written, or why it failed.
fn print_finished(job: &FlightJob, done: &FinishedFlight, folder: &Path, verbose: bool) {
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
                print!("{}", summary(result, verbose));
                println!("  wrote {}: {}", folder.display(), status.outputs.join(", "));
            }
            Err(error) => eprintln!("magcomp: error: processing {}: {error}", job.input.display()),
        },
    }
}

/// Makes the folders of a flight's outputs; what it made, as notes.
fn prepare_flight_outputs(job: &FlightJob, outputs: &FlightOutputs) -> magcomp::error::Result<Vec<String>> {
    let inputs: Vec<&Path> = std::iter::once(job.input.as_path())
        .chain(job.diagnosis.as_deref())
        .chain(job.plan.as_deref())
        .chain(job.model.as_deref())
        .collect();
    prepare(&inputs, &outputs.destinations())
}

/// The run's per-flight status table: flight, and how it ended.
fn status_table(statuses: &[(String, FlightState, String)]) -> String {
    let width = statuses
        .iter()
        .map(|(flight, _, _)| flight.chars().count())
        .max()
        .unwrap_or(0)
        .max(6);
    let mut table = format!("\n{:<width$}  status\n", "flight");
    for (flight, _, outcome) in statuses {
        table += &format!("{flight:<width$}  {outcome}\n");
    }
    table
}

fn summarize(folder: &Path) -> anyhow::Result<()> {
    let summary = magcomp::campaign::summary::summarize(folder)?;
    print!("{}", summary.describe());
    for path in summary.write(folder)? {
        println!("  wrote {}", path.display());
    }
    Ok(())
}

fn compensate(args: CompensateArgs, verbose: bool) -> anyhow::Result<()> {
    let mut pipeline = Pipeline::load_or_default(args.config.as_deref())?;
    if let Some(lambda) = args.lambda {
        anyhow::ensure!(
            lambda.is_finite() && lambda >= 0.0,
            "--lambda {lambda}: λ must be a non-negative number (0 for no regularisation); leave --lambda out to choose λ by PRESS"
        );
        pipeline.settings.fit.solve.lambda = LambdaChoice::Fixed(lambda);
    }
    let mut windows = args
        .windows
        .iter()
        .map(|w| CalibrationWindow::parse(w))
        .collect::<Result<Vec<_>, _>>()?;
    let mut windows_detected_on = None;
    if let Some(file) = &args.windows_file {
        let detected = magcomp::windows::read_detect_file(file, pipeline.settings.detect.window_margin_s)?;
        windows.extend(detected.windows);
        windows_detected_on = detected.flight.map(|identity| (file.clone(), identity));
    }
    if args.augment {
        pipeline.settings.diagnose.apply = ApplyDiagnosis::Always;
    }
    if args.plain {
        pipeline.settings.diagnose.apply = ApplyDiagnosis::Never;
    }
    pipeline.settings.ingest.date = args.date.or(pipeline.settings.ingest.date);
    pipeline.settings.reduced.dc |= args.dc;
    pipeline.settings.reduced.igrf |= args.igrf;
    let job = FlightJob {
        diagnosis: args.diagnosis.clone(),
        force_diagnosis: args.force,
        plan: args.plan.clone(),
        vector: args.vector,
        channels: args.channels,
        windows,
        lines: args
            .lines
            .as_deref()
            .map(magcomp::windows::parse_lines)
            .transpose()?
            .unwrap_or_default(),
        windows_detected_on,
        model: args.apply.clone(),
        aircraft: args.aircraft.clone(),
        ..FlightJob::new(args.flight.clone())
    };
    let beside_out = |suffix: &str| beside(&args.out, suffix);
    let outputs = FlightOutputs {
        diagnosis_json: Some(beside_out("_diagnosis.json")),
        compensated: args.out.clone(),
        model_json: args.model,
        quality_json: args.report,
        report_html: Some(args.html.clone().unwrap_or_else(|| beside_out("_report.html"))),
    };
    let other_inputs: Vec<&Path> = [&args.windows_file, &args.config, &args.apply]
        .into_iter()
        .flatten()
        .map(PathBuf::as_path)
        .collect();
    magcomp::formats::destination::refuse_inputs(&other_inputs, &outputs.destinations())?;
    print_notes(&prepare_flight_outputs(&job, &outputs)?);
    let bar = spinner(format!("compensating {}", args.flight.display()));
    let result = process_flight_listing(&job, &pipeline.settings, &outputs);
    bar.finish_and_clear();
    let (result, written) = result?;
    print!("{}", summary(&result, verbose));
    for path in written {
        println!("  wrote {}", path.display());
    }
    Ok(())
}

fn convert(
    flight: &Path,
    out: &Path,
    config: Option<&Path>,
    date: Option<magcomp::flight_date::FlightDate>,
) -> anyhow::Result<()> {
    let mut pipeline = Pipeline::load_or_default(config)?;
    pipeline.settings.ingest.date = date.or(pipeline.settings.ingest.date);
    let inputs: Vec<&Path> = std::iter::once(flight).chain(config).collect();
    print_notes(&prepare(
        &inputs,
        &[Destination::new(out, OutputKind::Flight, "--out")],
    )?);
    let log = magcomp::formats::read_flight_log(flight, &pipeline.settings.ingest)?;
    magcomp::formats::write_flight_log(&log, out)?;
    let warnings = (log.reading_warnings().iter().cloned())
        .chain(magcomp::formats::mcap::undated_warning(&log, out))
        .chain(magcomp::formats::write::text_columns_warning(&log, out, false));
    for warning in warnings {
        println!("  warning: {warning}");
    }
    println!(
        "wrote {} ({} rows, {} channels)",
        out.display(),
        log.len(),
        log.channels().len()
    );
    if let Some(report) = log.alignment() {
        println!("  time base: {} ({} rows)", report.time_base, report.rows);
        for note in &report.notes {
            println!("  note: {note}");
        }
        for warning in &report.warnings {
            println!("  warning: {warning}");
        }
    }
    Ok(())
}

fn sample_flight(out: &Path, windows: &Path, seed: u64) -> anyhow::Result<()> {
    print_notes(&prepare(
        &[],
        &[
            Destination::new(out, OutputKind::Csv, "--out"),
            Destination::new(windows, OutputKind::Json, "--windows"),
        ],
    )?);
    let flight = magcomp::sample_flight::generate(&magcomp::sample_flight::SampleFlightSpec::default(), seed);
    magcomp::sample_flight::write(&flight, out, windows)?;
    println!(
        "wrote {} ({} rows) and {}",
        out.display(),
        flight.time_s.len(),
        windows.display()
    );
    Ok(())
}

/// `simulate --replay`: the recorded flight flown again with plain
/// Tolles-Lawson and with the diagnosed models.
fn replay_flight(
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
    let log = read_screened(flight, &pipeline)?;
    let sensor = magcomp::pipeline::choose_vector_sensor(&log, None)?;
    let channels = magcomp::pipeline::choose_channels(&log, None)?;
    let mut windows = windows
        .iter()
        .map(|w| CalibrationWindow::parse(w))
        .collect::<Result<Vec<_>, _>>()?;
    if windows.is_empty() {
        windows = magcomp::detect::detect_manoeuvres(&log, &pipeline.settings.detect)?
            .calibration_windows(pipeline.settings.detect.window_margin_s);
    }
    let bar = spinner(format!("replaying {}", flight.display()));
    let plan = match diagnosis {
        Some(path) => magcomp::diagnose::read_saved(path)
            .and_then(|saved| saved.models_for(path, &log, false))
            .map(|(models, remark)| {
                if let Some(remark) = remark {
                    println!("  warning: {remark}");
                }
                models
            }),
        None => magcomp::diagnose::diagnose(
            &log,
            &sensor,
            &channels,
            &windows,
            &pipeline.settings.terms,
            &pipeline.settings.fit,
            &pipeline.settings.diagnose,
        )
        .map(|d| d.models()),
    };
    let replayed = plan.and_then(|plan| {
        magcomp::simulate::replay::replay(
            &log,
            &sensor,
            &channels,
            &windows,
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
    for channel in &replayed.channels {
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
    println!("wrote {} and {}", out.display(), report.display());
    Ok(())
}

fn simulate(scenario_path: &Path, out: &Path, seed: Option<u64>) -> anyhow::Result<()> {
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

fn plan_calibration(plan_path: &Path, out: &Path, config: Option<&Path>) -> anyhow::Result<()> {
    let pipeline = Pipeline::load_or_default(config)?;
    let plan = magcomp::plan::Plan::load(plan_path)?;
    let mut inputs: Vec<&Path> = vec![plan_path];
    inputs.extend(config);
    inputs.extend(plan.settings.installation.as_deref());
    print_notes(&prepare(&inputs, &[Destination::new(out, OutputKind::Json, "--out")])?);
    let bar = spinner(format!(
        "flying {} simulated flights of {}",
        plan.settings.realisations,
        plan_path.display()
    ));
    let report = magcomp::plan::predict(&plan, &pipeline.settings);
    bar.finish_and_clear();
    let report = report?;
    magcomp::formats::write_json(out, "the plan report", &report)?;
    for line in &report.summary {
        println!("  {line}");
    }
    for warning in &report.warnings {
        println!("  warning: {warning}");
    }
    println!("wrote {}", out.display());
    Ok(())
}

fn detect(flight: &Path, out: &Path, config: Option<&Path>, lines: Option<&str>) -> anyhow::Result<()> {
    let pipeline = Pipeline::load_or_default(config)?;
    let lines = lines.map(magcomp::windows::parse_lines).transpose()?;
    let inputs: Vec<&Path> = std::iter::once(flight).chain(config).collect();
    print_notes(&prepare(&inputs, &[Destination::new(out, OutputKind::Json, "--out")])?);
    let log = read_screened(flight, &pipeline)?;
    let mut detection = magcomp::detect::detect_manoeuvres(&log, &pipeline.settings.detect)?;
    if let Some(lines) = lines {
        let spans = magcomp::windows::line_spans(&log, &lines)?;
        detection = detection.on_lines(&spans);
    }
    /// DETECT.json: the detection and the flight it was made on.
    #[derive(serde::Serialize)]
    struct DetectJson<'a> {
        #[serde(flatten)]
        detection: &'a magcomp::detect::Detection,
        flight: magcomp::flight_identity::FlightIdentity,
    }
    let file = DetectJson {
        detection: &detection,
        flight: magcomp::flight_identity::FlightIdentity::of(&log)?,
    };
    magcomp::formats::write_json(out, "the detected manoeuvres", &file)?;
    for note in magcomp::pipeline::detection_notes(&detection) {
        println!("  {note}");
    }
    for warning in magcomp::pipeline::detection_warnings(&detection) {
        println!("  warning: {warning}");
    }
    for manoeuvre in &detection.manoeuvres {
        println!(
            "  {:<5} heading {:>5.1}: {:.1}–{:.1} s, {} cycles of {:.1} s, ±{:.1}°{}",
            format!("{:?}", manoeuvre.kind).to_lowercase(),
            manoeuvre.heading_deg,
            manoeuvre.t_start,
            manoeuvre.t_end,
            manoeuvre.cycles,
            manoeuvre.period_s,
            manoeuvre.amplitude_deg,
            manoeuvre
                .could_be
                .map(|other| format!(" (or a {}: uncertain)", format!("{other:?}").to_lowercase()))
                .unwrap_or_default()
        );
    }
    println!("wrote {}", out.display());
    Ok(())
}

fn diagnose(
    flight: &Path,
    (out, html): (&Path, &Path),
    windows: &[String],
    config: Option<&Path>,
) -> anyhow::Result<()> {
    let pipeline = Pipeline::load_or_default(config)?;
    let inputs: Vec<&Path> = std::iter::once(flight).chain(config).collect();
    print_notes(&prepare(
        &inputs,
        &[
            Destination::new(out, OutputKind::Json, "--out"),
            Destination::new(html, OutputKind::Html, "--html"),
        ],
    )?);
    let log = read_screened(flight, &pipeline)?;
    let job = FlightJob {
        diagnosis: None,
        force_diagnosis: false,
        windows: windows
            .iter()
            .map(|w| CalibrationWindow::parse(w))
            .collect::<Result<_, _>>()?,
        ..FlightJob::new(flight)
    };
    let bar = spinner(format!("diagnosing {}", flight.display()));
    let diagnosis = magcomp::pipeline::diagnose_flight(&log, &job, &pipeline.settings, &pipeline.settings.diagnose);
    bar.finish_and_clear();
    let diagnosis = diagnosis?;
    let mut set = OutputSet::new();
    set.add(magcomp::formats::stage_json(out, "the diagnosis", &diagnosis)?);
    set.add_last(magcomp::report::stage_diagnosis_report(html, flight, &diagnosis)?);
    set.commit()?;
    for channel in &diagnosis.channels {
        println!(
            "  {}: held-out RMS {:.4} nT with plain Tolles-Lawson, {:.4} nT with the findings and λ by {} as compensation picks it",
            channel.channel,
            channel.heldout_rms_baseline_nt,
            channel.heldout_rms_final_nt,
            pipeline.settings.fit.solve.criterion.describe()
        );
        if let (true, Some(start)) = (
            channel.search_criterion != pipeline.settings.fit.solve.criterion,
            channel.heldout_rms_other_criterion_nt,
        ) {
            println!(
                "    the search started from plain Tolles-Lawson with λ by {} ({start:.4} nT held out); its findings' figures are measured from there",
                channel.search_criterion.describe()
            );
        }
        if let Some(hint) = &channel.strongest_rejected {
            println!("    best candidate short of the threshold: {hint}");
        }
    }
    for note in &diagnosis.notes {
        println!("  note: {note}");
    }
    if diagnosis.findings.is_empty() {
        println!("  no finding: nothing in the library explains the residual better than plain Tolles-Lawson");
    }
    for finding in &diagnosis.findings {
        println!(
            "  {} on {}{}: held-out RMS {:.4} → {:.4} nT",
            finding.effect,
            finding.channel,
            finding
                .source
                .as_ref()
                .map(|s| format!(" from {s}"))
                .unwrap_or_default(),
            finding.heldout_rms_before_nt,
            finding.heldout_rms_after_nt
        );
        println!("    {}", finding.explanation);
    }
    println!("wrote {} and {}", out.display(), html.display());
    if diagnosis.channels.iter().any(|c| !c.model.is_plain()) {
        println!(
            "to compensate with these models: magcomp compensate {} --out OUT.csv --diagnosis {}",
            flight.display(),
            out.display()
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_left_reads_as_a_person_says_it() {
        assert_eq!(duration_words(Duration::from_secs(40)), "40 s");
        assert_eq!(duration_words(Duration::from_secs(61)), "2 min");
        assert_eq!(duration_words(Duration::from_secs(4_800)), "1 h 20 min");
    }
}
