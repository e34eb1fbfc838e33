//! What a run says to its user: typed warnings and notes.
//!
//! A [`Warning`] is something the user must look at before trusting an
//! output: a finding held back, a channel's survey moved beyond its stated
//! uncertainty, a figure that could not be computed. Each variant carries
//! its data, and its `Display` is the sentence printed on stdout, in the
//! report and in the quality JSON (serialised as that sentence, so the
//! JSON reads as it always has). Tests match the variants, not the words.
//!
//! The stages typed so far: the box's detection, the fit's own (the
//! diagnosis's evidence rule and its unexplained residual, the departure
//! from plain Tolles-Lawson, the uncertainty and the sigma column, the box
//! and the solver), the quality figures, the output's range, the vector
//! and gradient stages, and the run's inputs and outputs (windows from
//! another flight, an undated MCAP output, text columns not written), the
//! comparison with a flight plan, a saved model's or diagnosis's words,
//! and what reading a flight log lost or doubts ([`reading::Reading`]).
//!
//! A [`Note`] is what the user may want to know (how a column was named,
//! which model a channel was fitted with, an analysis not made, what
//! detection found, the flight against its plan); it is printed with `-v`
//! and kept in the quality JSON and the report, and typed the same way
//! (the diagnosis's in [`diagnosis::Diagnosing`], a vector model's
//! figures in [`vector::VectorSummary`], how an MCAP file was read in
//! [`reading::ReadNote`]). Before any flight is processed, a run's setup
//! (the output folders it made, what reading a campaign decided about its
//! flights) says what it did in [`setup::Setup`].
//!
//! While a flight is processed it also says how far it has got: a
//! [`progress::Meter`] hears each stage begin and each step of it done.

use std::fmt;

use serde::{Serialize, Serializer};

pub mod diagnosis;
pub mod plan;
pub mod progress;
pub mod reading;
pub mod setup;
pub mod vector;
pub use diagnosis::Diagnosing;
pub use plan::PlanWarning;
pub use reading::{ReadNote, Reading};
pub use setup::Setup;
pub use vector::VectorSummary;

/// Why a channel's diagnosed findings are held back by the evidence rule.
#[derive(Debug, Clone, PartialEq)]
pub enum HeldBack {
    /// With λ picked as compensation picks it, the findings do not lower
    /// the held-out RMS of plain Tolles-Lawson.
    NoGainHeldOut {
        /// The λ criterion, when λ is chosen (not fixed), in words.
        criterion: Option<String>,
        /// Held-out RMS of plain Tolles-Lawson, nT.
        plain_nt: f64,
        /// Held-out RMS with the findings, nT.
        diagnosed_nt: f64,
    },
    /// On the survey the findings would move the compensation beyond
    /// what they do over the calibration.
    BeyondCalibration {
        /// RMS of the findings' change on the survey, nT.
        survey_nt: f64,
        /// Its spread over the calibration windows, nT.
        calibration_nt: f64,
        /// How many times the calibration's spread is allowed.
        factor: f64,
        /// Departures below this always pass, nT.
        floor_nt: f64,
    },
    /// Levelled at the crossovers of the survey's lines (ties across the
    /// traverse lines), the findings leave the lines' levels more spread
    /// than plain Tolles-Lawson: they compensate the survey's headings
    /// worse.
    WorseAtCrossovers {
        /// Crossovers used.
        crossovers: usize,
        /// Lines levelled.
        lines: usize,
        /// Row-weighted spread of the line levels, plain, nT.
        plain_nt: f64,
        /// The same with the findings, nT.
        diagnosed_nt: f64,
        /// Standard error of the difference, nT.
        standard_error_nt: f64,
    },
    /// On the survey's block of parallel lines flown back and forth (no
    /// ties cross it), the findings move the level between neighbouring
    /// lines flown in opposite directions by more than the lines can show
    /// to be a correction: they may compensate the survey's headings
    /// worse than plain Tolles-Lawson
    /// ([`crate::diagnose::evidence::heading_level_risk_nt`]).
    WorseBetweenLines {
        /// Lines in the block.
        lines: usize,
        /// Triples of neighbouring lines compared.
        triples: usize,
        /// A line flown one way less the same ground flown the other way,
        /// its size, plain, nT.
        plain_nt: f64,
        /// The same with the findings, nT.
        diagnosed_nt: f64,
        /// How far the findings move the level, nT (exact: the geology
        /// cancels between the two compensations): the fitted findings'
        /// move from the base station's term alone (plain without one)
        /// where that is the risk, else the whole diagnosis's from plain.
        moved_nt: f64,
        /// Standard error of the heading level, nT.
        standard_error_nt: f64,
        /// Whether the base station's change between lines was taken out.
        external_field_removed: bool,
    },
    /// Nothing on the survey can check the findings, a sensor lag among
    /// them (too few crossovers with a base station to level at, no block
    /// of parallel lines flown both ways), and on it they would move the
    /// compensation by more than the uncertainty the channel states, on
    /// evidence within it: on the box they explain no more of the
    /// held-out RMS than that uncertainty.
    UncheckedOnSurvey {
        /// RMS of the findings' change on the survey, nT.
        survey_nt: f64,
        /// The uncertainty stated outside the calibration with the
        /// findings, nT, where one is stated.
        stated_nt: Option<f64>,
        /// What the lag explains of the held-out RMS on the box at the
        /// step the search accepted it, √(before² − after²), nT.
        explained_nt: f64,
        /// Departures below this always pass, nT.
        floor_nt: f64,
        /// Whether the survey's line levels were compared (at crossovers
        /// or between neighbouring lines): they do not show a lag's move
        /// of the geology along the lines. Otherwise nothing on the
        /// survey could be compared.
        levels_checked: bool,
    },
    /// With the findings the compensation would scale a crustal anomaly
    /// on the survey beyond the tolerance, and further from 1 than plain
    /// Tolles-Lawson does ([`crate::model::AnomalyGain`]).
    AnomalyGain {
        /// The median gain with the findings.
        gain: f64,
        /// The median gain of plain Tolles-Lawson.
        plain_gain: f64,
        /// The tolerance on |gain − 1| (`[quality] anomaly_gain_tolerance`).
        tolerance: f64,
    },
}

impl fmt::Display for HeldBack {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HeldBack::NoGainHeldOut {
                criterion,
                plain_nt,
                diagnosed_nt,
            } => write!(
                f,
                "with λ as compensation picks it{}, the findings do not lower the held-out RMS of plain Tolles-Lawson ({plain_nt:.4} → {diagnosed_nt:.4} nT)",
                criterion.as_ref().map(|c| format!(" (by {c})")).unwrap_or_default()
            ),
            HeldBack::BeyondCalibration {
                survey_nt,
                calibration_nt,
                factor,
                floor_nt,
            } => write!(
                f,
                "on the survey it would move the compensation by {survey_nt:.4} nT RMS, more than {factor} times what it does over the calibration ({calibration_nt:.4} nT) plus {floor_nt} nT: it would act beyond anything the box tested"
            ),
            HeldBack::WorseAtCrossovers { .. } | HeldBack::WorseBetweenLines { .. } => self.write_survey_levels(f),
            HeldBack::AnomalyGain {
                gain,
                plain_gain,
                tolerance,
            } => write!(
                f,
                "with them the compensation would scale a crustal anomaly on the survey by {gain:.3} (plain Tolles-Lawson {plain_gain:.3}), beyond 1 ± {tolerance}: the map's amplitudes would not be the ground's"
            ),
            HeldBack::UncheckedOnSurvey {
                survey_nt,
                stated_nt,
                explained_nt,
                floor_nt,
                levels_checked,
            } => write!(
                f,
                "on the survey it would move the compensation by {survey_nt:.4} nT RMS, beyond {}, while on the box it explains only {explained_nt:.4} nT of the held-out RMS, within it; and {}",
                match stated_nt {
                    Some(stated) if *stated >= *floor_nt => format!("the uncertainty the channel states outside the calibration ({stated:.4} nT)"),
                    _ => format!("{floor_nt} nT"),
                },
                match levels_checked {
                    true => "the survey's line levels cannot check that move (a lag moves the geology along the lines, which their levels do not show)",
                    false => "the survey has nothing to check that move against (no crossovers with a base station to level at, no block of parallel lines flown both ways)",
                }
            ),
        }
    }
}

impl HeldBack {
    /// The sentence of findings held back by the survey's own levels: at
    /// the crossovers, or between parallel lines flown both ways.
    fn write_survey_levels(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            HeldBack::WorseAtCrossovers {
                crossovers,
                lines,
                plain_nt,
                diagnosed_nt,
                standard_error_nt,
            } => write!(
                f,
                "levelled at the {crossovers} crossovers of {lines} survey lines (the base station's change between passes taken out), the lines' levels spread by {diagnosed_nt:.4} nT with the findings against {plain_nt:.4} nT plain (standard error {standard_error_nt:.4} nT): they compensate the survey's headings worse than plain Tolles-Lawson"
            ),
            HeldBack::WorseBetweenLines {
                lines,
                triples,
                plain_nt,
                diagnosed_nt,
                moved_nt,
                standard_error_nt,
                external_field_removed,
            } => write!(
                f,
                "on the survey's {lines} parallel lines flown back and forth, compared with their neighbours at {triples} lines{}, a line flown one way sits {diagnosed_nt:.4} nT from the same ground flown the other way with the findings against {plain_nt:.4} nT plain (standard error {standard_error_nt:.4} nT): the findings move that heading level by {moved_nt:.4} nT, which the lines cannot show to be a correction rather than an error of their own",
                match external_field_removed {
                    true => " (the base station's change between lines taken out)",
                    false => " (no base station: the external field's change between lines is in the comparison)",
                }
            ),
            _ => write!(f, "{self:?}"),
        }
    }
}

/// What a held-back channel gets instead of its findings.
pub const FITTED_PLAIN: &str = "so the channel is compensated with plain Tolles-Lawson";

/// Something the user must look at before trusting an output.
#[derive(Debug, Clone, PartialEq)]
pub enum Warning {
    /// What reading the flight log lost or doubts.
    Reading(Reading),
    /// Screening masked samples no instrument can record, and flagged
    /// their rows.
    Masked {
        /// The column.
        column: String,
        /// Samples masked.
        samples: usize,
        /// Why, in words.
        reason: String,
        /// Time of the first, in the flight's time unit.
        first_time: f64,
        /// Its value as read.
        first_value: f64,
        /// The row flag's name.
        flag: String,
    },
    /// A detected calibration box lacks manoeuvres: its FOM sums fewer
    /// than 12.
    IncompleteBox {
        /// The box's number, from 1 in time order.
        number: usize,
        /// Its start, in the flight's time unit.
        start: f64,
        /// Its end, in the flight's time unit.
        end: f64,
        /// The manoeuvres it lacks, in words ("pitch at 90°").
        missing: Vec<String>,
    },
    /// With the fluxgate standing in for the INS, manoeuvres on a heading
    /// turn the field direction alike, so detection named them by size
    /// only.
    NamedBySize {
        /// The leg's magnetic heading, degrees.
        heading_deg: f64,
        /// The kinds that look alike there, in pairs ("pitch", "yaw").
        alike: Vec<(String, String)>,
        /// The manoeuvres so named: start, end (s) and the kind given.
        manoeuvres: Vec<(f64, f64, String)>,
    },
    /// The fluxgate stood in for the INS under a steep field, and
    /// manoeuvres were reported missing: they may have been flown and not
    /// seen.
    SteepField {
        /// The field's dip at the fluxgate, degrees (its size).
        dip_deg: f64,
    },
    /// The INS attitude is missing near a box that lacks manoeuvres (or
    /// anywhere, with none found): what is missing may have been flown
    /// there.
    AttitudeGaps {
        /// The gaps, start and end (s).
        spans: Vec<(f64, f64)>,
    },
    /// Detected manoeuvres whose windows gaps in the fluxgate or scalar
    /// readings leave too short to band-pass: left out of the fit.
    ManoeuvresInGaps {
        /// Their labels.
        manoeuvres: Vec<String>,
    },
    /// Compensated rows lie beyond what the instrument reads: the model
    /// was applied far from what it was fitted on.
    OutputOutOfRange {
        /// The scalar channel or vector magnetometer.
        subject: String,
        /// Rows beyond the range.
        rows: usize,
        /// Time of the first, in the flight's time unit.
        first: f64,
    },
    /// The FOM after compensation is above the limit.
    FomAboveLimit {
        /// The scalar channel.
        channel: String,
        /// FOM after compensation, nT.
        fom_nt: f64,
        /// Manoeuvres it sums, of 12.
        manoeuvres: usize,
        /// `[quality] fom_limit_nt`.
        limit_nt: f64,
        /// What to do, as a sentence.
        next_step: String,
    },
    /// Compensation raised the survey lines' fourth-difference noise.
    NoiseRaised {
        /// The scalar channel.
        channel: String,
        /// Before compensation, nT.
        before_nt: f64,
        /// After, nT.
        after_nt: f64,
        /// What to do, as a sentence.
        next_step: String,
    },
    /// Compensation raised the level difference between reciprocal
    /// survey lines (the heading error).
    HeadingErrorRaised {
        /// The scalar channel.
        channel: String,
        /// Before compensation, nT.
        before_nt: f64,
        /// After, nT.
        after_nt: f64,
        /// Samples matched between the lines.
        pairs: usize,
        /// Whether the base station's change between the passes was
        /// taken out.
        station_removed: bool,
        /// What to do, as a sentence.
        next_step: String,
    },
    /// Compensation raised the difference between passes where survey
    /// lines cross.
    CrossoversRaised {
        /// The scalar channel.
        channel: String,
        /// RMS before compensation, nT.
        before_nt: f64,
        /// RMS after, nT.
        after_nt: f64,
        /// Crossovers compared.
        crossovers: usize,
        /// Whether the base station's change between the passes was
        /// taken out.
        station_removed: bool,
        /// What to do, as a sentence.
        next_step: String,
    },
    /// The compensation away from the calibration is uncertain beyond
    /// the channel's limit.
    UncertainAwayFromCalibration {
        /// The scalar channel.
        channel: String,
        /// One sigma outside the calibration, nT.
        sigma_nt: f64,
        /// Windows the jackknife moves.
        windows: usize,
        /// The limit, nT.
        limit_nt: f64,
        /// What to try, as sentences.
        advice: String,
        /// What to do, as a sentence.
        next_step: String,
    },
    /// The compensated level is uncertain by more than a few nT.
    UncertainLevel {
        /// The scalar channel.
        channel: String,
        /// One sigma of the level, nT.
        sigma_nt: f64,
    },
    /// The transfer check's warning: fitted without each heading in turn,
    /// the model does worse on it.
    PoorTransfer {
        /// The scalar channel.
        channel: String,
        /// The check's sentence.
        sentence: String,
        /// What to do, as a sentence.
        next_step: String,
    },
    /// The diagnosis leaves a residual well above the sensor's noise that
    /// no effect it knows explains.
    Unexplained {
        /// The scalar channel.
        channel: String,
        /// Held-out RMS of the residual, nT.
        heldout_rms_nt: f64,
        /// The residual against the sensor noise in the band.
        residual_to_noise: f64,
        /// The windows where it is largest, by label.
        largest_on: Vec<String>,
    },
    /// The flight could not be diagnosed (`[diagnose] apply = "auto"`), so
    /// it is compensated with plain Tolles-Lawson.
    NotDiagnosed {
        /// Why, as the diagnosis's error said.
        error: String,
    },
    /// The evidence rule held a channel's findings back: the channel is
    /// compensated with plain Tolles-Lawson.
    FindingsHeldBack {
        /// The scalar channel.
        channel: String,
        /// The findings, each as "effect from source".
        findings: Vec<String>,
        /// Why.
        reason: HeldBack,
    },
    /// The evidence rule would have held a channel's findings back, and
    /// they were applied because `[diagnose] apply = "always"` asks.
    FindingsAppliedAnyway {
        /// The scalar channel.
        channel: String,
        /// The findings, each as "effect from source".
        findings: Vec<String>,
        /// Why they would have been held back.
        reason: HeldBack,
    },
    /// The applied findings, or the base station's term, move the survey
    /// from plain Tolles-Lawson by more than the channel's stated
    /// uncertainty: no plain pass.
    SurveyDeparture {
        /// The scalar channel.
        channel: String,
        /// What moves it.
        moved_by: MovedBy,
        /// RMS of the move on the survey, nT.
        departure_nt: f64,
        /// The stated uncertainty outside the calibration, nT; `None`
        /// when none is stated.
        stated_nt: Option<f64>,
        /// Which compensation to use, and the survey's figures that say
        /// so ([`crate::quality::verdict::which_to_use`]).
        advice: String,
    },
    /// The compensated channel's noise could not be measured, so it has
    /// no sigma column.
    NoSigmaColumn {
        /// The scalar channel.
        channel: String,
    },
    /// Too few calibration windows to leave one out: nothing away from
    /// the calibration is checked.
    TooFewWindows {
        /// The scalar channel.
        channel: String,
        /// The windows it was fitted on.
        windows: usize,
    },
    /// No uncertainty figure could be computed for the channel.
    NoUncertainty {
        /// The scalar channel.
        channel: String,
        /// Why, in words.
        why: String,
    },
    /// The excitation analysis found a manoeuvre missing from the box.
    BoxGap {
        /// The scalar channel.
        channel: String,
        /// The gap, in words.
        gap: String,
    },
    /// Gaps in the recording cut calibration manoeuvres: their FOM cells
    /// and their share of the fit count only the samples kept.
    ManoeuvresCut {
        /// The scalar channel.
        channel: String,
        /// Each manoeuvre cut, in words ("roll on heading 20: 36 of 196
        /// samples kept").
        manoeuvres: Vec<String>,
    },
    /// Another fluxgate's plain Tolles-Lawson holds out better than the
    /// one the channel's terms were built from, by more than
    /// [`crate::quality::transfer::FLUXGATE_MATERIAL`].
    FluxgateBetter {
        /// The scalar channel.
        channel: String,
        /// The comparison, in words.
        comparison: String,
    },
    /// The solver the settings ask for was not used.
    SolverNotUsed {
        /// The scalar channel.
        channel: String,
        /// Why, and what was used instead.
        reason: String,
    },
    /// A compensated gradient's level is not pinned by the calibration
    /// (every compensated gradient carries it).
    GradientLevelUnpinned {
        /// The gradient column.
        column: String,
        /// Its two scalar channels.
        channels: [String; 2],
        /// Their separation, m.
        separation_m: f64,
        /// What `[fit] level` moved the gradient by, nT/m (0: nothing).
        moved_nt_per_m: f64,
    },
    /// The direct fit, which the gradient's output uses, and the
    /// difference of the compensated channels part on the survey lines
    /// beyond what they differ held out.
    GradientDirectAtOdds {
        /// The gradient column, its two channels and their separation, m.
        parting: GradientParting,
    },
    /// A gradient could not be compensated; the other outputs stand.
    GradientNotCompensated {
        /// The gradient column.
        column: String,
        /// Why, in words.
        reason: String,
    },
    /// No compensated scalar channel reads on the calibration box, so no
    /// fluxgate's vector can be given the field's size.
    VectorNoReference,
    /// A fluxgate could not be vector-compensated; the scalar outputs
    /// stand.
    VectorNotCompensated {
        /// The fluxgate (its column prefix).
        sensor: String,
        /// The saved model it was applied from, when it was.
        model: Option<std::path::PathBuf>,
        /// Why, in words.
        reason: String,
    },
    /// The vector's scale rests on a scalar channel's level over the box,
    /// where that channel's modelled aircraft field swings widely.
    VectorScaleSwings {
        /// The fluxgate.
        sensor: String,
        /// The scalar channel giving the field's size.
        reference: String,
        /// Its modelled aircraft field's swing over the box, RMS, nT.
        swing_nt: f64,
    },
    /// The vector's scale rests on a scalar channel's level, pinned by its
    /// modelled interference, but the aircraft's isotropic induced field
    /// at that sensor, which no manoeuvre shows, leaves it uncertain by
    /// more than the warning's limit.
    VectorLevelUncertain {
        /// The fluxgate.
        sensor: String,
        /// The scalar channel giving the field's size.
        reference: String,
        /// One sigma of its level, nT.
        sigma_nt: f64,
    },
    /// The vector-compensated field's direction is far from IGRF-14's.
    VectorDirectionOff {
        /// The fluxgate.
        sensor: String,
        /// The angle between the two directions, degrees.
        angle_deg: f64,
        /// Fitted minus IGRF-14's inclination, degrees.
        inclination_off_deg: f64,
        /// Fitted minus IGRF-14's declination, degrees, within ±180.
        declination_off_deg: f64,
        /// The angle beyond which this is said, degrees.
        bound_deg: f64,
        /// Whether the flight is dated (else IGRF-14 at 2025.0).
        dated: bool,
        /// What the angle is across the field, nT.
        across_nt: f64,
    },
    /// No position and no `[site]`: the field's sign is taken so that the
    /// fluxgate's axes are right-handed, unchecked.
    VectorSignUnverified {
        /// The fluxgate.
        sensor: String,
        /// The fitted field's inclination, degrees.
        inclination_deg: f64,
        /// Its declination, degrees.
        declination_deg: f64,
        /// The fluxgate's mounting, in words.
        mounting: String,
    },
    /// With the field's sign from IGRF-14, the fluxgate's axes are
    /// left-handed.
    VectorLeftHanded {
        /// The fluxgate.
        sensor: String,
    },
    /// The field is checked against IGRF-14 at the `[site]` only: the
    /// flight records no position, so its turn across the box is not
    /// modelled.
    VectorAtSiteOnly {
        /// The fluxgate.
        sensor: String,
    },
    /// The twelve-constant fit's windows give fewer than three headings:
    /// none is held out.
    VectorNotHeldOut {
        /// The fluxgate.
        sensor: String,
    },
    /// The vector Tolles-Lawson stage's own warning.
    VectorTollesLawson {
        /// The fluxgate.
        sensor: String,
        /// What it says.
        reason: String,
    },
    /// A saved model applied without a jackknife: the compensated channel
    /// has no sigma column.
    SavedWithoutJackknife {
        /// The channel.
        channel: String,
    },
    /// The calibration windows given were detected on another flight.
    WindowsFromOtherFlight {
        /// The windows file.
        windows_file: std::path::PathBuf,
        /// The flight they were detected on, in words.
        detected_on: String,
        /// This flight, in words.
        flight: String,
        /// How the two differ, in words.
        difference: String,
    },
    /// An MCAP output of a flight whose day is unknown: its log times
    /// count from 1970-01-01.
    McapUndated {
        /// The MCAP output.
        output: std::path::PathBuf,
        /// The flight's time column.
        time_column: String,
    },
    /// A saved diagnosis that does not record the flight it was made on,
    /// applied unchecked.
    DiagnosisUnchecked {
        /// The DIAGNOSIS.json.
        diagnosis: std::path::PathBuf,
        /// The flight it was applied to.
        flight: std::path::PathBuf,
    },
    /// A saved diagnosis of another flight, applied because of `--force`.
    DiagnosisForced {
        /// The DIAGNOSIS.json.
        diagnosis: std::path::PathBuf,
        /// The flight it was made on, in words.
        made_on: String,
        /// The flight it was applied to, in words.
        applied_to: String,
        /// How the two differ, in words.
        difference: String,
    },
    /// A saved model older (or younger) than `[model] max_age_days`.
    ModelTooOld {
        /// The model file.
        model: std::path::PathBuf,
        /// Days from its calibration to this flight (negative: after).
        age_days: i64,
        /// `[model] max_age_days`.
        max_age_days: u32,
    },
    /// A saved model's age is not known: a flight has no date, so
    /// `[model] max_age_days` cannot be checked.
    ModelAgeUnknown {
        /// Whether the calibration flight is the one without a date (else
        /// this flight).
        calibration_undated: bool,
    },
    /// A saved model calibrated on another airframe.
    ModelOtherAircraft {
        /// The model file.
        model: std::path::PathBuf,
        /// The aircraft it was calibrated on.
        made: String,
        /// This flight's.
        used: String,
    },
    /// A saved model's channel failed its calibration's FOM limit.
    ModelCalibrationFailed {
        /// The channel.
        channel: String,
        /// The model file.
        model: std::path::PathBuf,
        /// Its FOM on the calibration flight, nT.
        fom_nt: f64,
        /// `[quality] fom_limit_nt`.
        limit_nt: f64,
    },
    /// A saved model's channel has no FOM from its calibration flight.
    ModelCalibrationNoFom {
        /// The channel.
        channel: String,
        /// The model file.
        model: std::path::PathBuf,
    },
    /// On its calibration flight a saved model's findings moved the
    /// survey beyond the stated uncertainty (verdict CHECK).
    ModelCalibrationDeparted {
        /// The channel.
        channel: String,
        /// The move, RMS, nT.
        departure_nt: f64,
    },
    /// A saved model applied to a flight recorded at another rate.
    ModelRateDiffers {
        /// The model file.
        model: std::path::PathBuf,
        /// The rate it was fitted at, Hz.
        fitted_hz: f64,
        /// This flight's, Hz.
        flight_hz: f64,
        /// Each fit's rescaled per-sample terms: "channel (terms)".
        rescaled: Vec<String>,
    },
    /// Magnetometers of the flight the saved model holds no model of,
    /// written uncompensated.
    ModelLacksChannels {
        /// The model file.
        model: std::path::PathBuf,
        /// The channels.
        channels: Vec<String>,
    },
    /// The flight lacks some of the manoeuvres of the plan it was flown
    /// to.
    PlanManoeuvresMissing {
        /// The `PLAN_REPORT.json` given.
        report: std::path::PathBuf,
        /// The planned manoeuvres lacking, in words ("roll on heading 127°").
        missing: Vec<String>,
        /// How many the plan has.
        planned: usize,
    },
    /// A channel's figure lies outside the plan's range widened by its
    /// stated factor.
    PlanFigureOutside {
        /// The channel.
        channel: String,
        /// The figure, in words ("FOM").
        figure: &'static str,
        /// This flight's, nT.
        flown_nt: f64,
        /// The plan's median, nT.
        planned_nt: f64,
        /// The plan's simulated range, nT, when it has one.
        range: Option<(f64, f64)>,
        /// Flown over planned.
        ratio: f64,
        /// The factor the plan states.
        factor: f64,
        /// Worse than planned (else better).
        worse: bool,
    },
    /// The input's text columns are not written to an output that holds
    /// numeric columns only.
    TextColumnsNotWritten {
        /// The input.
        input: std::path::PathBuf,
        /// The text columns.
        columns: Vec<String>,
        /// The output.
        output: std::path::PathBuf,
    },
}

/// How a base station's record is used before the fit subtracts it
/// (`model::station`), and why.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StationFilter {
    /// Low-passed where its own noise takes over.
    LowPassed {
        /// The corner, Hz.
        corner_hz: f64,
        /// Valid samples in runs too short to filter (between gaps), used
        /// as recorded, their noise included.
        recorded_samples: usize,
    },
    /// As recorded: it holds more signal than noise up to its Nyquist
    /// frequency.
    SignalToNyquist,
    /// As recorded: it has no noise of its own to measure (a station
    /// sampled slower than the flight and held or interpolated between
    /// its samples).
    NoNoise,
    /// As recorded: no run of valid samples is long enough to filter, or
    /// the record has no sampling interval.
    TooShort,
}

impl StationFilter {
    /// The low-pass corner, Hz; `None` where the record is used as
    /// recorded.
    pub fn corner_hz(&self) -> Option<f64> {
        match self {
            StationFilter::LowPassed { corner_hz, .. } => Some(*corner_hz),
            _ => None,
        }
    }
}

/// What moves a channel's compensated survey from plain Tolles-Lawson.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MovedBy {
    /// Findings of the diagnosis fitted with the aircraft's terms.
    Findings,
    /// The base station's record subtracted before the fit, which moves
    /// the aircraft's coefficients it no longer biases.
    BaseStation,
    /// Both.
    FindingsAndBaseStation,
}

impl std::fmt::Display for MovedBy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            MovedBy::Findings => "the diagnosed findings move",
            MovedBy::BaseStation => "the base station's term (its record subtracted before the fit) moves",
            MovedBy::FindingsAndBaseStation => "the diagnosed findings and the base station's term move",
        })
    }
}

/// How a gradient's direct fit and the difference of its compensated
/// channels part on the survey lines ([`Warning::GradientDirectAtOdds`],
/// and the note where the output uses the difference).
#[derive(Debug, Clone, PartialEq)]
pub struct GradientParting {
    /// The gradient column.
    pub column: String,
    /// Its two scalar channels.
    pub channels: [String; 2],
    /// RMS about their mean difference, nT/m.
    pub apart_nt_per_m: f64,
    /// The channels' separation, m.
    pub separation_m: f64,
}

impl fmt::Display for GradientParting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let GradientParting {
            column,
            channels: [a, b],
            apart_nt_per_m: apart,
            separation_m: d,
        } = self;
        write!(
            f,
            "{column}: the direct fit and the difference of the compensated channels part on the survey lines by {apart:.4} nT/m (RMS about their mean difference, {:.3} nT over {d:.2} m), more than they differ held out, while neither {a} nor {b} is marked uncertain",
            apart * d
        )
    }
}

impl Warning {
    /// The scalar channel the warning is about, when it is about one (for
    /// [`Warning::OutputOutOfRange`], the channel or vector magnetometer).
    pub fn channel(&self) -> Option<&str> {
        match self {
            Warning::Reading(_)
            | Warning::Masked { .. }
            | Warning::NotDiagnosed { .. }
            | Warning::IncompleteBox { .. }
            | Warning::NamedBySize { .. }
            | Warning::SteepField { .. }
            | Warning::AttitudeGaps { .. }
            | Warning::ManoeuvresInGaps { .. }
            | Warning::GradientLevelUnpinned { .. }
            | Warning::GradientDirectAtOdds { .. }
            | Warning::GradientNotCompensated { .. }
            | Warning::VectorNoReference
            | Warning::VectorNotCompensated { .. }
            | Warning::VectorScaleSwings { .. }
            | Warning::VectorLevelUncertain { .. }
            | Warning::VectorDirectionOff { .. }
            | Warning::VectorSignUnverified { .. }
            | Warning::VectorLeftHanded { .. }
            | Warning::VectorAtSiteOnly { .. }
            | Warning::VectorNotHeldOut { .. }
            | Warning::VectorTollesLawson { .. }
            | Warning::WindowsFromOtherFlight { .. }
            | Warning::McapUndated { .. }
            | Warning::TextColumnsNotWritten { .. }
            | Warning::PlanManoeuvresMissing { .. }
            | Warning::ModelTooOld { .. }
            | Warning::ModelAgeUnknown { .. }
            | Warning::ModelOtherAircraft { .. }
            | Warning::ModelRateDiffers { .. }
            | Warning::ModelLacksChannels { .. }
            | Warning::DiagnosisUnchecked { .. }
            | Warning::DiagnosisForced { .. } => None,
            Warning::FindingsHeldBack { channel, .. }
            | Warning::FindingsAppliedAnyway { channel, .. }
            | Warning::SurveyDeparture { channel, .. }
            | Warning::NoSigmaColumn { channel }
            | Warning::PlanFigureOutside { channel, .. }
            | Warning::ModelCalibrationFailed { channel, .. }
            | Warning::ModelCalibrationNoFom { channel, .. }
            | Warning::ModelCalibrationDeparted { channel, .. }
            | Warning::SavedWithoutJackknife { channel }
            | Warning::TooFewWindows { channel, .. }
            | Warning::NoUncertainty { channel, .. }
            | Warning::BoxGap { channel, .. }
            | Warning::ManoeuvresCut { channel, .. }
            | Warning::FluxgateBetter { channel, .. }
            | Warning::SolverNotUsed { channel, .. }
            | Warning::FomAboveLimit { channel, .. }
            | Warning::NoiseRaised { channel, .. }
            | Warning::HeadingErrorRaised { channel, .. }
            | Warning::CrossoversRaised { channel, .. }
            | Warning::UncertainAwayFromCalibration { channel, .. }
            | Warning::UncertainLevel { channel, .. }
            | Warning::PoorTransfer { channel, .. }
            | Warning::Unexplained { channel, .. } => Some(channel),
            Warning::OutputOutOfRange { subject, .. } => Some(subject),
        }
    }
}

impl fmt::Display for Warning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::Reading(reading) => reading.fmt(f),
            Warning::IncompleteBox { .. }
            | Warning::NamedBySize { .. }
            | Warning::SteepField { .. }
            | Warning::AttitudeGaps { .. }
            | Warning::ManoeuvresInGaps { .. } => self.write_detection(f),
            Warning::FomAboveLimit { .. } | Warning::NoiseRaised { .. } | Warning::PoorTransfer { .. } => {
                self.write_quality(f)
            }
            Warning::HeadingErrorRaised { .. } | Warning::CrossoversRaised { .. } => self.write_levels_raised(f),
            Warning::GradientLevelUnpinned { .. }
            | Warning::GradientDirectAtOdds { .. }
            | Warning::GradientNotCompensated { .. } => self.write_gradient(f),
            Warning::VectorNoReference
            | Warning::VectorNotCompensated { .. }
            | Warning::VectorScaleSwings { .. }
            | Warning::VectorLevelUncertain { .. }
            | Warning::VectorNotHeldOut { .. }
            | Warning::VectorTollesLawson { .. } => self.write_vector(f),
            Warning::VectorDirectionOff { .. }
            | Warning::VectorSignUnverified { .. }
            | Warning::VectorLeftHanded { .. }
            | Warning::VectorAtSiteOnly { .. } => self.write_vector_direction(f),
            Warning::Masked { .. } | Warning::WindowsFromOtherFlight { .. } => self.write_input(f),
            Warning::OutputOutOfRange { .. } | Warning::McapUndated { .. } | Warning::TextColumnsNotWritten { .. } => {
                self.write_output(f)
            }
            Warning::PlanManoeuvresMissing { .. } | Warning::PlanFigureOutside { .. } => self.write_plan(f),
            Warning::ModelTooOld { .. }
            | Warning::ModelAgeUnknown { .. }
            | Warning::ModelOtherAircraft { .. }
            | Warning::ModelRateDiffers { .. }
            | Warning::ModelLacksChannels { .. } => self.write_saved_model(f),
            Warning::DiagnosisUnchecked { .. } | Warning::DiagnosisForced { .. } => self.write_saved_diagnosis(f),
            Warning::ModelCalibrationFailed { .. }
            | Warning::ModelCalibrationNoFom { .. }
            | Warning::ModelCalibrationDeparted { .. } => self.write_saved_calibration(f),
            Warning::Unexplained { .. }
            | Warning::NotDiagnosed { .. }
            | Warning::FindingsHeldBack { .. }
            | Warning::FindingsAppliedAnyway { .. }
            | Warning::SurveyDeparture { .. } => self.write_diagnosis(f),
            Warning::UncertainAwayFromCalibration { .. }
            | Warning::UncertainLevel { .. }
            | Warning::NoSigmaColumn { .. }
            | Warning::SavedWithoutJackknife { .. }
            | Warning::TooFewWindows { .. }
            | Warning::NoUncertainty { .. }
            | Warning::BoxGap { .. }
            | Warning::ManoeuvresCut { .. }
            | Warning::FluxgateBetter { .. }
            | Warning::SolverNotUsed { .. } => self.write_fit(f),
        }
    }
}

impl Warning {
    /// A variant `fmt` sent to a helper that does not write it (none does
    /// today): its data, rather than nothing.
    fn write_unrouted(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{self:?}")
    }

    /// The sentence of a warning of the box's detection.
    fn write_detection(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::IncompleteBox {
                number,
                start,
                end,
                missing,
            } => write!(
                f,
                "box {number} ({start:.1}–{end:.1}) is incomplete: {}; its FOM sums fewer than 12 manoeuvres",
                missing.join(", ")
            ),
            Warning::NamedBySize {
                heading_deg,
                alike,
                manoeuvres,
            } => write_named_by_size(f, *heading_deg, alike, manoeuvres),
            Warning::SteepField { dip_deg } => write!(
                f,
                "the field dips {dip_deg:.0}° at the fluxgate, which stands in for the INS: its horizontal part gives the heading weakly and a yaw barely turns the field direction, so manoeuvres reported missing may have been flown and not seen. Give the INS attitude (ins_pitch, ins_roll, ins_yaw) or the windows with --window"
            ),
            Warning::ManoeuvresInGaps { manoeuvres } => write!(
                f,
                "gaps in the fluxgate or scalar readings leave {} too short to band-pass: {}; the fit and the FOM go on without {}, so the box counts fewer manoeuvres. Fill the gaps, or fly {} again",
                match manoeuvres.len() {
                    1 => "a detected manoeuvre".to_string(),
                    n => format!("{n} detected manoeuvres"),
                },
                manoeuvres.join(", "),
                if manoeuvres.len() == 1 { "it" } else { "them" },
                if manoeuvres.len() == 1 { "it" } else { "them" },
            ),
            Warning::AttitudeGaps { spans } => {
                let spans: Vec<String> = (spans.iter())
                    .map(|(start, end)| format!("{start:.1}–{end:.1} s"))
                    .collect();
                write!(
                    f,
                    "the INS attitude is missing over {}: legs or manoeuvres flown there cannot be seen, so what is reported missing may have been flown there; give the windows with --window if so",
                    spans.join(", ")
                )
            }
            _ => self.write_unrouted(f),
        }
    }

    /// The gradient stage's warnings.
    fn write_gradient(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::GradientLevelUnpinned {
                column,
                channels: [a, b],
                separation_m,
                moved_nt_per_m,
            } => write!(
                f,
                "{column}: the gradient's level is not pinned by the calibration: the aircraft's steady field differs between {a} and {b} by an amount no manoeuvre reveals, up to the aircraft's field at the sensors over {separation_m:.2} m{}; use its variation along the lines, or level it to tie lines",
                match moved_nt_per_m {
                    0.0 => String::new(),
                    offset => format!(" ([fit] level moved it by {offset:.4} nT/m)"),
                }
            ),
            Warning::GradientDirectAtOdds { parting } => write!(
                f,
                "{parting}: the direct fit, which the output uses, is likely wrong there by about that much; use [[gradient]] method = \"auto\" or \"difference\", or fly a fuller box"
            ),
            Warning::GradientNotCompensated { column, reason } => {
                write!(f, "{column}: no gradient compensation: {reason}")
            }
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning of the diagnosis: a finding held back or
    /// applied anyway, the survey moved, the residual left unexplained.
    fn write_diagnosis(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::Unexplained { .. } => self.write_unexplained(f),
            Warning::NotDiagnosed { error } => {
                write!(f, "not diagnosed, so compensated with plain Tolles-Lawson: {error}")
            }
            Warning::FindingsHeldBack {
                channel,
                findings,
                reason,
            } => write!(
                f,
                "{channel}: the diagnosis's {} not applied: {reason}, {FITTED_PLAIN}",
                findings.join(", ")
            ),
            Warning::FindingsAppliedAnyway {
                channel,
                findings,
                reason,
            } => write!(
                f,
                "{channel}: the diagnosis's {} applied as [diagnose] apply = \"always\" asks, though {reason}",
                findings.join(", ")
            ),
            Warning::SurveyDeparture {
                channel,
                moved_by,
                departure_nt,
                stated_nt,
                advice,
            } => write!(
                f,
                "{channel}: {moved_by} the survey {departure_nt:.4} nT RMS from plain Tolles-Lawson, more than {}: the verdict is CHECK; {}{advice}",
                match stated_nt {
                    Some(sigma) => format!("its stated uncertainty ({sigma:.4} nT)"),
                    None => "anything its uncertainty states (none is stated)".into(),
                },
                match moved_by {
                    MovedBy::BaseStation => "the fits with and without the external field the station recorded disagree by more than that, so one of them is wrong by more than the uncertainty stated; ",
                    _ => "",
                }
            ),
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of [`Warning::Unexplained`]: the residual the
    /// diagnosis leaves, against the sensor's noise.
    fn write_unexplained(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let Warning::Unexplained {
            channel,
            heldout_rms_nt,
            residual_to_noise,
            largest_on,
        } = self
        else {
            return self.write_unrouted(f);
        };
        write!(
            f,
            "{channel}: the diagnosis leaves an unexplained residual of {heldout_rms_nt:.4} nT held out, {residual_to_noise:.0} times the sensor noise in the band, largest on {}: the compensation of this channel is not good to the noise level; see the diagnosis's unexplained finding",
            largest_on.join(", ")
        )
    }

    /// The sentence of a warning on a channel's fit: its sigma column,
    /// windows, uncertainty, box and solver.
    fn write_fit(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::UncertainAwayFromCalibration {
                channel,
                sigma_nt,
                windows,
                limit_nt,
                advice,
                next_step,
            } => write!(
                f,
                "{channel}: the compensation away from the calibration is uncertain by {sigma_nt:.3} nT (one sigma, from how much each of the {windows} windows moves the fit), above {limit_nt:.3} nT: the manoeuvres flown do not pin the model on the survey's headings and attitudes, and the survey lines can be wrong by that much or more. {advice} {next_step}"
            ),
            Warning::UncertainLevel { channel, sigma_nt } => write!(
                f,
                "{channel}: the compensated level is uncertain by {sigma_nt:.1} nT (one sigma, from how much each window moves the fit): the band-passed fit does not pin it; level the channel to a base station or tie lines before using absolute values"
            ),
            Warning::NoSigmaColumn { channel } => write!(
                f,
                "{channel}: no sigma column: the compensated channel's noise cannot be measured (too few consecutive samples)"
            ),
            Warning::TooFewWindows { channel, windows } => write!(
                f,
                "{channel}: fitted on {windows} calibration window(s), too few to leave one out: the compensation away from the calibration is not checked and has no uncertainty figure or sigma column. Give three or more windows, one per manoeuvre or leg (a window spanning a whole box is one window; `magcomp detect` finds the manoeuvres)"
            ),
            Warning::SavedWithoutJackknife { channel } => write!(
                f,
                "{channel}: no sigma column: the model was saved without a jackknife (fitted on fewer than three windows, or with another solver)"
            ),
            Warning::NoUncertainty { channel, why } => write!(f, "{channel}: no uncertainty figure: {why}"),
            Warning::BoxGap { channel, gap } => write!(f, "{channel}: {gap}"),
            Warning::FluxgateBetter { channel, comparison } => write!(f, "{channel}: {comparison}"),
            Warning::ManoeuvresCut { channel, manoeuvres } => write!(
                f,
                "{channel}: gaps in the recording (invalid scalar, fluxgate or source samples) cut {} of the calibration: {}; their FOM cells and their share of the fit count only the samples kept, so the FOM may understate those manoeuvres. Fill the gaps, or fly them again",
                match manoeuvres.len() {
                    1 => "a manoeuvre".to_string(),
                    n => format!("{n} manoeuvres"),
                },
                manoeuvres.join("; ")
            ),
            Warning::SolverNotUsed { channel, reason } => write!(f, "{channel}: {reason}"),
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning on the run's inputs: samples masked,
    /// windows from another flight.
    fn write_input(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::Masked {
                column,
                samples,
                reason,
                first_time,
                first_value,
                flag,
            } => {
                let one = *samples == 1;
                write!(
                    f,
                    "masked {samples} sample{} of {column} ({reason}), the first at {} s ({}); every stage treats {} as missing, and {} flagged {flag}:{column}",
                    if one { "" } else { "s" },
                    crate::error::Number(*first_time),
                    crate::error::Number(*first_value),
                    if one { "it" } else { "them" },
                    if one { "its row is" } else { "their rows are" },
                )
            }
            Warning::WindowsFromOtherFlight {
                windows_file,
                detected_on,
                flight,
                difference,
            } => write!(
                f,
                "the calibration windows of {} were detected on {detected_on}, not on this flight {flight} ({difference}): check that they lie on this flight's manoeuvres, or detect them on it with `magcomp detect`",
                windows_file.display()
            ),
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning on the run's outputs: rows out of range,
    /// an undated MCAP output, text columns not written.
    fn write_output(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::OutputOutOfRange { subject, rows, first } => write!(
                f,
                "{subject}: {rows} compensated row{} lie beyond what the instrument reads (a total field outside 1,000-100,000 nT, a component beyond ±100,000 nT), the first at {} s; they are written and flagged output_out_of_range:{subject}. The model was applied far from what it was fitted on: look at the attitude and fluxgate there, and at the calibration windows",
                if *rows == 1 { "" } else { "s" },
                crate::error::Number(*first),
            ),
            Warning::McapUndated { output, time_column } => write!(
                f,
                "{}: the flight's day is unknown (no year and doy columns, no --date), so its MCAP log times count '{time_column}' from 1970-01-01; give the day with --date YYYY-MM-DD",
                output.display()
            ),
            Warning::TextColumnsNotWritten { input, columns, output } => write!(
                f,
                "{}: the input's text column(s) {} are not written to {}, which holds the numeric columns only; a compensated CSV or XYZ written from an input of the same format keeps them",
                input.display(),
                columns.iter().map(|n| format!("'{n}'")).collect::<Vec<_>>().join(", "),
                output.display()
            ),
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning on a saved diagnosis applied.
    fn write_saved_diagnosis(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::DiagnosisUnchecked { diagnosis, flight } => write!(
                f,
                "{} does not record the flight it was made on (an older magcomp wrote it), so it was applied to {} without checking that it belongs to it",
                diagnosis.display(),
                flight.display()
            ),
            Warning::DiagnosisForced {
                diagnosis,
                made_on,
                applied_to,
                difference,
            } => write!(
                f,
                "{} was made on {made_on}, not on {applied_to} ({difference}); applied anyway because of --force",
                diagnosis.display()
            ),
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning on the comparison with a flight plan.
    fn write_plan(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::PlanManoeuvresMissing {
                report,
                missing,
                planned,
            } => write!(
                f,
                "against the plan ({}): the flight lacks {} of the plan's {planned} manoeuvres ({}); the plan's prediction counted on them, so its figures are for a box this flight did not fly",
                report.display(),
                missing.len(),
                missing.join(", ")
            ),
            Warning::PlanFigureOutside {
                channel,
                figure,
                flown_nt,
                planned_nt,
                range,
                ratio,
                factor,
                worse,
            } => write!(
                f,
                "{channel}: {figure} {flown_nt:.3} nT against the plan's {planned_nt:.3} nT{}, {ratio:.2}×, outside the plan's range widened by its stated factor of {factor}: {}; plan the next calibration with this flight's model (--model) as [plan] installation",
                match range {
                    Some((low, high)) => format!(" (range {low:.3}–{high:.3})"),
                    None => String::new(),
                },
                match worse {
                    true => "worse than planned: the aircraft's interference, the sensors' noise or the manoeuvres flown (amplitudes, periods, headings) differ from what the plan assumed",
                    false => "better than planned: the plan's installation overstates this aircraft's interference or noise, so additions it proposed may not be needed",
                }
            ),
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning on how a saved model's calibration
    /// flight went.
    fn write_saved_calibration(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::ModelCalibrationFailed {
                channel,
                model,
                fom_nt,
                limit_nt,
            } => write!(
                f,
                "{channel}: the model {} had a FOM of {fom_nt:.2} nT on its calibration flight, above the {limit_nt:.2} nT limit ([quality] fom_limit_nt): this flight is compensated with a calibration that failed; fly a new box, or accept the calibration flight's report first",
                model.display()
            ),
            Warning::ModelCalibrationNoFom { channel, model } => write!(
                f,
                "{channel}: the model {} has no FOM from its calibration flight (no labelled manoeuvres): nothing says the calibration passed; check the calibration flight's report",
                model.display()
            ),
            Warning::ModelCalibrationDeparted { channel, departure_nt } => write!(
                f,
                "{channel}: on its calibration flight the model's findings or base station's term moved the survey {departure_nt:.4} nT from plain Tolles-Lawson, beyond its stated uncertainty (verdict CHECK): compare with a plain model (--plain --model on the calibration flight) before using this channel"
            ),
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning on a saved model applied.
    fn write_saved_model(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::ModelTooOld {
                model,
                age_days,
                max_age_days,
            } => write!(
                f,
                "the model {} was calibrated {}, more than [model] max_age_days = {max_age_days}: an installation changes (equipment moved, repairs, a new instrument); fly a new calibration box, or check this flight's heading error and noise against the calibration flight's",
                model.display(),
                days_from(*age_days)
            ),
            Warning::ModelAgeUnknown { calibration_undated } => write!(
                f,
                "the model's age is not known: {} has no date, so magcomp cannot tell whether the installation has changed since the calibration ([model] max_age_days); give [[flight]] date or --date, or record year and doy columns",
                if *calibration_undated { "the calibration flight" } else { "this flight" }
            ),
            Warning::ModelOtherAircraft { model, made, used } => write!(
                f,
                "the model {} was calibrated on the aircraft '{made}' and this flight is '{used}': another airframe's magnetic signature does not compensate this one; apply a model of '{used}'",
                model.display()
            ),
            Warning::ModelRateDiffers {
                model,
                fitted_hz,
                flight_hz,
                rescaled,
            } => write_rate_differs(f, model, (*fitted_hz, *flight_hz), rescaled),
            Warning::ModelLacksChannels { model, channels } => {
                let them = if channels.len() == 1 { "it" } else { "them" };
                write!(
                    f,
                    "{} not compensated: the model {} holds no model of {them}; calibrate {them} on a flight with a box, or name this flight's channels with --channels",
                    channels.join(", "),
                    model.display()
                )
            }
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning of the vector stage.
    fn write_vector(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::VectorNoReference => f.write_str(
                "no vector compensation: no compensated scalar channel has a reading on the calibration box to give the field's size",
            ),
            Warning::VectorNotCompensated { sensor, model, reason } => match model {
                Some(path) => write!(f, "{sensor}: no vector compensation from the model {}: {reason}", path.display()),
                None => write!(f, "{sensor}: no vector compensation: {reason}"),
            },
            Warning::VectorScaleSwings {
                sensor,
                reference,
                swing_nt,
            } => write!(
                f,
                "{sensor}: the vector's scale rests on {reference}'s level over the box, where the aircraft's modelled field swings by {swing_nt:.1} nT RMS: its mean there, which no manoeuvre pins, may be as large and is an error of up to that size on each vector component (a scalar sensor on a tail stinger gives a surer level)"
            ),
            Warning::VectorLevelUncertain {
                sensor,
                reference,
                sigma_nt,
            } => write!(
                f,
                "{sensor}: the vector's scale rests on {reference}'s level, its modelled interference taken out, but the aircraft's isotropic induced field at that sensor, which no manoeuvre shows, leaves it uncertain by ±{sigma_nt:.1} nT, an error of up to that size on each vector component (a scalar sensor on a tail stinger gives a surer level)"
            ),
            Warning::VectorNotHeldOut { sensor } => write!(
                f,
                "{sensor}: the twelve-constant fit's windows do not give three headings (a window given by time that spans a turn has none), so no heading is held out and the vector's accuracy away from them is not checked; give the box's manoeuvres or legs as windows"
            ),
            Warning::VectorTollesLawson { sensor, reason } => write!(f, "{sensor}: vector Tolles-Lawson: {reason}"),
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning on the vector's direction and sign as
    /// checked against IGRF-14, or unchecked.
    fn write_vector_direction(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::VectorDirectionOff {
                sensor,
                angle_deg,
                inclination_off_deg,
                declination_off_deg,
                bound_deg,
                dated,
                across_nt,
            } => write!(
                f,
                "{sensor}: the vector-compensated field's direction is {angle_deg:.2}° from IGRF-14's ({inclination_off_deg:.2}° in inclination, {declination_off_deg:.2}° in declination; more than {bound_deg}°){}: check the INS attitude convention (CONTRACT §1), the position columns and the flight's date; the vector may be rotated by as much, {across_nt:.0} nT across the field",
                if *dated { "" } else { " with no flight date (IGRF taken at 2025.0)" },
            ),
            Warning::VectorSignUnverified {
                sensor,
                inclination_deg,
                declination_deg,
                mounting,
            } => write!(
                f,
                "{sensor}: the Earth field's direction is unverified: the flight records no position (lat, lon) and pipeline.toml sets no [site], and the data fix the direction only up to its sign (a fluxgate reading reversed on all three axes under a field pointing up reads as this one does); it is taken so that the fluxgate's axes are right-handed: inclination {inclination_deg:.2}°, declination {declination_deg:.2}°, {mounting}. Set [site] latitude, longitude and date to check it against IGRF-14. Without a position the field's turn across the box (about 0.01° a km) is not modelled either: expect tens of nT on each component"
            ),
            Warning::VectorLeftHanded { sensor } => write!(
                f,
                "{sensor}: with the field's sign from IGRF-14, the fluxgate's axes are left-handed (det K < 0): one axis, or all three, read reversed (the wiring, or a sign in the file); the vector output is in the INS's body axes as fitted, but check the fluxgate's axis signs, and the position and date if its axes are known to be right-handed"
            ),
            Warning::VectorAtSiteOnly { sensor } => write!(
                f,
                "{sensor}: the flight records no position: the field's sign and direction are checked against IGRF-14 at the [site], but the field's turn across the box (about 0.01° a km) is not modelled: expect tens of nT on each component (a few with lat and lon columns)"
            ),
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning of the compensation's quality figures.
    fn write_quality(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::FomAboveLimit {
                channel,
                fom_nt,
                manoeuvres,
                limit_nt,
                next_step,
            } => write!(
                f,
                "{channel}: FOM {fom_nt:.2} nT after compensation ({manoeuvres} of 12 manoeuvres), above the {limit_nt:.2} nT limit ([quality] fom_limit_nt). {next_step}"
            ),
            Warning::NoiseRaised {
                channel,
                before_nt,
                after_nt,
                next_step,
            } => write!(
                f,
                "{channel}: compensation raised the survey lines' fourth-difference noise from {before_nt:.4} to {after_nt:.4} nT ({:.2}×): the model adds more than it removes there. {next_step}",
                after_nt / before_nt
            ),
            Warning::PoorTransfer {
                sentence, next_step, ..
            } => write!(f, "{sentence}. {next_step}"),
            _ => self.write_unrouted(f),
        }
    }

    /// The sentence of a warning that compensation raised the level
    /// difference between passes over the same ground: reciprocal lines,
    /// crossovers.
    fn write_levels_raised(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::HeadingErrorRaised {
                channel,
                before_nt,
                after_nt,
                pairs,
                station_removed,
                next_step,
            } => write!(
                f,
                "{channel}: compensation raised the level difference between reciprocal survey lines (heading error) from {before_nt:.3} to {after_nt:.3} nT over {pairs} matched samples{}. {next_step}",
                between_passes(*station_removed)
            ),
            Warning::CrossoversRaised {
                channel,
                before_nt,
                after_nt,
                crossovers,
                station_removed,
                next_step,
            } => write!(
                f,
                "{channel}: compensation raised the RMS difference between the passes where survey lines cross from {before_nt:.3} to {after_nt:.3} nT over {crossovers} crossovers{}. {next_step}",
                between_passes(*station_removed)
            ),
            _ => self.write_unrouted(f),
        }
    }
}

/// The sentence of [`Warning::NamedBySize`]: the kinds that look `alike`
/// on the leg at `heading_deg`, degrees (magnetic), and the `manoeuvres`
/// named by size only.
fn write_named_by_size(
    f: &mut fmt::Formatter<'_>,
    heading_deg: f64,
    alike: &[(String, String)],
    manoeuvres: &[(f64, f64, String)],
) -> fmt::Result {
    let alike: Vec<String> = alike.iter().map(|(a, b)| format!("a {a} and a {b}")).collect();
    let named: Vec<String> = (manoeuvres.iter())
        .map(|(start, end, kind)| format!("{start:.1}–{end:.1} s as {kind}"))
        .collect();
    write!(
        f,
        "heading {heading_deg:.0}° (magnetic): with the fluxgate alone {} turn the field direction alike on this heading, so the manoeuvre(s) at {} are named by size only; check them against the flight notes, or give the windows with --window",
        alike.join(", and "),
        named.join(" and ")
    )
}

/// The sentence of [`Warning::ModelRateDiffers`]: the saved `model` was
/// fitted at `fitted_hz` and the flight recorded at `flight_hz`, Hz, with
/// its per-sample terms `rescaled`.
fn write_rate_differs(
    f: &mut fmt::Formatter<'_>,
    model: &std::path::Path,
    (fitted_hz, flight_hz): (f64, f64),
    rescaled: &[String],
) -> fmt::Result {
    let factor = flight_hz / fitted_hz;
    write!(
        f,
        "the model {} was fitted at {fitted_hz:.3} Hz and this flight is recorded at {flight_hz:.3} Hz: {}. The fit's band and its per-sample differences were those of the calibration's rate, and nothing on this flight checks the transfer: compare its noise and heading error with the calibration flight's, or calibrate at this rate",
        model.display(),
        match rescaled.is_empty() {
            true => "it has no per-sample term to rescale".to_string(),
            false => format!(
                "its per-sample terms (eddy currents, the field's derivative) were rescaled by the rates' ratio, {factor:.3}: {}; they carry the fluxgate's noise {factor:.2}× as strongly as on the calibration flight",
                rescaled.join("; ")
            ),
        }
    )
}

/// What a comparison between two passes over the same ground took out.
fn between_passes(station_removed: bool) -> &'static str {
    match station_removed {
        true => " (the base station's change between the passes taken out)",
        false => " (the flight has no base station, so this includes the external field's change between the passes)",
    }
}

impl From<Reading> for Warning {
    fn from(reading: Reading) -> Self {
        Warning::Reading(reading)
    }
}

impl Serialize for Warning {
    /// As its sentence: the quality JSON's `warnings` are sentences.
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

/// What the user may want to know about a run.
#[derive(Debug, Clone, PartialEq)]
pub enum Note {
    /// What the diagnosis says beside its findings.
    Diagnosing(Diagnosing),
    /// A campaign gave the flight its aircraft's calibration model.
    AssignedModel {
        /// The calibration flight whose model compensates this one.
        calibration: std::path::PathBuf,
        /// The flight was flown before any calibration flight of its
        /// aircraft, so it has the first one's.
        before_any: bool,
    },
    /// No vector compensation: the flight records no INS attitude.
    NoVectorAttitude,
    /// A fluxgate vector-compensated, with its model's figures.
    VectorCompensated(Box<VectorSummary>),
    /// The input already has the column magcomp would add: the
    /// compensation goes in a renamed one.
    Renamed {
        /// The scalar channel compensated.
        channel: String,
        /// The input's column of the same name, kept unchanged.
        original: String,
        /// The column the compensation is written in.
        column: String,
    },
    /// The channel's excitation (what the box pins) was not analysed.
    NoExcitationAnalysis {
        /// The scalar channel.
        channel: String,
        /// Why, in words.
        why: String,
    },
    /// The channel was fitted and compensated with its diagnosed model.
    DiagnosedModel {
        /// The scalar channel.
        channel: String,
        /// The model, in words.
        model: String,
    },
    /// A base station the models subtract from their channels before the
    /// fit, as it was used (`model::station`: low-passed where its own
    /// noise takes over).
    QuietStation {
        /// The station's column.
        column: String,
        /// How it was filtered: low-passed, or as recorded and why.
        filter: StationFilter,
        /// Its white noise, nT.
        noise_nt: f64,
        /// The channels whose models subtract it.
        channels: Vec<String>,
    },
    /// The line under the input's header is a row of units: read as
    /// units, not data, and kept in a compensated CSV.
    UnitsRow {
        /// The input.
        path: std::path::PathBuf,
        /// (column, unit), in the header's order.
        units: Vec<(String, String)>,
    },
    /// The channel was compensated with a saved model's findings.
    SavedFindings {
        /// The scalar channel.
        channel: String,
        /// The model, in words.
        model: String,
    },
    /// What detection found: its manoeuvres and boxes, and where the
    /// attitude came from.
    Detected {
        /// Manoeuvres detected.
        manoeuvres: usize,
        /// Boxes detected.
        boxes: usize,
        /// Whether the fluxgate's field direction stood in for the INS.
        from_fluxgate: bool,
    },
    /// The file has no INS attitude: detection read the fluxgate's field
    /// direction, and its headings are magnetic.
    AttitudeFromFluxgate,
    /// Detection found no calibration manoeuvre.
    NoManoeuvres,
    /// Detection on the calibration lines alone: the manoeuvres each line
    /// gave.
    ManoeuvresByLine {
        /// (line number, manoeuvres on it), in the lines' order.
        counts: Vec<(f64, usize)>,
    },
    /// A channel compensated on the flight that the plan did not predict.
    PlanLacksChannel {
        /// The scalar channel.
        channel: String,
        /// The plan's report.
        report: std::path::PathBuf,
    },
    /// A channel the plan predicted that the flight did not compensate.
    PlanChannelNotCompensated {
        /// The scalar channel.
        channel: String,
        /// The plan's report.
        report: std::path::PathBuf,
    },
    /// The manoeuvres flown are not compared with the plan's.
    PlanManoeuvresNotCompared {
        /// The plan's report.
        report: std::path::PathBuf,
        /// Why: the report lists no planned manoeuvres (`true`), or the
        /// calibration windows carry no manoeuvre kind and heading.
        no_plan: bool,
    },
    /// Manoeuvres flown that the plan did not have.
    PlanUnplannedManoeuvres {
        /// The plan's report.
        report: std::path::PathBuf,
        /// Each, in words ("roll at 90°").
        manoeuvres: Vec<String>,
    },
    /// The flight flew the plan's proposed additions: it is compared with
    /// the prediction with them.
    PlanWithAdditions {
        /// The plan's report.
        report: std::path::PathBuf,
        /// The additions' manoeuvres.
        additions: usize,
    },
    /// A flight's aircraft is not named, so the model's airframe is not
    /// checked.
    AircraftUnnamed {
        /// Whether the calibration flight names it.
        calibration_named: bool,
        /// Whether this flight names it.
        flight_named: bool,
    },
    /// The saved model was fitted on this very flight.
    ModelOnItsOwnFlight,
    /// The saved model is set against the flight's own calibration
    /// windows.
    ModelHeldOut {
        /// The windows.
        windows: usize,
        /// Whether the model was fitted on this flight (in sample).
        own_flight: bool,
    },
    /// The flight records the model's channel under its own name, so the
    /// `[model] channels` line for it is not used.
    ModelChannelOwnName {
        /// The model's channel.
        model: String,
        /// The column the line names.
        column: String,
    },
    /// The model's channel compensates another column of this flight.
    ModelChannelMapped {
        /// The model's channel.
        model: String,
        /// The flight's column.
        column: String,
    },
    /// No vector compensation with a saved model.
    NoSavedVectorCompensation {
        /// Whether the flight records an INS attitude (then the model
        /// holds no vector model).
        attitude: bool,
    },
    /// The fluxgate was calibrated against a scalar magnetometer.
    FluxgateCalibrated {
        /// The fluxgate.
        sensor: String,
        /// The scalar magnetometer it was calibrated against.
        reference: String,
        /// Scale factor per axis.
        scale: [f64; 3],
        /// Non-orthogonality angles, °.
        non_orthogonality_deg: [f64; 3],
        /// Offset per axis, nT.
        offset_nt: [f64; 3],
        /// The mismatch of |B| against the reference, RMS nT, before and
        /// after.
        mismatch_rms_nt: [f64; 2],
        /// Rows it was calibrated on.
        rows: usize,
    },
    /// Windows given by time took their leg's heading from the INS yaw,
    /// or could not.
    WindowHeadings {
        /// The headings taken, rounded to a degree, in the windows' order.
        headings_deg: Vec<f64>,
        /// Windows that span a turn or lack the yaw, and keep no heading.
        without: usize,
    },
    /// No manoeuvre was detected on the calibration lines named: each
    /// line's whole span is a window.
    LinesAsWindows {
        /// The lines named.
        lines: Vec<f64>,
        /// What the windows' headings are ([`Note::WindowHeadings`]).
        headings: Option<Box<Note>>,
    },
    /// The reduced columns remove the base station's variation: as
    /// recorded, or about its median when it records the total field.
    BaseStationRemoved {
        /// The base station's column.
        station: String,
        /// Its median over the flight, nT.
        median_nt: f64,
        /// Whether it records the total field (its variation about the
        /// median is removed) rather than the variation itself.
        total_field: bool,
    },
    /// The `_igrf` columns remove IGRF-14 for the flight's day.
    MainFieldRemoved {
        /// The day, `YYYY-MM-DD`.
        day: String,
        /// The position columns, `lat/lon[/height]`.
        position: String,
        /// Whether a height column was read (else at sea level).
        height: bool,
    },
    /// The channel has no estimator table: its windows do not give three
    /// headings.
    NoEstimatorTable {
        /// The scalar channel.
        channel: String,
    },
    /// Estimator families no split of the headings could fit.
    EstimatorTableLacks {
        /// The scalar channel.
        channel: String,
        /// The families left out.
        families: Vec<String>,
    },
    /// A box the transfer check could not fit.
    NoBoxTransfer {
        /// The scalar channel.
        channel: String,
        /// The box, from 1.
        number: usize,
        /// Why, in words.
        why: String,
    },
    /// A gradient formed: how, and why that way.
    GradientFormed {
        /// The gradient column.
        column: String,
        /// Its two channels (a − b).
        channels: [String; 2],
        /// Their separation, m.
        separation_m: f64,
        /// Whether the output is a model fitted to the difference (else
        /// the difference of the compensated channels).
        direct: bool,
        /// Why that method, in words.
        reason: String,
        /// Held out by heading: (headings, direct fit's and difference's
        /// residual, nT/m), when it was.
        held_out: Option<(usize, f64, f64)>,
    },
    /// A gradient formed from the channels a saved model compensated.
    GradientFromSavedChannels {
        /// The gradient column.
        column: String,
        /// Its two channels (a − b).
        channels: [String; 2],
        /// Their separation, m.
        separation_m: f64,
    },
    /// The direct fit parts from the difference on the survey lines, and
    /// the output uses the difference.
    GradientDifferenceUsed {
        /// How far they part.
        parting: GradientParting,
    },
    /// A channel's figures against the plan.
    PlanChannelFigures {
        /// The scalar channel.
        channel: String,
        /// The plan's report.
        report: std::path::PathBuf,
        /// Each figure against its prediction, in words.
        figures: Vec<String>,
        /// Whether every figure compared is as planned.
        as_planned: bool,
    },
}

impl From<Diagnosing> for Note {
    fn from(note: Diagnosing) -> Self {
        Note::Diagnosing(note)
    }
}

impl fmt::Display for Note {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::Diagnosing(note) => note.fmt(f),
            Note::AssignedModel {
                calibration,
                before_any,
            } => {
                write!(
                    f,
                    "compensated with the model of its aircraft's calibration flight {} (calibration = true)",
                    calibration.display()
                )?;
                match before_any {
                    true => {
                        f.write_str(": it was flown before any calibration flight of its aircraft, so the first one's")
                    }
                    false => Ok(()),
                }
            }
            Note::NoVectorAttitude => {
                f.write_str("no vector compensation: the flight records no INS attitude (roll, pitch and yaw)")
            }
            Note::VectorCompensated(summary) => summary.fmt(f),
            Note::WindowHeadings { .. } | Note::LinesAsWindows { .. } | Note::FluxgateCalibrated { .. } => {
                self.write_calibration(f)
            }
            Note::Detected { .. } | Note::AttitudeFromFluxgate | Note::NoManoeuvres | Note::ManoeuvresByLine { .. } => {
                self.write_detection(f)
            }
            Note::GradientFormed { .. }
            | Note::GradientFromSavedChannels { .. }
            | Note::GradientDifferenceUsed { .. } => self.write_gradient(f),
            Note::NoEstimatorTable { .. } | Note::EstimatorTableLacks { .. } | Note::NoBoxTransfer { .. } => {
                self.write_fit(f)
            }
            Note::AircraftUnnamed { .. } | Note::ModelOnItsOwnFlight | Note::ModelHeldOut { .. } => {
                self.write_saved_model(f)
            }
            Note::ModelChannelOwnName { .. }
            | Note::ModelChannelMapped { .. }
            | Note::NoSavedVectorCompensation { .. }
            | Note::SavedFindings { .. } => self.write_saved_channels(f),
            Note::BaseStationRemoved { .. } | Note::MainFieldRemoved { .. } => self.write_reduced(f),
            Note::PlanLacksChannel { .. }
            | Note::PlanChannelNotCompensated { .. }
            | Note::PlanChannelFigures { .. } => self.write_plan(f),
            Note::PlanManoeuvresNotCompared { .. }
            | Note::PlanUnplannedManoeuvres { .. }
            | Note::PlanWithAdditions { .. } => self.write_plan_manoeuvres(f),
            Note::Renamed { .. }
            | Note::NoExcitationAnalysis { .. }
            | Note::DiagnosedModel { .. }
            | Note::QuietStation { .. } => self.write_channel_output(f),
            Note::UnitsRow { path, units } => write_units_row(f, path, units),
        }
    }
}

/// The sentence of [`Note::UnitsRow`]: the first six columns' units, and
/// how many more.
fn write_units_row(f: &mut fmt::Formatter<'_>, path: &std::path::Path, units: &[(String, String)]) -> fmt::Result {
    const LISTED: usize = 6;
    let listed: Vec<String> = (units.iter().take(LISTED))
        .map(|(column, unit)| format!("{column} {unit}"))
        .collect();
    let more = match units.len().saturating_sub(LISTED) {
        0 => String::new(),
        n => format!(" and {n} more"),
    };
    write!(
        f,
        "line 2 of {} is a row of units ({}{more}): it is read as units, not data; a compensated CSV keeps it, with the added columns' units",
        path.display(),
        listed.join(", ")
    )
}

/// The sentence of [`Note::WindowHeadings`]: the headings, degrees, the
/// windows given by time take from the INS yaw, and how many keep none.
fn write_window_headings(f: &mut fmt::Formatter<'_>, headings_deg: &[f64], without: usize) -> fmt::Result {
    let keep_none = format!("{without} window(s) given by time span a turn or lack the yaw and keep no heading");
    if headings_deg.is_empty() {
        return f.write_str(&keep_none);
    }
    let taken: Vec<String> = headings_deg.iter().map(|h| format!("{h:.0}°")).collect();
    write!(
        f,
        "{} window(s) given by time take their leg's heading from the INS yaw ({})",
        headings_deg.len(),
        taken.join(", ")
    )?;
    match without {
        0 => Ok(()),
        _ => write!(f, "; {keep_none}"),
    }
}

impl Note {
    /// The sentence of a note on a channel's output: its column renamed,
    /// no excitation analysis, the diagnosed model it was compensated with.
    fn write_channel_output(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::Renamed {
                channel,
                original,
                column,
            } => write!(
                f,
                "the input already has a '{original}' column (kept unchanged); magcomp's compensation of '{channel}' is in '{column}'"
            ),
            Note::NoExcitationAnalysis { channel, why } => write!(f, "{channel}: no excitation analysis: {why}"),
            Note::DiagnosedModel { channel, model } => {
                write!(f, "{channel}: fitted and compensated with the diagnosed model: {model}")
            }
            Note::QuietStation {
                column,
                filter,
                noise_nt,
                channels,
            } => {
                let channels = channels.join(", ");
                match filter {
                    StationFilter::LowPassed {
                        corner_hz,
                        recorded_samples,
                    } => {
                        write!(
                            f,
                            "base station '{column}': low-passed at {corner_hz:.3} Hz before the fit of {channels} subtracts it; above that its record is its own noise ({noise_nt:.4} nT), which would enter the fit"
                        )?;
                        match recorded_samples {
                            0 => Ok(()),
                            n => write!(
                                f,
                                "; {n} of its samples, in runs between gaps too short to filter, are subtracted as recorded, that noise included"
                            ),
                        }
                    }
                    StationFilter::SignalToNyquist => write!(
                        f,
                        "base station '{column}': subtracted as recorded before the fit of {channels}; it records more of the external field than of its own noise ({noise_nt:.4} nT) up to its Nyquist frequency"
                    ),
                    StationFilter::NoNoise => write!(
                        f,
                        "base station '{column}': subtracted as recorded before the fit of {channels}; it has no noise of its own to take out (sampled slower than the flight and held or interpolated between samples)"
                    ),
                    StationFilter::TooShort => write!(
                        f,
                        "base station '{column}': subtracted as recorded before the fit of {channels}, its own noise ({noise_nt:.4} nT) included: no run of its valid samples is long enough to filter"
                    ),
                }
            }
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a note on a saved model applied to this flight.
    fn write_saved_model(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::AircraftUnnamed {
                calibration_named,
                flight_named,
            } => write!(
                f,
                "the aircraft is not named for {}: magcomp cannot check that the model is this airframe's (name it with [[flight]] aircraft)",
                match (calibration_named, flight_named) {
                    (false, false) => "either flight",
                    (false, true) => "the calibration flight",
                    _ => "this flight",
                }
            ),
            Note::ModelOnItsOwnFlight => f.write_str(
                "the model was fitted on this very flight: its compensation is that of the calibration run",
            ),
            Note::ModelHeldOut { windows, own_flight: true } => write!(
                f,
                "the model is set against {windows} calibration window(s) of the flight it was fitted on: its FOM and IR here are in sample"
            ),
            Note::ModelHeldOut { windows, own_flight: false } => write!(
                f,
                "the model is held out on this flight's {windows} calibration window(s): its FOM and IR here are of a model fitted on another flight"
            ),
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a note on which of this flight's channels a saved
    /// model compensates, and with what: the channel's name, its findings,
    /// no vector compensation.
    fn write_saved_channels(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::ModelChannelOwnName { model, column } => write!(
                f,
                "the flight records the model's channel '{model}' under its own name: [model] channels' '{column}' is not used for it"
            ),
            Note::ModelChannelMapped { model, column } => write!(
                f,
                "the model's channel '{model}' compensates this flight's column '{column}' ([model] channels)"
            ),
            Note::NoSavedVectorCompensation { attitude: false } => {
                f.write_str("no vector compensation: the flight records no INS attitude (roll, pitch and yaw)")
            }
            Note::SavedFindings { channel, model } => {
                write!(f, "{channel}: compensated with the saved model's findings: {model}")
            }
            Note::NoSavedVectorCompensation { attitude: true } => f.write_str(
                "no vector compensation: the model holds no vector model (its calibration flight fitted none: no INS attitude, or [vector] enabled = false there)",
            ),
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a note on the calibration: windows not detected,
    /// the fluxgate's own calibration.
    fn write_calibration(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::FluxgateCalibrated {
                sensor,
                reference,
                scale: [sx, sy, sz],
                non_orthogonality_deg: [nx, ny, nz],
                offset_nt: [ox, oy, oz],
                mismatch_rms_nt: [before, after],
                rows,
            } => write!(
                f,
                "{sensor} calibrated against {reference}: scale {sx:.4} {sy:.4} {sz:.4}, non-orthogonality {nx:.3} {ny:.3} {nz:.3}°, offset {ox:.1} {oy:.1} {oz:.1} nT; |B| mismatch {before:.2} → {after:.2} nT RMS over {rows} rows"
            ),
            Note::WindowHeadings { headings_deg, without } => write_window_headings(f, headings_deg, *without),
            Note::LinesAsWindows { lines, headings } => {
                let lines: Vec<String> = lines.iter().map(f64::to_string).collect();
                write!(
                    f,
                    "no calibration manoeuvre was detected on line(s) {}: each line's whole span is a calibration window",
                    lines.join(", ")
                )?;
                match headings {
                    Some(note) => write!(f, "; {note}"),
                    None => Ok(()),
                }
            }
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a note of the reduced columns.
    fn write_reduced(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::BaseStationRemoved {
                station,
                median_nt,
                total_field: false,
            } => write!(
                f,
                "reduced columns: the base station '{station}' records the variation (median {median_nt:.1} nT), removed as recorded"
            ),
            Note::BaseStationRemoved {
                station,
                median_nt,
                total_field: true,
            } => write!(
                f,
                "reduced columns: the base station '{station}' records the total field; its variation about its median over the flight ({median_nt:.1} nT) is removed"
            ),
            Note::MainFieldRemoved { day, position, height } => write!(
                f,
                "reduced columns: IGRF-14 for {day} at '{position}'{} removed for _igrf",
                if *height { "" } else { " (no height column: at sea level)" }
            ),
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a note of a channel's fit: its estimator table and
    /// its transfer between boxes.
    fn write_fit(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::NoEstimatorTable { channel } => write!(
                f,
                "{channel}: no estimator table: the calibration windows do not give three headings (a window given by time that spans a turn has none), so no estimator can be held out by heading"
            ),
            Note::EstimatorTableLacks { channel, families } => write!(
                f,
                "{channel}: the estimator table lacks {}: no split of the headings could be fitted by it",
                families.join(", ")
            ),
            Note::NoBoxTransfer { channel, number, why } => {
                write!(f, "{channel}: no box transfer from box {number}: {why}")
            }
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a note of a gradient.
    fn write_gradient(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::GradientFormed {
                column,
                channels: [a, b],
                separation_m,
                direct,
                reason,
                held_out,
            } => {
                write!(
                    f,
                    "{column}: ({a} − {b})/{separation_m:.3} m, from the {} ({reason})",
                    if *direct {
                        "model fitted to the difference"
                    } else {
                        "difference of the compensated channels"
                    }
                )?;
                match held_out {
                    Some((headings, direct, difference)) => write!(
                        f,
                        "; held out by heading ({headings} headings): direct {direct:.5} nT/m, difference {difference:.5} nT/m"
                    ),
                    None => Ok(()),
                }
            }
            Note::GradientFromSavedChannels {
                column,
                channels: [a, b],
                separation_m,
            } => write!(
                f,
                "{column}: ({a} − {b})/{separation_m:.3} m, from the difference of the channels the saved model compensated (a direct fit needs a calibration box)"
            ),
            Note::GradientDifferenceUsed { parting } => {
                write!(f, "{parting}: the direct fit is at odds, and the output uses the difference")
            }
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a note of the flight against its plan.
    fn write_plan(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::PlanLacksChannel { channel, report } => write!(
                f,
                "{channel}: not in the plan ({}), so not compared with it",
                report.display()
            ),
            Note::PlanChannelNotCompensated { channel, report } => write!(
                f,
                "{channel}: planned ({}) but not compensated on this flight",
                report.display()
            ),
            Note::PlanChannelFigures {
                channel,
                report,
                figures,
                as_planned,
            } => write!(
                f,
                "{channel}: against the plan ({}): {}; {}",
                report.display(),
                figures.join("; "),
                if *as_planned {
                    "as planned"
                } else {
                    "not as planned (see the warnings)"
                }
            ),
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a note of the manoeuvres flown against the plan's:
    /// not compared, unplanned, or with the plan's additions.
    fn write_plan_manoeuvres(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::PlanManoeuvresNotCompared { report, no_plan: true } => write!(
                f,
                "against the plan ({}): the report lists no planned manoeuvres (made by an older magcomp), so the manoeuvres flown are not compared with it",
                report.display()
            ),
            Note::PlanManoeuvresNotCompared { report, no_plan: false } => write!(
                f,
                "against the plan ({}): the calibration windows carry no manoeuvre kind and heading, so the manoeuvres flown are not compared with the plan's",
                report.display()
            ),
            Note::PlanUnplannedManoeuvres { report, manoeuvres } => write!(
                f,
                "against the plan ({}): the flight flew {} manoeuvre(s) the plan did not have ({})",
                report.display(),
                manoeuvres.len(),
                manoeuvres.join(", ")
            ),
            Note::PlanWithAdditions { report, additions } => write!(
                f,
                "against the plan ({}): the flight flew the plan's {additions} proposed additions, so it is compared with the prediction with them",
                report.display()
            ),
            _ => write!(f, "{self:?}"),
        }
    }

    /// The sentence of a note of the box's detection.
    fn write_detection(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::Detected {
                manoeuvres,
                boxes,
                from_fluxgate,
            } => write!(
                f,
                "calibration windows detected: {manoeuvres} manoeuvres in {boxes} box(es), attitude from {}",
                if *from_fluxgate { "the fluxgate" } else { "the INS" }
            ),
            Note::AttitudeFromFluxgate => f.write_str(
                "no INS attitude in the file: legs and manoeuvres come from the fluxgate's field direction; headings are magnetic",
            ),
            Note::NoManoeuvres => f.write_str("no calibration manoeuvres found"),
            Note::ManoeuvresByLine { counts } => {
                let counts: Vec<String> = (counts.iter())
                    .map(|(line, on_line)| format!("{on_line} on line {line}"))
                    .collect();
                write!(f, "calibration data by line: manoeuvres detected {}", counts.join(", "))
            }
            _ => write!(f, "{self:?}"),
        }
    }
}

impl Serialize for Note {
    /// As its sentence: the quality JSON's `notes` are sentences.
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

/// "3 days before this flight", "1 day after this flight", "the same day
/// as this flight": `days` from the calibration to the flight.
pub fn days_from(days: i64) -> String {
    let count = days.unsigned_abs();
    let unit = if count == 1 { "day" } else { "days" };
    match days {
        0 => "the same day as this flight".into(),
        d if d > 0 => format!("{count} {unit} before this flight"),
        _ => format!("{count} {unit} after this flight"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_held_back_finding_reads_as_the_run_has_always_said_it() {
        let reason = HeldBack::BeyondCalibration {
            survey_nt: 0.32,
            calibration_nt: 0.1,
            factor: 3.0,
            floor_nt: 0.01,
        };
        let warning = Warning::FindingsHeldBack {
            channel: "mag_2_uc".into(),
            findings: vec!["aux_coupling from cur_ail".into()],
            reason,
        };
        assert_eq!(
            warning.to_string(),
            "mag_2_uc: the diagnosis's aux_coupling from cur_ail not applied: on the survey it would move the compensation by 0.3200 nT RMS, more than 3 times what it does over the calibration (0.1000 nT) plus 0.01 nT: it would act beyond anything the box tested, so the channel is compensated with plain Tolles-Lawson"
        );
        assert_eq!(warning.channel(), Some("mag_2_uc"));
        let json = serde_json::to_string(std::slice::from_ref(&warning)).unwrap();
        assert_eq!(json, serde_json::to_string(&[warning.to_string()]).unwrap());
    }

    #[test]
    fn a_gradients_warnings_read_as_the_run_has_always_said_them() {
        let level = |moved_nt_per_m| {
            Warning::GradientLevelUnpinned {
                column: "grad_4_5_c".into(),
                channels: ["mag_4_uc".into(), "mag_5_uc".into()],
                separation_m: 15.0,
                moved_nt_per_m,
            }
            .to_string()
        };
        let unpinned = "grad_4_5_c: the gradient's level is not pinned by the calibration: the aircraft's steady field differs between mag_4_uc and mag_5_uc by an amount no manoeuvre reveals, up to the aircraft's field at the sensors over 15.00 m";
        let advice = "; use its variation along the lines, or level it to tie lines";
        assert_eq!(level(0.0), format!("{unpinned}{advice}"));
        assert_eq!(
            level(-0.0123),
            format!("{unpinned} ([fit] level moved it by -0.0123 nT/m){advice}")
        );
        let parting = GradientParting {
            column: "grad_4_5_c".into(),
            channels: ["mag_4_uc".into(), "mag_5_uc".into()],
            apart_nt_per_m: 0.02,
            separation_m: 15.0,
        };
        let at_odds = Warning::GradientDirectAtOdds { parting };
        assert_eq!(
            at_odds.to_string(),
            "grad_4_5_c: the direct fit and the difference of the compensated channels part on the survey lines by 0.0200 nT/m (RMS about their mean difference, 0.300 nT over 15.00 m), more than they differ held out, while neither mag_4_uc nor mag_5_uc is marked uncertain: the direct fit, which the output uses, is likely wrong there by about that much; use [[gradient]] method = \"auto\" or \"difference\", or fly a fuller box"
        );
        let none = Warning::GradientNotCompensated {
            column: "grad_4_5_c".into(),
            reason: "the saved model compensates mag_4_uc and not both of 'mag_4_uc' and 'mag_5_uc'".into(),
        };
        assert_eq!(
            none.to_string(),
            "grad_4_5_c: no gradient compensation: the saved model compensates mag_4_uc and not both of 'mag_4_uc' and 'mag_5_uc'"
        );
        assert!(at_odds.channel().is_none() && none.channel().is_none());
    }

    #[test]
    fn the_vector_stages_warnings_read_as_the_run_has_always_said_them() {
        let off = |dated| {
            Warning::VectorDirectionOff {
                sensor: "flux_b".into(),
                angle_deg: 0.734,
                inclination_off_deg: -0.61,
                declination_off_deg: 0.4,
                bound_deg: 0.5,
                dated,
                across_nt: 640.6,
            }
            .to_string()
        };
        let angle = "flux_b: the vector-compensated field's direction is 0.73° from IGRF-14's (-0.61° in inclination, 0.40° in declination; more than 0.5°)";
        let advice = ": check the INS attitude convention (CONTRACT §1), the position columns and the flight's date; the vector may be rotated by as much, 641 nT across the field";
        assert_eq!(off(true), format!("{angle}{advice}"));
        assert_eq!(
            off(false),
            format!("{angle} with no flight date (IGRF taken at 2025.0){advice}")
        );
        let swings = Warning::VectorScaleSwings {
            sensor: "flux_b".into(),
            reference: "mag_1_uc".into(),
            swing_nt: 12.34,
        };
        assert!(swings
            .to_string()
            .starts_with("flux_b: the vector's scale rests on mag_1_uc's level over the box, where the aircraft's modelled field swings by 12.3 nT RMS: "));
        let uncertain = Warning::VectorLevelUncertain {
            sensor: "flux_b".into(),
            reference: "mag_1_uc".into(),
            sigma_nt: 12.34,
        };
        assert!(uncertain
            .to_string()
            .contains("mag_1_uc's level, its modelled interference taken out, but the aircraft's isotropic induced field at that sensor, which no manoeuvre shows, leaves it uncertain by ±12.3 nT"));
        let unverified = Warning::VectorSignUnverified {
            sensor: "flux_b".into(),
            inclination_deg: 71.234,
            declination_deg: -3.456,
            mounting: "axes x/y/z".into(),
        };
        assert!(unverified
            .to_string()
            .contains("right-handed: inclination 71.23°, declination -3.46°, axes x/y/z. Set [site]"));
        let failed = |model: Option<&str>| {
            Warning::VectorNotCompensated {
                sensor: "flux_b".into(),
                model: model.map(std::path::PathBuf::from),
                reason: "no column flux_b_x".into(),
            }
            .to_string()
        };
        assert_eq!(failed(None), "flux_b: no vector compensation: no column flux_b_x");
        assert_eq!(
            failed(Some("out/model.json")),
            "flux_b: no vector compensation from the model out/model.json: no column flux_b_x"
        );
        let stage = Warning::VectorTollesLawson {
            sensor: "flux_b".into(),
            reason: "fewer rows than terms".into(),
        };
        assert_eq!(stage.to_string(), "flux_b: vector Tolles-Lawson: fewer rows than terms");
        // A fluxgate is not a scalar channel.
        assert!(stage.channel().is_none() && Warning::VectorNoReference.channel().is_none());
    }

    #[test]
    fn a_saved_models_warnings_read_as_the_run_has_always_said_them() {
        let model = std::path::PathBuf::from("cal/model.json");
        let old = Warning::ModelTooOld {
            model: model.clone(),
            age_days: 45,
            max_age_days: 30,
        };
        assert_eq!(
            old.to_string(),
            "the model cal/model.json was calibrated 45 days before this flight, more than [model] max_age_days = 30: an installation changes (equipment moved, repairs, a new instrument); fly a new calibration box, or check this flight's heading error and noise against the calibration flight's"
        );
        let failed = Warning::ModelCalibrationFailed {
            channel: "mag_1_uc".into(),
            model: model.clone(),
            fom_nt: 1.234,
            limit_nt: 0.1,
        };
        assert!(failed.to_string().starts_with(
            "mag_1_uc: the model cal/model.json had a FOM of 1.23 nT on its calibration flight, above the 0.10 nT limit ([quality] fom_limit_nt)"
        ));
        let rate = |rescaled: Vec<String>| {
            Warning::ModelRateDiffers {
                model: model.clone(),
                fitted_hz: 10.0,
                flight_hz: 20.0,
                rescaled,
            }
            .to_string()
        };
        assert!(rate(vec!["mag_1_uc (eddy_xy, eddy_xz)".into()]).starts_with(
            "the model cal/model.json was fitted at 10.000 Hz and this flight is recorded at 20.000 Hz: its per-sample terms (eddy currents, the field's derivative) were rescaled by the rates' ratio, 2.000: mag_1_uc (eddy_xy, eddy_xz); they carry the fluxgate's noise 2.00× as strongly as on the calibration flight. The fit's band"
        ));
        assert!(rate(Vec::new()).contains("20.000 Hz: it has no per-sample term to rescale. The fit's band"));
        let lacks = |channels: &[&str]| {
            Warning::ModelLacksChannels {
                model: model.clone(),
                channels: channels.iter().map(|c| c.to_string()).collect(),
            }
            .to_string()
        };
        assert!(lacks(&["mag_2_uc"]).starts_with(
            "mag_2_uc not compensated: the model cal/model.json holds no model of it; calibrate it on a flight with a box"
        ));
        assert!(lacks(&["mag_2_uc", "mag_3_uc"]).starts_with(
            "mag_2_uc, mag_3_uc not compensated: the model cal/model.json holds no model of them; calibrate them"
        ));
        assert_eq!(failed.channel(), Some("mag_1_uc"));
        assert!(old.channel().is_none());
        let forced = Warning::DiagnosisForced {
            diagnosis: "d.json".into(),
            made_on: "a.csv (10 rows)".into(),
            applied_to: "b.csv (12 rows)".into(),
            difference: "2 rows more".into(),
        };
        assert_eq!(
            forced.to_string(),
            "d.json was made on a.csv (10 rows), not on b.csv (12 rows) (2 rows more); applied anyway because of --force"
        );
        let unchecked = Warning::DiagnosisUnchecked {
            diagnosis: "d.json".into(),
            flight: "b.csv".into(),
        };
        assert_eq!(
            unchecked.to_string(),
            "d.json does not record the flight it was made on (an older magcomp wrote it), so it was applied to b.csv without checking that it belongs to it"
        );
    }

    #[test]
    fn days_read_as_words() {
        assert_eq!(days_from(3), "3 days before this flight");
        assert_eq!(days_from(1), "1 day before this flight");
        assert_eq!(days_from(0), "the same day as this flight");
        assert_eq!(days_from(-45), "45 days after this flight");
    }

    #[test]
    fn the_inputs_and_outputs_warnings_read_as_the_run_has_always_said_them() {
        let other = Warning::WindowsFromOtherFlight {
            windows_file: "w.json".into(),
            detected_on: "flight.csv (100 rows)".into(),
            flight: "other.csv (90 rows)".into(),
            difference: "10 rows fewer".into(),
        };
        assert_eq!(
            other.to_string(),
            "the calibration windows of w.json were detected on flight.csv (100 rows), not on this flight other.csv (90 rows) (10 rows fewer): check that they lie on this flight's manoeuvres, or detect them on it with `magcomp detect`"
        );
        let undated = Warning::McapUndated {
            output: "out.mcap".into(),
            time_column: "tt".into(),
        };
        assert_eq!(
            undated.to_string(),
            "out.mcap: the flight's day is unknown (no year and doy columns, no --date), so its MCAP log times count 'tt' from 1970-01-01; give the day with --date YYYY-MM-DD"
        );
        let text = Warning::TextColumnsNotWritten {
            input: "in.csv".into(),
            columns: vec!["remark".into(), "pilot".into()],
            output: "out.h5".into(),
        };
        assert_eq!(
            text.to_string(),
            "in.csv: the input's text column(s) 'remark', 'pilot' are not written to out.h5, which holds the numeric columns only; a compensated CSV or XYZ written from an input of the same format keeps them"
        );
        let saved = Warning::SavedWithoutJackknife {
            channel: "mag_1_uc".into(),
        };
        assert_eq!(
            saved.to_string(),
            "mag_1_uc: no sigma column: the model was saved without a jackknife (fitted on fewer than three windows, or with another solver)"
        );
        assert_eq!(saved.channel(), Some("mag_1_uc"));
        assert!(other.channel().is_none() && undated.channel().is_none() && text.channel().is_none());
    }

    #[test]
    fn a_move_nothing_on_the_survey_checks_names_the_stated_uncertainty_or_the_floor() {
        let reason = |stated_nt, levels_checked| HeldBack::UncheckedOnSurvey {
            survey_nt: 0.1022,
            stated_nt,
            explained_nt: 0.0259,
            floor_nt: 0.01,
            levels_checked,
        };
        let said = |stated_nt| reason(stated_nt, false).to_string();
        let head = "on the survey it would move the compensation by 0.1022 nT RMS, beyond";
        let tail = "while on the box it explains only 0.0259 nT of the held-out RMS, within it; and the survey has nothing to check that move against (no crossovers with a base station to level at, no block of parallel lines flown both ways)";
        assert_eq!(
            said(Some(0.0545)),
            format!("{head} the uncertainty the channel states outside the calibration (0.0545 nT), {tail}")
        );
        assert_eq!(said(Some(0.004)), format!("{head} 0.01 nT, {tail}"));
        assert_eq!(said(None), said(Some(0.004)));
        assert_eq!(
            reason(Some(0.0545), true).to_string(),
            format!("{head} the uncertainty the channel states outside the calibration (0.0545 nT), while on the box it explains only 0.0259 nT of the held-out RMS, within it; and the survey's line levels cannot check that move (a lag moves the geology along the lines, which their levels do not show)")
        );
    }

    #[test]
    fn the_detections_warnings_read_as_the_run_has_always_said_them() {
        let named = Warning::NamedBySize {
            heading_deg: 91.6,
            alike: vec![("pitch".into(), "yaw".into())],
            manoeuvres: vec![(120.04, 151.0, "pitch".into()), (160.0, 190.96, "yaw".into())],
        };
        assert_eq!(
            named.to_string(),
            "heading 92° (magnetic): with the fluxgate alone a pitch and a yaw turn the field direction alike on this heading, so the manoeuvre(s) at 120.0–151.0 s as pitch and 160.0–191.0 s as yaw are named by size only; check them against the flight notes, or give the windows with --window"
        );
        assert_eq!(
            Warning::SteepField { dip_deg: 81.4 }.to_string(),
            "the field dips 81° at the fluxgate, which stands in for the INS: its horizontal part gives the heading weakly and a yaw barely turns the field direction, so manoeuvres reported missing may have been flown and not seen. Give the INS attitude (ins_pitch, ins_roll, ins_yaw) or the windows with --window"
        );
        let gaps = Warning::AttitudeGaps {
            spans: vec![(10.0, 12.24), (300.0, 301.0)],
        };
        assert_eq!(
            gaps.to_string(),
            "the INS attitude is missing over 10.0–12.2 s, 300.0–301.0 s: legs or manoeuvres flown there cannot be seen, so what is reported missing may have been flown there; give the windows with --window if so"
        );
        assert!([named, gaps].iter().all(|w| w.channel().is_none()));
    }

    #[test]
    fn the_quality_warnings_read_as_the_run_has_always_said_them() {
        let step = "Refly the box".to_string();
        let cases = [
            (
                Warning::FomAboveLimit {
                    channel: "mag_1_uc".into(),
                    fom_nt: 1.234,
                    manoeuvres: 11,
                    limit_nt: 1.5 - 0.25,
                    next_step: step.clone(),
                },
                "mag_1_uc: FOM 1.23 nT after compensation (11 of 12 manoeuvres), above the 1.25 nT limit ([quality] fom_limit_nt). Refly the box",
            ),
            (
                Warning::NoiseRaised {
                    channel: "mag_1_uc".into(),
                    before_nt: 0.01,
                    after_nt: 0.025,
                    next_step: step.clone(),
                },
                "mag_1_uc: compensation raised the survey lines' fourth-difference noise from 0.0100 to 0.0250 nT (2.50×): the model adds more than it removes there. Refly the box",
            ),
            (
                Warning::CrossoversRaised {
                    channel: "mag_3_uc".into(),
                    before_nt: 0.1,
                    after_nt: 0.3,
                    crossovers: 7,
                    station_removed: false,
                    next_step: step.clone(),
                },
                "mag_3_uc: compensation raised the RMS difference between the passes where survey lines cross from 0.100 to 0.300 nT over 7 crossovers (the flight has no base station, so this includes the external field's change between the passes). Refly the box",
            ),
            (
                Warning::OutputOutOfRange {
                    subject: "flux_b".into(),
                    rows: 1,
                    first: 12.5,
                },
                "flux_b: 1 compensated row lie beyond what the instrument reads (a total field outside 1,000-100,000 nT, a component beyond ±100,000 nT), the first at 12.5 s; they are written and flagged output_out_of_range:flux_b. The model was applied far from what it was fitted on: look at the attitude and fluxgate there, and at the calibration windows",
            ),
        ];
        for (warning, sentence) in cases {
            assert_eq!(warning.to_string(), sentence);
        }
        let transfer = Warning::PoorTransfer {
            channel: "mag_2_uc".into(),
            sentence: "mag_2_uc: fitted without each heading in turn, worse".into(),
            next_step: step,
        };
        assert_eq!(
            transfer.to_string(),
            "mag_2_uc: fitted without each heading in turn, worse. Refly the box"
        );
        assert_eq!(transfer.channel(), Some("mag_2_uc"));
    }

    #[test]
    fn masked_samples_read_as_the_run_has_always_said_them() {
        let masked = |samples: usize| Warning::Masked {
            column: "flux_a_x".into(),
            samples,
            reason: "values beyond what the instrument reads".into(),
            first_time: 46012.3,
            first_value: 1e308,
            flag: "out_of_range".into(),
        };
        assert_eq!(
            masked(2).to_string(),
            "masked 2 samples of flux_a_x (values beyond what the instrument reads), the first at 46012.3 s (1e308); every stage treats them as missing, and their rows are flagged out_of_range:flux_a_x"
        );
        assert_eq!(
            masked(1).to_string(),
            "masked 1 sample of flux_a_x (values beyond what the instrument reads), the first at 46012.3 s (1e308); every stage treats it as missing, and its row is flagged out_of_range:flux_a_x"
        );
        assert_eq!(masked(1).channel(), None);
    }

    #[test]
    fn an_unexplained_residual_reads_as_the_run_has_always_said_it() {
        let warning = Warning::Unexplained {
            channel: "mag_3_uc".into(),
            heldout_rms_nt: 0.12345,
            residual_to_noise: 1712.4,
            largest_on: vec!["roll@90".into(), "yaw@180".into()],
        };
        assert_eq!(
            warning.to_string(),
            "mag_3_uc: the diagnosis leaves an unexplained residual of 0.1235 nT held out, 1712 times the sensor noise in the band, largest on roll@90, yaw@180: the compensation of this channel is not good to the noise level; see the diagnosis's unexplained finding"
        );
        assert_eq!(warning.channel(), Some("mag_3_uc"));
    }

    /// The detection, gradient and plan notes print the sentences the
    /// stages always wrote.
    #[test]
    fn typed_notes_read_as_the_stages_have_always_said_them() {
        let cases = [
            (
                Note::Detected {
                    manoeuvres: 12,
                    boxes: 1,
                    from_fluxgate: false,
                },
                "calibration windows detected: 12 manoeuvres in 1 box(es), attitude from the INS".to_string(),
            ),
            (
                Note::ManoeuvresByLine {
                    counts: vec![(1002.2, 12), (1002.21, 0)],
                },
                "calibration data by line: manoeuvres detected 12 on line 1002.2, 0 on line 1002.21".into(),
            ),
            (
                Note::GradientFormed {
                    column: "grad_1_2_c".into(),
                    channels: ["mag_1_uc".into(), "mag_2_uc".into()],
                    separation_m: 5.0,
                    direct: true,
                    reason: "the smaller held-out residual".into(),
                    held_out: Some((4, 0.00123456, 0.002)),
                },
                "grad_1_2_c: (mag_1_uc − mag_2_uc)/5.000 m, from the model fitted to the difference (the smaller held-out residual); held out by heading (4 headings): direct 0.00123 nT/m, difference 0.00200 nT/m".into(),
            ),
            (
                Note::AircraftUnnamed {
                    calibration_named: false,
                    flight_named: true,
                },
                "the aircraft is not named for the calibration flight: magcomp cannot check that the model is this airframe's (name it with [[flight]] aircraft)".into(),
            ),
            (
                Note::ModelHeldOut {
                    windows: 3,
                    own_flight: false,
                },
                "the model is held out on this flight's 3 calibration window(s): its FOM and IR here are of a model fitted on another flight".into(),
            ),
            (
                Note::LinesAsWindows {
                    lines: vec![1001.0, 1002.0],
                    headings: Some(Box::new(Note::WindowHeadings {
                        headings_deg: vec![0.0, 180.0],
                        without: 1,
                    })),
                },
                "no calibration manoeuvre was detected on line(s) 1001, 1002: each line's whole span is a calibration window; 2 window(s) given by time take their leg's heading from the INS yaw (0°, 180°); 1 window(s) given by time span a turn or lack the yaw and keep no heading".into(),
            ),
            (
                Note::FluxgateCalibrated {
                    sensor: "flux_a".into(),
                    reference: "mag_1_uc".into(),
                    scale: [1.01321, 0.98631, 1.0118],
                    non_orthogonality_deg: [0.4521, -0.2991, 0.781],
                    offset_nt: [109.54, -49.42, 66.4],
                    mismatch_rms_nt: [194.214, 0.18],
                    rows: 16120,
                },
                "flux_a calibrated against mag_1_uc: scale 1.0132 0.9863 1.0118, non-orthogonality 0.452 -0.299 0.781°, offset 109.5 -49.4 66.4 nT; |B| mismatch 194.21 → 0.18 nT RMS over 16120 rows".into(),
            ),
            (
                Note::BaseStationRemoved {
                    station: "diurnal".into(),
                    median_nt: 50_012.34,
                    total_field: true,
                },
                "reduced columns: the base station 'diurnal' records the total field; its variation about its median over the flight (50012.3 nT) is removed".into(),
            ),
            (
                Note::MainFieldRemoved {
                    day: "2026-06-13".into(),
                    position: "lat/lon".into(),
                    height: false,
                },
                "reduced columns: IGRF-14 for 2026-06-13 at 'lat/lon' (no height column: at sea level) removed for _igrf".into(),
            ),
            (
                Note::EstimatorTableLacks {
                    channel: "mag_1_uc".into(),
                    families: vec!["Tls".into(), "Tsvd".into()],
                },
                "mag_1_uc: the estimator table lacks Tls, Tsvd: no split of the headings could be fitted by it".into(),
            ),
            (
                Note::NoBoxTransfer {
                    channel: "mag_2_uc".into(),
                    number: 2,
                    why: "no calibration windows".into(),
                },
                "mag_2_uc: no box transfer from box 2: no calibration windows".into(),
            ),
            (
                Note::PlanChannelFigures {
                    channel: "mag_1_uc".into(),
                    report: "PLAN_REPORT.json".into(),
                    figures: vec!["FOM 0.433 nT, planned 0.550".into(), "sigma column not compared".into()],
                    as_planned: false,
                },
                "mag_1_uc: against the plan (PLAN_REPORT.json): FOM 0.433 nT, planned 0.550; sigma column not compared; not as planned (see the warnings)".into(),
            ),
        ];
        for (note, sentence) in cases {
            assert_eq!(note.to_string(), sentence);
            assert_eq!(serde_json::to_value(&note).unwrap(), serde_json::json!(sentence));
        }
    }

    #[test]
    fn a_renamed_column_reads_as_the_run_has_always_said_it() {
        let note = Note::Renamed {
            channel: "mag_1_uc".into(),
            original: "mag_1_c".into(),
            column: "mag_1_c_magcomp".into(),
        };
        let sentence = "the input already has a 'mag_1_c' column (kept unchanged); magcomp's compensation of 'mag_1_uc' is in 'mag_1_c_magcomp'";
        assert_eq!(note.to_string(), sentence);
        assert_eq!(serde_json::to_value(&note).unwrap(), serde_json::json!(sentence));
    }
}
