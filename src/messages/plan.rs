//! What a plan's prediction warns its user of (`magcomp plan`): targets
//! the plan cannot meet, simulated flights it could not analyse, the gaps
//! in its box, and flights whose compensation away from the calibration is
//! uncertain. Each warning names every channel it concerns.

use std::fmt;

use serde::{Serialize, Serializer};

/// A warning of a plan's prediction.
#[derive(Debug, Clone, PartialEq)]
pub enum PlanWarning {
    /// Channels whose compensated noise alone is at or above the survey
    /// target: no manoeuvre can meet it.
    NoiseAboveTarget {
        /// The survey target, nT.
        target_nt: f64,
        /// Each channel and its compensated noise (median over the
        /// simulated flights), nT.
        channels: Vec<(String, f64)>,
    },
    /// Channels whose predicted FOM is above its target.
    FomAboveTarget {
        /// The FOM target, nT.
        target_nt: f64,
        /// The channels, with their figures.
        channels: Vec<FomAbove>,
    },
    /// Simulated flights without an excitation analysis: the windows
    /// leave the design singular.
    NotAnalysed {
        /// Simulated flights in all.
        flights: usize,
        /// Each channel and how many of them it was not analysed on.
        channels: Vec<(String, usize)>,
    },
    /// A gap in the plan's box that most simulated flights name.
    Gap {
        /// The manoeuvre the box lacks, or flies too weakly.
        label: String,
        /// How much of a typical manoeuvre's excitation the plan's gives
        /// (median); `None` where the box does not fly it.
        excitation_flown: Option<f64>,
        /// How to fly it.
        shape: String,
        /// Each channel that names it and the median change of its
        /// survey uncertainty, percent.
        changes: Vec<(String, f64)>,
        /// The simulated flights that name it.
        flights: usize,
    },
    /// Channels whose compensation away from the calibration is uncertain
    /// beyond `threshold_nt` on some simulated flights.
    UncertainAway {
        /// The uncertainty compensate warns beyond, nT.
        threshold_nt: f64,
        /// Simulated flights in all.
        flights: usize,
        /// The channels, with their figures.
        channels: Vec<UncertainAway>,
    },
    /// No set of additions meets the survey target on every channel.
    TargetNotMet {
        /// The most additions searched.
        most_additions: usize,
        /// The survey target, nT.
        target_nt: f64,
    },
}

/// A channel whose predicted FOM is above its target.
#[derive(Debug, Clone, PartialEq)]
pub struct FomAbove {
    /// The channel.
    pub channel: String,
    /// Its FOM over the simulated flights (median, least, most), nT.
    pub fom_nt: [f64; 3],
    /// Its compensated noise (median), nT.
    pub noise_nt: f64,
}

/// A channel whose compensation away from the calibration is uncertain
/// on some simulated flights.
#[derive(Debug, Clone, PartialEq)]
pub struct UncertainAway {
    /// The channel.
    pub channel: String,
    /// The simulated flights it is uncertain on.
    pub flights: usize,
    /// The largest blocked-jackknife uncertainty, nT.
    pub jackknife_high_nt: f64,
    /// The largest survey-line error, nT.
    pub survey_error_high_nt: f64,
}

impl PlanWarning {
    /// Whether the warning names `channel`.
    pub fn names(&self, channel: &str) -> bool {
        match self {
            PlanWarning::NoiseAboveTarget { channels, .. } | PlanWarning::Gap { changes: channels, .. } => {
                channels.iter().any(|(c, _)| c == channel)
            }
            PlanWarning::NotAnalysed { channels, .. } => channels.iter().any(|(c, _)| c == channel),
            PlanWarning::FomAboveTarget { channels, .. } => channels.iter().any(|c| c.channel == channel),
            PlanWarning::UncertainAway { channels, .. } => channels.iter().any(|c| c.channel == channel),
            PlanWarning::TargetNotMet { .. } => false,
        }
    }
}

impl PlanWarning {
    /// The channels the warning names, each with its figures, as the
    /// sentence lists them.
    fn listed(&self) -> String {
        let items: Vec<String> = match self {
            PlanWarning::NoiseAboveTarget { channels, .. } => (channels.iter())
                .map(|(channel, floor)| format!("{channel} ({floor:.3} nT)"))
                .collect(),
            PlanWarning::FomAboveTarget { channels, .. } => (channels.iter())
                .map(|c| {
                    let [median, low, high] = c.fom_nt;
                    format!(
                        "{} (FOM {median:.2} nT (range {low:.2}–{high:.2}), its compensated noise {:.3} nT)",
                        c.channel, c.noise_nt
                    )
                })
                .collect(),
            PlanWarning::NotAnalysed { flights, channels } => (channels.iter())
                .map(|(channel, count)| format!("{channel} ({count} of {flights})"))
                .collect(),
            PlanWarning::Gap { changes, .. } => (changes.iter())
                .map(|(channel, percent)| format!("{percent:+.0} % on {channel}"))
                .collect(),
            PlanWarning::UncertainAway { flights, channels, .. } => (channels.iter())
                .map(|c| {
                    format!(
                        "{} in {} of the {flights} (the blocked jackknife up to {:.3} nT, the survey lines' error up to {:.3} nT)",
                        c.channel, c.flights, c.jackknife_high_nt, c.survey_error_high_nt
                    )
                })
                .collect(),
            PlanWarning::TargetNotMet { .. } => Vec::new(),
        };
        items.join(", ")
    }
}

impl fmt::Display for PlanWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let listed = self.listed();
        match self {
            PlanWarning::NoiseAboveTarget { target_nt, .. } => write!(
                f,
                "no manoeuvre can meet the survey target of {target_nt:.3} nT on {listed}: the compensated channel's noise alone is above it"
            ),
            PlanWarning::FomAboveTarget { target_nt, .. } => write!(
                f,
                "the plan's predicted FOM is above the target of {target_nt:.2} nT on {listed}; no addition to the box lowers it (it measures the compensated residual over the box's own manoeuvres)"
            ),
            PlanWarning::NotAnalysed { .. } => write!(
                f,
                "simulated flights without an excitation analysis (the windows leave the design singular) on {listed}: the survey uncertainty and the additions rest on the others"
            ),
            PlanWarning::Gap {
                label,
                excitation_flown,
                shape,
                flights,
                ..
            } => write!(
                f,
                "{}: flying it ({shape}) changes the survey uncertainty the coefficients leave by {listed} (medians of the {flights} simulated flights that name it).",
                gap_state(label, *excitation_flown)
            ),
            PlanWarning::UncertainAway { threshold_nt, .. } => write!(
                f,
                "on some simulated flights the compensation away from the calibration is uncertain by more than {threshold_nt:.3} nT: {listed}; the planned manoeuvres leave the fit open on the survey's headings and attitudes on some flights, and compensate would warn on them"
            ),
            PlanWarning::TargetNotMet {
                most_additions,
                target_nt,
            } => write!(
                f,
                "no set of up to {most_additions} additions meets the survey target of {target_nt:.3} nT on every channel; the report lists the best found"
            ),
        }
    }
}

/// What the plan's box has of the manoeuvre `label`: none, or a share
/// of a typical one's excitation.
pub fn gap_state(label: &str, excitation_flown: Option<f64>) -> String {
    match excitation_flown {
        None => format!("the plan's box has no {label}"),
        Some(share) => format!(
            "the plan's {label} gives {:.0} % of the excitation of a typical one",
            100.0 * share
        ),
    }
}

/// The plan report (`PLAN_REPORT.json`) gives each warning as its
/// sentence.
impl Serialize for PlanWarning {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plan_warnings_read_as_the_plan_has_always_said_them() {
        let noise = PlanWarning::NoiseAboveTarget {
            target_nt: 0.05,
            channels: vec![("mag_1_uc".into(), 0.0612), ("mag_3_uc".into(), 0.07)],
        };
        assert_eq!(
            noise.to_string(),
            "no manoeuvre can meet the survey target of 0.050 nT on mag_1_uc (0.061 nT), mag_3_uc (0.070 nT): the compensated channel's noise alone is above it"
        );
        assert!(noise.names("mag_3_uc") && !noise.names("mag_2_uc"));
        let fom = PlanWarning::FomAboveTarget {
            target_nt: 1.5,
            channels: vec![FomAbove {
                channel: "mag_2_uc".into(),
                fom_nt: [1.734, 1.2, 2.456],
                noise_nt: 0.0412,
            }],
        };
        assert_eq!(
            fom.to_string(),
            "the plan's predicted FOM is above the target of 1.50 nT on mag_2_uc (FOM 1.73 nT (range 1.20–2.46), its compensated noise 0.041 nT); no addition to the box lowers it (it measures the compensated residual over the box's own manoeuvres)"
        );
        assert_eq!(
            PlanWarning::NotAnalysed {
                flights: 8,
                channels: vec![("mag_1_uc".into(), 2)]
            }
            .to_string(),
            "simulated flights without an excitation analysis (the windows leave the design singular) on mag_1_uc (2 of 8): the survey uncertainty and the additions rest on the others"
        );
        let gap = |excitation_flown| PlanWarning::Gap {
            label: "roll@90".into(),
            excitation_flown,
            shape: "±10° roll".into(),
            changes: vec![("mag_1_uc".into(), -23.4), ("mag_2_uc".into(), 4.0)],
            flights: 7,
        };
        assert_eq!(
            gap(None).to_string(),
            "the plan's box has no roll@90: flying it (±10° roll) changes the survey uncertainty the coefficients leave by -23 % on mag_1_uc, +4 % on mag_2_uc (medians of the 7 simulated flights that name it)."
        );
        assert!(gap(Some(0.314))
            .to_string()
            .starts_with("the plan's roll@90 gives 31 % of the excitation of a typical one: flying it"));
        let uncertain = PlanWarning::UncertainAway {
            threshold_nt: 0.1,
            flights: 8,
            channels: vec![UncertainAway {
                channel: "mag_4_uc".into(),
                flights: 3,
                jackknife_high_nt: 0.2345,
                survey_error_high_nt: 0.31,
            }],
        };
        assert!(uncertain.to_string().ends_with(
            "uncertain by more than 0.100 nT: mag_4_uc in 3 of the 8 (the blocked jackknife up to 0.234 nT, the survey lines' error up to 0.310 nT); the planned manoeuvres leave the fit open on the survey's headings and attitudes on some flights, and compensate would warn on them"
        ));
        assert_eq!(
            PlanWarning::TargetNotMet {
                most_additions: 4,
                target_nt: 0.02
            }
            .to_string(),
            "no set of up to 4 additions meets the survey target of 0.020 nT on every channel; the report lists the best found"
        );
        assert_eq!(
            serde_json::to_string(&PlanWarning::TargetNotMet {
                most_additions: 4,
                target_nt: 0.02
            })
            .unwrap(),
            format!("\"{}\"", "no set of up to 4 additions meets the survey target of 0.020 nT on every channel; the report lists the best found")
        );
    }
}
