//! Re-simulating a recorded flight with a fitted model: does the physics a
//! diagnosis found reproduce the recording better than plain
//! Tolles-Lawson?
//!
//! `magcomp simulate --replay FLIGHT --diagnosis DIAGNOSIS.json --out
//! SIM.csv` flies the recorded trajectory again: the recorded fluxgate
//! gives the field directions and rates, the recorded auxiliary columns
//! the currents, and each scalar sensor reads
//!
//! $$ s(t) = E(t - \ell) + h(t - \ell) $$
//!
//! where h is the fitted model's aircraft field (Tolles-Lawson terms, with
//! the diagnosis's lagged eddy terms and source terms), ℓ its sensor lag,
//! and E the Earth's field along the track. E is the one part no model of
//! the aircraft predicts (crustal anomalies, diurnal variation); the
//! replay takes it from the recording itself, as the compensated channel
//! low-passed below the fitting band, so that everything in the band is
//! the model's.
//!
//! Each channel is replayed twice, with plain Tolles-Lawson and with the
//! diagnosed model, both fitted on the flight's calibration windows. The
//! figure is the in-band RMS of recording − replay, over the calibration
//! manoeuvres and over the rest of the flight (where crustal anomalies in
//! the band are in the recording and in neither replay).

use std::collections::BTreeMap;

use rayon::prelude::*;
use serde::Serialize;

use crate::calibration::windows::CalibrationWindow;
use crate::compensate::{compensate, LevelConvention};
use crate::error::Result;
use crate::ingest::flight_log::FlightLog;
use crate::model::terms::TermSet;
use crate::model::{advanced, fit, Calibration, Extensions, FitOptions, FittedModel, ModelSpec};
use crate::numerics::filter::FilterBand;
use crate::numerics::segments::valid_runs;
use crate::numerics::stacked::StorePool;
use crate::quality::root_mean_square;

/// How well one channel's replays reproduce its recording.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReplayedChannel {
    /// Scalar channel.
    pub channel: String,
    /// What the diagnosed model adds to Tolles-Lawson.
    pub model: String,
    /// In-band RMS of recording − plain Tolles-Lawson replay over the
    /// calibration manoeuvres, nT.
    pub calibration_rms_plain_nt: f64,
    /// The same with the diagnosed model, nT.
    pub calibration_rms_diagnosed_nt: f64,
    /// In-band RMS of recording − plain replay over the rest of the
    /// flight, nT.
    pub elsewhere_rms_plain_nt: f64,
    /// The same with the diagnosed model, nT.
    pub elsewhere_rms_diagnosed_nt: f64,
}

/// A replayed flight.
#[derive(Debug, Clone)]
pub struct Replay {
    /// The recording with every replayed scalar channel replaced by its
    /// replay with the diagnosed model.
    pub log: FlightLog,
    /// Per channel, in `channels` order.
    pub channels: Vec<ReplayedChannel>,
}

/// Replays `channels` of `log` with plain Tolles-Lawson on `terms` and
/// with their extensions in `plan`, all fitted on `windows`.
pub fn replay(
    calibration: &Calibration,
    terms: &TermSet,
    options: &FitOptions,
    plan: &BTreeMap<String, Extensions>,
) -> Result<Replay> {
    let Calibration {
        log,
        sensor,
        channels,
        windows,
    } = *calibration;
    let results: Vec<(ReplayedChannel, Vec<f64>)> = channels
        .par_iter()
        .map(|channel| {
            let stores = StorePool::new();
            let plain = fit(
                log,
                sensor,
                channel,
                windows,
                &ModelSpec::plain(*terms),
                options,
                &stores,
            )?;
            let spec = ModelSpec::of_channel(*terms, plan, channel);
            let diagnosed = match spec.is_plain() {
                false => fit(log, sensor, channel, windows, &spec, options, &stores)?,
                true => plain.clone(),
            };
            let recorded = &log
                .channel(channel)
                .expect("the fit checked that the channel is in the flight")
                .values;
            let plain_replay = replay_channel(log, &plain, options)?;
            let diagnosed_replay = replay_channel(log, &diagnosed, options)?;
            let (calibration_plain, elsewhere_plain) = mismatch(log, recorded, &plain_replay, windows, options)?;
            let (calibration_diagnosed, elsewhere_diagnosed) =
                mismatch(log, recorded, &diagnosed_replay, windows, options)?;
            let summary = ReplayedChannel {
                channel: channel.clone(),
                model: spec.describe(),
                calibration_rms_plain_nt: calibration_plain,
                calibration_rms_diagnosed_nt: calibration_diagnosed,
                elsewhere_rms_plain_nt: elsewhere_plain,
                elsewhere_rms_diagnosed_nt: elsewhere_diagnosed,
            };
            Ok((summary, diagnosed_replay))
        })
        .collect::<Result<_>>()?;
    let mut replayed = log.clone();
    for (summary, values) in &results {
        replayed = replayed.with_values(&summary.channel, values.clone())?;
    }
    Ok(Replay {
        log: replayed,
        channels: results.into_iter().map(|(s, _)| s).collect(),
    })
}

/// What the sensor would have recorded with `model`'s aircraft: the
/// Earth's field (the compensated channel below the fitting band) plus the
/// model's field, read `lag_s` late.
fn replay_channel(log: &FlightLog, model: &FittedModel, options: &FitOptions) -> Result<Vec<f64>> {
    let compensated = compensate(log, std::slice::from_ref(model), LevelConvention::Absolute)?;
    let channel = &compensated.channels[0];
    let below_band = match options.filter.band {
        FilterBand::Bandpass { low_hz, .. } | FilterBand::Highpass { low_hz } => low_hz,
        FilterBand::Lowpass { .. } | FilterBand::None => 0.0,
    };
    let earth = match below_band > 0.0 {
        true => filtered_runs(
            log,
            &channel.values,
            FilterBand::Lowpass { high_hz: below_band },
            options,
            0,
        )?,
        false => channel.values.clone(),
    };
    let aligned: Vec<f64> = earth.iter().zip(&channel.interference_nt).map(|(e, h)| e + h).collect();
    let lag_s = model.spec.extensions.lag_s;
    Ok(match lag_s {
        0.0 => aligned,
        lag_s => advanced(&aligned, log.time_s(), -lag_s),
    })
}

/// In-band RMS of `recorded − replayed` over the calibration windows'
/// rows and over every other row.
fn mismatch(
    log: &FlightLog,
    recorded: &[f64],
    replayed: &[f64],
    windows: &[CalibrationWindow],
    options: &FitOptions,
) -> Result<(f64, f64)> {
    let difference: Vec<f64> = recorded.iter().zip(replayed).map(|(r, s)| r - s).collect();
    let band = filtered_runs(
        log,
        &difference,
        options.filter.band,
        options,
        options.filter.trim_samples,
    )?;
    let mut in_windows = vec![false; log.len()];
    for window in windows {
        in_windows[window.rows(log.time_s())].fill(true);
    }
    let pick = |inside: bool| -> Vec<f64> {
        band.iter()
            .zip(&in_windows)
            .filter(|(v, w)| v.is_finite() && **w == inside)
            .map(|(v, _)| *v)
            .collect()
    };
    Ok((root_mean_square(&pick(true)), root_mean_square(&pick(false))))
}

/// `values` filtered run by run (contiguous finite samples), `trim`
/// samples dropped at both ends of each run; `NaN` where a run is too
/// short.
fn filtered_runs(
    log: &FlightLog,
    values: &[f64],
    band: FilterBand,
    options: &FitOptions,
    trim: usize,
) -> Result<Vec<f64>> {
    let settings = crate::model::FilterSettings { band, ..options.filter };
    let filter = crate::model::design_filter(log, &settings)?;
    let valid: Vec<bool> = values.iter().map(|v| v.is_finite()).collect();
    let mut out = vec![f64::NAN; values.len()];
    for run in valid_runs(log.time_s(), &valid, 0..log.len(), log.median_interval_s()) {
        if run.len() < filter.min_samples().max(2 * trim + 1) {
            continue;
        }
        let Ok(filtered) = filter.apply(&values[run.clone()]) else {
            continue;
        };
        let keep = trim..run.len() - trim;
        out[run.start + keep.start..run.start + keep.end].copy_from_slice(&filtered[keep]);
    }
    Ok(out)
}
