//! The report's warnings: what the channels' predictions leave short, and
//! the gaps in the box in words.

use super::realise::{median_of, noise_of, Realisation};
use super::ChannelPrediction;
use crate::messages::plan::{gap_state, FomAbove, PlanWarning, UncertainAway};

/// The warning naming the channels whose compensated noise alone is at or
/// above the survey `target`, nT, which no manoeuvre can meet.
pub(super) fn noise_above_target(
    channels: &[ChannelPrediction],
    realisations: &[Realisation],
    target: f64,
) -> Option<PlanWarning> {
    let floored: Vec<(String, f64)> = (channels.iter().zip(&realisations[0].outcomes))
        .filter_map(|(channel, outcome)| {
            let floor = median_of(realisations.iter().map(|r| noise_of(r, &outcome.channel)));
            (floor >= target).then(|| (channel.channel.clone(), floor))
        })
        .collect();
    (!floored.is_empty()).then_some(PlanWarning::NoiseAboveTarget {
        target_nt: target,
        channels: floored,
    })
}

/// What the channels' predictions leave short, one warning per kind
/// naming every channel it concerns: a FOM above its target, simulated
/// flights without an excitation analysis, each gap in the box, and
/// flights whose compensation away from the calibration is uncertain.
pub(super) fn channel_warnings(
    channels: &[ChannelPrediction],
    realisations: &[Realisation],
    target_fom: Option<f64>,
) -> Vec<PlanWarning> {
    let flights = realisations.len();
    let mut warnings = Vec::new();
    warnings.extend(fom_above_target(channels, target_fom));
    let unanalysed: Vec<(String, usize)> = (channels.iter())
        .filter_map(|channel| {
            let count = (realisations.iter())
                .filter(|r| (r.outcomes.iter()).any(|o| o.channel == channel.channel && o.design.is_none()))
                .count();
            (count > 0).then(|| (channel.channel.clone(), count))
        })
        .collect();
    if !unanalysed.is_empty() {
        warnings.push(PlanWarning::NotAnalysed {
            flights,
            channels: unanalysed,
        });
    }
    warnings.extend(gap_warnings(channels, realisations));
    warnings.extend(uncertain_away(channels, flights));
    warnings
}

/// The warning naming the channels whose predicted FOM is above
/// `target_fom`, nT, with their compensated noise.
fn fom_above_target(channels: &[ChannelPrediction], target_fom: Option<f64>) -> Option<PlanWarning> {
    let above: Vec<FomAbove> = (channels.iter())
        .filter(|c| c.meets_fom_target == Some(false))
        .map(|c| FomAbove {
            channel: c.channel.clone(),
            fom_nt: [c.fom_nt.median, c.fom_nt.low, c.fom_nt.high],
            noise_nt: c.noise_nt.median,
        })
        .collect();
    (!above.is_empty()).then(|| PlanWarning::FomAboveTarget {
        target_nt: target_fom.unwrap_or(f64::NAN),
        channels: above,
    })
}

/// The warning naming the channels uncertain away from the calibration on
/// some of the `flights` simulated flights, with how uncertain.
fn uncertain_away(channels: &[ChannelPrediction], flights: usize) -> Option<PlanWarning> {
    let uncertain: Vec<UncertainAway> = (channels.iter())
        .filter(|c| c.uncertain_flights > 0)
        .map(|c| UncertainAway {
            channel: c.channel.clone(),
            flights: c.uncertain_flights,
            jackknife_high_nt: c.jackknife_sigma_nt.high,
            survey_error_high_nt: c.survey_error_nt.high,
        })
        .collect();
    (!uncertain.is_empty()).then_some(PlanWarning::UncertainAway {
        threshold_nt: crate::quality::UNCERTAINTY_WARNING_NT,
        flights,
        channels: uncertain,
    })
}

/// One warning per gap in the box that most realisations name on some
/// channel: what the plan lacks, how to fly it, and the median change it
/// would make on each channel that names it.
fn gap_warnings(channels: &[ChannelPrediction], realisations: &[Realisation]) -> Vec<PlanWarning> {
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
            Some(PlanWarning::Gap {
                label: label.to_string(),
                excitation_flown: first.excitation_flown,
                shape: first.shape.clone(),
                changes: (named.iter())
                    .map(|(c, g)| (channels[*c].channel.clone(), g.change_percent))
                    .collect(),
                flights: first.flights,
            })
        })
        .collect()
}

/// A gap named `label` in channel `c`'s analyses: what the plan flies of
/// it, how to fly it, and the median change it would make.
struct GapFigures {
    /// The share of a typical manoeuvre's excitation the plan's gives;
    /// `None` where it does not fly it.
    excitation_flown: Option<f64>,
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
    Some(GapFigures {
        excitation_flown: first.flown.then(|| median_of(gaps.iter().map(|g| g.excitation_flown))),
        shape: first.shape_words(),
        change_percent: 100.0 * median_of(gaps.iter().map(|g| g.change)),
        flights: gaps.len(),
    })
}

/// The sentence of a gap named `label` in channel `c`'s analyses.
pub(super) fn gap_words(realisations: &[Realisation], c: usize, label: &str) -> String {
    match gap_figures(realisations, c, label) {
        None => format!("the plan's box lacks {label}"),
        Some(g) => format!(
            "{}: flying it ({}) changes the survey uncertainty the coefficients leave by {:+.0} % (median of {} simulated flights).",
            gap_state(label, g.excitation_flown),
            g.shape,
            g.change_percent,
            g.flights
        ),
    }
}
