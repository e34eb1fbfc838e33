//! The report's summary: the prediction in a few sentences.

use super::PlanReport;

/// The summary's sentences on the survey `target`, nT: met as the plan
/// stands, or the cheapest additions that meet it (or come closest) and
/// the channels flown with them.
fn target_summary(report: &PlanReport, target: f64) -> Vec<String> {
    let mut lines = Vec::new();
    let meeting: Vec<&str> = (report.channels.iter())
        .filter(|c| c.meets_survey_target == Some(true))
        .map(|c| c.channel.as_str())
        .collect();
    match (report.additions.is_empty(), report.additions_meet_target) {
        (true, Some(true)) => lines.push(format!(
            "The plan meets the survey target of {target:.3} nT as it stands on {} (a channel whose noise alone exceeds it is warned).",
            match meeting.is_empty() {
                true => "no channel".to_string(),
                false => meeting.join(", "),
            }
        )),
        (true, _) => lines.push(format!(
            "No addition lowers the survey uncertainty towards the target of {target:.3} nT."
        )),
        (false, met) => lines.extend(additions_summary(report, target, met)),
    }
    lines
}

/// The summary's sentences on the additions proposed towards the survey
/// `target`, nT, which they meet or (`met` not `Some(true)`) come closest
/// to, and on the channels flown with them.
fn additions_summary(report: &PlanReport, target: f64, met: Option<bool>) -> Vec<String> {
    let mut lines = Vec::new();
    let list: Vec<String> = (report.additions.iter())
        .map(|a| {
            format!(
                "{} on heading {:.0}{}{} ({:.0} s)",
                a.kind.name(),
                a.heading_deg,
                if a.count > 1 {
                    format!(" ×{}", a.count)
                } else {
                    String::new()
                },
                if a.new_leg { ", a new leg" } else { "" },
                a.cost_s
            )
        })
        .collect();
    let total: f64 = report.additions.iter().map(|a| a.cost_s).sum();
    let verdict = match met {
        Some(true) => "meet",
        _ => "come closest to",
    };
    lines.push(format!(
        "The cheapest additions that {verdict} the survey target of {target:.3} nT: {} ({total:.0} s of flight in all).",
        list.join(", ")
    ));
    for channel in &report.with_additions {
        lines.push(format!(
            "Flown with them, {}: survey uncertainty {}, simulated error {}, FOM {}.",
            channel.channel,
            channel.survey_sigma_nt.words(3),
            channel.survey_error_nt.words(3),
            channel.fom_nt.words(2)
        ));
    }
    lines
}

/// The prediction in a few sentences.
pub(super) fn summarise(report: &PlanReport) -> Vec<String> {
    let mut lines = vec![format!(
        "{} simulated flights of the plan ({} manoeuvres on headings {}, {:.0} s of calibration); aircraft: {}.",
        report.seeds.len(),
        report.manoeuvres,
        (report.headings_deg.iter())
            .map(|h| format!("{h:.0}"))
            .collect::<Vec<_>>()
            .join(", "),
        report.calibration_s,
        report.installation
    )];
    for channel in &report.channels {
        lines.push(format!(
            "{}: FOM {} after compensation ({} before); survey uncertainty {} (coefficients {:.3} nT, noise {:.3} nT); the simulated survey lines' error {}.",
            channel.channel,
            channel.fom_nt.words(2),
            channel.fom_before_nt.words(1),
            channel.survey_sigma_nt.words(3),
            channel.coefficient_sigma_nt.median,
            channel.noise_nt.median,
            channel.survey_error_nt.words(3),
        ));
    }
    if let Some(target) = report.target_survey_sigma_nt {
        lines.extend(target_summary(report, target));
    }
    lines
}
