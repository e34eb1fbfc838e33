//! pipeline.toml: the file as written, and the validated settings it
//! becomes.
//!
//! Two layers, as ripgrep's low- and high-level arguments. The raw structs
//! (here and in `sections`) mirror the file and reject unknown fields, so
//! a typo is an error that names the field; a field left out takes the
//! validated section's default. Validation (`Pipeline::validate`, through
//! each section's [`TryFrom`]) checks values and combinations, resolves
//! paths relative to the file, and reads nothing from disk; [`Pipeline::load`]
//! then reads the DETECT.json files flights name as windows. The validated
//! [`Settings`] hand each stage its own options (reading, detection, the
//! fit, the checks, the diagnosis).
//!
//! ```toml
//! [columns]            # SGL names by default; map your own here
//! time = "tt"
//!
//! [alignment]          # multi-rate inputs (MCAP)
//! time_base = "mag_1_uc"   # default: the first scalar magnetometer
//! gap_tolerance_s = 0.5    # default: 2.5 of each channel's own interval
//!
//! [[topic]]            # ROS 2 MagneticField topics (rosbag2 MCAP)
//! topic = "/imu/mag"
//! vector = "flux_a"    # or: scalar = "mag_1_uc" for its magnitude
//!
//! [filter]
//! band = "bandpass"    # bandpass | lowpass | highpass | none
//! low_hz = 0.1
//! high_hz = 0.9
//! poles = 4
//! trim_samples = 20
//! edge_padding = "scipy"   # scipy | dsp_jl | none
//! field_magnitude = "measured"  # measured (MagNav.jl's) | run_mean
//!
//! [fit]
//! terms = ["permanent", "induced", "eddy"]   # TL's 18 less the isotropic
//!                      # two; induced_6 and eddy_9 keep them (MagNav.jl)
//! bt_scale_nt = 50000.0
//! lambda = "press"     # or a number to fix it
//! criterion = "blocked_press"  # blocked_press (leave one window out) | press
//! level = "absolute"   # absolute | calibration_mean
//!
//! [vector]
//! enabled = true       # every fluxgate's vector, with INS attitude and a box
//! tolles_lawson = true # and its eddy-current and in-band induced terms
//!
//! [site]               # where the survey was flown, for files without a
//! latitude = 49.3      # position: IGRF-14 there fixes the field's sign
//! longitude = -123.1   # and checks the vector fit's direction
//! height_m = 500.0     # optional, 0 by default
//! date = "2026-06-15"  # optional; the flight's own date comes first
//!
//! [sensor_positions]   # body axes (forward, right, down), m; without
//! mag_4_uc = [0.0, -7.5, 0.0]   # [[gradient]], every pair is a gradient
//! mag_5_uc = [0.0, 7.5, 0.0]
//!
//! [[gradient]]         # grad_4_5_c = (mag_4_uc − mag_5_uc)/d, nT/m
//! channels = ["mag_4_uc", "mag_5_uc"]
//! separation_m = 15.0  # or from [sensor_positions]
//! method = "auto"      # auto (held out by heading) | direct | difference
//!
//! [output]
//! directory = "out"
//!
//! [[flight]]
//! input = "sample_flights/box_and_lines.csv"
//! windows_file = "sample_flights/box_and_lines.windows.json"
//! aircraft = "C-GMAG"  # optional: the summary follows its coefficients
//! calibration = true    # optional: its model compensates the aircraft's
//!                       # other flights (`calibrations`)
//!
//! [campaign]           # more flights: see `campaign`
//! inputs = ["flights/*.csv"]
//! manifest = "flights.csv"
//! ```

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::calibration::detect::DetectOptions;
use crate::calibration::fluxgate::VectorCalibrationOptions;
use crate::calibration::windows::{read_detect_file, CalibrationWindow};
use crate::compensate::gradient::{GradientMethod, GradientPair, LEAST_SEPARATION_M};
use crate::compensate::LevelConvention;
use crate::diagnose::DiagnoseOptions;
use crate::error::{Error, Result};
use crate::formats::align::AlignmentOptions;
use crate::formats::{ColumnNames, IngestOptions};
use crate::model::terms::{EddyTerms, InducedTerms, TermSet};
use crate::model::{FilterSettings, FitOptions};
use crate::numerics::estimators::Solver;
use crate::numerics::filter::{EdgePadding, FilterBand};
use crate::numerics::solve::{Criterion, LambdaChoice, SolveOptions};
use crate::quality::transfer::TransferOptions;
use crate::vector::VectorOptions;

mod calibrations;
mod campaign;
mod keys;
mod sections;

pub use keys::{accepted_keys, MAP_TABLES};

use sections::{
    RawAlignment, RawColumns, RawDetect, RawDiagnose, RawSite, RawTopic, RawTransfer, RawVector, RawVectorCalibration,
};

/// `[filter]` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RawFilter {
    /// `bandpass`, `lowpass`, `highpass` or `none`.
    pub band: String,
    /// Lower corner, Hz.
    pub low_hz: f64,
    /// Upper corner, Hz.
    pub high_hz: f64,
    /// Butterworth poles.
    pub poles: usize,
    /// Samples trimmed at each end of every filtered run.
    pub trim_samples: usize,
    /// Edge extension convention.
    pub edge_padding: EdgePadding,
    /// The field strength the fit's design is built with.
    pub field_magnitude: crate::model::FitMagnitude,
}

impl Default for RawFilter {
    fn default() -> Self {
        RawFilter {
            band: "bandpass".into(),
            low_hz: 0.1,
            high_hz: 0.9,
            poles: 4,
            trim_samples: 20,
            edge_padding: EdgePadding::Scipy,
            field_magnitude: crate::model::FitMagnitude::Measured,
        }
    }
}

/// A λ as written: `"press"` or a number.
#[derive(Debug, Clone, Deserialize)]
#[serde(untagged)]
pub(crate) enum RawLambda {
    /// A fixed value.
    Fixed(f64),
    /// `"press"`: select on the grid.
    Named(String),
}

/// `[fit]` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RawFit {
    /// Term groups: `permanent`, `induced` (`induced_6`/`_5`/`_3`), `eddy`
    /// (`eddy_9`/`_8`/`_3`), `field_derivative`, `bias`.
    pub terms: Vec<String>,
    /// Scale of induced and eddy terms, nT.
    pub bt_scale_nt: f64,
    /// `"press"` or a fixed λ.
    pub lambda: RawLambda,
    /// Selection statistic.
    pub criterion: Criterion,
    /// λ grid size.
    pub grid_points: usize,
    /// Condition number above which TSVD replaces ridge.
    pub tsvd_condition_limit: f64,
    /// DC level convention of the compensated output.
    pub level: LevelConvention,
    /// Estimator: `ridge`, `tsvd`, `ls`, `tls`, `ttls`, `damped_tsvd` or
    /// `auto`.
    pub solver: String,
}

impl Default for RawFit {
    fn default() -> Self {
        RawFit {
            terms: ["permanent", "induced", "eddy"].map(String::from).to_vec(),
            bt_scale_nt: 50_000.0,
            lambda: RawLambda::Named("press".into()),
            criterion: Criterion::BlockedPress,
            grid_points: 50,
            tsvd_condition_limit: 1e10,
            level: LevelConvention::Absolute,
            solver: Solver::Ridge.name().into(),
        }
    }
}

/// Decimal places of the added nT columns by default: 0.001 nT, below any
/// magnetometer's noise, where the shortest round-trip text of a double
/// wrote 17 digits and doubled a flight's CSV.
pub const DEFAULT_DECIMALS: u32 = 3;

/// The most decimal places `[output] decimals` takes: a double holds
/// about 15 significant digits, and a field of 50,000 nT uses five.
pub const MOST_DECIMALS: u32 = 10;

/// `[output]` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RawOutput {
    /// Folder for outputs, relative to pipeline.toml.
    pub directory: PathBuf,
    /// Decimal places of the added nT columns (gradients, nT/m, get three
    /// more); the input's columns are copied as they are.
    pub decimals: u32,
    /// Write `mag_<n>_dc`: compensated, the base station's variation
    /// removed.
    pub dc: bool,
    /// Write `mag_<n>_igrf`: compensated, the base station's variation
    /// and IGRF-14 removed.
    pub igrf: bool,
}

impl Default for RawOutput {
    fn default() -> Self {
        RawOutput {
            directory: "out".into(),
            decimals: DEFAULT_DECIMALS,
            dc: false,
            igrf: false,
        }
    }
}

/// Days after which a saved model is applied with a warning, by default
/// (`[model] max_age_days`): an installation drifts (a battery moved, a
/// repair, a new instrument), and most survey contracts ask for a box at
/// least monthly.
pub const DEFAULT_MAX_AGE_DAYS: u32 = 30;

/// `[model]` as written: how a saved model is applied (`--apply`,
/// `[[flight]] model`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RawModel {
    /// A model calibrated more than this many days from the flight it is
    /// applied to is a warning.
    pub max_age_days: u32,
    /// The model's scalar channels under this flight's names: model
    /// channel → the flight's column.
    pub channels: std::collections::BTreeMap<String, String>,
}

impl Default for RawModel {
    fn default() -> Self {
        RawModel {
            max_age_days: DEFAULT_MAX_AGE_DAYS,
            channels: Default::default(),
        }
    }
}

/// One `[[flight]]` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawFlight {
    /// Flight log path, relative to pipeline.toml.
    pub input: PathBuf,
    /// Vector magnetometer prefix; default: the first found.
    #[serde(default)]
    pub vector: Option<String>,
    /// Scalar channels; default: every scalar channel.
    #[serde(default)]
    pub channels: Option<Vec<String>>,
    /// Calibration windows given inline.
    #[serde(default)]
    pub windows: Vec<CalibrationWindow>,
    /// A DETECT.json file whose manoeuvres are the calibration windows.
    #[serde(default)]
    pub windows_file: Option<PathBuf>,
    /// Calibration data by line number (the `line` column): the
    /// manoeuvres detected on these lines, or their whole spans.
    #[serde(default)]
    pub lines: Vec<f64>,
    /// A DIAGNOSIS.json whose models to fit and compensate with.
    #[serde(default)]
    pub diagnosis: Option<PathBuf>,
    /// The PLAN_REPORT.json of the plan the flight was flown to.
    #[serde(default)]
    pub plan: Option<PathBuf>,
    /// A MODEL.json saved from a calibration flight of this aircraft: the
    /// flight is compensated with it, nothing refitted.
    #[serde(default)]
    pub model: Option<PathBuf>,
    /// The day the flight was flown, `YYYY-MM-DD` (UTC), over what the file
    /// says (MCAP output's log times count from its midnight).
    #[serde(default)]
    pub date: Option<String>,
    /// The airframe (e.g. its registration), for following its calibration
    /// over a campaign.
    #[serde(default)]
    pub aircraft: Option<String>,
    /// This flight is its aircraft's calibration: fitted on its own box,
    /// its model compensates the aircraft's other flights
    /// ([`calibrations`]).
    #[serde(default)]
    pub calibration: bool,
}

/// `[quality]` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RawQuality {
    /// Transfer check of the calibration.
    pub transfer: RawTransfer,
    /// FOM limit the report judges against, nT.
    pub fom_limit_nt: f64,
    /// How far a channel's anomaly gain may depart from 1.
    pub anomaly_gain_tolerance: f64,
    /// Whether a run with a channel at FAIL exits 0 rather than 3.
    pub exit_zero_on_fail: bool,
}

impl Default for RawQuality {
    fn default() -> Self {
        RawQuality {
            transfer: RawTransfer::default(),
            fom_limit_nt: 1.5,
            anomaly_gain_tolerance: crate::model::ANOMALY_GAIN_TOLERANCE,
            exit_zero_on_fail: false,
        }
    }
}

/// pipeline.toml as written.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RawPipeline {
    /// Column-name mapping.
    pub columns: RawColumns,
    /// Multi-rate alignment (MCAP inputs).
    pub alignment: RawAlignment,
    /// What ROS 2 topics become.
    #[serde(rename = "topic")]
    pub topics: Vec<RawTopic>,
    /// Band-pass settings.
    pub filter: RawFilter,
    /// Fit settings.
    pub fit: RawFit,
    /// Output settings.
    pub output: RawOutput,
    /// Applying saved models.
    pub model: RawModel,
    /// Manoeuvre detection thresholds.
    pub detect: RawDetect,
    /// Quality checks.
    pub quality: RawQuality,
    /// Physics diagnosis.
    pub diagnose: RawDiagnose,
    /// Fluxgate calibration before the fit.
    pub vector_calibration: RawVectorCalibration,
    /// Vector compensation.
    pub vector: RawVector,
    /// Where the survey was flown (flights without a position).
    pub site: Option<RawSite>,
    /// Gradients to compensate.
    #[serde(rename = "gradient")]
    pub gradients: Vec<RawGradient>,
    /// Scalar sensors' positions in body axes (forward, right, down), m.
    #[serde(deserialize_with = "positions")]
    pub sensor_positions: std::collections::BTreeMap<String, [f64; 3]>,
    /// Flights to process.
    #[serde(rename = "flight")]
    pub flights: Vec<RawFlight>,
    /// More flights, by glob pattern or manifest.
    pub campaign: campaign::RawCampaign,
}

/// One flight to process, validated.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightJob {
    /// Flight log path.
    pub input: PathBuf,
    /// Vector magnetometer prefix, if chosen.
    pub vector: Option<String>,
    /// Scalar channels, if chosen.
    pub channels: Option<Vec<String>>,
    /// Calibration windows.
    pub windows: Vec<CalibrationWindow>,
    /// Calibration lines: the manoeuvres detected on them (or, when none
    /// is, their whole spans) are the calibration windows.
    pub lines: Vec<f64>,
    /// The DETECT.json that gave windows, and the flight it was detected
    /// on: windows of another flight are a warning.
    pub windows_detected_on: Option<(PathBuf, crate::ingest::flight_identity::FlightIdentity)>,
    /// A DIAGNOSIS.json to accept: each channel it lists is fitted and
    /// compensated with the model it found.
    pub diagnosis: Option<PathBuf>,
    /// Apply `diagnosis` even when it was made on another flight (`--force`).
    pub force_diagnosis: bool,
    /// The PLAN_REPORT.json of the plan the flight was flown to: the
    /// compensation is set against its prediction
    /// ([`crate::quality::against_plan`]).
    pub plan: Option<PathBuf>,
    /// A MODEL.json saved from another flight to compensate this one with,
    /// nothing refitted ([`crate::pipeline::apply`]).
    pub model: Option<PathBuf>,
    /// The day the flight was flown, over what the file says.
    pub date: Option<crate::ingest::flight_date::FlightDate>,
    /// The airframe, when the campaign names it.
    pub aircraft: Option<String>,
    /// The flight is its aircraft's calibration: its model compensates
    /// the aircraft's flights that name none of their own (`calibrations`).
    pub calibration: bool,
    /// Why `model` is this flight's, when the campaign gave it (a note for
    /// its quality JSON and report): [`crate::messages::Note::AssignedModel`].
    pub assigned_model: Option<crate::messages::Note>,
    /// Why a campaign with calibration flights gave this flight none of
    /// their models, with what it has and the closest aircraft name (said
    /// when the flight then has no box of its own to fit on).
    pub no_calibration_because: Option<String>,
    /// What the flight's outputs are named after: the input's file stem,
    /// or, when two flights of a campaign share a stem, their path.
    pub output_name: String,
}

impl FlightJob {
    /// A flight with every choice left to the pipeline: detected windows,
    /// every scalar channel, the first fluxgate, no saved diagnosis.
    pub fn new(input: impl Into<PathBuf>) -> Self {
        let input = input.into();
        FlightJob {
            output_name: file_stem(&input),
            input,
            vector: None,
            channels: None,
            windows: Vec::new(),
            lines: Vec::new(),
            windows_detected_on: None,
            diagnosis: None,
            force_diagnosis: false,
            plan: None,
            model: None,
            date: None,
            aircraft: None,
            calibration: false,
            assigned_model: None,
            no_calibration_because: None,
        }
    }

    /// The model JSON this flight's run writes in `directory`.
    pub fn model_json_in(&self, directory: &Path) -> PathBuf {
        model_json_path(directory, &self.output_name)
    }
}

/// The model JSON of the flight whose outputs are named `stem`, in
/// `directory`: `<stem>_model.json`.
pub fn model_json_path(directory: &Path, stem: &str) -> PathBuf {
    directory.join(format!("{stem}_model.json"))
}

/// The file name of `path` without its extension (`flight` when it has
/// none).
fn file_stem(path: &Path) -> String {
    path.file_stem()
        .map_or("flight".into(), |s| s.to_string_lossy().into_owned())
}

/// The output name of the flight file `input` with its folders under
/// `base`: the folders and the `stem` joined by `_`.
fn name_by_path(input: &Path, stem: &String, base: &Path) -> String {
    let relative = input.strip_prefix(base).unwrap_or(input);
    let folders: Vec<String> = relative
        .parent()
        .into_iter()
        .flat_map(|p| p.components())
        .filter_map(|c| match c {
            std::path::Component::Normal(part) => Some(part.to_string_lossy().into_owned()),
            _ => None,
        })
        .collect();
    folders
        .iter()
        .chain(std::iter::once(stem))
        .cloned()
        .collect::<Vec<_>>()
        .join("_")
}

/// Gives every flight a distinct output name: its file stem, unless
/// another flight shares it; then its path under `base` without the
/// extension, folders joined by `_` (`2020/06/flight.csv` →
/// `2020_06_flight`); and if that is shared too, with the first eight hex
/// digits of the path's SHA-256 after it. Depends only on the list, so
/// every shard of a campaign names every flight alike.
fn name_outputs(flights: &mut [FlightJob], base: &Path) {
    // Counted once (a campaign can name 10,000 flights, and every shard
    // names them all).
    let tally = |names: &[String]| {
        let mut counts: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
        for name in names {
            *counts.entry(name.clone()).or_default() += 1;
        }
        counts
    };
    let stems: Vec<String> = flights.iter().map(|f| file_stem(&f.input)).collect();
    let by_path: Vec<String> = flights
        .iter()
        .zip(&stems)
        .map(|(flight, stem)| name_by_path(&flight.input, stem, base))
        .collect();
    let (stem_counts, path_counts) = (tally(&stems), tally(&by_path));
    for (index, flight) in flights.iter_mut().enumerate() {
        flight.output_name = match (stem_counts[&stems[index]], path_counts[&by_path[index]]) {
            (1, _) => stems[index].clone(),
            (_, 1) => by_path[index].clone(),
            _ => {
                use sha2::Digest;
                let digest = sha2::Sha256::digest(flight.input.to_string_lossy().as_bytes());
                let hex: String = digest[..4].iter().map(|b| format!("{b:02x}")).collect();
                format!("{}_{hex}", by_path[index])
            }
        };
    }
}

/// A validated pipeline: the settings every flight's stages take, where
/// the outputs go, and the flights.
#[derive(Debug, Clone, PartialEq)]
pub struct Pipeline {
    /// What each stage is handed.
    pub settings: Settings,
    /// Output folder.
    pub output_directory: PathBuf,
    /// Flights to process.
    pub flights: Vec<FlightJob>,
    /// What reading the campaign left out, and why, for the user.
    pub notes: Vec<crate::messages::Setup>,
}

/// The validated settings of a run, shared by every flight: each stage
/// takes its own part (reading, detection, the fit, the checks, the
/// diagnosis).
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// Reading options.
    pub ingest: IngestOptions,
    /// Tolles-Lawson terms of every model (`[fit] terms`).
    pub terms: TermSet,
    /// How models are fitted: band-pass and solve.
    pub fit: FitOptions,
    /// DC level convention.
    pub level: LevelConvention,
    /// Manoeuvre detection, used when a flight gives no windows.
    pub detect: DetectOptions,
    /// Transfer check of the calibration.
    pub transfer: TransferOptions,
    /// FOM limit the report judges against, nT.
    pub fom_limit_nt: f64,
    /// How far a channel's anomaly gain may depart from 1 before its
    /// verdict is FAIL and no finding that departs so is applied
    /// (`[quality] anomaly_gain_tolerance`).
    pub anomaly_gain_tolerance: f64,
    /// A run with a channel at FAIL exits 0 rather than 3
    /// (`[quality] exit_zero_on_fail`, `--exit-zero-on-fail`).
    pub exit_zero_on_fail: bool,
    /// Physics diagnosis, and whether the fit takes its models.
    pub diagnose: DiagnoseOptions,
    /// Fluxgate calibration before the fit.
    pub vector_calibration: VectorCalibrationOptions,
    /// Vector compensation (the twelve-constant model).
    pub vector: VectorOptions,
    /// Gradients to compensate (`[[gradient]]`, or every pair of
    /// `[sensor_positions]`).
    pub gradients: Vec<GradientPair>,
    /// Decimal places of the added nT columns (`[output] decimals`).
    pub output_decimals: u32,
    /// The reduced columns to add (`[output] dc`, `[output] igrf`).
    pub reduced: crate::compensate::reduce::ReducedColumns,
    /// Days after which an applied model is a warning (`[model]
    /// max_age_days`).
    pub model_max_age_days: u32,
    /// A saved model's scalar channels under the flight's own names
    /// (`[model] channels`: model channel → the flight's column).
    pub model_channels: std::collections::BTreeMap<String, String>,
}

impl Default for Settings {
    fn default() -> Self {
        Pipeline::default().settings
    }
}

impl Default for Pipeline {
    fn default() -> Self {
        let (pipeline, _) =
            Pipeline::validate(RawPipeline::default(), Path::new("."), "defaults").expect("the defaults are valid");
        pipeline
    }
}

/// A `windows_file` of the flight at `flight`, to read once the file is
/// validated.
struct WindowsFile {
    flight: usize,
    path: PathBuf,
}

impl Pipeline {
    /// Reads and validates a pipeline.toml, then reads the DETECT.json
    /// files its flights name as windows.
    pub fn load(path: &Path) -> Result<Self> {
        let text = crate::ingest::read_text(path).map_err(|e| Error::io(path, "reading", e))?;
        let source_name = path.display().to_string();
        let raw: RawPipeline = toml::from_str(&text).map_err(|e| Error::Config {
            source_name: source_name.clone(),
            message: e.to_string().trim().to_string(),
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        let mut raw = raw;
        let (flights, notes) =
            campaign::campaign_flights(&raw.campaign, &raw.flights, (base, &raw.output.directory), &source_name)?;
        raw.flights = flights;
        let (mut pipeline, windows_files) = Pipeline::validate(raw, base, &source_name)?;
        pipeline.notes.splice(0..0, notes);
        let margin_s = pipeline.settings.detect.window_margin_s;
        for file in windows_files {
            let detected = read_detect_file(&file.path, margin_s)?;
            let flight = &mut pipeline.flights[file.flight];
            flight.windows.extend(detected.windows);
            flight.windows_detected_on = detected.flight.map(|identity| (file.path, identity));
        }
        Ok(pipeline)
    }

    /// The settings of `path` when given, otherwise the defaults (a
    /// command run without `--config`).
    pub fn load_or_default(path: Option<&Path>) -> Result<Self> {
        match path {
            Some(path) => Pipeline::load(path),
            None => Ok(Pipeline::default()),
        }
    }

    /// Validates `raw`, resolving relative paths against `base`; reads
    /// nothing. Returns the windows files still to read.
    fn validate(raw: RawPipeline, base: &Path, source_name: &str) -> Result<(Self, Vec<WindowsFile>)> {
        let bad = |message: String| Error::Config {
            source_name: source_name.into(),
            message,
        };
        let terms = parse_terms(&raw.fit.terms, raw.fit.bt_scale_nt).map_err(bad)?;
        let fit = FitOptions {
            filter: filter_settings(&raw.filter).map_err(bad)?,
            solve: solve_options(&raw.fit).map_err(bad)?,
            solver: Solver::from_name(&raw.fit.solver).ok_or_else(|| {
                bad(format!(
                    "[fit] solver = \"{}\": write one of {}",
                    raw.fit.solver,
                    Solver::ALL.map(|s| format!("\"{}\"", s.name())).join(", ")
                ))
            })?,
        };
        check_limits(&raw).map_err(bad)?;
        let settings = Settings {
            output_decimals: raw.output.decimals,
            reduced: crate::compensate::reduce::ReducedColumns {
                dc: raw.output.dc,
                igrf: raw.output.igrf,
            },
            ingest: IngestOptions {
                columns: ColumnNames::try_from(raw.columns).map_err(bad)?,
                alignment: AlignmentOptions::try_from(raw.alignment).map_err(bad)?,
                topics: sections::topics(raw.topics).map_err(bad)?,
                date: None,
            },
            terms,
            fit,
            level: raw.fit.level,
            detect: DetectOptions::try_from(raw.detect).map_err(bad)?,
            transfer: TransferOptions::try_from(raw.quality.transfer).map_err(bad)?,
            fom_limit_nt: raw.quality.fom_limit_nt,
            anomaly_gain_tolerance: raw.quality.anomaly_gain_tolerance,
            exit_zero_on_fail: raw.quality.exit_zero_on_fail,
            diagnose: DiagnoseOptions::try_from(raw.diagnose).map_err(bad)?,
            vector_calibration: VectorCalibrationOptions::try_from(raw.vector_calibration).map_err(bad)?,
            vector: VectorOptions {
                site: raw.site.map(crate::vector::Site::try_from).transpose().map_err(bad)?,
                ..VectorOptions::from(raw.vector)
            },
            gradients: gradient_pairs(&raw.gradients, &raw.sensor_positions).map_err(bad)?,
            model_max_age_days: raw.model.max_age_days,
            model_channels: model_channels(raw.model.channels).map_err(bad)?,
        };
        let (mut flights, windows_files) = flight_jobs(raw.flights, base, source_name)?;
        name_outputs(&mut flights, base);
        let output_directory = base.join(raw.output.directory);
        let notes = calibrations::assign_calibrations(&mut flights, &output_directory, source_name)?;
        let pipeline = Pipeline {
            settings,
            output_directory,
            flights,
            notes,
        };
        Ok((pipeline, windows_files))
    }
}

/// `[quality] fom_limit_nt` positive, `[quality] anomaly_gain_tolerance`
/// between 0 and 1, and `[output] decimals` within
/// [`MOST_DECIMALS`].
fn check_limits(raw: &RawPipeline) -> std::result::Result<(), String> {
    if !(raw.quality.fom_limit_nt.is_finite() && raw.quality.fom_limit_nt > 0.0) {
        return Err(format!(
            "[quality] fom_limit_nt = {}: give a positive number of nT (1.5 is usual)",
            raw.quality.fom_limit_nt
        ));
    }
    let tolerance = raw.quality.anomaly_gain_tolerance;
    if !(tolerance.is_finite() && tolerance > 0.0 && tolerance < 1.0) {
        return Err(format!(
            "[quality] anomaly_gain_tolerance = {tolerance}: give how far the gain on a crustal anomaly may depart from 1, between 0 and 1 (0.02 is the default)"
        ));
    }
    if raw.output.decimals > MOST_DECIMALS {
        return Err(format!(
            "[output] decimals = {}: give 0 to {MOST_DECIMALS} decimal places of nT (3, 0.001 nT, is the default)",
            raw.output.decimals
        ));
    }
    Ok(())
}

/// `[model] channels`, checked: every name given, and no column of the
/// flight given to two of the model's channels.
fn model_channels(
    channels: std::collections::BTreeMap<String, String>,
) -> std::result::Result<std::collections::BTreeMap<String, String>, String> {
    if let Some((model, _)) = channels
        .iter()
        .find(|(m, c)| m.trim().is_empty() || c.trim().is_empty())
    {
        return Err(format!(
            "[model] channels: {model:?} = ...: give each of the model's channels and the flight's column by name"
        ));
    }
    let mut seen: std::collections::BTreeMap<&str, &str> = std::collections::BTreeMap::new();
    for (model, column) in &channels {
        if let Some(first) = seen.insert(column, model) {
            return Err(format!(
                "[model] channels: '{first}' and '{model}' are both given the column '{column}'; give each of the model's channels its own column"
            ));
        }
    }
    Ok(channels)
}

/// `[[gradient]]` as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawGradient {
    /// The two scalar channels, a then b: the gradient is (a − b)/d.
    #[serde(deserialize_with = "two_channels")]
    pub channels: [String; 2],
    /// Their distance, m; else from `[sensor_positions]`.
    #[serde(default)]
    pub separation_m: Option<f64>,
    /// How to compensate it.
    #[serde(default)]
    pub method: GradientMethod,
}

/// `[sensor_positions]`: three numbers a sensor, refused with any other
/// count (a fourth would otherwise be dropped without a word).
fn positions<'de, D: serde::Deserializer<'de>>(
    deserializer: D,
) -> std::result::Result<std::collections::BTreeMap<String, [f64; 3]>, D::Error> {
    let given: std::collections::BTreeMap<String, Vec<f64>> = Deserialize::deserialize(deserializer)?;
    (given.into_iter())
        .map(|(name, values)| match <[f64; 3]>::try_from(values.as_slice()) {
            Ok(position) => Ok((name, position)),
            Err(_) => Err(serde::de::Error::custom(format!(
                "{name}: give three values in metres (forward, right, down), not {}",
                values.len()
            ))),
        })
        .collect()
}

/// `[[gradient]] channels`: two names, refused with any other count.
fn two_channels<'de, D: serde::Deserializer<'de>>(deserializer: D) -> std::result::Result<[String; 2], D::Error> {
    let names: Vec<String> = Deserialize::deserialize(deserializer)?;
    let count = names.len();
    <[String; 2]>::try_from(names).map_err(|_| {
        serde::de::Error::custom(format!(
            "give the two scalar channels of one gradient, not {count}; write one [[gradient]] a pair"
        ))
    })
}

/// The gradients to compensate: each `[[gradient]]`, its separation given
/// or from the two sensors' positions; without any, every pair of
/// `[sensor_positions]` (in name order) at least [`LEAST_SEPARATION_M`]
/// apart.
fn gradient_pairs(
    raw: &[RawGradient],
    positions: &std::collections::BTreeMap<String, [f64; 3]>,
) -> std::result::Result<Vec<GradientPair>, String> {
    if let Some((name, _)) = positions.iter().find(|(_, p)| p.iter().any(|v| !v.is_finite())) {
        return Err(format!(
            "[sensor_positions] {name}: give three finite numbers of metres (forward, right, down)"
        ));
    }
    let between = |a: &str, b: &str| {
        let (pa, pb) = (positions.get(a)?, positions.get(b)?);
        let offset = nalgebra::Vector3::from(*pa) - nalgebra::Vector3::from(*pb);
        Some((offset.norm(), offset))
    };
    let pair = |a: &str, b: &str, separation: Option<f64>, method| {
        let measured = between(a, b);
        let separation_m = match (separation, measured) {
            (Some(given), Some((from_positions, _))) if (given - from_positions).abs() > 0.01 => {
                return Err(format!(
                    "[[gradient]] {a}, {b}: separation_m = {given} but [sensor_positions] puts them {from_positions:.3} m apart"
                ))
            }
            (Some(given), _) => given,
            (None, Some((from_positions, _))) => from_positions,
            (None, None) => {
                return Err(format!(
                    "[[gradient]] {a}, {b}: give separation_m, or both sensors' positions in [sensor_positions]"
                ))
            }
        };
        if !(separation_m.is_finite() && separation_m >= LEAST_SEPARATION_M) {
            return Err(format!(
                "[[gradient]] {a}, {b}: the sensors are {separation_m} m apart; a gradient needs at least {LEAST_SEPARATION_M} m"
            ));
        }
        if a == b {
            return Err(format!("[[gradient]] {a}, {b}: name two different channels"));
        }
        Ok(GradientPair {
            a: a.into(),
            b: b.into(),
            separation_m,
            axis_body: measured
                .filter(|(d, _)| *d > 0.0)
                .map(|(d, offset)| std::array::from_fn(|k| offset[k] / d)),
            method,
        })
    };
    if !raw.is_empty() {
        return raw
            .iter()
            .map(|g| pair(&g.channels[0], &g.channels[1], g.separation_m, g.method))
            .collect();
    }
    let names: Vec<&String> = positions.keys().collect();
    let mut pairs = Vec::new();
    for (i, a) in names.iter().enumerate() {
        for b in &names[i + 1..] {
            if between(a, b).is_some_and(|(d, _)| d >= LEAST_SEPARATION_M) {
                pairs.push(pair(a, b, None, GradientMethod::Auto)?);
            }
        }
    }
    Ok(pairs)
}

/// The `[[flight]]`s' jobs, paths resolved against `base`, and the
/// windows files still to read; an error for a flight that gives its
/// calibration data two ways.
fn flight_jobs(
    raw_flights: Vec<RawFlight>,
    base: &Path,
    source_name: &str,
) -> Result<(Vec<FlightJob>, Vec<WindowsFile>)> {
    let mut windows_files = Vec::new();
    let mut flights = Vec::with_capacity(raw_flights.len());
    for (index, mut flight) in raw_flights.into_iter().enumerate() {
        // The calibration data given two ways: which one wins would be a guess.
        let twice = match (
            flight.windows_file.is_some(),
            flight.lines.is_empty(),
            flight.windows.is_empty(),
        ) {
            (true, false, _) => {
                Some("both lines and windows_file are given; give the calibration data one way, by lines or by windows")
            }
            (true, true, false) => Some(
                "both windows and windows_file are given; give the calibration windows one way, inline or in the file",
            ),
            _ => None,
        };
        if let Some(problem) = twice {
            return Err(Error::Config {
                source_name: source_name.into(),
                message: format!("[[flight]] input = {:?}: {problem}", flight.input),
            });
        }
        if let Some(file) = flight.windows_file.take() {
            windows_files.push(WindowsFile {
                flight: index,
                path: base.join(file),
            });
        }
        flights.push(flight_job(flight, base, source_name)?);
    }
    Ok((flights, windows_files))
}

/// What a `[[flight]]` gives that cannot go together, or a line number
/// that is none, in words.
fn flight_conflict(raw: &RawFlight) -> Option<String> {
    if let Some(line) = raw.lines.iter().find(|l| !(l.is_finite() && **l != 0.0)) {
        return Some(format!(
            "lines holds {line}, which is no line number; give the calibration lines as numbers, e.g. lines = [1002.20]"
        ));
    }
    let problem = match () {
        _ if raw.model.is_some() && raw.diagnosis.is_some() => "both model and diagnosis are given; a saved model carries its own findings: give the model alone, or the diagnosis alone to fit on this flight's calibration",
        _ if raw.model.is_some() && raw.plan.is_some() => "both model and plan are given; a plan is set against the calibration box the flight fits on, and a flight given a model fits nothing: set the plan against the model's calibration flight",
        _ if !raw.lines.is_empty() && (!raw.windows.is_empty() || raw.windows_file.is_some()) => "both lines and windows are given; give the calibration data one way, by lines or by windows",
        _ => return None,
    };
    Some(problem.to_string())
}

fn flight_job(raw: RawFlight, base: &Path, source_name: &str) -> Result<FlightJob> {
    raw.windows.iter().try_for_each(|w| w.validate(source_name))?;
    let date = raw
        .date
        .as_deref()
        .map(|text| {
            crate::ingest::flight_date::FlightDate::parse(text).ok_or_else(|| Error::Config {
                source_name: source_name.into(),
                message: format!(
                    "[[flight]] input = {:?}: date = {text:?} is not a day; write it as YYYY-MM-DD, e.g. \"2020-06-20\"",
                    raw.input
                ),
            })
        })
        .transpose()?;
    if let Some(problem) = flight_conflict(&raw) {
        return Err(Error::Config {
            source_name: source_name.into(),
            message: format!("[[flight]] input = {:?}: {problem}", raw.input),
        });
    }
    let windows = raw.windows;
    let input = base.join(raw.input);
    Ok(FlightJob {
        vector: raw.vector,
        channels: raw.channels,
        windows,
        lines: raw.lines,
        diagnosis: raw.diagnosis.map(|d| base.join(d)),
        plan: raw.plan.map(|p| base.join(p)),
        model: raw.model.map(|m| base.join(m)),
        date,
        aircraft: raw.aircraft,
        calibration: raw.calibration,
        ..FlightJob::new(input)
    })
}

/// Largest λ grid: ample for any selection, and a bound on the memory the
/// grid's curves take.
const MOST_GRID_POINTS: usize = 10_000;

/// Most samples trimmed at each end of a filtered run.
const MOST_TRIM_SAMPLES: usize = 100_000;

fn parse_terms(names: &[String], bt_scale_nt: f64) -> std::result::Result<TermSet, String> {
    if !(bt_scale_nt.is_finite() && bt_scale_nt > 0.0) {
        return Err(format!(
            "[fit] bt_scale_nt = {bt_scale_nt}: it must be a positive number of nT (50000 is usual)"
        ));
    }
    let mut set = TermSet {
        permanent: false,
        induced: InducedTerms::None,
        eddy: EddyTerms::None,
        field_derivative: false,
        bias: false,
        bt_scale_nt,
    };
    let mut given: Vec<(&str, &str)> = Vec::new();
    for name in names {
        let family = match name.as_str() {
            n if n.starts_with("induced") => "induced",
            n if n.starts_with("eddy") => "eddy",
            "fdm" => "field_derivative",
            n => n,
        };
        if let Some((earlier, _)) = given.iter().find(|(_, f)| *f == family) {
            return Err(format!(
                "[fit] terms lists '{earlier}' and '{name}': both are the {family} terms; give one"
            ));
        }
        given.push((name, family));
        match name.as_str() {
            "permanent" => set.permanent = true,
            "induced" | "induced_traceless" => set.induced = InducedTerms::Traceless,
            "induced_6" => set.induced = InducedTerms::Six,
            "induced_5" => set.induced = InducedTerms::Five,
            "induced_3" => set.induced = InducedTerms::Three,
            "eddy" | "eddy_traceless" => set.eddy = EddyTerms::Traceless,
            "eddy_9" => set.eddy = EddyTerms::Nine,
            "eddy_8" => set.eddy = EddyTerms::Eight,
            "eddy_3" => set.eddy = EddyTerms::Three,
            "field_derivative" | "fdm" => set.field_derivative = true,
            "bias" => set.bias = true,
            other => return Err(format!("[fit] terms: unknown term group '{other}'; use permanent, induced, induced_6, induced_5, induced_3, eddy, eddy_9, eddy_8, eddy_3, field_derivative or bias")),
        }
    }
    if set.is_empty() {
        return Err(
            "[fit] terms is empty: list at least one term group, e.g. [\"permanent\", \"induced\", \"eddy\"]".into(),
        );
    }
    Ok(set)
}

fn filter_settings(raw: &RawFilter) -> std::result::Result<FilterSettings, String> {
    let band = match raw.band.as_str() {
        "bandpass" => FilterBand::Bandpass {
            low_hz: raw.low_hz,
            high_hz: raw.high_hz,
        },
        "lowpass" => FilterBand::Lowpass { high_hz: raw.high_hz },
        "highpass" => FilterBand::Highpass { low_hz: raw.low_hz },
        "none" => FilterBand::None,
        other => {
            return Err(format!(
                "[filter] band = '{other}': use bandpass, lowpass, highpass or none"
            ))
        }
    };
    if !(1..=12).contains(&raw.poles) {
        return Err(format!("[filter] poles = {}: use 1 to 12 (4 is usual)", raw.poles));
    }
    let corners: &[(&str, f64)] = match band {
        FilterBand::Bandpass { .. } => &[("low_hz", raw.low_hz), ("high_hz", raw.high_hz)],
        FilterBand::Lowpass { .. } => &[("high_hz", raw.high_hz)],
        FilterBand::Highpass { .. } => &[("low_hz", raw.low_hz)],
        FilterBand::None => &[],
    };
    if let Some((name, value)) = corners.iter().find(|(_, v)| !(v.is_finite() && *v > 0.0)) {
        return Err(format!("[filter] {name} = {value}: give a positive frequency in Hz"));
    }
    if matches!(band, FilterBand::Bandpass { .. }) && raw.low_hz >= raw.high_hz {
        return Err(format!(
            "[filter] low_hz = {} is not below high_hz = {}: the pass band runs from low_hz up to high_hz",
            raw.low_hz, raw.high_hz
        ));
    }
    if raw.trim_samples > MOST_TRIM_SAMPLES {
        return Err(format!(
            "[filter] trim_samples = {}: give at most {MOST_TRIM_SAMPLES} (20 is usual)",
            raw.trim_samples
        ));
    }
    Ok(FilterSettings {
        band,
        poles: raw.poles,
        padding: raw.edge_padding,
        trim_samples: raw.trim_samples,
        magnitude: raw.field_magnitude,
    })
}

fn solve_options(raw: &RawFit) -> std::result::Result<SolveOptions, String> {
    let lambda = match &raw.lambda {
        RawLambda::Named(name) if name == "press" => LambdaChoice::Select,
        RawLambda::Named(other) => {
            return Err(format!(
                "[fit] lambda = '{other}': write \"press\" or a non-negative number"
            ))
        }
        RawLambda::Fixed(value) if value.is_finite() && *value >= 0.0 => LambdaChoice::Fixed(*value),
        RawLambda::Fixed(value) => return Err(format!("[fit] lambda = {value}: λ must be a non-negative number")),
    };
    if !(50..=MOST_GRID_POINTS).contains(&raw.grid_points) {
        return Err(format!(
            "[fit] grid_points = {}: use 50 to {MOST_GRID_POINTS} λ values (50 is usual)",
            raw.grid_points
        ));
    }
    if !(raw.tsvd_condition_limit.is_finite() && raw.tsvd_condition_limit > 1.0) {
        return Err(format!(
            "[fit] tsvd_condition_limit = {}: give a condition number above 1 (1e10 is usual)",
            raw.tsvd_condition_limit
        ));
    }
    Ok(SolveOptions {
        lambda,
        criterion: raw.criterion,
        grid_points: raw.grid_points,
        tsvd_condition_limit: raw.tsvd_condition_limit,
        ..SolveOptions::default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Pipeline> {
        let raw: RawPipeline = toml::from_str(text).map_err(|e| Error::Config {
            source_name: "test".into(),
            message: e.to_string(),
        })?;
        Ok(Pipeline::validate(raw, Path::new("/data"), "test")?.0)
    }

    #[test]
    fn a_model_s_channels_are_each_given_their_own_column() {
        let pipeline = parse("[model]\nchannels = { mag_1_uc = \"MAG1\", mag_2_uc = \"MAG2\" }\n").unwrap();
        assert_eq!(
            pipeline.settings.model_channels.get("mag_2_uc").map(String::as_str),
            Some("MAG2")
        );
        let text = parse("[model]\nchannels = { mag_1_uc = \"MAG1\", mag_2_uc = \"MAG1\" }\n")
            .unwrap_err()
            .to_string();
        assert!(
            text.contains("'mag_1_uc' and 'mag_2_uc' are both given the column 'MAG1'"),
            "{text}"
        );
        let text = parse("[model]\nchannels = { mag_1_uc = \" \" }\n")
            .unwrap_err()
            .to_string();
        assert!(
            text.contains("give each of the model's channels and the flight's column by name"),
            "{text}"
        );
    }

    /// A fourth coordinate or a third channel is refused, not dropped.
    #[test]
    fn a_position_or_a_gradient_given_too_many_values_is_refused() {
        let text = parse("[sensor_positions]\nmag_1_uc = [0.0, -7.5, 0.0, 1.0]\n")
            .unwrap_err()
            .to_string();
        assert!(
            text.contains("mag_1_uc: give three values in metres (forward, right, down), not 4"),
            "{text}"
        );
        let text = parse("[[gradient]]\nchannels = [\"mag_1_uc\", \"mag_2_uc\", \"mag_3_uc\"]\nseparation_m = 15.0\n")
            .unwrap_err()
            .to_string();
        assert!(
            text.contains("give the two scalar channels of one gradient, not 3"),
            "{text}"
        );
        let pairs = parse("[[gradient]]\nchannels = [\"mag_1_uc\", \"mag_2_uc\"]\nseparation_m = 15.0\n")
            .unwrap()
            .settings
            .gradients;
        assert_eq!(
            (pairs.len(), pairs[0].a.as_str(), pairs[0].b.as_str()),
            (1, "mag_1_uc", "mag_2_uc")
        );
    }

    #[test]
    fn gradients_take_their_separation_from_the_file_or_the_sensor_positions() {
        let pairs = parse(
            "[sensor_positions]\nmag_4_uc = [0.0, -7.5, 0.0]\nmag_5_uc = [0.0, 7.5, 0.0]\nmag_1_uc = [-9.0, 0.0, 0.0]\n",
        )
        .unwrap()
        .settings
        .gradients;
        // Without [[gradient]], every pair of positioned sensors, in name
        // order.
        let names: Vec<(&str, &str)> = pairs.iter().map(|p| (p.a.as_str(), p.b.as_str())).collect();
        assert_eq!(
            names,
            [
                ("mag_1_uc", "mag_4_uc"),
                ("mag_1_uc", "mag_5_uc"),
                ("mag_4_uc", "mag_5_uc")
            ]
        );
        let wings = &pairs[2];
        assert!((wings.separation_m - 15.0).abs() < 1e-12);
        assert_eq!(wings.axis_body, Some([0.0, -1.0, 0.0]));
        assert!((pairs[0].separation_m - (81.0f64 + 56.25).sqrt()).abs() < 1e-12);
        assert_eq!(wings.column(), "grad_4_5_c");

        // [[gradient]] chooses; its separation, given, must agree with the
        // positions.
        let chosen = parse(
            "[sensor_positions]\nmag_4_uc = [0.0, -7.5, 0.0]\nmag_5_uc = [0.0, 7.5, 0.0]\n[[gradient]]\nchannels = [\"mag_5_uc\", \"mag_4_uc\"]\nmethod = \"direct\"\n",
        )
        .unwrap()
        .settings
        .gradients;
        assert_eq!(chosen.len(), 1);
        assert_eq!(
            (chosen[0].a.as_str(), chosen[0].method),
            ("mag_5_uc", GradientMethod::Direct)
        );
        let given = parse("[[gradient]]\nchannels = [\"mag_4_uc\", \"mag_5_uc\"]\nseparation_m = 2.5\n").unwrap();
        assert_eq!(given.settings.gradients[0].separation_m, 2.5);
        assert_eq!(given.settings.gradients[0].axis_body, None);
        for (text, says) in [
            ("[[gradient]]\nchannels = [\"mag_4_uc\", \"mag_5_uc\"]\n", "give separation_m"),
            (
                "[sensor_positions]\nmag_4_uc = [0.0, -7.5, 0.0]\nmag_5_uc = [0.0, 7.5, 0.0]\n[[gradient]]\nchannels = [\"mag_4_uc\", \"mag_5_uc\"]\nseparation_m = 14.0\n",
                "15.000 m apart",
            ),
            ("[[gradient]]\nchannels = [\"mag_4_uc\", \"mag_5_uc\"]\nseparation_m = 0.0\n", "at least 0.1 m"),
            ("[[gradient]]\nchannels = [\"mag_4_uc\", \"mag_4_uc\"]\nseparation_m = 1.0\n", "two different"),
            ("[sensor_positions]\nmag_4_uc = [0.0, nan, 0.0]\n", "finite"),
        ] {
            let error = parse(text).unwrap_err().to_string();
            assert!(error.contains(says), "{text}: {error}");
        }
    }

    #[test]
    fn flights_sharing_a_stem_are_named_by_their_folders() {
        let base = Path::new("/campaign");
        let mut flights: Vec<FlightJob> = [
            "/campaign/2020/06/flight.csv",
            "/campaign/2020/07/flight.csv",
            "/campaign/other.mcap",
            "/campaign/2020_06/flight.csv",
        ]
        .into_iter()
        .map(FlightJob::new)
        .collect();
        name_outputs(&mut flights, base);
        let names: Vec<&str> = flights.iter().map(|f| f.output_name.as_str()).collect();
        assert_eq!(names[1], "2020_07_flight");
        assert_eq!(names[2], "other");
        // Two paths that join alike take a hash of their path as well.
        assert!(names[0].starts_with("2020_06_flight_") && names[3].starts_with("2020_06_flight_"));
        assert_ne!(names[0], names[3]);
        assert_eq!(names[0].len(), "2020_06_flight_".len() + 8);
    }

    #[test]
    fn a_flight_date_is_a_real_day() {
        let pipeline = parse("[[flight]]\ninput = \"f.mcap\"\ndate = \"2020-06-20\"\n").unwrap();
        assert_eq!(
            pipeline.flights[0].date.map(|d| d.to_string()).as_deref(),
            Some("2020-06-20")
        );
        let error = parse("[[flight]]\ninput = \"f.mcap\"\ndate = \"2020-02-30\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("\"2020-02-30\" is not a day") && error.contains("YYYY-MM-DD"),
            "{error}"
        );
    }

    #[test]
    fn the_solver_is_named_or_refused_with_the_names() {
        assert_eq!(parse("").unwrap().settings.fit.solver, Solver::Ridge);
        for solver in Solver::ALL {
            let text = format!("[fit]\nsolver = \"{}\"\n", solver.name());
            assert_eq!(parse(&text).unwrap().settings.fit.solver, solver);
        }
        let error = parse("[fit]\nsolver = \"svd\"\n").unwrap_err().to_string();
        assert!(
            error.contains("\"svd\"") && error.contains("\"damped_tsvd\"") && error.contains("\"auto\""),
            "{error}"
        );
    }

    #[test]
    fn windows_beside_a_windows_file_are_refused() {
        let text = "[[flight]]\ninput = \"f.csv\"\nwindows_file = \"f.windows.json\"\n\
                    windows = [{t_start = 1.0, t_end = 9.0, kind = \"roll\", heading_deg = 90.0}]\n";
        let message = parse(text).unwrap_err().to_string();
        assert!(message.contains("both windows and windows_file"), "{message}");
    }

    #[test]
    fn a_column_whose_name_gives_it_another_role_is_refused() {
        let message = parse("[columns]\npitch = \"mag_1_uc\"\n").unwrap_err().to_string();
        assert!(
            message.contains("pitch = \"mag_1_uc\"") && message.contains("scalar magnetometer by its name"),
            "{message}"
        );
        let message = parse("[columns]\nline = \"flux_b_x\"\n").unwrap_err().to_string();
        assert!(message.contains("vector magnetometer 'flux_b'"), "{message}");
        // Listing the scalars frees the name.
        let settings = parse("[columns]\nscalar = [\"mag_2_uc\"]\npitch = \"mag_1_uc\"\n").unwrap();
        assert_eq!(settings.settings.ingest.columns.pitch, "mag_1_uc");
    }

    #[test]
    fn a_typo_names_the_field() {
        let text = parse("[filter]\nlow_hzz = 0.2\n").unwrap_err().to_string();
        assert!(text.contains("low_hzz"), "{text}");
    }

    #[test]
    fn defaults_are_tolles_lawson_less_the_isotropic_terms() {
        let pipeline = parse("").unwrap();
        assert_eq!(pipeline.settings.terms, TermSet::traceless());
        assert_eq!(pipeline.settings.terms.len(), 16);
        assert_eq!(
            pipeline.settings.fit.filter.magnitude,
            crate::model::FitMagnitude::Measured
        );
        let text =
            "[fit]\nterms = [\"permanent\", \"induced_6\", \"eddy_9\"]\n[filter]\nfield_magnitude = \"run_mean\"\n";
        let all = parse(text).unwrap().settings;
        assert_eq!(all.terms, TermSet::magnav());
        assert_eq!(all.terms.len(), 18);
        assert_eq!(all.fit.filter.magnitude, crate::model::FitMagnitude::RunMean);
        assert_eq!(pipeline.settings.fit.filter, FilterSettings::default());
        assert_eq!(pipeline.settings.fit.solve.lambda, LambdaChoice::Select);
    }

    #[test]
    fn fixed_lambda_windows_and_paths() {
        let text = "[fit]\nlambda = 0.001\nterms = [\"permanent\", \"induced_5\", \"eddy_8\"]\n\
                    [[flight]]\ninput = \"f.csv\"\nwindows = [{t_start = 1.0, t_end = 9.0, kind = \"roll\", heading_deg = 90.0}]\n";
        let pipeline = parse(text).unwrap();
        assert_eq!(pipeline.settings.fit.solve.lambda, LambdaChoice::Fixed(0.001));
        assert_eq!(pipeline.settings.terms.len(), 16);
        assert_eq!(pipeline.flights[0].input, Path::new("/data/f.csv"));
        assert_eq!(pipeline.flights[0].windows[0].display_label(), "roll, heading 90");
    }

    #[test]
    fn nonsense_values_are_rejected() {
        assert!(parse("[fit]\nlambda = \"gcv\"\n").is_err());
        assert!(parse("[fit]\nlambda = -1.0\n").is_err());
        assert!(parse("[fit]\nterms = [\"permanant\"]\n").is_err());
        assert!(parse("[filter]\nband = \"bandstop\"\n").is_err());
        assert!(parse("[fit]\ngrid_points = 10\n").is_err());
        for bad in [
            "[fit]\ngrid_points = 100000000\n",
            "[fit]\ntsvd_condition_limit = 0.5\n",
            "[filter]\nlow_hz = 0.9\nhigh_hz = 0.1\n",
            "[filter]\nhigh_hz = -1.0\n",
            "[filter]\ntrim_samples = 100000000\n",
            "[diagnose]\nmin_improvement = 1.5\n",
            "[diagnose]\nmax_lag_s = 1e9\n",
            "[diagnose]\nmax_findings = 0\n",
            "[vector_calibration]\nmax_iterations = 1000000000\n",
            "[alignment]\ngap_tolerance_s = -1.0\n",
            "[detect]\nmin_leg_s = 0.0\n",
            "[quality.transfer]\nwarning_factor = 0.5\n",
            "[columns]\ntime = \"\"\n",
            "[diagnose]\nvector_mismatch_nt = -3.0\n",
            "[site]\nlatitude = 95.0\nlongitude = 0.0\n",
            "[site]\nlongitude = 400.0\nlatitude = 0.0\n",
            "[site]\ndate = \"June\"\nlatitude = 0.0\nlongitude = 0.0\n",
            // Bounded, finite and signed: a margin of 1e308 s would run for
            // ever; NaN, infinity and negatives mean nothing.
            "[detect]\nwindow_margin_s = 1e308\n",
            "[detect]\nturn_heading_deg = nan\n",
            "[detect]\nturn_bank_deg = inf\n",
            "[detect]\nfluxgate_min_rms_deg = -0.5\n",
            "[detect]\njoin_activity_s = -2.0\n",
            "[detect]\nmin_half_cycles = 0\n",
            "[detect]\nmin_rms_deg = [1.2, 2.5, -1.2]\n",
            "[detect]\nmin_rms_deg = [1.2, 2.5, 1.2, 4.0]\n",
            "[detect]\ndominance_deg = [5.0, 6.0]\n",
            "[fit]\nterms = [\"permanent\", \"permanent\"]\n",
            "[fit]\nterms = [\"induced\", \"induced_6\"]\n",
        ] {
            let error = parse(bad).unwrap_err().to_string();
            let key = bad
                .lines()
                .nth(1)
                .and_then(|l| l.split(" =").next())
                .unwrap_or_default();
            let section = bad.lines().next().unwrap_or_default();
            // A value of the wrong shape is the TOML reader's error, which
            // shows the line and points at the value.
            let placed = error.contains(section) || error.contains("line 2");
            assert!(placed && error.contains(key), "{bad:?}: {error}");
        }
    }

    #[test]
    fn the_site_gives_the_vector_stage_a_position_and_a_date() {
        assert_eq!(parse("").unwrap().settings.vector.site, None);
        let pipeline = parse("[site]\nlatitude = -33.5\nlongitude = 151.25\ndate = \"2026-06-15\"\n").unwrap();
        assert_eq!(
            pipeline.settings.vector.site,
            Some(crate::vector::Site {
                latitude_deg: -33.5,
                longitude_deg: 151.25,
                height_m: 0.0,
                date: crate::ingest::flight_date::FlightDate::parse("2026-06-15"),
            })
        );
    }

    #[test]
    fn a_section_left_partly_out_keeps_the_defaults_of_the_rest() {
        let pipeline = parse("[detect]\nmin_leg_s = 60.0\n[diagnose]\napply = \"never\"\n").unwrap();
        let settings = &pipeline.settings;
        assert_eq!(settings.detect.min_leg_s, 60.0);
        assert_eq!(
            DetectOptions {
                min_leg_s: DetectOptions::default().min_leg_s,
                ..settings.detect.clone()
            },
            DetectOptions::default()
        );
        assert_eq!(settings.diagnose.apply, crate::diagnose::ApplyDiagnosis::Never);
        assert_eq!(
            settings.diagnose.min_improvement,
            DiagnoseOptions::default().min_improvement
        );
        assert_eq!(settings.ingest.columns, ColumnNames::default());
    }

    #[test]
    fn a_typo_in_any_section_names_the_field() {
        for (text, typo) in [
            ("[detect]\nmin_leg = 60.0\n", "min_leg"),
            ("[diagnose]\nmin_improvment = 0.2\n", "min_improvment"),
            ("[vector_calibration]\nenable = true\n", "enable"),
            ("[quality.transfer]\nwarning = 3.0\n", "warning"),
            ("[alignment]\ntimebase = \"mag_1_uc\"\n", "timebase"),
            ("[columns]\ntimes = \"t\"\n", "times"),
            ("[[topic]]\ntopic = \"/imu/mag\"\nvectr = \"flux_a\"\n", "vectr"),
        ] {
            let error = parse(text).unwrap_err().to_string();
            assert!(error.contains(typo), "{text:?}: {error}");
        }
    }

    #[test]
    fn a_topic_is_mapped_once_to_one_kind_of_channel() {
        let both = "[[topic]]\ntopic = \"/imu/mag\"\nvector = \"flux_a\"\nscalar = \"mag_9\"\n";
        let error = parse(both).unwrap_err().to_string();
        assert!(error.contains("/imu/mag") && error.contains("not both"), "{error}");
        let twice = "[[topic]]\ntopic = \"/imu/mag\"\nvector = \"flux_a\"\n[[topic]]\ntopic = \"/imu/mag\"\nscalar = \"mag_9\"\n";
        let error = parse(twice).unwrap_err().to_string();
        assert!(error.contains("mapped twice"), "{error}");
        let one = parse("[[topic]]\ntopic = \"/imu/mag\"\nscalar = \"mag_9\"\n").unwrap();
        assert_eq!(one.settings.ingest.topics[0].scalar.as_deref(), Some("mag_9"));
    }

    #[test]
    fn validating_reads_no_file_and_loading_reads_the_windows_files() {
        let text = "[[flight]]\ninput = \"f.csv\"\nwindows_file = \"absent.windows.json\"\n";
        assert!(parse(text).is_ok(), "validation alone must not open the windows file");
        let folder = std::env::temp_dir().join(format!("magcomp-config-{}", std::process::id()));
        std::fs::create_dir_all(&folder).unwrap();
        let config = folder.join("pipeline.toml");
        std::fs::write(&config, text).unwrap();
        let error = Pipeline::load(&config).unwrap_err().to_string();
        std::fs::remove_dir_all(&folder).unwrap();
        assert!(error.contains("absent.windows.json"), "{error}");
    }
}
