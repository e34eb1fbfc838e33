//! Findings in words: the effect, its parameters, where it matters, and
//! the `unexplained` finding for structured residual no candidate explains.

use super::*;

/// Least share of the final residual's energy in structured stretches for
/// an `unexplained` finding.
pub(super) const UNEXPLAINED_SHARE: f64 = 0.5;

/// An `unexplained` finding when what is left after the search (and the
/// second-order term, where it helps) is structured, held out and in
/// sample alike: at least half its energy in stretches that stand out
/// ([`localise::STRUCTURE_FACTOR`]), in two manoeuvres or more, and the
/// held-out RMS three times the in-band noise floor. One stretch alone is
/// not enough: leaving a heading out can extrapolate badly over one
/// manoeuvre, so that a single stretch holds about half a channel's
/// residual with nothing concealed there (measured figures:
/// docs/measurements.md, section diagnose::finding), while an unrecorded
/// current that switches shows wherever it switched.
pub(super) fn unexplained(channel: &str, rms_nt: f64, found: &localise::Localisation) -> Option<Finding> {
    if !is_structured(rms_nt, found) {
        return None;
    }
    let columns = coherent_columns(found).join(", ");
    let band = loudest_band(found);
    Some(Finding {
        effect: Effect::Unexplained(Unexplained {
            structured_energy_share: found.structured_energy_share,
            noise_floor_nt: found.noise_floor_nt,
            residual_to_noise: rms_nt / found.noise_floor_nt.max(f64::MIN_POSITIVE),
        }),
        channel: channel.to_string(),
        source: None,
        explanation: format!(
            "{:.0} % of what is left of {channel}'s residual ({rms_nt:.4} nT held out, {:.1} times the sensor noise in the band) sits in {} stretches, most of it at {band}, and nothing in the library explains it. The recorded columns most coherent with it are {columns}; look at what the aircraft was doing then (an unrecorded load switching, a sensor fault, a local anomaly).",
            100.0 * found.structured_energy_share,
            rms_nt / found.noise_floor_nt.max(f64::MIN_POSITIVE),
            found.structured.len()
        ),
        located: found.structured.clone(),
        heldout_rms_before_nt: rms_nt,
        heldout_rms_after_nt: rms_nt,
        not_applied: None,
        anomaly_gain: None,
    })
}

/// A held-out residual this many times the in-band noise floor is
/// unexplained wherever it lies, structured in stretches or spread over
/// every manoeuvre. A model that describes the aircraft predicts a heading
/// it did not see to within the noise, the error of its coefficients and
/// the Earth field's own change in the band (the sensor swings through
/// the field's gradient as the aircraft manoeuvres): on 36 channels of 12
/// clean simulated flights (tail, cabin and wing; seeds 500–511) the
/// search's held-out residual was 1.6–10.5 times the floor, the largest on
/// tail sensors, whose floor is lowest. On a real survey aircraft the
/// cabin sensors' residual held out was 80–1,700 times theirs. Fifty
/// leaves five times the clean flights' worst.
pub(super) const FAR_ABOVE_NOISE: f64 = 50.0;

/// An `unexplained` finding for a residual `rms_nt` held out
/// ([`FAR_ABOVE_NOISE`] times the noise floor or more) that the search
/// could not bring down, spread or not: where it is largest (manoeuvres,
/// and the headings they were flown on), in which band, and the columns
/// most coherent with it. `in_sample_nt` is the same model's residual
/// fitted on every heading: far above the noise too, the model lacks
/// physics; near it, the model fits what it saw and does not carry to
/// the heading it did not see.
pub(super) fn far_above_noise(
    channel: &str,
    rms_nt: f64,
    in_sample_nt: f64,
    found: &localise::Localisation,
) -> Option<Finding> {
    let floor = found.noise_floor_nt;
    if !(floor > 0.0 && rms_nt > FAR_ABOVE_NOISE * floor) {
        return None;
    }
    let mut worst: Vec<&localise::WindowResidual> = found.windows.iter().collect();
    worst.sort_by(|a, b| b.heldout_rms_final_nt.total_cmp(&a.heldout_rms_final_nt));
    let located: Vec<Located> = (worst.iter().take(3))
        .map(|w| Located {
            t_start: w.t_start,
            t_end: w.t_end,
            label: w.label.clone(),
        })
        .collect();
    let places = (worst.iter().take(3))
        .map(|w| format!("{} ({:.3} nT)", w.label, w.heldout_rms_final_nt))
        .collect::<Vec<_>>()
        .join(", ");
    let band = loudest_band(found);
    let columns = match coherent_columns(found) {
        named if named.is_empty() => "no recorded column".to_string(),
        named => named.join(", "),
    };
    let ratio = rms_nt / floor;
    let kind = match in_sample_nt > FAR_ABOVE_NOISE * floor {
        true => format!("fitted on every heading it still leaves {in_sample_nt:.4} nT, so physics is missing from the model"),
        false => format!("fitted on every heading it leaves {in_sample_nt:.4} nT, so the model fits what it saw but does not carry to a heading it did not see"),
    };
    Some(Finding {
        effect: Effect::Unexplained(Unexplained {
            structured_energy_share: found.structured_energy_share,
            noise_floor_nt: floor,
            residual_to_noise: ratio,
        }),
        channel: channel.to_string(),
        source: None,
        explanation: format!(
            "{channel}'s best model leaves {rms_nt:.4} nT held out, {ratio:.0} times the sensor noise in the band ({floor:.4} nT), and nothing in the library brings it down; {kind}. It is largest on {places}, most of it at {band}; the recorded columns most coherent with it are {columns}. The compensation of this channel is not to be trusted to that level: look at the installation and what the aircraft was doing (an unrecorded current, a sensor fault, a fluxgate that does not see the sensor's field)."
        ),
        located,
        heldout_rms_before_nt: rms_nt,
        heldout_rms_after_nt: rms_nt,
        not_applied: None,
        anomaly_gain: None,
    })
}

/// The sub-band where the residual is largest, e.g. "0.10–0.30 Hz".
fn loudest_band(found: &localise::Localisation) -> String {
    (found.spectrum.iter())
        .max_by(|a, b| a.residual_rms_nt.total_cmp(&b.residual_rms_nt))
        .map(|b| format!("{:.2}–{:.2} Hz", b.low_hz, b.high_hz))
        .unwrap_or_default()
}

/// The three recorded columns most coherent with the residual, with R².
fn coherent_columns(found: &localise::Localisation) -> Vec<String> {
    (found.coherence.iter().take(3))
        .map(|c| format!("{} (R² {:.2})", c.column, c.r_squared))
        .collect()
}

/// Whether a residual of `rms_nt` is structured as [`unexplained`] asks.
pub(super) fn is_structured(rms_nt: f64, found: &localise::Localisation) -> bool {
    let labels: std::collections::BTreeSet<&str> = found.structured.iter().map(|l| l.label.as_str()).collect();
    found.structured_energy_share >= UNEXPLAINED_SHARE && labels.len() >= 2 && rms_nt > 3.0 * found.noise_floor_nt
}

pub(super) fn describe(extension: &Extension) -> String {
    match extension {
        Extension::Lag { lag_s } => format!("sensor_lag {lag_s:.2} s"),
        Extension::Eddy { tau_s } => format!("eddy_time_constant {tau_s:.2} s"),
        Extension::Coupling { source } => match source.strip_prefix(crate::model::cross_sensor::CROSS_COLUMN_PREFIX) {
            Some(sensors) => format!("cross_sensor from {sensors}"),
            None => format!("aux_coupling from {source}"),
        },
        Extension::CouplingRate { source } => format!("aux_coupling from the rate of {source}"),
        Extension::CouplingWithRate { source } => format!("aux_coupling from {source} and its rate"),
        Extension::External { source } => format!("external_field from {source}"),
        Extension::SecondOrder => "second_order".into(),
    }
}

/// A sensor lag found near `lag_s`, refined in steps of 0.01 s (a tenth
/// of a sample at 10 Hz) around that grid point: its effect and words,
/// `model` set to it, and the held-out residuals it leaves.
fn lag_finding(problem: &Problem, model: &mut Model, lag_s: f64) -> Result<(Effect, String, HeldOut)> {
    let base = Model {
        lag_s: 0.0,
        ..model.clone()
    };
    let refined = refine(problem, (lag_s, 0.01, 5), |lag_s| Model { lag_s, ..base.clone() })?;
    let explanation = format!(
        "{} reads the field {:.3} s {} the fluxgate and attitude: its record is shifted in time against the regressors, which leaves a residual proportional to the rate of change during every manoeuvre.",
        problem.channel,
        refined.0.abs(),
        if refined.0 > 0.0 { "later than" } else { "earlier than" }
    );
    model.lag_s = refined.0;
    Ok((
        Effect::SensorLag(SensorLag { lag_s: refined.0 }),
        explanation,
        refined.1,
    ))
}

/// An eddy time constant found near `tau_s`, refined in steps of a tenth
/// of τ around that grid point: its effect and words, `model` set to it,
/// and the held-out residuals it leaves.
fn eddy_finding(problem: &Problem, model: &mut Model, tau_s: f64) -> Result<(Effect, String, HeldOut)> {
    let base = Model {
        eddy_tau_s: 0.0,
        ..model.clone()
    };
    let refined = refine(problem, (tau_s, 0.1 * tau_s, 4), |eddy_tau_s| Model {
        eddy_tau_s,
        ..base.clone()
    })?;
    let explanation = format!(
        "Eddy currents in the airframe near {} build up and decay with a time constant of about {:.2} s instead of following the field's rate of change at once: the eddy terms, lagged by it, explain the residual that plain Tolles-Lawson leaves in the faster manoeuvres.",
        problem.channel, refined.0
    );
    model.eddy_tau_s = refined.0;
    Ok((
        Effect::EddyTimeConstant(EddyTimeConstant { tau_s: refined.0 }),
        explanation,
        refined.1,
    ))
}

/// Describes an accepted extension; a lag is refined first. Returns the
/// finding with the model and held-out residuals it ends with.
pub(super) fn finding(
    problem: &Problem,
    mut model: Model,
    extension: &Extension,
    (before_nt, before_windows): (f64, &[WindowFit]),
    mut result: HeldOut,
) -> Result<(Finding, Model, HeldOut)> {
    let (effect, source, explanation);
    match extension {
        Extension::Lag { lag_s } => {
            (effect, explanation, result) = lag_finding(problem, &mut model, *lag_s)?;
            source = None;
        }
        Extension::Eddy { tau_s } => {
            (effect, explanation, result) = eddy_finding(problem, &mut model, *tau_s)?;
            source = None;
        }
        Extension::Coupling { source: column }
        | Extension::CouplingRate { source: column }
        | Extension::CouplingWithRate { source: column } => {
            (effect, explanation) = coupling(problem, &model, extension, column)?;
            source = Some(column.clone());
        }
        Extension::SecondOrder => {
            let term_rms_nt = second_order_rms(problem, &model)?;
            effect = Effect::SecondOrder(SecondOrder { term_rms_nt });
            source = None;
            explanation = format!(
                "The aircraft's field at {} is large enough that its part across the Earth's field changes the total field the scalar reads (|F⊥|²/2|B|, {term_rms_nt:.3} nT RMS over the calibration): the first-order Tolles-Lawson terms leave it in the residual, and the term computed from the fitted permanent and induced field explains it.",
                problem.channel
            );
        }
        Extension::External { source: column } => {
            let gain = station_gain(problem, &model, column)?;
            effect = Effect::ExternalField(ExternalField { gain });
            source = Some(column.clone());
            explanation = format!(
                "Geomagnetic variation recorded by the base station '{column}' is in the calibration band: {} follows it with a gain of {gain:.2}. The model is fitted on the channel less the station's variation (gain 1), so the variation no longer biases the aircraft's coefficients; the compensated channel keeps it, for the survey's diurnal correction.",
                problem.channel
            );
        }
    }
    let found = Finding {
        effect,
        channel: problem.channel.to_string(),
        source,
        explanation,
        located: locate(before_windows, &result.windows),
        heldout_rms_before_nt: before_nt,
        heldout_rms_after_nt: result.rms_nt,
        not_applied: None,
        anomaly_gain: None,
    };
    Ok((found, model, result))
}

/// The coupling of `column` that `extension` adds to `model`, fitted: its
/// effect and the explanation in words.
fn coupling(problem: &Problem, model: &Model, extension: &Extension, column: &str) -> Result<(Effect, String)> {
    let direct = !matches!(extension, Extension::CouplingRate { .. });
    let rate = !matches!(extension, Extension::Coupling { .. });
    let coefficients = extension_coefficients(problem, model, 3 * (direct as usize + rate as usize))?;
    let (k, kdot) = coefficients.split_at(if direct { 3 } else { 0 });
    let mut parts = Vec::new();
    let axes = |v: &[f64]| [v[0], v[1], v[2]];
    if direct {
        parts.push(format!(
            "the field of whatever '{column}' measures reaches {}: a body-fixed field proportional to it ({:.3}, {:.3}, {:.3} nT per unit along x, y, z), which the scalar sees through the direction cosines",
            problem.channel, k[0], k[1], k[2]
        ));
    }
    if rate {
        parts.push(format!(
            "'{column}' acts through its rate of change too: a field proportional to d{column}/dt ({:.3}, {:.3}, {:.3} nT per unit/s along x, y, z), as from eddy currents a changing current induces in conductors near {}",
            kdot[0], kdot[1], kdot[2], problem.channel
        ));
    }
    let effect = Effect::AuxCoupling(AuxCoupling {
        k_nt_per_unit: direct.then(|| axes(k)),
        kdot_nt_s_per_unit: rate.then(|| axes(kdot)),
    });
    Ok((effect, capitalised(&parts.join("; ")) + "."))
}

/// `text` with its first letter in upper case.
pub(super) fn capitalised(text: &str) -> String {
    let mut letters = text.chars();
    letters
        .next()
        .map_or_else(String::new, |first| first.to_uppercase().chain(letters).collect())
}

/// The last `count` extra coefficients of a fit of `model` on all windows.
pub(super) fn extension_coefficients(problem: &Problem, model: &Model, count: usize) -> Result<Vec<f64>> {
    let spec = problem.spec(model);
    let fitted = prepare(problem, &spec)?.fit(problem.windows, problem.options, problem.stores)?;
    Ok(fitted.coefficients[fitted.coefficients.len() - count..].to_vec())
}

/// The gain with which the channel follows the base station `column`,
/// measured, not fitted: what `model` (fitted on the channel less the
/// station's variation) leaves of the channel, the station's variation
/// added back, regressed on that variation over the calibration windows,
/// each window's mean and trend taken out of both. 1 when the sensor
/// reads the station's variation as the station does.
fn station_gain(problem: &Problem, model: &Model, column: &str) -> Result<f64> {
    let spec = problem.spec(model);
    let fitted = prepare(problem, &spec)?.fit(problem.windows, problem.options, problem.stores)?;
    let prediction = fitted.predict(problem.log)?;
    let station = problem
        .log
        .channel(column)
        .map(|c| c.values.as_slice())
        .unwrap_or_default();
    let time = problem.log.time_s();
    let (mut cross, mut square) = (0.0, 0.0);
    for window in problem.windows {
        let rows: Vec<usize> = window
            .rows(time)
            .filter(|&r| prediction.scalar_nt[r].is_finite() && prediction.interference_nt[r].is_finite())
            .filter(|&r| station.get(r).is_some_and(|v| v.is_finite()))
            .collect();
        let left: Vec<f64> = rows
            .iter()
            .map(|&r| prediction.scalar_nt[r] - prediction.interference_nt[r])
            .collect();
        let variation: Vec<f64> = rows.iter().map(|&r| station[r]).collect();
        let times: Vec<f64> = rows.iter().map(|&r| time[r]).collect();
        let (left, variation) = (detrended(&times, &left), detrended(&times, &variation));
        cross += left.iter().zip(&variation).map(|(a, b)| a * b).sum::<f64>();
        square += variation.iter().map(|b| b * b).sum::<f64>();
    }
    Ok(match square > 0.0 {
        true => cross / square,
        false => f64::NAN,
    })
}

/// `values` less their least-squares line in `times`.
fn detrended(times: &[f64], values: &[f64]) -> Vec<f64> {
    let n = values.len().max(1) as f64;
    let (t_mean, v_mean) = (times.iter().sum::<f64>() / n, values.iter().sum::<f64>() / n);
    let spread: f64 = times.iter().map(|t| (t - t_mean).powi(2)).sum();
    let slope = match spread > 0.0 {
        true => {
            (times.iter().zip(values))
                .map(|(t, v)| (t - t_mean) * (v - v_mean))
                .sum::<f64>()
                / spread
        }
        false => 0.0,
    };
    (times.iter().zip(values))
        .map(|(t, v)| v - v_mean - slope * (t - t_mean))
        .collect()
}

/// RMS over the calibration windows of the second-order term of `model`
/// fitted on every window, nT.
pub(super) fn second_order_rms(problem: &Problem, model: &Model) -> Result<f64> {
    let spec = problem.spec(model);
    let fitted = prepare(problem, &spec)?.fit(problem.windows, problem.options, problem.stores)?;
    let term = crate::model::second_order_term(
        problem.log.vector_components(problem.sensor),
        &problem.terms,
        &fitted.coefficients,
    );
    let rows: Vec<f64> = (problem.windows.iter())
        .flat_map(|w| w.rows(problem.log.time_s()))
        .map(|row| term[row])
        .filter(|v| v.is_finite())
        .collect();
    let mean = rows.iter().sum::<f64>() / rows.len().max(1) as f64;
    Ok(root_mean_square(&rows.iter().map(|v| v - mean).collect::<Vec<_>>()))
}

/// The three windows whose held-out residual RMS dropped most.
pub(super) fn locate(before: &[WindowFit], after: &[WindowFit]) -> Vec<Located> {
    let mut gains: Vec<(f64, &WindowFit)> = before
        .iter()
        .zip(after)
        .map(|(b, a)| {
            (
                root_mean_square(&b.band_after_nt) - root_mean_square(&a.band_after_nt),
                b,
            )
        })
        .collect();
    gains.sort_by(|a, b| b.0.total_cmp(&a.0));
    gains
        .into_iter()
        .take(3)
        .filter(|(gain, _)| *gain > 0.0)
        .map(|(_, w)| Located {
            t_start: w.window.t_start,
            t_end: w.window.t_end,
            label: w.window.display_label(),
        })
        .collect()
}

/// A diagnosed effect the fit of a channel applied.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AppliedFinding {
    /// Scalar channel.
    pub channel: String,
    /// The effect (written by its CONTRACT §3 name).
    pub effect: EffectKind,
    /// The column that drives it, when one does.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub source: Option<String>,
    /// Held-out in-band RMS before the effect was modelled, nT.
    pub heldout_rms_before_nt: f64,
    /// Held-out in-band RMS with it, nT.
    pub heldout_rms_after_nt: f64,
}

impl AppliedFinding {
    /// "sensor_lag on mag_1_uc: held-out RMS 0.1080 → 0.0320 nT (−70 % against the model before it)".
    pub fn describe(&self) -> String {
        if self.effect == EffectKind::VectorCalibration {
            return format!(
                "vector_calibration of {}: magnitude against {}, held out, {:.1} → {:.1} nT",
                self.channel,
                self.source.as_deref().unwrap_or("the scalar"),
                self.heldout_rms_before_nt,
                self.heldout_rms_after_nt
            );
        }
        format!(
            "{} on {}{}: held-out RMS {:.4} → {:.4} nT ({:+.0} % against the model before it)",
            self.effect,
            self.channel,
            self.source.as_ref().map(|s| format!(" from {s}")).unwrap_or_default(),
            self.heldout_rms_before_nt,
            self.heldout_rms_after_nt,
            100.0 * (self.heldout_rms_after_nt / self.heldout_rms_before_nt - 1.0)
        )
    }
}
