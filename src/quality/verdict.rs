//! A channel's one verdict: `FAIL` > `CHECK` > `PASS`, in that order of
//! precedence, with the reasons in words.
//!
//! The verdict reads the figures of the flight the model compensates, not
//! only those of the box it was fitted on:
//! - **FAIL** when the FOM exceeds the limit (`[quality] fom_limit_nt`);
//!   when the compensation scales a crustal anomaly by more than the
//!   tolerance (`[quality] anomaly_gain_tolerance`); or when the model
//!   makes a survey-side figure clearly worse than the uncompensated
//!   record: the heading level between neighbouring lines flown both ways,
//!   or the crossover differences ([`clearly_worse`]).
//! - **CHECK** when what the diagnosis added moves the survey from plain
//!   Tolles-Lawson beyond the stated uncertainty, or when nothing on the
//!   flight checks the model (no FOM and no survey-side figure).
//! - **PASS** otherwise.
//!
//! The same word goes to stdout, the run table, the quality JSON
//! (`verdict`), the campaign summary, the report and the saved model; a run
//! with a FAIL exits with code 3 (docs/CONTRACT.md §2).

use serde::{Deserialize, Serialize};

use super::ChannelQuality;

/// A channel's verdict; the order of the variants is their precedence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "UPPERCASE")]
pub enum Verdict {
    /// Every figure within its limit.
    Pass,
    /// Usable, but the reasons say what to look at before signing off.
    Check,
    /// A figure beyond its limit: the channel is not to be delivered as it is.
    Fail,
}

impl Verdict {
    /// "PASS", "CHECK" or "FAIL".
    pub fn word(self) -> &'static str {
        match self {
            Verdict::Pass => "PASS",
            Verdict::Check => "CHECK",
            Verdict::Fail => "FAIL",
        }
    }

    /// The verdict of a word as the quality JSON writes it.
    pub fn from_word(word: &str) -> Option<Self> {
        match word {
            "PASS" => Some(Verdict::Pass),
            "CHECK" => Some(Verdict::Check),
            "FAIL" => Some(Verdict::Fail),
            _ => None,
        }
    }
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.word())
    }
}

/// A survey-side figure is clearly worse when the compensated one exceeds
/// the uncompensated one by this factor...
pub const SURVEY_WORSE_FACTOR: f64 = 1.5;

/// ...and by at least this much, nT: a tenth of a nT more on lines whose
/// heading level was already a few tenths decides nothing. A model of
/// another airframe raised a real survey's heading level from 9.9 to 75.8
/// nT and from 2.5 to 4.7 nT.
pub const SURVEY_WORSE_FLOOR_NT: f64 = 1.0;

/// Whether `after` is clearly worse than `before` ([`SURVEY_WORSE_FACTOR`],
/// [`SURVEY_WORSE_FLOOR_NT`]).
pub fn clearly_worse(before_nt: f64, after_nt: f64) -> bool {
    after_nt > before_nt * SURVEY_WORSE_FACTOR && after_nt > before_nt + SURVEY_WORSE_FLOOR_NT
}

/// The limits a verdict is judged against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VerdictLimits {
    /// The FOM limit, nT (`[quality] fom_limit_nt`).
    pub fom_limit_nt: f64,
    /// How far the anomaly gain may depart from 1
    /// (`[quality] anomaly_gain_tolerance`).
    pub anomaly_gain_tolerance: f64,
}

/// Why a channel is not a plain PASS.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum VerdictReason {
    /// The FOM exceeds the limit.
    FomAboveLimit {
        /// FOM after compensation, nT.
        fom_nt: f64,
        /// The limit, nT.
        limit_nt: f64,
    },
    /// The compensation scales a crustal anomaly beyond the tolerance.
    AnomalyGain {
        /// The median gain over the survey rows.
        gain: f64,
        /// The tolerance on |gain − 1|.
        tolerance: f64,
    },
    /// A survey-side figure the model made clearly worse.
    SurveyWorse {
        /// Which figure: "heading level between neighbouring lines" or
        /// "crossover differences".
        figure: &'static str,
        /// Uncompensated, nT.
        before_nt: f64,
        /// Compensated, nT.
        after_nt: f64,
    },
    /// A survey-side figure the model made clearly worse, within the
    /// figure's own uncertainty.
    SurveyWorseUncertain {
        /// Which figure.
        figure: &'static str,
        /// Uncompensated, nT.
        before_nt: f64,
        /// Compensated, nT.
        after_nt: f64,
        /// The figure's standard error, nT, where it has one.
        standard_error_nt: Option<f64>,
    },
    /// The heading level between neighbouring lines carries the
    /// aircraft's heading effect and the model leaves more than
    /// [`NOT_COMPENSATED_FRACTION`] of it: the model does not compensate
    /// this flight.
    SurveyNotCompensated {
        /// Which figure.
        figure: &'static str,
        /// Uncompensated, nT.
        before_nt: f64,
        /// Compensated, nT.
        after_nt: f64,
    },
    /// The findings move the survey from plain Tolles-Lawson beyond the
    /// stated uncertainty.
    Departure {
        /// The departure, RMS over the survey, nT.
        departure_nt: f64,
        /// The stated uncertainty, nT, when there is one.
        stated_nt: Option<f64>,
        /// Which to use, and the survey's figures that say so.
        advice: String,
    },
    /// A saved model's FOM on its calibration flight was above the limit
    /// (this flight has no box of its own to measure one).
    CalibrationFomAboveLimit {
        /// The calibration flight's FOM after compensation, nT.
        fom_nt: f64,
        /// The limit, nT.
        limit_nt: f64,
    },
    /// Neither a FOM nor a survey-side figure of this flight checks the
    /// model.
    Unchecked {
        /// A saved model's FOM on its calibration flight, nT, the only
        /// figure behind it.
        calibration_fom_nt: Option<f64>,
    },
}

/// What a saved model's calibration flight said of a channel, for the
/// verdict of a flight compensated with it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CalibrationVerdict {
    /// The FOM after compensation on the calibration flight, nT.
    pub fom_after_nt: Option<f64>,
}

impl VerdictReason {
    /// The verdict this reason alone gives.
    pub fn verdict(&self) -> Verdict {
        match self {
            VerdictReason::Departure { .. }
            | VerdictReason::Unchecked { .. }
            | VerdictReason::SurveyWorseUncertain { .. }
            | VerdictReason::SurveyNotCompensated { .. } => Verdict::Check,
            _ => Verdict::Fail,
        }
    }
}

impl std::fmt::Display for VerdictReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            VerdictReason::FomAboveLimit { fom_nt, limit_nt } => {
                write!(f, "FOM {fom_nt:.2} nT is above the limit of {limit_nt:.2} nT")
            }
            VerdictReason::AnomalyGain { gain, tolerance } => write!(
                f,
                "the compensation scales a crustal anomaly by {gain:.3}, beyond 1 ± {tolerance}: the map's amplitudes would not be the ground's"
            ),
            VerdictReason::SurveyWorse {
                figure,
                before_nt,
                after_nt,
            } => write!(
                f,
                "this model raises the {figure} from {before_nt:.2} to {after_nt:.2} nT: is it this aircraft's, and this installation's?"
            ),
            VerdictReason::SurveyNotCompensated {
                figure,
                before_nt,
                after_nt,
            } => write!(
                f,
                "this model leaves the {figure} at {after_nt:.2} nT against {before_nt:.2} nT uncompensated: it does not compensate this flight's heading effect; is it this aircraft's, and this installation's?"
            ),
            VerdictReason::SurveyWorseUncertain {
                figure,
                before_nt,
                after_nt,
                standard_error_nt,
            } => write!(
                f,
                "this model raises the {figure} from {before_nt:.2} to {after_nt:.2} nT, {}: compare a tie line or a reflown line before delivering this channel",
                match standard_error_nt {
                    Some(se) => format!("within {HEADING_LEVEL_STANDARD_ERRORS} standard errors of the geology's scatter ({se:.2} nT)"),
                    None => "on too few lines to tell the model from the geology".to_string(),
                }
            ),
            VerdictReason::Departure {
                departure_nt,
                stated_nt,
                advice,
            } => write!(
                f,
                "what the diagnosis added moves the survey {departure_nt:.4} nT from plain Tolles-Lawson, beyond the stated uncertainty{}: {advice}",
                stated_nt.map(|s| format!(" of {s:.4} nT")).unwrap_or_default()
            ),
            VerdictReason::CalibrationFomAboveLimit { fom_nt, limit_nt } => write!(
                f,
                "on its calibration flight the model's FOM was {fom_nt:.2} nT, above the limit of {limit_nt:.2} nT"
            ),
            VerdictReason::Unchecked { calibration_fom_nt } => write!(
                f,
                "nothing on this flight checks the model: no labelled manoeuvres for a FOM, no reciprocal lines, no block of lines flown both ways, no crossing lines{}; fly a tie line across the survey, or lines both ways, to check it here",
                match calibration_fom_nt {
                    Some(fom) => format!(" (only its calibration flight's FOM of {fom:.2} nT is behind it)"),
                    None => String::new(),
                }
            ),
        }
    }
}

/// Every reason `quality` is not a plain PASS, in order of precedence;
/// `calibration`, for a flight compensated with a saved model, what its
/// calibration flight said.
pub fn reasons(
    quality: &ChannelQuality,
    limits: &VerdictLimits,
    calibration: Option<CalibrationVerdict>,
) -> Vec<VerdictReason> {
    let mut reasons = Vec::new();
    if let Some(fom_nt) = quality.fom_after_nt.filter(|f| *f > limits.fom_limit_nt) {
        reasons.push(VerdictReason::FomAboveLimit {
            fom_nt,
            limit_nt: limits.fom_limit_nt,
        });
    }
    let calibration_fom_nt = calibration.and_then(|c| c.fom_after_nt);
    if let Some(fom_nt) = calibration_fom_nt.filter(|f| quality.fom_after_nt.is_none() && *f > limits.fom_limit_nt) {
        reasons.push(VerdictReason::CalibrationFomAboveLimit {
            fom_nt,
            limit_nt: limits.fom_limit_nt,
        });
    }
    if let Some(gain) = quality
        .anomaly_gain
        .filter(|g| (g - 1.0).abs() > limits.anomaly_gain_tolerance)
    {
        reasons.push(VerdictReason::AnomalyGain {
            gain,
            tolerance: limits.anomaly_gain_tolerance,
        });
    }
    reasons.extend(survey_worse(quality));
    if let Some((departure_nt, stated_nt)) = quality.unchecked_departure() {
        reasons.push(VerdictReason::Departure {
            departure_nt,
            stated_nt,
            advice: which_to_use(quality),
        });
    }
    let survey_checked =
        quality.heading_level.is_some() || quality.crossovers.is_some() || quality.heading_error.is_some();
    if quality.fom_after_nt.is_none() && !survey_checked {
        reasons.push(VerdictReason::Unchecked { calibration_fom_nt });
    }
    reasons.sort_by_key(|r| std::cmp::Reverse(r.verdict()));
    reasons
}

/// Standard errors of the heading level a rise must exceed besides
/// [`clearly_worse`]'s factor and floor: the level is known only to the
/// geology's curvature across neighbouring lines.
pub const HEADING_LEVEL_STANDARD_ERRORS: f64 = 3.0;

/// Fewest triples of neighbouring lines whose heading level can fail a
/// model: two leave no scatter to judge the level by (its standard error
/// is zero), and a near-perfect compensation of a clean simulated survey
/// of four lines raised it from 1.79 to 3.37 nT, the geology's, not the
/// model's.
pub const HEADING_LEVEL_LEAST_TRIPLES: usize = 3;

/// The survey-side figures the model made clearly worse: FAIL where the
/// rise stands beyond the figure's own uncertainty, CHECK where it does
/// not (the heading level of too few lines, or within
/// [`HEADING_LEVEL_STANDARD_ERRORS`] of the geology's scatter).
fn survey_worse(quality: &ChannelQuality) -> Vec<VerdictReason> {
    let mut reasons = Vec::new();
    if let Some(f) = quality
        .heading_level
        .as_ref()
        .filter(|f| clearly_worse(f.before_nt, f.after_nt))
    {
        let figure = "heading level between neighbouring lines";
        let certain = f.triples >= HEADING_LEVEL_LEAST_TRIPLES
            && f.after_nt - f.before_nt > HEADING_LEVEL_STANDARD_ERRORS * f.standard_error_nt;
        reasons.push(match certain {
            true => VerdictReason::SurveyWorse {
                figure,
                before_nt: f.before_nt,
                after_nt: f.after_nt,
            },
            false => VerdictReason::SurveyWorseUncertain {
                figure,
                before_nt: f.before_nt,
                after_nt: f.after_nt,
                standard_error_nt: (f.triples >= HEADING_LEVEL_LEAST_TRIPLES).then_some(f.standard_error_nt),
            },
        });
    }
    let crossovers = (quality.crossovers.as_ref()).map(|f| ("crossover differences", f.before_nt, f.after_nt));
    let reciprocal = (quality.heading_error.as_ref()).map(|f| {
        (
            "heading error between reciprocal lines",
            f.before_nt.abs(),
            f.after_nt.abs(),
        )
    });
    reasons.extend(
        [crossovers, reciprocal]
            .into_iter()
            .flatten()
            .filter(|(_, before, after)| clearly_worse(*before, *after))
            .map(|(figure, before_nt, after_nt)| VerdictReason::SurveyWorse {
                figure,
                before_nt,
                after_nt,
            }),
    );
    if reasons.is_empty() {
        reasons.extend(survey_not_compensated(quality));
    }
    reasons
}

/// A heading level this large uncompensated, nT, carries a heading effect
/// a model of the aircraft must take out.
pub const NOT_COMPENSATED_FLOOR_NT: f64 = 1.0;

/// A model that leaves more than this fraction of such a heading level
/// does not compensate the flight: the aircraft's own model takes 90 % or
/// more (seeds 700–704: 31.1 → 1.6 nT, 25.0 → 0.09 nT); another
/// aircraft's left 24.2 of 25.0 nT and raised 31.1 to 38.2 nT.
pub const NOT_COMPENSATED_FRACTION: f64 = 0.5;

/// Fewest triples of neighbouring lines whose heading level can say a
/// model does not compensate: with fewer the geology's curvature across
/// the lines stays in it (a clean survey of five lines read 2.98 nT
/// uncompensated and 3.26 nT with its own good model; crossovers of ties
/// flown at other heights kept 1.5–2.7 nT of geology with good models,
/// so they are not used).
pub const NOT_COMPENSATED_LEAST_TRIPLES: usize = 6;

/// The heading level between neighbouring lines, when it carries the
/// aircraft's heading effect ([`NOT_COMPENSATED_FLOOR_NT`] or more
/// uncompensated, beyond five standard errors, over
/// [`NOT_COMPENSATED_LEAST_TRIPLES`] or more) and the model leaves more
/// than [`NOT_COMPENSATED_FRACTION`] of it.
fn survey_not_compensated(quality: &ChannelQuality) -> Option<VerdictReason> {
    let f = quality.heading_level.as_ref()?;
    let (before_nt, after_nt) = (f.before_nt.abs(), f.after_nt.abs());
    let carries = f.triples >= NOT_COMPENSATED_LEAST_TRIPLES
        && before_nt > NOT_COMPENSATED_FLOOR_NT
        && before_nt > 5.0 * f.standard_error_nt;
    (carries && after_nt > NOT_COMPENSATED_FRACTION * before_nt).then_some(VerdictReason::SurveyNotCompensated {
        figure: "heading level between neighbouring lines",
        before_nt,
        after_nt,
    })
}

/// A survey figure the default and plain Tolles-Lawson may differ by
/// without either being the better, nT.
pub const SURVEY_FIGURE_TOLERANCE_NT: f64 = 0.005;

/// Which compensation to deliver where the default departs from plain
/// Tolles-Lawson, from the survey's own figures with each (the heading
/// level between neighbouring lines, the crossovers, reciprocal lines),
/// in words with the figures.
pub fn which_to_use(quality: &ChannelQuality) -> String {
    let Some(plain) = &quality.plain_survey else {
        return no_survey_figure(quality);
    };
    let pairs: Vec<(&str, f64, f64)> = [
        (
            "heading level",
            quality.heading_level.as_ref().map(|f| f.after_nt),
            plain.heading_level_nt,
        ),
        (
            "crossovers",
            quality.crossovers.as_ref().map(|f| f.after_nt),
            plain.crossovers_nt,
        ),
        (
            "reciprocal lines",
            quality.heading_error.as_ref().map(|f| f.after_nt.abs()),
            plain.heading_error_nt,
        ),
    ]
    .into_iter()
    .filter_map(|(name, default, plain)| Some((name, default?, plain?)))
    .collect();
    if pairs.is_empty() {
        return no_survey_figure(quality);
    }
    let words: Vec<String> = (pairs.iter())
        .map(|(name, default, plain)| format!("{name} {default:.3} nT against {plain:.3} nT plain"))
        .collect();
    let better = pairs.iter().all(|(_, d, p)| *d <= p + SURVEY_FIGURE_TOLERANCE_NT);
    let worse = pairs.iter().all(|(_, d, p)| *d > p + SURVEY_FIGURE_TOLERANCE_NT);
    match (better, worse) {
        (true, _) => format!("use it: the survey's own figures agree ({})", words.join(", ")),
        (_, true) => format!(
            "use plain Tolles-Lawson (--plain): the survey's own figures are worse with the diagnosis ({})",
            words.join(", ")
        ),
        _ => format!(
            "the survey's own figures disagree ({}): compare a tie line before choosing",
            words.join(", ")
        ),
    }
}

/// The advice where the survey has no figure to compare the two by.
fn no_survey_figure(quality: &ChannelQuality) -> String {
    let transfer = (quality.box_transfer.first())
        .map(|t| format!("; fitted on {}, it leaves {:.3} nT on {}", t.fit, t.band_std_nt, t.test))
        .unwrap_or_default();
    format!(
        "nothing on the survey tells the two apart (no crossing, reciprocal or neighbouring lines flown both ways){transfer}; fly a tie line across the lines to decide, and until then deliver plain Tolles-Lawson (--plain) where a move of this size matters"
    )
}

/// The verdict of `reasons`: the highest of theirs, PASS without any.
pub fn verdict_of(reasons: &[VerdictReason]) -> Verdict {
    reasons
        .iter()
        .map(VerdictReason::verdict)
        .max()
        .unwrap_or(Verdict::Pass)
}

/// Sets `quality`'s verdict and its reasons in words, each after the
/// verdict it gives ("FAIL: FOM 3.51 nT is above …"); `calibration` as
/// for [`reasons`].
pub fn judge(quality: &mut ChannelQuality, limits: &VerdictLimits, calibration: Option<CalibrationVerdict>) {
    let reasons = reasons(quality, limits, calibration);
    quality.verdict = verdict_of(&reasons);
    quality.verdict_reasons = (reasons.iter())
        .map(|reason| format!("{}: {reason}", reason.verdict()))
        .collect();
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_order_of_precedence_is_fail_check_pass() {
        assert!(Verdict::Fail > Verdict::Check && Verdict::Check > Verdict::Pass);
        let reasons = [
            VerdictReason::Departure {
                departure_nt: 0.2,
                stated_nt: Some(0.01),
                advice: String::new(),
            },
            VerdictReason::FomAboveLimit {
                fom_nt: 1.54,
                limit_nt: 1.5,
            },
        ];
        assert_eq!(verdict_of(&reasons), Verdict::Fail);
        assert_eq!(verdict_of(&reasons[..1]), Verdict::Check);
        assert_eq!(verdict_of(&[]), Verdict::Pass);
        for verdict in [Verdict::Pass, Verdict::Check, Verdict::Fail] {
            assert_eq!(Verdict::from_word(verdict.word()), Some(verdict));
            assert_eq!(serde_json::to_value(verdict).unwrap(), verdict.word());
        }
    }

    #[test]
    fn a_survey_figure_is_clearly_worse_by_both_factor_and_floor() {
        // The figures of a real survey compensated with another
        // airframe's model.
        assert!(clearly_worse(9.9, 75.8));
        assert!(clearly_worse(2.5, 4.7));
        // Within the factor, or within the floor.
        assert!(!clearly_worse(2.5, 3.7));
        assert!(!clearly_worse(0.3, 1.2));
        assert!(!clearly_worse(4.0, 1.0));
        assert!(clearly_worse(0.3, 1.31));
    }
}
