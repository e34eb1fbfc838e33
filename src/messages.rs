//! What a run says to its user: typed warnings and notes.
//!
//! A [`Warning`] is something the user must look at before trusting an
//! output: a finding held back, a channel's survey moved beyond its stated
//! uncertainty, a figure that could not be computed. Each variant carries
//! its data, and its `Display` is the sentence printed on stdout, in the
//! report and in the quality JSON (serialised as that sentence, so the
//! JSON reads as it always has). Tests match the variants, not the words.
//!
//! The stages typed so far are the fit's own (the diagnosis's evidence
//! rule, the departure from plain Tolles-Lawson, the uncertainty and the
//! sigma column, the box and the solver). The other stages' warnings
//! (reading, screening, detection, the vector and gradient stages, the
//! plan) still come as their sentence: [`Warning::Said`].
//!
//! A [`Note`] is what the user may want to know (how a column was named,
//! which model a channel was fitted with, an analysis not made); it is
//! printed with `-v` and kept in the quality JSON and the report, and
//! typed the same way.

use std::fmt;

use serde::{Serialize, Serializer};

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
        }
    }
}

/// What a held-back channel gets instead of its findings.
pub const FITTED_PLAIN: &str = "so the channel is compensated with plain Tolles-Lawson";

/// Something the user must look at before trusting an output.
#[derive(Debug, Clone, PartialEq)]
pub enum Warning {
    /// A warning of a stage not typed yet, as its sentence.
    Said(String),
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
    /// The applied findings move the survey from plain Tolles-Lawson by
    /// more than the channel's stated uncertainty: no plain pass.
    SurveyDeparture {
        /// The scalar channel.
        channel: String,
        /// RMS of the move on the survey, nT.
        departure_nt: f64,
        /// The stated uncertainty outside the calibration, nT; `None`
        /// when none is stated.
        stated_nt: Option<f64>,
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
    /// The solver the settings ask for was not used.
    SolverNotUsed {
        /// The scalar channel.
        channel: String,
        /// Why, and what was used instead.
        reason: String,
    },
}

impl Warning {
    /// The scalar channel the warning is about, when it is about one.
    pub fn channel(&self) -> Option<&str> {
        match self {
            Warning::Said(_) | Warning::NotDiagnosed { .. } | Warning::IncompleteBox { .. } => None,
            Warning::FindingsHeldBack { channel, .. }
            | Warning::FindingsAppliedAnyway { channel, .. }
            | Warning::SurveyDeparture { channel, .. }
            | Warning::NoSigmaColumn { channel }
            | Warning::TooFewWindows { channel, .. }
            | Warning::NoUncertainty { channel, .. }
            | Warning::BoxGap { channel, .. }
            | Warning::SolverNotUsed { channel, .. } => Some(channel),
        }
    }

    /// Each sentence of an untyped stage as a [`Warning::Said`].
    pub fn said(sentences: impl IntoIterator<Item = String>) -> impl Iterator<Item = Warning> {
        sentences.into_iter().map(Warning::Said)
    }
}

impl From<String> for Warning {
    fn from(sentence: String) -> Self {
        Warning::Said(sentence)
    }
}

impl fmt::Display for Warning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Warning::Said(sentence) => f.write_str(sentence),
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
                departure_nt,
                stated_nt,
            } => write!(
                f,
                "{channel}: the diagnosed findings move the survey {departure_nt:.4} nT RMS from plain Tolles-Lawson, more than {}: the verdict is not a plain pass; compare with a plain run (--plain) before using this channel",
                match stated_nt {
                    Some(sigma) => format!("its stated uncertainty ({sigma:.4} nT)"),
                    None => "anything its uncertainty states (none is stated)".into(),
                }
            ),
            Warning::NoSigmaColumn { channel } => write!(
                f,
                "{channel}: no sigma column: the compensated channel's noise cannot be measured (too few consecutive samples)"
            ),
            Warning::TooFewWindows { channel, windows } => write!(
                f,
                "{channel}: fitted on {windows} calibration window(s), too few to leave one out: the compensation away from the calibration is not checked and has no uncertainty figure or sigma column. Give three or more windows, one per manoeuvre or leg (a window spanning a whole box is one window; `magcomp detect` finds the manoeuvres)"
            ),
            Warning::NoUncertainty { channel, why } => write!(f, "{channel}: no uncertainty figure: {why}"),
            Warning::BoxGap { channel, gap } => write!(f, "{channel}: {gap}"),
            Warning::SolverNotUsed { channel, reason } => write!(f, "{channel}: {reason}"),
        }
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
    /// A note of a stage not typed yet, as its sentence.
    Said(String),
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
}

impl Note {
    /// Each sentence of an untyped stage as a [`Note::Said`].
    pub fn said(sentences: impl IntoIterator<Item = String>) -> impl Iterator<Item = Note> {
        sentences.into_iter().map(Note::Said)
    }
}

impl From<String> for Note {
    fn from(sentence: String) -> Self {
        Note::Said(sentence)
    }
}

impl fmt::Display for Note {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Note::Said(sentence) => f.write_str(sentence),
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
            Note::UnitsRow { path, units } => {
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
            Note::SavedFindings { channel, model } => {
                write!(f, "{channel}: compensated with the saved model's findings: {model}")
            }
        }
    }
}

impl Serialize for Note {
    /// As its sentence: the quality JSON's `notes` are sentences.
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
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

    #[test]
    fn an_untyped_stage_keeps_its_sentence() {
        let warning = Warning::from("box 1 (0.0–10.0) is incomplete".to_string());
        assert_eq!(warning.to_string(), "box 1 (0.0–10.0) is incomplete");
        assert_eq!(warning.channel(), None);
    }
}
