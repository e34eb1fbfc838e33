//! The additions to the plan's box: chosen greedily towards the survey
//! target and flown again with the plan, or, without a target, each
//! candidate's value alone.

use super::file::Plan;
use super::realise::{median_of, noise_of, predictions, realise_all, Realisation};
use super::warnings::noise_above_target;
use super::{Addition, CandidateValue, ChannelPrediction};
use crate::calibration::headings::angle_apart;
use crate::calibration::windows::ManoeuvreKind;
use crate::config::Settings;
use crate::error::{Error, Result};
use crate::simulate::scenario::{RawScenario, Scenario};

/// An addition is taken only if it lowers the channels' summed excess
/// over the target by at least this fraction.
const LEAST_GAIN: f64 = 0.005;

/// Extra flight time for a manoeuvre on a heading that is not a leg of
/// the plan: a lead-in and two 90° turns at 3°/s, s.
const NEW_LEG_S: f64 = 80.0;

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
pub(super) struct Proposed {
    /// The additions chosen towards the survey target.
    pub(super) additions: Vec<Addition>,
    /// Whether they meet it; `None` without a target or an analysis.
    pub(super) additions_meet_target: Option<bool>,
    /// The channels predicted with the additions flown.
    pub(super) with_additions: Vec<ChannelPrediction>,
    /// Without a target, what each candidate alone would do.
    pub(super) candidates: Vec<CandidateValue>,
}

/// The additions towards the plan's survey target and the channels flown
/// with them, or without a target each candidate's value; warns in
/// `warnings` of channels whose noise alone is above the target.
pub(super) fn propose(
    plan: &Plan,
    (realisations, channels): (&[Realisation], &[ChannelPrediction]),
    (seeds, settings): (&[u64], &Settings),
    warnings: &mut Vec<crate::messages::PlanWarning>,
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

/// Greedy additions towards `target` (see [`crate::plan`]): the list and
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
