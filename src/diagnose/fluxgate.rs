//! Is the fluxgate itself wrong? Its magnitude against the scalar channel
//! with the least aircraft field, held out heading by heading; the
//! `vector_calibration` finding when the mismatch stands.

use super::*;

/// The scalar channel with the least aircraft field of its own, and that
/// field's size: the standard deviation over the calibration windows of
/// the interference plain Tolles-Lawson fitted on them predicts, nT.
pub(super) fn quietest_reference(
    calibration: &Calibration,
    (terms, options): (&TermSet, &FitOptions),
    stores: &StorePool,
) -> Result<(String, f64)> {
    let ranked = super::cross::ranked_by_interference(calibration, (terms, options), stores)?;
    ranked.into_iter().next().ok_or_else(|| crate::Error::Fit {
        path: calibration.log.source().to_path_buf(),
        channel: calibration.sensor.prefix.clone(),
        source: crate::error::FitFailure::Other("no scalar channel to judge the fluxgate against".into()),
    })
}

/// The mismatch a `vector_calibration` finding needs, nT:
/// `vector_mismatch_nt` plus three times the reference's own aircraft
/// field, which the fluxgate calibration would otherwise take for offsets
/// and scale errors of the fluxgate.
pub(super) fn mismatch_threshold(settings: &DiagnoseOptions, reference_interference_nt: f64) -> f64 {
    settings.vector_mismatch_nt + 3.0 * reference_interference_nt
}

/// Calibrates the fluxgate against `reference` and measures the mismatch
/// held out: each heading's calibration windows against a calibration
/// fitted on the rest of the flight. `None` when the flight cannot pin a
/// calibration.
pub(super) fn check_fluxgate(
    log: &FlightLog,
    sensor: &VectorSensor,
    reference: &str,
    windows: &[CalibrationWindow],
    reference_interference_nt: f64,
    settings: &DiagnoseOptions,
) -> std::result::Result<FluxgateCheck, String> {
    const ITERATIONS: usize = 100;
    let folds = fold_rows(windows, log.time_s(), log.len());
    // Each heading's windows held out of a calibration on the rest of the
    // flight, once the whole flight's stands; the folds side by side.
    let calibration = calibrate(log, sensor, reference, &[], ITERATIONS).map_err(|e| e.to_string())?;
    let fold_calibrations: Vec<Option<VectorCalibration>> = folds
        .par_iter()
        .map(|(_, train)| calibrate_near(log, sensor, (reference, train), ITERATIONS, &calibration).ok())
        .collect();
    let scalar = &log
        .channel(&calibration.reference)
        .ok_or_else(|| format!("the reference '{}' is not in the flight", calibration.reference))?
        .values;
    let field = log.vector_components(sensor);
    let located = worst_windows(windows, log.time_s(), (field, scalar));
    let (mut before, mut after) = (Vec::new(), Vec::new());
    for ((held, _), fold) in folds.into_iter().zip(fold_calibrations) {
        let Some(fold) = fold else {
            continue;
        };
        for i in held.into_iter().flatten() {
            let m = [field[0][i], field[1][i], field[2][i]];
            if m.iter().all(|v| v.is_finite()) && scalar[i].is_finite() {
                let magnitude = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                before.push(magnitude(m) - scalar[i]);
                after.push(magnitude(fold.correct(m)) - scalar[i]);
            }
        }
    }
    if before.is_empty() {
        return Err("no heading's windows could be held out from a calibration on the rest of the flight".into());
    }
    Ok(FluxgateCheck {
        calibration,
        heldout_mismatch_before_nt: root_mean_square(&before),
        heldout_mismatch_after_nt: root_mean_square(&after),
        reference_interference_nt,
        threshold_nt: mismatch_threshold(settings, reference_interference_nt),
        located,
    })
}

/// Rows of a flight `rows` long.
type Rows = Vec<std::ops::Range<usize>>;

/// Each heading's (held-out rows, training rows): the heading's windows,
/// and the rest of the flight around them.
fn fold_rows(windows: &[CalibrationWindow], time: &[f64], rows: usize) -> Vec<(Rows, Rows)> {
    folds(windows)
        .into_iter()
        .map(|(out, _)| {
            let held: Rows = out.iter().map(|w| w.rows(time)).collect();
            let mut train = Vec::new();
            let mut next = 0;
            let mut sorted = held.clone();
            sorted.sort_by_key(|r| r.start);
            for range in &sorted {
                if range.start > next {
                    train.push(next..range.start);
                }
                next = next.max(range.end);
            }
            train.push(next..rows);
            (held, train)
        })
        .collect()
}

/// The three windows where the fluxgate's magnitude misses the scalar
/// most (RMS), worst first.
fn worst_windows(windows: &[CalibrationWindow], time: &[f64], (field, scalar): ([&[f64]; 3], &[f64])) -> Vec<Located> {
    let mut per_window: Vec<(f64, &CalibrationWindow)> = Vec::new();
    for window in windows {
        let misses: Vec<f64> = window
            .rows(time)
            .filter(|&i| scalar[i].is_finite() && field.iter().all(|c| c[i].is_finite()))
            .map(|i| (field[0][i].powi(2) + field[1][i].powi(2) + field[2][i].powi(2)).sqrt() - scalar[i])
            .collect();
        if !misses.is_empty() {
            per_window.push((root_mean_square(&misses), window));
        }
    }
    per_window.sort_by(|a, b| b.0.total_cmp(&a.0));
    per_window
        .iter()
        .take(3)
        .map(|(_, w)| Located {
            t_start: w.t_start,
            t_end: w.t_end,
            label: w.display_label(),
        })
        .collect()
}

/// Whether the fluxgate's magnitude misses the scalar total field by more
/// than `vector_mismatch_nt` held out and the calibration removes most of
/// it: the `vector_calibration` finding. (A better Tolles-Lawson fit on the
/// calibrated fluxgate is not evidence on its own: calibrating also
/// removes the aircraft's own field at the fluxgate, which can lower a
/// sensor's held-out RMS markedly with a fluxgate that has no error of its
/// own; measured figures: docs/measurements.md, section diagnose::fluxgate.)
pub(super) fn mismatch_stands(check: &FluxgateCheck, settings: &DiagnoseOptions) -> bool {
    check.heldout_mismatch_before_nt > check.threshold_nt
        && check.heldout_mismatch_after_nt < check.heldout_mismatch_before_nt * (1.0 - settings.min_improvement)
}

/// The `vector_calibration` finding of a check that stands, naming the
/// channels whose held-out fit the calibrated fluxgate improves.
pub(super) fn fluxgate_finding(check: &FluxgateCheck, channels: &[ChannelDiagnosis]) -> Finding {
    let helped: Vec<(&str, f64, f64)> = channels
        .iter()
        .filter_map(|c| {
            let calibrated = c.heldout_rms_calibrated_fluxgate_nt?;
            (calibrated < c.heldout_rms_baseline_nt).then_some((
                c.channel.as_str(),
                c.heldout_rms_baseline_nt,
                calibrated,
            ))
        })
        .collect();
    let c = &check.calibration;
    let tolles_lawson = match helped.is_empty() {
        true => "Tolles-Lawson absorbs most of it (its terms are linear in the direction cosines), so the compensation changes little; vector products and heading need the calibration.".to_string(),
        false => format!(
            "Refitting Tolles-Lawson on the calibrated fluxgate lowers the held-out RMS of {}.",
            helped
                .iter()
                .map(|(c, raw, calibrated)| format!("{c} ({raw:.4} → {calibrated:.4} nT)"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    Finding {
        effect: Effect::VectorCalibration(FluxgateErrors {
            scale: c.scale,
            offset_nt: c.offset_nt,
            non_orthogonality_deg: c.non_orthogonality_deg,
        }),
        channel: c.sensor.clone(),
        source: Some(c.reference.clone()),
        explanation: format!(
            "The magnitude of {} misses the total field of {} by {:.1} nT RMS as the aircraft turns: scale factors {:.4}, {:.4}, {:.4}, non-orthogonality {:.2}°, {:.2}°, {:.2}° and offsets {:.0}, {:.0}, {:.0} nT (the sensor's own errors and any aircraft field at it) explain all but {:.2} nT. {tolles_lawson}",
            c.sensor,
            c.reference,
            check.heldout_mismatch_before_nt,
            c.scale[0],
            c.scale[1],
            c.scale[2],
            c.non_orthogonality_deg[0],
            c.non_orthogonality_deg[1],
            c.non_orthogonality_deg[2],
            c.offset_nt[0],
            c.offset_nt[1],
            c.offset_nt[2],
            check.heldout_mismatch_after_nt
        ),
        located: check.located.clone(),
        heldout_rms_before_nt: check.heldout_mismatch_before_nt,
        heldout_rms_after_nt: check.heldout_mismatch_after_nt,
        not_applied: None,
        anomaly_gain: None,
    }
}
