//! `magcomp compensate`: fit and compensate one flight.

use std::path::{Path, PathBuf};

use magcomp::calibration::windows::CalibrationWindow;
use magcomp::config::{FlightJob, Pipeline};
use magcomp::diagnose::ApplyDiagnosis;
use magcomp::numerics::solve::LambdaChoice;
use magcomp::output::sink::{process_flight_listing, FlightOutputs};
use magcomp::pipeline::summary;

use super::progress::FlightBar;
use super::{beside, parse_date, prepare_flight_outputs, print_notes};

#[derive(clap::Args)]
pub struct CompensateArgs {
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
    date: Option<magcomp::ingest::flight_date::FlightDate>,
    /// Exit 0 even when a channel's verdict is FAIL (default: exit code
    /// 3, the outputs written); also [quality] exit_zero_on_fail.
    #[arg(long)]
    exit_zero_on_fail: bool,
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

/// The settings `args`' flags change: a fixed λ, the diagnosis always or
/// never applied, the flight's date, the reduced columns.
fn apply_flags(settings: &mut magcomp::config::Settings, args: &CompensateArgs) -> anyhow::Result<()> {
    if let Some(lambda) = args.lambda {
        anyhow::ensure!(
            lambda.is_finite() && lambda >= 0.0,
            "--lambda {lambda}: λ must be a non-negative number (0 for no regularisation); leave --lambda out to choose λ by PRESS"
        );
        settings.fit.solve.lambda = LambdaChoice::Fixed(lambda);
    }
    if args.augment {
        settings.diagnose.apply = ApplyDiagnosis::Always;
    }
    if args.plain {
        settings.diagnose.apply = ApplyDiagnosis::Never;
    }
    settings.ingest.date = args.date.or(settings.ingest.date);
    settings.reduced.dc |= args.dc;
    settings.reduced.igrf |= args.igrf;
    settings.exit_zero_on_fail |= args.exit_zero_on_fail;
    Ok(())
}

/// The flight `args` name as a job: its windows (given, and read from a
/// DETECT.json with the flight they were detected on), lines, diagnosis,
/// plan, vector sensor, channels, saved model and aircraft.
fn flight_job(args: &CompensateArgs, pipeline: &Pipeline) -> anyhow::Result<FlightJob> {
    let mut windows = args
        .windows
        .iter()
        .map(|w| CalibrationWindow::parse(w))
        .collect::<Result<Vec<_>, _>>()?;
    let mut windows_detected_on = None;
    if let Some(file) = &args.windows_file {
        let detected = magcomp::calibration::windows::read_detect_file(file, pipeline.settings.detect.window_margin_s)?;
        windows.extend(detected.windows);
        windows_detected_on = detected.flight.map(|identity| (file.clone(), identity));
    }
    Ok(FlightJob {
        diagnosis: args.diagnosis.clone(),
        force_diagnosis: args.force,
        plan: args.plan.clone(),
        vector: args.vector.clone(),
        channels: args.channels.clone(),
        windows,
        lines: args
            .lines
            .as_deref()
            .map(magcomp::calibration::windows::parse_lines)
            .transpose()?
            .unwrap_or_default(),
        windows_detected_on,
        model: args.apply.clone(),
        aircraft: args.aircraft.clone(),
        ..FlightJob::new(args.flight.clone())
    })
}

/// Fits and compensates one flight and writes its outputs.
pub fn compensate(args: CompensateArgs, verbose: bool) -> anyhow::Result<super::Outcome> {
    let mut pipeline = Pipeline::load_or_default(args.config.as_deref())?;
    apply_flags(&mut pipeline.settings, &args)?;
    let job = flight_job(&args, &pipeline)?;
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
    let bar = FlightBar::alone(&args.flight, "starting");
    let result = process_flight_listing(&job, &pipeline.settings, &outputs, &bar);
    drop(bar);
    let (result, written) = result?;
    print!("{}", summary(&result, pipeline.settings.fom_limit_nt, verbose));
    for path in written {
        println!("  wrote {}", path.display());
    }
    let failed = (result.channels.iter()).any(|c| c.verdict == magcomp::quality::verdict::Verdict::Fail);
    Ok(super::Outcome::of(failed, pipeline.settings.exit_zero_on_fail))
}
