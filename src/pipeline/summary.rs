//! A flight's run in words, for stdout.

use super::FlightResult;

/// The lines of [`summary`] for a flight compensated with a saved model:
/// the model, then per channel its calibration figures and this flight's.
pub(super) fn applied_summary(result: &FlightResult, applied: &crate::apply::AppliedModel) -> String {
    let mut text = format!(
        "  compensated with the saved model {} (fitted on {}{}{}{}); nothing refitted\n",
        applied.file.display(),
        applied.fitted_on.display(),
        applied.date.map(|d| format!(", {d}")).unwrap_or_default(),
        applied
            .aircraft
            .as_ref()
            .map(|a| format!(", aircraft {a}"))
            .unwrap_or_default(),
        applied
            .age_days
            .map(|d| format!(", {}", crate::apply::days_from(d)))
            .unwrap_or_default(),
    );
    for (quality, model) in result.channels.iter().zip(&result.models) {
        let calibration = (applied.calibration.iter())
            .find(|c| c.channel == quality.channel)
            .map_or("no calibration figures saved".into(), |c| c.describe());
        text += &format!(
            "  {} vs {}: on its calibration {calibration}; here 4th-difference noise {:.4} → {:.4} nT",
            quality.channel,
            model.vector_sensor,
            quality.noise_4th_difference_before_nt,
            quality.noise_4th_difference_after_nt
        );
        if !model.windows.is_empty() {
            let how = match applied.fitted_on_this_flight {
                true => "on the windows it was fitted on",
                false => "held out on this flight's windows",
            };
            text += &format!(
                "; {how}: band std {:.3} → {:.3} nT, IR {:.2}",
                quality.band_std_before_nt, quality.band_std_after_nt, quality.improvement_ratio
            );
            if let (Some(before), Some(after)) = (quality.fom_before_nt, quality.fom_after_nt) {
                text += &format!(", FOM {before:.2} → {after:.2} nT ({} of 12)", quality.fom_manoeuvres);
            }
        }
        text += "\n";
        if let Some(error) = &quality.heading_error {
            text += &format!(
                "    heading error ({} matched samples on reciprocal lines): {:.3} → {:.3} nT\n",
                error.pairs, error.before_nt, error.after_nt
            );
        }
    }
    text
}

/// A few lines per channel for the terminal, and the warnings; the notes
/// with `verbose`, else their count (the quality JSON and the report hold
/// them all).
pub fn summary(result: &FlightResult, verbose: bool) -> String {
    let mut text = format!("{}: {} rows\n", result.flight.display(), result.rows);
    if let Some(applied) = &result.model {
        text += &applied_summary(result, applied);
    }
    for (quality, model) in result.channels.iter().zip(&result.models) {
        if result.model.is_some() {
            break;
        }
        let solution = &model.solution;
        let regulariser = match (
            model.solver.as_ref().and_then(|s| s.estimator),
            solution.lambda,
            solution.rank,
        ) {
            (Some(estimator), _, _) => estimator.describe(),
            (None, Some(lambda), _) => format!("ridge λ={lambda:.3e}"),
            (None, _, Some(rank)) => format!("TSVD rank {rank}"),
            _ => String::new(),
        };
        text += &format!(
            "  {} vs {}: {} ({} samples, cond {:.2e}); band std {:.3} → {:.3} nT, IR {:.2}",
            quality.channel,
            model.vector_sensor,
            regulariser,
            solution.samples,
            solution.condition_number,
            quality.band_std_before_nt,
            quality.band_std_after_nt,
            quality.improvement_ratio
        );
        if let (Some(before), Some(after)) = (quality.fom_before_nt, quality.fom_after_nt) {
            text += &format!(
                "; FOM {before:.2} → {after:.2} nT ({} of 12 manoeuvres)",
                quality.fom_manoeuvres
            );
        }
        text += &format!("\n    {}\n", solution.reason);
        if let Some(error) = &quality.heading_error {
            text += &format!(
                "    heading error ({} matched samples on reciprocal lines): {:.3} → {:.3} nT\n",
                error.pairs, error.before_nt, error.after_nt
            );
        }
        if let Some(check) = &quality.transfer {
            let how = match check.method {
                crate::quality::transfer::TransferMethod::SecondBox => "second box",
                crate::quality::transfer::TransferMethod::LeaveOneHeadingOut => "leave one heading out",
            };
            text += &format!(
                "    held-out FOM ({how}): {:.2} nT against {:.2} nT in sample ({:.1}×)\n",
                check.held_out_fom_nt, check.in_sample_fom_nt, check.ratio
            );
        }
        for transfer in &quality.box_transfer {
            text += &format!(
                "    box transfer: fitted on {}, {} residual {:.3} nT (fitted on itself {:.3} nT)\n",
                transfer.fit, transfer.test, transfer.band_std_nt, transfer.own_fit_band_std_nt
            );
        }
    }
    text += &match (result.diagnosis_mode, result.applied_findings.is_empty()) {
        _ if result.model.is_some() => match result.applied_findings.is_empty() {
            true => String::new(),
            false => "  the model's findings (from its calibration flight):\n".to_string(),
        },
        (crate::diagnose::ApplyDiagnosis::Never, _) => "  diagnosis: not applied (plain Tolles-Lawson)\n".to_string(),
        (_, true) if result.diagnosis.is_some() => {
            "  diagnosis: no finding changes the model; plain Tolles-Lawson\n".to_string()
        }
        (_, true) => String::new(),
        (_, false) => "  diagnosis applied:\n".to_string(),
    };
    for applied in &result.applied_findings {
        text += &format!("    {}\n", applied.describe());
    }
    match (verbose, result.notes.len()) {
        (_, 0) => {}
        (true, _) => {
            for note in &result.notes {
                text += &format!("  note: {note}\n");
            }
        }
        (false, count) => {
            text += &format!(
                "  {count} note{} in the report (-v prints them)\n",
                if count == 1 { "" } else { "s" }
            )
        }
    }
    for warning in &result.warnings {
        text += &format!("  warning: {warning}\n");
    }
    text
}
