//! Gradient compensation: the difference of two scalar sensors over their
//! separation, in nT/m, with the aircraft's interference removed.
//!
//! A gradient can be compensated two ways:
//! - **difference**: each sensor compensated on its own, then
//!   $(c_a - c_b)/d$;
//! - **direct**: one Tolles-Lawson model fitted to the recorded difference
//!   $m_a - m_b$ (band-passed, λ by the same criterion as any channel),
//!   then $((m_a - m_b) - \hat I_{ab})/d$.
//!
//! The two differ in what the fit sees. Whatever both sensors see alike
//! (geomagnetic pulsations, the crust's field in the calibration band
//! over the box) is noise to each single-sensor fit and biases its
//! coefficients, each its own way, so the biases need not cancel in the
//! difference; it cancels in $m_a - m_b$ before the direct fit. The
//! direct fit has one λ for the pair, the difference one per sensor. Which
//! is better on a flight is measured, not assumed: each heading of the box
//! is held out in turn, both are fitted on the others, and the band-passed
//! residual of the gradient on the held-out heading decides (`method =
//! "auto"`).
//!
//! **Level.** The manoeuvres pin the interference's variation, not its
//! mean: the induced terms sum to a constant, and the aircraft's steady
//! field at the two sensors differs by an amount no manoeuvre reveals. The
//! gradient's level is therefore that of the compensated channels (or of
//! the direct fit's), as `[fit] level` says, and can be off by the
//! aircraft's steady difference over d; the run says so. What is
//! compensated is the gradient's variation along the lines, which is what
//! gradient surveys level to tie lines anyway.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::calibration::windows::CalibrationWindow;
use crate::compensate::{compensate_channel, CompensatedGradient, Compensation, LevelConvention};
use crate::error::{Error, Result};
use crate::ingest::flight_log::{Channel, ChannelRole, FlightLog, VectorSensor};
use crate::messages::{GradientParting, Note, Warning};
use crate::model::terms::TermSet;
use crate::model::{fit, FitOptions, FittedModel, ModelSpec, SharedDesign, WindowFit};
use crate::numerics::stacked::StorePool;

/// How a gradient is compensated (`[[gradient]] method`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GradientMethod {
    /// The one of the two with the smaller held-out residual.
    #[default]
    Auto,
    /// One model fitted to the difference of the two sensors.
    Direct,
    /// The difference of the two compensated channels.
    Difference,
}

/// One gradient to compensate: `(a − b)/separation`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GradientPair {
    /// The first sensor (the gradient points from `b` to `a`).
    pub a: String,
    /// The second sensor.
    pub b: String,
    /// Distance between them, m.
    pub separation_m: f64,
    /// The unit vector from `b` to `a` in body axes (forward, right, down),
    /// when their positions are known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub axis_body: Option<[f64; 3]>,
    /// How to compensate it.
    pub method: GradientMethod,
}

impl GradientPair {
    /// The output column: `grad_<a>_<b>_c` with each sensor's stem
    /// ([`sensor_stem`]).
    pub fn column(&self) -> String {
        format!("{}_c", gradient_name(&self.a, &self.b))
    }
}

/// Sensors closer than this (m) make no gradient: their difference is
/// the aircraft's and the noise's.
pub const LEAST_SEPARATION_M: f64 = 0.1;

/// `grad_<a>_<b>`, each sensor by its stem: `mag_1_uc` and `mag_3_uc` give
/// `grad_1_3`.
pub fn gradient_name(a: &str, b: &str) -> String {
    format!("grad_{}_{}", sensor_stem(a), sensor_stem(b))
}

/// A scalar channel's short name: `<n>` of the SGL `mag_<n>_uc`, else the
/// name itself.
pub fn sensor_stem(channel: &str) -> &str {
    channel
        .strip_prefix("mag_")
        .and_then(|s| s.strip_suffix("_uc"))
        .unwrap_or(channel)
}

/// The held-out comparison of the two methods, nT/m.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GradientHeldOut {
    /// Headings held out in turn.
    pub headings: usize,
    /// Band-passed rows scored (held-out rows both methods predict).
    pub rows: usize,
    /// RMS of the direct model's band-passed gradient residual, nT/m.
    pub direct_nt_per_m: f64,
    /// RMS of the difference of the two channels' residuals, nT/m.
    pub difference_nt_per_m: f64,
}

/// What the gradient stage did with one pair.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GradientResult {
    /// The output column.
    pub column: String,
    /// The pair and its settings.
    pub pair: GradientPair,
    /// The method the output comes from.
    pub method_used: GradientMethod,
    /// Why that method.
    pub reason: String,
    /// Both methods held out by heading; `None` with fewer than three
    /// headings.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub held_out: Option<GradientHeldOut>,
    /// The direct model's in-band residual over the box, nT/m.
    pub direct_residual_nt_per_m: f64,
    /// How far the two methods' gradients differ on the survey lines (the
    /// rows outside the windows without lines): RMS about the mean
    /// difference, nT/m. One of them is at least half that wrong there.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub methods_disagree_nt_per_m: Option<f64>,
    /// Whether they part beyond what either held out while neither
    /// channel is marked uncertain: the direct fit is then the one at
    /// odds, and `auto` takes the difference.
    pub direct_at_odds: bool,
    /// The level the output's convention added, nT/m: how far the
    /// gradient's mean rests on a choice, not on the data.
    pub level_offset_nt_per_m: f64,
}

/// Everything the stage produced.
#[derive(Debug, Default)]
pub struct GradientStage {
    /// One per pair compensated.
    pub results: Vec<GradientResult>,
    /// The direct models (the model JSON holds them).
    pub models: Vec<FittedModel>,
    /// The compensated columns.
    pub compensated: Vec<CompensatedGradient>,
    /// Lines for the summary.
    pub notes: Vec<Note>,
    /// What the user must know.
    pub warnings: Vec<Warning>,
}

/// What the stage reads from the run: the flight as fitted, the fluxgate,
/// the windows, the channels' models and their compensation.
pub struct GradientInputs<'a> {
    /// The flight as the fits saw it (fluxgate calibrated when it was).
    pub log: &'a FlightLog,
    /// The fluxgate the terms are built from.
    pub sensor: &'a VectorSensor,
    /// Calibration windows.
    pub windows: &'a [CalibrationWindow],
    /// The fitted channel models.
    pub models: &'a [FittedModel],
    /// Their compensation.
    pub compensation: &'a Compensation,
    /// The terms over the whole flight that compensation built
    /// ([`crate::compensate::compensate_with`]): the direct model reads
    /// the same fluxgate, so it takes its terms from here when its terms
    /// are among them, and builds them otherwise.
    pub shared: &'a [SharedDesign],
    /// Whether each model's compensation carries the uncertainty warning
    /// ([`crate::quality::is_uncertain`]), in the models' order.
    pub uncertain: &'a [bool],
}

/// Compensates every pair of `pairs` whose sensors both have a model. A
/// pair that cannot be compensated is a warning; the other outputs stand.
pub fn compensate_gradients(
    inputs: &GradientInputs,
    pairs: &[GradientPair],
    (terms, options, level): (TermSet, &FitOptions, LevelConvention),
) -> GradientStage {
    // The pairs are independent: fitted in parallel, gathered in order.
    let outcomes: Vec<_> = pairs
        .par_iter()
        .map(|pair| compensate_pair(inputs, pair, (terms, options, level)))
        .collect();
    let mut stage = GradientStage::default();
    for (pair, outcome) in pairs.iter().zip(outcomes) {
        match outcome {
            Ok((result, model, compensated)) => {
                stage.notes.push(describe(&result));
                stage.warnings.push(level_warning(pair, result.level_offset_nt_per_m));
                match disagreement(&result) {
                    Some(AtOdds::Warning(warning)) => stage.warnings.push(warning),
                    Some(AtOdds::Note(note)) => stage.notes.push(note),
                    None => {}
                }
                stage.results.push(result);
                stage.models.push(model);
                stage.compensated.push(compensated);
            }
            Err(e) => stage.warnings.push(Warning::GradientNotCompensated {
                column: pair.column(),
                reason: e.to_string(),
            }),
        }
    }
    stage
}

/// The gradients of `pairs` on a flight compensated with a saved model
/// (`models`, in the order of `compensation`'s channels): the difference of
/// the two compensated channels over the separation. A direct fit needs a
/// calibration box, and the model file holds the scalar models only: a
/// pair asking for `method = "direct"`, or naming a channel the model does
/// not compensate, is a warning and gets no column.
pub fn gradients_from_saved_model(
    models: &[FittedModel],
    compensation: &Compensation,
    pairs: &[GradientPair],
) -> GradientStage {
    let mut stage = GradientStage::default();
    for pair in pairs {
        let column = pair.column();
        let index = |name: &str| models.iter().position(|m| m.channel == name);
        let (Some(ia), Some(ib)) = (index(&pair.a), index(&pair.b)) else {
            stage.warnings.push(Warning::GradientNotCompensated {
                column,
                reason: format!(
                    "the saved model compensates {} and not both of '{}' and '{}'",
                    models.iter().map(|m| m.channel.as_str()).collect::<Vec<_>>().join(", "),
                    pair.a,
                    pair.b
                ),
            });
            continue;
        };
        if pair.method == GradientMethod::Direct {
            stage.warnings.push(Warning::GradientNotCompensated {
                column,
                reason: "[[gradient]] method = \"direct\" fits a model to the difference on a calibration box, which a flight compensated with a saved model does not have; method = \"difference\" (or \"auto\") takes the difference of the compensated channels".into(),
            });
            continue;
        }
        let d = pair.separation_m;
        let (a, b) = (&compensation.channels[ia], &compensation.channels[ib]);
        stage.compensated.push(CompensatedGradient {
            column: column.clone(),
            values: a.values.iter().zip(&b.values).map(|(a, b)| (a - b) / d).collect(),
        });
        stage.notes.push(Note::GradientFromSavedChannels {
            column: column.clone(),
            channels: [pair.a.clone(), pair.b.clone()],
            separation_m: d,
        });
        stage
            .warnings
            .push(level_warning(pair, (a.level_offset_nt - b.level_offset_nt) / d));
    }
    stage
}

/// The warning every compensated gradient carries: its level is not
/// pinned by the calibration; `offset_nt_per_m` is what `[fit] level`
/// moved it by.
fn level_warning(pair: &GradientPair, offset_nt_per_m: f64) -> Warning {
    Warning::GradientLevelUnpinned {
        column: pair.column(),
        channels: [pair.a.clone(), pair.b.clone()],
        separation_m: pair.separation_m,
        moved_nt_per_m: offset_nt_per_m,
    }
}

/// Two methods whose gradients part on the survey lines by more than
/// this, nT over the separation (the scalar channels' uncertainty
/// warning), and by more than [`DISAGREEMENT_FACTOR`] times what either
/// held out, are not both right there.
const DISAGREEMENT_FLOOR_NT: f64 = 0.05;

/// See [`DISAGREEMENT_FLOOR_NT`].
const DISAGREEMENT_FACTOR: f64 = 5.0;

/// Whether the direct fit and the difference of the compensated channels
/// (channels `ia`, `ib`) part on the survey lines by `apart` (nT/m)
/// beyond what either held out, while neither channel's compensation is
/// marked uncertain (which would explain a bad difference): the direct fit
/// is then the one at odds.
fn direct_at_odds(
    inputs: &GradientInputs,
    (ia, ib): (usize, usize),
    apart: Option<f64>,
    held_out: Option<&GradientHeldOut>,
    d: f64,
) -> bool {
    let held = held_out.map_or(0.0, |h| h.direct_nt_per_m.max(h.difference_nt_per_m));
    let uncertain = |i: usize| inputs.uncertain.get(i) == Some(&true);
    apart.is_some_and(|apart| apart > (DISAGREEMENT_FLOOR_NT / d).max(DISAGREEMENT_FACTOR * held))
        && !uncertain(ia)
        && !uncertain(ib)
}

/// What a run says of a direct fit at odds.
enum AtOdds {
    /// The output is the direct fit.
    Warning(Warning),
    /// The output is the difference.
    Note(Note),
}

/// A direct fit at odds ([`direct_at_odds`]): a warning when the output
/// is the direct fit (`method = "direct"` asked for it), a note when it is
/// the difference; `None` otherwise.
fn disagreement(result: &GradientResult) -> Option<AtOdds> {
    if !result.direct_at_odds {
        return None;
    }
    let parting = GradientParting {
        column: result.column.clone(),
        channels: [result.pair.a.clone(), result.pair.b.clone()],
        apart_nt_per_m: result.methods_disagree_nt_per_m?,
        separation_m: result.pair.separation_m,
    };
    Some(match result.method_used {
        GradientMethod::Direct => AtOdds::Warning(Warning::GradientDirectAtOdds { parting }),
        _ => AtOdds::Note(Note::GradientDifferenceUsed { parting }),
    })
}

/// One line on a compensated gradient.
fn describe(result: &GradientResult) -> Note {
    Note::GradientFormed {
        column: result.column.clone(),
        channels: [result.pair.a.clone(), result.pair.b.clone()],
        separation_m: result.pair.separation_m,
        direct: result.method_used == GradientMethod::Direct,
        reason: result.reason.clone(),
        held_out: (result.held_out.as_ref())
            .map(|held| (held.headings, held.direct_nt_per_m, held.difference_nt_per_m)),
    }
}

/// Where the pair's two channels are among the compensated ones; an error
/// for a channel not compensated or a separation that is not positive.
fn pair_indices(inputs: &GradientInputs, pair: &GradientPair) -> Result<(usize, usize)> {
    let index = |name: &str| {
        inputs
            .models
            .iter()
            .position(|m| m.channel == name)
            .ok_or_else(|| Error::Config {
                source_name: "[[gradient]]".into(),
                message: format!("'{name}' is not a compensated scalar channel of this flight"),
            })
    };
    let indices = (index(&pair.a)?, index(&pair.b)?);
    if !(pair.separation_m.is_finite() && pair.separation_m > 0.0) {
        return Err(Error::Config {
            source_name: "[[gradient]]".into(),
            message: format!("separation {} m: it must be positive", pair.separation_m),
        });
    }
    Ok(indices)
}

fn compensate_pair(
    inputs: &GradientInputs,
    pair: &GradientPair,
    (terms, options, level): (TermSet, &FitOptions, LevelConvention),
) -> Result<(GradientResult, FittedModel, CompensatedGradient)> {
    let log = inputs.log;
    let (ia, ib) = pair_indices(inputs, pair)?;
    let name = gradient_name(&pair.a, &pair.b);
    let lean = difference_log(log, inputs.sensor, pair, &name)?;
    let sensor = lean.vector_sensor(&inputs.sensor.prefix).ok_or_else(|| Error::Vector {
        sensor: inputs.sensor.prefix.clone(),
        message: "the fluxgate is not in the flight".into(),
    })?;
    let spec = ModelSpec::plain(terms);
    let stores = StorePool::new();
    let model = fit(&lean, &sensor, &name, inputs.windows, &spec, options, &stores)?;
    let d = pair.separation_m;
    let held_out = held_out(inputs, (&lean, &sensor, &name), (&spec, options), (ia, ib, d))?;
    // Both methods' difference fields, nT: the one used is the output,
    // and where they part on the survey one of them is wrong.
    let direct = {
        // Only the values are read: the rows' flags are the channels'.
        let channel = compensate_channel(&lean, &model, level, inputs.shared)?;
        (channel.values, channel.level_offset_nt)
    };
    let difference = {
        let (a, b) = (&inputs.compensation.channels[ia], &inputs.compensation.channels[ib]);
        let values: Vec<f64> = a.values.iter().zip(&b.values).map(|(a, b)| a - b).collect();
        (values, a.level_offset_nt - b.level_offset_nt)
    };
    let disagree_nt = survey_spread(log, inputs.windows, &direct.0, &difference.0);
    let at_odds = direct_at_odds(inputs, (ia, ib), disagree_nt.map(|v| v / d), held_out.as_ref(), d);
    let (method_used, reason) = choose(pair.method, held_out.as_ref(), at_odds);
    let (values, level_offset_nt) = match method_used {
        GradientMethod::Direct => direct,
        _ => difference,
    };
    let residual = model
        .windows
        .iter()
        .flat_map(|w| w.band_after_nt.iter())
        .fold((0.0, 0usize), |(s, n), r| (s + r * r, n + 1));
    let result = GradientResult {
        column: pair.column(),
        pair: pair.clone(),
        method_used,
        reason,
        held_out,
        direct_residual_nt_per_m: (residual.0 / residual.1.max(1) as f64).sqrt() / d,
        methods_disagree_nt_per_m: disagree_nt.map(|v| v / d),
        direct_at_odds: at_odds,
        level_offset_nt_per_m: level_offset_nt / d,
    };
    let compensated = CompensatedGradient {
        column: pair.column(),
        values: values.into_iter().map(|v| v / d).collect(),
    };
    Ok((result, model, compensated))
}

/// The spread of `a − b` about its mean over the survey lines' rows (the
/// rows outside `windows` without lines), nT; `None` without a row where
/// both are finite.
fn survey_spread(log: &FlightLog, windows: &[CalibrationWindow], a: &[f64], b: &[f64]) -> Option<f64> {
    let lines = log.survey_lines();
    let rows: Vec<usize> = match lines.is_empty() {
        false => lines.into_iter().flat_map(|(_, rows)| rows).collect(),
        true => {
            let mut inside = vec![false; log.len()];
            for window in windows {
                inside[window.rows(log.time_s())].fill(true);
            }
            (0..log.len()).filter(|&r| !inside[r]).collect()
        }
    };
    let differences: Vec<f64> = (rows.iter()).map(|&r| a[r] - b[r]).filter(|v| v.is_finite()).collect();
    (!differences.is_empty()).then(|| crate::numerics::statistics::standard_deviation(&differences))
}

/// The flight reduced to what the direct fit reads: the fluxgate and the
/// recorded difference `a − b` as a scalar channel named `name` (NaN
/// where either is missing).
fn difference_log(log: &FlightLog, sensor: &VectorSensor, pair: &GradientPair, name: &str) -> Result<FlightLog> {
    let values = |channel: &str| {
        log.channel(channel)
            .map(|c| c.values.as_slice())
            .ok_or_else(|| Error::MissingColumn {
                path: log.source().to_path_buf(),
                role: "scalar magnetometer",
                looked_for: format!("'{channel}'"),
                hint: "Name two scalar channels the flight records in [[gradient]].".into(),
            })
    };
    let difference: Vec<f64> = values(&pair.a)?
        .iter()
        .zip(values(&pair.b)?)
        .map(|(a, b)| a - b)
        .collect();
    let mut channels: Vec<Channel> = sensor.axes.iter().map(|&i| log.channels()[i].clone()).collect();
    channels.push(Channel {
        name: name.into(),
        role: ChannelRole::ScalarMagnetometer,
        values: difference,
    });
    log.with_channels(channels)
}

/// Each heading held out in turn: the direct model and the two channels'
/// models fitted on the others, the band-passed residual of the gradient
/// on it, over the separation `d`. `None` with fewer than three headings.
fn held_out(
    inputs: &GradientInputs,
    (lean, lean_sensor, name): (&FlightLog, &VectorSensor, &str),
    (spec, options): (&ModelSpec, &FitOptions),
    (ia, ib, d): (usize, usize, f64),
) -> Result<Option<GradientHeldOut>> {
    let Some(splits) = crate::calibration::headings::heading_splits(inputs.windows) else {
        return Ok(None);
    };
    let stores = StorePool::new();
    let folds: Vec<Vec<(f64, f64)>> = splits
        .par_iter()
        .map(|(held, kept)| {
            let direct = fit(lean, lean_sensor, name, kept, spec, options, &stores)?.held_out(
                lean,
                lean_sensor,
                held,
                options,
            )?;
            let channel = |i: usize| -> Result<Vec<WindowFit>> {
                let model: &FittedModel = &inputs.models[i];
                fit(
                    inputs.log,
                    inputs.sensor,
                    &model.channel,
                    kept,
                    &model.spec,
                    options,
                    &stores,
                )?
                .held_out(inputs.log, inputs.sensor, held, options)
            };
            let (a, b) = (by_row(&channel(ia)?), by_row(&channel(ib)?));
            Ok(by_row(&direct)
                .into_iter()
                .filter_map(|(row, direct)| Some((direct, a.get(&row)? - b.get(&row)?)))
                .collect())
        })
        .collect::<Result<_>>()?;
    let pairs: Vec<(f64, f64)> = folds.into_iter().flatten().collect();
    if pairs.is_empty() {
        return Ok(None);
    }
    let rms =
        |pick: fn(&(f64, f64)) -> f64| (pairs.iter().map(|p| pick(p).powi(2)).sum::<f64>() / pairs.len() as f64).sqrt();
    Ok(Some(GradientHeldOut {
        headings: splits.len(),
        rows: pairs.len(),
        direct_nt_per_m: rms(|p| p.0) / d,
        difference_nt_per_m: rms(|p| p.1) / d,
    }))
}

/// The band-passed residual of `fits` by flight row.
fn by_row(fits: &[WindowFit]) -> std::collections::BTreeMap<usize, f64> {
    fits.iter()
        .flat_map(|w| {
            w.flight_rows
                .iter()
                .cloned()
                .flatten()
                .zip(w.band_after_nt.iter().copied())
        })
        .collect()
}

/// The method to use and why; `at_odds`: the direct fit parts from the
/// difference on the survey lines ([`direct_at_odds`]).
fn choose(asked: GradientMethod, held_out: Option<&GradientHeldOut>, at_odds: bool) -> (GradientMethod, String) {
    match (asked, held_out) {
        (GradientMethod::Direct, _) => (GradientMethod::Direct, "as [[gradient]] method asks".into()),
        (GradientMethod::Difference, _) => (GradientMethod::Difference, "as [[gradient]] method asks".into()),
        (GradientMethod::Auto, _) if at_odds => (
            GradientMethod::Difference,
            "the direct fit parts from the difference on the survey lines while neither channel is marked uncertain".into(),
        ),
        (GradientMethod::Auto, Some(held)) if held.direct_nt_per_m <= held.difference_nt_per_m => (
            GradientMethod::Direct,
            "the smaller residual held out by heading".into(),
        ),
        (GradientMethod::Auto, Some(_)) => (
            GradientMethod::Difference,
            "the smaller residual held out by heading".into(),
        ),
        (GradientMethod::Auto, None) => (
            GradientMethod::Direct,
            "not compared held out: the windows span fewer than three headings; the direct fit is not disturbed by what both sensors see alike".into(),
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensate::compensate;
    use crate::simulate::scenario::{RawScenario, Scenario};

    /// The direct model reads the fluxgate of the flight its channels were
    /// compensated on: compensated with the terms that compensation built,
    /// it gives the bits of the compensation that builds its own, and
    /// those of the whole compensation the gradient stage once made.
    #[test]
    fn the_direct_model_from_the_shared_terms_is_the_same_bits() {
        let raw: RawScenario = toml::from_str("[survey]\nline_count = 1\nline_length_m = 3000.0\n").unwrap();
        let log = crate::simulate::simulate(&Scenario::try_from(raw).unwrap())
            .unwrap()
            .log;
        let windows = crate::calibration::detect::detect_manoeuvres(&log, &Default::default())
            .unwrap()
            .calibration_windows(1.0);
        let sensor = log.vector_sensors().into_iter().next().unwrap();
        let (options, stores) = (FitOptions::default(), StorePool::new());
        let spec = ModelSpec::plain(TermSet::default());
        let channel_model = fit(&log, &sensor, "mag_1_uc", &windows, &spec, &options, &stores).unwrap();
        let shared = SharedDesign::of_models(&log, std::slice::from_ref(&channel_model));
        assert_eq!(shared.len(), 1);
        let pair = GradientPair {
            a: "mag_1_uc".into(),
            b: "mag_2_uc".into(),
            separation_m: 1.5,
            axis_body: None,
            method: GradientMethod::Direct,
        };
        let name = gradient_name(&pair.a, &pair.b);
        let lean = difference_log(&log, &sensor, &pair, &name).unwrap();
        let lean_sensor = lean.vector_sensor(&sensor.prefix).unwrap();
        let direct = fit(&lean, &lean_sensor, &name, &windows, &spec, &options, &stores).unwrap();
        let level = LevelConvention::CalibrationMean;
        let bits = |values: &[f64]| values.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        let from_shared = compensate_channel(&lean, &direct, level, &shared).unwrap();
        let own = compensate_channel(&lean, &direct, level, &[]).unwrap();
        let whole = compensate(&lean, std::slice::from_ref(&direct), level).unwrap();
        assert!(from_shared.values.iter().filter(|v| v.is_finite()).count() > lean.len() / 2);
        assert_eq!(bits(&from_shared.values), bits(&own.values));
        assert_eq!(bits(&from_shared.values), bits(&whole.channels[0].values));
        assert_eq!(
            from_shared.level_offset_nt.to_bits(),
            whole.channels[0].level_offset_nt.to_bits()
        );
    }
}
