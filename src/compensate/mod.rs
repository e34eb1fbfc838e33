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
//! A model with extensions (an accepted diagnosis) is evaluated on its own
//! terms: the fluxgate calibrated, the extension columns added to
//! $A\beta$, and $m_{uc}$ read `lag_s` later when the sensor lags, so the
//! compensated value at a row is the field at that row's time and place.
//!
//! What is made from the compensated channels is here too: the gradients
//! between two compensated sensors ([`gradient`]) and the DC-shifted and
//! IGRF-reduced columns ([`reduce`]).

pub mod gradient;
pub mod reduce;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::ingest::flags::{FlagKind, RowFlags};
use crate::ingest::flight_log::FlightLog;
use crate::messages::Warning;
use crate::model::{FittedModel, SharedDesign};

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
    /// Mean of the interference over the calibration windows, nT (δ under
    /// [`LevelConvention::CalibrationMean`], whichever convention is
    /// used): saved with the model for flights it is applied to.
    pub calibration_interference_nt: f64,
    /// One sigma of each compensated value relative to the channel's
    /// level over the calibration windows, nT (the `mag_<n>_c_sigma`
    /// column): $\sqrt{\sigma_\beta(i)^2 + \sigma_n^2}$, with
    /// $\sigma_\beta(i)$ the spread of the modelled interference at row i
    /// under the blocked jackknife of the coefficients
    /// ([`crate::model::FittedModel::prediction_sigma`]) and $\sigma_n$ the
    /// compensated channel's fourth-difference noise. The level itself is
    /// not in it: the band-passed fit does not pin it (its sigma is the
    /// quality JSON's `level_sigma_nt`, a warning when large), and a
    /// sensor's constant offset is seen by no calibration. `None` without
    /// a jackknife (fewer than three windows, or another solver).
    pub sigma_nt: Option<Vec<f64>>,
}

/// A compensated gradient ([`gradient`]) on every row, nT/m (`NaN` where either sensor
/// or the fluxgate is missing).
#[derive(Debug, Clone, PartialEq)]
pub struct CompensatedGradient {
    /// The output column, `grad_<a>_<b>_c`.
    pub column: String,
    /// Values, nT/m.
    pub values: Vec<f64>,
}

/// One compensated channel reduced for levelling and gridding
/// ([`reduce`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ReducedChannel {
    /// The output column, `mag_<n>_dc` or `mag_<n>_igrf`.
    pub column: String,
    /// Values, nT (`NaN` where the row has none).
    pub values: Vec<f64>,
}

/// All compensated channels of a flight, with per-row flags.
#[derive(Debug, Clone, PartialEq)]
pub struct Compensation {
    /// One entry per fitted model, in model order.
    pub channels: Vec<CompensatedChannel>,
    /// Per row: why its outputs are missing or suspect (none when fine).
    pub flags: Vec<RowFlags>,
    /// The Earth's field from each fluxgate, vector-compensated
    /// ([`crate::vector`]); empty when vector compensation is off or
    /// impossible.
    pub vectors: Vec<crate::vector::CompensatedVector>,
    /// Each compensated gradient, nT/m ([`gradient`]); empty when
    /// none is asked for.
    pub gradients: Vec<CompensatedGradient>,
    /// The compensated channels reduced for levelling and gridding
    /// (`mag_<n>_dc`, `mag_<n>_igrf`; [`reduce`]); empty unless
    /// asked for.
    pub reduced: Vec<ReducedChannel>,
}

impl Compensation {
    /// Every column of values magcomp adds, in the order of the added
    /// column names: each compensated channel (and its sigma, when it has
    /// one), then each fluxgate's body
    /// x, y, z and north, east, down, then each gradient, then each
    /// reduced channel (the flags column follows them).
    pub fn value_columns(&self) -> Vec<&[f64]> {
        let channels = self
            .channels
            .iter()
            .flat_map(|c| std::iter::once(c.values.as_slice()).chain(c.sigma_nt.as_deref()));
        let vectors = self
            .vectors
            .iter()
            .flat_map(|v| v.body_nt.iter().chain(&v.ned_nt).map(Vec::as_slice));
        let gradients = self.gradients.iter().map(|g| g.values.as_slice());
        let reduced = self.reduced.iter().map(|r| r.values.as_slice());
        channels.chain(vectors).chain(gradients).chain(reduced).collect()
    }

    /// Rounds every added column to `decimals` places of nT (gradients,
    /// nT/m, to three more): the resolution the outputs are written at,
    /// in every format alike. A sigma is rounded up, so that no stated
    /// uncertainty comes out smaller than it is (nor zero). `NaN` stays
    /// `NaN`.
    pub fn round_to(&mut self, decimals: u32) {
        let round_with = |values: &mut [f64], places: u32, to_integer: fn(f64) -> f64| {
            let scale = 10f64.powi(places as i32);
            for v in values.iter_mut().filter(|v| v.is_finite()) {
                let scaled = *v * scale;
                // Beyond 2^52 every double is already an integer.
                if scaled.abs() < 4.5e15 {
                    *v = to_integer(scaled) / scale + 0.0;
                }
            }
        };
        let round = |values: &mut [f64], places: u32| round_with(values, places, f64::round);
        for channel in &mut self.channels {
            round(&mut channel.values, decimals);
            if let Some(sigma) = channel.sigma_nt.as_mut() {
                // A millionth of a step below: a sigma already on the grid
                // (2.007 is 2007.0000000000002 thousandths) stays on it.
                round_with(sigma, decimals, |x| (x - 1e-6).ceil());
            }
        }
        for vector in &mut self.vectors {
            for component in vector.body_nt.iter_mut().chain(vector.ned_nt.iter_mut()) {
                round(component, decimals);
            }
        }
        for gradient in &mut self.gradients {
            round(&mut gradient.values, decimals + 3);
        }
        for reduced in &mut self.reduced {
            round(&mut reduced.values, decimals);
        }
    }

    /// Adds `vector` and flags the rows where it is missing: without a
    /// fluxgate reading (both frames), without an attitude (north-east-down);
    /// and those where a component lies beyond what a fluxgate reads
    /// (`output_out_of_range:<sensor>`).
    pub fn add_vector(&mut self, vector: crate::vector::CompensatedVector) {
        let most = crate::ingest::screen::MOST_VECTOR_COMPONENT_NT;
        for (row, flags) in self.flags.iter_mut().enumerate() {
            if vector.body_nt[0][row].is_nan() {
                flags.raise(FlagKind::MissingVector, &vector.sensor);
            } else if vector.ned_nt[0][row].is_nan() {
                flags.raise(FlagKind::MissingAttitude, &vector.sensor);
            }
            let components = vector.body_nt.iter().chain(&vector.ned_nt);
            if components.map(|c| c[row]).any(|v| v.is_finite() && v.abs() > most) {
                flags.raise(FlagKind::OutputOutOfRange, &vector.sensor);
            }
        }
        self.vectors.push(vector);
    }

    /// One warning per scalar channel or fluxgate with compensated values
    /// beyond what the instrument reads (rows flagged
    /// `output_out_of_range`): how many, the first row's time and value.
    pub fn out_of_range_warnings(&self, time_s: &[f64]) -> Vec<Warning> {
        let subjects =
            (self.channels.iter().map(|c| c.channel.as_str())).chain(self.vectors.iter().map(|v| v.sensor.as_str()));
        subjects
            .filter_map(|subject| {
                let rows =
                    (0..self.flags.len()).filter(|&row| self.flags[row].has(FlagKind::OutputOutOfRange, subject));
                let (first, count) = rows.fold((None, 0), |(first, count), row| (first.or(Some(row)), count + 1));
                Some(Warning::OutputOutOfRange {
                    subject: subject.to_string(),
                    rows: count,
                    first: time_s[first?],
                })
            })
            .collect()
    }
}

/// Compensates every row of every channel that has a model, in parallel
/// over channels: $m_c = m_{uc} - (A\beta - \delta)$ with $A\beta$ the
/// model's prediction ([`FittedModel::predict`]). A model whose scalar
/// channel or vector sensor the flight lacks (a model fitted on another
/// flight) is an error.
pub fn compensate(log: &FlightLog, models: &[FittedModel], level: LevelConvention) -> Result<Compensation> {
    compensate_with(log, models, level, &SharedDesign::of_models(log, models))
}

/// [`compensate`], taking the models' terms from `shared` where it holds
/// them.
pub fn compensate_with(
    log: &FlightLog,
    models: &[FittedModel],
    level: LevelConvention,
    shared: &[SharedDesign],
) -> Result<Compensation> {
    let channels: Vec<CompensatedChannel> = models
        .par_iter()
        .map(|model| compensate_channel(log, model, level, shared))
        .collect::<Result<_>>()?;
    let flags = row_flags(log, models, &channels);
    Ok(Compensation {
        channels,
        flags,
        vectors: Vec::new(),
        gradients: Vec::new(),
        reduced: Vec::new(),
    })
}

/// One channel of [`compensate_with`], without the rows' flags: what a
/// stage that reads only the values (the direct gradient) needs.
pub(crate) fn compensate_channel(
    log: &FlightLog,
    model: &FittedModel,
    level: LevelConvention,
    shared: &[SharedDesign],
) -> Result<CompensatedChannel> {
    let prediction = model.predict_with(log, shared)?;
    Ok(level_compensated(
        log,
        model,
        &prediction.scalar_nt,
        prediction.interference_nt,
        level,
    ))
}

/// `scalar` less `interference`, levelled by `level`.
fn level_compensated(
    log: &FlightLog,
    model: &FittedModel,
    scalar: &[f64],
    interference: Vec<f64>,
    level: LevelConvention,
) -> CompensatedChannel {
    // A model applied to another flight keeps the level of its own
    // calibration, which this flight's rows cannot give.
    let calibration_interference_nt = match &model.calibration_level {
        Some(saved) => saved.interference_nt,
        None => calibration_mean(log, model, &interference),
    };
    let level_offset_nt = match level {
        LevelConvention::Absolute => 0.0,
        LevelConvention::CalibrationMean => calibration_interference_nt,
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
        calibration_interference_nt,
        sigma_nt: None,
    }
}

impl CompensatedChannel {
    /// Sets [`CompensatedChannel::sigma_nt`] from the model's `prediction`
    /// sigma and the compensated channel's `noise_nt`; `NaN` where the
    /// value is missing.
    pub fn set_sigma(&mut self, prediction: &crate::model::PredictionSigma, noise_nt: f64) {
        let sigma = self
            .values
            .iter()
            .zip(&prediction.relative_nt)
            .map(|(value, sigma)| match value.is_finite() {
                true => sigma.hypot(noise_nt),
                false => f64::NAN,
            })
            .collect();
        self.sigma_nt = Some(sigma);
    }
}

/// Mean of the finite interference over the calibration windows' rows.
fn calibration_mean(log: &FlightLog, model: &FittedModel, interference: &[f64]) -> f64 {
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

/// Reasons a row's outputs are missing, after those raised while reading
/// and screening, in model order: a missing scalar or vector sample, a
/// missing source column of an augmented model, or a lag that reads the
/// scalar beyond its record.
fn row_flags(log: &FlightLog, models: &[FittedModel], channels: &[CompensatedChannel]) -> Vec<RowFlags> {
    let mut flags = match log.row_flags().len() == log.len() {
        true => log.row_flags().to_vec(),
        false => vec![RowFlags::default(); log.len()],
    };
    for (model, compensated) in models.iter().zip(channels) {
        let scalar = &log
            .channel(&model.channel)
            .expect("the prediction checked that every model's channel is in the flight log")
            .values;
        let Some(sensor) = log.vector_sensor(&model.vector_sensor) else {
            continue;
        };
        let field = log.vector_components(&sensor);
        let sources: Vec<(&str, &[f64])> = (model.spec.extensions.sources.iter())
            .filter_map(|s| Some((s.column(), log.channel(s.column())?.values.as_slice())))
            .collect();
        let terms = model.spec.fitted_terms();
        let derivatives = terms.eddy != crate::model::terms::EddyTerms::None || terms.field_derivative;
        for row in 0..log.len() {
            let mut explained = false;
            if !scalar[row].is_finite() {
                flags[row].raise(FlagKind::MissingScalar, &model.channel);
                explained = true;
            }
            if field.iter().any(|c| !c[row].is_finite()) {
                flags[row].raise(FlagKind::MissingVector, &model.vector_sensor);
                explained = true;
            }
            for (column, values) in &sources {
                if !values[row].is_finite() {
                    flags[row].raise(FlagKind::MissingSource, column);
                    explained = true;
                }
            }
            // Beside a missing vector sample the eddy terms' time
            // derivative is one-sided: the value stands, less accurately.
            let valid = |r: usize| field.iter().all(|c| c[r].is_finite());
            let beside_gap = (row > 0 && !valid(row - 1)) || (row + 1 < log.len() && !valid(row + 1));
            if !explained && derivatives && beside_gap && compensated.values[row].is_finite() {
                flags[row].raise(FlagKind::BesideGap, &model.vector_sensor);
            }
            let value = compensated.values[row];
            let (lowest, highest) = crate::ingest::screen::TOTAL_FIELD_RANGE_NT;
            if value.is_finite() && !(lowest..=highest).contains(&value) {
                flags[row].raise(FlagKind::OutputOutOfRange, &model.channel);
            }
            if !explained && !compensated.values[row].is_finite() {
                let kind = match model.spec.extensions.lag_s != 0.0 {
                    true => FlagKind::LagOutsideRecord,
                    false => FlagKind::ModelUndefined,
                };
                flags[row].raise(kind, &model.channel);
            }
        }
    }
    flags
}

#[cfg(test)]
mod rounding_tests {
    use super::*;

    /// Values round to the nearest step, a sigma up to the next one (never
    /// to zero), gradients three places finer, and a missing value stays
    /// missing.
    #[test]
    fn outputs_round_to_their_resolution_and_a_sigma_rounds_up() {
        let mut compensation = Compensation {
            channels: vec![CompensatedChannel {
                channel: "mag_1_uc".into(),
                values: vec![53_000.123_45, -0.0004, f64::NAN],
                interference_nt: vec![0.0; 3],
                level_offset_nt: 0.0,
                calibration_interference_nt: 0.0,
                sigma_nt: Some(vec![0.0004, 0.0021, 2.007]),
            }],
            flags: Vec::new(),
            vectors: Vec::new(),
            gradients: vec![CompensatedGradient {
                column: "grad_1_2_c".into(),
                values: vec![0.012345678, 0.0, 1.0],
            }],
            reduced: Vec::new(),
        };
        compensation.round_to(3);
        let channel = &compensation.channels[0];
        assert_eq!(channel.values[..2], [53_000.123, 0.0]);
        assert!(channel.values[2].is_nan());
        assert_eq!(channel.sigma_nt.as_deref().unwrap(), [0.001, 0.003, 2.007]);
        assert_eq!(compensation.gradients[0].values, [0.012346, 0.0, 1.0]);
        // -0.0004 rounds to +0, written "0", not "-0".
        assert!(channel.values[1].is_sign_positive());
    }
}
