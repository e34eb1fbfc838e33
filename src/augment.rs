//! The Tolles-Lawson model extended with physics its 18 terms leave out:
//! what `diagnose` finds, and what the fit, compensation and transfer
//! check use once a diagnosis is accepted.
//!
//! An [`Augmentation`] of one scalar channel is
//! - a fluxgate calibration the channel is fitted on ($\hat b = C(m - o)$);
//! - a sensor lag: the scalar reads the field `lag_s` late, so its record
//!   is read `lag_s` earlier (linear interpolation) before the fit and
//!   before compensation;
//! - an eddy time constant τ: the nine eddy terms $u_i \dot B_j$ give way
//!   to $u_i\,L_\tau[\dot B_j]$, with $L_\tau$ the first-order lag
//!   $\tau \dot y + y = x$;
//! - the ten cubic direction-cosine terms $u_i u_j u_k$ (the second-order
//!   part of a large aircraft field);
//! - source terms, in the order they were accepted: an auxiliary column c
//!   driving a body-fixed field, seen as $(c - \bar c)(k_x u_x + k_y u_y +
//!   k_z u_z)$, or a base-station column regressed on, $g\,(c - \bar c)$.
//!   The level $\bar c$ is the column's median on the flight the model was
//!   fitted on: the steady part of a body-fixed field is the permanent
//!   terms' already.

use std::borrow::Cow;
use std::collections::BTreeMap;

use rayon::prelude::*;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::fit::{fit_channel_with, FitOptions, FittedTollesLawson, Regressors, WindowFit};
use crate::flight_log::{FlightLog, VectorSensor};
use crate::tolles_lawson::EddyTerms;
use crate::vector_calibration::VectorCalibration;
use crate::windows::CalibrationWindow;

/// A recorded column whose variation enters the model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum SourceTerm {
    /// A body-fixed field proportional to the column: three regressors
    /// $(c - \bar c) u_i$.
    AuxCoupling {
        /// The column.
        column: String,
        /// $\bar c$, in the column's unit.
        level: f64,
    },
    /// Geomagnetic variation recorded by a base station: one regressor
    /// $c - \bar c$.
    ExternalField {
        /// The column.
        column: String,
        /// $\bar c$, nT.
        level: f64,
    },
}

impl SourceTerm {
    /// The column the term reads.
    pub fn column(&self) -> &str {
        match self {
            SourceTerm::AuxCoupling { column, .. } | SourceTerm::ExternalField { column, .. } => column,
        }
    }
}

/// Physics added to one channel's Tolles-Lawson model. The default is
/// plain Tolles-Lawson.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Augmentation {
    /// Fluxgate calibration applied before the terms are built.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vector_calibration: Option<VectorCalibration>,
    /// The scalar reads the field this late, s (negative: early).
    pub lag_s: f64,
    /// Eddy time constant, s; 0 keeps the instantaneous eddy terms.
    pub eddy_tau_s: f64,
    /// The ten cubic direction-cosine terms.
    pub second_order: bool,
    /// Source terms, in the order they were accepted.
    pub sources: Vec<SourceTerm>,
}

/// What an augmented model is fitted on and predicts from.
#[derive(Debug, Clone)]
pub struct Prepared<'a> {
    /// The flight with the fluxgate calibrated and the scalar advanced by
    /// the lag (borrowed when neither applies).
    pub log: Cow<'a, FlightLog>,
    /// Names of the extra regressors.
    pub names: Vec<String>,
    /// Extra regressor columns, one value per row.
    pub columns: Vec<Vec<f64>>,
}

impl Prepared<'_> {
    /// The extra regressors as the fit takes them.
    pub fn regressors(&self) -> Regressors<'_> {
        Regressors {
            names: self.names.clone(),
            columns: self.columns.iter().map(Vec::as_slice).collect(),
        }
    }
}

impl Augmentation {
    /// Plain Tolles-Lawson: nothing added.
    pub fn is_plain(&self) -> bool {
        self == &Augmentation::default()
    }

    /// Fit settings: the nine instantaneous eddy terms give way to their
    /// lagged versions when the model has an eddy time constant.
    pub fn fit_options(&self, options: &FitOptions) -> FitOptions {
        let mut options = options.clone();
        if self.eddy_tau_s > 0.0 {
            options.terms.eddy = EddyTerms::None;
        }
        options
    }

    /// The flight and extra regressors of `channel`: calibrates the
    /// fluxgate, advances the scalar, builds the columns. A source column
    /// the flight lacks is an error.
    pub fn prepare<'a>(
        &self,
        log: &'a FlightLog,
        sensor: &VectorSensor,
        channel: &str,
        bt_scale_nt: f64,
    ) -> Result<Prepared<'a>> {
        let calibrated = match &self.vector_calibration {
            Some(calibration) => Cow::Owned(calibration.apply(log, sensor)?),
            None => Cow::Borrowed(log),
        };
        let direction = field_directions(&calibrated, sensor);
        self.prepare_calibrated(calibrated, sensor, channel, &direction, bt_scale_nt)
    }

    /// [`Self::prepare`] on a flight whose fluxgate is already what the
    /// model uses, with its field directions.
    pub(crate) fn prepare_calibrated<'a>(
        &self,
        log: Cow<'a, FlightLog>,
        sensor: &VectorSensor,
        channel: &str,
        direction: &[Vec<f64>; 3],
        bt_scale_nt: f64,
    ) -> Result<Prepared<'a>> {
        let (mut names, mut columns) = (Vec::new(), Vec::new());
        if self.second_order {
            for (i, j, k) in cubic_monomials() {
                let axes = ["x", "y", "z"];
                names.push(format!("second_order_u{}{}{}", axes[i], axes[j], axes[k]));
                columns.push((0..log.len()).map(|r| direction[i][r] * direction[j][r] * direction[k][r]).collect());
            }
        }
        // Lagged eddy terms next: the newest source term stays last.
        if self.eddy_tau_s > 0.0 {
            let dt = log.median_interval_s();
            let field = log.vector_components(sensor);
            let lagged: Vec<Vec<f64>> = field.iter().map(|b| lagged_rate(b, dt, self.eddy_tau_s)).collect();
            for (i, axis_i) in ["x", "y", "z"].iter().enumerate() {
                for (j, axis_j) in ["x", "y", "z"].iter().enumerate() {
                    names.push(format!("eddy_lagged_{axis_i}{axis_j}"));
                    columns.push(direction[i].iter().zip(&lagged[j]).map(|(u, d)| u * d / bt_scale_nt).collect());
                }
            }
        }
        for source in &self.sources {
            let Some(values) = log.channel(source.column()).map(|c| &c.values) else {
                return Err(Error::MissingColumn {
                    path: log.source().to_path_buf(),
                    role: "model source column",
                    looked_for: format!("'{}', which the model of '{channel}' uses", source.column()),
                    hint: "Compensate with a diagnosis made on a flight that records the same columns.".into(),
                });
            };
            match source {
                SourceTerm::AuxCoupling { column, level } => {
                    for (axis, u) in ["x", "y", "z"].iter().zip(direction) {
                        names.push(format!("{column}_{axis}"));
                        columns.push(values.iter().zip(u).map(|(c, u)| (c - level) * u).collect());
                    }
                }
                SourceTerm::ExternalField { column, level } => {
                    names.push(column.clone());
                    columns.push(values.iter().map(|c| c - level).collect());
                }
            }
        }
        let log = match self.lag_s {
            0.0 => log,
            lag_s => {
                let Some(scalar) = log.channel(channel) else {
                    return Err(Error::MissingColumn {
                        path: log.source().to_path_buf(),
                        role: "scalar magnetometer",
                        looked_for: format!("'{channel}'"),
                        hint: "Name a scalar channel the flight records.".into(),
                    });
                };
                let values = advanced(&scalar.values, log.time_s(), lag_s);
                Cow::Owned(log.with_values(channel, values)?)
            }
        };
        Ok(Prepared { log, names, columns })
    }

    /// Fits `channel` with this augmentation on `windows`.
    pub fn fit(
        &self,
        log: &FlightLog,
        sensor: &VectorSensor,
        channel: &str,
        windows: &[CalibrationWindow],
        options: &FitOptions,
    ) -> Result<FittedTollesLawson> {
        let prepared = self.prepare(log, sensor, channel, options.terms.bt_scale_nt)?;
        let mut fitted = fit_channel_with(
            &prepared.log,
            sensor,
            channel,
            windows,
            &self.fit_options(options),
            &prepared.regressors(),
        )?;
        fitted.augmentation = (!self.is_plain()).then(|| self.clone());
        Ok(fitted)
    }

    /// One line for people: what the model adds.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if let Some(c) = &self.vector_calibration {
            parts.push(format!("{} calibrated", c.sensor));
        }
        if self.lag_s != 0.0 {
            parts.push(format!("sensor lag {:.3} s", self.lag_s));
        }
        if self.eddy_tau_s > 0.0 {
            parts.push(format!("eddy τ {:.2} s", self.eddy_tau_s));
        }
        if self.second_order {
            parts.push("second-order terms".into());
        }
        for source in &self.sources {
            parts.push(match source {
                SourceTerm::AuxCoupling { column, .. } => format!("coupling to {column}"),
                SourceTerm::ExternalField { column, .. } => format!("base station {column}"),
            });
        }
        match parts.is_empty() {
            true => "plain Tolles-Lawson".into(),
            false => parts.join(", "),
        }
    }
}

/// The band-passed residual of a fitted model (augmented or not) on
/// `windows`, which it need not have been fitted on.
pub fn held_out(
    model: &FittedTollesLawson,
    log: &FlightLog,
    sensor: &VectorSensor,
    windows: &[CalibrationWindow],
    options: &FitOptions,
) -> Result<Vec<WindowFit>> {
    match &model.augmentation {
        None => model.held_out(log, sensor, windows, options),
        Some(augmentation) => {
            let prepared = augmentation.prepare(log, sensor, &model.channel, options.terms.bt_scale_nt)?;
            model.held_out_with(
                &prepared.log,
                sensor,
                windows,
                &augmentation.fit_options(options),
                &prepared.regressors(),
            )
        }
    }
}

/// Fits `channel` with `augmentation`, or plain Tolles-Lawson without one.
pub fn fit(
    log: &FlightLog,
    sensor: &VectorSensor,
    channel: &str,
    windows: &[CalibrationWindow],
    options: &FitOptions,
    augmentation: Option<&Augmentation>,
) -> Result<FittedTollesLawson> {
    match augmentation {
        Some(augmentation) => augmentation.fit(log, sensor, channel, windows, options),
        None => crate::fit::fit_channel(log, sensor, channel, windows, options),
    }
}

/// Fits every channel in `channels`, each with its model in `plan` (plain
/// Tolles-Lawson when it has none), in parallel over channels.
pub fn fit_channels(
    log: &FlightLog,
    sensor: &VectorSensor,
    channels: &[String],
    windows: &[CalibrationWindow],
    options: &FitOptions,
    plan: &BTreeMap<String, Augmentation>,
) -> Result<Vec<FittedTollesLawson>> {
    if plan.is_empty() || windows.is_empty() {
        return crate::fit::fit_channels(log, sensor, channels, windows, options);
    }
    channels
        .par_iter()
        .map(|channel| {
            let augmentation = plan.get(channel).filter(|a| !a.is_plain());
            fit(log, sensor, channel, windows, options, augmentation)
        })
        .collect()
}

/// Unit field direction per row.
pub fn field_directions(log: &FlightLog, sensor: &VectorSensor) -> [Vec<f64>; 3] {
    let field = log.vector_components(sensor);
    [0, 1, 2].map(|i| {
        (0..log.len())
            .map(|k| field[i][k] / (field[0][k].powi(2) + field[1][k].powi(2) + field[2][k].powi(2)).sqrt())
            .collect()
    })
}

/// The median of a column's finite values (0 when it has none).
pub fn column_level(values: &[f64]) -> f64 {
    let mut finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return 0.0;
    }
    let middle = finite.len() / 2;
    *finite.select_nth_unstable_by(middle, f64::total_cmp).1
}

/// The ten cubic monomials $u_i u_j u_k$, $i \le j \le k$.
fn cubic_monomials() -> impl Iterator<Item = (usize, usize, usize)> {
    (0..3).flat_map(|i| (i..3).flat_map(move |j| (j..3).map(move |k| (i, j, k))))
}

/// The scalar read `lag_s` earlier: value at t + lag by linear
/// interpolation; `NaN` where t + lag is outside the record.
pub fn advanced(values: &[f64], time_s: &[f64], lag_s: f64) -> Vec<f64> {
    time_s
        .iter()
        .map(|&t| {
            let at = t + lag_s;
            let upper = time_s.partition_point(|&x| x < at);
            if upper == 0 || upper >= time_s.len() {
                return f64::NAN;
            }
            let (t0, t1) = (time_s[upper - 1], time_s[upper]);
            let weight = (at - t0) / (t1 - t0);
            values[upper - 1] + weight * (values[upper] - values[upper - 1])
        })
        .collect()
}

/// Per-sample central difference of `values` passed through a first-order
/// lag of `tau_s`, $y_k = \alpha y_{k-1} + (1-\alpha) x_k$ with
/// $\alpha = e^{-\Delta t/\tau}$, restarted after every missing sample.
fn lagged_rate(values: &[f64], dt: f64, tau_s: f64) -> Vec<f64> {
    let rate = crate::tolles_lawson::central_difference(values);
    let alpha = (-dt / tau_s).exp();
    let mut state = f64::NAN;
    rate.iter()
        .map(|x| {
            state = if !x.is_finite() {
                f64::NAN
            } else if state.is_finite() {
                alpha * state + (1.0 - alpha) * x
            } else {
                *x
            };
            state
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn advancing_by_a_fraction_of_a_sample_interpolates() {
        let time: Vec<f64> = (0..5).map(|k| k as f64 * 0.1).collect();
        let values: Vec<f64> = time.iter().map(|t| 10.0 * t).collect();
        let read = advanced(&values, &time, 0.025);
        // 10 × (t + 0.025) inside; the last sample has nothing after it.
        for k in 0..4 {
            assert!((read[k] - (10.0 * time[k] + 0.25)).abs() < 1e-12, "{k}: {}", read[k]);
        }
        assert!(read[4].is_nan());
    }

    #[test]
    fn lagged_rate_settles_to_a_constant_rate() {
        // A ramp of 2 per sample: its rate is 2 everywhere, and the lag
        // passes a constant unchanged.
        let ramp: Vec<f64> = (0..50).map(|k| 2.0 * k as f64).collect();
        assert!(lagged_rate(&ramp, 0.1, 0.5).iter().all(|r| (r - 2.0).abs() < 1e-12));
        // After a step in rate to 1 the gap to it closes by e^{−Δt/τ} a sample.
        let bend: Vec<f64> = (0..50).map(|k| if k < 10 { 0.0 } else { (k - 10) as f64 }).collect();
        let lagged = lagged_rate(&bend, 0.1, 0.5);
        let alpha = (-0.2f64).exp();
        for k in 11..30 {
            let ratio = (1.0 - lagged[k + 1]) / (1.0 - lagged[k]);
            assert!((ratio - alpha).abs() < 1e-9, "{k}: {ratio}");
        }
        assert!(lagged[9].abs() < 1e-12 && lagged[20] > 0.8 && lagged[20] < 0.9, "{}", lagged[20]);
    }

    #[test]
    fn column_level_is_the_median_of_finite_values() {
        assert_eq!(column_level(&[5.0, f64::NAN, 1.0, 3.0]), 3.0);
        assert_eq!(column_level(&[f64::NAN]), 0.0);
    }
}
