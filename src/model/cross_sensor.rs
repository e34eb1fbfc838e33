//! Other sensors as interference sensors: what a fluxgate's magnitude or
//! another scalar sees that the channel's attitude terms cannot hold.
//!
//! Sensors a metre or two apart at survey height read nearly the same
//! geology. Each of two of them, the minuend m (a fluxgate's magnitude
//! $|F|$ or another scalar) and the reference r (one of the quietest
//! scalars), is compensated for its own attitude part: the Tolles-Lawson
//! terms of the vector magnetometer and the total field's second-order
//! term, fitted to it on the calibration windows ($H_m$, $H_r$). Their
//! difference
//!
//! $$ s = (m - H_m) - (r - H_r) - \bar s $$
//!
//! holds hardly any of the Earth's field and nothing that follows the
//! attitude, first or second order: what is left varies on its own, a
//! current no column records, switched, ramped or cycled, seen by every
//! sensor near it. (The difference's attitude part fitted as one, as the
//! first version did, leaves each sensor's second-order residual in s: on
//! clean simulated flights two cabin sensors' residuals then stood in for
//! each other's on 12 of 1,344 channels.) The channel's model couples s
//! through its direction cosines, $s\,(k \cdot u)$, as an auxiliary
//! column's field (three regressors). What the sensors' separation leaves
//! of a gradient is no scaling of the anomaly; the model's anomaly gain
//! counts the rest ([`CrossSignal::anomaly_rate`]).

use serde::{Deserialize, Serialize};

use crate::calibration::windows::CalibrationWindow;
use crate::error::Result;
use crate::ingest::flight_log::{Channel, ChannelRole, FlightLog, VectorSensor};
use crate::model::terms::TermSet;
use crate::numerics::stacked::StorePool;

use super::{design_matrix, fit, second_order_term, Extensions, FitOptions, ModelSpec};

/// One sensor's attitude part: the terms of the vector magnetometer and
/// the second-order term from the same coefficients, fitted to it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AttitudePart {
    /// The terms.
    pub terms: TermSet,
    /// Their coefficients, nT per unit term.
    pub coefficients: Vec<f64>,
}

impl AttitudePart {
    /// The part on every row of `log`, nT (`NaN` where the field is).
    fn predict(&self, log: &FlightLog, sensor: &VectorSensor) -> Vec<f64> {
        let design = design_matrix(log, sensor, &self.terms);
        let second = second_order_term(log.vector_components(sensor), &self.terms, &self.coefficients);
        (0..log.len())
            .map(|row| design.predict_row(row, &self.coefficients) + second[row])
            .collect()
    }

    /// How the part moves with a crustal anomaly δ along the field, per
    /// nT of it, on every row: its terms of degree one scale by $δ/|B|$
    /// ([`TermSet::field_degrees`]); the second-order term's share is a
    /// thousandth of that and left out.
    fn anomaly_rate(&self, log: &FlightLog, sensor: &VectorSensor) -> Vec<f64> {
        let design = design_matrix(log, sensor, &self.terms);
        let degree_one = self.terms.degree_one_part(&self.coefficients);
        let field = log.vector_components(sensor);
        (0..log.len())
            .map(|row| {
                let magnitude = field.iter().map(|c| c[row] * c[row]).sum::<f64>().sqrt();
                design.predict_row(row, &degree_one) / magnitude
            })
            .collect()
    }
}

/// The recipe of a cross-sensor signal, kept with the model so that any
/// flight with the same sensors rebuilds it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CrossSignal {
    /// What is read: a fluxgate's prefix (its magnitude) or a scalar
    /// channel.
    pub minuend: String,
    /// The reference scalar subtracted.
    pub reference: String,
    /// The vector magnetometer whose terms model each attitude part.
    pub vector_sensor: String,
    /// The minuend's attitude part.
    pub minuend_part: AttitudePart,
    /// The reference's attitude part.
    pub reference_part: AttitudePart,
    /// The signal's median over the calibration windows, nT.
    pub level: f64,
}

/// The prefix of a synthetic column holding a cross-sensor signal in the
/// log the diagnosis searches.
pub const CROSS_COLUMN_PREFIX: &str = "cross_sensor:";

impl CrossSignal {
    /// The sensors it reads, as DIAGNOSIS.json names them:
    /// `flux_c|mag_5_uc`.
    pub fn name(&self) -> String {
        format!("{}|{}", self.minuend, self.reference)
    }

    /// The signal on every row of `log` (`NaN` where an input is missing).
    pub fn values(&self, log: &FlightLog) -> Result<Vec<f64>> {
        let (minuend, reference) = (
            reading(log, &self.minuend).ok_or_else(|| missing(log, self))?,
            reading(log, &self.reference).ok_or_else(|| missing(log, self))?,
        );
        let sensor = log
            .vector_sensor(&self.vector_sensor)
            .ok_or_else(|| missing(log, self))?;
        let (m, r) = (
            self.minuend_part.predict(log, &sensor),
            self.reference_part.predict(log, &sensor),
        );
        Ok((0..log.len())
            .map(|k| (minuend[k] - m[k]) - (reference[k] - r[k]) - self.level)
            .collect())
    }

    /// How the signal moves with a crustal anomaly δ along the field, per
    /// nT of it, on every row: the anomaly adds δ to the minuend and the
    /// reference alike (a fluxgate's magnitude grows by δ too), which
    /// cancel, and moves each attitude part
    /// (its terms of degree one in the field): the reference's less the
    /// minuend's.
    pub fn anomaly_rate(&self, log: &FlightLog) -> Result<Vec<f64>> {
        let sensor = log
            .vector_sensor(&self.vector_sensor)
            .ok_or_else(|| missing(log, self))?;
        let (m, r) = (
            self.minuend_part.anomaly_rate(log, &sensor),
            self.reference_part.anomaly_rate(log, &sensor),
        );
        Ok(r.iter().zip(&m).map(|(r, m)| r - m).collect())
    }
}

fn missing(log: &FlightLog, signal: &CrossSignal) -> crate::error::Error {
    crate::error::Error::MissingColumn {
        path: log.source().to_path_buf(),
        role: "cross-sensor source",
        looked_for: format!(
            "'{}', '{}' and the fluxgate '{}', which the model's cross-sensor term reads",
            signal.minuend, signal.reference, signal.vector_sensor
        ),
        hint: "Compensate with a model made on a flight that records the same sensors.".into(),
    }
}

/// What `name` reads on every row: a fluxgate's magnitude for a fluxgate
/// prefix, else the scalar channel; `None` when `log` has neither.
pub fn reading(log: &FlightLog, name: &str) -> Option<Vec<f64>> {
    match log.vector_sensor(name) {
        Some(sensor) => {
            let field = log.vector_components(&sensor);
            Some(
                (0..log.len())
                    .map(|k| field.iter().map(|c| c[k] * c[k]).sum::<f64>().sqrt())
                    .collect(),
            )
        }
        None => Some(log.channel(name)?.values.clone()),
    }
}

/// The attitude part of `name`'s reading on `log`: `terms` of `sensor`
/// with the second-order term, fitted on `windows`; `None` when `log`
/// lacks it.
fn fit_attitude_part(
    log: &FlightLog,
    sensor: &VectorSensor,
    (name, windows): (&str, &[CalibrationWindow]),
    (terms, options, stores): (TermSet, &FitOptions, &StorePool),
) -> Result<Option<AttitudePart>> {
    let Some(values) = reading(log, name) else {
        return Ok(None);
    };
    // A lean flight: the fluxgate and the reading as its one scalar.
    let mut channels: Vec<Channel> = sensor.axes.iter().map(|&i| log.channels()[i].clone()).collect();
    channels.push(Channel {
        name: "cross_sensor_reading".into(),
        role: ChannelRole::ScalarMagnetometer,
        values,
    });
    let lean = log.with_channels(channels)?;
    let Some(lean_sensor) = lean.vector_sensor(&sensor.prefix) else {
        return Ok(None);
    };
    let extensions = Extensions {
        second_order: true,
        ..Extensions::default()
    };
    let spec = ModelSpec::new(terms, extensions);
    let model = fit(
        &lean,
        &lean_sensor,
        "cross_sensor_reading",
        windows,
        &spec,
        options,
        stores,
    )?;
    Ok(Some(AttitudePart {
        terms,
        coefficients: model.coefficients,
    }))
}

/// The attitude part of each of `names` (fluxgate prefixes or scalar
/// channels) on `log`, fitted once each (the parts of [`cross_signal`]):
/// a sensor that serves several signals is fitted for all of them.
pub fn fit_attitude_parts(
    log: &FlightLog,
    sensor: &VectorSensor,
    (names, windows): (&[String], &[CalibrationWindow]),
    settings: (TermSet, &FitOptions, &StorePool),
) -> Result<std::collections::BTreeMap<String, AttitudePart>> {
    use rayon::prelude::*;
    let fitted: Vec<Option<AttitudePart>> = names
        .par_iter()
        .map(|name| fit_attitude_part(log, sensor, (name, windows), settings))
        .collect::<Result<_>>()?;
    Ok((names.iter().cloned().zip(fitted))
        .filter_map(|(name, part)| Some((name, part?)))
        .collect())
}

/// The cross-sensor signal of `minuend` less `reference` on `log`, from
/// their attitude parts fitted on `windows` (its level their median
/// there).
pub fn cross_signal(
    log: &FlightLog,
    sensor: &VectorSensor,
    (minuend, reference): ((&str, &AttitudePart), (&str, &AttitudePart)),
    windows: &[CalibrationWindow],
) -> Result<CrossSignal> {
    let mut signal = CrossSignal {
        minuend: minuend.0.to_string(),
        reference: reference.0.to_string(),
        vector_sensor: sensor.prefix.clone(),
        minuend_part: minuend.1.clone(),
        reference_part: reference.1.clone(),
        level: 0.0,
    };
    let values = signal.values(log)?;
    let on_windows: Vec<f64> = (windows.iter())
        .flat_map(|w| w.rows(log.time_s()))
        .map(|row| values[row])
        .collect();
    signal.level = super::column_level(&on_windows);
    Ok(signal)
}
