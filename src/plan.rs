//! Planning a calibration before it is flown: `magcomp plan PLAN.toml
//! --out PLAN_REPORT.json`.
//!
//! A plan is a scenario ([`crate::simulate::scenario`]: the box's headings,
//! manoeuvres, amplitudes and periods, the sample rate, the sensors, the
//! survey lines the compensation is for) with a `[plan]` table:
//!
//! ```toml
//! [plan]
//! realisations = 8                  # simulated flights of the plan
//! target_survey_sigma_nt = 0.02     # optional: the survey uncertainty wanted
//! target_fom_nt = 1.0               # optional: the FOM wanted
//! installation = "last_model.json"  # optional: a previous flight's --model
//! most_additions = 6                # additions proposed at most
//! ```
//!
//! Each realisation flies the plan in the simulator with its own seed
//! (turbulence, the pilot's amplitudes and periods, noise; and, without
//! an installation, an aircraft drawn at each sensor location's typical
//! size), fits plain Tolles-Lawson on the planned manoeuvres as
//! `compensate` does, and measures what a flight of the plan would give:
//! the FOM, the survey uncertainty the excitation analysis states (the
//! coefficients' part, [`crate::model::excitation`], with the compensated
//! noise), and the survey lines' error against the simulation's truth.
//! The prediction is the median over the realisations, with their range.
//!
//! With a survey target, additions are chosen greedily from the analysis's
//! candidate manoeuvres (pitch, roll and yaw on each heading): each step
//! takes the one that lowers the channels' excess over the target most per
//! second of flight, scored on every realisation's information at once,
//! until every channel meets the target or nothing helps. Flight time is
//! the manoeuvre's length and a pause, plus a lead-in and two turns when
//! its heading is not a leg of the plan. The plan is then flown again with
//! the additions, so the report shows what they achieve, not only what the
//! analysis expects.
//!
//! With `installation`, each scalar sensor the model file compensates
//! takes that aircraft's field (its permanent, induced and eddy
//! coefficients turned into the simulator's $P + A B + E \dot B$); a plan
//! without `[[scalar]]` tables takes the model file's channels.
//!
//! A flight flown to the plan is set against the report by
//! [`crate::quality::against_plan`] (`compensate --plan PLAN_REPORT.json`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calibration::headings::angle_apart;
use crate::calibration::windows::ManoeuvreKind;
use crate::config::Settings;
use crate::error::{Error, Result};
use crate::model::excitation::{analyse_design, Design, Excitation};
use crate::model::{fit, FittedModel, ModelSpec, SharedDesign};
use crate::numerics::stacked::StorePool;
use crate::simulate::physics::AircraftField;
use crate::simulate::scenario::{RawScenario, ScalarSensor, Scenario, SensorLocation};
use crate::simulate::{simulate, SimulatedFlight};

/// Realisations when `[plan]` gives none.
const DEFAULT_REALISATIONS: usize = 8;

/// Most realisations a plan may ask for.
const MOST_REALISATIONS: usize = 64;

/// An addition is taken only if it lowers the channels' summed excess
/// over the target by at least this fraction.
const LEAST_GAIN: f64 = 0.005;

/// Extra flight time for a manoeuvre on a heading that is not a leg of
/// the plan: a lead-in and two 90° turns at 3°/s, s.
const NEW_LEG_S: f64 = 80.0;

pub use crate::quality::against_plan::STATED_FACTOR;

/// `[plan]`: how to predict.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlanSettings {
    /// Simulated flights of the plan.
    pub realisations: usize,
    /// The survey uncertainty wanted, one sigma, nT.
    pub target_survey_sigma_nt: Option<f64>,
    /// The FOM wanted, nT.
    pub target_fom_nt: Option<f64>,
    /// A previous flight's model JSON (`compensate --model`): the
    /// aircraft's field at each sensor it compensates.
    pub installation: Option<PathBuf>,
    /// Most manoeuvres added (a repeat counts each time).
    pub most_additions: usize,
}

impl Default for PlanSettings {
    fn default() -> Self {
        PlanSettings {
            realisations: DEFAULT_REALISATIONS,
            target_survey_sigma_nt: None,
            target_fom_nt: None,
            installation: None,
            most_additions: 6,
        }
    }
}

/// A checked plan.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The plan file.
    pub path: PathBuf,
    /// `[plan]`.
    pub settings: PlanSettings,
    /// The planned flight.
    pub scenario: Scenario,
    /// Where each sensor's aircraft field comes from, in words.
    pub installation: String,
}

impl Plan {
    /// Reads and checks a plan file.
    pub fn load(path: &Path) -> Result<Plan> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, "reading", e))?;
        let config = |message: String| Error::Config {
            source_name: path.display().to_string(),
            message,
        };
        let mut table: toml::Table = toml::from_str(&text).map_err(|e| config(e.to_string()))?;
        let settings: PlanSettings = match table.remove("plan") {
            Some(value) => value.try_into().map_err(|e| config(format!("[plan]: {e}")))?,
            None => PlanSettings::default(),
        };
        let has_scalars = table.contains_key("scalar");
        let mut raw: RawScenario = toml::Value::Table(table)
            .try_into()
            .map_err(|e| config(e.to_string()))?;
        check_plan(&settings, &raw).map_err(config)?;
        let installation = match &settings.installation {
            None => "typical values: each scalar sensor's aircraft field drawn at its location's size (tail, wing or cabin), afresh in every realisation".to_string(),
            Some(file) => {
                let file = match file.is_absolute() {
                    true => file.clone(),
                    false => path.parent().unwrap_or(Path::new(".")).join(file),
                };
                install(&mut raw, &file, has_scalars)?
            }
        };
        let scenario = Scenario::try_from(raw).map_err(config)?;
        Ok(Plan {
            path: path.to_path_buf(),
            settings,
            scenario,
            installation,
        })
    }
}

/// Refuses a plan that cannot be predicted: too few or too many simulated
/// flights, a target that is not a positive number of nT, or no box.
fn check_plan(settings: &PlanSettings, raw: &RawScenario) -> std::result::Result<(), String> {
    if !(1..=MOST_REALISATIONS).contains(&settings.realisations) {
        return Err(format!(
            "[plan] realisations = {}: give 1 to {MOST_REALISATIONS} simulated flights",
            settings.realisations
        ));
    }
    for (name, target) in [
        ("target_survey_sigma_nt", settings.target_survey_sigma_nt),
        ("target_fom_nt", settings.target_fom_nt),
    ] {
        if target.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
            return Err(format!("[plan] {name}: give a positive number of nT"));
        }
    }
    if raw.calibration.repeats == 0 {
        return Err("[calibration] repeats = 0: a plan needs a calibration box to predict".into());
    }
    Ok(())
}

/// The aircraft field of each mag_<n>_uc channel of a model JSON's
/// `models`, and the terms each leaves out (in words).
fn aircraft_fields(models: &[serde_json::Value]) -> (BTreeMap<String, AircraftField>, Vec<String>) {
    let mut fields: BTreeMap<String, AircraftField> = BTreeMap::new();
    let mut left_out: Vec<String> = Vec::new();
    for model in models {
        let (Some(channel), Some((field, unused))) =
            (model.get("channel").and_then(|c| c.as_str()), aircraft_field(model))
        else {
            continue;
        };
        if channel.starts_with("mag_") && channel.ends_with("_uc") {
            fields.insert(channel.to_string(), field);
            if !unused.is_empty() {
                left_out.push(format!("{channel}'s {}", unused.join(", ")));
            }
        }
    }
    (fields, left_out)
}

/// Sets the aircraft field of each scalar sensor of `raw` that the model
/// file at `file` compensates (all of the file's channels when the plan
/// names no sensor); says what was taken.
fn install(raw: &mut RawScenario, file: &Path, has_scalars: bool) -> Result<String> {
    let not_ours = |problem: String| {
        Error::NotOurFile {
        path: file.to_path_buf(),
        expected: "a model JSON written by compensate --model",
        problem,
        hint: "Give [plan] installation the --model file of a previous flight of this aircraft, or leave it out for typical values.",
    }
    };
    let text = std::fs::read_to_string(file).map_err(|e| Error::io(file, "reading", e))?;
    let json: serde_json::Value = serde_json::from_str(&text).map_err(|e| not_ours(e.to_string()))?;
    let models = json
        .get("models")
        .and_then(|m| m.as_array())
        .ok_or_else(|| not_ours("it has no \"models\" list".into()))?;
    let (fields, left_out) = aircraft_fields(models);
    if fields.is_empty() {
        return Err(not_ours(
            "no model of a mag_<n>_uc channel with Tolles-Lawson coefficients and a sample rate".into(),
        ));
    }
    if !has_scalars {
        raw.scalar = fields
            .keys()
            .map(|name| ScalarSensor::new(name, SensorLocation::Tail, 0.005))
            .collect();
    }
    let mut taken = Vec::new();
    let mut typical = Vec::new();
    for sensor in &mut raw.scalar {
        match fields.get(&sensor.name) {
            Some(field) => {
                sensor.aircraft = Some(field.clone());
                taken.push(sensor.name.clone());
            }
            None => typical.push(sensor.name.clone()),
        }
    }
    Ok(installed_words(file, &taken, &left_out, &typical))
}

/// What [`install`] took from the model file at `file`, in words: the
/// sensors `taken` from it, the terms `left_out` and the sensors drawn at
/// their `typical` size.
fn installed_words(file: &Path, taken: &[String], left_out: &[String], typical: &[String]) -> String {
    let mut words = format!(
        "from {}: the aircraft's field at {} from that flight's Tolles-Lawson coefficients",
        file.display(),
        taken.join(", ")
    );
    if !left_out.is_empty() {
        words += &format!(
            "; left out, as the simulated aircraft field holds no such term: {}",
            left_out.join("; ")
        );
    }
    if !typical.is_empty() {
        words += &format!(
            "; {} not in it, so drawn at the location's typical size",
            typical.join(", ")
        );
    }
    words
}

/// The simulator's aircraft field from one model of a model JSON: the
/// permanent terms are P; the induced terms $a_{ij} u_i B_j / s$ give the
/// symmetric A ($a_{ii} = s A_{ii}$, $a_{ij} = 2 s A_{ij}$); the eddy
/// terms $b_{ij} u_i \Delta B_j / s$, ΔB per sample, give
/// $E_{ij} = b_{ij} / (s f_s)$ in seconds. Terms the model lacks are zero;
/// extension columns (lags, couplings) are left out and named. `None`
/// without coefficients or a sample rate.
fn aircraft_field(model: &serde_json::Value) -> Option<(AircraftField, Vec<String>)> {
    let names = model.get("term_names")?.as_array()?;
    let values = model.get("coefficients")?.as_array()?;
    let rate = model.get("sample_rate_hz")?.as_f64().filter(|r| *r > 0.0)?;
    let scale = (model.pointer("/spec/terms/bt_scale_nt"))
        .and_then(|s| s.as_f64())
        .filter(|s| *s > 0.0)?;
    let axis = |c: char| "xyz".find(c);
    let mut field = AircraftField {
        permanent_nt: [0.0; 3],
        induced: [[0.0; 3]; 3],
        eddy_s: [[0.0; 3]; 3],
    };
    let mut any = false;
    let mut unused = Vec::new();
    for (name, value) in names.iter().zip(values) {
        let (Some(name), Some(value)) = (name.as_str(), value.as_f64()) else {
            continue;
        };
        let letters: Vec<usize> = name.rsplit('_').next()?.chars().filter_map(axis).collect();
        match (name.split('_').next(), letters.as_slice()) {
            (Some("perm"), &[i]) => field.permanent_nt[i] = value,
            (Some("ind"), &[i, j]) if i == j => field.induced[i][i] = value / scale,
            (Some("ind"), &[i, j]) => {
                field.induced[i][j] = value / (2.0 * scale);
                field.induced[j][i] = field.induced[i][j];
            }
            (Some("eddy"), &[i, j]) => field.eddy_s[i][j] = value / (scale * rate),
            _ => {
                unused.push(name.to_string());
                continue;
            }
        }
        any = true;
    }
    (any && field.is_plausible()).then_some((field, unused))
}

/// A figure over the realisations.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Spread {
    /// Median.
    pub median: f64,
    /// Smallest.
    pub low: f64,
    /// Largest.
    pub high: f64,
}

impl Spread {
    fn of(values: impl IntoIterator<Item = f64>) -> Spread {
        let mut values: Vec<f64> = values.into_iter().filter(|v| !v.is_nan()).collect();
        values.sort_by(f64::total_cmp);
        let n = values.len();
        match n {
            0 => Spread {
                median: f64::NAN,
                low: f64::NAN,
                high: f64::NAN,
            },
            _ => Spread {
                median: match n % 2 {
                    1 => values[n / 2],
                    _ => 0.5 * (values[n / 2 - 1] + values[n / 2]),
                },
                low: values[0],
                high: values[n - 1],
            },
        }
    }

    fn words(&self, decimals: usize) -> String {
        format!(
            "{:.d$} nT (range {:.d$}–{:.d$})",
            self.median,
            self.low,
            self.high,
            d = decimals
        )
    }
}

/// What one channel would achieve on flights of the plan.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChannelPrediction {
    /// Scalar channel.
    pub channel: String,
    /// FOM before compensation, nT.
    pub fom_before_nt: Spread,
    /// FOM after compensation, nT.
    pub fom_nt: Spread,
    /// Manoeuvres in the FOM (median).
    pub fom_manoeuvres: usize,
    /// The survey uncertainty the excitation analysis states (the model
    /// JSON's `excitation.survey_sigma_nt`) with the compensated noise,
    /// one sigma, nT: what the target and the additions are judged on.
    pub survey_sigma_nt: Spread,
    /// The coefficients' part of it (the excitation analysis), nT.
    pub coefficient_sigma_nt: Spread,
    /// The compensated channel's noise on the survey lines, one sigma of
    /// white noise (from the fourth difference,
    /// [`crate::quality::ChannelQuality::white_noise_nt`]), nT.
    pub noise_nt: Spread,
    /// What the simulated flights achieved: the RMS over the survey lines
    /// of the compensated value's error against the simulation's truth,
    /// relative to its level over the calibration windows, nT.
    pub survey_error_nt: Spread,
    /// The blocked jackknife's uncertainty of the compensation away from
    /// the calibration (the quality JSON's `outside_calibration_sigma_nt`),
    /// nT.
    pub jackknife_sigma_nt: Spread,
    /// The `mag_<n>_c_sigma` column's RMS over the survey lines (the
    /// jackknife's spread with the noise), nT.
    pub sigma_column_nt: Spread,
    /// Simulated flights whose compensation would carry the uncertainty
    /// warning (jackknife above [`crate::quality::UNCERTAINTY_WARNING_NT`]).
    pub uncertain_flights: usize,
    /// Terms poorly pinned in at least half the realisations.
    pub poorly_pinned: Vec<String>,
    /// Gaps in the box the analysis names in at least half the
    /// realisations.
    pub gaps: Vec<String>,
    /// Their labels, in the same order.
    #[serde(skip)]
    pub gap_labels: Vec<String>,
    /// Whether the median FOM meets `[plan] target_fom_nt`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub meets_fom_target: Option<bool>,
    /// Whether the median survey sigma meets `[plan] target_survey_sigma_nt`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub meets_survey_target: Option<bool>,
}

/// A manoeuvre of the planned box.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PlannedManoeuvre {
    /// Manoeuvre.
    pub kind: ManoeuvreKind,
    /// Leg heading, degrees.
    pub heading_deg: f64,
}

/// A manoeuvre to add to the plan.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Addition {
    /// Manoeuvre.
    pub kind: ManoeuvreKind,
    /// Heading, degrees.
    pub heading_deg: f64,
    /// Amplitude, degrees (the plan's, as the realisations flew it).
    pub amplitude_deg: f64,
    /// Period, s.
    pub period_s: f64,
    /// Length, s.
    pub duration_s: f64,
    /// Times it is flown (one after the other on its leg).
    pub count: usize,
    /// Flight time it adds, all times together, s.
    pub cost_s: f64,
    /// Whether its heading is a new leg.
    pub new_leg: bool,
    /// Each channel's predicted survey sigma (median) with this and the
    /// additions before it, nT.
    pub survey_sigma_nt: BTreeMap<String, f64>,
}

/// `PLAN_REPORT.json`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlanReport {
    /// The plan file.
    pub plan: PathBuf,
    /// The seeds of the simulated flights.
    pub seeds: Vec<u64>,
    /// Where the aircraft's field comes from.
    pub installation: String,
    /// The planned box's headings, degrees.
    pub headings_deg: Vec<f64>,
    /// Manoeuvres in the planned box(es).
    pub manoeuvres: usize,
    /// Each planned manoeuvre, as the first simulated flight flew it:
    /// what a flight of the plan is matched with (`compensate --plan`).
    pub planned_manoeuvres: Vec<PlannedManoeuvre>,
    /// Length of the calibration (first manoeuvre to last), s (median).
    pub calibration_s: f64,
    /// `[plan] target_fom_nt`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_fom_nt: Option<f64>,
    /// `[plan] target_survey_sigma_nt`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_survey_sigma_nt: Option<f64>,
    /// The factor within which the medians are expected to hold on
    /// flights of the plan.
    pub stated_factor: f64,
    /// Each channel's prediction.
    pub channels: Vec<ChannelPrediction>,
    /// Additions that would meet the survey target, cheapest first
    /// (empty without a target, or when the plan meets it).
    pub additions: Vec<Addition>,
    /// Whether the additions meet the target, as the analysis predicts.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub additions_meet_target: Option<bool>,
    /// The plan flown again with the additions.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub with_additions: Vec<ChannelPrediction>,
    /// Without a survey target: each candidate's median change of the
    /// survey sigma, per channel, the most useful first.
    pub candidates: Vec<CandidateValue>,
    /// What the user must know.
    pub warnings: Vec<String>,
    /// The prediction in words.
    pub summary: Vec<String>,
}

/// What one candidate manoeuvre would do, on the median realisation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CandidateValue {
    /// Manoeuvre.
    pub kind: ManoeuvreKind,
    /// Heading, degrees.
    pub heading_deg: f64,
    /// Flight time it adds, s.
    pub cost_s: f64,
    /// Each channel's median relative change of the coefficients' survey
    /// sigma (negative: better).
    pub change: BTreeMap<String, f64>,
}

/// One channel of one realisation.
struct Outcome {
    channel: String,
    fom: Option<(f64, f64, usize)>,
    coefficient_sigma_nt: f64,
    noise_nt: f64,
    survey_error_nt: f64,
    /// The blocked jackknife's uncertainty away from the calibration, nT.
    jackknife_sigma_nt: f64,
    /// RMS of the sigma column over the survey lines, nT.
    sigma_column_nt: f64,
    poorly_pinned: Vec<String>,
    /// The box's gaps the analysis names.
    gaps: Vec<crate::model::excitation::Candidate>,
    design: Option<Design>,
}

/// One simulated flight of the plan.
struct Realisation {
    /// The manoeuvres flown, in order.
    flown: Vec<PlannedManoeuvre>,
    outcomes: Vec<Outcome>,
    manoeuvres: usize,
    calibration_s: f64,
}

/// The warning naming the channels whose compensated noise alone is at or
/// above the survey `target`, nT, which no manoeuvre can meet.
fn noise_above_target(channels: &[ChannelPrediction], realisations: &[Realisation], target: f64) -> Option<String> {
    let floored: Vec<String> = (channels.iter().zip(&realisations[0].outcomes))
        .filter_map(|(channel, outcome)| {
            let floor = median_of(realisations.iter().map(|r| noise_of(r, &outcome.channel)));
            (floor >= target).then(|| format!("{} ({floor:.3} nT)", channel.channel))
        })
        .collect();
    (!floored.is_empty()).then(|| {
        format!(
            "no manoeuvre can meet the survey target of {target:.3} nT on {}: the compensated channel's noise alone is above it",
            floored.join(", ")
        )
    })
}

/// The flights of `plan` with its proposed `additions` flown too, one per
/// seed.
fn realise_with(
    plan: &Plan,
    additions: &[Addition],
    (seeds, settings): (&[u64], &Settings),
) -> Result<Vec<Realisation>> {
    let mut scenario = plan.scenario.clone();
    add_to_scenario(&mut scenario.raw, additions);
    let scenario = Scenario::try_from(scenario.raw).map_err(|message| Error::Config {
        source_name: plan.path.display().to_string(),
        message,
    })?;
    realise_all(&scenario, seeds, settings)
}

/// What flying `candidate` costs, s (the manoeuvre, a mean pause, and on
/// a heading that is not one of the plan's legs a new leg), and whether it
/// needs a new leg.
fn addition_cost(plan: &Plan, candidate: &crate::model::excitation::Candidate) -> (f64, bool) {
    let pause = plan.scenario.raw.calibration.pause_s;
    let headings = &plan.scenario.raw.calibration.headings_deg;
    let new_leg = !headings.iter().any(|h| angle_apart(*h, candidate.heading_deg) < 1.0);
    let extra = if new_leg { NEW_LEG_S } else { 0.0 };
    (candidate.duration_s + 0.5 * (pause[0] + pause[1]) + extra, new_leg)
}

/// What a prediction proposes to add to the plan's box.
struct Proposed {
    /// The additions chosen towards the survey target.
    additions: Vec<Addition>,
    /// Whether they meet it; `None` without a target or an analysis.
    additions_meet_target: Option<bool>,
    /// The channels predicted with the additions flown.
    with_additions: Vec<ChannelPrediction>,
    /// Without a target, what each candidate alone would do.
    candidates: Vec<CandidateValue>,
}

/// The additions towards the plan's survey target and the channels flown
/// with them, or without a target each candidate's value; warns in
/// `warnings` of channels whose noise alone is above the target.
fn propose(
    plan: &Plan,
    (realisations, channels): (&[Realisation], &[ChannelPrediction]),
    (seeds, settings): (&[u64], &Settings),
    warnings: &mut Vec<String>,
) -> Result<Proposed> {
    let target_survey = plan.settings.target_survey_sigma_nt;
    let target_fom = plan.settings.target_fom_nt;
    let cost = |candidate: &crate::model::excitation::Candidate| addition_cost(plan, candidate);
    let mut additions = Vec::new();
    let mut additions_meet_target = None;
    let mut with_additions = Vec::new();
    let mut candidates = Vec::new();
    match target_survey {
        Some(target) => {
            let chosen = choose_additions(realisations, target, plan.settings.most_additions, &cost);
            warnings.extend(noise_above_target(channels, realisations, target));
            if let Some((list, met)) = chosen {
                additions = list;
                additions_meet_target = Some(met);
                if !additions.is_empty() {
                    let again = realise_with(plan, &additions, (seeds, settings))?;
                    with_additions = predictions(&again, target_survey, target_fom);
                }
            }
        }
        None => candidates = candidate_values(realisations, &cost),
    }
    Ok(Proposed {
        additions,
        additions_meet_target,
        with_additions,
        candidates,
    })
}

/// Predicts what flights of `plan` would achieve (see the module doc).
/// Results do not depend on the number of threads: each realisation is
/// simulated and fitted on its own seed, and they are gathered in order.
pub fn predict(plan: &Plan, settings: &Settings) -> Result<PlanReport> {
    let seeds: Vec<u64> = (0..plan.settings.realisations as u64)
        .map(|k| plan.scenario.raw.seed.wrapping_add(k))
        .collect();
    let realisations = realise_all(&plan.scenario, &seeds, settings)?;
    let target_survey = plan.settings.target_survey_sigma_nt;
    let target_fom = plan.settings.target_fom_nt;
    let channels = predictions(&realisations, target_survey, target_fom);
    let mut warnings = Vec::new();
    let headings = plan.scenario.raw.calibration.headings_deg.clone();
    let proposed = propose(plan, (&realisations, &channels), (&seeds, settings), &mut warnings)?;
    warnings.extend(channel_warnings(&channels, &realisations, target_fom));
    if proposed.additions_meet_target == Some(false) {
        warnings.push(format!(
            "no set of up to {} additions meets the survey target of {:.3} nT on every channel; the report lists the best found",
            plan.settings.most_additions,
            target_survey.unwrap_or(f64::NAN)
        ));
    }
    let mut report = PlanReport {
        plan: plan.path.clone(),
        seeds,
        installation: plan.installation.clone(),
        headings_deg: headings.clone(),
        manoeuvres: median_of(realisations.iter().map(|r| r.manoeuvres as f64)).round() as usize,
        planned_manoeuvres: realisations.first().map(|r| r.flown.clone()).unwrap_or_default(),
        calibration_s: median_of(realisations.iter().map(|r| r.calibration_s)),
        target_fom_nt: target_fom,
        target_survey_sigma_nt: target_survey,
        stated_factor: STATED_FACTOR,
        channels,
        additions: proposed.additions,
        additions_meet_target: proposed.additions_meet_target,
        with_additions: proposed.with_additions,
        candidates: proposed.candidates,
        warnings,
        summary: Vec::new(),
    };
    report.summary = summarise(&report);
    Ok(report)
}

/// What the channels' predictions leave short, one warning per kind
/// naming every channel it concerns: a FOM above its target, simulated
/// flights without an excitation analysis, each gap in the box, and
/// flights whose compensation away from the calibration is uncertain.
fn channel_warnings(
    channels: &[ChannelPrediction],
    realisations: &[Realisation],
    target_fom: Option<f64>,
) -> Vec<String> {
    let flights = realisations.len();
    let mut warnings = Vec::new();
    let listed = |items: Vec<String>| items.join(", ");
    warnings.extend(fom_above_target(channels, target_fom));
    let unanalysed: Vec<String> = (channels.iter())
        .filter_map(|channel| {
            let count = (realisations.iter())
                .filter(|r| (r.outcomes.iter()).any(|o| o.channel == channel.channel && o.design.is_none()))
                .count();
            (count > 0).then(|| format!("{} ({count} of {flights})", channel.channel))
        })
        .collect();
    if !unanalysed.is_empty() {
        warnings.push(format!(
            "simulated flights without an excitation analysis (the windows leave the design singular) on {}: the survey uncertainty and the additions rest on the others",
            listed(unanalysed)
        ));
    }
    warnings.extend(gap_warnings(channels, realisations));
    warnings.extend(uncertain_away(channels, flights));
    warnings
}

/// The warning naming the channels whose predicted FOM is above
/// `target_fom`, nT, with their compensated noise.
fn fom_above_target(channels: &[ChannelPrediction], target_fom: Option<f64>) -> Option<String> {
    let above: Vec<String> = (channels.iter())
        .filter(|c| c.meets_fom_target == Some(false))
        .map(|c| {
            format!(
                "{} (FOM {}, its compensated noise {:.3} nT)",
                c.channel,
                c.fom_nt.words(2),
                c.noise_nt.median
            )
        })
        .collect();
    (!above.is_empty()).then(|| {
        format!(
            "the plan's predicted FOM is above the target of {:.2} nT on {}; no addition to the box lowers it (it measures the compensated residual over the box's own manoeuvres)",
            target_fom.unwrap_or(f64::NAN),
            above.join(", ")
        )
    })
}

/// The warning naming the channels uncertain away from the calibration on
/// some of the `flights` simulated flights, with how uncertain.
fn uncertain_away(channels: &[ChannelPrediction], flights: usize) -> Option<String> {
    let uncertain: Vec<String> = (channels.iter())
        .filter(|c| c.uncertain_flights > 0)
        .map(|c| {
            format!(
                "{} in {} of the {flights} (the blocked jackknife up to {:.3} nT, the survey lines' error up to {:.3} nT)",
                c.channel, c.uncertain_flights, c.jackknife_sigma_nt.high, c.survey_error_nt.high,
            )
        })
        .collect();
    (!uncertain.is_empty()).then(|| {
        format!(
            "on some simulated flights the compensation away from the calibration is uncertain by more than {:.3} nT: {}; the planned manoeuvres leave the fit open on the survey's headings and attitudes on some flights, and compensate would warn on them",
            crate::quality::UNCERTAINTY_WARNING_NT,
            uncertain.join(", ")
        )
    })
}

/// One warning per gap in the box that most realisations name on some
/// channel: what the plan lacks, how to fly it, and the median change it
/// would make on each channel that names it.
fn gap_warnings(channels: &[ChannelPrediction], realisations: &[Realisation]) -> Vec<String> {
    let mut labels: Vec<&str> = Vec::new();
    for label in channels.iter().flat_map(|c| &c.gap_labels) {
        if !labels.contains(&label.as_str()) {
            labels.push(label);
        }
    }
    labels
        .into_iter()
        .filter_map(|label| {
            let named: Vec<(usize, GapFigures)> = (channels.iter().enumerate())
                .filter(|(_, c)| c.gap_labels.iter().any(|l| l == label))
                .filter_map(|(c, _)| gap_figures(realisations, c, label).map(|g| (c, g)))
                .collect();
            let (_, first) = named.first()?;
            let changes: Vec<String> = (named.iter())
                .map(|(c, g)| format!("{:+.0} % on {}", g.change_percent, channels[*c].channel))
                .collect();
            Some(format!(
                "{}: flying it ({}) changes the survey uncertainty the coefficients leave by {} (medians of the {} simulated flights that name it).",
                first.state,
                first.shape,
                changes.join(", "),
                first.flights
            ))
        })
        .collect()
}

/// Simulates and fits `scenario` once per seed, in parallel, in order.
fn realise_all(scenario: &Scenario, seeds: &[u64], settings: &Settings) -> Result<Vec<Realisation>> {
    seeds
        .par_iter()
        .map(|&seed| {
            let mut scenario = scenario.clone();
            scenario.raw.seed = seed;
            let flight = simulate(&scenario)?;
            realise(&flight, settings)
        })
        .collect()
}

/// What `model` states of its compensation on `log`: the jackknife's
/// sigma outside the calibration, and the sigma column's RMS over the
/// survey lines (rows whose `line` is positive, the white noise
/// `noise_nt` added), nT; NaN for both without a jackknife.
fn stated_sigmas(
    log: &crate::ingest::flight_log::FlightLog,
    model: &FittedModel,
    (shared, line): (&[SharedDesign], &[f64]),
    noise_nt: f64,
) -> Result<(f64, f64)> {
    let Some(prediction) = model.prediction_sigma_with(log, shared)? else {
        return Ok((f64::NAN, f64::NAN));
    };
    let column: Vec<f64> = (0..line.len())
        .filter(|&i| line[i] > 0.0)
        .map(|i| prediction.relative_nt[i].hypot(noise_nt))
        .filter(|v| v.is_finite())
        .collect();
    Ok((
        crate::quality::uncertainty_of(log, model, &prediction).map_or(f64::NAN, |u| u.outside_calibration_sigma_nt),
        (column.iter().map(|v| v * v).sum::<f64>() / column.len() as f64).sqrt(),
    ))
}

/// One channel's outcome on a simulated flight: its quality figures, its
/// excitation analysis and the error of its compensated survey lines
/// against the flight's truth.
fn outcome(
    flight: &SimulatedFlight,
    (model, compensated): (&FittedModel, &crate::compensate::CompensatedChannel),
    design: Option<(Excitation, Design)>,
    (shared, line): (&[SharedDesign], &[f64]),
) -> Result<Outcome> {
    let log = &flight.log;
    let quality = crate::quality::assess_quality(log, model, compensated);
    let noise_nt = quality.white_noise_nt().unwrap_or(f64::NAN);
    let truth = flight.truth.earth_total_nt(&model.channel).unwrap_or_default();
    let (excitation, design) = design.unzip();
    let (jackknife_sigma_nt, sigma_column_nt) = stated_sigmas(log, model, (shared, line), noise_nt)?;
    Ok(Outcome {
        channel: model.channel.clone(),
        fom: quality
            .fom_before_nt
            .zip(quality.fom_after_nt)
            .map(|(b, a)| (b, a, quality.fom_manoeuvres)),
        coefficient_sigma_nt: excitation.as_ref().map_or(f64::NAN, |e| e.survey_sigma_nt),
        noise_nt,
        survey_error_nt: error_from_calibration_level(model, &compensated.values, truth, line),
        poorly_pinned: (excitation.iter())
            .flat_map(|e| e.terms.iter().filter(|t| t.poorly_pinned).map(|t| t.term.clone()))
            .collect(),
        gaps: (excitation.iter())
            .flat_map(|e| e.additions.iter().filter(|c| c.gap).cloned())
            .collect(),
        jackknife_sigma_nt,
        sigma_column_nt,
        design,
    })
}

/// Fits and measures one simulated flight as `compensate --plain` would,
/// on its planned manoeuvres.
fn realise(flight: &SimulatedFlight, settings: &Settings) -> Result<Realisation> {
    let log = &flight.log;
    let sensor = crate::pipeline::choose_vector_sensor(log, None)?;
    let windows = flight.truth.calibration_windows(settings.detect.window_margin_s);
    let stores = StorePool::new();
    let spec = ModelSpec::plain(settings.terms);
    let channels: Vec<String> = flight.truth.sensors.iter().map(|s| s.channel.clone()).collect();
    let models: Vec<FittedModel> = (channels.iter())
        .map(|channel| fit(log, &sensor, channel, &windows, &spec, &settings.fit, &stores))
        .collect::<Result<_>>()?;
    let shared = SharedDesign::of_models(log, &models);
    let designs: Vec<Option<(Excitation, Design)>> = (models.iter())
        .map(|model| analyse_design(log, &sensor, model, &windows, &settings.fit, (&stores, &shared)))
        .collect::<Result<_>>()?;
    let compensation = crate::compensate::compensate_with(log, &models, settings.level, &shared)?;
    let line = log.channel("line").map(|c| c.values.as_slice()).unwrap_or_default();
    let outcomes = (models.iter().zip(&compensation.channels).zip(designs))
        .map(|((model, compensated), design)| outcome(flight, (model, compensated), design, (&shared, line)))
        .collect::<Result<_>>()?;
    let manoeuvres = &flight.truth.manoeuvres;
    let calibration_s = match (manoeuvres.first(), manoeuvres.last()) {
        (Some(first), Some(last)) => last.t_end - first.t_start,
        _ => 0.0,
    };
    Ok(Realisation {
        outcomes,
        manoeuvres: manoeuvres.len(),
        flown: (manoeuvres.iter())
            .map(|m| PlannedManoeuvre {
                kind: m.kind,
                heading_deg: m.heading_deg,
            })
            .collect(),
        calibration_s,
    })
}

/// RMS over the survey lines (rows whose `line` is positive) of the
/// compensated value's error against the truth, less its mean over the
/// calibration windows' rows (the band-passed fit does not pin the
/// level), nT; NaN without such rows.
pub fn error_from_calibration_level(model: &FittedModel, compensated: &[f64], truth: &[f64], line: &[f64]) -> f64 {
    let error = |i: usize| match (compensated.get(i), truth.get(i)) {
        (Some(c), Some(t)) => c - t,
        _ => f64::NAN,
    };
    let calibration: Vec<f64> = (model.windows.iter())
        .flat_map(|w| w.flight_rows.iter().cloned().flatten())
        .map(error)
        .filter(|e| e.is_finite())
        .collect();
    let level = calibration.iter().sum::<f64>() / calibration.len() as f64;
    let survey: Vec<f64> = (0..line.len())
        .filter(|&i| line[i] > 0.0)
        .map(|i| error(i) - level)
        .filter(|e| e.is_finite())
        .collect();
    (survey.iter().map(|e| e * e).sum::<f64>() / survey.len() as f64).sqrt()
}

/// The predictions of every channel, from the realisations.
fn predictions(
    realisations: &[Realisation],
    target_survey: Option<f64>,
    target_fom: Option<f64>,
) -> Vec<ChannelPrediction> {
    let Some(first) = realisations.first() else {
        return Vec::new();
    };
    (first.outcomes.iter().enumerate())
        .map(|(c, outcome)| channel_prediction(realisations, (c, outcome), (target_survey, target_fom)))
        .collect()
}

/// The words of each item `list` gives channel `c` on at least half the
/// realisations (items keyed, the words of the first kept), in key order.
fn held_by_most(
    realisations: &[Realisation],
    c: usize,
    list: &dyn Fn(&Outcome) -> Vec<(String, String)>,
) -> Vec<String> {
    let half = realisations.len().div_ceil(2);
    let mut counts: BTreeMap<String, (usize, String)> = BTreeMap::new();
    for r in realisations {
        for (key, words) in list(&r.outcomes[c]) {
            counts.entry(key).or_insert((0, words)).0 += 1;
        }
    }
    (counts.into_values())
        .filter(|(n, _)| *n >= half)
        .map(|(_, words)| words)
        .collect()
}

/// Channel `c`'s prediction (its `outcome` on the first realisation names
/// it): each figure's spread over the realisations, what most of them
/// leave poorly pinned or missing, and the targets met.
fn channel_prediction(
    realisations: &[Realisation],
    (c, outcome): (usize, &Outcome),
    (target_survey, target_fom): (Option<f64>, Option<f64>),
) -> ChannelPrediction {
    let figure = |f: &dyn Fn(&Outcome) -> f64| Spread::of(realisations.iter().map(|r| f(&r.outcomes[c])));
    let majority = |list: &dyn Fn(&Outcome) -> Vec<(String, String)>| held_by_most(realisations, c, list);
    let uncertain_flights = (realisations.iter())
        .filter(|r| r.outcomes[c].jackknife_sigma_nt > crate::quality::UNCERTAINTY_WARNING_NT)
        .count();
    let gap_labels = majority(&|o| o.gaps.iter().map(|g| (g.label(), g.label())).collect());
    let fom_nt = figure(&|o| o.fom.map_or(f64::NAN, |f| f.1));
    let survey_sigma_nt = figure(&|o| o.coefficient_sigma_nt.hypot(o.noise_nt));
    ChannelPrediction {
        channel: outcome.channel.clone(),
        fom_before_nt: figure(&|o| o.fom.map_or(f64::NAN, |f| f.0)),
        fom_nt,
        fom_manoeuvres: median_of(
            realisations
                .iter()
                .map(|r| r.outcomes[c].fom.map_or(0.0, |f| f.2 as f64)),
        ) as usize,
        survey_sigma_nt,
        coefficient_sigma_nt: figure(&|o| o.coefficient_sigma_nt),
        noise_nt: figure(&|o| o.noise_nt),
        survey_error_nt: figure(&|o| o.survey_error_nt),
        jackknife_sigma_nt: figure(&|o| o.jackknife_sigma_nt),
        sigma_column_nt: figure(&|o| o.sigma_column_nt),
        uncertain_flights,
        poorly_pinned: majority(&|o| o.poorly_pinned.iter().map(|t| (t.clone(), t.clone())).collect()),
        gaps: gap_labels
            .iter()
            .map(|label| gap_words(realisations, c, label))
            .collect(),
        gap_labels,
        meets_fom_target: target_fom.map(|t| fom_nt.median <= t),
        meets_survey_target: target_survey.map(|t| survey_sigma_nt.median <= t),
    }
}

/// A gap named `label` in channel `c`'s analyses: what the plan lacks,
/// how to fly it, and the median change it would make.
struct GapFigures {
    state: String,
    shape: String,
    change_percent: f64,
    /// Realisations that name it.
    flights: usize,
}

fn gap_figures(realisations: &[Realisation], c: usize, label: &str) -> Option<GapFigures> {
    let gaps: Vec<&crate::model::excitation::Candidate> = (realisations.iter())
        .flat_map(|r| r.outcomes[c].gaps.iter().filter(|g| g.label() == label))
        .collect();
    let first = gaps.first()?;
    let state = match first.flown {
        false => format!("the plan's box has no {label}"),
        true => format!(
            "the plan's {label} gives {:.0} % of the excitation of a typical one",
            100.0 * median_of(gaps.iter().map(|g| g.excitation_flown))
        ),
    };
    Some(GapFigures {
        state,
        shape: first.shape_words(),
        change_percent: 100.0 * median_of(gaps.iter().map(|g| g.change)),
        flights: gaps.len(),
    })
}

/// The sentence of a gap named `label` in channel `c`'s analyses.
fn gap_words(realisations: &[Realisation], c: usize, label: &str) -> String {
    match gap_figures(realisations, c, label) {
        None => format!("the plan's box lacks {label}"),
        Some(g) => format!(
            "{}: flying it ({}) changes the survey uncertainty the coefficients leave by {:+.0} % (median of {} simulated flights).",
            g.state, g.shape, g.change_percent, g.flights
        ),
    }
}

/// The median of the finite values; NaN without one.
fn median_of(values: impl IntoIterator<Item = f64>) -> f64 {
    Spread::of(values.into_iter().filter(|v| v.is_finite())).median
}

/// Channel `channel`'s noise in realisation `r`.
fn noise_of(r: &Realisation, channel: &str) -> f64 {
    r.outcomes
        .iter()
        .find(|o| o.channel == channel)
        .map_or(f64::NAN, |o| o.noise_nt)
}

/// The candidates of the first realisation with a design (the same
/// kinds and headings in every realisation, the plan's legs completed to
/// four), and each one's index in every realisation's design of every
/// channel.
fn candidate_index(
    realisations: &[Realisation],
) -> Vec<(crate::model::excitation::Candidate, Vec<Vec<Option<usize>>>)> {
    let Some(reference) = realisations
        .iter()
        .flat_map(|r| r.outcomes.iter())
        .find_map(|o| o.design.as_ref())
    else {
        return Vec::new();
    };
    reference
        .candidates()
        .map(|candidate| {
            let index = realisations
                .iter()
                .map(|r| {
                    (r.outcomes.iter())
                        .map(|o| {
                            o.design.as_ref().and_then(|d| {
                                d.candidates().position(|c| {
                                    c.kind == candidate.kind && angle_apart(c.heading_deg, candidate.heading_deg) < 1.0
                                })
                            })
                        })
                        .collect()
                })
                .collect();
            (candidate.clone(), index)
        })
        .collect()
}

/// Each channel's median, over the realisations, of the survey sigma
/// (coefficients' part with the noise) with the candidates `chosen`
/// (indices into `index`) flown as well.
fn sigma_with(
    realisations: &[Realisation],
    index: &[(crate::model::excitation::Candidate, Vec<Vec<Option<usize>>>)],
    chosen: &[usize],
) -> Vec<f64> {
    let channels = realisations.first().map_or(0, |r| r.outcomes.len());
    (0..channels)
        .map(|c| {
            median_of(realisations.iter().enumerate().map(|(k, r)| {
                let outcome = &r.outcomes[c];
                let Some(design) = &outcome.design else {
                    return f64::NAN;
                };
                let picks: Vec<usize> = chosen.iter().filter_map(|&m| index[m].1[k][c]).collect();
                design.survey_sigma_with(&picks).hypot(outcome.noise_nt)
            }))
        })
        .collect()
}

/// The channels' summed excess over `target`, as ratios: Σ max(σ/target, 1)
/// over the channels whose noise alone does not exceed it.
fn excess(sigmas: &[f64], reachable: &[bool], target: f64) -> f64 {
    (sigmas.iter().zip(reachable))
        .filter(|(s, r)| **r && s.is_finite())
        .map(|(s, _)| (s / target).max(1.0))
        .sum()
}

/// `chosen` grouped by the manoeuvre each is (`same` of two), in the
/// order of first choice.
fn grouped(chosen: &[usize], same: impl Fn(usize, usize) -> bool) -> Vec<Vec<usize>> {
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for &m in chosen {
        match groups.iter_mut().find(|g| same(g[0], m)) {
            Some(group) => group.push(m),
            None => groups.push(vec![m]),
        }
    }
    groups
}

/// Greedy additions towards `target` (see the module doc): the list and
/// whether it meets the target on every channel that can meet it. `None`
/// when no realisation could be analysed.
fn choose_additions(
    realisations: &[Realisation],
    target: f64,
    most: usize,
    cost: &dyn Fn(&crate::model::excitation::Candidate) -> (f64, bool),
) -> Option<(Vec<Addition>, bool)> {
    let index = candidate_index(realisations);
    if index.is_empty() {
        return None;
    }
    let names: Vec<String> = realisations[0].outcomes.iter().map(|o| o.channel.clone()).collect();
    let reachable: Vec<bool> = names
        .iter()
        .map(|name| median_of(realisations.iter().map(|r| noise_of(r, name))) < target)
        .collect();
    let met = |sigmas: &[f64]| (sigmas.iter().zip(&reachable)).all(|(s, r)| !r || *s <= target);
    let mut chosen: Vec<usize> = Vec::new();
    let mut sigmas = sigma_with(realisations, &index, &chosen);
    while !met(&sigmas) && chosen.len() < most {
        let now = excess(&sigmas, &reachable, target);
        let best = (0..index.len())
            .map(|m| {
                let mut trial = chosen.clone();
                trial.push(m);
                let after = sigma_with(realisations, &index, &trial);
                let gain = now - excess(&after, &reachable, target);
                (m, gain, gain / cost(&index[m].0).0, after)
            })
            .filter(|(_, gain, _, _)| *gain >= LEAST_GAIN * now)
            .max_by(|a, b| a.2.total_cmp(&b.2).then(b.0.cmp(&a.0)));
        let Some((m, _, _, after)) = best else {
            break;
        };
        chosen.push(m);
        sigmas = after;
    }
    // A manoeuvre chosen again later is listed once, flown that many
    // times: the list keeps the order of first choice, and each entry's
    // figures are those of it and the entries before it.
    let additions = listed_additions(realisations, &index, &chosen, (&names, cost));
    Some((additions, met(&sigmas)))
}

/// What flying a candidate costs, s, and whether it needs a new leg
/// ([`addition_cost`]).
type CostOf<'a> = dyn Fn(&crate::model::excitation::Candidate) -> (f64, bool) + 'a;

/// The additions `chosen` (indices into `index`, in the order chosen) as
/// the plan lists them: a manoeuvre chosen again listed once, flown that
/// many times, with its cost and each channel's survey sigma, nT, flown
/// with it and those before it.
fn listed_additions(
    realisations: &[Realisation],
    index: &[(crate::model::excitation::Candidate, Vec<Vec<Option<usize>>>)],
    chosen: &[usize],
    (names, cost): (&[String], &CostOf),
) -> Vec<Addition> {
    let mut additions = Vec::new();
    let groups = grouped(chosen, |a, b| {
        index[a].0.kind == index[b].0.kind && index[a].0.heading_deg == index[b].0.heading_deg
    });
    let mut flown: Vec<usize> = Vec::new();
    for group in groups {
        flown.extend(&group);
        let candidate = &index[group[0]].0;
        let (cost_s, new_leg) = cost(candidate);
        let repeat_s = cost_s - if new_leg { NEW_LEG_S } else { 0.0 };
        let after = sigma_with(realisations, index, &flown);
        additions.push(Addition {
            kind: candidate.kind,
            heading_deg: candidate.heading_deg,
            amplitude_deg: candidate.amplitude_deg,
            period_s: candidate.period_s,
            duration_s: candidate.duration_s,
            count: group.len(),
            cost_s: cost_s + (group.len() - 1) as f64 * repeat_s,
            new_leg,
            survey_sigma_nt: names.iter().cloned().zip(after).collect(),
        });
    }
    additions
}

/// Without a target: what each candidate alone would do.
fn candidate_values(
    realisations: &[Realisation],
    cost: &dyn Fn(&crate::model::excitation::Candidate) -> (f64, bool),
) -> Vec<CandidateValue> {
    let index = candidate_index(realisations);
    let names: Vec<String> = realisations
        .first()
        .map(|r| r.outcomes.iter().map(|o| o.channel.clone()).collect())
        .unwrap_or_default();
    let channels = names.len();
    let change_of = |m: usize, c: usize| -> f64 {
        median_of(realisations.iter().enumerate().map(|(k, r)| {
            let Some(design) = &r.outcomes[c].design else {
                return f64::NAN;
            };
            let Some(pick) = index[m].1[k][c] else {
                return f64::NAN;
            };
            design.survey_sigma_with(&[pick]) / design.survey_sigma_with(&[]) - 1.0
        }))
    };
    let mut values: Vec<CandidateValue> = (0..index.len())
        .map(|m| CandidateValue {
            kind: index[m].0.kind,
            heading_deg: index[m].0.heading_deg,
            cost_s: cost(&index[m].0).0,
            change: (0..channels).map(|c| (names[c].clone(), change_of(m, c))).collect(),
        })
        .collect();
    let mean_change = |v: &CandidateValue| v.change.values().filter(|c| c.is_finite()).sum::<f64>();
    values.sort_by(|a, b| mean_change(a).total_cmp(&mean_change(b)));
    values
}

/// The plan with `additions` flown: on a leg of the plan as an `extra`;
/// on a new heading as a new leg with only the added manoeuvres.
fn add_to_scenario(raw: &mut RawScenario, additions: &[Addition]) {
    let box_ = &mut raw.calibration;
    for addition in additions.iter().flat_map(|a| std::iter::repeat_n(a, a.count)) {
        let heading = addition.heading_deg;
        let leg = box_
            .headings_deg
            .iter()
            .copied()
            .find(|h| angle_apart(*h, heading) < 1.0);
        match leg {
            Some(leg) => {
                // A new leg's first manoeuvre of a kind is its own; the
                // rest of that kind are extras.
                let omitted = format!("{}@{leg}", addition.kind.name());
                match box_.omit.iter().position(|o| *o == omitted) {
                    Some(at) => {
                        box_.omit.remove(at);
                    }
                    None => box_.extra.push(omitted),
                }
            }
            None => {
                box_.headings_deg.push(heading);
                for kind in [ManoeuvreKind::Pitch, ManoeuvreKind::Roll, ManoeuvreKind::Yaw] {
                    if kind != addition.kind {
                        box_.omit.push(format!("{}@{heading}", kind.name()));
                    }
                }
            }
        }
    }
}

/// The summary's sentences on the survey `target`, nT: met as the plan
/// stands, or the cheapest additions that meet it (or come closest) and
/// the channels flown with them.
fn target_summary(report: &PlanReport, target: f64) -> Vec<String> {
    let mut lines = Vec::new();
    let meeting: Vec<&str> = (report.channels.iter())
        .filter(|c| c.meets_survey_target == Some(true))
        .map(|c| c.channel.as_str())
        .collect();
    match (report.additions.is_empty(), report.additions_meet_target) {
        (true, Some(true)) => lines.push(format!(
            "The plan meets the survey target of {target:.3} nT as it stands on {} (a channel whose noise alone exceeds it is warned).",
            match meeting.is_empty() {
                true => "no channel".to_string(),
                false => meeting.join(", "),
            }
        )),
        (true, _) => lines.push(format!(
            "No addition lowers the survey uncertainty towards the target of {target:.3} nT."
        )),
        (false, met) => lines.extend(additions_summary(report, target, met)),
    }
    lines
}

/// The summary's sentences on the additions proposed towards the survey
/// `target`, nT, which they meet or (`met` not `Some(true)`) come closest
/// to, and on the channels flown with them.
fn additions_summary(report: &PlanReport, target: f64, met: Option<bool>) -> Vec<String> {
    let mut lines = Vec::new();
    let list: Vec<String> = (report.additions.iter())
        .map(|a| {
            format!(
                "{} on heading {:.0}{}{} ({:.0} s)",
                a.kind.name(),
                a.heading_deg,
                if a.count > 1 {
                    format!(" ×{}", a.count)
                } else {
                    String::new()
                },
                if a.new_leg { ", a new leg" } else { "" },
                a.cost_s
            )
        })
        .collect();
    let total: f64 = report.additions.iter().map(|a| a.cost_s).sum();
    let verdict = match met {
        Some(true) => "meet",
        _ => "come closest to",
    };
    lines.push(format!(
        "The cheapest additions that {verdict} the survey target of {target:.3} nT: {} ({total:.0} s of flight in all).",
        list.join(", ")
    ));
    for channel in &report.with_additions {
        lines.push(format!(
            "Flown with them, {}: survey uncertainty {}, simulated error {}, FOM {}.",
            channel.channel,
            channel.survey_sigma_nt.words(3),
            channel.survey_error_nt.words(3),
            channel.fom_nt.words(2)
        ));
    }
    lines
}

/// The prediction in a few sentences.
fn summarise(report: &PlanReport) -> Vec<String> {
    let mut lines = vec![format!(
        "{} simulated flights of the plan ({} manoeuvres on headings {}, {:.0} s of calibration); aircraft: {}.",
        report.seeds.len(),
        report.manoeuvres,
        (report.headings_deg.iter())
            .map(|h| format!("{h:.0}"))
            .collect::<Vec<_>>()
            .join(", "),
        report.calibration_s,
        report.installation
    )];
    for channel in &report.channels {
        lines.push(format!(
            "{}: FOM {} after compensation ({} before); survey uncertainty {} (coefficients {:.3} nT, noise {:.3} nT); the simulated survey lines' error {}.",
            channel.channel,
            channel.fom_nt.words(2),
            channel.fom_before_nt.words(1),
            channel.survey_sigma_nt.words(3),
            channel.coefficient_sigma_nt.median,
            channel.noise_nt.median,
            channel.survey_error_nt.words(3),
        ));
    }
    if let Some(target) = report.target_survey_sigma_nt {
        lines.extend(target_summary(report, target));
    }
    lines
}
