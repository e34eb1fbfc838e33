//! Other sensors as interference sensors: what a fluxgate's magnitude or
//! another scalar sees that the channel's attitude terms cannot hold.
//!
//! Sensors a metre or two apart at survey height read nearly the same
//! geology, so the difference of two of them, $d = m - r$ (the minuend m
//! a fluxgate's magnitude $|F|$ or another scalar, the reference r the
//! quietest scalar), holds the aircraft's interference at both and hardly
//! any of the Earth's field. Its attitude part, the Tolles-Lawson terms
//! of the vector magnetometer fitted to d on the calibration windows
//! ($A\beta$), is taken out:
//!
//! $$ s = m - r - A\beta - \bar s $$
//!
//! What is left varies independently of the attitude: a current no
//! column records, switched, ramped or cycled, seen by every sensor near
//! it. The channel's model couples s through its direction cosines,
//! $s\,(k \cdot u)$, as an auxiliary column's field (three regressors).
//! What the sensors' separation leaves of the geology in s, the model's
//! anomaly gain counts ([`crate::model::AnomalyGain`]): s's slope
//! against the total field.

use serde::{Deserialize, Serialize};

use crate::calibration::windows::CalibrationWindow;
use crate::error::Result;
use crate::ingest::flight_log::{Channel, ChannelRole, FlightLog, VectorSensor};
use crate::model::terms::TermSet;
use crate::numerics::stacked::StorePool;

use super::{design_matrix, fit, FitOptions, ModelSpec};

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
    /// The vector magnetometer whose terms model the attitude part.
    pub vector_sensor: String,
    /// Those terms.
    pub terms: TermSet,
    /// Their coefficients, nT per unit term.
    pub coefficients: Vec<f64>,
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
        let difference = difference(log, &self.minuend, &self.reference).ok_or_else(|| missing(log, self))?;
        let sensor = log
            .vector_sensor(&self.vector_sensor)
            .ok_or_else(|| missing(log, self))?;
        let design = design_matrix(log, &sensor, &self.terms);
        Ok((difference.iter().enumerate())
            .map(|(row, d)| d - design.predict_row(row, &self.coefficients) - self.level)
            .collect())
    }
}

impl CrossSignal {
    /// How the signal moves with a crustal anomaly δ along the field, per
    /// nT of it, on every row: the anomaly adds δ to the minuend and the
    /// reference alike (a fluxgate's magnitude grows by δ too), which
    /// cancel, and scales the attitude part's terms of degree one in the
    /// field by $δ/|B|$: $\partial s / \partial δ = -H_1/|B|$
    /// ([`TermSet::field_degrees`]). What the sensors' separation leaves
    /// of a gradient is no scaling of the anomaly; the survey's own checks
    /// judge it.
    pub fn anomaly_rate(&self, log: &FlightLog) -> Result<Vec<f64>> {
        let sensor = log
            .vector_sensor(&self.vector_sensor)
            .ok_or_else(|| missing(log, self))?;
        let design = design_matrix(log, &sensor, &self.terms);
        let degree_one: Vec<f64> = (self.terms.field_degrees().iter().zip(&self.coefficients))
            .map(|(&degree, &b)| if degree == 1 { b } else { 0.0 })
            .collect();
        let field = log.vector_components(&sensor);
        Ok((0..log.len())
            .map(|row| {
                let magnitude = field.iter().map(|c| c[row] * c[row]).sum::<f64>().sqrt();
                -design.predict_row(row, &degree_one) / magnitude
            })
            .collect())
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

/// $m - r$ on every row: `minuend` a fluxgate's prefix (its magnitude) or
/// a scalar channel, `reference` a scalar channel; `None` when `log`
/// lacks either.
pub fn difference(log: &FlightLog, minuend: &str, reference: &str) -> Option<Vec<f64>> {
    let reference = &log.channel(reference)?.values;
    let minuend: Vec<f64> = match log.vector_sensor(minuend) {
        Some(sensor) => {
            let field = log.vector_components(&sensor);
            (0..log.len())
                .map(|k| field.iter().map(|c| c[k] * c[k]).sum::<f64>().sqrt())
                .collect()
        }
        None => log.channel(minuend)?.values.clone(),
    };
    Some(minuend.iter().zip(reference).map(|(m, r)| m - r).collect())
}

/// The cross-sensor signal of `minuend` less `reference` on `log`, its
/// attitude part fitted with `terms` of `sensor` on `windows`.
pub fn fit_cross_signal(
    log: &FlightLog,
    sensor: &VectorSensor,
    (minuend, reference): (&str, &str),
    windows: &[CalibrationWindow],
    (terms, options, stores): (TermSet, &FitOptions, &StorePool),
) -> Result<Option<CrossSignal>> {
    let Some(values) = difference(log, minuend, reference) else {
        return Ok(None);
    };
    // A lean flight: the fluxgate and the difference as its one scalar.
    let mut channels: Vec<Channel> = sensor.axes.iter().map(|&i| log.channels()[i].clone()).collect();
    channels.push(Channel {
        name: "cross_sensor_difference".into(),
        role: ChannelRole::ScalarMagnetometer,
        values,
    });
    let lean = log.with_channels(channels)?;
    let Some(lean_sensor) = lean.vector_sensor(&sensor.prefix) else {
        return Ok(None);
    };
    let spec = ModelSpec::plain(terms);
    let model = fit(
        &lean,
        &lean_sensor,
        "cross_sensor_difference",
        windows,
        &spec,
        options,
        stores,
    )?;
    let mut signal = CrossSignal {
        minuend: minuend.to_string(),
        reference: reference.to_string(),
        vector_sensor: sensor.prefix.clone(),
        terms,
        coefficients: model.coefficients,
        level: 0.0,
    };
    let values = signal.values(log)?;
    let on_windows: Vec<f64> = (windows.iter())
        .flat_map(|w| w.rows(log.time_s()))
        .map(|row| values[row])
        .collect();
    signal.level = super::column_level(&on_windows);
    Ok(Some(signal))
}
