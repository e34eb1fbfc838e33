//! The evidence rule: a finding that passed the held-out test on the
//! calibration is applied to the survey by default only when what it does
//! there stays within what the calibration saw it do.
//!
//! The held-out test judges a finding on the box alone. A source column
//! that stands in for something on the box (a servo current that follows
//! the rolls) can pass it with a coupling that, on the survey, multiplies
//! a level the box never saw: on a clean simulated flight such a coupling
//! lowered the held-out RMS by 30 % and moved the survey's level by
//! 4,400 nT. So before the diagnosed model is applied its compensated
//! channel is set against plain Tolles-Lawson's over the whole flight: the
//! difference d between them is what the findings add (a lag's included:
//! it reads the record itself earlier, so it moves the survey's geology
//! by τ times its rate, far more at survey height than at the box's). Over the calibration windows d
//! swings by its spread about its median; on the survey lines (the rows
//! outside the calibration when the file has no line column) it departs
//! from that median by its survey RMS. The findings are applied when
//!
//! survey departure ≤ [`SURVEY_FACTOR`] × calibration spread + [`SURVEY_FLOOR_NT`].
//!
//! Physics the calibration measured acts on the survey no harder than in
//! the manoeuvres, which drive the largest rates and attitudes: a lag or
//! an eddy τ (the field's rate of change), the second-order term (the
//! heading), a coupling whose source ranges over the survey as over the
//! box. A departure three times the calibration's spread is extrapolation
//! beyond anything the box tested; the floor keeps differences below a
//! hundredth of a nT, under any survey's noise, from deciding anything.
//! Findings that fail are reported with `"applied": false` and the figures
//! as the reason, the channel is fitted plain, and the run warns.

use std::collections::BTreeMap;

use crate::calibration::windows::CalibrationWindow;
use crate::error::Result;
use crate::ingest::flight_log::FlightLog;
use crate::messages::HeldBack;
use crate::model::terms::TermSet;
use crate::model::{fit, Calibration, Extensions, FitOptions, FittedModel, ModelSpec};
use crate::numerics::stacked::StorePool;

/// How far the survey departure may exceed the calibration's spread.
pub const SURVEY_FACTOR: f64 = 3.0;

/// Departures below this are applied whatever the calibration's spread, nT.
pub const SURVEY_FLOOR_NT: f64 = crate::quality::DEPARTURE_FLOOR_NT;

/// What a channel's findings add to its compensation, on the calibration
/// and on the survey.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Departure {
    /// RMS of the diagnosed model's prediction less plain Tolles-Lawson's
    /// about its median over the calibration windows, nT.
    pub calibration_spread_nt: f64,
    /// RMS of the same difference on the survey about that median, nT.
    pub survey_departure_nt: f64,
    /// Survey rows it was measured on.
    pub survey_rows: usize,
}

impl Departure {
    /// Whether the findings stay within what the calibration saw.
    pub fn holds(&self) -> bool {
        self.survey_departure_nt <= SURVEY_FACTOR * self.calibration_spread_nt + SURVEY_FLOOR_NT
    }

    /// Why the findings are held back when they fail.
    pub fn held_back(&self) -> HeldBack {
        HeldBack::BeyondCalibration {
            survey_nt: self.survey_departure_nt,
            calibration_nt: self.calibration_spread_nt,
            factor: SURVEY_FACTOR,
            floor_nt: SURVEY_FLOOR_NT,
        }
    }
}

/// `d = diagnosed − plain` (compensated channels) over the calibration windows and the survey
/// rows of `log` (its survey lines; without any, the rows outside every
/// window). `None` without finite calibration or survey rows.
pub fn departure(
    log: &FlightLog,
    windows: &[CalibrationWindow],
    plain: &[f64],
    diagnosed: &[f64],
) -> Option<Departure> {
    let time = log.time_s();
    let mut in_windows = vec![false; log.len()];
    for window in windows {
        in_windows[window.rows(time)].fill(true);
    }
    let lines = log.survey_lines();
    let survey: Vec<usize> = match lines.is_empty() {
        true => (0..log.len()).filter(|row| !in_windows[*row]).collect(),
        false => lines
            .into_iter()
            .flat_map(|(_, rows)| rows)
            .filter(|row| !in_windows[*row])
            .collect(),
    };
    let difference = |row: usize| diagnosed[row] - plain[row];
    let mut box_values: Vec<f64> = (0..log.len())
        .filter(|row| in_windows[*row])
        .map(difference)
        .filter(|d| d.is_finite())
        .collect();
    let survey_values: Vec<f64> = survey.into_iter().map(difference).filter(|d| d.is_finite()).collect();
    if box_values.is_empty() || survey_values.is_empty() {
        return None;
    }
    let rms_about = |values: &[f64], centre: f64| {
        (values.iter().map(|v| (v - centre).powi(2)).sum::<f64>() / values.len() as f64).sqrt()
    };
    let middle = box_values.len() / 2;
    let centre = *box_values.select_nth_unstable_by(middle, f64::total_cmp).1;
    Some(Departure {
        calibration_spread_nt: rms_about(&box_values, centre),
        survey_departure_nt: rms_about(&survey_values, centre),
        survey_rows: survey_values.len(),
    })
}

/// The channel's model with the findings the rule judges taken away: a
/// fluxgate calibration (the flight's) and a base station's term are kept.
/// The base station's term is subtracted before the fit but never
/// predicted (the compensated channel keeps the Earth's field): it acts
/// on the survey only through
/// the coefficients it unbiases, so what the model moves there is plain
/// Tolles-Lawson's own bias, not an effect carried beyond the box. With
/// 6 nT of pulsations the plain fit was 1.7 nT wrong on the survey and the
/// unbiased one moved it by 2.7 nT: judged, it was refused.
pub fn plain_of(model: &Extensions) -> Extensions {
    Extensions {
        vector_calibration: model.vector_calibration.clone(),
        sources: (model.sources.iter())
            .filter(|s| s.is_external_field())
            .cloned()
            .collect(),
        ..Extensions::default()
    }
}

/// What each channel of `plan` adds on the survey to its `reference`
/// model ([`plain_of`] for the findings the rule judges,
/// [`tolles_lawson_of`] for everything the diagnosis added): per channel
/// whose model is not its reference, its [`Departure`] (`None` where it
/// cannot be measured: no survey rows).
pub fn departures(
    compensations: &Compensations,
    plan: &BTreeMap<String, Extensions>,
    reference: fn(&Extensions) -> Extensions,
) -> Result<BTreeMap<String, Option<Departure>>> {
    let Calibration { log, windows, .. } = *compensations.calibration;
    use rayon::prelude::*;
    let changed: Vec<(&String, &Extensions)> = plan.iter().filter(|(_, model)| *model != &reference(model)).collect();
    let measured: Vec<(String, Option<Departure>)> = changed
        .par_iter()
        .map(|(channel, model)| {
            let diagnosed = compensations.of(channel, model)?;
            let plain = compensations.of(channel, &reference(model))?;
            Ok(((*channel).clone(), departure(log, windows, &plain, &diagnosed)))
        })
        .collect::<Result<_>>()?;
    Ok(measured.into_iter().collect())
}

/// The channels' compensations over the whole flight, each model fitted
/// once: the evidence rule's checks ask for the same ones. The compensated
/// channel, not the interference alone: a lag reads the record itself
/// earlier, which moves the survey's geology along with it (τ × its rate,
/// far more at survey height than at the box's).
pub struct Compensations<'c, 'a> {
    calibration: &'c Calibration<'a>,
    terms: TermSet,
    options: &'c FitOptions,
    stores: StorePool,
    done: std::sync::Mutex<Vec<Computed>>,
}

/// A channel, its model fitted, and its compensation.
type Computed = (
    String,
    Extensions,
    std::sync::Arc<Vec<f64>>,
    std::sync::Arc<FittedModel>,
);

impl<'c, 'a> Compensations<'c, 'a> {
    /// None computed yet.
    pub fn new(calibration: &'c Calibration<'a>, (terms, options): (TermSet, &'c FitOptions)) -> Self {
        Compensations {
            calibration,
            terms,
            options,
            stores: StorePool::new(),
            done: Default::default(),
        }
    }

    /// `channel` compensated with `extensions` fitted on the calibration.
    pub fn of(&self, channel: &str, extensions: &Extensions) -> Result<std::sync::Arc<Vec<f64>>> {
        Ok(self.computed(channel, extensions)?.2)
    }

    /// The uncertainty `channel` compensated with `extensions` states
    /// outside the calibration ([`crate::quality::Uncertainty`]'s
    /// `outside_calibration_sigma_nt`, as the quality file gives it), nT;
    /// `None` where it states none.
    pub fn stated_nt(&self, channel: &str, extensions: &Extensions) -> Result<Option<f64>> {
        let model = self.computed(channel, extensions)?.3;
        let uncertainty = crate::quality::uncertainty(self.calibration.log, &model)?;
        Ok(uncertainty.map(|u| u.outside_calibration_sigma_nt))
    }

    /// How `channel` compensated with `extensions` scales a crustal
    /// anomaly over the survey ([`FittedModel::anomaly_gain`]).
    pub fn anomaly_gain(&self, channel: &str, extensions: &Extensions) -> Result<Option<crate::model::AnomalyGain>> {
        let model = self.computed(channel, extensions)?.3;
        model.anomaly_gain(self.calibration.log, &[])
    }

    /// `channel` fitted with `extensions` and compensated, once.
    fn computed(&self, channel: &str, extensions: &Extensions) -> Result<Computed> {
        let done = |list: &[Computed]| {
            (list.iter())
                .find(|(c, e, _, _)| c == channel && e == extensions)
                .cloned()
        };
        if let Some(found) = done(&self.done.lock().unwrap_or_else(|e| e.into_inner())) {
            return Ok(found);
        }
        let Calibration {
            log, sensor, windows, ..
        } = *self.calibration;
        let spec = ModelSpec::new(self.terms, extensions.clone());
        let model = fit(log, sensor, channel, windows, &spec, self.options, &self.stores)?;
        let prediction = model.predict(log)?;
        let values: std::sync::Arc<Vec<f64>> = std::sync::Arc::new(
            (prediction.scalar_nt.iter())
                .zip(&prediction.interference_nt)
                .map(|(scalar, interference)| scalar - interference)
                .collect(),
        );
        let found = (
            channel.to_string(),
            extensions.clone(),
            values,
            std::sync::Arc::new(model),
        );
        let mut list = self.done.lock().unwrap_or_else(|e| e.into_inner());
        list.push(found.clone());
        Ok(found)
    }
}

/// Fewest crossovers the survey-side comparison decides on: two tie the
/// levels of three lines together.
pub const LEAST_CROSSOVERS: usize = 2;

/// How much more the findings may spread the survey's line levels than
/// plain Tolles-Lawson, nT: below a two-hundredth of a nT no survey's
/// levelling would notice.
pub const LEVEL_TOLERANCE_NT: f64 = 0.005;

/// The standard errors of the comparison the findings are given besides
/// the tolerance. Holding findings back costs at most their gain (the
/// channel is compensated plain, the reference the survey is judged
/// against), while applying findings that the crossovers call worse risks
/// the survey: the burden of proof is on the findings, and a few crossovers
/// with no misfit to spare (a standard error of zero) decide on the
/// tolerance alone. On 300 clean simulated flights (80 % with 1–4 ties)
/// this held back 8 of the 9 harmful channels with crossovers, and none of
/// the 109 that the findings helped by more than 10 %.
pub const LEVEL_STANDARD_ERRORS: f64 = 0.5;

/// Whether findings that spread the line levels as `comparison` says are
/// worse on the survey than plain Tolles-Lawson.
pub fn levels_worse(comparison: &crate::quality::crossovers::LevelComparison) -> bool {
    comparison.candidate_nt
        > comparison.reference_nt + LEVEL_TOLERANCE_NT + LEVEL_STANDARD_ERRORS * comparison.standard_error_nt
}

/// Plain Tolles-Lawson for a channel whose model is `model`: nothing of
/// the diagnosis but the flight's fluxgate calibration.
pub fn tolles_lawson_of(model: &Extensions) -> Extensions {
    Extensions {
        vector_calibration: model.vector_calibration.clone(),
        ..Extensions::default()
    }
}

/// Which survey-side check judged a flight's findings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SurveyCheck {
    /// Tie-line levelling at the crossovers of the survey's lines.
    Crossovers,
    /// The heading level between neighbouring lines of a block flown back
    /// and forth.
    NeighbouringLines,
    /// Neither could be made: fewer than [`LEAST_CROSSOVERS`] crossovers
    /// (or no base station), and no block of at least
    /// [`LEAST_TRIPLES`] + 2 parallel lines flown both ways.
    NotMade,
}

/// Fewest triples of neighbouring lines the heading-level comparison
/// decides on: two leave one second difference to judge the scatter by.
pub const LEAST_TRIPLES: usize = 2;

/// Whether findings that leave the heading level as `comparison` says
/// are worse on the survey than plain Tolles-Lawson: the same tolerance
/// and burden of proof as at the crossovers.
pub fn heading_level_worse(comparison: &crate::quality::corrugation::HeadingLevelComparison) -> bool {
    comparison.candidate_nt.abs()
        > comparison.reference_nt.abs() + LEVEL_TOLERANCE_NT + LEVEL_STANDARD_ERRORS * comparison.standard_error_nt
}

/// How far fitted findings may risk raising the survey's heading level,
/// nT: a level of 0.02 nT puts 0.01 nT on every line, half of it each way,
/// the least harm the clean campaign counts.
pub const HEADING_LEVEL_RISK_NT: f64 = 0.02;

/// The most the findings could raise the size of the survey's heading
/// level, nT, with the reference's true level anywhere from its estimate
/// to [`LEVEL_STANDARD_ERRORS`] standard errors short of it, toward the
/// side the findings move the level to.
///
/// The findings move the level by Δ, known exactly: the geology is the
/// same under both compensations and cancels in their difference. The
/// reference's own level L is known only to its standard error, the
/// geology's curvature across lines a few hundred metres apart. The size
/// rises, |L + Δ| > |L|, unless L lies beyond −Δ/2: where the standard
/// error is as large as Δ the lines cannot tell a finding that corrects a
/// level from one that makes it. On a clean simulated flight with lines
/// 500 m apart (seed 581) a spurious lag moved the level by 0.083 nT
/// against a standard error of 0.043 nT; compared on their estimates
/// alone (0.040 and 0.043 nT) the two looked alike, and the survey's
/// error against the truth nearly doubled (0.021 → 0.038 nT).
///
/// With two triples the level has no scatter to judge it by (a standard
/// error of zero): the reference's level could be anything, and the risk
/// is the whole move. A level or standard error that is not a number is
/// an infinite risk.
pub fn heading_level_risk_nt(comparison: &crate::quality::corrugation::HeadingLevelComparison) -> f64 {
    let change = comparison.candidate_nt - comparison.reference_nt;
    if !(change.is_finite() && comparison.standard_error_nt.is_finite()) {
        return f64::INFINITY;
    }
    if comparison.triples <= 2 {
        return change.abs();
    }
    // The reference's level where the findings would take it back toward
    // zero.
    let against = -change.signum() * comparison.reference_nt;
    let least = (against - LEVEL_STANDARD_ERRORS * comparison.standard_error_nt).clamp(0.0, change.abs());
    change.abs() - 2.0 * least
}

/// Whether findings that move the heading level as `comparison` says
/// risk the survey more than [`HEADING_LEVEL_RISK_NT`]
/// ([`heading_level_risk_nt`]): the burden of proof is heavier than at
/// the crossovers, where two lines' levels are tied, while neighbouring
/// lines only bound the geology between them.
pub fn heading_level_risky(comparison: &crate::quality::corrugation::HeadingLevelComparison) -> bool {
    heading_level_risk_nt(comparison) > HEADING_LEVEL_RISK_NT
}

/// The part of `model` that is recorded rather than fitted: plain
/// Tolles-Lawson with the base station's term, which subtracts the
/// external field a second instrument recorded, with gain 1, from what the
/// aircraft's coefficients are fitted to. On the neighbouring lines the
/// whole diagnosis is judged against plain as at the crossovers
/// ([`heading_level_worse`]); what the fitted findings (a lag, an eddy τ,
/// the second-order term, a coupling, another λ criterion) add to the
/// recorded part must show itself a correction ([`heading_level_risky`]).
/// On 180 clean simulated flights the base station's term, applied
/// alone, helped 31 of 62 channels by more than 10 % and harmed none;
/// three of them on a flight whose lines' geology left their heading
/// level uncertain by 1.3 nT, where judged by risk it would have been
/// held back.
pub fn recorded_part(model: &Extensions) -> Extensions {
    Extensions {
        sources: (model.sources.iter())
            .filter(|s| s.is_external_field())
            .cloned()
            .collect(),
        ..tolles_lawson_of(model)
    }
}

/// Survey-side evidence, per channel of `plan` whose model is not plain
/// Tolles-Lawson, against plain Tolles-Lawson's compensation (the base
/// station's term and every finding taken away):
/// - where the survey's lines cross at least [`LEAST_CROSSOVERS`] times
///   and a base station takes out the external field's drift between the
///   passes, the tie-line levelling of the two ([`levels_worse`]);
/// - otherwise, where a block of parallel lines is flown back and forth,
///   the heading level between neighbouring lines of the two
///   ([`heading_level_worse`]), and the move the fitted findings make in
///   it beyond the base station's term ([`recorded_part`],
///   [`heading_level_risky`]).
///
/// Returns the check made and, per channel it finds worse, why its
/// findings are held back.
pub fn survey_checks(
    compensations: &Compensations,
    plan: &BTreeMap<String, Extensions>,
) -> Result<(SurveyCheck, BTreeMap<String, HeldBack>)> {
    use crate::quality::corrugation::{compare_heading_levels, Corrugation};
    use crate::quality::crossovers::{compare_levels, Crossovers};
    let log = compensations.calibration.log;
    let changed: Vec<(&String, &Extensions)> = (plan.iter())
        .filter(|(_, model)| *model != &tolles_lawson_of(model))
        .collect();
    let crossovers = Crossovers::of(log);
    if crossovers.points.len() >= LEAST_CROSSOVERS && crossovers.external_field_removed() {
        let worse = judged(compensations, (&changed, false), |[plain, _, diagnosed]| {
            let comparison = compare_levels(log, &crossovers, (plain, diagnosed), LEAST_CROSSOVERS)?;
            levels_worse(&comparison).then_some(HeldBack::WorseAtCrossovers {
                crossovers: comparison.crossovers,
                lines: comparison.lines,
                plain_nt: comparison.reference_nt,
                diagnosed_nt: comparison.candidate_nt,
                standard_error_nt: comparison.standard_error_nt,
            })
        })?;
        return Ok((SurveyCheck::Crossovers, worse));
    }
    let corrugation = Corrugation::of(log);
    if corrugation.triples() < LEAST_TRIPLES || !corrugation.tells_heading_level() {
        return Ok((SurveyCheck::NotMade, BTreeMap::new()));
    }
    let worse = judged(compensations, (&changed, true), |[plain, recorded, diagnosed]| {
        let whole = compare_heading_levels(&corrugation, (plain, diagnosed), LEAST_TRIPLES)?;
        let risky =
            compare_heading_levels(&corrugation, (recorded, diagnosed), LEAST_TRIPLES).filter(heading_level_risky);
        let moved_nt = match risky {
            Some(fitted) => fitted.candidate_nt - fitted.reference_nt,
            None if heading_level_worse(&whole) => whole.candidate_nt - whole.reference_nt,
            None => return None,
        };
        Some(HeldBack::WorseBetweenLines {
            lines: whole.lines,
            triples: whole.triples,
            plain_nt: whole.reference_nt.abs(),
            diagnosed_nt: whole.candidate_nt.abs(),
            moved_nt: moved_nt.abs(),
            standard_error_nt: whole.standard_error_nt,
            external_field_removed: corrugation.external_field_removed(),
        })
    })?;
    Ok((SurveyCheck::NeighbouringLines, worse))
}

/// Each of the `changed` channels judged by `judge` on its compensations
/// by plain Tolles-Lawson, by the model's recorded part
/// ([`recorded_part`]; plain's own where the model has no base station,
/// or where `recorded` is false) and by the model: those it finds worse,
/// and why.
fn judged(
    compensations: &Compensations,
    (changed, recorded): (&[(&String, &Extensions)], bool),
    judge: impl Fn([&[f64]; 3]) -> Option<HeldBack> + Sync,
) -> Result<BTreeMap<String, HeldBack>> {
    use rayon::prelude::*;
    let found: Vec<Option<(String, HeldBack)>> = changed
        .par_iter()
        .map(|(channel, model)| {
            let diagnosed = compensations.of(channel, model)?;
            let plain = compensations.of(channel, &tolles_lawson_of(model))?;
            let recorded = match recorded {
                true => compensations.of(channel, &recorded_part(model))?,
                false => plain.clone(),
            };
            Ok(judge([&plain, &recorded, &diagnosed]).map(|reason| ((*channel).clone(), reason)))
        })
        .collect::<Result<_>>()?;
    Ok(found.into_iter().flatten().collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_departure_beyond_the_calibration_fails_and_one_within_holds() {
        let within = Departure {
            calibration_spread_nt: 0.1,
            survey_departure_nt: 0.25,
            survey_rows: 100,
        };
        assert!(within.holds());
        let beyond = Departure {
            survey_departure_nt: 0.32,
            ..within
        };
        assert!(!beyond.holds());
        assert!(
            matches!(beyond.held_back(), HeldBack::BeyondCalibration { survey_nt, .. } if survey_nt == 0.32),
            "{:?}",
            beyond.held_back()
        );
        let tiny = Departure {
            calibration_spread_nt: 0.0,
            survey_departure_nt: 0.009,
            survey_rows: 100,
        };
        assert!(tiny.holds());
    }

    /// The recorded part keeps the base station's term, and nothing
    /// fitted.
    #[test]
    fn the_recorded_part_is_the_base_stations_term_alone() {
        use crate::model::SourceTerm;
        let station = SourceTerm::ExternalField {
            column: "diurnal".into(),
            level: 12.0,
        };
        let model = Extensions {
            lag_s: 0.2,
            second_order: true,
            sources: vec![
                SourceTerm::AuxCoupling {
                    column: "cur_ail".into(),
                    level: 0.5,
                },
                station.clone(),
            ],
            ..Extensions::default()
        };
        let recorded = recorded_part(&model);
        assert_eq!(
            recorded,
            Extensions {
                sources: vec![station],
                ..Extensions::default()
            }
        );
        assert_eq!(recorded_part(&recorded), recorded);
        assert!(recorded_part(&Extensions {
            lag_s: 0.2,
            ..Extensions::default()
        })
        .is_plain());
    }

    /// The risk is the most the level's size could rise with plain's true
    /// level half a standard error short of its estimate, toward the
    /// findings' side.
    #[test]
    fn a_heading_level_move_the_lines_cannot_show_to_be_a_correction_is_a_risk() {
        use crate::quality::corrugation::HeadingLevelComparison;
        let compared = |reference_nt: f64, candidate_nt: f64, standard_error_nt: f64| HeadingLevelComparison {
            triples: 7,
            lines: 9,
            reference_nt,
            candidate_nt,
            standard_error_nt,
        };
        // Seed 581's figures: the move of 0.083 nT against plain's level of
        // 0.040 ± 0.043 nT. Half a standard error short of 0.040 is 0.0185:
        // the risk is 0.083 − 2 × 0.0185.
        let seed_581 = compared(0.040, -0.043, 0.043);
        assert!((heading_level_risk_nt(&seed_581) - 0.046).abs() < 1e-12);
        assert!(heading_level_risky(&seed_581));
        // Judged on the sizes, as at the crossovers, it passes.
        assert!(!heading_level_worse(&seed_581));
        // The same move with plain's level pinned (standard error 0.004):
        // the findings take a level of 0.083 nT to zero.
        let correction = compared(0.083, 0.0, 0.004);
        assert!((heading_level_risk_nt(&correction) - (0.083 - 2.0 * 0.081)).abs() < 1e-12);
        assert!(!heading_level_risky(&correction));
        // A move away from zero is its own size, whatever the error.
        let away = compared(0.01, 0.04, 0.0);
        assert!((heading_level_risk_nt(&away) - 0.03).abs() < 1e-12);
        assert!(heading_level_risky(&away));
        // A move smaller than the tolerance is never a risk.
        let small = compared(-0.002, 0.015, 0.5);
        assert!((heading_level_risk_nt(&small) - 0.017).abs() < 1e-12);
        assert!(!heading_level_risky(&small));
        // Past zero to a larger size on the other side: the move less twice
        // plain's level half a standard error short.
        let beyond = compared(-0.05, 0.06, 0.01);
        assert!((heading_level_risk_nt(&beyond) - (0.11 - 2.0 * 0.045)).abs() < 1e-12);
        // A move that halves a level well clear of zero: the whole move is
        // a gain.
        let halved = compared(0.2, 0.1, 0.0);
        assert!((heading_level_risk_nt(&halved) + 0.1).abs() < 1e-12);
        // Two triples leave no scatter to judge the level by: the whole
        // move is the risk.
        let two = HeadingLevelComparison { triples: 2, ..halved };
        assert!((heading_level_risk_nt(&two) - 0.1).abs() < 1e-12);
        assert!(heading_level_risky(&two));
        // Not a number: held back.
        let unknown = compared(f64::NAN, 0.1, 0.01);
        assert_eq!(heading_level_risk_nt(&unknown), f64::INFINITY);
        assert!(heading_level_risky(&compared(0.2, 0.1, f64::NAN)));
    }
}
