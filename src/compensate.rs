//! Subtracting the predicted interference from every row.
//!
//! For each fitted channel the interference $A\beta$ is evaluated on every
//! row where the vector magnetometer is valid, with derivatives taken inside
//! contiguous runs. The compensated value is
//!
//! $$ m_c = m_{uc} - (A\beta - \delta) $$
//!
//! where the level offset δ depends on [`LevelConvention`]. The fit is made
//! on band-passed data, so it constrains the *variation* of the interference,
//! not its mean; the convention says which DC level the output keeps.
//! A row whose scalar or vector sample is missing gets an empty value and a
//! reason in the flags; no row is ever dropped.
//!
//! A model with an [`Augmentation`] (an accepted diagnosis) is evaluated on
//! its own terms: the fluxgate calibrated, the extra regressors added to
//! $A\beta$, and $m_{uc}$ read `lag_s` later when the sensor lags, so the
//! compensated value at a row is the field at that row's time and place.

use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::augment::{second_order_term, Augmentation};
use crate::error::Result;
use crate::fit::FittedTollesLawson;
use crate::flight_log::{FlightLog, VectorSensor};
use crate::segments::valid_runs;
use crate::tolles_lawson::DesignMatrix;

/// Which DC level the compensated channel keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LevelConvention {
    /// δ = 0: subtract the full modelled interference $A\beta$, as
    /// MagNav.jl does. The permanent terms then shift the level by a
    /// heading-independent amount that the band-passed fit only loosely fixes.
    #[default]
    Absolute,
    /// δ = mean of $A\beta$ over the calibration windows: the compensated
    /// channel keeps the uncompensated mean level over calibration.
    CalibrationMean,
}

/// The compensated values of one scalar channel.
#[derive(Debug, Clone, PartialEq)]
pub struct CompensatedChannel {
    /// Input scalar channel.
    pub channel: String,
    /// Compensated values, nT (`NaN` where flagged).
    pub values: Vec<f64>,
    /// Modelled interference $A\beta$, nT (`NaN` where the vector is missing).
    pub interference_nt: Vec<f64>,
    /// The level offset δ, nT.
    pub level_offset_nt: f64,
}

/// All compensated channels of a flight, with per-row flags.
#[derive(Debug, Clone, PartialEq)]
pub struct Compensation {
    /// One entry per fitted model, in model order.
    pub channels: Vec<CompensatedChannel>,
    /// Per row: empty when fine, else `;`-separated reasons.
    pub flags: Vec<String>,
}

/// Compensates every row of every channel that has a model, in parallel
/// over channels. A model whose scalar channel or vector sensor the flight
/// lacks (a model fitted on another flight) is an error.
pub fn compensate(log: &FlightLog, models: &[FittedTollesLawson], level: LevelConvention) -> Result<Compensation> {
    for model in models {
        let sensors = log.vector_sensors();
        let missing = match (
            log.channel(&model.channel),
            sensors.iter().any(|s| s.prefix == model.vector_sensor),
        ) {
            (None, _) => Some(("scalar magnetometer", model.channel.clone())),
            (_, false) => Some(("vector magnetometer", model.vector_sensor.clone())),
            _ => None,
        };
        if let Some((role, name)) = missing {
            return Err(crate::Error::MissingColumn {
                path: log.source().to_path_buf(),
                role,
                looked_for: format!("'{name}', which the model of '{}' uses", model.channel),
                hint: "Compensate with models fitted on this flight's own channels.".into(),
            });
        }
    }
    let designs = shared_design_matrices(log, models);
    let channels: Vec<CompensatedChannel> = models
        .par_iter()
        .map(|model| match &model.augmentation {
            None => {
                let scalar = &log
                    .channel(&model.channel)
                    .expect("compensate checked that every model's channel is in the flight log")
                    .values;
                Ok(compensate_channel(
                    log,
                    model,
                    scalar,
                    (&designs[&design_key(model)], &[]),
                    level,
                ))
            }
            Some(augmentation) => compensate_augmented(log, model, augmentation, level),
        })
        .collect::<Result<_>>()?;
    let flags = row_flags(log, models, &channels);
    Ok(Compensation { channels, flags })
}

type DesignKey = (String, String);

fn design_key(model: &FittedTollesLawson) -> DesignKey {
    (model.vector_sensor.clone(), format!("{:?}", model.terms))
}

/// One full-flight design matrix per (vector sensor, term set) of the
/// plain models.
fn shared_design_matrices(log: &FlightLog, models: &[FittedTollesLawson]) -> BTreeMap<DesignKey, DesignMatrix> {
    let mut designs = BTreeMap::new();
    for model in models.iter().filter(|m| m.augmentation.is_none()) {
        designs
            .entry(design_key(model))
            .or_insert_with(|| design_matrix(log, &sensor_named(log, &model.vector_sensor), model));
    }
    designs
}

/// The model's Tolles-Lawson terms over the whole flight.
fn design_matrix(log: &FlightLog, sensor: &VectorSensor, model: &FittedTollesLawson) -> DesignMatrix {
    let field = log.vector_components(sensor);
    let valid: Vec<bool> = (0..log.len()).map(|i| field.iter().all(|c| c[i].is_finite())).collect();
    let runs = valid_runs(log.time_s(), &valid, 0..log.len(), log.median_interval_s());
    model.terms.design_matrix(field, &runs)
}

/// An augmented model: its own flight (calibrated fluxgate, advanced
/// scalar), terms and extra regressors.
fn compensate_augmented(
    log: &FlightLog,
    model: &FittedTollesLawson,
    augmentation: &Augmentation,
    level: LevelConvention,
) -> Result<CompensatedChannel> {
    let sensor = sensor_named(log, &model.vector_sensor);
    let prepared = augmentation.prepare(log, &sensor, &model.channel, model.terms.bt_scale_nt)?;
    let design = design_matrix(&prepared.log, &sensor, model);
    let scalar = &prepared
        .log
        .channel(&model.channel)
        .expect("compensate checked that every model's channel is in the flight log")
        .values;
    // A base-station term is fitted (so geomagnetic variation in the
    // calibration band does not bias the aircraft's coefficients) but not
    // subtracted: it is the Earth's field, which the compensated channel
    // keeps; removing it is the survey's diurnal correction, a step of
    // its own.
    let aircraft_columns: Vec<Vec<f64>> = prepared
        .columns
        .iter()
        .zip(geomagnetic_columns(augmentation, prepared.columns.len()))
        .map(|(column, geomagnetic)| match geomagnetic {
            true => vec![0.0; column.len()],
            false => column.clone(),
        })
        .collect();
    let mut compensated = compensate_channel(log, model, scalar, (&design, &aircraft_columns), level);
    if augmentation.second_order {
        // The second-order term is interference like the rest; the level
        // convention's offset is taken again with it included.
        let term = second_order_term(
            prepared.log.vector_components(&sensor),
            &model.terms,
            &model.coefficients,
        );
        let mut interference = compensated.interference_nt;
        for (h, q) in interference.iter_mut().zip(&term) {
            *h += q;
        }
        compensated = level_compensated(log, model, scalar, interference, level);
    }
    Ok(compensated)
}

/// Per extra column of `augmentation`'s sources, in their order, whether
/// it is the base station's geomagnetic variation (an `ExternalField`
/// source, one column; couplings and their rates have three each).
fn geomagnetic_columns(augmentation: &Augmentation, count: usize) -> Vec<bool> {
    use crate::augment::SourceTerm;
    let mask: Vec<bool> = augmentation
        .sources
        .iter()
        .flat_map(|source| match source {
            SourceTerm::ExternalField { .. } => vec![true],
            SourceTerm::AuxCoupling { .. } | SourceTerm::AuxCouplingRate { .. } => vec![false; 3],
        })
        .collect();
    match mask.len() == count {
        true => mask,
        false => vec![false; count],
    }
}

fn sensor_named(log: &FlightLog, prefix: &str) -> VectorSensor {
    log.vector_sensors()
        .into_iter()
        .find(|s| s.prefix == prefix)
        .expect("compensate checked that every model's vector sensor is in the flight log")
}

/// `scalar` less the interference of the terms in `design` and the extra
/// columns, whose coefficients follow the terms'.
fn compensate_channel(
    log: &FlightLog,
    model: &FittedTollesLawson,
    scalar: &[f64],
    (design, extra): (&DesignMatrix, &[Vec<f64>]),
    level: LevelConvention,
) -> CompensatedChannel {
    let (terms, added) = model
        .coefficients
        .split_at(design.columns.len().min(model.coefficients.len()));
    let interference: Vec<f64> = (0..log.len())
        .map(|row| design.predict_row(row, terms) + extra.iter().zip(added).map(|(c, b)| c[row] * b).sum::<f64>())
        .collect();
    level_compensated(log, model, scalar, interference, level)
}

/// `scalar` less `interference`, levelled by `level`.
fn level_compensated(
    log: &FlightLog,
    model: &FittedTollesLawson,
    scalar: &[f64],
    interference: Vec<f64>,
    level: LevelConvention,
) -> CompensatedChannel {
    let level_offset_nt = match level {
        LevelConvention::Absolute => 0.0,
        LevelConvention::CalibrationMean => calibration_mean(log, model, &interference),
    };
    let values = scalar
        .iter()
        .zip(&interference)
        .map(|(m, h)| m - (h - level_offset_nt))
        .collect();
    CompensatedChannel {
        channel: model.channel.clone(),
        values,
        interference_nt: interference,
        level_offset_nt,
    }
}

/// Mean of the finite interference over the calibration windows' rows.
fn calibration_mean(log: &FlightLog, model: &FittedTollesLawson, interference: &[f64]) -> f64 {
    let (sum, count) = model
        .windows
        .iter()
        .flat_map(|w| w.window.rows(log.time_s()))
        .filter_map(|row| interference[row].is_finite().then_some(interference[row]))
        .fold((0.0, 0usize), |(s, n), h| (s + h, n + 1));
    if count == 0 {
        0.0
    } else {
        sum / count as f64
    }
}

/// Reasons a row's outputs are missing, `;`-separated, in model order:
/// a missing scalar or vector sample, a missing source column of an
/// augmented model, or a lag that reads the scalar beyond its record.
fn row_flags(log: &FlightLog, models: &[FittedTollesLawson], channels: &[CompensatedChannel]) -> Vec<String> {
    let mut flags = match log.row_flags().len() == log.len() {
        true => log.row_flags().to_vec(),
        false => vec![String::new(); log.len()],
    };
    let mut push = |row: usize, reason: String| {
        if !flags[row].split(';').any(|r| r == reason) {
            if !flags[row].is_empty() {
                flags[row].push(';');
            }
            flags[row].push_str(&reason);
        }
    };
    for (model, compensated) in models.iter().zip(channels) {
        let scalar = &log
            .channel(&model.channel)
            .expect("compensate checked that every model's channel is in the flight log")
            .values;
        let field = log.vector_components(&sensor_named(log, &model.vector_sensor));
        let sources: Vec<(&str, &[f64])> = model
            .augmentation
            .iter()
            .flat_map(|a| &a.sources)
            .filter_map(|s| Some((s.column(), log.channel(s.column())?.values.as_slice())))
            .collect();
        let derivatives = model.terms.eddy != crate::tolles_lawson::EddyTerms::None || model.terms.field_derivative;
        for row in 0..log.len() {
            let mut explained = false;
            if !scalar[row].is_finite() {
                push(row, format!("missing_scalar:{}", model.channel));
                explained = true;
            }
            if field.iter().any(|c| !c[row].is_finite()) {
                push(row, format!("missing_vector:{}", model.vector_sensor));
                explained = true;
            }
            for (column, values) in &sources {
                if !values[row].is_finite() {
                    push(row, format!("missing_source:{column}"));
                    explained = true;
                }
            }
            // Beside a missing vector sample the eddy terms' time
            // derivative is one-sided: the value stands, less accurately.
            let valid = |r: usize| field.iter().all(|c| c[r].is_finite());
            let beside_gap = (row > 0 && !valid(row - 1)) || (row + 1 < log.len() && !valid(row + 1));
            if !explained && derivatives && beside_gap && compensated.values[row].is_finite() {
                push(row, format!("beside_gap:{}", model.vector_sensor));
            }
            if !explained && !compensated.values[row].is_finite() {
                let lagged = model.augmentation.as_ref().is_some_and(|a| a.lag_s != 0.0);
                push(
                    row,
                    format!(
                        "{}:{}",
                        if lagged {
                            "lag_outside_record"
                        } else {
                            "model_undefined"
                        },
                        model.channel
                    ),
                );
            }
        }
    }
    flags
}
