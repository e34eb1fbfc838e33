//! A flight's run in words, for stdout.

use super::FlightResult;

/// The lines of [`summary`] for a flight compensated with a saved model:
/// the model, then per channel its calibration figures and this flight's.
pub(super) fn applied_summary(result: &FlightResult, applied: &crate::pipeline::apply::AppliedModel) -> String {
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
            .map(|d| format!(", {}", crate::messages::days_from(d)))
            .unwrap_or_default(),
    );
    for (quality, model) in result.channels.iter().zip(&result.models) {
        let calibration = (applied.calibration.iter())
            .find(|c| c.channel == quality.channel)
            .map_or("no calibration figures saved".into(), |c| c.describe());
        text += &format!(
            "  {}: {} vs {}: on its calibration {calibration}; here 4th-difference noise {:.4} → {:.4} nT",
            quality.channel,
            quality.verdict,
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
                text += &format!(", FOM {before:.2} → {after:.2} nT ({})", quality.manoeuvre_count());
            }
        }
        if let Some(gain) = quality.anomaly_gain {
            text += &format!(", anomaly gain ×{gain:.3}");
        }
        text += "\n";
        text += &verdict_reasons(quality);
        text += &survey_figures(quality);
    }
    text
}

/// A channel's survey figures before and after, a line each: the heading
/// error, the crossovers and the heading level, those it has.
fn survey_figures(quality: &crate::quality::ChannelQuality) -> String {
    let mut text = String::new();
    if let Some(error) = &quality.heading_error {
        text += &format!(
            "    heading error ({} matched samples on reciprocal lines): {:.3} → {:.3} nT\n",
            error.pairs, error.before_nt, error.after_nt
        );
    }
    if let Some(figures) = &quality.crossovers {
        text += &format!(
            "    crossovers ({} where lines cross): RMS {:.3} → {:.3} nT\n",
            figures.crossovers, figures.before_nt, figures.after_nt
        );
    }
    if let Some(figures) = &quality.heading_level {
        text += &format!(
            "    heading level between neighbouring lines ({} lines flown both ways): {:.3} → {:.3} nT\n",
            figures.lines, figures.before_nt, figures.after_nt
        );
    }
    text
}

/// Why a channel's verdict is not a plain PASS, a line each.
fn verdict_reasons(quality: &crate::quality::ChannelQuality) -> String {
    (quality.verdict_reasons.iter())
        .map(|reason| format!("    {reason}\n"))
        .collect()
}

/// One line per channel for the terminal (its verdict, FOM, IR, held-out
/// FOM, heading error and the findings applied), then the warnings; with
/// `verbose`, each channel's fit in detail and the notes, else the notes'
/// count (the quality JSON and the report hold them all). `limit_nt` is
/// the FOM limit (`[quality] fom_limit_nt`).
pub fn summary(result: &FlightResult, limit_nt: f64, verbose: bool) -> String {
    let mut text = format!("{}: {} rows\n", result.flight.display(), result.rows);
    if let Some(applied) = &result.model {
        text += &applied_summary(result, applied);
    }
    for (quality, model) in result.channels.iter().zip(&result.models) {
        if result.model.is_some() {
            break;
        }
        text += &channel_line(result, quality, limit_nt);
        if verbose {
            text += &fit_details(quality, model);
        }
    }
    text += diagnosis_heading(result);
    for applied in &result.applied_findings {
        text += &format!("    {}\n", applied.describe());
    }
    text + &messages(result, verbose)
}

/// The line over the findings applied: the saved model's, the
/// diagnosis's, or why there are none.
fn diagnosis_heading(result: &FlightResult) -> &'static str {
    match (result.diagnosis_mode, result.applied_findings.is_empty()) {
        _ if result.model.is_some() => match result.applied_findings.is_empty() {
            true => "",
            false => "  the model's findings (from its calibration flight):\n",
        },
        (crate::diagnose::ApplyDiagnosis::Never, _) => "  diagnosis: not applied (plain Tolles-Lawson)\n",
        (_, true) if result.diagnosis.is_some() => "  diagnosis: no finding changes the model; plain Tolles-Lawson\n",
        (_, true) => "",
        (_, false) => "  diagnosis applied:\n",
    }
}

/// The notes (with `verbose`, else their count) and the warnings.
fn messages(result: &FlightResult, verbose: bool) -> String {
    let mut text = String::new();
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

/// A fitted channel's line: verdict, FOM against the limit, IR, the
/// held-out FOM, the heading error and the findings applied to it.
fn channel_line(result: &FlightResult, quality: &crate::quality::ChannelQuality, limit_nt: f64) -> String {
    let mut line = format!("  {}: {}", quality.channel, quality.verdict);
    if let (Some(before), Some(after)) = (quality.fom_before_nt, quality.fom_after_nt) {
        line += &format!(
            "  FOM {before:.2} → {after:.2} nT (limit {limit_nt:.2}; {})",
            quality.manoeuvre_count()
        );
    }
    line += &format!(", IR {:.1}", quality.improvement_ratio);
    if let Some(check) = &quality.transfer {
        line += &format!(", held out {:.2} nT", check.held_out_fom_nt);
    }
    if let Some(error) = &quality.heading_error {
        line += &format!(", heading error {:.3} → {:.3} nT", error.before_nt, error.after_nt);
    }
    if let Some(figures) = &quality.crossovers {
        line += &format!(", crossovers {:.3} → {:.3} nT", figures.before_nt, figures.after_nt);
    }
    if let Some(figures) = &quality.heading_level {
        line += &format!(
            ", lines' heading level {:.3} → {:.3} nT",
            figures.before_nt, figures.after_nt
        );
    }
    if let Some(gain) = quality.anomaly_gain {
        line += &format!(", anomaly gain ×{gain:.3}");
    }
    let findings = findings_on(result, &quality.channel);
    if !findings.is_empty() {
        line += &format!("; findings applied: {}", findings.join(", "));
    }
    line + "\n" + &verdict_reasons(quality)
}

/// The findings applied to `channel`, in words. A fluxgate calibration is
/// the fluxgate's ("flux_a (for mag_1_uc)"), found against the channel it
/// names as its source.
fn findings_on(result: &FlightResult, channel: &str) -> Vec<String> {
    use crate::diagnose::EffectKind;
    (result.applied_findings.iter())
        .filter_map(|f| match f.effect {
            EffectKind::VectorCalibration if f.source.as_deref() == Some(channel) => Some(format!(
                "{} of {}",
                f.effect,
                f.channel.split(' ').next().unwrap_or_default()
            )),
            _ if f.channel == channel => Some(format!(
                "{}{}",
                f.effect,
                f.source.as_ref().map(|s| format!(" from {s}")).unwrap_or_default()
            )),
            _ => None,
        })
        .collect()
}

/// The regulariser a channel was fitted with, in words: its estimator
/// when chosen by the solver, else ridge's λ or truncated SVD's rank.
fn regulariser_words(model: &crate::model::FittedModel) -> String {
    let solution = &model.solution;
    match (
        model.solver.as_ref().and_then(|s| s.estimator),
        solution.lambda,
        solution.rank,
    ) {
        (Some(estimator), _, _) => estimator.describe(),
        (None, Some(lambda), _) => format!("ridge λ={lambda:.3e}"),
        (None, _, Some(rank)) => format!("TSVD rank {rank}"),
        _ => String::new(),
    }
}

/// A fitted channel's fit in detail (`-v`): the solver, samples and
/// conditioning, the band-passed residual, why this λ or rank, the held-out
/// FOM, the heading error's matched samples and the box transfers.
fn fit_details(quality: &crate::quality::ChannelQuality, model: &crate::model::FittedModel) -> String {
    let solution = &model.solution;
    let regulariser = regulariser_words(model);
    let mut text = format!(
        "    fit on {}: {} ({} samples, cond {:.2e}); band std {:.3} → {:.3} nT\n    {}\n",
        model.vector_sensor,
        regulariser,
        solution.samples,
        solution.condition_number,
        quality.band_std_before_nt,
        quality.band_std_after_nt,
        solution.reason
    );
    if let Some(check) = &quality.transfer {
        text += &format!(
            "    held-out FOM ({}): {:.2} nT against {:.2} nT in sample ({:.1}×)\n",
            check.method.describe(),
            check.held_out_fom_nt,
            check.in_sample_fom_nt,
            check.ratio
        );
        let evidence = crate::quality::transfer_evidence(quality);
        if check.warning.is_some() && evidence == crate::quality::TransferEvidence::SurveyDisagrees {
            text += "    the held-out ratio is above the warning factor, but the survey's lines over the same ground show no error it would leave (heading level, heading error, crossovers): no warning\n";
        }
    }
    if let Some(fluxgates) = &quality.fluxgates {
        text += &format!("    {}\n", fluxgates.describe());
    }
    text += &survey_checks(quality);
    if let (Some(gain), Some([low, high])) = (quality.anomaly_gain, quality.anomaly_gain_range) {
        text += &format!(
            "    anomaly gain ×{gain:.4} over the survey's rows ({low:.4}–{high:.4}): how the compensation scales a crustal anomaly\n"
        );
    }
    for transfer in &quality.box_transfer {
        text += &format!(
            "    box transfer: fitted on {}, {} residual {:.3} nT (fitted on itself {:.3} nT)\n",
            transfer.fit, transfer.test, transfer.band_std_nt, transfer.own_fit_band_std_nt
        );
    }
    text
}

/// How a channel's survey checks were made (`-v`): the heading error's
/// matched samples, the crossovers and the lines' heading level.
fn survey_checks(quality: &crate::quality::ChannelQuality) -> String {
    let mut text = String::new();
    if let Some(error) = &quality.heading_error {
        text += &format!(
            "    heading error over {} matched samples of reciprocal lines\n",
            error.pairs
        );
    }
    if let Some(figures) = &quality.crossovers {
        text += &format!(
            "    crossovers: {} where survey lines cross{}\n",
            figures.crossovers,
            match figures.external_field_removed {
                true => ", the base station's change between passes taken out",
                false => ", no base station: the external field's change between passes is in them",
            }
        );
    }
    if let Some(figures) = &quality.heading_level {
        text += &format!(
            "    lines' heading level: {} lines flown both ways, each against its neighbours at {} lines, standard error {:.3} nT{}\n",
            figures.lines,
            figures.triples,
            figures.standard_error_nt,
            match figures.external_field_removed {
                true => ", the base station's change between lines taken out",
                false => ", no base station: the external field's change between lines is in it",
            }
        );
    }
    text
}
