//! The `magcomp` command line: a thin layer over the library.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cli;

use cli::compensate::CompensateArgs;
use cli::parse_date;

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
        /// Exit 0 even when a channel's verdict is FAIL (default: exit code
        /// 3, the outputs written); also [quality] exit_zero_on_fail.
        #[arg(long)]
        exit_zero_on_fail: bool,
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
        date: Option<magcomp::ingest::flight_date::FlightDate>,
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
    let outcome = dispatch(cli.command, cli.verbose);
    match outcome {
        Ok(cli::Outcome::Done) => ExitCode::SUCCESS,
        Ok(cli::Outcome::ChannelFailed) => {
            eprintln!("{}", cli::FAIL_EXIT_LINE);
            ExitCode::from(3)
        }
        Err(error) => {
            eprintln!("magcomp: error: {}", error_paragraph(&error));
            ExitCode::FAILURE
        }
    }
}

/// Runs the subcommand `command` (`verbose`: with `-v`).
fn dispatch(command: Command, verbose: bool) -> anyhow::Result<cli::Outcome> {
    match command {
        Command::Run {
            config,
            plain,
            force,
            exit_zero_on_fail,
            shard,
        } => cli::run::run(&config, (plain, force, verbose, exit_zero_on_fail), shard.as_deref()),
        Command::Compensate(args) => cli::compensate::compensate(*args, verbose),
        command => other_command(command).map(|()| cli::Outcome::Done),
    }
}

/// Runs a subcommand that compensates no flight.
fn other_command(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Run { .. } | Command::Compensate(_) => unreachable!("dispatched above"),
        Command::Summarize { outdir } => cli::summarize::summarize(&outdir),
        Command::Detect {
            flight,
            out,
            config,
            lines,
        } => cli::detect::detect(&flight, &out, config.as_deref(), lines.as_deref()),
        Command::Diagnose {
            flight,
            out,
            html,
            windows,
            config,
        } => {
            let html = html.unwrap_or_else(|| out.with_extension("html"));
            cli::diagnose::diagnose(&flight, (&out, &html), &windows, config.as_deref())
        }
        Command::SampleFlight { out, windows, seed } => cli::sample_flight::sample_flight(&out, &windows, seed),
        Command::Plan { plan, out, config } => cli::plan::plan_calibration(&plan, &out, config.as_deref()),
        Command::Convert {
            flight,
            out,
            config,
            date,
        } => cli::convert::convert(&flight, &out, config.as_deref(), date),
        Command::Simulate {
            scenario,
            out,
            seed,
            replay,
            diagnosis,
            windows,
            config,
        } => match (scenario, replay) {
            (_, Some(flight)) => {
                cli::simulate::replay_flight(&flight, &out, diagnosis.as_deref(), &windows, config.as_deref())
            }
            (Some(scenario), None) => cli::simulate::simulate(&scenario, &out, seed),
            (None, None) => Err(anyhow::anyhow!("give a SCENARIO.toml to simulate, or --replay FLIGHT")),
        },
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
