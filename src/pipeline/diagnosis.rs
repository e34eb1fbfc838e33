//! What the fit takes from a diagnosis: a saved DIAGNOSIS.json, or one
//! made now and judged by the evidence rule.

use std::collections::BTreeMap;

use crate::config::{FlightJob, Settings};
use crate::diagnose::{AppliedFinding, EffectKind};
use crate::error::{Error, Result};
use crate::ingest::flight_log::FlightLog;
use crate::messages::{HeldBack, MovedBy, Warning, FITTED_PLAIN};
use crate::model::{Calibration, Extensions};

/// The findings of `diagnosis` that change the model of a channel whose
/// diagnosed model is not plain (an `unexplained` finding changes none).
pub(super) fn applied_findings(diagnosis: &crate::diagnose::Diagnosis) -> Vec<AppliedFinding> {
    let changed = |channel: &str| {
        diagnosis
            .channels
            .iter()
            .any(|c| c.channel == channel && !c.model.is_plain())
    };
    let calibrated_channels: Vec<&str> = diagnosis
        .channels
        .iter()
        .filter(|c| c.model.vector_calibration.is_some())
        .map(|c| c.channel.as_str())
        .collect();
    diagnosis
        .findings
        .iter()
        .filter(|f| f.effect.kind() != EffectKind::Unexplained && f.not_applied.is_none())
        .filter(|f| f.effect.kind() == EffectKind::VectorCalibration || changed(&f.channel))
        .filter(|f| f.effect.kind() != EffectKind::VectorCalibration || !calibrated_channels.is_empty())
        .map(|f| AppliedFinding {
            channel: match f.effect.kind() {
                EffectKind::VectorCalibration => format!("{} (for {})", f.channel, calibrated_channels.join(", ")),
                _ => f.channel.clone(),
            },
            effect: f.effect.kind(),
            source: f.source.clone(),
            heldout_rms_before_nt: f.heldout_rms_before_nt,
            heldout_rms_after_nt: f.heldout_rms_after_nt,
        })
        .collect()
}

/// What the fit takes from a diagnosis.
pub(super) struct ExtensionsPlan {
    /// Each channel's diagnosed model (plain when absent).
    pub(super) models: BTreeMap<String, Extensions>,
    /// The diagnosis made now, if one was.
    pub(super) diagnosis: Option<crate::diagnose::Diagnosis>,
    /// What the user must know: a diagnosis that could not be made or
    /// checked.
    pub(super) warnings: Vec<Warning>,
}

/// The diagnosed model of each channel to fit with: from the flight's
/// DIAGNOSIS.json (refused when made on another flight, unless forced), or
/// from a diagnosis made now (`[diagnose] apply`, then returned too); empty
/// otherwise. A saved diagnosis that calibrates the fluxgate while the
/// `[vector_calibration]` stage already has is refused. `logs` are the
/// flight as read and as fitted (fluxgate calibrated by the stage).
pub(super) fn augmentation_plan(
    job: &FlightJob,
    raw_log: &FlightLog,
    calibration: &Calibration,
    (options, meter): (&Settings, &dyn crate::messages::progress::Meter),
    stage_calibrated: bool,
) -> Result<ExtensionsPlan> {
    use crate::diagnose::ApplyDiagnosis;
    if let Some(path) = &job.diagnosis {
        let (models, remark) = crate::diagnose::read_saved(path)?.models_for(path, raw_log, job.force_diagnosis)?;
        if stage_calibrated && models.values().any(|m| m.vector_calibration.is_some()) {
            return Err(Error::Config {
                source_name: path.display().to_string(),
                message: "the diagnosis calibrates the fluxgate and so does the [vector_calibration] stage; turn the stage off (enabled = false) or diagnose the calibrated flight".into(),
            });
        }
        return Ok(ExtensionsPlan {
            models,
            diagnosis: None,
            warnings: remark.into_iter().collect(),
        });
    }
    let plain = |warnings| ExtensionsPlan {
        models: BTreeMap::new(),
        diagnosis: None,
        warnings,
    };
    if options.diagnose.apply == ApplyDiagnosis::Never {
        return Ok(plain(Vec::new()));
    }
    let settings = (&options.terms, &options.fit, &options.diagnose);
    match crate::diagnose::diagnose_metered(calibration, settings, meter) {
        Ok(mut diagnosis) => {
            diagnosis.flight = Some(crate::ingest::flight_identity::FlightIdentity::of(raw_log)?);
            Ok(ExtensionsPlan {
                models: diagnosis.models(),
                warnings: unexplained_warnings(&diagnosis),
                diagnosis: Some(diagnosis),
            })
        }
        // Under "auto" a flight that cannot be diagnosed is fitted plain,
        // loudly; the plain fit then reports any fault of the data itself.
        Err(error) if options.diagnose.apply == ApplyDiagnosis::Auto => Ok(plain(vec![Warning::NotDiagnosed {
            error: error.to_string(),
        }])),
        Err(error) => Err(error),
    }
}

/// The channels whose diagnosed model (beyond what is kept of plain)
/// does not lower the held-out RMS of plain Tolles-Lawson with λ picked as
/// compensation picks it, held back.
fn no_gain_held_out(
    diagnosis: &crate::diagnose::Diagnosis,
    plan: &BTreeMap<String, Extensions>,
    options: &Settings,
) -> Vec<(String, HeldBack)> {
    let criterion = match options.fit.solve.lambda {
        crate::numerics::solve::LambdaChoice::Select => Some(options.fit.solve.criterion.describe().to_string()),
        _ => None,
    };
    (diagnosis.channels.iter())
        .filter(|c| {
            plan.get(&c.channel)
                .is_some_and(|m| *m != crate::diagnose::evidence::plain_of(m))
        })
        .filter(|c| c.heldout_rms_final_nt >= c.heldout_rms_baseline_nt)
        .map(|c| {
            let reason = HeldBack::NoGainHeldOut {
                criterion: criterion.clone(),
                plain_nt: c.heldout_rms_baseline_nt,
                diagnosed_nt: c.heldout_rms_final_nt,
            };
            (c.channel.clone(), reason)
        })
        .collect()
}

/// Applies the evidence rule ([`crate::diagnose::evidence`]) to a fresh
/// diagnosis's plan. A channel's findings are held back (fitted plain
/// under `apply = "auto"`, its findings marked not applied with the
/// reason, and a warning; only warned of under `"always"`) when
///
/// - with λ picked as compensation picks it, they do not lower the
///   held-out RMS of plain Tolles-Lawson: the search may have measured
///   them from the other criterion's fit, and what is applied is this one
///   (on clean simulated flights, two sensor lags that made the survey
///   three times worse held out 4–8 % worse this way); or
/// - they would act on the survey beyond what the calibration saw; or
/// - where the survey's lines cross and a base station takes out the
///   external field's drift, tie-line levelling finds the lines' levels
///   more spread with them than with plain Tolles-Lawson; or, where no
///   ties cross a block of lines flown back and forth, neighbouring lines
///   flown in opposite directions sit further apart in level with them
///   (either way every finding of the channel is held back, the base
///   station's term too).
///
/// Returns the plan and, per channel whose model is not plain
/// Tolles-Lawson, how far what it adds (its findings, the base station's
/// term) moves the survey from plain Tolles-Lawson (nT RMS), and what
/// moves it: the verdict's departure ([`verdict_departures`]).
pub(super) fn evidence_rule(
    calibration: &Calibration,
    mut plan: BTreeMap<String, Extensions>,
    diagnosis: &mut crate::diagnose::Diagnosis,
    options: &Settings,
    warnings: &mut Vec<Warning>,
) -> Result<(BTreeMap<String, Extensions>, Departures)> {
    use crate::diagnose::evidence::{
        departures, plain_of, survey_checks, tolles_lawson_of, Compensations, SurveyCheck, LEAST_CROSSOVERS,
        LEAST_TRIPLES,
    };
    report_cross_sensor(&mut plan, diagnosis, options.diagnose.cross_sensor);
    // The survey is a survey-fitted term's evidence, not the box: the box's
    // rules judge the rest without it.
    let mut surveyed = SurveyFitted::take(&mut plan, diagnosis);
    let mut refused = no_gain_held_out(diagnosis, &plan, options);
    let compensations = Compensations::new(calibration, (options.terms, &options.fit));
    let measured = departures(&compensations, &plan, plain_of)?;
    let mut applied = BTreeMap::new();
    for (channel, departure) in measured {
        let Some(departure) = departure else {
            continue;
        };
        applied.insert(channel.clone(), departure.survey_departure_nt);
        if !departure.holds() && !refused.iter().any(|(c, _)| *c == channel) {
            refused.push((channel, departure.held_back()));
        }
    }
    hold_back(
        (&mut plan, &mut applied),
        diagnosis,
        (options, warnings),
        refused,
        false,
    );
    // Survey-side evidence on what the rules above left: against plain
    // Tolles-Lawson with nothing of the diagnosis (the base station's term
    // included: it unbiases the fit on the box, and the survey shows
    // whether the survey gains). A survey-fitted term is judged too: the
    // lines' levels are what its fit, about each line's mean, never saw.
    surveyed.restore(&mut plan, diagnosis);
    let (check, worse) = survey_checks(&compensations, &plan)?;
    hold_back((&mut plan, &mut applied), diagnosis, (options, warnings), worse, true);
    surveyed = SurveyFitted::take(&mut plan, diagnosis);
    let unsupported = unchecked_moves(&compensations, &plan, (&applied, &diagnosis.findings), check)?;
    hold_back(
        (&mut plan, &mut applied),
        diagnosis,
        (options, warnings),
        unsupported,
        false,
    );
    surveyed.restore(&mut plan, diagnosis);
    let (gains, scaled) = anomaly_gains(&compensations, &plan, options.anomaly_gain_tolerance)?;
    hold_back((&mut plan, &mut applied), diagnosis, (options, warnings), scaled, false);
    state_anomaly_gains(diagnosis, &gains);
    let unchecked: Vec<String> = (plan.iter())
        .filter(|(_, model)| **model != tolles_lawson_of(model))
        .map(|(channel, _)| channel.clone())
        .collect();
    if check == SurveyCheck::NotMade && !unchecked.is_empty() {
        let note = crate::messages::Diagnosing::SurveyNotChecked {
            channels: unchecked,
            least_crossovers: LEAST_CROSSOVERS,
            least_lines: LEAST_TRIPLES + 2,
        };
        diagnosis.notes.push(note.into());
    }
    let verdict = verdict_departures(&compensations, &plan)?;
    Ok((plan, verdict))
}

/// The cross-sensor terms whose gain the survey fitted, with their
/// findings, taken out of a plan while the box's rules judge the rest.
/// Their evidence is the survey, held out line by line
/// ([`crate::diagnose`]'s survey step); the box holds a current that
/// varies through the flight in a few manoeuvres, where a term fitted on
/// the survey can raise the held-out residual (seed 3 of the
/// unrecorded-current campaign: 0.19 → 0.34 nT, the survey 1.77 → 0.60
/// nT against the quiet scalar). The anomaly gain judges them with the
/// rest.
struct SurveyFitted {
    terms: Vec<(String, crate::model::SourceTerm)>,
    findings: Vec<crate::diagnose::Finding>,
}

impl SurveyFitted {
    /// The survey-fitted terms of `plan` and their findings, taken out.
    fn take(plan: &mut BTreeMap<String, Extensions>, diagnosis: &mut crate::diagnose::Diagnosis) -> SurveyFitted {
        let mut terms = Vec::new();
        for (channel, model) in plan.iter_mut() {
            let (fitted, kept) =
                (std::mem::take(&mut model.sources).into_iter()).partition(|s| s.survey_gain().is_some());
            model.sources = kept;
            terms.extend(
                fitted
                    .into_iter()
                    .map(|term: crate::model::SourceTerm| (channel.clone(), term)),
            );
        }
        let fitted = |f: &crate::diagnose::Finding| match &f.effect {
            crate::diagnose::Effect::CrossSensor(cross) => cross.survey_gain.is_some() && f.not_applied.is_none(),
            _ => false,
        };
        let (findings, kept) = std::mem::take(&mut diagnosis.findings).into_iter().partition(fitted);
        diagnosis.findings = kept;
        SurveyFitted { terms, findings }
    }

    /// The terms put back in `plan` and the diagnosis's models, on top of
    /// what the box's rules kept, and their findings with them.
    fn restore(self, plan: &mut BTreeMap<String, Extensions>, diagnosis: &mut crate::diagnose::Diagnosis) {
        for (channel, term) in self.terms {
            if let Some(model) = plan.get_mut(&channel) {
                model.sources.push(term.clone());
            }
            if let Some(entry) = diagnosis.channels.iter_mut().find(|c| c.channel == channel) {
                if !entry.model.sources.contains(&term) {
                    entry.model.sources.push(term);
                }
            }
        }
        diagnosis.findings.extend(self.findings);
    }
}

/// Each applied finding of `diagnosis` that changes its channel's model
/// (or is its base station) takes the channel's anomaly gain from `gains`.
fn state_anomaly_gains(diagnosis: &mut crate::diagnose::Diagnosis, gains: &[(String, f64)]) {
    for finding in (diagnosis.findings.iter_mut()).filter(|f| f.not_applied.is_none()) {
        finding.anomaly_gain = (gains.iter())
            .find(|(channel, _)| *channel == finding.channel)
            .map(|(_, gain)| *gain)
            .filter(|_| applies_to_model(finding.effect.kind()) || finding.effect.kind() == EffectKind::ExternalField);
    }
}

/// Each channel's anomaly gain, and the channels held back with why.
type Gains = (Vec<(String, f64)>, Vec<(String, HeldBack)>);

/// The anomaly gain ([`crate::model::AnomalyGain`]) of each channel of
/// `plan` whose model is not plain Tolles-Lawson, and the channels whose
/// findings scale the geology beyond `tolerance`, further from 1 than
/// plain Tolles-Lawson does: those are held back. A term, finding or
/// source is judged by how it scales the survey's anomalies as well as by
/// how quiet it makes the box.
fn anomaly_gains(
    compensations: &crate::diagnose::evidence::Compensations,
    plan: &BTreeMap<String, Extensions>,
    tolerance: f64,
) -> Result<Gains> {
    use crate::diagnose::evidence::{plain_of, tolles_lawson_of};
    use rayon::prelude::*;
    let judged: Vec<Option<(String, f64, Option<HeldBack>)>> = (plan.iter())
        .filter(|(_, model)| **model != tolles_lawson_of(model))
        .collect::<Vec<_>>()
        .par_iter()
        .map(|(channel, model)| {
            let Some(gain) = compensations.anomaly_gain(channel, model)? else {
                return Ok(None);
            };
            let plain = compensations.anomaly_gain(channel, &tolles_lawson_of(model))?;
            let plain_gain = plain.map_or(1.0, |g| g.median);
            let departs = gain.departure() > tolerance && gain.departure() > (plain_gain - 1.0).abs();
            let held = (departs && **model != plain_of(model)).then_some(HeldBack::AnomalyGain {
                gain: gain.median,
                plain_gain,
                tolerance,
            });
            Ok(Some(((*channel).clone(), gain.median, held)))
        })
        .collect::<Result<_>>()?;
    let judged: Vec<(String, f64, Option<HeldBack>)> = judged.into_iter().flatten().collect();
    let held = (judged.iter())
        .filter_map(|(channel, _, held)| Some((channel.clone(), held.clone()?)))
        .collect();
    let gains = (judged.into_iter())
        .filter(|(_, _, held)| held.is_none())
        .map(|(channel, gain, _)| (channel, gain))
        .collect();
    Ok((gains, held))
}

/// How far a channel's compensation moves the survey from plain
/// Tolles-Lawson, what moves it, and plain Tolles-Lawson's compensation
/// to set the survey's own figures against.
#[derive(Debug, Clone)]
pub(super) struct Departure {
    /// RMS over the survey, nT.
    pub(super) nt: f64,
    /// What moves it.
    pub(super) moved_by: MovedBy,
    /// The channel compensated with plain Tolles-Lawson (its level
    /// aside), nT.
    pub(super) plain: std::sync::Arc<Vec<f64>>,
}

/// Takes the cross-sensor terms out of `plan` and the diagnosis's models,
/// and marks their findings reported, not applied: under `[diagnose]
/// cross_sensor = "report"` every one, under `"survey"` (the default)
/// those the survey does not bear out, under `"apply"` none.
fn report_cross_sensor(
    plan: &mut BTreeMap<String, Extensions>,
    diagnosis: &mut crate::diagnose::Diagnosis,
    setting: crate::diagnose::CrossSensorUse,
) {
    use crate::diagnose::{CrossSensorUse, Effect};
    let (survey_borne, box_fitted) = match setting {
        CrossSensorUse::Apply => return,
        CrossSensorUse::Survey => (true, true),
        CrossSensorUse::SurveyFitted => (true, false),
        CrossSensorUse::Report => (false, false),
    };
    let borne = |f: &crate::diagnose::Finding| match &f.effect {
        Effect::CrossSensor(cross) => {
            survey_borne
                && (box_fitted || cross.survey_gain.is_some())
                && cross.survey.as_ref().is_some_and(|s| s.holds())
        }
        _ => false,
    };
    let fitted_on_survey = |f: &crate::diagnose::Finding| match &f.effect {
        Effect::CrossSensor(cross) => cross.survey_gain.is_some(),
        _ => false,
    };
    let reported: Vec<(String, String, bool)> = (diagnosis.findings.iter())
        .filter(|f| f.effect.kind() == EffectKind::CrossSensor && !borne(f))
        .filter_map(|f| Some((f.channel.clone(), f.source.clone()?, fitted_on_survey(f))))
        .collect();
    let taken = |channel: &str, s: &crate::model::SourceTerm| match s {
        crate::model::SourceTerm::CrossSensor { name, survey_gain, .. } => {
            (reported.iter()).any(|(c, n, fitted)| c == channel && n == name && *fitted == survey_gain.is_some())
        }
        _ => false,
    };
    for (channel, model) in plan.iter_mut() {
        model.sources.retain(|s| !taken(channel, s));
    }
    for channel in &mut diagnosis.channels {
        let name = channel.channel.clone();
        channel.model.sources.retain(|s| !taken(&name, s));
    }
    let reason = match (survey_borne, box_fitted) {
        (true, false) => "fitted on the box, where two cabin sensors' residuals can stand in for each other on clean flights: reported, not applied, under [diagnose] cross_sensor = \"survey_fitted\", which applies a signal whose gain the survey lines fit, each held out; \"survey\" applies one fitted on the box that the survey bears out, \"apply\" every one".to_string(),
        (true, true) => format!(
            "the survey does not bear this signal out (the channel's difference from a quiet scalar the signal does not read must fall by {:.0} % or more, on more than half the lines), and on the box alone two cabin sensors' residuals can stand in for each other on clean flights: reported, not applied, unless [diagnose] cross_sensor = \"apply\"",
            100.0 * crate::diagnose::SURVEY_CROSS_GAIN
        ),
        (false, _) => "other sensors' signals are reported, not applied, under [diagnose] cross_sensor = \"report\": on clean flights two cabin sensors' residuals can stand in for each other; \"survey_fitted\" applies one whose gain the survey fits, \"survey\" one the survey bears out, \"apply\" every one".into(),
    };
    for finding in (diagnosis.findings.iter_mut()).filter(|f| f.effect.kind() == EffectKind::CrossSensor) {
        if !borne(finding) {
            finding.not_applied = Some(reason.clone());
        }
    }
}

/// Per channel, its [`Departure`].
pub(super) type Departures = BTreeMap<String, Departure>;

/// How far each channel of `plan` departs on the survey from plain
/// Tolles-Lawson ([`crate::diagnose::evidence::departures`] against
/// [`tolles_lawson_of`](crate::diagnose::evidence::tolles_lawson_of)),
/// and what moves it. The figure the verdict sets against the channel's
/// stated uncertainty: no plain pass for a move beyond it that nothing
/// checked.
///
/// The base station's term counts as a move. It is recorded rather than
/// fitted, and the evidence rule judges the findings beside it
/// ([`crate::diagnose::evidence::plain_of`]), but the coefficients it
/// unbiases move the survey as a finding's would, and plain
/// Tolles-Lawson is what a user compares with. On clean plan 579 of the
/// default's safety campaign the station's term alone took a cabin sensor
/// from 0.0069 to 0.0363 nT against truth, under a verdict of PASS.
fn verdict_departures(
    compensations: &crate::diagnose::evidence::Compensations,
    plan: &BTreeMap<String, Extensions>,
) -> Result<Departures> {
    use crate::diagnose::evidence::{departures, plain_of, tolles_lawson_of};
    let measured = departures(compensations, plan, tolles_lawson_of)?;
    let moved_by = |model: &Extensions| {
        let station = (model.sources.iter()).any(|s| s.is_external_field());
        match (model != &plain_of(model), station) {
            (true, true) => MovedBy::FindingsAndBaseStation,
            (false, true) => MovedBy::BaseStation,
            _ => MovedBy::Findings,
        }
    };
    let mut found = Departures::new();
    for (channel, departure) in measured {
        let (Some(model), Some(departure)) = (plan.get(&channel), departure) else {
            continue;
        };
        let departure = Departure {
            nt: departure.survey_departure_nt,
            moved_by: moved_by(model),
            plain: compensations.of(&channel, &tolles_lawson_of(model))?,
        };
        found.insert(channel, departure);
    }
    Ok(found)
}

/// The channels of `plan` whose findings move the survey in a way its
/// own checks cannot judge ([`unchecked_kinds`]), by more than the
/// uncertainty the channel states with them (`departures`: each channel's
/// move, RMS from plain Tolles-Lawson) on evidence within it: what those
/// findings explain of the held-out RMS on the box (theirs among
/// `findings`), √(Σ before² − after²), is no larger than that
/// uncertainty. Returns why each is held back.
///
/// A clean simulated flight (plan 733 of the default's safety campaign:
/// four sensors, 50 Hz, two survey lines, no tie) showed why: a sensor lag
/// of 0.099 s halved the tail sensor's held-out RMS on a box flown with
/// the airframe's coupled motion (0.0302 → 0.0155 nT) and moved the survey
/// by 0.10 nT, against a stated uncertainty of 0.054 nT; against truth the
/// survey went from 0.017 to 0.096 nT. The lag explained 0.026 nT of the
/// held-out RMS, under the stated 0.054 nT. On the concealed-effect flights
/// (`tests/default_compensation.rs`) flown with two lines and no tie, a
/// true lag of 0.15 s on a cabin sensor explained 0.24–1.09 nT on the box
/// against stated uncertainties of 0.015–0.086 nT (7.4 to 46 times), and
/// took the survey from 2.34 to 0.24 nT against truth (mean of ten).
fn unchecked_moves(
    compensations: &crate::diagnose::evidence::Compensations,
    plan: &BTreeMap<String, Extensions>,
    (departures, findings): (&BTreeMap<String, f64>, &[crate::diagnose::Finding]),
    check: crate::diagnose::evidence::SurveyCheck,
) -> Result<Vec<(String, HeldBack)>> {
    use rayon::prelude::*;
    let moved: Vec<(&String, &Extensions, f64, Vec<EffectKind>)> = (plan.iter())
        .filter_map(|(channel, model)| {
            let kinds = unchecked_kinds(model, check);
            let departure = *departures.get(channel)?;
            (!kinds.is_empty() && crate::quality::departs_beyond_stated(departure, None))
                .then_some((channel, model, departure, kinds))
        })
        .collect();
    let judged: Vec<Option<(String, HeldBack)>> = moved
        .par_iter()
        .map(|(channel, model, departure, kinds)| {
            let stated = compensations.stated_nt(channel, model)?;
            // What those findings explain of the held-out RMS, each at the
            // step the search accepted it (the channel's figures would
            // count a base station's gain, which holding back keeps).
            let explained = (findings.iter())
                .filter(|f| f.channel == **channel && f.not_applied.is_none() && kinds.contains(&f.effect.kind()))
                .map(|f| (f.heldout_rms_before_nt.powi(2) - f.heldout_rms_after_nt.powi(2)).max(0.0))
                .sum::<f64>()
                .sqrt();
            let reason = HeldBack::UncheckedOnSurvey {
                survey_nt: *departure,
                stated_nt: stated,
                explained_nt: explained,
                floor_nt: crate::quality::DEPARTURE_FLOOR_NT,
                levels_checked: check != crate::diagnose::evidence::SurveyCheck::NotMade,
            };
            // Beyond the stated uncertainty on the survey, on evidence
            // within it on the box.
            let unsupported = crate::quality::departs_beyond_stated(*departure, stated)
                && !crate::quality::departs_beyond_stated(explained, stated);
            Ok(unsupported.then(|| ((*channel).clone(), reason)))
        })
        .collect::<Result<_>>()?;
    Ok(judged.into_iter().flatten().collect())
}

/// The kinds of `model`'s findings whose move on the survey the survey's
/// own `check` cannot judge, and which [`unchecked_moves`] weighs against
/// what they explain on the box:
/// - a sensor lag, whatever the check: it reads the record itself
///   earlier, so it moves the survey's geology along the lines by τ times
///   its rate, and the box's record moves with it. The lines' levels, at
///   crossovers or between neighbours, show only the part a regional
///   gradient turns into a level. On clean plan 267 (23 lines flown back
///   and forth, no tie) a lag of the tail sensor passed the neighbouring
///   lines and took the survey from 0.021 to 0.092 nT against truth;
/// - a coupling to a recorded channel, where no check could be made: it
///   adds the source's survey record times its coefficient, which
///   nothing but the survey's levels can test. On clean plan 135 (two
///   lines, no tie) a coupling to the aileron servo's current, which the
///   simulator couples to nothing, took a cabin sensor from 0.059 to
///   0.107 nT.
///
/// The other findings change only the interference predicted, and the
/// departure check bounds how far beyond the box they act by what they do
/// over it. On clean plans 300–449 and 580–759 one second-order term
/// helped a cabin sensor from 0.98 to 0.30 nT on a survey with nothing to
/// check it, moving it 4.8 nT against a stated 0.053 nT: judged by this
/// rule it would have been lost.
fn unchecked_kinds(model: &Extensions, check: crate::diagnose::evidence::SurveyCheck) -> Vec<EffectKind> {
    let mut kinds = Vec::new();
    if model.lag_s != 0.0 {
        kinds.push(EffectKind::SensorLag);
    }
    let coupled = (model.sources.iter()).any(|s| !s.is_external_field());
    if coupled && check == crate::diagnose::evidence::SurveyCheck::NotMade {
        kinds.extend([EffectKind::AuxCoupling, EffectKind::CrossSensor]);
    }
    kinds
}

/// [`hold_back_one`] for each channel of `held`, with its reason.
fn hold_back(
    (plan, applied): (&mut BTreeMap<String, Extensions>, &mut BTreeMap<String, f64>),
    diagnosis: &mut crate::diagnose::Diagnosis,
    (options, warnings): (&Settings, &mut Vec<Warning>),
    held: impl IntoIterator<Item = (String, HeldBack)>,
    entirely: bool,
) {
    for one in held {
        hold_back_one((plan, applied), diagnosis, (options, warnings), one, entirely);
    }
}

/// Holds back `channel`'s findings for `reason` under `apply = "auto"`:
/// marks them not applied, fits the channel plain (keeping the base
/// station's term unless `entirely`) and warns; under `"always"` only
/// warns. A channel held back leaves `applied`, the departures of the
/// channels whose findings are applied.
fn hold_back_one(
    (plan, applied): (&mut BTreeMap<String, Extensions>, &mut BTreeMap<String, f64>),
    diagnosis: &mut crate::diagnose::Diagnosis,
    (options, warnings): (&Settings, &mut Vec<Warning>),
    (channel, reason): (String, HeldBack),
    entirely: bool,
) {
    use crate::diagnose::evidence::{plain_of, tolles_lawson_of};
    let judged = |kind: EffectKind| match entirely {
        true => !matches!(kind, EffectKind::Unexplained | EffectKind::VectorCalibration),
        false => applies_to_model(kind),
    };
    let named: Vec<String> = (diagnosis.findings.iter())
        .filter(|f| f.channel == channel && judged(f.effect.kind()) && f.not_applied.is_none())
        .map(|f| {
            format!(
                "{}{}",
                f.effect,
                f.source.as_ref().map(|s| format!(" from {s}")).unwrap_or_default()
            )
        })
        .collect();
    if options.diagnose.apply == crate::diagnose::ApplyDiagnosis::Always {
        warnings.push(Warning::FindingsAppliedAnyway {
            channel,
            findings: named,
            reason,
        });
        return;
    }
    for finding in (diagnosis.findings.iter_mut())
        .filter(|f| f.channel == channel && judged(f.effect.kind()) && f.not_applied.is_none())
    {
        finding.not_applied = Some(format!("{reason}, {FITTED_PLAIN}"));
    }
    let plainer = |model: &Extensions| match entirely {
        true => tolles_lawson_of(model),
        false => plain_of(model),
    };
    if let Some(model) = plan.get_mut(&channel) {
        *model = plainer(model);
    }
    if let Some(entry) = diagnosis.channels.iter_mut().find(|c| c.channel == channel) {
        entry.model = plainer(&entry.model);
    }
    applied.remove(&channel);
    warnings.push(Warning::FindingsHeldBack {
        channel,
        findings: named,
        reason,
    });
}

/// Whether a finding of `kind` changes a channel's own model (a fluxgate
/// calibration is the flight's, an `unexplained` residual changes none).
pub(super) fn applies_to_model(kind: EffectKind) -> bool {
    !matches!(
        kind,
        EffectKind::Unexplained | EffectKind::VectorCalibration | EffectKind::ExternalField
    )
}

/// One warning per channel the diagnosis left with an `unexplained`
/// residual: its compensation is not to be trusted to the noise level.
pub(super) fn unexplained_warnings(diagnosis: &crate::diagnose::Diagnosis) -> Vec<Warning> {
    (diagnosis.findings.iter())
        .filter_map(|f| match &f.effect {
            crate::diagnose::Effect::Unexplained(u) => Some(Warning::Unexplained {
                channel: f.channel.clone(),
                heldout_rms_nt: f.heldout_rms_after_nt,
                residual_to_noise: u.residual_to_noise,
                largest_on: f.located.iter().map(|l| l.label.clone()).collect(),
            }),
            _ => None,
        })
        .collect()
}

/// What a user can do about a failed quality check, given how the flight
/// was fitted.
pub(super) fn next_step(apply: crate::diagnose::ApplyDiagnosis, saved: bool, diagnosed: bool) -> &'static str {
    match (saved || diagnosed, apply) {
        (true, _) => "Look at the report's worst manoeuvres and the diagnosis's unexplained residual; refly the box if a manoeuvre is poor.",
        (false, crate::diagnose::ApplyDiagnosis::Never) => "Fit with the diagnosis (drop --plain, or [diagnose] apply = \"auto\") to model the physics plain Tolles-Lawson leaves out, or run `magcomp diagnose` to see it.",
        (false, _) => "The flight could not be diagnosed; fly a complete box (four headings, each with pitch, roll and yaw) to let the diagnosis model what plain Tolles-Lawson leaves out.",
    }
}
