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

mod additions;
mod file;
mod realise;
mod summary;
mod warnings;

use std::collections::BTreeMap;
use std::path::PathBuf;

use serde::Serialize;

use crate::calibration::windows::ManoeuvreKind;
use crate::config::Settings;
use crate::error::Result;

pub use crate::quality::against_plan::STATED_FACTOR;
pub use file::{Plan, PlanSettings};
pub use realise::error_from_calibration_level;

use additions::propose;
use realise::{median_of, predictions, realise_all};
use summary::summarise;
use warnings::channel_warnings;

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
    pub warnings: Vec<crate::messages::PlanWarning>,
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
        warnings.push(crate::messages::PlanWarning::TargetNotMet {
            most_additions: plan.settings.most_additions,
            target_nt: target_survey.unwrap_or(f64::NAN),
        });
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
