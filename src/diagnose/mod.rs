//! Physics discovery: where the Tolles-Lawson model and the recording
//! disagree, which physics was left out, its parameters, and the held-out
//! fit with it modelled.
//!
//! Every figure is a **held-out** in-band RMS: each heading's calibration
//! windows are predicted by a fit on the other headings (leave one heading
//! out), so an extension that only adds freedom does not score.
//!
//! Hypotheses, each a model extension with physical parameters:
//! - `sensor_lag`: the scalar reads the field `lag_s` late; the recording
//!   is read `lag_s` earlier (linear interpolation), the lag found on a
//!   grid and refined to sub-sample resolution by a parabola through the
//!   best three points;
//! - `aux_coupling`: a recorded channel c (every numeric auxiliary column)
//!   drives a body-fixed field, seen by the scalar as
//!   $c\,(k_x u_x + k_y u_y + k_z u_z)$: three regressors; optionally
//!   with $\dot c\,(\dot k_x u_x + \dot k_y u_y + \dot k_z u_z)$ too, the
//!   field of eddy currents a changing current induces nearby (scanned
//!   with each column, and offered again for a column already coupled;
//!   the rate must earn its place by the threshold);
//! - `external_field`: the base station's variation, one regressor;
//! - `eddy_time_constant`: eddy currents that respond through a first-order
//!   lag τ: the nine eddy terms $u_i\,\dot B_j$ are replaced by
//!   $u_i\,L_\tau[\dot B_j]$ with $\tau \dot y + y = x$, τ found on a grid
//!   and refined by a parabola. A scalar lag delays everything the sensor
//!   sees; an eddy time constant delays only the eddy part, so the two
//!   compete on the held-out fit and the better one is named;
//! - `vector_calibration` (per flight, not per channel): the fluxgate's
//!   scale, non-orthogonality and offsets from $|m|$ against the total
//!   field of the scalar with the least aircraft field of its own
//!   ([`crate::calibration::fluxgate`]), held out by heading (each heading's
//!   windows against a calibration fitted on the rest of the flight).
//!   Reported when that mismatch exceeds `vector_mismatch_nt` (200 nT,
//!   0.4 % of the Earth's field: the factory residuals and the aircraft's
//!   field at the fluxgate itself give tens of nT, a 1 % scale error
//!   several hundred) plus three times the reference's own aircraft field
//!   (which a calibration against it would take for fluxgate offsets and
//!   scale errors), and the calibration removes most of it. Each channel's search then starts
//!   from whichever fluxgate reading fits it better held out.
//!
//! Selection is greedy: the candidate that lowers the held-out RMS most is
//! accepted when it lowers it by more than `min_improvement` (30 %), then
//! the search repeats on the extended model. A source must also beat the
//! best of every candidate column shifted in time (see
//! `beats_shifted_sources`), a permutation test of the scan's multiple
//! comparison. The threshold guards the scan too. Unrelated regressors
//! change a held-out RMS by under 1 %, but a channel that follows the
//! manoeuvres (a servo current, the trim tab) can stand in for structured
//! residual it did not cause. Such a stand-in borrows only the manoeuvres'
//! timing, so it explains part of that residual, while a real effect
//! explains most of it: the threshold sits between the two (measured
//! figures: docs/measurements.md, section diagnose).
//!
//! What is left is localised ([`localise`]): per manoeuvre, per sub-band
//! against the noise floor, in structured stretches, and by coherence with
//! every auxiliary column; structured residual in two manoeuvres or more
//! becomes an `unexplained` finding.
//!
//! Control: the best few candidates are also scored with the total
//! field's second-order term added (a large aircraft field's part across
//! the Earth's, $|F_\perp|^2 / 2|B|$, computed from the fitted permanent
//! and induced coefficients, so it adds no parameter; see
//! [`crate::model`]), against the current model with the same term;
//! each side keeps it only where it lowers its held-out RMS. An effect is
//! accepted only if it still pays then, so a channel standing in for the
//! second-order residual is rejected. Where the aircraft's field is large
//! (a cabin sensor), the term can be nearly all that the first-order model
//! leaves in the band (measured figures: docs/measurements.md, section
//! diagnose).
//!
//! Start: λ is picked by the pipeline's criterion (blocked PRESS by
//! default) or by the other one, whichever predicts the held-out headings
//! better for the channel; the diagnosed model carries the choice
//! (see `criterion_trial`).
//!
//! Layout: this module holds the entry points and DIAGNOSIS.json's types;
//! `heldout` the leave-one-heading-out scoring, `search` the greedy search
//! and its candidates, `shifted` the shifted-source guard, `fluxgate` the
//! fluxgate check, `finding` the findings in words, [`localise`] where the
//! residual is.

mod cross;
mod effect;
pub mod evidence;
mod finding;
mod fluxgate;
mod heldout;
pub mod localise;
mod screen;
mod search;
mod shifted;
mod survey;

use finding::*;
use fluxgate::*;
use heldout::*;
use search::*;
use shifted::*;

pub use effect::{
    AuxCoupling, CrossSensor, EddyTimeConstant, Effect, EffectKind, ExternalField, FluxgateErrors, SecondOrder,
    SensorLag, SurveyEvidence, Unexplained, SURVEY_CROSS_GAIN,
};
pub use finding::AppliedFinding;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use std::borrow::Cow;
use std::collections::BTreeMap;

use crate::calibration::fluxgate::{calibrate, calibrate_near, VectorCalibration};
use crate::calibration::headings::{distinct_headings, heading_splits};
use crate::calibration::windows::CalibrationWindow;
use crate::error::Result;
use crate::ingest::flight_log::{ChannelRole, FlightLog, VectorSensor};
use crate::messages::progress::{Meter, Silent, Stage};
use crate::messages::{Diagnosing, Note};
use crate::model::terms::TermSet;
use crate::model::{
    column_level, field_directions, fit, Calibration, Extensions, FitOptions, FittedModel, ModelSpec, Prepared,
    SourceTerm, WindowFit,
};
use crate::numerics::solve::{Criterion, Figures, LambdaChoice, SolveOptions};
use crate::numerics::stacked::StorePool;
use crate::quality::root_mean_square;

/// `[diagnose]` settings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DiagnoseOptions {
    /// Smallest relative drop of the held-out RMS that accepts an effect.
    pub min_improvement: f64,
    /// Largest lag searched, s (both signs).
    pub max_lag_s: f64,
    /// Most effects accepted per channel.
    pub max_findings: usize,
    /// Held-out RMS of $|B_{fluxgate}| - F$ above which the fluxgate's
    /// calibration is reported, nT.
    pub vector_mismatch_nt: f64,
    /// Whether `run` and `compensate` diagnose each flight first and fit
    /// and compensate every channel with the model its findings make.
    pub apply: ApplyDiagnosis,
    /// Whether a `cross_sensor` finding is applied or only reported.
    pub cross_sensor: CrossSensorUse,
}

/// `[diagnose] cross_sensor`: what the compensation does with a
/// `cross_sensor` finding.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CrossSensorUse {
    /// Found, held out and reported, never applied: on clean simulated
    /// flights, where no source on board causes it, two cabin sensors'
    /// shared residual still stood in for a source on 5 of 1,344 channels
    /// on the box alone.
    Report,
    /// A fluxgate's magnitude less another scalar whose gain the survey
    /// lines fit, each line held out (the diagnosis's last step,
    /// `src/diagnose/survey.rs`), applied where it takes a
    /// quarter or more of the channel's difference from the quietest
    /// scalar and keeps the lines' levels at the crossovers; the signals
    /// fitted on the box reported (the default).
    SurveyFitted,
    /// As `SurveyFitted`, with the differences of two scalars fitted too,
    /// and a box-fitted signal applied where the survey bears it out
    /// ([`SurveyEvidence::holds`]); a signal the box held out too weakly
    /// becomes a finding where the survey bears it out. On 35 of 1,344
    /// clean channels the box-fitted ones were applied (none harmed
    /// against the truth, 32 helped by more than 10 %: the term takes a
    /// residual the sensors share out, but names a source that is not
    /// there).
    Survey,
    /// Applied under the evidence rule like any other finding.
    Apply,
}

/// `[diagnose] apply`: whether `run` and `compensate` use the diagnosis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", try_from = "ApplySetting")]
pub enum ApplyDiagnosis {
    /// Diagnose every flight and fit with the findings that pass the
    /// held-out test and the permutation guard; a flight whose calibration
    /// cannot be diagnosed is compensated with plain Tolles-Lawson, with a
    /// warning saying why (the default).
    Auto,
    /// Plain Tolles-Lawson only (`--plain`).
    Never,
    /// Diagnose every flight and fit with its findings; a flight that
    /// cannot be diagnosed is an error.
    Always,
}

/// `apply` as written: `"auto"`, `"never"`, `"always"`, or the booleans of
/// earlier versions (`true` = `"always"`, `false` = `"never"`).
#[derive(Deserialize)]
#[serde(untagged)]
enum ApplySetting {
    Flag(bool),
    Word(String),
}

impl TryFrom<ApplySetting> for ApplyDiagnosis {
    type Error = String;

    fn try_from(setting: ApplySetting) -> std::result::Result<Self, String> {
        match setting {
            ApplySetting::Flag(true) => Ok(ApplyDiagnosis::Always),
            ApplySetting::Flag(false) => Ok(ApplyDiagnosis::Never),
            ApplySetting::Word(word) => match word.as_str() {
                "auto" => Ok(ApplyDiagnosis::Auto),
                "never" => Ok(ApplyDiagnosis::Never),
                "always" => Ok(ApplyDiagnosis::Always),
                other => Err(format!(
                    "[diagnose] apply = \"{other}\": use \"auto\" (the default), \"never\" or \"always\""
                )),
            },
        }
    }
}

impl Default for DiagnoseOptions {
    fn default() -> Self {
        DiagnoseOptions {
            min_improvement: 0.3,
            max_lag_s: 0.5,
            max_findings: 3,
            vector_mismatch_nt: 200.0,
            apply: ApplyDiagnosis::Auto,
            cross_sensor: CrossSensorUse::SurveyFitted,
        }
    }
}

/// A window where a finding matters.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Located {
    /// Start, flight time.
    pub t_start: f64,
    /// End, flight time.
    pub t_end: f64,
    /// Manoeuvre and heading.
    pub label: String,
}

/// One discovered effect (CONTRACT §3).
#[derive(Debug, Clone, PartialEq)]
pub struct Finding {
    /// The effect and its physical parameters; DIAGNOSIS.json writes them
    /// as `effect` (the CONTRACT §3 name) and `parameters` (`lag_s`,
    /// `k_x_nt_per_unit`, ...).
    pub effect: Effect,
    /// Scalar channel.
    pub channel: String,
    /// The column that drives it, when one does.
    pub source: Option<String>,
    /// One or two plain sentences of physics.
    pub explanation: String,
    /// The windows it improves most.
    pub located: Vec<Located>,
    /// Held-out RMS before this effect was modelled, nT.
    pub heldout_rms_before_nt: f64,
    /// Held-out RMS after, nT.
    pub heldout_rms_after_nt: f64,
    /// Why the finding, though it passed the held-out test, was not
    /// applied to the compensation (the evidence rule,
    /// [`evidence`]); `None` when applied or never meant to be.
    pub not_applied: Option<String>,
    /// How the channel's compensation with this finding applied scales a
    /// crustal anomaly on the survey ([`crate::model::AnomalyGain`]'s
    /// median); set once the finding is applied, written as
    /// `parameters.anomaly_gain`.
    pub anomaly_gain: Option<f64>,
}

impl Serialize for Finding {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> std::result::Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut finding = serializer.serialize_struct("Finding", 10)?;
        finding.serialize_field("effect", &self.effect.kind())?;
        finding.serialize_field("channel", &self.channel)?;
        match &self.source {
            Some(source) => finding.serialize_field("source", source)?,
            None => finding.skip_field("source")?,
        }
        let mut parameters = self.effect.parameters();
        if let Some(gain) = self.anomaly_gain {
            parameters.insert("anomaly_gain".into(), gain);
        }
        finding.serialize_field("parameters", &parameters)?;
        finding.serialize_field("explanation", &self.explanation)?;
        finding.serialize_field("located", &self.located)?;
        finding.serialize_field("heldout_rms_before_nt", &self.heldout_rms_before_nt)?;
        finding.serialize_field("heldout_rms_after_nt", &self.heldout_rms_after_nt)?;
        match &self.not_applied {
            Some(reason) => {
                finding.serialize_field("applied", &false)?;
                finding.serialize_field("reason", reason)?;
            }
            None => {
                finding.skip_field("applied")?;
                finding.skip_field("reason")?;
            }
        }
        finding.end()
    }
}

/// Held-out figures of one channel.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChannelDiagnosis {
    /// Scalar channel.
    pub channel: String,
    /// Plain Tolles-Lawson, held out, nT.
    pub heldout_rms_baseline_nt: f64,
    /// Tolles-Lawson with the total field's second-order term, held out,
    /// nT: the control every effect is also scored against.
    pub heldout_rms_second_order_nt: f64,
    /// With every accepted effect, held out, nT, λ picked as the pipeline
    /// picks it.
    pub heldout_rms_final_nt: f64,
    /// The best candidate that fell short of the threshold, and its
    /// held-out RMS: what the data hint at without proving.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub strongest_rejected: Option<String>,
    /// Plain Tolles-Lawson on the calibrated fluxgate, held out, nT; only
    /// when the flight has a `vector_calibration` finding.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heldout_rms_calibrated_fluxgate_nt: Option<f64>,
    /// Plain Tolles-Lawson with λ picked by the other criterion (PRESS
    /// when the pipeline uses blocked PRESS, and the reverse), held out,
    /// nT; absent when λ is fixed. The search starts from the better one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heldout_rms_other_criterion_nt: Option<f64>,
    /// The statistic that picked λ where the search started (the held-out
    /// RMS before the first finding is with it). The diagnosed model keeps
    /// the pipeline's.
    pub search_criterion: Criterion,
    /// Which fluxgate reading the search used.
    pub fluxgate: FluxgateReading,
    /// The model the findings make: what `compensate --diagnosis` and the
    /// pipeline's `[diagnose] apply` fit and compensate with.
    pub model: Extensions,
    /// Where the held-out residual is: per manoeuvre, per sub-band against
    /// the noise floor, structured stretches, coherent columns.
    #[serde(flatten)]
    pub localisation: localise::Localisation,
}

/// Which fluxgate reading a channel's diagnosis used.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FluxgateReading {
    /// As recorded.
    Raw,
    /// With the fluxgate check's calibration, which fitted better held out.
    Calibrated,
}

/// DIAGNOSIS.json.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Diagnosis {
    /// The flight diagnosed: a saved diagnosis is applied to it alone.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub flight: Option<crate::ingest::flight_identity::FlightIdentity>,
    /// Per channel.
    pub channels: Vec<ChannelDiagnosis>,
    /// Accepted effects.
    pub findings: Vec<Finding>,
    /// The fluxgate against the scalar total field: its calibration and
    /// the held-out mismatch before and after.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fluxgate: Option<FluxgateCheck>,
    /// What could not be checked, and checks that found nothing.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<Note>,
}

impl Diagnosis {
    /// Each channel's diagnosed model.
    pub fn models(&self) -> BTreeMap<String, Extensions> {
        self.channels
            .iter()
            .map(|c| (c.channel.clone(), c.model.clone()))
            .collect()
    }
}

/// A DIAGNOSIS.json as read back: the flight it was made on and each
/// channel's diagnosed model.
#[derive(Debug, Clone, PartialEq)]
pub struct SavedDiagnosis {
    /// The flight diagnosed (absent in files of older versions).
    pub flight: Option<crate::ingest::flight_identity::FlightIdentity>,
    /// Each channel's diagnosed model.
    pub models: BTreeMap<String, Extensions>,
}

impl SavedDiagnosis {
    /// The models, after checking that the diagnosis was made on `log`:
    /// a diagnosis of another flight is an error unless `force`. Also
    /// returns a remark for the user when the check could not be made or
    /// was overridden.
    pub fn models_for(
        self,
        path: &std::path::Path,
        log: &FlightLog,
        force: bool,
    ) -> Result<(BTreeMap<String, Extensions>, Option<crate::messages::Warning>)> {
        let Some(made_on) = &self.flight else {
            let remark = crate::messages::Warning::DiagnosisUnchecked {
                diagnosis: path.to_path_buf(),
                flight: log.source().to_path_buf(),
            };
            return Ok((self.models, Some(remark)));
        };
        let applied_to = crate::ingest::flight_identity::FlightIdentity::of(log)?;
        let Some(difference) = made_on.difference(&applied_to) else {
            return Ok((self.models, None));
        };
        if !force {
            return Err(crate::Error::OtherFlight {
                path: path.to_path_buf(),
                what: "this diagnosis",
                made_on: made_on.describe(),
                applied_to: applied_to.describe(),
                difference,
            });
        }
        let remark = crate::messages::Warning::DiagnosisForced {
            diagnosis: path.to_path_buf(),
            made_on: made_on.describe(),
            applied_to: applied_to.describe(),
            difference,
        };
        Ok((self.models, Some(remark)))
    }
}

/// The diagnosed model of each channel in a DIAGNOSIS.json, with the
/// flight it was made on.
pub fn read_saved(path: &std::path::Path) -> Result<SavedDiagnosis> {
    #[derive(Deserialize)]
    struct File {
        #[serde(default)]
        flight: Option<crate::ingest::flight_identity::FlightIdentity>,
        channels: Vec<Entry>,
    }
    #[derive(Deserialize)]
    struct Entry {
        channel: String,
        #[serde(default)]
        model: Extensions,
    }
    let text = crate::ingest::read_text(path).map_err(|e| crate::Error::io(path, "reading", e))?;
    let file: File = serde_json::from_str(&text).map_err(|e| crate::Error::NotOurFile {
        path: path.to_path_buf(),
        expected: "a DIAGNOSIS.json as `magcomp diagnose` writes it",
        problem: e.to_string(),
        hint: "Diagnose the flight again.",
    })?;
    Ok(SavedDiagnosis {
        flight: file.flight,
        models: file.channels.into_iter().map(|e| (e.channel, e.model)).collect(),
    })
}

/// The fluxgate's magnitude against the quietest scalar channel.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FluxgateCheck {
    /// The calibration fitted on the whole flight.
    pub calibration: VectorCalibration,
    /// RMS of $|m| - F$ on the calibration windows of each heading, the
    /// calibration fitted on the rest of the flight, nT.
    pub heldout_mismatch_before_nt: f64,
    /// RMS of $|C(m - o)| - F$ there, nT.
    pub heldout_mismatch_after_nt: f64,
    /// The three windows where the uncalibrated mismatch is largest.
    pub located: Vec<Located>,
    /// The reference's own aircraft field over the calibration windows
    /// (standard deviation of plain Tolles-Lawson's predicted
    /// interference), nT.
    pub reference_interference_nt: f64,
    /// The held-out mismatch a finding needs: `vector_mismatch_nt` plus
    /// three times the reference's own aircraft field, nT.
    pub threshold_nt: f64,
}

/// A model extension under test.
#[derive(Debug, Clone, PartialEq)]
enum Extension {
    Lag {
        lag_s: f64,
    },
    Eddy {
        tau_s: f64,
    },
    Coupling {
        source: String,
    },
    /// The rate of change of a column already coupled.
    CouplingRate {
        source: String,
    },
    /// A column and its rate of change together.
    CouplingWithRate {
        source: String,
    },
    External {
        source: String,
    },
    /// The total field's second-order term.
    SecondOrder,
}

/// The model under test: plain Tolles-Lawson with the physics accepted
/// so far.
type Model = Extensions;

/// The same model with the total field's second-order term: the control
/// every effect must beat.
fn with_second_order(model: &Model) -> Model {
    Model {
        second_order: true,
        ..model.clone()
    }
}

/// Most candidates (best first) checked against the second-order control
/// in one step of the search.
const CONTROL_CHECKS: usize = 4;

/// Leading candidates also scored with λ picked by the other criterion.
const CRITERION_CHECKS: usize = 8;

/// The data one channel's diagnosis works on.
struct Problem<'a> {
    log: &'a FlightLog,
    sensor: &'a VectorSensor,
    channel: &'a str,
    windows: &'a [CalibrationWindow],
    /// The Tolles-Lawson terms every model under test has.
    terms: TermSet,
    options: &'a FitOptions,
    /// Unit field direction u_x, u_y, u_z per row.
    direction: &'a [Vec<f64>; 3],
    /// The candidate source columns (auxiliary and base station, mostly
    /// recorded) and the level each is taken about.
    levels: &'a BTreeMap<String, f64>,
    /// Stores of finished fits, shared by every fit of the diagnosis.
    stores: &'a StorePool,
    /// The flight's scalar channels, least aircraft field first (empty
    /// where they were not ranked): the quiet scalars a cross-sensor
    /// signal is judged against on the survey.
    quietest: &'a [String],
    /// The recipe of each synthetic cross-sensor column, by its name.
    signals: &'a BTreeMap<String, crate::model::cross_sensor::CrossSignal>,
}

/// Where a channel's search starts: plain Tolles-Lawson held out, with λ
/// by the pipeline's criterion and by the other.
struct ChannelStart {
    /// Held-out RMS of plain Tolles-Lawson by the pipeline's criterion, nT.
    raw_rms: f64,
    /// The same by the other criterion, when it could be measured, nT.
    other_rms: Option<f64>,
    /// The model the search starts from (plain, λ by whichever criterion
    /// predicts the held-out headings better).
    start_model: Model,
    /// Its held-out figures.
    raw: HeldOut,
}

/// The start of `problem`'s search ([`ChannelStart`]), or why the channel
/// cannot be diagnosed.
fn channel_start(problem: &Problem) -> Result<std::result::Result<ChannelStart, String>> {
    let raw = held_out(problem, &Model::default())?;
    if let Some(why) = raw.unusable() {
        return Ok(Err(format!(
            "{}: not diagnosed: {why}, so no effect can be measured against it",
            problem.channel
        )));
    }
    let raw_rms = raw.rms_nt;
    // λ by the other criterion: the search starts from whichever predicts
    // the held-out headings better (see `criterion_trial`).
    let other = criterion_trial(problem)?;
    let other_rms = other.as_ref().map(|(_, h)| h.rms_nt);
    let (start_model, raw) = match other {
        Some((model, h)) if h.rms_nt < raw.rms_nt => (model, h),
        _ => (Model::default(), raw),
    };
    Ok(Ok(ChannelStart {
        raw_rms,
        other_rms,
        start_model,
        raw,
    }))
}

/// Diagnoses every channel on its calibration windows, starting from
/// plain Tolles-Lawson on `terms`.
pub fn diagnose(
    calibration: &Calibration,
    terms: &TermSet,
    options: &FitOptions,
    settings: &DiagnoseOptions,
) -> Result<Diagnosis> {
    diagnose_metered(calibration, (terms, options, settings), &Silent)
}

/// [`diagnose`], telling `meter` of two steps a channel: its plain fits
/// held out, then its search.
pub fn diagnose_metered(
    calibration: &Calibration,
    (terms, options, settings): (&TermSet, &FitOptions, &DiagnoseOptions),
    meter: &dyn Meter,
) -> Result<Diagnosis> {
    let Calibration {
        log,
        sensor,
        channels,
        windows,
    } = *calibration;
    let hold_out = HoldOut::of(windows);
    if let Some(problem) = hold_out.insufficient() {
        return Err(not_enough_calibration(log, problem));
    }
    meter.begin(Stage::Diagnosing, 2 * channels.len() as u64);
    // The fluxgate is judged against the scalar channel with the least
    // aircraft field of its own, and the threshold grows with what is
    // left: a cabin sensor's hundreds of nT would otherwise count as
    // fluxgate offsets. Other sensors' geology-free signals are source columns.
    let stores = StorePool::new();
    let cross = cross::prepare(calibration, (terms, options), &stores)?;
    let (log, all_levels) = (&cross.log, source_levels(&cross.log));
    let raw_direction = field_directions(log, sensor);
    let levels = cross.levels_by_channel(channels, &all_levels);
    let problem = |channel, log, direction| Problem {
        log,
        sensor,
        channel,
        windows,
        terms: *terms,
        options,
        direction,
        levels: levels.get(channel).unwrap_or(&all_levels),
        stores: &stores,
        quietest: &cross.quietest,
        signals: &cross.signals,
    };
    // The fluxgate check and each channel's plain fits held out (by
    // either λ criterion) do not need each other: side by side.
    let ranked = (&stores, cross.ranked.as_deref());
    let (checked, starts) = rayon::join(
        || fluxgate_check(calibration, (terms, options), ranked, settings),
        || {
            channels
                .par_iter()
                .map(|channel| {
                    let start = channel_start(&problem(channel, log, &raw_direction));
                    meter.step();
                    start
                })
                .collect::<Result<Vec<_>>>()
        },
    );
    let (fluxgate, mut notes) = checked_or_said(checked);
    notes.extend(hold_out.caveat());
    // The calibrated fluxgate is tried only once its finding stands.
    let calibrated = calibrated_flight(fluxgate.as_ref(), settings, (log, sensor))?;
    let on_calibrated = calibrated.as_ref().map(|(l, d)| (l, d));
    let fluxgate_calibration = fluxgate.as_ref().map(|check| &check.calibration);
    let search = |k: usize, start: ChannelStart| {
        let channel = &channels[k];
        let raw = problem(channel, log, &raw_direction);
        let calibrated = on_calibrated.map(|(l, d)| problem(channel, l, d));
        diagnose_from(start, (raw, calibrated), fluxgate_calibration, settings)
    };
    let results = search_each(starts?, &search, meter)?;
    let (channel_results, findings, untestable) = cross.named(searched_channels(log, results)?);
    notes.extend(untestable);
    notes.extend(criterion_notes(&channel_results, options));
    let searched = (channel_results, findings, notes);
    Ok(with_fluxgate(searched, fluxgate, calibrated.is_some(), settings))
}

/// Each channel's search (`search`, given the channel's index) from its
/// start, side by side; a channel whose start failed keeps why. `meter`
/// hears each channel done.
fn search_each(
    starts: Vec<std::result::Result<ChannelStart, String>>,
    search: &(dyn Fn(usize, ChannelStart) -> Result<(ChannelDiagnosis, Vec<Finding>)> + Sync),
    meter: &dyn Meter,
) -> Result<Vec<Searched>> {
    (starts.into_par_iter().enumerate())
        .map(|(k, start)| {
            let searched = match start {
                Ok(start) => search(k, start).map(Ok),
                Err(why) => Ok(Err(why)),
            };
            meter.step();
            searched
        })
        .collect()
}

/// The flight with the fluxgate calibrated by the check's calibration,
/// and its field directions, when its mismatch finding stands.
fn calibrated_flight(
    fluxgate: Option<&FluxgateCheck>,
    settings: &DiagnoseOptions,
    (log, sensor): (&FlightLog, &VectorSensor),
) -> Result<Option<(FlightLog, [Vec<f64>; 3])>> {
    let Some(check) = fluxgate.filter(|check| mismatch_stands(check, settings)) else {
        return Ok(None);
    };
    let calibrated = check.calibration.apply(log, sensor)?;
    let directions = field_directions(&calibrated, sensor);
    Ok(Some((calibrated, directions)))
}

/// The fluxgate's check, or a note saying why it was not made.
fn checked_or_said(checked: std::result::Result<FluxgateCheck, String>) -> (Option<FluxgateCheck>, Vec<Note>) {
    match checked {
        Ok(check) => (Some(check), Vec::new()),
        Err(reason) => (None, vec![Diagnosing::FluxgateNotChecked { reason }.into()]),
    }
}

/// The fluxgate checked against the scalar channel with the least
/// aircraft field of its own; why not, when it cannot be.
fn fluxgate_check(
    calibration: &Calibration,
    (terms, options): (&TermSet, &FitOptions),
    (stores, ranked): (&StorePool, Option<&[(String, f64)]>),
    settings: &DiagnoseOptions,
) -> std::result::Result<FluxgateCheck, String> {
    let Calibration {
        log, sensor, windows, ..
    } = *calibration;
    // The channels' ranking the cross-sensor columns made, where they made
    // one: the same plain fits, not fitted again.
    let quietest = match ranked.and_then(|r| r.first()) {
        Some(first) => Ok(first.clone()),
        None => quietest_reference(calibration, (terms, options), stores),
    };
    quietest
        .map_err(|e| e.to_string())
        .and_then(|(reference, interference_nt)| {
            check_fluxgate(log, sensor, &reference, windows, interference_nt, settings)
        })
}

/// The diagnosis of the channels' results with the fluxgate's: its finding
/// first where it stands (`calibrated`: the search ran on the calibrated
/// fluxgate), else a note of its figures.
fn with_fluxgate(
    (channels, findings, mut notes): (Vec<ChannelDiagnosis>, Vec<Vec<Finding>>, Vec<Note>),
    fluxgate: Option<FluxgateCheck>,
    calibrated: bool,
    settings: &DiagnoseOptions,
) -> Diagnosis {
    let fluxgate_found = fluxgate
        .as_ref()
        .filter(|_| calibrated)
        .map(|check| fluxgate_finding(check, &channels));
    let findings = fluxgate_found
        .into_iter()
        .chain(findings.into_iter().flatten())
        .collect();
    if let Some(check) = fluxgate.as_ref().filter(|_| !calibrated) {
        notes.push(fluxgate_note(check, settings));
    }
    Diagnosis {
        flight: None,
        channels,
        findings,
        fluxgate,
        notes,
    }
}

/// One channel's search: its summary and findings, or why its calibration
/// cannot be tested.
type Searched = std::result::Result<(ChannelDiagnosis, Vec<Finding>), String>;

/// The channels' summaries and findings, and a note for each channel that
/// could not be tested; an error when none could.
#[allow(clippy::type_complexity)]
fn searched_channels(
    log: &FlightLog,
    results: Vec<Searched>,
) -> Result<(Vec<ChannelDiagnosis>, Vec<Vec<Finding>>, Vec<Note>)> {
    let (results, untestable): (Vec<_>, Vec<_>) = results.into_iter().partition(|r| r.is_ok());
    let untestable: Vec<String> = untestable.into_iter().filter_map(|r| r.err()).collect();
    if results.is_empty() {
        return Err(not_enough_calibration(log, untestable.join("; ")));
    }
    let results: Vec<(ChannelDiagnosis, Vec<Finding>)> = results.into_iter().filter_map(|r| r.ok()).collect();
    let (channel_results, findings): (Vec<_>, Vec<_>) = results.into_iter().unzip();
    let untestable = (untestable.into_iter())
        .map(|reason| Diagnosing::ChannelNotTested { reason }.into())
        .collect();
    Ok((channel_results, findings, untestable))
}

/// One channel's diagnosis from its plain start: the search runs on the
/// calibrated fluxgate (`calibrated`) where plain Tolles-Lawson fits better
/// held out there, else on the raw one, and its figures are set beside
/// plain's.
fn diagnose_from(
    start: ChannelStart,
    (raw_problem, calibrated): (Problem, Option<Problem>),
    fluxgate: Option<&VectorCalibration>,
    settings: &DiagnoseOptions,
) -> Result<(ChannelDiagnosis, Vec<Finding>)> {
    let ChannelStart {
        raw_rms,
        other_rms,
        start_model,
        raw,
    } = start;
    // Plain Tolles-Lawson on the calibrated fluxgate; the search starts
    // from it where it fits better held out.
    let alternative = calibrated.and_then(|p| held_out(&p, &start_model).ok().map(|h| (p, h)));
    let calibrated_rms = alternative.as_ref().map(|(_, h)| h.rms_nt);
    let (chosen, start, label) = match alternative {
        Some((p, h)) if h.rms_nt < raw.rms_nt => (p, h, FluxgateReading::Calibrated),
        _ => (raw_problem, raw, FluxgateReading::Raw),
    };
    let (mut summary, mut found) = diagnose_channel(&chosen, start_model, start, settings)?;
    // The model compensation uses keeps the pipeline's criterion: the
    // in-band held-out RMS says nothing of what a less regularised fit
    // does outside the band (see `criterion_trial`).
    if summary.model.lambda_criterion.take().is_some() {
        summary.heldout_rms_final_nt = held_out(&chosen, &summary.model)?.rms_nt;
    }
    // Last, on the model compensation uses: a signal the survey fits.
    // The signals are made from the recorded fluxgate.
    if settings.cross_sensor != CrossSensorUse::Report && label == FluxgateReading::Raw {
        let scalars = settings.cross_sensor != CrossSensorUse::SurveyFitted;
        if let Some(fitted) = survey::survey_fitted(&chosen, &summary.model, scalars)? {
            let after_nt = held_out(&chosen, &fitted.model)?.rms_nt;
            found.push(survey::fitted_finding(
                &chosen,
                &fitted,
                (summary.heldout_rms_final_nt, after_nt),
            ));
            summary.model = fitted.model;
        }
    }
    summary.heldout_rms_baseline_nt = raw_rms;
    summary.heldout_rms_calibrated_fluxgate_nt = calibrated_rms;
    summary.heldout_rms_other_criterion_nt = other_rms;
    summary.fluxgate = label;
    if label == FluxgateReading::Calibrated {
        summary.model.vector_calibration = fluxgate.cloned();
    }
    Ok((summary, found))
}

/// A note for each channel whose search used the other λ criterion.
fn criterion_notes(channel_results: &[ChannelDiagnosis], options: &FitOptions) -> Vec<Note> {
    let mut notes = Vec::new();
    for c in channel_results {
        if let (true, Some(other_nt)) = (
            c.search_criterion != options.solve.criterion,
            c.heldout_rms_other_criterion_nt,
        ) {
            notes.push(
                Diagnosing::OtherCriterion {
                    channel: c.channel.clone(),
                    searched_by: c.search_criterion.describe().into(),
                    kept: options.solve.criterion.describe().into(),
                    baseline_nt: c.heldout_rms_baseline_nt,
                    other_nt,
                    final_nt: c.heldout_rms_final_nt,
                }
                .into(),
            );
        }
    }
    notes
}

/// The fluxgate check's figures, when its finding does not stand.
fn fluxgate_note(check: &FluxgateCheck, settings: &DiagnoseOptions) -> Note {
    Diagnosing::FluxgateMismatchShort {
        sensor: check.calibration.sensor.clone(),
        reference: check.calibration.reference.clone(),
        reference_interference_nt: check.reference_interference_nt,
        before_nt: check.heldout_mismatch_before_nt,
        after_nt: check.heldout_mismatch_after_nt,
        threshold_nt: check.threshold_nt,
        least_nt: settings.vector_mismatch_nt,
    }
    .into()
}

/// The held-out in-band RMS of `spec` on `channel`, nT, scored as the
/// diagnosis scores its candidates (each heading predicted by a fit on the
/// others): how a model of the user's own, or the truth of a simulated
/// flight, compares with the diagnosed one.
pub fn heldout_rms(
    log: &FlightLog,
    sensor: &VectorSensor,
    channel: &str,
    windows: &[CalibrationWindow],
    spec: &ModelSpec,
    options: &FitOptions,
) -> Result<f64> {
    let model = &spec.extensions;
    let calibrated = match &model.vector_calibration {
        Some(calibration) => Cow::Owned(calibration.apply(log, sensor)?),
        None => Cow::Borrowed(log),
    };
    let direction = field_directions(&calibrated, sensor);
    let levels = source_levels(&calibrated);
    let problem = Problem {
        log: &calibrated,
        sensor,
        channel,
        windows,
        terms: spec.terms,
        options,
        direction: &direction,
        levels: &levels,
        stores: &StorePool::new(),
        quietest: &[],
        signals: &BTreeMap::new(),
    };
    let uncalibrated = Model {
        vector_calibration: None,
        ..model.clone()
    };
    Ok(held_out(&problem, &uncalibrated)?.rms_nt)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A simulated box and line to score candidates on in unit tests.
    pub(in crate::diagnose) struct TestFlight {
        pub(in crate::diagnose) log: FlightLog,
        pub(in crate::diagnose) windows: Vec<CalibrationWindow>,
        sensor: VectorSensor,
        direction: [Vec<f64>; 3],
        pub(in crate::diagnose) levels: BTreeMap<String, f64>,
        options: FitOptions,
        stores: StorePool,
    }

    impl TestFlight {
        /// The simulator's one-line flight with a tail sensor, with `extra`
        /// auxiliary columns (name, period in s: 3 + sin(t / period)), and
        /// its detected windows.
        pub(in crate::diagnose) fn new(extra: &[(&str, f64)]) -> Self {
            use crate::ingest::flight_log::Channel;
            use crate::simulate::scenario::{RawScenario, Scenario};
            let raw: RawScenario = toml::from_str("[survey]\nline_count = 1\nline_length_m = 3000.0\n").unwrap();
            let flight = crate::simulate::simulate(&Scenario::try_from(raw).unwrap()).unwrap();
            let mut channels = flight.log.channels().to_vec();
            for &(name, period) in extra {
                channels.push(Channel {
                    name: name.into(),
                    role: ChannelRole::Auxiliary,
                    values: flight.log.time_s().iter().map(|t| 3.0 + (t / period).sin()).collect(),
                });
            }
            let time = flight.log.time_s().to_vec();
            let log = FlightLog::new(flight.log.source(), flight.log.time_column(), time, channels).unwrap();
            let windows = crate::calibration::detect::detect_manoeuvres(&log, &Default::default())
                .unwrap()
                .calibration_windows(1.0);
            let sensor = log.vector_sensor("flux_a").unwrap();
            let direction = field_directions(&log, &sensor);
            let levels = source_levels(&log);
            TestFlight {
                log,
                windows,
                sensor,
                direction,
                levels,
                options: FitOptions::default(),
                stores: StorePool::new(),
            }
        }

        /// The problem of channel mag_1_uc on it, on the default terms.
        pub(in crate::diagnose) fn problem(&self) -> Problem<'_> {
            Problem {
                log: &self.log,
                sensor: &self.sensor,
                channel: "mag_1_uc",
                windows: &self.windows,
                terms: TermSet::default(),
                options: &self.options,
                direction: &self.direction,
                levels: &self.levels,
                stores: &self.stores,
                quietest: &[],
                signals: &super::cross::NO_SIGNALS,
            }
        }
    }
}
