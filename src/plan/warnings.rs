//! The report's warnings: what the channels' predictions leave short, and
//! the gaps in the box in words.

use super::realise::{median_of, noise_of, Realisation};
use super::ChannelPrediction;

/// The warning naming the channels whose compensated noise alone is at or
/// above the survey `target`, nT, which no manoeuvre can meet.
pub(super) fn noise_above_target(
    channels: &[ChannelPrediction],
    realisations: &[Realisation],
    target: f64,
) -> Option<String> {
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

/// What the channels' predictions leave short, one warning per kind
/// naming every channel it concerns: a FOM above its target, simulated
/// flights without an excitation analysis, each gap in the box, and
/// flights whose compensation away from the calibration is uncertain.
pub(super) fn channel_warnings(
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
pub(super) fn gap_words(realisations: &[Realisation], c: usize, label: &str) -> String {
    match gap_figures(realisations, c, label) {
        None => format!("the plan's box lacks {label}"),
        Some(g) => format!(
            "{}: flying it ({}) changes the survey uncertainty the coefficients leave by {:+.0} % (median of {} simulated flights).",
            g.state, g.shape, g.change_percent, g.flights
        ),
    }
}
