//! What a diagnosis says beside its findings, as [`Diagnosing`] notes: what
//! it could not check, how it held the calibration out, and the figures of
//! a check whose finding does not stand. They are DIAGNOSIS.json's
//! `notes` and the run's notes.

use std::fmt;

/// A note of the diagnosis.
#[derive(Debug, Clone, PartialEq)]
pub enum Diagnosing {
    /// The fluxgate's calibration could not be checked against a scalar
    /// channel.
    FluxgateNotChecked {
        /// Why, in words.
        reason: String,
    },
    /// Windows given by time, without headings, are held out one by one.
    HeldOutByWindow {
        /// The windows.
        windows: usize,
    },
    /// Fewer than three windows given by time are held out by quarters.
    HeldOutByQuarter {
        /// The windows.
        windows: usize,
    },
    /// A channel whose calibration could not be tested.
    ChannelNotTested {
        /// Why, in words (it names the channel).
        reason: String,
    },
    /// A channel's search used the other λ criterion; its diagnosed model
    /// keeps the pipeline's.
    OtherCriterion {
        /// The channel.
        channel: String,
        /// The criterion the search used, in words.
        searched_by: String,
        /// The pipeline's criterion, in words.
        kept: String,
        /// Held-out RMS of plain Tolles-Lawson by the pipeline's criterion, nT.
        baseline_nt: f64,
        /// The same by the other criterion, nT.
        other_nt: f64,
        /// Held-out RMS of the diagnosed model with the pipeline's
        /// criterion, nT.
        final_nt: f64,
    },
    /// The fluxgate's held-out mismatch against the quietest scalar
    /// channel, too small (or not removed by the calibration) for a
    /// `vector_calibration` finding.
    FluxgateMismatchShort {
        /// The fluxgate.
        sensor: String,
        /// The scalar channel it is judged against.
        reference: String,
        /// That channel's own aircraft field over the manoeuvres, nT.
        reference_interference_nt: f64,
        /// Held-out mismatch of the raw fluxgate, nT.
        before_nt: f64,
        /// The same calibrated, nT.
        after_nt: f64,
        /// What a finding needs, nT.
        threshold_nt: f64,
        /// `[diagnose] vector_mismatch_nt`, nT.
        least_nt: f64,
    },
    /// A channel for which no cross-sensor signal could be formed: the
    /// flight has no other scalar to take as the reference.
    CrossSensorNotTried {
        /// The channel.
        channel: String,
        /// The fluxgates the flight has.
        fluxgates: usize,
    },
    /// Findings applied where the survey has nothing to check them
    /// against.
    SurveyNotChecked {
        /// The channels.
        channels: Vec<String>,
        /// The crossovers with a base station a check needs.
        least_crossovers: usize,
        /// The parallel lines flown both ways a check needs.
        least_lines: usize,
    },
}

impl fmt::Display for Diagnosing {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Diagnosing::FluxgateNotChecked { reason } => write!(f, "fluxgate calibration not checked: {reason}"),
            Diagnosing::HeldOutByWindow { windows } => write!(
                f,
                "held out window by window ({windows} windows given by time, without headings), not heading by heading: the figures test what those windows share, and an effect that changes with heading is tested only as far as they differ"
            ),
            Diagnosing::HeldOutByQuarter { windows } => write!(
                f,
                "held out by quarters of {windows} window{} given by time: each quarter is predicted from the rest of its own window, so the figures test consistency within the windows, not transfer to other headings or manoeuvres",
                if *windows == 1 { "" } else { "s" }
            ),
            Diagnosing::ChannelNotTested { reason } => f.write_str(reason),
            Diagnosing::OtherCriterion {
                channel,
                searched_by,
                kept,
                baseline_nt,
                other_nt,
                final_nt,
            } => write!(
                f,
                "{channel}: λ picked by {searched_by} predicts the held-out headings better in band than by {kept} ({baseline_nt:.4} → {other_nt:.4} nT), so the search used it; the diagnosed model keeps {kept} ({final_nt:.4} nT held out with the findings, if any), because a less regularised fit is not checked outside the band: held-out figures measure only the calibration band, and on simulated flights with known truth the pipeline's criterion compensated closer to it outside the band"
            ),
            Diagnosing::FluxgateMismatchShort {
                sensor,
                reference,
                reference_interference_nt,
                before_nt,
                after_nt,
                threshold_nt,
                least_nt,
            } => write!(
                f,
                "{sensor}'s magnitude against {reference} (the scalar with the least aircraft field, {reference_interference_nt:.1} nT over the manoeuvres): held-out mismatch {before_nt:.1} nT raw, {after_nt:.1} nT calibrated; below the {threshold_nt:.0} nT a finding needs ({least_nt:.0} nT and three times that field), or not removed by the calibration"
            ),
            Diagnosing::CrossSensorNotTried { channel, fluxgates } => write!(
                f,
                "{channel}: other sensors as interference sensors not tried: the flight has no other scalar to take as the reference, and {} less {channel} would hold {channel}'s own interference",
                match fluxgates {
                    1 => "its fluxgate's magnitude".to_string(),
                    n => format!("each of its {n} fluxgates' magnitudes"),
                }
            ),
            Diagnosing::SurveyNotChecked {
                channels,
                least_crossovers,
                least_lines,
            } => write!(
                f,
                "the findings applied on {} were not checked against the survey's line levels: it has fewer than {least_crossovers} crossovers with a base station, and no block of {least_lines} or more parallel lines flown both ways",
                channels.join(", ")
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_diagnosis_notes_read_as_the_diagnosis_has_always_said_them() {
        let said = |note: Diagnosing| note.to_string();
        assert_eq!(
            said(Diagnosing::HeldOutByQuarter { windows: 1 }),
            "held out by quarters of 1 window given by time: each quarter is predicted from the rest of its own window, so the figures test consistency within the windows, not transfer to other headings or manoeuvres"
        );
        assert!(
            said(Diagnosing::HeldOutByQuarter { windows: 2 }).starts_with("held out by quarters of 2 windows given")
        );
        assert!(said(Diagnosing::HeldOutByWindow { windows: 5 }).starts_with(
            "held out window by window (5 windows given by time, without headings), not heading by heading"
        ));
        assert_eq!(
            said(Diagnosing::FluxgateNotChecked {
                reason: "no INS".into()
            }),
            "fluxgate calibration not checked: no INS"
        );
        assert_eq!(
            said(Diagnosing::SurveyNotChecked {
                channels: vec!["mag_1_uc".into(), "mag_3_uc".into()],
                least_crossovers: 2,
                least_lines: 5,
            }),
            "the findings applied on mag_1_uc, mag_3_uc were not checked against the survey's line levels: it has fewer than 2 crossovers with a base station, and no block of 5 or more parallel lines flown both ways"
        );
        assert_eq!(
            said(Diagnosing::FluxgateMismatchShort {
                sensor: "flux_a".into(),
                reference: "mag_1_uc".into(),
                reference_interference_nt: 12.34,
                before_nt: 40.06,
                after_nt: 38.0,
                threshold_nt: 87.0,
                least_nt: 50.0,
            }),
            "flux_a's magnitude against mag_1_uc (the scalar with the least aircraft field, 12.3 nT over the manoeuvres): held-out mismatch 40.1 nT raw, 38.0 nT calibrated; below the 87 nT a finding needs (50 nT and three times that field), or not removed by the calibration"
        );
        let other = said(Diagnosing::OtherCriterion {
            channel: "mag_4_uc".into(),
            searched_by: "PRESS".into(),
            kept: "blocked PRESS".into(),
            baseline_nt: 0.05,
            other_nt: 0.04,
            final_nt: 0.03,
        });
        assert!(other.starts_with("mag_4_uc: λ picked by PRESS predicts the held-out headings better in band than by blocked PRESS (0.0500 → 0.0400 nT), so the search used it; the diagnosed model keeps blocked PRESS (0.0300 nT held out"));
    }
}
